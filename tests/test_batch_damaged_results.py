"""A rerun of batch over a results folder whose own files were damaged since (trial U1):
batch's map, template database and simulated dataset are its own to make again, and a damaged
one is made again or refused in one line, never a traceback."""

from __future__ import annotations

import json

import h5py
import numpy as np
from click.testing import CliRunner

from fieldloc_cli.main import cli

SPEC = """build_map: {{resolution: 0.5}}
{templates}datasets:
  - simulate: {{preset: omni-clean, field: spl, frames: 2, seed: 7}}
methods: [{method}]
"""


def _batch(tmp_path, method: str, templates: str = ""):
    spec = tmp_path / "spec.yaml"
    spec.write_text(SPEC.format(method=method, templates=templates))
    args = ["batch", str(spec), "-o", str(tmp_path / "res"), "--serial"]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    return args


def _rerun(args):
    r = CliRunner().invoke(cli, args)
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    assert "Traceback" not in r.output
    return r


def test_a_damaged_map_of_batch_is_built_again(tmp_path):
    """The map's ``inputs`` an array of numbers (a TypeError in the run, trial U1-6)."""
    args = _batch(tmp_path, "lut")
    (m,) = (tmp_path / "res" / "maps").glob("*.map.h5")
    with h5py.File(m, "a") as f:
        f.attrs["inputs"] = np.arange(3)
    for run in (tmp_path / "res" / "runs").rglob("run.json"):
        run.unlink()  # the runs again, on the map
    r = _rerun(args)
    assert r.exit_code == 0, r.output
    with h5py.File(m, "r") as f:
        assert isinstance(json.loads(f.attrs["inputs"]), dict)


def test_a_damaged_simulation_record_of_batch_is_one_line(tmp_path):
    """The dataset's simulation.yaml not UTF-8 (a UnicodeDecodeError traceback, trial U1-1):
    batch cannot tell the folder its own, so the run fails naming it, the batch exits 1."""
    args = _batch(tmp_path, "lut")
    (rec,) = (tmp_path / "res" / "datasets").glob("*/simulation.yaml")
    rec.write_bytes(b"\xff\xfe not text")
    r = _rerun(args)
    assert r.exit_code == 1, r.output
    assert "every run failed" in r.stderr.strip().splitlines()[-1]
    (run,) = (tmp_path / "res" / "runs").rglob("run.json")
    assert "is not a dataset made by fieldloc simulate" in run.read_text()


def test_a_damaged_template_database_of_batch_is_built_again(tmp_path):
    """The database's ``conf`` an array of numbers (a TypeError traceback, trial U1-2)."""
    args = _batch(tmp_path, "templates", "templates: {grid: 3.0, seed: 8}\n")
    (t,) = (tmp_path / "res" / "templates").glob("*.templates.h5")
    with h5py.File(t, "a") as f:
        f.attrs["conf"] = np.arange(3)
    for run in (tmp_path / "res" / "runs").rglob("run.json"):
        run.unlink()
    r = _rerun(args)
    assert r.exit_code == 0, r.output
    with h5py.File(t, "r") as f:
        assert isinstance(json.loads(f.attrs["conf"]), dict)
