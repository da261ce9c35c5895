"""mcl on real NAO frames standing still, through the product path: each HULKs capture
(../shared/realdata/hulks-goalbox-labels) becomes a dataset folder of a robot standing still
(the image 15 times, zero odometry, calib.yaml from the capture's own camera matrix, so the
observation model gets that frame's camera height), extracted and localised by the stage mains
with the CLI's defaults (stages.pipelines.bench.mcl_hulks; ``fieldloc bench --only mcl-hulks``
runs every capture). The labels' pose is the truth; the field is 180 deg symmetric, so the top
hypothesis or its mirror counts.

The goal: within 50 cm (here also 15 deg) on every frame that shows at least two
non-parallel lines or a crossing. Not met: on all 107 captures with labels (the four with
swapped labels corrected), 98 of the 105 informative ones (93 %; 94 of 104 before the crossings'
full-resolution checks found more crossings); on the third of them this test runs (every third
capture, to keep it near 25 s), 32 of 34 (94 %) before those checks. Since a uniform start
places its belief at the first frame's best places (mcl's ``START_PLACES``) the count is the
same, with other misses; every frame whose 15 still frames decide the labels' pose (by the
brute force over the field, bench.mcl_hulks.decided: 96 of the 105) is found, as before. Why
the seven informative misses miss (each capture's observations, the belief's end and the
observation model's log-likelihood at the labels' pose against the found pose's):
- five (1687084008, -029, 1687086314, -437, 1687089095; 0.55-1.01 m off) are frames that
  decide another place than the labels' pose, and mcl finds that place (the brute force's
  best, 0.3-6.9 nats a frame above the labels' pose). For the first four the labels' pose is
  the cause: the labelled points lie on extracted lines (within 5 cm), but no field pose fits
  the labels (at their own pose they lie up to 0.5 m off the field's lines: the robots'
  uncalibrated camera matrices put the labelled lines 0.57 m apart where the rules say 0.6 m).
  1687089095 was a hit before (the uniform belief settled near the labels' pose by chance);
- two (1687086320, 1687089006; 2.7 and 0.9 m off) are ambiguous frames (no place 20 : 1 above the
  others); the belief says so, its top pose and mirror hold 0.38 and 0.44 where a hit holds
  1.0 (median). (Before the places, three such frames, 1687089006, -024, -089, missed, holding
  0.49-0.80; -024 and -089 are hits now.)
No search failure among them. The confidence: a belief that cannot tell a pose from its mirror
gives each at most 0.5, so no frame of this path is accepted (min_confidence 0.8); what tells
hits from misses is the top pose and its mirror together (confidence_up_to_mirror, what
lut's TrackBank.confident counts): AUROC 0.69 for a hit and 0.97 for within 1 m on all 107
(0.84 and 0.98 before the places: the misses that decide another place now hold that place's
1.0, as the model says; one of them, 1687086314, is 1.01 m off at 0.95; 0.81 and 0.99 before
a uniform start's rivals became hypotheses of the estimate). Skipped when ../shared/realdata is
absent."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stages.pipelines.bench.mcl_hulks import HULKS, STILL_UPDATES, still_dataset, still_robot

pytestmark = [
    pytest.mark.realdata,
    pytest.mark.skipif(not HULKS.is_dir(), reason="needs ../shared/realdata"),
]

EVERY = 3  # every third capture: 36 of the 107


@pytest.fixture(scope="module")
def still(tmp_path_factory):
    captures = sorted(HULKS.glob("*.json"))[::EVERY]
    return still_robot(tmp_path_factory.mktemp("still"), captures)


def test_still_robot_from_a_uniform_start_on_the_hulks_frames(still):
    informative = [r for r in still if r.informative]
    assert len(still) == 36 and len(informative) >= 32
    hits = np.array([r.hit for r in informative])
    assert hits.mean() >= 32 / 34, [(r.name, round(r.error_m, 2)) for r in informative
                                   if not r.hit]
    # every frame whose still frames decide the labels' pose (the brute force) is found
    decided = [r for r in informative if r.decided and r.truth_best]
    assert len(decided) >= 30
    assert all(r.hit for r in decided), [(r.name, round(r.error_m, 2)) for r in decided
                                         if not r.hit]


def test_no_frame_of_a_uniform_start_is_accepted(still):
    """The cap of a symmetric belief: the top hypothesis at most 0.5 (below min_confidence),
    on informative and uninformative frames alike."""
    assert max(r.confidence for r in still) <= 0.5 + 1e-9
    assert any(not r.informative for r in still)


def test_the_pipeline_is_the_cli(tmp_path):
    """The still-robot chain gives what ``fieldloc calibrate perspective --from-hulks``,
    ``fieldloc extract`` and ``fieldloc localize --method mcl --init uniform`` give on the
    same folder."""
    from click.testing import CliRunner

    from fieldloc_cli.main import cli
    from stages.common.poses_file import read_poses

    capture = sorted(HULKS.glob("*.json"))[0]
    r = still_robot(tmp_path / "pipeline", [capture])[0]
    data = still_dataset(capture, tmp_path / "cli", STILL_UPDATES)
    runner = CliRunner()
    for args in (["calibrate", "perspective", "--from-hulks", str(capture), "-o",
                  str(data / "calib.yaml"), "--overwrite"],
                 ["build-map", "spl", "-o", str(tmp_path / "spl.map.h5")],
                 ["extract", str(data)],
                 ["localize", str(data), "--map", str(tmp_path / "spl.map.h5"), "--method",
                  "mcl", "--init", "uniform", "-o", str(tmp_path / "poses.h5")]):
        res = runner.invoke(cli, ["-q", *args])
        assert res.exit_code == 0, res.output
    cols, _ = read_poses(tmp_path / "poses.h5")
    top = cols["hypotheses"][-1, 0]
    assert math.isclose(top[3], r.confidence)
    pipeline, _ = read_poses(tmp_path / "pipeline" / capture.stem / "poses-mcl.h5")
    np.testing.assert_allclose(cols["hypotheses"][-1], pipeline["hypotheses"][-1])
