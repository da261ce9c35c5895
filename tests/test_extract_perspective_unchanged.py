"""The perspective chain keeps its features: fixed frames of the KidSize and NAO renderers
(and, where ../shared/realdata is present, real HULKs NAO frames) extracted with the default
conf give the features stored in tests/data/perspective_features_reference.npz, within the
tolerances below. A deliberate change of the features (a new threshold, a new check)
rewrites the reference (``python tests/test_extract_perspective_unchanged.py``) in the same
commit, which says why and what moved.

What must hold, per set of frames:
- the rendered frames are the reference's frames: at most RENDER_SHARE of their pixels
  differ by more than RENDER_GREY grey levels (the renderer's float32 arithmetic and
  numpy's and OpenCV's vectorised functions may round a few pixels the other way on another
  processor; a changed renderer moves far more). The reference keeps every 8th row and
  column of each rendered frame (IMAGE_STRIDE) to compare with;
- lines: each reference line has a line within LINE_PX image px (both ends, either order);
  the counts differ by at most COUNT_MARGIN per frame; all but CHANGED_SHARE of the lines
  are unchanged (within LINE_CLOSE_PX);
- crossings and posts likewise by their image position and kind;
- the field boundary within BOUNDARY_PX where both have it.
A feature near a decision threshold (a crossing's verification, a line's merge) may flip on
a last-bit change of its inputs; CHANGED_SHARE bounds how many may.

The renderer's frames depend on OpenCV's major version (its remap of float maps rounds the
offsets to 1/32 px in 4.x, not in 5.x: 0.2 to 6 % of the pixels move by more than 2 grey
levels), so the rendered frames are compared only under the OpenCV major version the
reference was written with (``opencv_major`` in it); the real frames under any.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from stages import simulate
from stages.common.field import load_field
from stages.extract import perspective
from stages.simulate import scene
from stages.simulate.perspective_renderer import PerspectiveRenderer

REFERENCE = Path(__file__).parent / "data" / "perspective_features_reference.npz"
HULKS = (Path(__file__).resolve().parents[2] / "shared" / "realdata" / "hulks-goalbox-labels"
         / "measurements")
HULKS_EVERY = 11  # every 11th capture by name (10 frames, top and bottom camera)
RENDERS = (("perspective-default", "kidsize"), ("perspective-nao", "spl"))
FRAMES = 4

RENDER_GREY, RENDER_SHARE = 2, 0.001  # pixels differing by > 2 levels: at most 0.1 %
IMAGE_STRIDE = 8  # the reference's sample of a rendered frame: every 8th row and column
LINE_PX = 3.0  # a line matched: both ends within 3 px
LINE_CLOSE_PX = 0.05  # a line unchanged: both ends within 0.05 px
POINT_PX = 3.0  # crossings and posts matched within 3 px (and of the same kind)
COUNT_MARGIN = 1  # features of a kind per frame: at most one more or fewer
CHANGED_SHARE = 0.1  # at most 10 % of the features unmatched or moved beyond "unchanged"
BOUNDARY_PX = 1.0


def rendered_frames(preset: str, field_name: str):
    """(name, image, camera, pitch, roll) of FRAMES fixed frames in front of a goal."""
    fm = load_field(field_name)
    conf = dict(simulate.confs[preset])
    world = scene.build(fm, conf["scene"], np.arange(FRAMES) / 10.0, 4)
    renderer = PerspectiveRenderer(conf["perspective"], world, seed=4)
    cam = renderer.camera
    rng = np.random.default_rng(8)
    out = []
    for k in range(FRAMES):
        pose = np.array([fm.length / 2 - rng.uniform(0.5, 4.0), rng.uniform(-2.5, 2.5),
                         rng.uniform(-0.9, 0.9)])
        pitch, roll = cam.pitch + rng.normal(0, 0.03), rng.normal(0, 0.02)
        out.append((f"{preset}-{k}", renderer.render_view(pose, pitch, roll, frame=k), cam,
                    pitch, roll))
    return out


def hulks_frames():
    import cv2

    from stages.calibrate import hulks

    out = []
    for js in sorted(HULKS.glob("*.json"))[::HULKS_EVERY]:
        stem = js.stem
        cam = hulks.read_frame(HULKS / f"{stem}.json").camera
        out.append((f"hulks-{stem}", cv2.imread(str(HULKS / f"{stem}.jpg")), cam, None, None))
    return out


def features(frames) -> dict[str, np.ndarray]:
    """The features of each frame, and a sample of each rendered frame's pixels."""
    conf = perspective.confs["default"]
    out = {}
    for name, img, cam, pitch, roll in frames:
        res = perspective.extract_frame(img, cam, conf, pitch=pitch, roll=roll)
        if not name.startswith("hulks-"):
            out[f"{name}/image_sample"] = img[::IMAGE_STRIDE, ::IMAGE_STRIDE]
        for key, value in res.items():
            out[f"{name}/{key}"] = value
    return out


def differing_share(a: np.ndarray, b: np.ndarray) -> float:
    """The share of pixels (uint8 images) whose channels differ by more than RENDER_GREY."""
    return float(np.mean(np.abs(a.astype(int) - b.astype(int)).max(axis=-1) > RENDER_GREY))


def _line_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per pair of lines (rows of (x0, y0, x1, y1)): the larger distance of their ends, the
    ends taken in the nearer order; (len(a), len(b))."""
    a, b = np.asarray(a, float).reshape(-1, 1, 2, 2), np.asarray(b, float).reshape(1, -1, 2, 2)
    same = np.hypot(*(a - b).transpose(3, 0, 1, 2)).max(axis=-1)
    swap = np.hypot(*(a - b[:, :, ::-1]).transpose(3, 0, 1, 2)).max(axis=-1)
    return np.minimum(same, swap)


def _matched(dist: np.ndarray, tol: float) -> np.ndarray:
    """Per reference feature (rows), its nearest feature's distance when within ``tol``
    and that feature not nearer to another reference feature; else inf."""
    out = np.full(dist.shape[0], np.inf)
    if dist.size == 0:
        return out
    best = dist.argmin(axis=1)
    for i, j in enumerate(best):
        if dist[i, j] <= tol and dist[:, j].argmin() == i:
            out[i] = dist[i, j]
    return out


def compare(got: dict, ref: dict, name: str) -> dict:
    """How frame ``name``'s features ``got`` differ from the reference's: per kind (lines,
    crossings, posts) the counts, the reference features matched and their largest
    deviation, and those unchanged (lines within LINE_CLOSE_PX, points within 0.05 px)."""
    out = {}
    d = _matched(_line_distance(ref[f"{name}/line_ends_px"], got[f"{name}/line_ends_px"]),
                 LINE_PX)
    out["lines"] = (len(ref[f"{name}/lines"]), len(got[f"{name}/lines"]), d)
    for kind, px, code in (("crossings", "crossings_px", 0), ("posts", "posts_px", None)):
        a, b = ref[f"{name}/{px}"].astype(float), got[f"{name}/{px}"].astype(float)
        dist = np.hypot(*(a[:, None, :] - b[None, :, :]).transpose(2, 0, 1))
        if code is not None:  # the same kind of crossing
            same = ref[f"{name}/{kind}"][:, code][:, None] == got[f"{name}/{kind}"][:, code][None]
            dist = np.where(same, dist, np.inf)
        out[kind] = (len(a), len(b), _matched(dist, POINT_PX))
    return out


def _check(got: dict, names: list[str]) -> int:
    ref = np.load(REFERENCE)
    total = changed = 0
    assert names
    for name in names:
        sample = f"{name}/image_sample"
        if sample in ref.files:
            assert differing_share(got[sample], ref[sample]) <= RENDER_SHARE, \
                f"{name}: the frame itself changed"
        for kind, (n_ref, n_got, d) in compare(got, ref, name).items():
            assert abs(n_ref - n_got) <= COUNT_MARGIN, (name, kind, n_ref, n_got)
            close = LINE_CLOSE_PX if kind == "lines" else 0.05
            total += max(n_ref, n_got)
            changed += int(np.sum(~(d <= close))) + max(n_got - n_ref, 0)
        a, b = ref[f"{name}/boundary"], got[f"{name}/boundary"]
        if a.shape == b.shape:
            both = np.isfinite(a) & np.isfinite(b)
            np.testing.assert_allclose(b[both], a[both], rtol=0, atol=BOUNDARY_PX, err_msg=name)
        else:
            changed += 1
    assert changed <= CHANGED_SHARE * total, (changed, total)
    return total


def _same_opencv_major():
    import cv2

    major = int(cv2.__version__.split(".")[0])
    written = int(np.load(REFERENCE)["opencv_major"])
    if major != written:
        pytest.skip(f"the reference frames were rendered with OpenCV {written}.x, this is "
                    f"{cv2.__version__} (its remap rounds differently)")


@pytest.mark.parametrize("preset,field_name", RENDERS)
def test_rendered_frames_give_the_reference_features(preset, field_name):
    _same_opencv_major()
    frames = rendered_frames(preset, field_name)
    got = features(frames)
    assert _check(got, [f[0] for f in frames]) >= 10
    # the frames hold what is compared: lines and crossings
    assert sum(len(got[f"{f[0]}/lines"]) for f in frames) >= 8
    assert sum(len(got[f"{f[0]}/crossings"]) for f in frames) >= 2


@pytest.mark.realdata
@pytest.mark.skipif(not HULKS.is_dir(), reason="needs ../shared/realdata")
def test_real_nao_frames_give_the_reference_features():
    frames = hulks_frames()
    got = features(frames)
    assert _check(got, [f[0] for f in frames]) >= 10


def write_reference():
    frames = [f for p, fn in RENDERS for f in rendered_frames(p, fn)]
    if HULKS.is_dir():
        frames += hulks_frames()
    import cv2

    REFERENCE.parent.mkdir(exist_ok=True)
    np.savez_compressed(REFERENCE, opencv_major=np.array(int(cv2.__version__.split(".")[0])),
                        **features(frames))
    print(f"wrote {REFERENCE} ({len(frames)} frames)")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    write_reference()
