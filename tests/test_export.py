"""`fieldloc export` (csv, tum, json), truth.tum beside a report, and evo reading both."""

import csv
import json
import math
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages import evaluate
from stages.common.artifacts import root_attrs
from stages.common.dataset import write_csv
from stages.common.poses_file import PoseTrack, write_poses
from stages.evaluate import export


def _poses(path):
    """Four frames: two accepted with two hypotheses each, one not accepted, one failed."""
    track = PoseTrack()
    cov = np.diag([0.01, 0.02, 0.003])
    track.add("a", 1.0, (1.0, 2.0, 0.5), confidence=0.8, mode="global", covariance=cov,
              hypotheses=[[1.0, 2.0, 0.5, 0.8], [-1.0, -2.0, 0.5 - math.pi, 0.15]])
    track.add("b", 1.1, (1.1, 2.0, 0.6), confidence=0.9, mode="local",
              hypotheses=[[1.1, 2.0, 0.6, 0.9], [0.0, 0.0, 0.0, 0.05]])
    track.add("c", 1.2, (5.0, 0.0, 0.0), confidence=0.2, mode="local", accepted=False)
    track.add("d", 1.3, None, mode="failed", flags="too-few-points")
    attrs = root_attrs("fieldloc.poses", 2, {"method": "lut"}, {})
    attrs.update(method="lut", field="msl-2015", dataset="", min_confidence=0.5)
    return write_poses(path, track, attrs)


def test_csv_tum_json(tmp_path):
    poses = _poses(tmp_path / "poses.h5")
    runner = CliRunner()
    for fmt in ("csv", "json"):
        res = runner.invoke(cli, ["export", str(poses), "--format", fmt])
        assert res.exit_code == 0, res.output
    res = runner.invoke(cli, ["export", str(poses), "--format", "tum", "-o",
                              str(tmp_path / "out.tum")])
    assert res.exit_code == 0, res.output

    with open(tmp_path / "poses.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == list(export.CSV_COLUMNS)
    assert [r["name"] for r in rows] == ["a", "b", "c", "d"]
    assert [r["accepted"] for r in rows] == ["1", "1", "0", "0"]
    assert [r["failed"] for r in rows] == ["0", "0", "0", "1"]
    assert float(rows[0]["x"]) == 1.0 and float(rows[0]["cov_yy"]) == pytest.approx(0.02)
    assert rows[3]["x"] == "nan" and rows[3]["flags"] == "too-few-points"
    assert [int(r["hypotheses"]) for r in rows] == [2, 2, 1, 0]

    doc = json.loads((tmp_path / "poses.json").read_text())
    assert doc["schema"] == "fieldloc.poses-export" and doc["min_confidence"] == 0.5
    fr = doc["frames"]
    assert fr[0]["hypotheses"][1] == pytest.approx([-1.0, -2.0, 0.5 - math.pi, 0.15])
    assert fr[0]["covariance"][2][2] == pytest.approx(0.003)
    assert fr[3]["x"] is None and fr[3]["hypotheses"] == [] and fr[1]["covariance"] is None

    tum = np.loadtxt(tmp_path / "out.tum")
    # accepted frames only, as poses.tum: a and b
    np.testing.assert_allclose(tum[:, 0], [1.0, 1.1])
    np.testing.assert_allclose(tum[:, 1:3], [[1.0, 2.0], [1.1, 2.0]])
    np.testing.assert_allclose(2 * np.arctan2(tum[:, 6], tum[:, 7]), [0.5, 0.6], atol=1e-5)
    assert (tmp_path / "out.tum").read_text() == (tmp_path / "poses.tum").read_text()

    res = runner.invoke(cli, ["export", str(poses), "--format", "csv"])
    assert res.exit_code == 1 and "exists" in res.output
    res = runner.invoke(cli, ["export", str(tmp_path / "poses.csv"), "--format", "json",
                              "-o", str(tmp_path / "x.json")])
    assert res.exit_code == 1 and "not an HDF5 file" in res.output


def _evo_ape() -> str | None:
    pytest.importorskip("evo")
    return shutil.which("evo_ape") or shutil.which("evo_ape", path=str(Path(sys.executable).parent))


def test_evo_ape_agrees_with_fieldloc(tmp_path):
    """evo_ape on truth.tum (beside the report) and poses.tum gives fieldloc's RMSE and median
    (over the localised frames) within 1 mm."""
    evo_ape = _evo_ape()
    if evo_ape is None:
        pytest.skip("evo_ape not on PATH")
    rng = np.random.default_rng(4)
    t_truth = np.arange(0, 6.0, 0.05)  # truth at 20 Hz
    truth = {"stamp": t_truth, "x": np.cos(t_truth), "y": np.sin(0.5 * t_truth),
             "theta": 0.3 * t_truth}
    write_csv(tmp_path / "truth.csv", "truth", truth)
    track = PoseTrack()
    for k, t0 in enumerate(t_truth[::2]):  # poses at 10 Hz, 3 ms off the truth stamps
        t = t0 + 0.003
        if k % 7 == 3:
            track.add(f"f{k}", t, None, mode="failed")
            continue
        i = int(round(t0 / 0.05))
        err = rng.normal(0, 0.05, 2)
        track.add(f"f{k}", t, (truth["x"][i] + err[0], truth["y"][i] + err[1],
                               truth["theta"][i] + rng.normal(0, 0.02)), confidence=0.9)
    attrs = root_attrs("fieldloc.poses", 2, {}, {})
    attrs.update(method="lut", field="msl-2015", dataset="")
    poses = write_poses(tmp_path / "poses.h5", track, attrs)
    report_dir = evaluate.main({"plots": False}, poses, tmp_path / "truth.csv",
                               tmp_path / "report")
    rep = json.loads((report_dir / "report.json").read_text())
    assert (report_dir / "truth.tum").is_file()
    env = dict(os.environ, HOME=str(tmp_path), MPLBACKEND="Agg")  # evo keeps settings in ~
    tol = evaluate.confs["default"]["stamp_tolerance"]
    res = subprocess.run([evo_ape, "tum", str(report_dir / "truth.tum"), str(poses.with_suffix(
        ".tum")), "--t_max_diff", str(tol), "--save_results", str(tmp_path / "ape.zip"),
        "--no_warnings"], capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    with zipfile.ZipFile(tmp_path / "ape.zip") as z:
        stats = json.loads(z.read("stats.json"))
    loc = rep["localised"]["position_error_m"]
    assert 0.02 < loc["rmse"] < 0.2  # errors of a few cm: a real comparison
    assert rep["localised"]["frames"] == len(np.loadtxt(poses.with_suffix(".tum")))
    assert abs(stats["rmse"] - loc["rmse"]) < 1e-3
    assert abs(stats["median"] - loc["median"]) < 1e-3
