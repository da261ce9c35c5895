"""The perspective chain keeps its features, and the renderer its frames.

Features: fixed frames of the KidSize and NAO renderers, stored losslessly in
tests/data/perspective_frames/ (PNG, with their cameras and head angles in frames.json), and,
where ../shared/realdata is present, real HULKs NAO frames, extracted with the default conf,
give the features stored in tests/data/perspective_features_reference.npz within the
tolerances below. The stored frames are inputs: this test does not render, so neither the
renderer nor OpenCV's resampling moves them. A deliberate change of the features (a new
threshold, a new check) or of the renderer rewrites the frames and the reference
(``python tests/test_extract_perspective_unchanged.py``) in the same commit, which says why
and what moved.

What must hold, per set of frames:
- lines: each reference line has a line within LINE_PX image px (both ends, either order);
  the counts differ by at most COUNT_MARGIN per frame; all but CHANGED_SHARE of the lines
  are unchanged (within LINE_CLOSE_PX);
- crossings and posts likewise by their image position and kind;
- the field boundary within BOUNDARY_PX where both have it.
A feature near a decision threshold (a crossing's verification, a line's merge) may flip on
a last-bit change of its inputs; CHANGED_SHARE bounds how many may.

Renderer: the same frames rendered afresh are the stored ones up to rounding: at most
RENDER_ANY of their pixels differ at all and at most RENDER_SHARE by more than RENDER_GREY
grey levels. The renderer samples its textures on OpenCV's 1/32-texel fixed-point grid
(stages.common.fixed_remap), the same in OpenCV 4.x and 5.x; its blurs, resizes and
numpy's vectorised float functions may still round a few pixels the other way on another
processor or OpenCV version (measured: at most 0.07 % of the pixels, by at most 3 levels).
A changed renderer moves far more (sampling at exact rather than 1/32-texel coordinates
changed 6 to 32 % of the pixels, up to 14 levels).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from stages.common.perspective_camera import PerspectiveCamera
from stages.extract import perspective

DATA = Path(__file__).parent / "data"
REFERENCE = DATA / "perspective_features_reference.npz"
FRAMES_DIR = DATA / "perspective_frames"  # <name>.png and frames.json
HULKS = (Path(__file__).resolve().parents[2] / "shared" / "realdata" / "hulks-goalbox-labels"
         / "measurements")
HULKS_EVERY = 11  # every 11th capture by name (10 frames, top and bottom camera)
RENDERS = (("perspective-default", "kidsize"), ("perspective-nao", "spl"))
FRAMES = 4

RENDER_GREY, RENDER_SHARE = 2, 0.001  # pixels differing by > 2 levels: at most 0.1 %
RENDER_ANY = 0.01  # pixels differing at all: at most 1 %
LINE_PX = 3.0  # a line matched: both ends within 3 px
LINE_CLOSE_PX = 0.05  # a line unchanged: both ends within 0.05 px
POINT_PX = 3.0  # crossings and posts matched within 3 px (and of the same kind)
COUNT_MARGIN = 1  # features of a kind per frame: at most one more or fewer
CHANGED_SHARE = 0.1  # at most 10 % of the features unmatched or moved beyond "unchanged"
BOUNDARY_PX = 1.0


def rendered_frames(preset: str, field_name: str):
    """(name, image, camera, pitch, roll) of FRAMES fixed frames in front of a goal, rendered
    now."""
    from stages import simulate
    from stages.common.field import load_field
    from stages.simulate import scene
    from stages.simulate.perspective_renderer import PerspectiveRenderer

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


def stored_frames(preset: str | None = None):
    """(name, image, camera, pitch, roll) of the stored rendered frames (of ``preset``, or
    all), in the order they were written."""
    meta = json.loads((FRAMES_DIR / "frames.json").read_text())
    out = []
    for name, m in meta.items():
        if preset is not None and m["preset"] != preset:
            continue
        img = cv2.imread(str(FRAMES_DIR / f"{name}.png"), cv2.IMREAD_COLOR)
        assert img is not None, name
        out.append((name, img, PerspectiveCamera.from_dict(m["camera"]), m["pitch"],
                    m["roll"]))
    return out


def write_frames(frames) -> None:
    """Store rendered frames losslessly, with their cameras and head angles."""
    FRAMES_DIR.mkdir(parents=True, exist_ok=True)
    meta = {}
    for name, img, cam, pitch, roll in frames:
        ok = cv2.imwrite(str(FRAMES_DIR / f"{name}.png"), img,
                         [cv2.IMWRITE_PNG_COMPRESSION, 9,
                          cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_FILTERED])
        assert ok, name
        meta[name] = {"preset": name.rsplit("-", 1)[0], "camera": cam.to_dict(),
                      "pitch": float(pitch), "roll": float(roll)}
    (FRAMES_DIR / "frames.json").write_text(json.dumps(meta, indent=1) + "\n")


def hulks_frames():
    from stages.calibrate import hulks

    out = []
    for js in sorted(HULKS.glob("*.json"))[::HULKS_EVERY]:
        stem = js.stem
        cam = hulks.read_frame(HULKS / f"{stem}.json").camera
        out.append((f"hulks-{stem}", cv2.imread(str(HULKS / f"{stem}.jpg")), cam, None, None))
    return out


def features(frames) -> dict[str, np.ndarray]:
    """The features of each frame."""
    conf = perspective.confs["default"]
    out = {}
    for name, img, cam, pitch, roll in frames:
        res = perspective.extract_frame(img, cam, conf, pitch=pitch, roll=roll)
        for key, value in res.items():
            out[f"{name}/{key}"] = value
    return out


def grey_difference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per pixel of two uint8 images, the largest difference of its channels."""
    return np.abs(a.astype(int) - b.astype(int)).max(axis=-1)


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


def _camera_values(cam) -> list[float]:
    return [cam.fx, cam.fy, cam.cx, cam.cy, cam.height, cam.pitch, cam.roll, cam.yaw,
            *cam.distortion, *cam.position]


@pytest.mark.parametrize("preset", [p for p, _ in RENDERS])
def test_stored_frames_give_the_reference_features(preset):
    frames = stored_frames(preset)
    assert len(frames) == FRAMES
    got = features(frames)
    assert _check(got, [f[0] for f in frames]) >= 10
    # the frames hold what is compared: lines and crossings
    assert sum(len(got[f"{f[0]}/lines"]) for f in frames) >= 8
    assert sum(len(got[f"{f[0]}/crossings"]) for f in frames) >= 2


@pytest.mark.parametrize("preset,field_name", RENDERS)
def test_renderer_reproduces_the_stored_frames(preset, field_name):
    stored = {f[0]: f for f in stored_frames(preset)}
    fresh = rendered_frames(preset, field_name)
    assert sorted(stored) == sorted(f[0] for f in fresh)
    for name, img, cam, pitch, roll in fresh:
        _, ref, ref_cam, ref_pitch, ref_roll = stored[name]
        # the same view: head angles and camera as stored (inputs written by repr)
        assert cam.image_size == ref_cam.image_size, name
        np.testing.assert_allclose(
            [pitch, roll, *_camera_values(cam)], [ref_pitch, ref_roll, *_camera_values(ref_cam)],
            rtol=1e-12, atol=1e-12, err_msg=name)
        assert img.shape == ref.shape and img.dtype == ref.dtype, name
        d = grey_difference(img, ref)
        assert np.mean(d > 0) <= RENDER_ANY, (name, float(np.mean(d > 0)), int(d.max()))
        assert np.mean(d > RENDER_GREY) <= RENDER_SHARE, \
            (name, float(np.mean(d > RENDER_GREY)), int(d.max()))


@pytest.mark.realdata
@pytest.mark.skipif(not HULKS.is_dir(), reason="needs ../shared/realdata")
def test_real_nao_frames_give_the_reference_features():
    frames = hulks_frames()
    got = features(frames)
    assert _check(got, [f[0] for f in frames]) >= 10


def write_reference():
    """Render the frames, store them, and write the features of the stored frames (and of
    the HULKs frames where present)."""
    write_frames([f for p, fn in RENDERS for f in rendered_frames(p, fn)])
    frames = stored_frames()
    if HULKS.is_dir():
        frames += hulks_frames()
    np.savez_compressed(REFERENCE, **features(frames))
    print(f"wrote {FRAMES_DIR} and {REFERENCE} ({len(frames)} frames)")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    write_reference()
