"""Issue 9's speed-up of the perspective chain must keep its features: fixed frames of the
KidSize and NAO renderers (and, where ../shared/realdata is present, real HULKs NAO frames)
extracted with the default conf give the rows stored in
tests/data/perspective_features_reference.npz, to 1e-6.

The reference was written by this module's ``write_reference`` with the code before the
speed-up. A deliberate change of the features (a new threshold, a new check) rewrites it
(``python tests/test_extract_perspective_unchanged.py``) in the same commit, which says why.
The renders are hashed too, so that a changed renderer is told apart from a changed extractor.
"""

from __future__ import annotations

import hashlib
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


def _hash(a) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


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
    conf = perspective.confs["default"]
    out = {}
    for name, img, cam, pitch, roll in frames:
        res = perspective.extract_frame(img, cam, conf, pitch=pitch, roll=roll)
        out[f"{name}/image"] = np.array(_hash(img))
        for key, value in res.items():
            out[f"{name}/{key}"] = value
    return out


def _compare(got: dict, names: list[str]):
    ref = np.load(REFERENCE)
    compared = 0
    for name in names:
        image = f"{name}/image"
        assert str(got[image]) == str(ref[image]), f"{name}: the frame itself changed"
        for key in [k for k in ref.files if k.startswith(f"{name}/") and k != image]:
            a, b = got[key], ref[key]
            assert a.shape == b.shape, (key, a.shape, b.shape)
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-6, err_msg=key)
            compared += a.size
    return compared


@pytest.mark.parametrize("preset,field_name", RENDERS)
def test_rendered_frames_give_the_reference_features(preset, field_name):
    frames = rendered_frames(preset, field_name)
    got = features(frames)
    assert _compare(got, [f[0] for f in frames]) > 100
    # the frames hold what is compared: lines and crossings
    assert sum(len(got[f"{f[0]}/lines"]) for f in frames) >= 8
    assert sum(len(got[f"{f[0]}/crossings"]) for f in frames) >= 2


@pytest.mark.realdata
@pytest.mark.skipif(not HULKS.is_dir(), reason="needs ../shared/realdata")
def test_real_nao_frames_give_the_reference_features():
    frames = hulks_frames()
    got = features(frames)
    assert _compare(got, [f[0] for f in frames]) > 100


def write_reference():
    frames = [f for p, fn in RENDERS for f in rendered_frames(p, fn)]
    if HULKS.is_dir():
        frames += hulks_frames()
    REFERENCE.parent.mkdir(exist_ok=True)
    np.savez_compressed(REFERENCE, **features(frames))
    print(f"wrote {REFERENCE} ({len(frames)} frames)")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    write_reference()
