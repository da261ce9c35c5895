"""What a frame decides on a point-symmetric field: the pose up to the field's 180 deg turn
(stages.localize.symmetry), through the commands a user runs: ``localize`` writes the
confidence and acceptance up to the mirror, ``evaluate --up-to-mirror`` scores against the
truth or its mirror, ``export`` writes the pair."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
from click.testing import CliRunner
from hypothesis import given
from hypothesis import strategies as st

from fieldloc_cli.main import cli
from stages.common.poses_file import read_poses
from stages.localize.symmetry import MIRROR_MATCH_M, confidence_up_to_mirror


def _run(args):
    res = CliRunner().invoke(cli, [str(a) for a in args])
    assert res.exit_code == 0, res.output
    return res


def _snapshots(omni_default_rendered, msl2015_map, out):
    """Every rendered frame localised on its own with the line-histogram heading: no track,
    no start half, nothing that can tell a pose from its mirror."""
    ds, feats = omni_default_rendered
    _run(["localize", ds, "--map", msl2015_map, "--features", feats, "--independent",
          "--heading", "histogram", "-o", out])
    return read_poses(out)[0]


def test_snapshots_decide_the_pose_pair(omni_default_rendered, msl2015_map, tmp_path):
    from stages.localize import lut

    c = _snapshots(omni_default_rendered, msl2015_map, tmp_path / "p.h5")
    ok = ~c["failed"]
    conf, conf_m = c["confidence"], c["confidence_up_to_mirror"]
    h = c["hypotheses"]
    # a snapshot never tells the pose from its mirror: the top alone is never accepted
    assert not c["accepted"].any() and (conf[ok] <= 0.5 + 1e-6).all()
    # the pair's probability: the top's plus that of the hypotheses at its mirror image
    mx, my = -h[:, :1, 0], -h[:, :1, 1]
    at = np.hypot(h[:, 1:, 0] - mx, h[:, 1:, 1] - my) < MIRROR_MATCH_M
    expect = np.minimum(h[:, 0, 3] + np.nansum(np.where(at, h[:, 1:, 3], 0.0), axis=1), 1.0)
    np.testing.assert_allclose(conf_m[ok], expect[ok], atol=1e-6)
    assert (conf_m >= conf - 1e-7).all() and (conf_m <= 1 + 1e-6).all()
    thr = lut.confs["independent"]["min_confidence"]
    assert (c["accepted_up_to_mirror"] == (ok & (conf_m >= thr))).all()
    # the pair is what most frames decide: the mirror is listed at about the top's probability
    assert at[ok, 0].mean() >= 0.9
    assert c["accepted_up_to_mirror"].sum() >= 5


def test_evaluate_and_export_up_to_mirror(omni_default_rendered, msl2015_map, tmp_path):
    ds, _ = omni_default_rendered
    poses = tmp_path / "p.h5"
    c = _snapshots(omni_default_rendered, msl2015_map, poses)
    _run(["evaluate", poses, "-o", tmp_path / "plain", "-c", "plots=false"])
    _run(["evaluate", poses, "-o", tmp_path / "pair", "-c", "plots=false", "--up-to-mirror"])
    plain = json.loads((tmp_path / "plain" / "report.json").read_text())
    pair = json.loads((tmp_path / "pair" / "report.json").read_text())
    assert plain["accepted"] == 0 and pair["accepted"] == int(c["accepted_up_to_mirror"].sum())
    assert pair["evaluate_conf"]["up_to_mirror"] is True

    def top_errors(folder):
        with open(folder / "errors.csv") as f:
            rows = list(csv.DictReader(f))
        return rows

    # scored against the truth or its mirror, whichever is nearer: never worse per frame
    truth = np.loadtxt(ds / "truth.csv", delimiter=",", skiprows=1)
    ok = ~c["failed"]
    d_truth = np.hypot(c["x"] - truth[:, 1], c["y"] - truth[:, 2])
    d_mirror = np.hypot(c["x"] + truth[:, 1], c["y"] + truth[:, 2])
    assert pair["hypotheses"]["top_within"]["0.4"] == np.mean(
        np.where(ok, np.minimum(d_truth, d_mirror), np.inf) <= 0.4)
    assert pair["hypotheses"]["top_within"]["0.4"] >= plain["hypotheses"]["top_within"]["0.4"]
    assert pair["hypotheses"]["top_mirrored"] == 0
    assert len(top_errors(tmp_path / "pair")) == len(c["x"])

    # export: both poses of a frame decided only up to the mirror
    out = tmp_path / "p.csv"
    _run(["export", poses, "--format", "csv", "-o", out])
    with open(out) as f:
        rows = list(csv.DictReader(f))
    pairs = [r for r in rows if r["accepted_up_to_mirror"] == "1" and r["accepted"] == "0"]
    assert len(pairs) == int(c["accepted_up_to_mirror"].sum())
    for r in pairs:
        assert math.isclose(float(r["mirror_x"]), -float(r["x"]), abs_tol=1e-6)
        assert math.isclose(float(r["mirror_y"]), -float(r["y"]), abs_tol=1e-6)
        turn = (float(r["mirror_theta"]) - float(r["theta"])) % (2 * math.pi)
        assert math.isclose(turn, math.pi, abs_tol=1e-5)
    assert all(r["mirror_x"] == "nan" for r in rows if r not in pairs)
    js = tmp_path / "p.json"
    _run(["export", poses, "--format", "json", "-o", js])
    frames = json.loads(js.read_text())["frames"]
    assert [f["confidence_up_to_mirror"] for f in frames] == [
        round(float(v), 6) for v in c["confidence_up_to_mirror"]]


hyp = st.tuples(st.floats(-9, 9), st.floats(-6, 6), st.floats(-3.1, 3.1), st.floats(0, 1))


@given(st.lists(hyp, min_size=1, max_size=6), st.data())
def test_the_pair_holds_the_top_and_its_mirror_whatever_the_order(rows, data):
    """Properties: without the symmetry the top's own probability; with it at least that,
    more by exactly the probability of a hypothesis put at the top's mirror image, and the
    same whatever the order of the hypotheses after the top."""
    h = np.array(rows, float)[None]
    top = h[0, 0]
    assert confidence_up_to_mirror(h, False)[0] == top[3]
    base = confidence_up_to_mirror(h, True)[0]
    assert base >= top[3]
    rest = h[0, 1:]
    perm = data.draw(st.permutations(list(range(len(rest)))))
    shuffled = np.concatenate([h[:, :1], rest[perm][None]], axis=1)
    np.testing.assert_allclose(confidence_up_to_mirror(shuffled, True)[0], base, atol=1e-12)
    p = data.draw(st.floats(0, 1))
    mirror = np.array([[[-top[0], -top[1], top[2] + math.pi, p]]])
    more = confidence_up_to_mirror(np.concatenate([h, mirror], axis=1), True)[0]
    np.testing.assert_allclose(more, base + p, atol=1e-12)
