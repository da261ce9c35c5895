"""`fieldloc batch` with method templates (stages.pipelines.batch, batch_spec): two rendered omni
datasets of one robot in one venue (calib_seed and world_seed shared) get their template
database from the SPEC's venue-level `templates:` key, a grid of 9 captures around the centre
of KidSize. The grid is rendered and the database built once for both datasets' runs, a rerun
builds nothing, another build conf is another database from the same grid, and a recording
given a templates.h5 path localises against it as the rendered dataset did."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from stages import build_templates, simulate
from stages.common.batch_file import load_batch
from stages.common.errors import FieldlocError
from stages.common.poses_file import read_poses
from stages.pipelines import batch
from stages.pipelines.batch_spec import read_spec

ROBOT = {"calib_seed": 5, "world_seed": 5}  # one robot, one venue, two sessions
GRID = {"grid": 1.0, "headings": 1, "centre": [0.0, 0.0], "half_size": 1.0, "seed": 9}
SPEC = {
    "field": "kidsize",
    "build_map": {"resolution": 0.2},
    "templates": GRID,
    "datasets": [
        {"name": "omni-a", "simulate": {"preset": "omni-clean", "field": "kidsize", "frames": 3,
                                        "seed": 1, "conf": ROBOT}},
        {"name": "omni-b", "simulate": {"preset": "omni-clean", "field": "kidsize", "frames": 3,
                                        "seed": 2, "conf": ROBOT}},
        {"name": "persp-a", "simulate": {"preset": "perspective-clean", "field": "kidsize",
                                         "frames": 2, "seed": 3}},
    ],
    "methods": ["lut", "templates"],
    "runs": ["templates x *", "lut x omni-a"],
}


def _write_spec(folder: Path, spec: dict) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "spec.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


class _Counts:
    """How often the batch built a template database and rendered a template grid."""

    def __init__(self, monkeypatch):
        self.builds: list[str] = []
        self.grids: list[str] = []
        build, render = build_templates.main, simulate.main

        def counted_build(conf, dataset_dir, output, **kw):
            self.builds.append(str(output))
            return build(conf, dataset_dir, output, **kw)

        def counted_render(conf, field, output_dir, **kw):
            if conf.get("trajectory", {}).get("kind") == "grid":
                self.grids.append(str(output_dir))
            return render(conf, field, output_dir, **kw)

        monkeypatch.setattr(build_templates, "main", counted_build)
        monkeypatch.setattr(simulate, "main", counted_render)


@pytest.fixture(scope="module")
def first(tmp_path_factory):
    """The SPEC run serially once: (spec, results, reported lines, builds, grid renders)."""
    mp = pytest.MonkeyPatch()
    try:
        counts = _Counts(mp)
        root = tmp_path_factory.mktemp("batch-templates")
        spec = _write_spec(root, SPEC)
        lines: list[str] = []
        out = batch.main("serial", spec, root / "results", report=lines.append)
    finally:
        mp.undo()
    return spec, out, lines, counts.builds, counts.grids


def test_templates_runs_share_one_database_built_once(first):
    spec, out, lines, builds, grids = first
    index = load_batch(out)
    status = {r["key"]: r["status"] for r in index["runs"]}
    assert status == {"omni-a/templates-default": "ok", "omni-b/templates-default": "ok",
                      "omni-a/lut-default": "ok"}, [r["error"] for r in index["runs"]]
    for key in ("omni-a/templates-default", "omni-b/templates-default"):
        cols, attrs = read_poses(out / "runs" / key / "poses.h5")
        assert attrs["method"] == "templates" and len(cols["failed"]) == 3
        assert (out / "runs" / key / "report" / "report.json").is_file()
    # the perspective dataset gets no templates from the venue key, and its run is skipped
    assert index["datasets"]["persp-a"]["templates"] == ""
    assert any("camera kind" in s and "templates x persp-a" in s for s in index["skipped"])
    # one grid, one database, for both datasets
    db = index["datasets"]["omni-a"]["templates"]
    assert db == index["datasets"]["omni-b"]["templates"] and Path(db).is_file()
    assert builds == [db] and len(grids) == 1
    grid = Path(grids[0])
    assert len(list((grid / "images").glob("*.png"))) == 9
    # the grid is the datasets' robot: its calibration is theirs, its session its own seed
    for name in ("omni-a", "omni-b"):
        assert (grid / "calib.yaml").read_bytes() == \
            (out / "datasets" / name / "calib.yaml").read_bytes()
    rec = yaml.safe_load((grid / "simulation.yaml").read_text())
    assert (rec["seed"], rec["calib_seed"], rec["world_seed"]) == (9, 5, 5)
    # templates runs read no features: omni-b has only a templates run and is not extracted
    assert not list((out / "features").glob("omni-b.*"))


def test_rerun_builds_nothing_and_other_build_conf_reuses_the_grid(first, monkeypatch):
    spec, out, _lines, builds, grids = first
    db = Path(load_batch(out)["datasets"]["omni-a"]["templates"])
    stamp = db.stat().st_mtime_ns
    counts = _Counts(monkeypatch)
    lines: list[str] = []
    batch.main("serial", spec, out, report=lines.append)
    assert "3 runs: 3 finished before, 0 to do" in lines
    assert counts.builds == [] and counts.grids == [] and db.stat().st_mtime_ns == stamp

    # rotation-invariant SURF: another database of the same grid, and the template runs again
    other = dict(SPEC, templates={**GRID, "build": "surf"})
    spec2 = _write_spec(spec.parent / "other", other)
    lines = []
    batch.main("serial", spec2, out, report=lines.append)
    assert "3 runs: 1 finished before, 2 to do" in lines
    assert counts.grids == [] and len(counts.builds) == 1
    assert counts.builds[0] != str(db) and db.stat().st_mtime_ns == stamp
    index = load_batch(out)
    assert all(r["status"] == "ok" for r in index["runs"])
    assert index["datasets"]["omni-a"]["templates"] == counts.builds[0]


def test_recording_with_a_templates_file(first, tmp_path):
    """A dataset folder given a templates.h5 path: the same poses as the rendered dataset's
    run against the same database."""
    spec, out, *_ = first
    db = load_batch(out)["datasets"]["omni-a"]["templates"]
    rec = {"field": "kidsize", "build_map": {"resolution": 0.2},
           "datasets": [{"path": str(out / "datasets" / "omni-a"), "name": "lab",
                         "templates": db}],
           "methods": ["templates"]}
    res = batch.main("serial", _write_spec(tmp_path, rec), tmp_path / "results",
                     report=lambda line: None)
    [run] = load_batch(res)["runs"]
    assert run["status"] == "ok", run["error"]
    got, _ = read_poses(res / "runs" / "lab" / "templates-default" / "poses.h5")
    want, _ = read_poses(out / "runs" / "omni-a" / "templates-default" / "poses.h5")
    for k in ("x", "y", "theta", "failed"):
        # exact same-run: two batches of this session
        np.testing.assert_array_equal(got[k], want[k])


@pytest.mark.parametrize("change, message", [
    ({"templates": {**GRID, "seed": 1}}, "seed 1 is dataset omni-a's own"),
    ({"templates": {"grid": 1.0}}, "missing key 'seed'"),
    ({"templates": {**GRID, "conf": {"calib_seed": 3}}}, "'calib_seed' is the dataset's robot"),
    ({"templates": {**GRID, "captures": "x"}}, "give 'grid'"),
    ({"templates": {**GRID, "gird": 1}}, "unknown key 'gird'"),
    ({"templates": "no-such.h5"}, "template database not found"),
])
def test_templates_spec_errors_are_one_line(tmp_path, change, message):
    spec = _write_spec(tmp_path, {**SPEC, **change,
                                  "datasets": SPEC["datasets"][:1]})
    with pytest.raises(FieldlocError, match="spec.yaml: templates") as e:
        read_spec(spec, tmp_path / "results")
    assert message in str(e.value) and "\n" not in str(e.value)


def test_perspective_dataset_given_templates_is_refused(tmp_path):
    ds = dict(SPEC["datasets"][2], templates=GRID)
    spec = _write_spec(tmp_path, {**SPEC, "datasets": [ds]})
    with pytest.raises(FieldlocError, match=r"datasets\[0\]\.templates: .*perspective camera"):
        read_spec(spec, tmp_path / "results")


def test_dataset_declines_the_venue_templates(tmp_path):
    ds = dict(SPEC["datasets"][0], templates=None)
    plan = read_spec(_write_spec(tmp_path, {**SPEC, "datasets": [ds, SPEC["datasets"][1]]}),
                     tmp_path / "results")
    assert plan.datasets[0].templates is None and plan.datasets[1].templates is not None
    assert [r.key for r in plan.runs] == ["omni-b/templates-default", "omni-a/lut-default"]
    assert any("without templates" in s and "templates x omni-a" in s for s in plan.skipped)


@pytest.mark.skipif(sys.platform != "linux", reason="LocalCluster on loopback, Linux")
def test_a_dask_batch_from_nothing_is_resumed(first, tmp_path):
    """On 2 workers a batch renders its dataset and grid after planning its runs; its records
    still name what the runs read (the truth hashed where it exists), so the next batch runs
    nothing; and lut's poses are the serial batch's."""
    spec, out, *_ = first
    s = {**SPEC, "datasets": SPEC["datasets"][:1], "runs": "all"}
    spec2 = _write_spec(tmp_path, s)
    res = batch.main({"workers": 2}, spec2, tmp_path / "results", report=lambda line: None)
    assert all(r["status"] == "ok" for r in load_batch(res)["runs"])
    lines: list[str] = []
    batch.main("serial", spec2, res, report=lines.append)
    assert "2 runs: 2 finished before, 0 to do" in lines
    got, _ = read_poses(res / "runs" / "omni-a" / "lut-default" / "poses.h5")
    want, _ = read_poses(out / "runs" / "omni-a" / "lut-default" / "poses.h5")
    # exact same-run: a resumed batch and the first, here
    np.testing.assert_array_equal(got["x"], want["x"])
