"""fieldloc evaluate: stamp matching, error statistics with failures, reports, plots, table, CLI."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages import evaluate as stage
from stages.common.artifacts import root_attrs
from stages.common.dataset import write_csv
from stages.common.errors import FieldlocError
from stages.common.field import load_field, preset_names
from stages.common.poses_file import PoseTrack, write_poses
from stages.common.report_file import load_report, read_errors_csv
from stages.evaluate.metrics import (
    error_stats,
    heading_error,
    match_by_stamp,
    percentile,
)
from stages.evaluate.report import tabulate
from stages.pipelines import evaluation
from stages.show.field import draw_field
from stages.show.figure import new_figure, save_figure


def write_track(path, frames, *, method="lut", field="msl-2015", dataset=""):
    """frames: (stamp, pose or None[, runtime s]) per frame."""
    track = PoseTrack()
    for i, fr in enumerate(frames):
        stamp, pose = fr[0], fr[1]
        runtime = fr[2] if len(fr) > 2 else 0.001
        track.add(f"f{i:03d}", stamp, pose, mode="global" if i == 0 else "local",
                  runtime=runtime, error=0.1, confidence=0.9)
    attrs = root_attrs("fieldloc.poses", 1, {"method": method, "c": 0.25}, {})
    attrs.update(method=method, field=field, dataset=str(dataset))
    return write_poses(path, track, attrs)


def write_truth(path, stamps, xs=None, ys=None, thetas=None):
    n = len(stamps)
    z = np.zeros(n)
    cols = {"stamp": np.asarray(stamps, float),
            "x": z if xs is None else np.asarray(xs, float),
            "y": z if ys is None else np.asarray(ys, float),
            "theta": z if thetas is None else np.asarray(thetas, float)}
    return write_csv(path, "truth", cols)


# Five frames at the truth stamps 0..4 (truth: the origin, heading 0). Position errors
# 0.05, 0.15, 0.30, 0.50 m and one failure; heading errors 1, 2, 3, 4 deg.
HAND = [
    (0.0, (0.05, 0.0, math.radians(1)), 0.001),
    (1.0, (0.0, -0.15, math.radians(-2)), 0.002),
    (2.0, (0.18, 0.24, math.radians(3)), 0.003),  # 3-4-5 triangle: 0.30 m
    (3.0, (-0.5, 0.0, math.radians(-4)), 0.004),
    (4.0, None, 0.010),
]


@pytest.fixture
def hand(tmp_path):
    poses = write_track(tmp_path / "poses.h5", HAND)
    truth = write_truth(tmp_path / "truth.csv", [0, 1, 2, 3, 4])
    return poses, truth


# ---------------------------------------------------------------------------- metrics


def test_match_by_stamp_nearest_within_tolerance():
    truth = np.array([3.0, 1.0, 2.0, 0.0])  # unsorted on purpose
    stamps = np.array([0.01, 1.49, 1.51, 2.03, 5.0, -0.02, 2.019])
    idx = match_by_stamp(stamps, truth, 0.02)
    # 0.01 -> 0.0 (index 3); 1.49/1.51 are 0.49 away from anything; 2.03 is 0.03 from 2.0;
    # 5.0 has no truth; -0.02 is exactly at the tolerance; 2.019 is within it
    assert idx.tolist() == [3, -1, -1, -1, -1, 3, 2]
    assert match_by_stamp(stamps, truth, 0.5)[1:3].tolist() == [1, 2]


def test_heading_error_wraps_at_pi():
    deg = np.radians
    e = np.degrees(heading_error(deg([179, 350, -170, 90, 180]), deg([-179, 10, 170, -90, -180])))
    np.testing.assert_allclose(e, [2, 20, 20, 180, 0], atol=1e-9)


def test_percentile_with_infinite_values():
    assert percentile([1, 2, 3, 4], 50) == pytest.approx(2.5)
    assert percentile([1, 2, 3, 4], 90) == pytest.approx(np.percentile([1, 2, 3, 4], 90))
    assert percentile([1, 2, np.inf], 50) == 2.0
    assert percentile([1, 2, np.inf, np.inf], 50) == math.inf
    assert math.isnan(percentile([], 50))
    s = error_stats([0.1, np.inf])
    assert s["max"] == math.inf and s["mean"] == math.inf and s["median"] == math.inf


def test_hand_computed_statistics(hand):
    poses, truth = hand
    fe, summary = stage.evaluate_poses(*_cols(poses, truth))
    np.testing.assert_allclose(fe.position_error, [0.05, 0.15, 0.30, 0.50, np.inf], atol=1e-9)
    np.testing.assert_allclose(np.degrees(fe.heading_error), [1, 2, 3, 4, np.inf], atol=1e-9)
    assert summary["frames"] == 5 and summary["matched"] == 5
    assert summary["failures"] == 1 and summary["matched_failures"] == 1
    pos = summary["position_error_m"]
    # sorted: .05 .15 .30 .50 inf -> median .30; p90 between .50 and inf -> inf
    assert pos["median"] == pytest.approx(0.30)
    assert pos["p90"] == math.inf and pos["max"] == math.inf and pos["mean"] == math.inf
    assert summary["heading_error_deg"]["median"] == pytest.approx(3.0)
    # a failure is never within: shares over all 5 matched frames
    assert summary["within"] == pytest.approx({"0.1": 0.2, "0.2": 0.4, "0.4": 0.6})
    loc = summary["localised"]
    assert loc["frames"] == 4
    assert loc["position_error_m"]["median"] == pytest.approx(0.225)
    assert loc["position_error_m"]["mean"] == pytest.approx(0.25)
    assert loc["position_error_m"]["max"] == pytest.approx(0.50)
    assert loc["position_error_m"]["p90"] == pytest.approx(0.30 + 0.7 * 0.20)
    assert loc["heading_error_deg"]["mean"] == pytest.approx(2.5)
    assert loc["within"] == pytest.approx({"0.1": 0.25, "0.2": 0.5, "0.4": 0.75})
    assert summary["runtime_ms"]["median"] == pytest.approx(3.0, rel=1e-5)
    assert summary["runtime_ms"]["mean"] == pytest.approx(4.0, rel=1e-5)
    assert summary["modes"] == {"global": 1, "local": 4}


def test_mostly_failed_run_has_infinite_median(tmp_path):
    poses = write_track(tmp_path / "p.h5", [(0, None), (1, None), (2, (0, 0, 0))])
    truth = write_truth(tmp_path / "t.csv", [0, 1, 2])
    _, s = stage.evaluate_poses(*_cols(poses, truth))
    assert s["position_error_m"]["median"] == math.inf
    assert s["within"]["0.4"] == pytest.approx(1 / 3)
    assert s["localised"]["position_error_m"]["median"] == 0.0


def test_all_failed_run_reports_null_for_localised(tmp_path):
    poses = write_track(tmp_path / "p.h5", [(0, None), (1, None)])
    truth = write_truth(tmp_path / "t.csv", [0, 1])
    out = stage.main(None, poses, truth, tmp_path / "r")
    raw = json.loads((out / "report.json").read_text())
    assert raw["localised"]["frames"] == 0
    assert raw["localised"]["position_error_m"]["median"] is None
    assert raw["position_error_m"]["median"] == "inf"
    assert raw["within"] == {"0.1": 0.0, "0.2": 0.0, "0.4": 0.0}


def test_stamp_tolerance_and_unmatched_frames(tmp_path):
    frames = [(0.015, (0, 0, 0)), (1.03, (0, 0, 0)), (2.0, (0.3, 0, 0)), (9.0, (5, 5, 0))]
    poses = write_track(tmp_path / "p.h5", frames)
    truth = write_truth(tmp_path / "t.csv", [0, 1, 2, 3])
    fe, s = stage.evaluate_poses(*_cols(poses, truth))
    assert fe.matched.tolist() == [True, False, True, False]  # 1.03 is 0.03 s off; 9.0 no truth
    assert s["matched"] == 2 and s["unmatched"] == 2 and s["frames"] == 4
    assert s["within"]["0.1"] == pytest.approx(0.5)  # unmatched frames are not scored
    assert math.isnan(fe.position_error[3])
    _, s2 = stage.evaluate_poses(*_cols(poses, truth), {"stamp_tolerance": 0.05})
    assert s2["matched"] == 3


def test_truth_rows_without_pose_are_dropped(tmp_path):
    """Motion capture losing the robot leaves NaN rows; a frame there is unmatched rather than
    matched to a neighbour further away."""
    poses = write_track(tmp_path / "p.h5", [(0.0, (0, 0, 0)), (1.0, (0, 0, 0))])
    truth = write_truth(tmp_path / "t.csv", [0.0, 1.0, 1.01], xs=[0.0, np.nan, 0.2])
    fe, s = stage.evaluate_poses(*_cols(poses, truth))
    assert s["matched"] == 2
    assert fe.position_error[1] == pytest.approx(0.2)  # matched to 1.01, not the NaN row


def test_mirrored_estimates_are_counted(tmp_path):
    poses = write_track(tmp_path / "p.h5", [(0, (-3.0, -1.0, math.pi)), (1, (3.05, 1.0, 0.0))])
    truth = write_truth(tmp_path / "t.csv", [0, 1], xs=[3.0, 3.0], ys=[1.0, 1.0])
    _, s = stage.evaluate_poses(*_cols(poses, truth))
    assert s["mirrored"] == 1


def _cols(poses, truth):
    from stages.common.dataset import read_csv
    from stages.common.poses_file import read_poses

    return read_poses(poses)[0], read_csv(truth, "truth")


# ---------------------------------------------------------------------------- report files


def test_report_files(hand, tmp_path):
    poses, truth = hand
    out = evaluation.main(None, poses, truth, tmp_path / "report")
    text = (out / "report.json").read_text()

    def no_constants(name):
        raise AssertionError(f"non-standard JSON constant {name}")

    raw = json.loads(text, parse_constant=no_constants)  # strict JSON: no Infinity/NaN
    for key in ("frames", "matched", "failures", "position_error_m", "heading_error_deg",
                "within", "runtime_ms", "method", "field", "conf", "conventions"):
        assert key in raw, key
    for key in ("median", "mean", "p90", "max"):
        assert key in raw["position_error_m"] and key in raw["heading_error_deg"]
    assert set(raw["within"]) == {"0.1", "0.2", "0.4"}
    assert set(raw["runtime_ms"]) >= {"median", "mean"}
    assert raw["method"] == "lut" and raw["field"] == "msl-2015"
    assert raw["conf"] == {"method": "lut", "c": 0.25}  # the localisation conf of the poses
    assert raw["evaluate_conf"] == stage.confs["default"]
    assert raw["position_error_m"]["max"] == "inf"
    rep = load_report(out)
    assert rep["position_error_m"]["max"] == math.inf
    assert rep["position_error_m"]["median"] == pytest.approx(0.30)

    err = read_errors_csv(out / "errors.csv")
    assert err["name"].tolist() == [f"f{i:03d}" for i in range(5)]
    np.testing.assert_allclose(err["position_error_m"], [0.05, 0.15, 0.3, 0.5, np.inf],
                               atol=1e-5)
    assert err["failed"].tolist() == [0, 0, 0, 0, 1]
    assert np.isnan(err["x"][4])

    for name in ("error_cdf.png", "trajectory.png", "error_over_time.png"):
        p = out / "plots" / name
        assert p.stat().st_size > 1000
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(out.glob(".*")) and not list((out / "plots").glob(".*"))  # no temp files


def test_existing_report_kept_or_refused(hand, tmp_path):
    poses, truth = hand
    out = evaluation.main(None, poses, truth, tmp_path / "r")
    mtimes = {p: p.stat().st_mtime_ns for p in [out / "report.json", *(out / "plots").iterdir()]}
    evaluation.main(None, poses, truth, out)  # same inputs and conf: kept as it is, plots too
    assert {p: p.stat().st_mtime_ns for p in mtimes} == mtimes
    (out / "plots" / "trajectory.png").unlink()  # a run stopped while drawing: drawn again
    evaluation.main(None, poses, truth, out)
    assert (out / "plots" / "trajectory.png").is_file()
    assert (out / "report.json").stat().st_mtime_ns == mtimes[out / "report.json"]
    with pytest.raises(FieldlocError, match="overwrite"):
        stage.main({"stamp_tolerance": 0.01}, poses, truth, out)
    stage.main({"stamp_tolerance": 0.01, "plots": False}, poses, truth, out, overwrite=True)
    assert load_report(out)["evaluate_conf"]["stamp_tolerance"] == 0.01
    assert not (out / "plots" / "trajectory.png").exists()  # no plots of the old report left


def test_report_plots_drawn_from_a_report_folder(hand, tmp_path):
    """evaluate writes the numbers and lists the plots; show.report_plots draws them from the
    report folder alone, and replaces existing ones only when asked."""
    from stages.show import report_plots

    poses, truth = hand
    out = stage.main(None, poses, truth, tmp_path / "r")
    listed = load_report(out)["files"]["plots"]
    assert listed == [f"plots/{n}" for n in ("error_cdf.png", "trajectory.png",
                                             "error_over_time.png", "reliability.png")]
    assert not any((out / p).exists() for p in listed)
    assert report_plots.main(None, out) == out / "plots"
    assert all((out / p).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in listed)
    with pytest.raises(FieldlocError, match="overwrite"):
        report_plots.main(None, out)
    report_plots.main({"dpi": 60}, out, overwrite=True)


def test_bad_inputs_raise_fieldloc_errors(hand, tmp_path):
    poses, truth = hand
    with pytest.raises(FieldlocError, match="not found"):
        stage.main(None, tmp_path / "missing.h5", truth, tmp_path / "r")
    with pytest.raises(FieldlocError, match="not found"):
        stage.main(None, poses, tmp_path / "missing.csv", tmp_path / "r")
    bad = tmp_path / "bad.csv"
    bad.write_text("t,x,y,yaw\n0,0,0,0\n")
    with pytest.raises(FieldlocError, match="stamp,x,y,theta"):
        stage.main(None, poses, bad, tmp_path / "r")
    late = write_truth(tmp_path / "late.csv", [100.0, 101.0])
    with pytest.raises(FieldlocError, match=r"within 0\.02 s"):
        stage.main(None, poses, late, tmp_path / "r")
    with pytest.raises(FieldlocError, match="not an HDF5 file"):
        stage.main(None, truth, truth, tmp_path / "r")  # a CSV is not a poses file
    with pytest.raises(FieldlocError, match="thresholds"):
        stage.main({"thresholds": [0.1, -1]}, poses, truth, tmp_path / "r")
    with pytest.raises(FieldlocError, match="unknown conf key"):
        stage.main({"tolerance": 0.1}, poses, truth, tmp_path / "r")
    assert not (tmp_path / "r" / "report.json").exists()


def test_truth_from_dataset_named_in_poses(tmp_path):
    ds = tmp_path / "dataset"
    ds.mkdir()
    write_truth(ds / "truth.csv", [0, 1])
    poses = write_track(tmp_path / "p.h5", [(0, (0.1, 0, 0)), (1, (0, 0, 0))], dataset=ds)
    out = stage.main({"plots": False}, poses, None, tmp_path / "r")
    assert load_report(out)["position_error_m"]["max"] == pytest.approx(0.1)
    noset = write_track(tmp_path / "q.h5", [(0, (0, 0, 0))])
    with pytest.raises(FieldlocError, match="--truth"):
        stage.main(None, noset, None, tmp_path / "r2")


def test_truth_of_another_recording_said_a_copy_not(tmp_path, caplog):
    """`fieldloc evaluate --truth` warns where the truth is not the poses' dataset's (another
    recording's, trial K229) and keeps quiet for that truth itself or a copy of it."""
    ds = tmp_path / "dataset"
    ds.mkdir()
    write_truth(ds / "truth.csv", [0, 1])
    poses = write_track(tmp_path / "p.h5", [(0, (0.1, 0, 0)), (1, (0, 0, 0))], dataset=ds)
    copy = write_truth(tmp_path / "copy.csv", [0, 1])
    other = write_truth(tmp_path / "other.csv", [0, 1], xs=[1.0, 1.0])
    said = "not the truth of the dataset the poses were made from"
    for k, (truth, warned) in enumerate([(ds, False), (copy, False), (other, True)]):
        caplog.clear()
        res = CliRunner().invoke(cli, ["evaluate", str(poses), "--truth", str(truth), "-o",
                                       str(tmp_path / f"r{k}")])
        assert res.exit_code == 0, res.output
        assert (said in caplog.text) == warned, (truth, caplog.text)


# ---------------------------------------------------------------------------- plots


@pytest.mark.parametrize("name", preset_names())
def test_draw_field_every_preset(tmp_path, name):
    fm = load_field(name)
    fig = new_figure(4, 3)
    ax = fig.add_subplot()
    draw_field(ax, fm)
    xmin, xmax, ymin, ymax = fm.world_bounds()
    assert ax.get_xlim() == pytest.approx((xmin, xmax))
    assert ax.get_ylim() == pytest.approx((ymin, ymax))
    # one patch per segment and arc, plus penalty marks (two bars each)
    n_lines = len(fm.segments) + len(fm.arcs) + 2 * len(fm.penalty_marks)
    assert len(ax.collections[0].get_paths()) == n_lines
    p = save_figure(fig, tmp_path / f"{name}.png")
    assert p.stat().st_size > 1000


def test_unknown_field_of_poses_still_plots(tmp_path, caplog):
    poses = write_track(tmp_path / "p.h5", HAND, field="no-such-field")
    truth = write_truth(tmp_path / "t.csv", [0, 1, 2, 3, 4])
    out = evaluation.main(None, poses, truth, tmp_path / "r")
    assert (out / "plots" / "trajectory.png").stat().st_size > 1000
    assert "without field lines" in caplog.text
    with pytest.raises(FieldlocError, match="no-such-field"):  # an explicit --field must load
        stage.main(None, poses, truth, tmp_path / "r2", field="no-such-field")
    assert not (tmp_path / "r2" / "errors.csv").exists()  # refused before anything is written
    out3 = evaluation.main(None, poses, truth, tmp_path / "r3", field="spl")
    assert load_report(out3)["field"] == "spl"


# ---------------------------------------------------------------------------- table


def test_tabulate_formats(hand, tmp_path):
    poses, truth = hand
    a = stage.main({"plots": False}, poses, truth, tmp_path / "a")
    good = write_track(tmp_path / "good.h5", [(0, (0.02, 0, 0), 0.0005), (1, (0, 0.04, 0))],
                       method="mcl")
    b = stage.main({"plots": False}, good, truth, tmp_path / "b")
    text = tabulate([a, b / "report.json"])
    lines = text.splitlines()
    assert len(lines) == 3
    assert lines[0].split()[:5] == ["run", "method", "frames", "matched", "failures"]
    assert "<=10cm" in lines[0] and "<=40cm" in lines[0] and "runtime" in lines[0]
    row_a, row_b = lines[1].split(), lines[2].split()
    # run, method, frames, matched, failures, accepted, median cm, p90 cm, heading deg,
    # within %, top and top-K within 40 cm %, mirror %, AUROC, ms (v1-style tracks: every frame
    # that did not fail is accepted, with one hypothesis)
    assert row_a[1:] == ["lut", "5", "5", "1", "4", "30.0", "inf", "3.00", "20.0", "40.0",
                         "60.0", "60.0", "60.0", "0.0", "0.500", "3.000"]
    assert row_b[0].endswith("b") and row_b[1:7] == ["mcl", "2", "2", "0", "2", "3.0"]
    # numeric columns are right-aligned: every row ends at the same column as the header
    widths = {len(line) for line in lines}
    assert len(widths) == 1

    md = tabulate([a, b], fmt="markdown").splitlines()
    assert md[0].startswith("| run") and set(md[1]) <= {"|", "-", ":"}
    rows = list(csv.reader(tabulate([a, b], fmt="csv").splitlines()))
    assert rows[0][0] == "run" and rows[1][6] == "30.0" and len(rows) == 3
    with pytest.raises(FieldlocError, match="format"):
        tabulate([a], fmt="html")


# ---------------------------------------------------------------------------- CLI


def test_cli_round_trip(hand, tmp_path):
    poses, truth = hand
    other = tmp_path / "runs" / "mcl"
    other.mkdir(parents=True)
    p2 = write_track(other / "poses.h5", [(t, (0.0, 0.0, 0.0)) for t in range(5)], method="mcl")
    runner = CliRunner()
    res = runner.invoke(cli, ["evaluate", str(poses), str(p2), "--truth", str(truth),
                              "-o", str(tmp_path / "reports")])
    assert res.exit_code == 0, res.output
    out = res.stdout.split("\n\n")  # the table, then each run's reliability table
    table = out[0].splitlines()
    assert len(table) == 3 and table[0].startswith("run")
    assert len(out) == 3 and all("reliability of the confidence" in o and "AUROC" in o
                                 for o in out[1:])
    # two files named poses.h5: report folders disambiguated by their parent folders
    dirs = [f"{tmp_path.name}-poses", "mcl-poses"]  # in the order of the poses files
    assert sorted(p.name for p in (tmp_path / "reports").iterdir()) == sorted(dirs)
    assert all((tmp_path / "reports" / d / "report.json").is_file() for d in dirs)
    assert "mcl" in table[2] and "100.0" in table[2]  # all within 10 cm

    res2 = runner.invoke(cli, ["evaluate", "--table"]
                         + [str(tmp_path / "reports" / d) for d in dirs])
    assert res2.exit_code == 0, res2.output
    assert res2.stdout.splitlines()[1:] and res2.stdout.splitlines()[1].split()[1:] == \
        table[1].split()[1:]

    # the CLI's defaults are the stage's defaults
    res3 = runner.invoke(cli, ["evaluate", str(poses), "--truth", str(truth)])
    assert res3.exit_code == 0, res3.output
    rep = load_report(poses.parent / "poses-eval")
    assert rep["evaluate_conf"] == stage.confs["default"]
    res4 = runner.invoke(cli, ["evaluate", str(poses), "--truth", str(truth), "-o",
                               str(tmp_path / "tol"), "--stamp-tolerance", "0.5",
                               "-c", "plots=false", "--format", "csv"])
    assert res4.exit_code == 0, res4.output
    assert load_report(tmp_path / "tol")["evaluate_conf"]["stamp_tolerance"] == 0.5
    assert res4.stdout.startswith("run,method,")


@pytest.mark.parametrize("case", ["missing-poses", "bad-truth", "no-match", "no-report",
                                  "table-with-truth"])
def test_cli_errors_are_one_line(hand, tmp_path, case):
    poses, truth = hand
    bad = tmp_path / "bad.csv"
    bad.write_text("stamp,x,y\n0,0,0\n")
    late = write_truth(tmp_path / "late.csv", [50.0])
    args = {
        "missing-poses": [str(tmp_path / "nope.h5"), "--truth", str(truth)],
        "bad-truth": [str(poses), "--truth", str(bad)],
        "no-match": [str(poses), "--truth", str(late)],
        "no-report": ["--table", str(tmp_path)],
        "table-with-truth": ["--table", str(tmp_path), "--truth", str(truth)],
    }[case]
    res = CliRunner().invoke(cli, ["evaluate", *args])
    assert res.exit_code == 1, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fieldloc: error: "), res.stderr
    assert "Traceback" not in res.output
    assert res.stdout == ""


def test_the_line_share_judge_tells_a_unique_best_pose_from_one_of_a_few():
    """LineRaster.rivals: the centre circle and the halfway line seen from a pose are what
    only that pose (and its mirror) explain; a stretch of the touch line is explained as well
    by poses all along the field's lines."""
    from stages.common.field import field_from_spec
    from stages.common.geometry import field_to_robot
    from stages.evaluate.line_share import LineRaster
    from stages.pipelines.realdata import REALDATA, lab_field

    if not (REALDATA / "minho-lab" / "Lar.view").is_file():
        pytest.skip("minho-lab/Lar.view not present (../shared/realdata)")
    fm = field_from_spec(lab_field())
    raster = LineRaster(fm)
    a = np.radians(np.arange(0, 360, 10))
    circle = 1.37 * np.stack([np.cos(a), np.sin(a)], axis=1)
    halfway = np.stack([np.zeros(31), np.linspace(-3, 3, 31)], axis=1)
    pose = np.array([1.0, 0.5, 0.3])
    seen = field_to_robot(pose, np.concatenate([circle, halfway]))
    best = raster.best_pose(seen)
    assert best[0] >= 0.95
    assert min(np.hypot(*(best[1][:2] - q[:2])) for q in (pose, fm.mirror_pose(pose))) < 0.15
    assert raster.rivals(seen, best) == []
    touch = np.stack([np.linspace(-1, 1, 21), np.full(21, 7.54 / 2)], axis=1)
    seen = field_to_robot(np.array([0.0, 2.5, 0.0]), touch)
    best = raster.best_pose(seen)
    assert best[0] == 1.0 and len(raster.rivals(seen, best)) >= 2


def test_poses_of_frames_ordered_by_name_not_stamp_are_read(tmp_path):
    """A dataset stamped from its file names orders its frames by name (9.5.png after
    10.5.png), so localize writes stamps that go back; the poses reader takes them, and
    `fieldloc evaluate` scores them by stamp."""
    poses = write_track(tmp_path / "p.h5", [(10.5, (0.1, 0, 0)), (9.5, (0.2, 0, 0))])
    truth = write_truth(tmp_path / "truth.csv", [9.5, 10.5])
    res = CliRunner().invoke(cli, ["evaluate", str(poses), "--truth", str(truth), "-o",
                                   str(tmp_path / "r")])
    assert res.exit_code == 0, res.output
    assert load_report(tmp_path / "r")["position_error_m"]["max"] == pytest.approx(0.2)
