"""The real-data checks of lut's ranked hypotheses, run as a user runs them
(stages.pipelines.realdata: the stage mains with the CLI's defaults; calibrate --from-minho,
build-map, extract --preset real, localize --heading histogram --independent), judged by the
brute-force line share of stages.evaluate.line_share. Skipped when ../shared/realdata is absent.

Goals and what this commit reaches (the README's results table):
- a pose on >= 9 of 10 minho-lab images: met (10 of 10);
- >= 70 % of the points within 15 cm and >= the image's null baseline + 0.15 on >= 8 of 10:
  met (8 of 10 since a global frame's candidates are weighed by all the frame's line points,
  lut's ``global_evidence``; 4 before. Image 04 holds 12 points whose null baseline, 0.86,
  lies above the brute-force best share, 0.83: no pose can meet it);
- the pose, or its mirror, moving <= 30 cm / 5 deg between range limits 3.5, 4 and 5 m: not
  met on every image (6 of 10). The brute-force best pose of each range's points stays put
  on 1 of 10 (the points of one range limit decide another place), and the method's pose
  holds there;
- the top or second hypothesis at the brute-force best pose, or its mirror, for the images
  and for their points through --points: not met (3 and 2 of 10). On 7 of the 10 images the
  judge's best is one of a few: poses elsewhere explain within 0.03 of its share
  (LineRaster.rivals), so no method can be held to it there; on the 3 where it is unique (2
  under another CPU's rounding: one image sits at the 0.03 margin), the top or second
  hypothesis holds it on every one.
Where a goal is not met the test holds the level reached, so a regression fails it; every
image's probability is low (below the acceptance threshold) wherever the pose is unsure, and
the test checks that too: no image is accepted with a pose explaining less than its null."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import REALDATA

pytestmark = [pytest.mark.realdata,
              pytest.mark.skipif(not REALDATA.exists(), reason="../shared/realdata is absent")]


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    from stages.pipelines.realdata import minho_lab

    r = minho_lab(REALDATA, tmp_path_factory.mktemp("minho-lab"))
    print("\nminho-lab through the product path (share at the top hypothesis / null / brute-"
          "force best, confidence):")
    for n, v in r["rows"].items():
        print(f"  {n}: {v['points']:3d} points  {v['share']:.2f} / {v['null']:.2f} /"
              f" {v['best_share']:.2f}  confidence {v['confidence']:.2f}  moves"
              f" {v['range_move_m']:.2f} m {v['range_move_deg']:.1f} deg  beats elsewhere"
              f" by {v['margin_points']} points")
    return r


def test_every_minho_lab_image_gets_a_pose(lab):
    assert lab["images"] == 10 and lab["with_pose"] >= 9


def test_minho_lab_poses_explain_the_points_beyond_the_null(lab):
    assert lab["explained"] >= 8, lab["rows"]


def test_minho_lab_poses_are_stable_over_the_range_limit(lab):
    assert lab["stable"] >= 6  # goal: every image (module doc)
    # where the points of every range limit decide one pose, the method holds it
    assert lab["stable_where_best_stable"] == lab["best_stable"], lab["rows"]


def test_an_unsure_minho_lab_image_is_not_accepted(lab):
    """The confidence means what it says: an image is accepted only where its top pose
    explains clearly more than chance."""
    from stages.localize import lut

    thr = lut.confs["default"]["min_confidence"]
    for n, v in lab["rows"].items():
        if v["confidence"] >= thr:
            assert v["share"] >= v["null"] + 0.15, (n, v)


def test_a_minho_lab_image_accepted_up_to_the_mirror_explains_its_points(lab):
    """The same of the pose pair on the symmetric lab field (stages.localize.symmetry): an
    image is accepted up to the mirror only where the pair explains clearly more than chance;
    the pair's probability is at least the top's."""
    for n, v in lab["rows"].items():
        assert v["confidence_up_to_mirror"] >= v["confidence"] - 1e-6, (n, v)
        if v["accepted_up_to_mirror"]:
            assert v["share"] >= v["null"] + 0.15, (n, v)


def test_a_minho_lab_pose_pair_the_points_do_not_decide_is_not_accepted(lab):
    """Issue 25's real snapshots: accepted up to the mirror where the pose pair is right.
    Whether a minho-lab image's pair is right is not known (no truth), and the judge says the
    images do not decide it: on every image a place apart from the best pose and its mirror
    explains all but at most 2 of the points the best explains, on two of them one more
    (brute force over the field, the best from a narrower search than the places elsewhere;
    06 and 09, whose best has no rival within 0.03 of its share, beat the place elsewhere by
    2 of 49 and 2 of 17 points). Accepting such a pair would be a guess at high confidence,
    so none is accepted; real frames whose pair is known are (the NuBot centre frame,
    tests/test_nubot_calibration.py; the HULKs stills, tests/test_mcl_hulks.py)."""
    rows = lab["rows"].values()
    assert lab["largest_margin_points"] == max(r["margin_points"] for r in rows)
    for r in rows:
        if r["margin_points"] <= 2:
            assert not r["accepted_up_to_mirror"], r


def test_minho_lab_hypotheses_hold_the_brute_force_pose(lab):
    # where the judge's best pose is what the points decide (no pose elsewhere within 0.03 of
    # its share), the top or second hypothesis holds it on every one. Whether an image is
    # such is a decision at the judge's margin: one image sits at 0.03, and is counted unique
    # under one CPU's rounding (3 images) and not under another's (2)
    assert lab["unique_best"] >= 2
    assert lab["top_or_second_at_unique_best"] == lab["unique_best"], lab["rows"]
    assert lab["top_or_second_at_best"] >= lab["unique_best"]  # goal: every image (module doc)
    assert lab["points_top_or_second_at_best"] >= 2
    # the top pose explains within 0.03 of the best share (one of the poses the judge cannot
    # tell from its best) on 6 of 10 (7 where the margin image is not unique)
    assert lab["top_as_good_as_best"] >= 6


def test_a_minho_lab_pair_fit_accepts_covers_what_the_image_cannot_tell_apart(tmp_path):
    """fit on the same images (the stage main with the CLI's defaults, independent frames,
    histogram heading): where it accepts an image up to the mirror, the brute-force best pose
    and every pose elsewhere that explains all but at most 2 of the best's points lie within
    3 standard deviations (the frame's stated position covariance) of its pose or its mirror:
    what it accepts is the place with the spread it states, never a pick among places the
    image does not tell apart. (Image 03, 35 points: fit accepts its pair at 0.97; the best
    and the pose elsewhere lie 0.44 and 0.40 m along one line from fit's pose, 2.4 and 1.8
    standard deviations of its 0.22 m along that line: one place, slid along its line.)"""
    from stages.common.features_file import FeaturesFile
    from stages.common.field import load_field
    from stages.evaluate.line_share import LineRaster
    from stages.pipelines.realdata import NEAR, _localise, lab_dataset

    ds, field = lab_dataset(REALDATA, tmp_path)
    cols, feats = _localise(ds, field, tmp_path, method="fit")
    fm = load_field(field)
    raster = LineRaster(fm)
    with FeaturesFile(feats) as ff:
        pts = {n: np.asarray(ff.frame(n)["points"], float) for n in ff.names}
    for i, name in enumerate(cols["name"]):
        if not cols["accepted_up_to_mirror"][i]:
            continue
        p = pts[str(name)]
        share, best = raster.best_pose(p, NEAR)
        alike = [best] + [q for s, q in raster.rivals(p, (share, best), NEAR, within=1.0)
                          if (share - s) * len(p) <= 2.5]
        top = np.array([cols["x"][i], cols["y"][i]])
        info = np.linalg.inv(cols["covariance"][i][:2, :2])
        for q in alike:
            d = min(float(np.sqrt((m[:2] - top) @ info @ (m[:2] - top)))
                    for m in (q, fm.mirror_pose(q)))
            assert d <= 3.0, (str(name), q, d)
