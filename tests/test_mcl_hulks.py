"""mcl on real NAO frames standing still (issue 9): each of the HULKs frames
(../shared/realdata/hulks-goalbox-labels, imported and extracted by the CLI with its defaults)
is given to the particle filter of ``localize --method mcl --init uniform`` 15 times with no
motion, the frame's own camera height in the observation model. The pose the labels give
(test_extract_hulks.field_pose_from_labels: the goal area's lines placed on the SPL field) is
the truth; the field is 180 deg symmetric, so the top hypothesis or its mirror counts.

Issue 9's goal: within 50 cm (and here 15 deg) on every frame that shows at least two
non-parallel lines or a crossing. Not met: 88 % of 100 frames today (84 % before the kidnap
share, the line-placed poses and the range sigma from the camera height). The labels' own pose
is rough (the robots' uncalibrated camera matrices put the labelled lines 0.57 m apart where
the rules say 0.6 m), and on most misses the extracted lines fit the found pose better than
the labels' pose. Skipped when ../shared/realdata is absent."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from test_extract_hulks import HULKS, SWAPPED, field_pose_from_labels, read_labels

pytestmark = [
    pytest.mark.realdata,
    pytest.mark.skipif(not HULKS.is_dir(), reason="needs ../shared/realdata"),
]

STILL_FRAMES = 15
NON_PARALLEL = math.radians(20)


def _informative(obs) -> bool:
    """At least two lines more than 20 deg from parallel, or a crossing."""
    if len(obs.crossings):
        return True
    d = obs.lines[:, 1] if len(obs.lines) else np.zeros(0)
    return bool(np.any(np.abs(np.sin(d[:, None] - d[None, :])) > math.sin(NON_PARALLEL)))


def test_still_robot_from_a_uniform_start_on_the_hulks_frames(hulks_extracted, tmp_path):

    from stages import build_map
    from stages.calibrate import hulks
    from stages.common.features_file import FeaturesFile
    from stages.common.field import load_field
    from stages.common.map_file import MapFile
    from stages.common.observations import Observations
    from stages.localize import confs
    from stages.localize.mcl import ParticleFilter
    from stages.localize.observation_model import ObservationModel

    features = hulks_extracted[1]
    spl = load_field("spl")
    map_file = MapFile(build_map.main(None, "spl", tmp_path / "spl.map.h5"))
    with FeaturesFile(features) as ff:
        frames = {n: ff.frame(n) for n in ff.names}
    hits = []
    for k, (name, frame) in enumerate(sorted(frames.items())):
        js = HULKS / f"{name}.json"
        if name in SWAPPED:
            continue
        camera = hulks.read_frame(js).camera
        floor = {key: camera.pixel_to_floor(px) for key, px in read_labels(js).items()}
        if not all(np.all(np.isfinite(v)) for v in floor.values()):
            continue
        truth = field_pose_from_labels(floor, spl)
        if truth is None:
            continue
        conf = copy.deepcopy(confs["mcl-uniform"])
        conf["seed"] = k
        obs_conf = dict(conf["observation"], camera_height=float(camera.height))
        model = ObservationModel.from_map(map_file, obs_conf)
        obs = Observations.from_features(frame)
        if not _informative(model.usable(obs)):
            continue
        pf = ParticleFilter(model, conf)
        pf.initialise()
        for i in range(STILL_FRAMES):
            est = pf.step((0.0, 0.0, 0.0), 0.1, obs, first=i == 0)
        top = np.asarray(est.hypotheses[0][:3] if len(est.hypotheses) else est.pose, float)
        ok = False
        for p in (top, spl.mirror_pose(top)):
            turn = abs((p[2] - truth[2] + math.pi) % (2 * math.pi) - math.pi)
            ok |= math.hypot(p[0] - truth[0], p[1] - truth[1]) <= 0.5 and turn <= math.radians(15)
        hits.append(ok)
    assert len(hits) >= 90
    assert np.mean(hits) >= 0.85, (np.mean(hits), len(hits))
