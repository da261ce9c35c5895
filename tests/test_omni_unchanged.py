"""Issue 9 changed shared code (stages/common/colour.py, stages/simulate/scene.py) for the
perspective camera only: the omni renderer's frames, the omni extractor's features and the
colour classes of the omni conf must stay bit-identical. The hashes were computed with the code
before those changes in this project's environment (first at commit 3c9b69e; then after issue
7's realistic omni-default renderer, from its branch before the perspective changes merged, and
the merged code reproduced them; last after msl-2015's letters were read from the lines' outer
side, which moved every line by half a line width); a deliberate change of the omni renderer
or extractor updates them."""

from __future__ import annotations

import copy
import hashlib

import numpy as np

from stages import simulate
from stages.common import colour
from stages.common.field import load_field
from stages.extract import omni
from stages.simulate import scene, trajectory
from stages.simulate.omni_renderer import OmniRenderer

RENDER = ["f525d171db8c2e43", "13aae7385d822a3a"]
EXTRACT = ["ac83f81994eb2d87", "934063be16964358"]
GRID = ["ce09cce4ce40d46f", "7dc60a4efa83d61b"]


def _hash(a) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


def test_omni_frames_features_and_colour_classes_are_unchanged():
    field = load_field("msl-2015")
    conf = copy.deepcopy(simulate.confs["omni-default"])
    conf["scene"]["texture_resolution"] = 0.02
    path = trajectory.generate(field, 6, conf["rate_hz"], conf["trajectory"],
                               np.random.default_rng(1))
    world = scene.build(field, conf["scene"], path.stamps, 1, robot_poses=path.poses)
    renderer = OmniRenderer(conf["omni"], world, 1)
    renderer.prepare(path)
    images = [renderer.render(path.poses[i], i) for i in (0, 5)]
    assert [_hash(i) for i in images] == RENDER
    feats = [omni.extract_frame(i, renderer.camera, omni.confs["default"]) for i in images]
    assert [_hash(np.concatenate([np.nan_to_num(f[k]).ravel() for k in sorted(f)]))
            for f in feats] == EXTRACT
    assert [_hash(colour.classify_grid(i, colour.confs["default"])[0]) for i in images] == GRID
