"""`fieldloc batch` (stages.pipelines.batch) on a small grid: rendered omni and perspective
datasets of a few frames on a coarse KidSize map, lut (two presets) and mcl. Finished runs are
not run again, an interrupted batch keeps them, a failed run is reported while the others go
on, a wrong SPEC key is one line, and a 2-worker LocalCluster gives the serial results value
for value."""

from __future__ import annotations

import csv
import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages.common.batch_file import RUN_NAME, load_batch
from stages.common.errors import FieldlocError
from stages.common.poses_file import read_poses
from stages.pipelines import batch
from stages.pipelines.batch_spec import read_spec

SPEC = {
    "field": "kidsize",
    "build_map": {"resolution": 0.2},
    "datasets": [
        {"name": "omni-a", "simulate": {"preset": "omni-clean", "field": "kidsize",
                                        "frames": 3, "seed": 1}},
        {"name": "persp-a", "simulate": {"preset": "perspective-clean", "field": "kidsize",
                                         "frames": 3, "seed": 2}},
    ],
    "methods": ["lut", "lut-no-fusion", {"method": "mcl", "conf": ["particles_max=500"]},
                "no-such-method"],
    "runs": "all",
}


def _write_spec(folder: Path, spec: dict) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "spec.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    """The SPEC run serially: (spec file, results folder, the lines it reported)."""
    root = tmp_path_factory.mktemp("batch")
    spec = _write_spec(root, SPEC)
    lines: list[str] = []
    out = batch.main("serial", spec, root / "serial", report=lines.append)
    return spec, out, lines


def _keys(results) -> list[str]:
    return [r["key"] for r in load_batch(results)["runs"]]


def test_a_batch_runs_the_grid_and_writes_the_comparison(serial):
    spec, out, lines = serial
    index = load_batch(out)
    assert _keys(out) == ["omni-a/lut-default", "omni-a/lut-no-fusion",
                          "persp-a/mcl-default-" + index["runs"][2]["key"].rsplit("-", 1)[1]]
    assert all(r["status"] == "ok" for r in index["runs"])
    # the method the registry lacks and the pairs of the wrong camera are said, not run
    assert any("'no-such-method'" in s and "not registered" in s for s in index["skipped"])
    assert any("camera kind" in s and "lut x persp-a" in s for s in index["skipped"])
    assert any(s.startswith("skipped: method 'no-such-method'") for s in lines)
    # the numbers are evaluate's: the comparison reads each run's report.json
    rows = list(csv.DictReader((out / "comparison.csv").open()))
    assert [r["run"] for r in rows] == _keys(out)
    rep = json.loads((out / index["runs"][0]["report"] / "report.json").read_text())
    med = rep["position_error_m"]["median"]
    assert rows[0]["median cm"] == ("inf" if med == "inf" else f"{med * 100:.1f}")
    assert rows[0]["frames"] == "3" and rows[0]["status"] == "ok"
    md = (out / "comparison.md").read_text().splitlines()
    assert [c.strip() for c in md[0].split("|")[1:4]] == ["dataset", "method", "frames"]
    assert len(md) == 5
    for name in ("cdf-omni-a.png", "cdf-persp-a.png", "summary.png"):
        assert (out / "plots" / name).stat().st_size > 1000
    # the features are extracted once per dataset and shared by its runs
    feats = {json.loads((out / r["dir"] / RUN_NAME).read_text())["inputs"]["features"]
             for r in index["runs"][:2]}
    assert len(feats) == 1 and len(list((out / "features").glob("omni-a.*.h5"))) == 1
    # `evaluate --table RESULTS` prints the comparison
    r = CliRunner().invoke(cli, ["evaluate", "--table", str(out)])
    assert r.exit_code == 0, r.output
    assert r.stdout.splitlines()[0].split()[:3] == ["dataset", "method", "frames"]
    assert len(r.stdout.splitlines()) == 4


def test_a_rerun_does_only_what_is_missing(serial, tmp_path):
    spec, out, _ = serial
    res = tmp_path / "res"
    shutil.copytree(out, res, symlinks=True)
    poses = {k: (res / "runs" / k / "poses.h5").stat().st_mtime_ns for k in _keys(res)}
    (res / "runs" / "omni-a" / "lut-no-fusion" / RUN_NAME).unlink()
    lines: list[str] = []
    batch.main("serial", spec, res, report=lines.append)
    assert "3 runs: 2 finished before, 1 to do" in lines
    after = {k: (res / "runs" / k / "poses.h5").stat().st_mtime_ns for k in _keys(res)}
    assert [k for k in poses if after[k] != poses[k]] == ["omni-a/lut-no-fusion"]
    # a changed conf is another run (its own key), the finished ones stay
    spec2 = dict(SPEC, methods=[{"method": "lut", "conf": {"heading": "truth"}}])
    lines.clear()
    batch.main("serial", _write_spec(tmp_path / "s2", spec2), res, report=lines.append)
    assert "1 runs: 0 finished before, 1 to do" in lines
    assert (res / "runs" / "omni-a" / "lut-default" / RUN_NAME).is_file()


def test_an_interrupted_batch_keeps_its_finished_runs(serial, tmp_path, monkeypatch):
    spec, out, _ = serial
    res = tmp_path / "res"
    real = batch.do_run
    calls = []

    def interrupted(run, *args):
        calls.append(run.key)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(run, *args)

    monkeypatch.setattr(batch, "do_run", interrupted)
    with pytest.raises(KeyboardInterrupt):
        batch.main("serial", spec, res)
    monkeypatch.setattr(batch, "do_run", real)
    first = calls[0]
    assert (res / "runs" / first / RUN_NAME).is_file()
    assert not (res / "runs" / calls[1] / RUN_NAME).exists()
    lines: list[str] = []
    batch.main("serial", spec, res, report=lines.append)
    assert "3 runs: 1 finished before, 2 to do" in lines
    assert all(r["status"] == "ok" for r in load_batch(res)["runs"])


def _nan_odometry_copy(dataset: Path, dst: Path) -> Path:
    """A copy of ``dataset`` whose odometry holds a NaN row: localize refuses it at run time."""
    shutil.copytree(dataset, dst)
    odo = (dst / "odometry.csv").read_text().splitlines()
    odo[2] = ",".join(odo[2].split(",")[:1] + ["nan"] * 3)
    (dst / "odometry.csv").write_text("\n".join(odo) + "\n")
    return dst


def test_a_failed_run_is_reported_and_the_others_go_on(serial, tmp_path):
    """A recording whose odometry holds a NaN row: localize refuses it at run time."""
    spec, out, _ = serial
    bad = _nan_odometry_copy(out / "datasets" / "omni-a", tmp_path / "bad")
    good = tmp_path / "good"
    shutil.copytree(out / "datasets" / "omni-a", good)
    s = {"map": str(next((out / "maps").glob("*.map.h5"))), "datasets": [
        {"path": str(bad)}, {"path": str(good)}], "methods": ["lut"]}
    lines: list[str] = []
    res = batch.main("serial", _write_spec(tmp_path / "s", s), tmp_path / "res",
                     report=lines.append)
    runs = {r["key"]: r for r in load_batch(res)["runs"]}
    assert runs["good/lut-default"]["status"] == "ok"
    assert runs["bad/lut-default"]["status"] == "failed"
    assert "odometry.csv" in runs["bad/lut-default"]["error"]
    assert "1 of 2 runs finished, 1 failed:" in lines
    assert any(line.startswith("  bad/lut-default: ") for line in lines)
    table = CliRunner().invoke(cli, ["evaluate", "--table", str(res)]).stdout
    assert "failed runs (1):" in table and "- bad/lut-default: " in table


def test_a_batch_whose_every_run_failed_exits_1(serial, tmp_path):
    """Every run failed: the command ends with one line and exit code 1 (the index is
    written, so `evaluate --table` still lists the failures)."""
    spec, out, _ = serial
    bad = _nan_odometry_copy(out / "datasets" / "omni-a", tmp_path / "bad")
    s = {"map": str(next((out / "maps").glob("*.map.h5"))), "datasets": [{"path": str(bad)}],
         "methods": ["lut"]}
    res = CliRunner().invoke(cli, ["-q", "batch", str(_write_spec(tmp_path / "s", s)), "-o",
                                   str(tmp_path / "res"), "--serial"])
    assert res.exit_code == 1
    assert res.stderr.strip().splitlines()[-1].startswith("fieldloc: error: every run failed")
    assert load_batch(tmp_path / "res")["runs"][0]["status"] == "failed"


@pytest.mark.parametrize("change, message", [
    ({"method": ["lut"]}, "unknown key 'method' (known: field, map,"),
    ({"datasets": [{"simulate": {"preset": "omni-clean", "field": "kidsize",
                                 "frame": 3}}]}, "datasets[0].simulate: unknown key 'frame'"),
    ({"methods": [{"method": "lut", "conf": {"headng": "imu"}}]},
     "methods[0]: unknown conf key 'headng'"),
    ({"runs": ["lut x omni-*", "mcl persp-a"]}, "runs[1]: 'mcl persp-a' is not of the form"),
    ({"runs": ["lutt x *"]}, "runs[0]: 'lutt' names no method"),
    # a value of hundreds of kB is quoted by its first few dozen characters
    ({"methods": [{"method": "lut", "name": "x" * 300_000}]},
     "methods: method name 'xxxx"),
    ({"methods": [{"method": list(range(100_000))}]},
     "methods[0].method: expected a text, got [0, 1, 2,"),
    ({"runs": ["x" * 300_000]}, "runs[0]: 'xxxx"),
    ({"runs": ["lut x " + "y" * 300_000]}, "runs[0]: 'yyyy"),
])
def test_a_wrong_spec_is_one_clear_line(change, message, tmp_path):
    spec = _write_spec(tmp_path, {**SPEC, **change})
    with pytest.raises(FieldlocError, match=None) as e:
        read_spec(spec, tmp_path / "res")
    assert message in str(e.value) and str(spec) in str(e.value)
    r = CliRunner().invoke(cli, ["batch", str(spec), "-o", str(tmp_path / "res"), "--serial"])
    assert r.exit_code == 1
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("fieldloc: error: ")
    assert message in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr) < 1200 and "x" * 61 not in r.stderr and "y" * 61 not in r.stderr
    assert not (tmp_path / "res").exists()


def test_a_simulated_datasets_field_file_is_relative_to_the_spec(tmp_path, monkeypatch):
    """A dataset's simulate.field given as a YAML path is read from the SPEC's folder, as
    every path of the SPEC (trial P4: it was read from the working folder): run from another
    folder, a field file there is found, and a missing one is named by its path there."""
    specs = tmp_path / "specs"
    (specs / "fields").mkdir(parents=True)
    (specs / "fields" / "lab.yaml").write_text((Path(__file__).resolve().parents[1] / "maps"
                                                / "spl.yaml").read_text())
    monkeypatch.chdir(tmp_path)  # another folder than the SPEC's
    for field, found in (("fields/lab.yaml", True), ("fields/none.yaml", False)):
        spec = _write_spec(specs, {**SPEC, "datasets": [
            {"simulate": {"preset": "omni-clean", "field": field, "frames": 2}}]})
        if found:
            assert read_spec(spec, tmp_path / "res").datasets[0].sim_field == str(
                specs / field)
        else:
            r = CliRunner().invoke(cli, ["batch", str(spec), "-o", str(tmp_path / "res"),
                                         "--serial"])
            assert r.exit_code == 1 and str(specs / field) in r.stderr, r.stderr
            assert not (tmp_path / "res").exists()


def test_workers_beyond_four_per_core_are_refused(tmp_path):
    """--workers 100000 would start as many worker processes (each holding a map): refused
    in one line before anything is made."""
    spec = _write_spec(tmp_path, SPEC)
    r = CliRunner().invoke(cli, ["-q", "batch", str(spec), "-o", str(tmp_path / "res"),
                                 "--workers", "100000"])
    assert r.exit_code == 1 and r.stderr.count("\n") == 1
    assert "--workers 100000 on" in r.stderr and "at most 4 per core" in r.stderr
    assert not (tmp_path / "res").exists()


def test_a_spec_that_plans_no_run_is_refused_before_anything_is_made(tmp_path):
    """Every method unregistered (or none reading a dataset's camera kind): nothing would run,
    so the batch fails in one line saying why, and no results folder is made."""
    spec = _write_spec(tmp_path, {**SPEC, "methods": ["no-such-method"]})
    r = CliRunner().invoke(cli, ["-q", "batch", str(spec), "-o", str(tmp_path / "res"),
                                 "--serial"])
    assert r.exit_code == 1 and r.stderr.count("\n") == 1
    assert "nothing to run: method 'no-such-method' (methods[0]): not registered" in r.stderr
    omni_only = {**SPEC, "datasets": SPEC["datasets"][:1], "methods": ["mcl"]}
    r = CliRunner().invoke(cli, ["-q", "batch", str(_write_spec(tmp_path / "b", omni_only)),
                                 "-o", str(tmp_path / "res"), "--serial"])
    assert r.exit_code == 1 and "nothing to run: 1 runs whose method does not read" in r.stderr
    assert not (tmp_path / "res").exists()


@pytest.mark.skipif(sys.platform != "linux", reason="LocalCluster on loopback, Linux")
def test_two_workers_give_the_serial_results_value_for_value(serial, tmp_path):
    """The same datasets (as folders) and methods on a LocalCluster of 2 worker processes."""
    spec, out, _ = serial
    s = {"field": "kidsize", "build_map": {"resolution": 0.2},
         "datasets": [{"path": str(out / "datasets" / n)} for n in ("omni-a", "persp-a")],
         "methods": SPEC["methods"][:3]}
    spec_folders = _write_spec(tmp_path / "s", s)
    ser = batch.main("serial", spec_folders, tmp_path / "serial")
    par = batch.main({"workers": 2}, spec_folders, tmp_path / "dask")
    runs = load_batch(par)["runs"]
    assert len(runs) == 3 and all(r["status"] == "ok" for r in runs)
    assert all(not r["worker"].endswith(f":{os.getpid()}") for r in runs)  # not in here
    for r in runs:
        a, _ = read_poses(ser / r["dir"] / "poses.h5")
        b, _ = read_poses(par / r["dir"] / "poses.h5")
        for col in a:
            if col == "runtime":
                continue
            va, vb = np.asarray(a[col]), np.asarray(b[col])
            if va.dtype.kind == "f":
                # exact same-run: serial and Dask runs on this machine
                assert np.array_equal(va, vb, equal_nan=True), (r["key"], col)
            else:
                # exact same-run: serial and Dask runs on this machine
                assert np.array_equal(va, vb), (r["key"], col)
    ca = list(csv.DictReader((ser / "comparison.csv").open()))
    cb = list(csv.DictReader((par / "comparison.csv").open()))
    for x, y in zip(ca, cb):
        x.pop("ms/frame"), y.pop("ms/frame")
        assert x == y
    # a dataset's CDF picture, drawn by a worker once its runs were done: the serial one
    cdfs = sorted(p.name for p in (ser / "plots").glob("cdf-*.png"))
    assert cdfs == sorted(p.name for p in (par / "plots").glob("cdf-*.png")) and cdfs
    for name in cdfs:
        assert (ser / "plots" / name).read_bytes() == (par / "plots" / name).read_bytes(), name
    # and the runs of the serial batch of the same datasets: the same poses
    first = runs[0]["dir"]
    # exact same-run: two batches of this session
    assert np.array_equal(read_poses(out / first / "poses.h5")[0]["x"],
                          read_poses(par / first / "poses.h5")[0]["x"], equal_nan=True)


def test_the_readme_comparison_is_a_batch_comparison(serial):
    """`make compare` writes comparison.md of specs/compare.yaml and its summary picture into
    docs/manual.md's compare block: the block is that table (same columns as the code makes now,
    six datasets or more) and the picture it shows is in the repository."""
    import re

    from stages.evaluate.report import comparison_table

    root = Path(__file__).resolve().parents[1]
    text = (root / "docs" / "manual.md").read_text()
    m = re.search(r"<!-- compare:begin -->\n(.*?)<!-- compare:end -->", text, flags=re.S)
    assert m, "docs/manual.md lacks the compare block"
    lines = m.group(1).splitlines()
    header = comparison_table(serial[1], "markdown").splitlines()[0]
    assert [c.strip() for c in lines[0].split("|")] == [c.strip() for c in header.split("|")]
    rows = [ln for ln in lines[2:] if ln.startswith("|")]
    assert len({r.split("|")[1].strip() for r in rows}) >= 6
    images = re.findall(r"!\[[^]]*\]\(([^)]+)\)", m.group(1))
    assert images and all((root / "docs" / p).is_file() for p in images)
    spec = yaml.safe_load((root / "specs" / "compare.yaml").read_text())
    assert read_spec(root / "specs" / "compare.yaml", root / "build" / "x").runs
    assert {d["simulate"]["preset"].split("-")[0] for d in spec["datasets"]} == {
        "omni", "perspective"}


def test_a_dataset_rendered_again_is_extracted_anew(serial, tmp_path, monkeypatch):
    """Other simulate options render the dataset again: neither its earlier features nor the
    frames of an interrupted extraction of the earlier rendering are taken over."""
    from stages import extract
    from stages.common.features_file import FeaturesFile

    _, out, _ = serial
    mp = str(next((out / "maps").glob("*.map.h5")))

    def spec(frames, seed):
        return _write_spec(tmp_path / f"s{frames}", {"map": mp, "methods": ["lut"], "datasets": [
            {"name": "omni-a", "simulate": {"preset": "omni-clean", "field": "kidsize",
                                            "frames": frames, "seed": seed}}]})

    real, calls = extract.read_frame, []

    def interrupted(path):
        calls.append(path)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(path)

    monkeypatch.setattr(extract, "read_frame", interrupted)
    with pytest.raises(KeyboardInterrupt):
        batch.main("serial", spec(4, 7), tmp_path / "res")
    assert list((tmp_path / "res" / "features").glob(".omni-a.*.parts"))  # 2 frames in it
    monkeypatch.setattr(extract, "read_frame", real)
    res = batch.main("serial", spec(3, 8), tmp_path / "res")
    assert not list((res / "features").glob(".omni-a.*"))
    (feats,) = (res / "features").glob("omni-a.*.features.h5")
    fresh = extract.main(None, res / "datasets" / "omni-a", tmp_path / "fresh.h5")
    with FeaturesFile(feats) as a, FeaturesFile(fresh) as b:
        assert list(a.names) == list(b.names) == ["000000", "000001", "000002"]
        for n in a.names:
            fa, fb = a.frame(n), b.frame(n)
            assert fa.keys() == fb.keys()
            for k in fa:
                va, vb = np.asarray(fa[k]), np.asarray(fb[k])
                # exact same-run: the batch's extract and a fresh one, here
                assert np.array_equal(va, vb, equal_nan=va.dtype.kind == "f"), (n, k)


def test_runs_start_longest_first_and_never_run_first(serial, tmp_path):
    """Dask starts the runs by the seconds their run.json recorded, the longest first; a run
    with no record (never run, or its record gone) first of all."""
    spec, out, _ = serial
    results = tmp_path / "res"
    shutil.copytree(out, results)
    plan = read_spec(spec, results)
    seconds = {r.key: json.loads((out / r.dir / RUN_NAME).read_text()).get("seconds")
               for r in plan.runs if (out / r.dir / RUN_NAME).is_file()}
    ran = [r for r in plan.runs if isinstance(seconds.get(r.key), float)]
    assert len(ran) >= 3
    (results / ran[-1].dir / RUN_NAME).unlink()
    order = batch.longest_first(plan, ran)
    assert order[0].key == ran[-1].key
    rest = [seconds[r.key] for r in order[1:]]
    assert rest == sorted(rest, reverse=True)

