"""Bad input and faults (the hostile-input reviews), each as a case of the command line.

A case is a command, the exit code it must end with, a fragment of its message (stderr or a
warning), and what it must not do: no command ends in a traceback, none changes or removes a
file it was given (every file of the shared inputs and of the case's folder is hashed before
and after), and a refused command writes nothing at all (not even a temporary part). Some cases
also check what a successful command wrote. The classes follow the reviews': data lost,
tracebacks, silent or misleading results, what a newcomer hit. Interruptions are in
tests/test_kill.py, the readers' fuzzing in tests/test_fuzz_readers.py; the figures of all
three are stated in the README and checked against the suite at the end of this file.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import json
import logging
import math
import os
import re
import shutil
import signal
import stat
import struct
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages import build_map, extract, localize, simulate
from stages.common.artifacts import LOCK_SUFFIX
from stages.common.camera import load_calib
from stages.common.conf import check_bounds
from stages.common.field import field_from_spec
from stages.common.poses_file import read_poses

ROOT = Path(__file__).resolve().parents[1]
SIZE = 0.25  # m: coarse map cells keep the shared maps cheap; the same code paths run


# ---------------------------------------------------------------------------- shared inputs


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """Small inputs shared (read-only) by every case: spl maps, a 4-frame omni dataset on spl
    with features, poses and a report, a 2-frame perspective kidsize dataset with features, a
    field YAML and calibration pairs."""
    root = tmp_path_factory.mktemp("faults-world")
    p = {"root": root}
    p["map"] = build_map.main({"resolution": SIZE}, "spl", root / "spl.map.h5")
    p["kmap"] = build_map.main({"resolution": SIZE}, "kidsize", root / "kidsize.map.h5")
    p["map3"] = build_map.main({"resolution": 0.3, "max_range": 3.0}, "spl",
                               root / "spl-range3.map.h5")
    conf = dict(simulate.confs["omni-default"], frames=4, seed=3)
    p["omni"] = simulate.main(conf, "spl", root / "omni")
    p["features"] = extract.main(None, p["omni"], p["omni"] / "features.h5")
    # the tracks: four frames hold an accepted pose and a not-accepted one (the grid's
    # belief gathers over more frames than that)
    p["poses"] = localize.main({"method": "lut", "belief": "tracks"}, p["omni"], p["map"],
                               root / "poses.h5", features=p["features"])
    kconf = dict(simulate.confs["perspective-default"], frames=2, seed=4)
    p["kid"] = simulate.main(kconf, "kidsize", root / "kid")
    p["kid_features"] = extract.main(None, p["kid"], root / "kid-features.h5")
    p["field_yaml"] = root / "field.yaml"
    shutil.copyfile(ROOT / "maps" / "spl.yaml", p["field_yaml"])
    r = np.linspace(45, 225, 12)
    d = 0.002 * r + 1e-11 * r**5
    p["marks"] = root / "marks.csv"
    p["marks"].write_text("radius_px,distance_m\n" + "".join(f"{a},{b}\n" for a, b in zip(r, d)))
    p["note"] = root / "note.png"
    p["note"].write_bytes(b"a user's own picture")
    minho = root / "minho"
    minho.mkdir()
    (minho / "mirror.cfg").write_text("STEP=0.25\nPIXEL_DISTANCES=60,100,130,150\n")
    (minho / "image.cfg").write_text("IMG_CENTER=240,240\nTILT=90\n")
    p["minho"] = minho
    return p


def snapshot(*folders) -> dict[str, str]:
    out = {}
    for folder in folders:
        for f in Path(folder).rglob("*"):
            if f.is_file() and not f.is_symlink():
                # exact bytes: files on disk checked unchanged
                out[str(f)] = hashlib.sha256(f.read_bytes()).hexdigest()
    return out


def _cut_first_frame_to_jpeg(ds: Path) -> None:
    """Frame 000000 of ``ds`` as a JPEG file of which only the first half is left (libjpeg
    decoded it, grey below the cut, and said so on stderr only)."""
    first = ds / "images" / "000000.png"
    ok, data = cv2.imencode(".jpg", cv2.imread(str(first)))
    first.unlink()
    (ds / "images" / "000000.jpg").write_bytes(data.tobytes()[:len(data) // 2])
    frames = ds / "frames.csv"
    frames.write_text(frames.read_text().replace("000000.png", "000000.jpg"))


def copy_dataset(world, name: str, ws: Path) -> Path:
    """A copy of a shared dataset in the case's folder (to break it)."""
    dst = ws / name
    shutil.copytree(world[name], dst, ignore=shutil.ignore_patterns("features.h5", "runs"))
    return dst


def edit_calib(ds: Path, **values) -> None:
    d = yaml.safe_load((ds / "calib.yaml").read_text())
    d.update(values)
    (ds / "calib.yaml").write_text(yaml.safe_dump(d))


def edit_csv(path: Path, line: int, text: str | None) -> None:
    """Replace (or with None remove) line ``line`` (1-based, the header is line 1)."""
    lines = path.read_text().splitlines()
    if text is None:
        del lines[line - 1]
    else:
        lines[line - 1] = text
    path.write_text("\n".join(lines) + "\n")


# ---------------------------------------------------------------------------- cases


@dataclass
class Case:
    id: str
    kind: str  # data-lost | traceback | silent | newcomer (the issue's classes)
    args: list[str]
    rc: int
    fragment: str
    setup: object = None  # (world, ws) -> dict of more placeholders
    check: object = None  # (paths, result) -> None, extra assertions
    removes_parts: bool = False  # stale temporary parts and locks set up by it may vanish


def _with_ds(name, change):
    def setup(w, ws):
        ds = copy_dataset(w, name, ws)
        change(ds)
        return {"ds": ds}
    return setup


def _simulated_folder_with(extra: str):
    def setup(w, ws):
        data = ws / "data"
        simulate.main(dict(simulate.confs["omni-clean"], frames=1), "spl", data)
        if extra == "thesis":
            (ws / "thesis").mkdir()
            (ws / "thesis" / "thesis.txt").write_text("two years of work")
        else:
            shutil.copyfile(w["field_yaml"], data / "field.yaml")
        return {"data": data}
    return setup


def _link_to(name: str, symbolic: bool):
    """A case's ws/link.h5: a symbolic or hard link to the shared input ``name`` (another
    name for an input is still that input)."""
    def setup(w, ws):
        (os.symlink if symbolic else os.link)(w[name], ws / "link.h5")
        return {}
    return setup


def _poses_columns(path):
    cols, _ = read_poses(path)
    return cols


def _check_unreadable_counted(paths, res):
    cols = _poses_columns(paths["ws"] / "p.h5")
    assert len(cols["name"]) == 4
    bad = cols["name"] == "000002"
    assert cols["failed"][bad].all() and cols["flags"][bad][0] == "unreadable-image"
    assert np.isfinite(cols["stamp"]).all()


def _check_report_over_all_frames(paths, res):
    import json

    rep = json.loads((paths["ws"] / "rep" / "report.json").read_text())
    assert rep["frames"] == 4 and rep["failures"] >= 1


def _check_integer_ids(paths, res):
    cols = _poses_columns(paths["ws"] / "p.h5")
    assert sorted(cols["name"]) == ["000000", "000001", "000002", "000003"]
    assert not any("no-imu-row" in f for f in cols["flags"])


def _check_modes(paths, res):
    umask = os.umask(0o022)
    os.umask(umask)
    want = 0o666 & ~umask
    for f in (paths["ws"] / "p.h5", paths["ws"] / "p.tum"):
        assert stat.S_IMODE(f.stat().st_mode) == want, oct(f.stat().st_mode)


def _check_reused_features(paths, res):
    assert not (paths["ws"] / "p.features.h5").exists()
    _, attrs = read_poses(paths["ws"] / "p.h5")
    assert attrs["inputs"]["features"] == str(paths["ds"] / "features.h5")


def _setup_own_features(w, ws):
    ds = copy_dataset(w, "omni", ws)
    shutil.copyfile(w["features"], ds / "features.h5")
    return {"ds": ds}


def _points_csv(w, ws, ids, file_name="pts.csv"):
    from stages.common.features_file import FeaturesFile

    rows = ["frame,x,y"]
    with FeaturesFile(w["features"]) as ff:
        for name, new in zip(ff.names, ids):
            rows += [f"{new},{x:.4f},{y:.4f}" for x, y in ff.frame(name)["points"]]
    (ws / file_name).write_text("\n".join(rows) + "\n")
    return {}


def _first_row_with(name: str, column: int, value: str, make=None, source: str | None = None):
    """ws/``name``: a CSV (``make(w, ws)`` writes it there, or the shared file ``source`` is
    copied) whose first data row has ``value`` as its ``column``-th cell."""
    def setup(w, ws):
        if make is not None:
            make(w, ws)
        else:
            shutil.copyfile(w[source], ws / name)
        lines = (ws / name).read_text().splitlines()
        cells = lines[1].split(",")
        cells[column] = value
        lines[1] = ",".join(cells)
        (ws / name).write_text("\n".join(lines) + "\n")
        return {}
    return setup


def _minho_with(line: str):
    """ws/minho: the shared MINHO files, mirror.cfg's key of ``line`` replaced by it."""
    def setup(w, ws):
        shutil.copytree(w["minho"], ws / "minho")
        key = line.split("=", 1)[0]
        cfg = ws / "minho" / "mirror.cfg"
        cfg.write_text("".join(line + "\n" if t.startswith(key + "=") else t + "\n"
                               for t in cfg.read_text().splitlines()))
        return {}
    return setup


def _minho_plus(name: str, text: str):
    """ws/minho: the shared MINHO files, ``text`` added at the end of its ``name``."""
    def setup(w, ws):
        shutil.copytree(w["minho"], ws / "minho")
        with open(ws / "minho" / name, "a") as f:
            f.write(text)
        return {}
    return setup


def _setup_tiny_frame(w, ws):
    """ws/omni: the shared omni dataset with its frame 000001 a 1 x 1 px PNG; ws/t.h5: the
    templates of the shared one."""
    from stages import build_templates

    ds = copy_dataset(w, "omni", ws)
    cv2.imwrite(str(ds / "images" / "000001.png"), np.zeros((1, 1, 3), np.uint8))
    build_templates.main(None, w["omni"], ws / "t.h5")
    return {"ds": ds}


def _minho_replaced(name: str, text: str | None):
    """ws/minho: the shared MINHO files, its ``name`` holding ``text`` (None: a folder)."""
    def setup(w, ws):
        shutil.copytree(w["minho"], ws / "minho")
        (ws / "minho" / name).unlink()
        if text is None:
            (ws / "minho" / name).mkdir()
        else:
            (ws / "minho" / name).write_text(text)
        return {}
    return setup


def _setup_relative_run(w, ws):
    """localize run from inside ws with relative paths; evaluate then runs elsewhere."""
    ds = copy_dataset(w, "omni", ws)
    cwd = os.getcwd()
    os.chdir(ws)
    try:
        r = CliRunner().invoke(cli, ["-q", "localize", "omni", "--map", str(w["map"]),
                                     "--features", str(w["features"]), "-o", "rel.h5"])
        assert r.exit_code == 0, r.output
    finally:
        os.chdir(cwd)
    return {"ds": ds}


def _setup_same_stem(w, ws):
    ds = copy_dataset(w, "omni", ws)
    img = cv2.imread(str(ds / "images" / "000003.png"))
    cv2.imwrite(str(ds / "images" / "000003.jpg"), img)
    return {"ds": ds}


def _setup_unreadable(w, ws, localised=False):
    ds = copy_dataset(w, "omni", ws)
    (ds / "images" / "000002.png").write_bytes(b"not an image")
    if localised:
        r = CliRunner().invoke(cli, ["-q", "localize", str(ds), "--map", str(w["map"]), "-o",
                                     str(ws / "p.h5")])
        assert r.exit_code == 0, r.output
    return {"ds": ds}


def _copy(src, dst):
    shutil.copyfile(src, dst)
    return {}


def _setup_no_frames_csv(w, ws):
    """Images named 000000.png .. without frames.csv are read as stamps 0, 1, 2, 3 s; the
    imu and odometry rows are at 0.0, 0.1, 0.2, 0.3 s."""
    ds = copy_dataset(w, "omni", ws)
    (ds / "frames.csv").unlink()
    return {"ds": ds}


def _setup_wrong_size(w, ws):
    ds = copy_dataset(w, "omni", ws)
    for f in (ds / "images").iterdir():
        cv2.imwrite(str(f), np.zeros((100, 120, 3), np.uint8))
    return {"ds": ds}


def _setup_stale(w, ws):
    """Parts left by a killed run (its pid is gone) and by an older fieldloc."""
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    (ws / f".m.h5.fieldloc-{p.pid}-abcd1234.part").write_bytes(b"x" * 1000)
    (ws / ".m.h5.k2j3h4g5.part").write_bytes(b"y" * 10)
    return {}


def _check_stale_removed(paths, res):
    left = sorted(p.name for p in paths["ws"].iterdir())
    assert left == ["m.h5"], left


def _setup_corrupt_map(w, ws):
    data = Path(w["map"]).read_bytes()
    (ws / "cut.map.h5").write_bytes(data[: len(data) // 2])
    with h5py.File(ws / "hollow.map.h5", "w") as f:
        f.attrs["schema"] = "fieldloc.map"
        f.attrs["schema_version"] = 1
    return {}


def _setup_field(change):
    def setup(w, ws):
        spec = yaml.safe_load(Path(w["field_yaml"]).read_text())
        spec.update(change)
        (ws / "f.yaml").write_text(yaml.safe_dump(spec))
        return {}
    return setup


# nine levels of nine aliases: 9^9 (387 million) strings once expanded ("billion laughs")
ALIAS_BOMB = "[&a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]" + "".join(
    f", &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, 9)) + "]"


def _setup_field_text(append: str):
    """The shared field YAML with ``append`` added as text (YAML that a dict cannot hold)."""
    def setup(w, ws):
        (ws / "f.yaml").write_text(Path(w["field_yaml"]).read_text() + append)
        return {}
    return setup


def _setup_calib_text(append: str):
    """The omni dataset copied, its calib.yaml with ``append`` added as text."""
    def setup(w, ws):
        ds = copy_dataset(w, "omni", ws)
        with open(ds / "calib.yaml", "a") as f:
            f.write(append)
        return {"ds": str(ds)}
    return setup



# ------------------------------------------------------------------ the later review's setups


def _bag(ws: Path, rel: str = "x.bag", fmt: str = "ros1") -> Path:
    """A 2-frame bag (ros1: a .bag file; ros2-sqlite3: a folder) written with rosbags."""
    from stages.ingest.bag_writer import write_bag

    path = ws / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    img = np.zeros((48, 64, 3), np.uint8)
    return write_bag(path, fmt, image_topic="/cam",
                     frames=[(1.0 + 0.1 * i, (img, "bgr8")) for i in range(2)])


def _setup_bags(w, ws):
    """Damaged bags: empty, random bytes, truncated; ROS 2 folders whose metadata.yaml is not
    YAML and whose .db3 is empty; a good bag inside a folder d; a user's folder thesis."""
    good = _bag(ws)
    (ws / "zero.bag").write_bytes(b"")
    (ws / "random.bag").write_bytes(np.random.default_rng(5).bytes(5000))
    (ws / "cut.bag").write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    r2 = _bag(ws, "r2", "ros2-sqlite3")
    bad = ws / "r2-yaml"
    bad.mkdir()
    (bad / "metadata.yaml").write_text("rosbag2_bagfile_information: {{{: [\n")
    for db in r2.glob("*.db3"):
        shutil.copyfile(db, bad / db.name)
    empty = ws / "r2-empty"
    empty.mkdir()
    shutil.copyfile(r2 / "metadata.yaml", empty / "metadata.yaml")
    for db in r2.glob("*.db3"):
        (empty / db.name).write_bytes(b"")
    _bag(ws, "d/x.bag")
    (ws / "thesis").mkdir()
    (ws / "thesis" / "thesis.txt").write_text("two years of work")
    return {}


def _setup_users_outputs(w, ws):
    """A user's own files under the names outputs take: an HDF5 file without fieldloc's
    schema, a picture of each kind, a CSV, a JSON, a TUM trajectory without write_tum's
    header, a calibration and a field YAML of a team, and a B-Human field file to import."""
    with h5py.File(ws / "mine.h5", "w") as f:
        f["data"] = np.arange(5.0)
        f.attrs["schema"] = "my-lab.log"
    cv2.imwrite(str(ws / "photo.png"), np.full((8, 8, 3), 90, np.uint8))
    cv2.imwrite(str(ws / "photo.jpg"), np.full((8, 8, 3), 90, np.uint8))
    (ws / "notes.csv").write_text("name,x,y\nmy,1,2\n")
    (ws / "notes.json").write_text('{"schema": "my-lab"}\n')
    (ws / "traj.tum").write_text("0.0 1 2 0 0 0 0 1\n")
    (ws / "calib.yaml").write_text("camera: omni\n# our robot's mirror, measured by hand\n")
    (ws / "field.yaml").write_text("name: our-lab\n")
    _setup_team_file(w, ws)
    return {}


def _setup_lookup_with_notes(w, ws):
    """A copy of the map whose .lookup folder (the cache beside it) holds a user's notes and
    a cache file of an earlier content of the map (which may go)."""
    shutil.copyfile(w["map"], ws / "m.map.h5")
    (ws / "m.map.h5.lookup").mkdir()
    (ws / "m.map.h5.lookup" / "notes.txt").write_text("where I keep my maps")
    (ws / "m.map.h5.lookup" / "results-2026.csv").write_text("run,score\n")
    return {}


def _setup_forged_marks(w, ws):
    """Files that only mention fieldloc: a note saying "written by fieldloc" (as a log of
    fieldloc's own refusals does), an HDF5 file of a schema fieldloc does not write."""
    (ws / "note.h5").write_text("my notes: these poses were written by fieldloc, keep this\n")
    with h5py.File(ws / "mine.h5", "w") as f:
        f["x"] = np.arange(3.0)
        f.attrs["schema"] = "fieldloc.mine"
    return {}


def _setup_batch_version(value: str):
    """ws/res: a results folder whose batch.json names ``value`` (JSON text) as its version."""
    def setup(w, ws):
        (ws / "res").mkdir()
        (ws / "res" / "batch.json").write_text(
            '{"schema": "fieldloc.batch", "schema_version": ' + value + ', "runs": []}')
        return {}
    return setup


def _setup_parts_of_this_run(change):
    """extract's resume folder for ws/f.h5 as a run on the shared omni dataset with the
    defaults leaves it (its run.json), then ``change(folder)``: what the case's extract finds."""
    def setup(w, ws):
        from stages import extract
        from stages.common.dataset import open_dataset
        from stages.common.features_file import FrameParts

        ds = open_dataset(w["omni"])
        camera = ds.camera()
        conf = extract.resolve_extract_conf(camera.kind, None)
        attrs, _mask, _head = extract._run_attrs(ds, camera, extract.kind_module(camera.kind),
                                                 conf)
        parts = FrameParts(ws / "f.h5", attrs)
        parts.open()
        change(parts.dir)
        return {}
    return setup


def _write(name: str, data: bytes):
    return lambda folder: (folder / name).write_bytes(data)


def _setup_users_parts_folder(w, ws):
    """A folder of the user's at ``.f.h5.parts`` (extract's resume folder for f.h5): it was
    removed without a word (trial D1, D12)."""
    (ws / ".f.h5.parts").mkdir()
    (ws / ".f.h5.parts" / "thesis.txt").write_text("two years of work")
    return {}


def _setup_png_claiming(w, ws):
    """ws/x.png: a frame of the shared dataset whose header claims 100000 x 100000 px."""
    shutil.copyfile(w["omni"] / "images" / "000000.png", ws / "x.png")
    _claim_size(ws / "x.png", 100000, 100000)
    return {}


def _setup_record_of_frames(n: int):
    """ws/data: a 1-frame simulated dataset whose simulation.yaml claims ``n`` frames
    (written as simulate writes its record, vouching for itself: what is tested is the
    count, not a record edited since)."""
    def setup(w, ws):
        from stages.common.artifacts import record_text

        data = simulate.main(dict(simulate.confs["omni-clean"], frames=1), "spl", ws / "data")
        rec = yaml.safe_load((data / "simulation.yaml").read_text())
        rec["frames"] = n
        (data / "simulation.yaml").write_text(record_text(rec, "simulation.yaml"))
        return {}
    return setup


def _setup_report_copy(w, ws):
    """The shared report copied to ws/runs/a, with a poses.h5 beside it; a user's page."""
    shutil.copytree(w["omni"] / "runs" / "r", ws / "runs" / "a")
    shutil.copyfile(w["poses"], ws / "runs" / "a" / "poses.h5")
    (ws / "mine.html").write_text("<html>my own notes</html>")
    return {}


def _shift_truth(ds: Path) -> None:
    """Another recording's truth on the same field: every x 1 m further."""
    rows = (ds / "truth.csv").read_text().splitlines()
    head, body = rows[0], [r.split(",") for r in rows[1:]]
    (ds / "truth.csv").write_text("\n".join(
        [head] + [",".join([r[0], str(float(r[1]) + 1.0), *r[2:]]) for r in body]) + "\n")


def _setup_read_only_poses(w, ws):
    """A poses file fieldloc wrote, made read-only by its user (chmod 444) to keep it."""
    shutil.copyfile(w["poses"], ws / "kept.h5")
    os.chmod(ws / "kept.h5", 0o444)
    return {}


def _setup_report_copy_read_only(w, ws):
    """The shared report copied to ws/runs/a, its errors.csv made read-only (chmod 444)."""
    _setup_report_copy(w, ws)
    os.chmod(ws / "runs" / "a" / "errors.csv", 0o444)
    return {}


def _setup_bad_report(change):
    def setup(w, ws):
        import json

        shutil.copytree(w["omni"] / "runs" / "r", ws / "r")
        rep = json.loads((ws / "r" / "report.json").read_text())
        change(rep)
        (ws / "r" / "report.json").write_text(json.dumps(rep))
        return {}
    return setup


def _setup_poses_edit(change):
    def setup(w, ws):
        shutil.copyfile(w["poses"], ws / "p.h5")
        with h5py.File(ws / "p.h5", "a") as f:
            change(f)
        return {}
    return setup


def _shorten_x(f):
    x = f["poses/x"][()]
    del f["poses/x"]
    f["poses/x"] = x[:2]


def _flat_hypotheses(f):
    del f["hypotheses"]
    f["hypotheses"] = np.ones((1, 2))


def _setup_features_edit(change):
    """The shared features file with ``change(f, i)`` made to it: ``f`` the open file, ``i``
    the stored position of its second frame by name."""
    def setup(w, ws):
        shutil.copyfile(w["features"], ws / "f.h5")
        with h5py.File(ws / "f.h5", "a") as f:
            names = [n.decode() for n in f["index/name"][()]]
            change(f, names.index(sorted(names)[1]))
        return {}
    return setup


def _set_column(f, key, data, rows):
    for part, value in ((f"data/{key}", data), (f"rows/{key}", rows)):
        del f[part]
        f[part] = value


def _drop_radial(f, i):
    """Frame ``i`` without its radial dataset (its rows gone, its count -1)."""
    rows = f["rows/radial"][()]
    start = np.concatenate([[0], np.cumsum(np.maximum(rows, 0))])
    data = np.delete(f["data/radial"][()], np.s_[start[i]:start[i + 1]], axis=0)
    rows[i] = -1
    _set_column(f, "radial", data, rows)


def _cut_radial(f, i):
    """Every frame's radial (72, 3): the last crossing of each scan line gone."""
    _set_column(f, "radial", f["data/radial"][:, :3], f["rows/radial"][()])


def _setup_nan_segments(w, ws):
    shutil.copyfile(w["map"], ws / "nan.map.h5")
    with h5py.File(ws / "nan.map.h5", "a") as f:
        f["field/segments"][0, 0, 0] = np.nan
    return {}


def _setup_spec(text: str):
    """A batch SPEC in ws (``text`` formatted with the shared map's path)."""
    def setup(w, ws):
        (ws / "spec.yaml").write_text(text.format(map=w["map"], field=w["field_yaml"]))
        return {}
    return setup


def _setup_field_name_bomb(w, ws):
    text = Path(w["field_yaml"]).read_text()
    assert text.count("name: spl") == 1
    (ws / "f.yaml").write_text(text.replace("name: spl", f"name: {ALIAS_BOMB}"))
    return {}


def _setup_live_lock(w, ws):
    """The lock of a run that is alive (a sleeping process stands for it)."""
    p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    (ws / ".f.h5.fieldloc-lock").write_text(f"{p.pid}\n")
    return {"holder": p}


def _check_lock_holder_untouched(paths, res):
    p = paths["holder"]
    assert p.poll() is None  # the refusing run did not touch the live run
    p.kill()
    p.wait()


def _check_one_frame_of_four(paths, res):
    """Every dataset frame has a row: the three the points file names no point of failed."""
    cols = _poses_columns(paths["ws"] / "p.h5")
    assert len(cols["name"]) == 4
    flags = [str(f) for f in cols["flags"]]
    assert [("no-points" in f) for f in flags] == [False, True, True, True], flags
    assert cols["failed"][1:].all()


def _setup_custom_field_poses(w, ws):
    """Poses of the omni frames made with the map of a custom field (its name no preset)."""
    spec = yaml.safe_load(Path(w["field_yaml"]).read_text())
    spec["name"] = "minho-lab"
    (ws / "lab.yaml").write_text(yaml.safe_dump(spec))
    m = build_map.main({"resolution": 0.5}, ws / "lab.yaml", ws / "lab.map.h5")
    localize.main({"method": "lut"}, w["omni"], m, ws / "p.h5", features=w["features"],
                  allow_field_mismatch=True)
    (ws / "lab.yaml").unlink()  # the map carries the field
    return {}


def _setup_team_file(w, ws):
    """A B-Human fieldDimensions.cfg (mm) and a field YAML to give as --base."""
    dims = {"xPosOpponentFieldBorder": 5200, "xPosOpponentGoal": 5055,
            "xPosOpponentGoalLine": 4500, "xPosOpponentGoalArea": 3900,
            "xPosOpponentPenaltyMark": 3200, "xPosOpponentPenaltyArea": 2850,
            "yPosLeftFieldBorder": 3700, "yPosLeftTouchline": 3000, "yPosLeftPenaltyArea": 2000,
            "yPosLeftGoalArea": 1100, "yPosLeftGoal": 800, "fieldLinesWidth": 50,
            "centerCircleRadius": 750, "goalPostRadius": 50, "penaltyMarkSize": 100}
    (ws / "fd.cfg").write_text("".join(f"{k} = {v};\n" for k, v in dims.items()))
    shutil.copyfile(w["field_yaml"], ws / "base.yaml")
    return {}


def _setup_fifo_image(w, ws):
    """The omni dataset copied, its third image a FIFO (reading it would block forever)."""
    ds = copy_dataset(w, "omni", ws)
    (ds / "images" / "000002.png").unlink()
    os.mkfifo(ds / "images" / "000002.png")
    return {"ds": ds}


def _sparse(name: str, size: int):
    """A change of a folder: its file ``name`` replaced by a sparse file of ``size`` bytes
    (zeros, no disk used) -- a text file fieldloc would read whole."""
    def change(folder: Path):
        (folder / name).unlink(missing_ok=True)
        with open(folder / name, "wb") as f:
            f.truncate(size)
    return change


def _setup_fifo_file(name):
    """The omni dataset copied, its file ``name`` a FIFO: reading it would block forever, and
    taking it as absent would run on without what it holds."""
    def setup(w, ws):
        ds = copy_dataset(w, "omni", ws)
        (ds / name).unlink()
        os.mkfifo(ds / name)
        return {"ds": ds}
    return setup


def _setup_minho_fifo_image(w, ws):
    """A MINHO calibration folder whose first image (where the image size is read) is a FIFO."""
    minho = ws / "minho"
    shutil.copytree(w["minho"], minho)
    (minho / "images").mkdir()
    os.mkfifo(minho / "images" / "0001.png")
    return {"m": minho}


def _setup_loops(*names):
    """Symbolic links in the case's folder, each to itself (``ln -s x x``): a link loop, which
    Path.resolve raised RuntimeError for (Python < 3.13) and Path.exists calls absent."""
    def setup(w, ws):
        for name in names:
            (ws / name).parent.mkdir(parents=True, exist_ok=True)
            os.symlink(Path(name).name, ws / name)
        return {}
    return setup


LOOP_SPECS = {  # batch SPECs naming ws/loop (a link loop) as a dataset's ...
    "path": "map: {map}\ndatasets: [{{path: loop}}]\nmethods: [lut]\n",
    "calib": "map: {map}\ndatasets: [{{path: {omni}, calib: loop}}]\nmethods: [lut]\n",
    "from_minho": "map: {map}\ndatasets: [{{path: {omni}, calib: {{from_minho: loop}}}}]\n"
                  "methods: [lut]\n",
    "map": "datasets: [{{path: {omni}, map: loop}}]\nmethods: [lut]\n",
    "templates": "field: spl\ndatasets: [{{path: {omni}, templates: loop}}]\n"
                 "methods: [templates]\n",
}


def _setup_loops_and_spec(w, ws):
    """Link loops ws/loop, ws/loop.yaml, ws/d/poses.h5 (the stem of the shared poses) and
    ws/R/report.json; ws/spec.yaml, a batch SPEC of the shared omni dataset, and ws/<key>.yaml
    of LOOP_SPECS."""
    _setup_loops("loop", "loop.yaml", "d/poses.h5", "R/report.json")(w, ws)
    (ws / "spec.yaml").write_text(f"map: {w['map']}\ndatasets: [{{path: {w['omni']}}}]\n"
                                  "methods: [lut]\n")
    for key, text in LOOP_SPECS.items():
        (ws / f"{key}.yaml").write_text(text.format(map=w["map"], omni=w["omni"]))
    return {}


def _check_said_once(twice: str):
    def check(paths, res):
        assert twice not in res.stderr and "symbolic link loop" in res.stderr, res.stderr
    return check


def _setup_loop_map_spec(w, ws):
    """ws/loop (a link loop) and ws/top.yaml, a batch SPEC whose top-level map is it."""
    _setup_loops_and_spec(w, ws)
    (ws / "top.yaml").write_text(f"map: loop\ndatasets: [{{path: {w['omni']}}}]\n"
                                 "methods: [lut]\n")
    return {}


def _setup_special(name, kind="fifo"):
    """A FIFO (or, as root, a character device like /dev/null) named ``name`` in the case's
    folder: an output that an atomic write would replace with a file."""
    def setup(w, ws):
        if kind == "fifo":
            os.mkfifo(ws / name)
        else:
            if os.geteuid() != 0:
                pytest.skip("making a device node needs root")
            os.mknod(ws / name, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
        return {}
    return setup


def _check_still_special(name):
    def check(paths, res):
        mode = os.lstat(paths["ws"] / name).st_mode
        assert stat.S_ISFIFO(mode) or stat.S_ISCHR(mode), "the node was replaced"
    return check


def _setup_deep_json(name):
    """A folder ``deep`` holding ``name``: a JSON array nested 100,000 deep (json.loads
    recurses once per level)."""
    def setup(w, ws):
        (ws / "deep").mkdir()
        (ws / "deep" / name).write_text("[" * 100_000 + "]" * 100_000)
        return {}
    return setup


def _setup_team_files(w, ws):
    """Copies of a Carpe Noctem CarpetCalibrator.conf (with its picture) and of HULKs captures
    (two JSON + image pairs) from ../shared/realdata, and a user's own folder."""
    real = ROOT.parent / "shared" / "realdata"
    if not (real / "cnc-calibration").is_dir() or not (real / "hulks-goalbox-labels").is_dir():
        pytest.skip(f"{real} lacks the CNC or HULKs files")
    shutil.copytree(real / "cnc-calibration", ws / "cnc")
    os.chmod(ws / "cnc", 0o755)
    (ws / "hulks").mkdir()
    for stem in sorted(p.stem for p in (real / "hulks-goalbox-labels" / "measurements")
                       .glob("*.json"))[:2]:
        for suffix in (".json", ".jpg"):
            shutil.copy(real / "hulks-goalbox-labels" / "measurements" / (stem + suffix),
                        ws / "hulks")
    (ws / "thesis").mkdir()
    (ws / "thesis" / "thesis.txt").write_text("two years of work")
    return {"capture": str(sorted((ws / "hulks").glob("*.json"))[0])}


def _setup_hulks_capture(old: str, new: str):
    """ws/h.json: the first HULKs capture of ``_setup_team_files`` (written compact, as
    json.dumps does) with the text ``old`` replaced by ``new``."""
    def setup(w, ws):
        paths = _setup_team_files(w, ws)
        text = json.dumps(json.loads(Path(paths["capture"]).read_text()))
        assert old in text, old
        (ws / "h.json").write_text(text.replace(old, new, 1))
        return paths
    return setup


def _claim_size(png: Path, width: int, height: int) -> None:
    """Rewrite the IHDR chunk of the PNG file ``png`` to claim ``width`` x ``height`` pixels
    (with a right CRC: the rest of the file is left as it was)."""
    import struct
    import zlib

    data = png.read_bytes()
    chunk = b"IHDR" + struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    png.write_bytes(data[:8] + struct.pack(">I", 13) + chunk
                    + struct.pack(">I", zlib.crc32(chunk)) + data[33:])


def _setup_line_image(name: str):
    """The shared MINHO folder copied and ws/li, a folder of one line image named ``name``
    (a grey 480 x 480 picture: what is tested is the name)."""
    def setup(w, ws):
        (ws / "li").mkdir()
        cv2.imwrite(str(ws / "li" / name), np.full((480, 480, 3), 90, np.uint8))
        return _setup_minho()(w, ws)
    return setup


def _setup_bag_of_frames(*frames):
    """ws/x.bag: a ROS 1 bag of ``frames`` on /cam, each "grey" (a 64 x 48 PNG), "raw WxH" (a
    mono8 frame of that size) or "bayer WxH" (a compressed Bayer PNG whose header claims that
    size); raw frames and compressed ones are not mixed (one message type per topic)."""
    def setup(w, ws):
        from stages.ingest.bag_writer import write_bag

        out = []
        for i, kind in enumerate(frames):
            what, _, size = kind.partition(" ")
            width, height = (int(v) for v in size.split("x")) if size else (0, 0)
            if what == "grey":
                payload = (cv2.imencode(".png", np.full((48, 64), 90, np.uint8))[1].tobytes(),
                           "png")
            elif what == "raw":
                payload = (np.zeros((height, width), np.uint8), "mono8")
            else:
                cv2.imwrite(str(ws / "m.png"), np.zeros((8, 8), np.uint8))
                _claim_size(ws / "m.png", width, height)
                payload = ((ws / "m.png").read_bytes(), "bayer_rggb8; png compressed mono8")
                (ws / "m.png").unlink()
            out.append((1.0 + 0.1 * i, payload))
        write_bag(ws / "x.bag", "ros1", image_topic="/cam", frames=out)
        return {}
    return setup


def _setup_minho(mirror: str | None = None, image: bytes | None = None):
    """The shared MINHO folder copied, with ``mirror`` as its mirror.cfg and ``image`` as the
    one file of its images folder, where given."""
    def setup(w, ws):
        minho = ws / "minho"
        shutil.copytree(w["minho"], minho)
        if mirror is not None:
            (minho / "mirror.cfg").write_text(mirror)
        if image is not None:
            (minho / "images").mkdir()
            (minho / "images" / "0001.png").write_bytes(image)
        return {"m": minho}
    return setup


def _setup_cnc(change):
    """_setup_team_files, then ``change`` (the CNC folder) applied."""
    def setup(w, ws):
        out = _setup_team_files(w, ws)
        change(ws / "cnc")
        return out
    return setup


def _odometry_dx(value: str):
    """The omni dataset copied, the dx of odometry.csv's second row set to the text ``value``."""
    def change(ds):
        lines = (ds / "odometry.csv").read_text().splitlines()
        cells = lines[2].split(",")
        cells[1] = value
        edit_csv(ds / "odometry.csv", 3, ",".join(cells))
    return _with_ds("omni", change)


def _check_fifo_frame_failed(paths, res):
    from stages.common.features_file import FeaturesFile

    with FeaturesFile(paths["ws"] / "f.h5") as ff:
        assert "000002" not in ff.names and len(ff.names) == 3


LONG = "x" * 300_000  # a bad value of 300 kB: the message quotes a few dozen characters of it


def _check_short_message(paths, res):
    assert "x" * 61 not in res.stderr and len(res.stderr) < 2000, len(res.stderr)



def _setup_user_summaries(batch_json: str | None, dirs=()):
    """A batch SPEC of the shared omni dataset, and a folder res holding a user's own
    comparison tables and summary picture (and ``batch.json`` text, and empty ``dirs``)."""
    def setup(w, ws):
        (ws / "spec.yaml").write_text(f"map: {w['map']}\ndatasets: [{{path: {w['omni']}}}]\n"
                                      "methods: [lut]\n")
        res = ws / "res"
        (res / "plots").mkdir(parents=True)
        (res / "comparison.csv").write_text("my thesis table\n")
        (res / "comparison.md").write_text("notes\n")
        (res / "plots" / "summary.png").write_bytes(b"a user's own picture")
        if batch_json is not None:
            (res / "batch.json").write_text(batch_json)
        for d in dirs:
            (res / d).mkdir()
        return {}
    return setup


def _setup_batch_field_name(w, ws):
    spec = yaml.safe_load(Path(w["field_yaml"]).read_text())
    spec["name"] = "../../escaped-batch"
    (ws / "f.yaml").write_text(yaml.safe_dump(spec))
    (ws / "spec.yaml").write_text(f"field: {ws / 'f.yaml'}\ndatasets: [{{path: {w['omni']}}}]\n"
                                  "methods: [lut]\n")
    return {}


def _edit_intrinsics(**values):
    def change(ds):
        d = yaml.safe_load((ds / "calib.yaml").read_text())
        d["intrinsics"].update(values)
        (ds / "calib.yaml").write_text(yaml.safe_dump(d))
    return _with_ds("kid", change)


def _setup_extract_spec(dataset: str, extract: str, method: str):
    """A batch SPEC of one shared dataset, with a top-level ``extract`` and one method."""
    def setup(w, ws):
        (ws / "spec.yaml").write_text(f"map: {w['map']}\ndatasets: [{{path: {w[dataset]}}}]\n"
                                      f"extract: {extract}\nmethods: [{method}]\n")
        return {}
    return setup


# ---- s54 group H1: numbers a user wrote (setups)
HUGE = "9" * 400  # an integer beyond the float range (1.8e308 has 309 digits)


def _with_yaml_value(name: str, file: str, key: str, raw: str):
    """The shared dataset ``name`` copied, the value of ``key`` (dotted, a list's index as a
    number: "polynomial.1") in its ``file`` (calib.yaml, simulation.yaml) replaced by the raw
    YAML text ``raw`` (``yes``, an integer of 400 digits: what a dict would not dump)."""
    def change(ds):
        d = yaml.safe_load((ds / file).read_text())
        *parents, last = key.split(".")
        node = d
        for part in parents:
            node = node[int(part)] if isinstance(node, list) else node[part]
        node[int(last) if isinstance(node, list) else last] = "@RAW@"
        (ds / file).write_text(yaml.safe_dump(d).replace("'@RAW@'", raw))
    return _with_ds(name, change)


def _setup_number_file(name: str, text: str):
    """ws/``name``: a team's field file of ``text``, HUGE standing for an integer of 400
    digits."""
    def setup(w, ws):
        (ws / name).write_text(text.replace("HUGE", HUGE))
        return {}
    return setup


def _setup_huge_spec(w, ws):
    """ws/spec.yaml: a batch SPEC of the shared dataset whose lut conf has a 400-digit
    hypotheses."""
    (ws / "spec.yaml").write_text(f"map: {w['map']}\ndatasets: [{{path: {w['omni']}}}]\n"
                                  f"methods: [{{method: lut, conf: {{hypotheses: {HUGE}}}}}]\n")
    return {}


def _setup_one_bag(w, ws):
    """ws/x.bag: a 2-frame bag."""
    _bag(ws)
    return {}


LOCALIZE = ["localize", "{omni}", "--map", "{map}", "--features", "{features}"]


def _g3_seed_1_0(w, ws):
    """ws/simulation.yaml: the shared dataset's record, its seed written 1_0 (YAML 1.1's 10)."""
    text = (w["omni"] / "simulation.yaml").read_text()
    (ws / "simulation.yaml").write_text(re.sub(r"^seed: .*$", "seed: 1_0", text, flags=re.M))
    return {}


def _g3_bounded_line(paths, res):
    """The one error line quoting a path of 4000 characters is at most LINE_MAX long and
    keeps the path's tail (which file)."""
    from stages.common.one_line import LINE_MAX

    line = res.stderr.splitlines()[0]
    assert len(line) <= LINE_MAX and line.endswith("/none.h5"), (len(line), line)


W = "{ws}"
SIM_OMNI = ["simulate", "omni", "--field", "spl", "--frames", "2", "-o", W + "/sim"]
SIM_NAO = ["simulate", "perspective", "--field", "kidsize", "--frames", "2", "-o", W + "/sim",
           "--preset", "perspective-nao"]


def _spec_with(conf: str = "", evaluate: str = "", templates: str = "", methods: str = "[lut]",
               preset: str = "omni-clean") -> str:
    """A batch SPEC (a _setup_spec text: braces doubled) of one simulated 2-frame dataset on
    spl and the shared map, with a simulate ``conf``, an ``evaluate``, ``templates``."""
    text = ("map: {map}\ndatasets:\n  - name: d\n    simulate: {{preset: " + preset
            + ", field: spl, frames: 2, seed: 1" + (f", conf: {conf}" if conf else "") + "}}\n")
    text += f"evaluate: {evaluate}\n" if evaluate else ""
    text += f"templates: {templates}\n" if templates else ""
    return text + f"methods: {methods}\n"


# ------------------------------------------------------------------ damaged artifacts' setups


def _setup_damaged(key: str, name: str, change):
    """The shared artifact ``key`` copied to ws/``name`` with ``change(f)`` made to it (``f``
    open for writing); ``key`` "templates": a templates file built from the shared omni
    dataset."""
    def setup(w, ws):
        if key == "templates":
            from stages import build_templates

            build_templates.main(None, w["omni"], ws / name)
        else:
            shutil.copyfile(w[key], ws / name)
        with h5py.File(ws / name, "a") as f:
            change(f)
        return {}
    return setup


# ---------------------------------------------------------------------------- outputs that
# replaced a user's files (hostile review s53: the TUM twin, evaluate's folder, debug images,
# the report's plots, simulate --overwrite)


def _setup_user_tum(w, ws):
    """ws/mine.tum: a user's file of the name localize -o ws/mine.h5 writes its TUM twin to."""
    (ws / "mine.tum").write_text("mine\n")
    return {}


def _setup_truth_tum_in_dataset(w, ws):
    """A copy of the omni dataset holding the user's truth.tum (their truth, converted)."""
    ds = copy_dataset(w, "omni", ws)
    shutil.copyfile(ds / "truth.csv", ds / "truth.tum")
    return {"ds": ds}


def _setup_fieldloc_tum(w, ws):
    """ws/p.tum: the TUM twin an earlier localize wrote, without the poses that record it
    (s56 W5: no poses beside it vouch for it; tests/test_overwrite_vouches.py replaces a
    pair)."""
    shutil.copyfile(w["poses"].with_suffix(".tum"), ws / "p.tum")
    return {}


def _setup_user_report_folder(report_json: bool):
    """ws/u: a user's folder holding files of the names evaluate writes (report.json too, if
    ``report_json``), none of them written by fieldloc."""
    def setup(w, ws):
        u = ws / "u"
        (u / "plots").mkdir(parents=True)
        (u / "errors.csv").write_text("mine\n")
        (u / "plots" / "trajectory.png").write_text("x")
        if report_json:
            (u / "report.json").write_text("mine\n")
        return {}
    return setup


def _attr(name: str, value):
    return lambda f: f.attrs.__setitem__(name, value)


def _replace(path: str, make):
    """Dataset ``path`` replaced by ``make(its values)``."""
    def change(f):
        new = make(f[path][()])
        del f[path]
        f[path] = new
    return change


def _subarray(path: str, each: tuple):
    """Dataset ``path`` replaced by one of as many rows whose every element is an array of
    shape ``each`` (an HDF5 array type, stored as such)."""
    def change(f):
        n = len(f[path])
        del f[path]
        f.create_dataset(path, shape=(n,), dtype=np.dtype(("<f8", each)))
    return change


def _corrupt_chunk(path: str):
    """Dataset ``path`` stored again gzip-compressed, its first chunk's bytes then overwritten
    (a damaged block of a file: the filter fails on reading it)."""
    def change(f):
        data = f[path][()]
        del f[path]
        d = f.create_dataset(path, data=data, chunks=data.shape, compression="gzip")
        offset, size = d.id.get_chunk_info(0).byte_offset, d.id.get_chunk_info(0).size
        name = f.filename
        f.flush()
        with open(name, "r+b") as raw:
            raw.seek(offset)
            raw.write(bytes(range(256)) * (size // 256 + 1))
    return change


def _extracted_then(change):
    """A dataset change: its features.h5 extracted, then ``change(ds)``."""
    def edit(ds):
        from stages import extract

        extract.main(None, ds, ds / "features.h5")
        change(ds)
    return edit


def _add_mask(ds):
    """A robot mask (all of the image seen) put into the dataset folder."""
    import cv2

    from stages.common.dataset import open_dataset

    w, h = open_dataset(ds).camera().image_size
    cv2.imwrite(str(ds / "mask.png"), np.full((h, w), 255, np.uint8))


def _as_jp2(ds):
    """Frame 000002's image renamed .jp2 (a kind fieldloc does not read), as frames.csv lists
    it."""
    os.replace(ds / "images" / "000002.png", ds / "images" / "000002.jp2")
    csv_path = ds / "frames.csv"
    csv_path.write_text(csv_path.read_text().replace("000002.png", "000002.jp2"))


def _as_bigtiff(ds):
    """Frame 000002's image replaced by a BigTIFF header (64-bit offsets) claiming 9000 x 9000
    px, as frames.csv lists it."""
    (ds / "images" / "000002.png").unlink()
    entries = b"".join(struct.pack("<HHQQ", tag, 4, 1, 9000) for tag in (256, 257))
    (ds / "images" / "000002.tif").write_bytes(
        b"II+\0" + struct.pack("<HHQ", 8, 0, 16) + struct.pack("<Q", 2) + entries
        + struct.pack("<Q", 0))
    csv_path = ds / "frames.csv"
    csv_path.write_text(csv_path.read_text().replace("000002.png", "000002.tif"))


def _as_group(path: str):
    """Dataset ``path`` replaced by an empty group."""
    def change(f):
        del f[path]
        f.create_group(path)
    return change


def _external(path: str):
    """Dataset ``path`` replaced by a link to the same name in another file beside it."""
    def change(f):
        other = Path(f.filename).with_name("elsewhere.h5")
        with h5py.File(other, "w") as g:
            g[path] = f[path][()]
        del f[path]
        f[path] = h5py.ExternalLink(other.name, path)
    return change


def _as_text(path: str):
    """Dataset ``path`` replaced by as many strings as it has rows."""
    return _replace(path, lambda d: np.array([b"abc"] * len(d)))


def _nan_first(path: str, value: float = math.nan):
    """The first value of dataset ``path`` NaN (or ``value``)."""
    def change(f):
        d = f[path][()]
        d.flat[0] = value
        f[path][...] = d
    return change


def _stamp_times(name: str, factor: float):
    """A dataset copy whose ``name`` CSV has its stamps multiplied by ``factor`` (as if in
    ms or ns)."""
    def change(ds: Path):
        lines = (ds / name).read_text().splitlines()
        col = lines[0].split(",").index("stamp")
        rows = [r.split(",") for r in lines[1:]]
        for r in rows:
            r[col] = repr(float(r[col]) * factor + factor)
        (ds / name).write_text("\n".join([lines[0], *(",".join(r) for r in rows)]) + "\n")
    return change


def _field_size_nan(ds: Path) -> None:
    rec = yaml.safe_load((ds / "simulation.yaml").read_text())
    rec["field_size"] = [math.nan, 1.0]
    (ds / "simulation.yaml").write_text(yaml.safe_dump(rec))


def _nulls(report: dict) -> None:
    for k in report:
        if k not in ("schema", "schema_version"):
            report[k] = None


def _setup_user_debug_folder(w, ws):
    """ws/dbg: a user's folder holding a copy of a dataset frame and a file of their own, under
    the names of the overlays extract --debug-images writes."""
    (ws / "dbg").mkdir()
    shutil.copyfile(w["omni"] / "images" / "000000.png", ws / "dbg" / "000000.png")
    (ws / "dbg" / "000001.png").write_text("mine")
    return {}


def _setup_user_debug_folder_with_record(w, ws):
    """ws/dbg: a user's notes and a debug-images.yaml extract did not write (trial U2,
    U2-13: the refusal said "(no debug-images.yaml)")."""
    (ws / "dbg").mkdir()
    (ws / "dbg" / "notes.txt").write_text("mine")
    (ws / "dbg" / "debug-images.yaml").write_text("a: 1\n")
    return {}


def _setup_debug_folder_made(w, ws):
    """ws/dbg: the overlays an earlier extract (into ws/f0.h5) wrote, with its marker."""
    extract.main(None, w["omni"], ws / "f0.h5", debug_images=ws / "dbg")
    return {}


def _check_overlays_redrawn(paths, res):
    dbg = paths["ws"] / "dbg"
    assert (dbg / extract.DEBUG_RECORD).is_file()
    assert sorted(p.name for p in dbg.glob("*.png")) == [f"{i:06d}.png" for i in range(4)]


def _setup_report_with_plots(w, ws):
    """A copy of the shared report whose plots are a link to /etc/passwd and an empty file."""
    shutil.copytree(w["omni"] / "runs" / "r", ws / "r")
    (ws / "r" / "plots").mkdir(exist_ok=True)
    os.symlink("/etc/passwd", ws / "r" / "plots" / "trajectory.png")
    (ws / "r" / "plots" / "error_cdf.png").write_bytes(b"")
    return {}


def _check_no_foreign_plot(paths, res):
    import base64

    page = (paths["ws"] / "r.html").read_text()
    assert "error_cdf.png not shown: not a PNG image" in page
    secret = base64.b64encode(Path("/etc/passwd").read_bytes()[:30]).decode()[:24]
    assert secret not in page


def _setup_simulated_with_notes(w, ws):
    """ws/data: a dataset simulate made, to which the user then added notes.txt."""
    simulate.main(dict(simulate.confs["omni-clean"], frames=1), "spl", ws / "data")
    (ws / "data" / "notes.txt").write_text("what I saw")
    return {}



# ---- s54 group H4: files and interruptions (setups and checks of its cases)
def _setup_simulated_with_picture(w, ws):
    """ws/data: a 1-frame dataset simulate made, to which the user added a picture in images/
    under a frame's name that the dataset does not have."""
    simulate.main(dict(simulate.confs["omni-clean"], frames=1), "spl", ws / "data")
    (ws / "data" / "images" / "000005.png").write_bytes(b"mine")
    return {}


def _setup_fifo(w, ws):
    os.mkfifo(ws / "fifo")
    return {}


def _setup_big_json(w, ws):
    """A (sparse) file larger than bench's bound of a --json file."""
    from stages.pipelines.bench.harness import MAX_JSON_BYTES

    with open(ws / "big.json", "wb") as f:
        f.truncate(MAX_JSON_BYTES + 1)
    return {}


def _check_one_summary_line(paths, res):
    """The summary of an output named with a line break stays one line."""
    assert len(res.stderr.strip().splitlines()) == 1, res.stderr



# s53 hostile2 F5-F7: simulate's scalar conf keys given a value outside their range
# (simulate.SCALAR_BOUNDS) through -c, refused in one line naming the key before anything is
# rendered: (key, value, the sweep's kind). F5 ended in tracebacks, F6 hung, F7 ran silently.
SIMULATE_SCALAR_FAULTS = [
    *[(k, v, "traceback") for k, v in (
        ("trajectory.accel_max", "0"), ("trajectory.lateral_accel_max", "0"),
        ("trajectory.yaw_accel_max", "-1"),
        *[(f"odometry.{k}", "-1") for k in (
            "scale_sigma", "rotation_scale_sigma", "slip_sigma", "slip_rotation", "noise_xy",
            "noise_theta", "collision_xy", "collision_theta")],
        *[(f"imu.{k}", "-1") for k in ("yaw_noise", "bias_sigma", "collision_yaw")],
        ("scene.texture_resolution", "-1"), ("scene.texture_resolution", "0"),
        ("scene.line_resolution", "-1"), ("scene.line_resolution", "0"),
        ("scene.line_resolution", "1e9"), ("scene.wall_height", "-1"),
        ("scene.wall_height", "0"), ("omni.viewpoint_height", "-1"),
        ("omni.viewpoint_height", "0"), ("omni.rim_radius", "-1"), ("omni.rim_radius", "0"),
        ("omni.outer_elevation_rate", "-1"), ("omni.outer_elevation_rate", "1e9"),
        ("omni.body_radius", "1e9"), ("omni.strut_width", "-1"), ("omni.strut_width", "0"),
        ("omni.strut_width", "1e9"), ("omni.polar_bearings", "-1"),
        ("omni.polar_bearings", "0"), ("omni.polar_step", "-1"), ("omni.polar_step", "0"),
        ("omni.polar_step", "1e9"), ("omni.imaging.chroma_subsample", "1e9"),
        ("perspective.head.bob_pitch", "1e9"), ("perspective.head.tilt", "1e9"),
        ("perspective.head.jitter", "-1"), ("perspective.head.measurement_noise", "-1"),
        ("perspective.imaging.exposure_time", "1e9"),
        ("perspective.imaging.chroma_subsample", "1e9"))],
    *[(k, "1e9", "hang") for k in (
        "trajectory.substeps", *[f"scene.{k}" for k in (
            "robots", "people", "balls", "cables", "sticks", "papers", "tapes", "audience",
            "sun_patches", "shadows")],
        "omni.rim_radius", "omni.polar_bearings", "omni.imaging.blur_sigma",
        "perspective.imaging.blur", "perspective.imaging.corner_blur")],
    *[(k, v, "silent") for k, v in (
        ("scene.robots", "-1"), ("imu.collision_rate_hz", "-1"), ("scene.line_wear", "-1"),
        ("odometry.drift", "-1"), ("imu.bias_walk", "-1"), ("scene.people", "-1"),
        ("scene.handlers", "-1"), ("scene.carpet_variation", "-1"), ("trajectory.margin", "-1"),
        ("trajectory.turn_rate_max", "-1"), ("trajectory.grid_spacing", "0"),
        ("trajectory.grid_headings", "0"), ("scene.goal_height", "-1"),
        ("omni.imaging.knee", "-1"), ("omni.imaging.saturation", "-1"),
        ("omni.imaging.jpeg_quality", "1e9"), ("omni.imaging.jpeg_quality", "-1"),
        ("omni.shadow_depth", "2"), ("perspective.head.walk_speed", "0"),
        ("perspective.head.turn_speed", "0"), ("perspective.head.step_hz", "-1"),
        ("perspective.intrinsics.cx", "-1"), ("perspective.sheen", "-1"),
        ("perspective.imaging.jpeg_quality", "101"), ("perspective.imaging.vignetting", "2"),
        # s53 leftovers: absurd values that ran
        ("trajectory.speed_max", "1e9"), ("trajectory.speed_min", "1e9"),
        ("calib_error.scale", "1e9"), ("calib_error.scale", "0.01"),
        ("calib_error.radius_error_length_px", "1e9"), ("calib_error.table_range", "1e9"))],
]
# keys held by the camera's own checks (camera_from_conf), with their own message
SCALAR_FRAGMENTS = {"perspective.intrinsics.cx": "the principal point cx, cy must lie in the image"}

# ------------------------------------------- s54 group H3: damaged artifacts' setups


def _fill(path: str, value: float):
    """Every value of dataset ``path`` set to ``value``."""
    def change(f):
        f[path][...] = np.full(f[path].shape, value, dtype=f[path].dtype)
    return change


def _setup_odometry_bag(odometry, imu=None, frame_stamps=(1.0, 1.1, 1.2, 1.3)):
    """ws/x.bag: 64 x 48 frames at ``frame_stamps``, odometry rows (stamp, x, y, yaw), IMU
    rows (stamp, yaw) as given (a value in them may be damaged)."""
    def setup(w, ws):
        from stages.ingest.bag_writer import write_bag

        img = np.zeros((48, 64, 3), np.uint8)
        write_bag(ws / "x.bag", "ros1", image_topic="/cam",
                  frames=[(t, (img, "bgr8")) for t in frame_stamps], odometry=odometry,
                  imu=imu)
        return {}
    return setup


GOOD_ODOMETRY = [(0.95 + 0.05 * i, 0.1 * i, 0.0, 0.01 * i) for i in range(9)]
GOOD_IMU = [(0.95 + 0.05 * i, 0.01 * i) for i in range(9)]
EVALUATE_MORE = ["--truth", "{omni}", "-o", W + "/rep"]
IMPORT_BAG = ["import", "rosbag", W + "/x.bag", "-o", W + "/ds", "--image-topic", "/cam",
              "--odom-topic", "/odom", "--imu-topic", "/imu"]


def _check_frames_written(ds: Path, n: int) -> None:
    """The imported dataset holds ``n`` frames, each an image file."""
    assert len((ds / "frames.csv").read_text().splitlines()) == n + 1
    assert len(list((ds / "images").iterdir())) == n


def _check_dataset_readable(paths, res):
    """The imported dataset is one the dataset's readers take, every value finite."""
    from stages.common.dataset import open_dataset, read_csv

    ds = paths["ws"] / "ds"
    open_dataset(ds)
    for name in ("odometry", "imu"):
        if (ds / f"{name}.csv").is_file():
            cols = read_csv(ds / f"{name}.csv", name)
            assert all(np.isfinite(v).all() for v in cols.values()), name


def _setup_other_stamps(w, ws):
    """ws/ds: the omni dataset with frame 000001 at another stamp than its features say."""
    ds = copy_dataset(w, "omni", ws)
    edit_csv(ds / "frames.csv", 3, "000001.png,0.050000")
    return {"ds": ds}


def _setup_report_edited(name: str, text: bytes | None):
    """ws/rep: a report evaluate wrote of the shared poses; then its ``name`` given ``text``
    appended (None: left as written)."""
    def setup(w, ws):
        from stages import evaluate

        evaluate.main(None, w["poses"], w["omni"], ws / "rep")
        if text is not None:
            (ws / "rep" / name).parent.mkdir(exist_ok=True)
            with open(ws / "rep" / name, "ab") as f:
                f.write(text)
        return {}
    return setup


def _setup_simulated_edited(name: str | None):
    """ws/data: a one-frame dataset simulate wrote; then its ``name`` edited (None: not)."""
    def setup(w, ws):
        simulate.main(dict(simulate.confs["omni-clean"], frames=1), "spl", ws / "data")
        if name is not None:
            with open(ws / "data" / name, "ab") as f:
                f.write(b"# mine\n")
        return {}
    return setup


def _setup_debug_folder_with_picture(w, ws):
    """ws/dbg: a folder extract's --debug-images made (its record), holding a user's picture
    under the name of frame 000000's overlay."""
    (ws / "dbg").mkdir()
    (ws / "dbg" / "debug-images.yaml").write_text("generator: fieldloc extract\n")
    (ws / "dbg" / "000000.png").write_bytes(b"my own picture")
    return {}


def _setup_imported_edited(change):
    """ws/ds: a dataset import rosbag wrote from ws/x.bag; then ``change(ds)``."""
    bag = _setup_odometry_bag(GOOD_ODOMETRY, GOOD_IMU)

    def setup(w, ws):
        bag(w, ws)
        res = CliRunner().invoke(cli, [a.format(ws=ws) for a in IMPORT_BAG])
        assert res.exit_code == 0, res.output
        change(ws / "ds")
        return {}
    return setup


# ------------------------------------------------- s55 group F5: setups


def _table_set(value):
    """A change of an importer's folder: its import.yaml's written_files set to ``value``
    (the key removed for "del": an older fieldloc's record)."""
    def change(ds):
        _set_written_files(ds / "import.yaml", value)
    return change


def _set_written_files(record: Path, value) -> None:
    """The YAML record ``record`` with its written_files set to ``value`` (removed for
    "del": an older fieldloc's record)."""
    rec = yaml.safe_load(record.read_text())
    if value == "del":
        rec.pop("written_files")
    else:
        rec["written_files"] = value
    record.write_text(yaml.safe_dump(rec, sort_keys=False))


def _f5_damaged_table(value):
    """A change of an imported folder: import.yaml's written_files set to ``value`` ("del":
    removed, an older record's), and a user's notes.txt added."""
    table = _table_set(value)

    def change(ds):
        table(ds)
        (ds / "notes.txt").write_text("mine")
    return change


def _setup_hulks_imported(value, extra: str | None):
    """ws/out: a dataset calibrate --from-hulks wrote from ws/hulks, its import.yaml's
    written_files set to ``value`` ("del": removed), and a user's file ``extra`` added."""
    def setup(w, ws):
        paths = _setup_team_files(w, ws)
        res = CliRunner().invoke(cli, ["calibrate", "perspective", "--from-hulks",
                                       str(ws / "hulks"), "-o", str(ws / "out")])
        assert res.exit_code == 0, res.output
        _table_set(value)(ws / "out")
        if extra is not None:
            (ws / "out" / extra).write_bytes(b"mine")
        return paths
    return setup


def _setup_simulated_frames_with_picture(n):
    """ws/data: a 1-frame dataset simulate made whose simulation.yaml's ``frames`` was damaged
    to ``n``, and a user's picture added under a frame-like name."""
    setup_record = _setup_record_of_frames(n)

    def setup(w, ws):
        setup_record(w, ws)
        shutil.copyfile(w["omni"] / "images" / "000003.png",
                        ws / "data" / "images" / "000009.png")
        return {}
    return setup


def _setup_report_plots_a_file(w, ws):
    """ws/rep: a report evaluate wrote of the shared poses, whose plots/ the user replaced by
    a file of that name."""
    from stages import evaluate

    evaluate.main(None, w["poses"], w["omni"], ws / "rep")
    shutil.rmtree(ws / "rep" / "plots", ignore_errors=True)
    (ws / "rep" / "plots").write_text("mine")
    return {}


# ------------------------------------------------- s56 group G1: setups


def _g1_same_size_edit(path: Path) -> None:
    """Change the last digit of ``path`` that is not a 9 (the file keeps its size)."""
    t = bytearray(path.read_bytes())
    i = max(i for i, c in enumerate(t) if chr(c).isdigit() and chr(c) != "9")
    t[i] += 1
    path.write_bytes(bytes(t))


def _g1_simulated_table(value, change):
    """ws/data: a one-frame dataset simulate wrote, its simulation.yaml's written_files set
    to ``value`` ("del": removed, an older simulate's record), then ``change(data)``."""
    def setup(w, ws):
        data = simulate.main(dict(simulate.confs["omni-clean"], frames=1), "spl", ws / "data")
        _set_written_files(data / "simulation.yaml", value)
        change(data)
        return {}
    return setup


def _g1_report_table(value, name):
    """ws/rep: a report evaluate wrote of the shared poses, its report.json's written_files
    set to ``value`` ("del": removed, an older evaluate's), then ``name`` edited (same size)."""
    def setup(w, ws):
        import json

        from stages import evaluate

        rep = evaluate.main(None, w["poses"], w["omni"], ws / "rep")
        rec = json.loads((rep / "report.json").read_text())
        if value == "del":
            rec.pop("written_files")
        else:
            rec["written_files"] = value
        (rep / "report.json").write_text(json.dumps(rec))
        _g1_same_size_edit(rep / name)
        return {}
    return setup


def _g1_overlay_edited_keeping_mark(w, ws):
    """ws/dbg: the overlays an earlier extract drew; 000001.png then painted on by an editor
    that keeps the PNG's text chunks (fieldloc's mark)."""
    from PIL import Image, ImageDraw, PngImagePlugin

    extract.main(None, w["omni"], ws / "f0.h5", debug_images=ws / "dbg")
    png = ws / "dbg" / "000001.png"
    im = Image.open(png)
    im.load()
    info = PngImagePlugin.PngInfo()
    for k, v in im.text.items():
        info.add_text(k, v)
    ImageDraw.Draw(im).rectangle([10, 10, 60, 60], fill=(255, 0, 0))
    im.save(png, pnginfo=info)
    return {}


def _g1_twin(change):
    """ws/p.h5 and ws/p.tum: a copy of the shared poses and their twin; then
    ``change(ws)``."""
    def setup(w, ws):
        shutil.copyfile(w["poses"], ws / "p.h5")
        shutil.copyfile(Path(w["poses"]).with_suffix(".tum"), ws / "p.tum")
        change(ws)
        return {}
    return setup


def _g1_note_below_header(ws):
    lines = (ws / "p.tum").read_text().splitlines(keepends=True)
    (ws / "p.tum").write_text(lines[0] + "# my note\n" + "".join(lines[1:]))


def _g1_users_copy_without_poses(ws):
    (ws / "p.h5").unlink()
    head = (ws / "p.tum").read_text().splitlines()[0]
    (ws / "p.tum").write_text(head + "\n1 2 3 0 0 0 0 1 my data\n")

# ---- s56 group G2: the setups of its cases (features of another recording, frames of other
# image kinds, a PNG damaged under right CRCs)


def _setup_other_recording(w, ws):
    """ws/ds: another simulated omni recording, its frames named and stamped as the shared
    dataset's (every simulated dataset's are: 000000.png at 0 s, ...)."""
    ds = simulate.main(dict(simulate.confs["omni-default"], frames=4, seed=1864), "spl",
                       ws / "ds")
    return {"ds": ds}


def _setup_reencoded(w, ws):
    """ws/ds: the shared omni dataset with frame 000001 written again (the same pixels, other
    bytes: another image than the one its features were extracted from)."""
    ds = copy_dataset(w, "omni", ws)
    p = ds / "images" / "000001.png"
    cv2.imwrite(str(p), cv2.imread(str(p)), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    return {"ds": ds}


def _setup_cut_to_two(w, ws):
    """ws/ds: the shared omni dataset cut to its first two frames (after its extraction)."""
    ds = copy_dataset(w, "omni", ws)
    for name in ("000002.png", "000003.png"):
        (ds / "images" / name).unlink()
    (ds / "frames.csv").write_text("name,stamp\n" + "".join(
        line + "\n" for line in (ds / "frames.csv").read_text().splitlines()[1:3]))
    return {"ds": ds}


def _check_two_frames(paths, res):
    columns, _attrs = read_poses(paths["ws"] / "p.h5")
    assert sorted(set(columns["name"])) == ["000000", "000001"]


def _setup_frame_as(suffix: str):
    """ws/ds: the shared omni dataset whose frame 000001 is a ``suffix`` file (a .gif: a kind
    fieldloc does not read), named so in frames.csv."""
    def setup(w, ws):
        from PIL import Image

        ds = copy_dataset(w, "omni", ws)
        png_path = ds / "images" / "000001.png"
        img = cv2.imread(str(png_path))
        png_path.unlink()
        if suffix == ".gif":
            Image.fromarray(img[..., ::-1]).save(ds / "images" / "000001.gif")
        else:
            cv2.imwrite(str(ds / "images" / f"000001{suffix}"), img)
        frames = ds / "frames.csv"
        frames.write_text(frames.read_text().replace("000001.png", f"000001{suffix}"))
        return {"ds": ds}
    return setup


def _check_frames_extracted(n: int):
    def check(paths, res):
        from stages.common.features_file import FeaturesFile

        with FeaturesFile(paths["ws"] / "f.h5") as ff:
            assert len(ff.names) == n
    return check


def _setup_idat_damaged_crc_right(w, ws):
    """ws/ds: the shared omni dataset whose frame 000001's IDAT data is damaged under right
    CRCs (libpng printed "libpng error: bad adaptive filter value" of it)."""
    import struct
    import zlib

    ds = copy_dataset(w, "omni", ws)
    p = ds / "images" / "000001.png"
    data = p.read_bytes()
    at = data.index(b"IDAT")
    length = struct.unpack(">I", data[at - 4:at])[0]
    body = bytearray(data[at + 4:at + 4 + length])
    for i in range(len(body) // 3, len(body) // 3 + 30):
        body[i] ^= 0x5A
    chunk = b"IDAT" + bytes(body)
    p.write_bytes(data[:at] + chunk + struct.pack(">I", zlib.crc32(chunk))
                  + data[at + 8 + length:])
    return {"ds": ds}


# ------------------------------------------------- s56 group W1: setups


def _w1_note(record: Path, how: str) -> None:
    """A user's note written into the fieldloc record ``record``: a comment line appended
    ("comment", YAML), a key of its own as the first line ("key", YAML), or a key added to
    the JSON object ("key", report.json)."""
    import json

    if record.suffix == ".json":
        data = json.loads(record.read_text())
        data["my_notes"] = "keep me"
        record.write_text(json.dumps(data, indent=2) + "\n")
    elif how == "comment":
        record.write_text(record.read_text() + "# my notes: camera was tilted\n")
    else:
        record.write_text("my_notes: keep me\n" + record.read_text())


def _w1_self_entry_removed(record: Path) -> None:
    """``record`` as an older fieldloc wrote it: a written_files table without an entry for
    the record itself."""
    rec = yaml.safe_load(record.read_text())
    rec["written_files"].pop(record.name)
    record.write_text(yaml.safe_dump(rec, sort_keys=False))


def _w1_simulated(change):
    """ws/data: a one-frame dataset simulate wrote; then ``change(its simulation.yaml)``."""
    def setup(w, ws):
        data = simulate.main(dict(simulate.confs["omni-clean"], frames=1), "spl", ws / "data")
        change(data / "simulation.yaml")
        return {}
    return setup


def _w1_hulks_imported(how: str):
    """ws/out: a dataset calibrate --from-hulks wrote from ws/hulks; then a user's note in
    its import.yaml."""
    def setup(w, ws):
        paths = _setup_team_files(w, ws)
        res = CliRunner().invoke(cli, ["calibrate", "perspective", "--from-hulks",
                                       str(ws / "hulks"), "-o", str(ws / "out")])
        assert res.exit_code == 0, res.output
        _w1_note(ws / "out" / "import.yaml", how)
        return paths
    return setup


def _w1_debug_images(how: str):
    """ws/dbg: the overlays an earlier extract drew; then a user's note in the folder's
    debug-images.yaml."""
    def setup(w, ws):
        extract.main(None, w["omni"], ws / "f0.h5", debug_images=ws / "dbg")
        _w1_note(ws / "dbg" / "debug-images.yaml", how)
        return {}
    return setup


def _w1_report(w, ws):
    """ws/rep: a report evaluate wrote of the shared poses; then a key of the user's in its
    report.json."""
    from stages import evaluate

    evaluate.main(None, w["poses"], w["omni"], ws / "rep")
    _w1_note(ws / "rep" / "report.json", "key")
    return {}


def _j_frame_as(ds: Path, name: str, suffix: str, data: bytes) -> None:
    """Frame ``name`` of ``ds`` replaced by the image file ``data`` of ``suffix``."""
    (ds / "images" / f"{name}.png").unlink()
    (ds / "images" / f"{name}.{suffix}").write_bytes(data)
    frames = ds / "frames.csv"
    frames.write_text(frames.read_text().replace(f"{name}.png", f"{name}.{suffix}"))


def _j_damaged_first_frame(ds: Path) -> None:
    """Frame 000000 of ``ds`` as a JPEG file whose scan data is damaged (libjpeg printed
    "Corrupt JPEG data: 4682 extraneous bytes before marker 0xd9" and decoded garbage). Skips
    the case where simplejpeg is not installed (a Python it has no wheel for)."""
    from test_jpeg_and_image_headers import damaged_scan

    pytest.importorskip("simplejpeg")

    ok, data = cv2.imencode(".jpg", cv2.imread(str(ds / "images" / "000000.png")))
    _j_frame_as(ds, "000000", "jpg", damaged_scan(data.tobytes()))


def _j_claiming(kind: str, width: int, height: int):
    def change(ds: Path) -> None:
        from test_jpeg_and_image_headers import claiming

        _j_frame_as(ds, "000002", kind, claiming(kind, width, height))
    return change


def _j_first_image_deleted(w, ws):
    ds = copy_dataset(w, "omni", ws)
    (ds / "images" / "000000.png").unlink()
    return {"ds": ds}


def _k_jpeg(img: np.ndarray, kind: str) -> bytes:
    """Frame ``img`` (BGR) as one of trial F's JPEG files that went to OpenCV's libjpeg whole
    (tests/test_jpeg_and_image_headers.py makes them): "cmyk" a CMYK file whose scan is
    damaged (J1); "jfif", "adobe", "sos" a header libjpeg warns of, the scan behind it cut short
    or damaged (J2); "marker" an unknown marker in the scan (J4); "xmp-exif6" an XMP APP1 before
    the EXIF APP1 of orientation 6 (J3); "segments" more empty segments than MAX_SEGMENTS
    (P1)."""
    from test_jpeg_and_image_headers import (
        EXIF_LAYOUTS,
        as_cmyk,
        damaged_scan,
        segment,
        with_header_warning,
        with_marker_in_scan,
    )

    from stages.common.jpeg import MAX_SEGMENTS

    plain = cv2.imencode(".jpg", img)[1].tobytes()
    if kind == "cmyk":
        return damaged_scan(as_cmyk(img))
    if kind == "jfif":
        data = with_header_warning(plain, kind)
        return data[:len(data) // 2] + b"\xff\xd9"
    if kind in ("adobe", "sos"):
        return damaged_scan(with_header_warning(plain, kind))
    if kind == "marker":
        return with_marker_in_scan(plain)
    if kind == "xmp-exif6":
        payloads = EXIF_LAYOUTS["xmp then exif 6"]
        return plain[:2] + b"".join(segment(0xE1, p) for p in payloads) + plain[2:]
    assert kind == "segments"
    return plain[:2] + segment(0xE2, b"") * (MAX_SEGMENTS + 1) + plain[2:]


def _k_frame(name: str, kind: str):
    """A dataset change: frame ``name`` as ``_k_jpeg``'s file of ``kind``, or ("png-exif6") as
    a PNG whose eXIf chunk gives orientation 6 (J5)."""
    def change(ds: Path) -> None:
        from test_jpeg_and_image_headers import with_exif_chunk

        pytest.importorskip("simplejpeg")
        png = (ds / "images" / f"{name}.png").read_bytes()
        if kind == "png-exif6":
            (ds / "images" / f"{name}.png").write_bytes(with_exif_chunk(png, 6))
            return
        img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
        _j_frame_as(ds, name, "jpg", _k_jpeg(img, kind))
    return change


def _check_all_frames_extracted(paths, res):
    """The frame with an EXIF Orientation was extracted: read as stored, the size the
    calibration gives, not turned to 480 x 752 px and skipped (trial U2, U2-4)."""
    from stages.common.features_file import FeaturesFile

    assert "failed" not in res.output and "skipped" not in res.output, res.output
    with FeaturesFile(paths["ws"] / "f.h5") as ff:
        assert "000001" in ff.names


def _u2_head_stamps_far(ds: Path) -> None:
    """head.csv's stamps moved by 1e6 s, far from every frame's (trial U2, U2-7)."""
    lines = (ds / "head.csv").read_text().splitlines()
    moved = [f"{float(s) + 1e6:.6f},{rest}" for s, _c, rest in
             (line.partition(",") for line in lines[1:])]
    (ds / "head.csv").write_text("\n".join([lines[0], *moved]) + "\n")


def _k_cmyk_mask(ds: Path) -> None:
    """The dataset's mask.png (frame-sized) as a CMYK JPEG file whose scan is damaged (J1)."""
    pytest.importorskip("simplejpeg")
    img = np.full((480, 480, 3), 255, np.uint8)
    cv2.circle(img, (240, 240), 60, (0, 0, 0), -1)
    (ds / "mask.png").write_bytes(_k_jpeg(img, "cmyk"))


def _stems_listed_one_deleted(stem_of, deleted: int):
    """A setup: ws/omni with its frames renamed to ``stem_of(i)`` + .png (a dot inside the
    stem), frames.csv listing the stems, frame ``deleted``'s image deleted."""
    def setup(w, ws):
        ds = copy_dataset(w, "omni", ws)
        rows = ["name,stamp"]
        for i in range(4):
            (ds / "images" / f"{i:06d}.png").rename(ds / "images" / f"{stem_of(i)}.png")
            rows.append(f"{stem_of(i)},{i / 10:.1f}")
        (ds / "frames.csv").write_text("\n".join(rows) + "\n")
        (ds / "images" / f"{stem_of(deleted)}.png").unlink()
        return {"ds": ds}
    return setup


# frames named like timestamps (1687078170.100.png), the first image deleted (trial F)
_l_dotted_stems_first_deleted = _stems_listed_one_deleted(lambda i: f"1687078170.{i + 1}00", 0)
# frames named f0.v2.png .. (a dot and letters in the stem), f1.v2.png deleted (trial H: taken
# for a file of kind "v2", it took no position)
_h_stems_with_a_dot_second_deleted = _stems_listed_one_deleted(lambda i: f"f{i}.v2", 1)


def _l_deleted_frame_listed_twice(w, ws):
    """ws/omni with 000000.png deleted and frames.csv listing it twice: by its file name and
    by its stem."""
    ds = copy_dataset(w, "omni", ws)
    (ds / "images" / "000000.png").unlink()
    with open(ds / "frames.csv", "a") as f:
        f.write("000000,0.000000\n")
    return {"ds": ds}


def _g_listed_by_name_and_stem(w, ws):
    """ws/omni with frames.csv listing frame 000003 twice, by its file name (line 5, at
    0.3 s) and by its stem (line 6) at another stamp."""
    ds = copy_dataset(w, "omni", ws)
    with open(ds / "frames.csv", "a") as f:
        f.write("000003,0.350000\n")
    return {"ds": ds}


def _rows_after_frame_0(name: str, rows: list[str]):
    """ws/<name> with ``rows`` (name,stamp) in frames.csv after frame 000000's, none of them
    a file."""
    def setup(w, ws):
        ds = copy_dataset(w, name, ws)
        lines = (ds / "frames.csv").read_text().splitlines()
        lines[2:2] = rows
        (ds / "frames.csv").write_text("\n".join(lines) + "\n")
        return {"ds": ds}
    return setup


def _g_rows_of_no_frame(name: str):
    """ws/<name> with frames.csv rows after frame 000000's that name no frame and no file:
    a text file, a .gif (a kind fieldloc does not read) and a .jpg among PNG frames, each
    sorting before frame 000001."""
    return _rows_after_frame_0(name, ["000000b.txt,0.01", "000000c.gif,0.02",
                                      "000000d.jpg,0.03"])


def _g_deleted_frame_in_a_folder(w, ws):
    """ws/omni with 000000.png deleted and frames.csv naming it in a folder (sub/000000.png)."""
    ds = copy_dataset(w, "omni", ws)
    (ds / "images" / "000000.png").unlink()
    edit_csv(ds / "frames.csv", 2, "sub/000000.png,0.000000")
    return {"ds": ds}


def _h_folder_row(row: str):
    """ws/omni with a frames.csv row after frame 000000's naming a folder (``row``), which
    was taken for a deleted frame with an empty or folder name (trial H)."""
    return _rows_after_frame_0("omni", [f"{row},0.01"])


def _i_second_frame_deleted_listed_as(row: str):
    """ws/omni with 000001.png deleted and frames.csv listing it as ``row`` in a folder: with
    a backslash (cam\\000001.png) it became a missing frame named cam\\000001 that sorted
    last, and its message named a path built from the row (trial I)."""
    return _with_ds("omni", lambda ds: ((ds / "images" / "000001.png").unlink(),
                                        edit_csv(ds / "frames.csv", 3, f"{row},0.100000")))


def _i_rows_in_images_backslash(ds):
    """Every frames.csv row of ``ds`` as images\\<file name> (a frames.csv written on
    Windows)."""
    frames = ds / "frames.csv"
    head, *rows = frames.read_text().splitlines()
    frames.write_text("\n".join([head, *(f"images\\{r}" for r in rows)]) + "\n")


def _j_rows_on_drive_c(ds):
    """Every frames.csv row of ``ds`` as C:<file name> (a Windows drive-relative path, no
    separator): each was a deleted frame C:000000 .., and image 000000.png had "no stamp"
    naming no line (trial J)."""
    frames = ds / "frames.csv"
    head, *rows = frames.read_text().splitlines()
    frames.write_text("\n".join([head, *(f"C:{r}" for r in rows)]) + "\n")


def _j_recording(held: str):
    """ws/rec, a recording: a copy of the shared omni dataset (``held`` "frames.csv"), or a
    folder holding only images/ with one frame (``held`` "images/"); a batch SPEC of the
    shared omni dataset and a copy b.h5 of the shared poses beside it."""
    def setup(w, ws):
        _copy(w["poses"], ws / "b.h5")
        (ws / "spec.yaml").write_text(f"map: {w['map']}\ndatasets: [{{path: {w['omni']}}}]\n"
                                      "methods: [lut]\n")
        if held == "frames.csv":
            return {"rec": copy_dataset(w, "omni", ws)}
        (ws / "rec" / "images").mkdir(parents=True)
        _copy(Path(w["omni"]) / "images" / "000000.png", ws / "rec" / "images" / "000000.png")
        return {"rec": ws / "rec"}
    return setup


def _j_poses_in_dataset(w, ws):
    """ws/omni, a copy of the shared dataset, with the shared run's poses.h5 in it."""
    ds = copy_dataset(w, "omni", ws)
    _copy(w["poses"], ds / "poses.h5")
    return {"ds": ds}


def _check_report_beside_the_poses(paths, res):
    """evaluate without -o wrote its report into a new folder beside the poses file, and no
    file among the recording's own."""
    ds = Path(paths["ds"])
    assert (ds / "poses-eval" / "report.json").is_file()
    assert not any((ds / n).exists() for n in ("report.json", "errors.csv", "plots"))


def _i_hidden_image_listed(w, ws):
    """ws/omni with a hidden file images/.png (a copy of 000000.png) and a frames.csv row
    .png after frame 000000's: it was a deleted frame ".png" at position 0 (trial I)."""
    paths = _rows_after_frame_0("omni", [".png,0.01"])(w, ws)
    shutil.copy(paths["ds"] / "images" / "000000.png", paths["ds"] / "images" / ".png")
    return paths


def _i_image_listed_in_another_case(ds):
    """``ds`` with frame 000000's image renamed a0.png and frames.csv listing it as A0.png."""
    (ds / "images" / "000000.png").rename(ds / "images" / "a0.png")
    edit_csv(ds / "frames.csv", 2, "A0.png,0.000000")


def _check_drew(frame: str):
    """A show command's check: it said it drew frame ``frame``."""
    def check(paths, res):
        assert f"b.png: frame {frame}, " in res.output, res.output
    return check


def _h_jpg_frame_deleted(w, ws):
    """ws/omni with frames 000001 and 000003 as JPG files among the PNG ones, 000001.jpg
    deleted."""
    ds = copy_dataset(w, "omni", ws)
    for i in (1, 3):
        png = ds / "images" / f"{i:06d}.png"
        cv2.imwrite(str(png.with_suffix(".jpg")), cv2.imread(str(png)))
        png.unlink()
        frames = ds / "frames.csv"
        frames.write_text(frames.read_text().replace(png.name, png.with_suffix(".jpg").name))
    (ds / "images" / "000001.jpg").unlink()
    return {"ds": ds}


def _l_perspective_first_frame_failed(w, ws):
    """ws/kid with frame 000000's image junk, and ws/f.h5 extracted from it (000000 failed,
    so only 000001 is in it)."""
    ds = copy_dataset(w, "kid", ws)
    (ds / "images" / "000000.png").write_bytes(b"junk")
    extract.main(None, ds, ws / "f.h5")
    return {"ds": ds}


def _l_report_with_a_repeated_key(w, ws):
    """ws/rep: a report evaluate wrote; then a user's note as a first "schema" key before
    fieldloc's (json keeps the last of a repeated key: the parsed report is unchanged)."""
    from stages import evaluate

    evaluate.main(None, w["poses"], w["omni"], ws / "rep")
    rec = ws / "rep" / "report.json"
    text = rec.read_text()
    rec.write_text(text.replace('  "schema"', '  "schema": "MY NOTE: redo, camera tilted",\n'
                                '  "schema"', 1))
    return {}


CASES = [
    # ------------------------------------------------------------------ data lost
    Case("localize -o the map --overwrite", "data-lost",
         [*LOCALIZE, "-o", "{map}", "--overwrite"], 1, "is an input of this command (map)"),
    Case("localize -o a symlink to the map --overwrite", "data-lost",
         [*LOCALIZE, "-o", W + "/link.h5", "--overwrite"], 1,
         "is an input of this command (map)", setup=_link_to("map", symbolic=True)),
    Case("localize -o a hard link to the features --overwrite", "data-lost",
         [*LOCALIZE, "-o", W + "/link.h5", "--overwrite"], 1,
         "is an input of this command (features)", setup=_link_to("features", symbolic=False)),
    Case("localize -o the features --overwrite", "data-lost",
         [*LOCALIZE, "-o", "{features}", "--overwrite"], 1, "input of this command (features)"),
    Case("localize -o a dataset CSV --overwrite", "data-lost",
         [*LOCALIZE, "-o", "{omni}/truth.csv", "--overwrite"], 1, "(truth.csv)"),
    Case("localize -o X.h5 whose X.tum is the points file", "data-lost",
         ["localize", "{omni}", "--map", "{map}", "--points", W + "/p.tum", "-o", W + "/p.h5"],
         1, "(points)", setup=lambda w, ws: _points_csv(w, ws, range(4), file_name="p.tum")),
    Case("extract -o DIR/calib.yaml --overwrite", "data-lost",
         ["extract", "{omni}", "-o", "{omni}/calib.yaml", "--overwrite"], 1, "(calib.yaml)"),
    Case("extract -o a dataset image --overwrite", "data-lost",
         ["extract", "{omni}", "-o", "{omni}/images/000001.png", "--overwrite"], 1, "(images)"),
    Case("extract --debug-images into the images folder", "data-lost",
         ["extract", "{omni}", "-o", W + "/f.h5", "--debug-images", "{omni}/images"], 1,
         "(dataset image)"),
    Case("build-map f.yaml -o f.yaml --overwrite", "data-lost",
         ["build-map", "{field_yaml}", "-o", "{field_yaml}", "--overwrite"], 1, "(field)"),
    Case("calibrate omni marks.csv -o marks.csv --overwrite", "data-lost",
         ["calibrate", "omni", "{marks}", "-o", "{marks}", "--centre", "240", "240",
          "--image-size", "480", "480", "--valid-radius", "40", "230", "--overwrite"], 1,
         "(points)"),
    Case("calibrate --from-minho DIR -o DIR/mirror.cfg --overwrite", "data-lost",
         ["calibrate", "omni", "--from-minho", "{minho}", "-o", "{minho}/mirror.cfg",
          "--image-size", "480", "480", "--overwrite"], 1, "(the MINHO folder)"),
    Case("show map m.h5 -o m.h5", "data-lost", ["show", "map", "{map}", "-o", "{map}"], 1,
         "(map)"),
    Case("show map m.h5 -o m.h5 --overwrite", "data-lost",
         ["show", "map", "{map}", "-o", "{map}", "--overwrite"], 1, "(map)"),
    Case("show points -o a dataset frame", "data-lost",
         ["show", "points", "{omni}", "--frame", "0", "--features", "{features}", "-o",
          "{omni}/images/000000.png", "--overwrite"], 1, "(images)"),
    Case("show map -o an existing picture", "data-lost",
         ["show", "map", "{map}", "-o", "{note}"], 1, "exists (use --overwrite"),
    Case("show belief -o the map --overwrite", "data-lost",
         ["show", "belief", "{kid}", "--frame", "0", "--map", "{kmap}", "--features",
          "{kid_features}", "-o", "{kmap}", "--overwrite"], 1, "(map)"),
    Case("evaluate -o DIR/truth.csv --overwrite", "data-lost",
         ["evaluate", "{poses}", "--truth", "{omni}", "-o", "{omni}/truth.csv", "--overwrite"],
         1, "is an input of this command (truth)"),
    Case("evaluate -o the folder of the poses file named report.json", "data-lost",
         ["evaluate", W + "/report.json", "--truth", "{omni}", "-o", W, "--overwrite"], 1,
         "(poses)", setup=lambda w, ws: _copy(w["poses"], ws / "report.json")),
    Case("simulate --overwrite onto a user's folder", "data-lost",
         ["simulate", "omni", "--field", "spl", "-o", W + "/thesis", "--frames", "1",
          "--overwrite"], 1, "not a dataset made by fieldloc simulate",
         setup=_simulated_folder_with("thesis")),
    Case("simulate --overwrite onto the folder holding the field YAML", "data-lost",
         ["simulate", "omni", "--field", W + "/data/field.yaml", "-o", W + "/data",
          "--frames", "1", "--overwrite"], 1, "holds an input of this command (field YAML",
         setup=_simulated_folder_with("field")),
    Case("build-map onto an existing file", "data-lost",
         ["build-map", "spl", "-o", "{note}"], 1, "exists (use --overwrite"),
    Case("bench --json onto an existing file", "data-lost",
         ["bench", "--only", "none", "--json", "{note}"], 1, "exists (use --overwrite"),
    # ------------------------------------------------------------------ tracebacks
    Case("calib valid_radius [300, 100]", "traceback",
         ["extract", W + "/omni", "-o", W + "/f.h5"], 1, "'valid_radius' needs 0 <= RMIN < RMAX",
         setup=_with_ds("omni", lambda ds: edit_calib(ds, valid_radius=[300, 100]))),
    Case("calib valid_radius a ring narrower than a pixel", "traceback",
         ["extract", W + "/omni", "-o", W + "/f.h5"], 1, "is a ring narrower than 1 px",
         setup=_with_ds("omni", lambda ds: edit_calib(ds, valid_radius=[40, 40.0000001]))),
    Case("calibrate --valid-radius narrower than a pixel writes nothing", "silent",
         ["calibrate", "omni", "{marks}", "-o", W + "/c.yaml", "--centre", "240", "240",
          "--image-size", "480", "480", "--valid-radius", "40", "40.5"], 1,
         "is a ring narrower than 1 px"),
    Case("perspective calib pitch in degrees", "silent",
         ["extract", W + "/kid", "-o", W + "/f.h5"], 1,
         "'pitch' must be an angle in radians within [-pi, pi], got 25 (degrees?)",
         setup=_with_ds("kid", lambda ds: edit_calib(ds, pitch=25.0))),
    Case("perspective calib height in millimetres", "silent",
         ["extract", W + "/kid", "-o", W + "/f.h5"], 1, "'height' must be >= 0.001 and <= 10 m",
         setup=_with_ds("kid", lambda ds: edit_calib(ds, height=550.0))),
    Case("head.csv pitch in degrees", "silent",
         ["extract", W + "/kid", "-o", W + "/f.h5"], 1,
         "head.csv: line 3: pitch 25 is not within [-1.5708, 1.5708] rad",
         setup=_with_ds("kid", lambda ds: edit_csv(ds / "head.csv", 3, "0.1,25,0"))),
    # trial U2 (U2-8, U2-7): a head turned beyond a quarter turn; head.csv of other stamps
    *[Case(f"head.csv {what} beyond a quarter turn", "silent",
           ["extract", W + "/kid", "-o", W + "/f.h5"], 1,
           f"head.csv: line 2: {what} is not within [-1.5708, 1.5708] rad (beyond a quarter"
           " turn the camera faces the sky, or is upside down)",
           setup=_with_ds("kid", lambda ds, row=row: edit_csv(ds / "head.csv", 2, row)))
      for what, row in (("pitch 1.6", "0,1.6,0"), ("pitch -1.6", "0,-1.6,0"),
                        ("roll 3.14", "0,0.1,3.14"))],
    Case("head.csv stamps far from every frame's", "silent",
         ["extract", W + "/kid", "-o", W + "/f.h5"], 0,
         "2 of 2 frames have no head.csv row within 0.05 s: the frame stamps (from frames.csv,"
         " 0..0.1 s) and head.csv (1000000..1000000.1 s) do not meet",
         setup=_with_ds("kid", _u2_head_stamps_far)),
    Case("omni calib forward_angle in degrees", "silent",
         ["extract", W + "/omni", "-o", W + "/f.h5"], 1,
         "'forward_angle' must be an angle in radians within [-2 pi, 2 pi], got 90 (degrees?)",
         setup=_with_ds("omni", lambda ds: edit_calib(ds, forward_angle=90.0))),
    Case("calib decreasing polynomial", "traceback",
         ["extract", W + "/omni", "-o", W + "/f.h5"], 1, "is not increasing over 'valid_radius'",
         setup=_with_ds("omni", lambda ds: edit_calib(
             ds, polynomial=[5.0, -0.01, 0.0, 0.0, 0.0, 0.0]))),
    Case("calib 3-coefficient polynomial", "traceback",
         ["extract", W + "/omni", "-o", W + "/f.h5"], 1, "six coefficients a0..a5",
         setup=_with_ds("omni", lambda ds: edit_calib(ds, polynomial=[0.0, 0.01, 1e-5]))),
    Case("calib image_size [-480, 0]", "traceback",
         ["extract", W + "/omni", "-o", W + "/f.h5"], 1, "'image_size' must be [width, height]",
         setup=_with_ds("omni", lambda ds: edit_calib(ds, image_size=[-480, 0]))),
    Case("calib mirrored: 'no' (a string)", "traceback",
         ["extract", W + "/omni", "-o", W + "/f.h5"], 1, "'mirrored' must be true or false",
         setup=_with_ds("omni", lambda ds: edit_calib(ds, mirrored="no"))),
    Case("perspective calib with fx at the top level", "traceback",
         ["extract", W + "/kid", "-o", W + "/f.h5"], 1, "go under 'intrinsics:'",
         setup=_with_ds("kid", lambda ds: edit_calib(ds, fx=330.0))),
    Case("images of another size than calib.yaml", "traceback",
         ["extract", W + "/omni", "-o", W + "/f.h5"], 1, "calibration expects 480 x 480",
         setup=_setup_wrong_size),
    Case("odometry.csv with NaN (lut)", "traceback",
         [*LOCALIZE[:1], W + "/omni", *LOCALIZE[2:], "-o", W + "/p.h5"], 1,
         "odometry.csv: line 3: 'dx' is nan",
         setup=_with_ds("omni", lambda ds: edit_csv(ds / "odometry.csv", 3, "0.1,nan,0,0"))),
    Case("odometry.csv with inf (lut)", "traceback",
         [*LOCALIZE[:1], W + "/omni", *LOCALIZE[2:], "-o", W + "/p.h5"], 1, "'dtheta' is inf",
         setup=_with_ds("omni", lambda ds: edit_csv(ds / "odometry.csv", 4, "0.2,0,0,inf"))),
    Case("odometry.csv with NaN (mcl)", "traceback",
         ["localize", W + "/kid", "--map", "{kmap}", "--features", "{kid_features}",
          "--method", "mcl", "-o", W + "/p.h5"], 1, "line 2: 'dy' is nan",
         setup=_with_ds("kid", lambda ds: edit_csv(ds / "odometry.csv", 2, "0.0,0,nan,0"))),
    Case("odometry stamps out of order", "traceback",
         [*LOCALIZE[:1], W + "/omni", *LOCALIZE[2:], "-o", W + "/p.h5"], 1,
         "line 4: stamp 0.05 is before line 3's stamp 0.1",
         setup=_with_ds("omni", lambda ds: edit_csv(ds / "odometry.csv", 4, "0.05,0,0,0"))),
    Case("imu stamps repeated", "traceback",
         [*LOCALIZE[:1], W + "/omni", *LOCALIZE[2:], "-o", W + "/p.h5"], 1,
         "stamp 0.1 repeats line 3's stamp",
         setup=_with_ds("omni", lambda ds: edit_csv(ds / "imu.csv", 4, "0.1,0,0"))),
    Case("truth.csv row with a missing column", "traceback",
         ["evaluate", "{poses}", "--truth", W + "/omni", "-o", W + "/rep"], 1,
         "line 3: expected 4 values",
         setup=_with_ds("omni", lambda ds: edit_csv(ds / "truth.csv", 3, "0.1,0.5,0.2"))),
    Case("evaluate --truth poses.h5", "traceback",
         ["evaluate", "{poses}", "--truth", "{poses}", "-o", W + "/rep"], 1,
         "not a text CSV file"),
    Case("evaluate -o into a folder the system refuses", "traceback",
         ["evaluate", "{poses}", "--truth", "{omni}", "-o", "/sys/fieldloc-report"], 1,
         "/sys/fieldloc-report"),
    Case("extract -o DIR/calib.yaml/f.h5", "traceback",
         ["extract", "{omni}", "-o", "{omni}/calib.yaml/f.h5"], 1, "is a file, not a folder"),
    Case("build-map -o into a folder that does not exist", "traceback",
         ["build-map", "spl", "-o", W + "/no/such/m.h5"], 1, "does not exist"),
    Case("field length: 1e5 (build-map)", "traceback",
         ["build-map", W + "/f.yaml", "-o", W + "/m.h5"], 1,
         "key 'length' is 100000.0 m, not a soccer field's (1-40 m)",
         setup=_setup_field({"length": 100000.0})),
    Case("field length: 1e5 (simulate)", "traceback",
         ["simulate", "omni", "--field", W + "/f.yaml", "-o", W + "/sim", "--frames", "1"], 1,
         "key 'length' is 100000.0 m, not a soccer field's (1-40 m)",
         setup=_setup_field({"length": 100000.0})),
    *[Case(f"build-map of a field whose {what} (trial O1, O2: 106 s and 2.7 GB at 4 km)",
           "hang", ["build-map", W + "/f.yaml", "-o", W + "/m.h5"], 1, msg,
           setup=_setup_field(change)) for what, change, msg in (
        ("length is 4000 m", {"length": 4000.0},
         "key 'length' is 4000.0 m, not a soccer field's (1-40 m): is the file in another"
         " unit?"),
        ("border is 5000 m", {"border": 5000.0},
         "key 'border' is 5000.0 m; the floor around a field is at most 10 m"))],
    Case("alias bomb in a field's notes (build-map)", "hang",
         ["build-map", W + "/f.yaml", "-o", W + "/m.h5"], 1, "YAML aliases expand to more than",
         setup=_setup_field_text(f"\nnotes: {ALIAS_BOMB}\n")),
    Case("alias bomb in calib.yaml (extract)", "hang",
         ["extract", "{ds}", "-o", W + "/f.h5"], 1, "YAML aliases expand to more than",
         setup=_setup_calib_text(f"\nbomb: {ALIAS_BOMB}\n")),
    Case("alias bomb as a -c value (localize)", "hang",
         [*LOCALIZE, "-o", W + "/p.h5", "-c", f"min_confidence={ALIAS_BOMB}"], 1,
         "must be a number, got '[&a0 [lol, lol"),
    Case("a field key given twice (build-map)", "silent",
         ["build-map", W + "/f.yaml", "-o", W + "/m.h5"], 1, "the key 'name' is given twice",
         setup=_setup_field_text("\nname: twice\n")),
    Case("build-map --resolution 0.001", "traceback",
         ["build-map", "spl", "-o", W + "/m.h5", "--resolution", "0.001"], 1,
         "11001 x 8001 cells, more than the 300,000 a map may hold"),
    Case("a frames.csv of a million and one rows: refused before any is read (trial P2)",
         "hang", ["extract", "{ds}", "-o", W + "/f.h5"], 1,
         "frames.csv: more than 1,000,000 rows; a CSV fieldloc reads holds at most",
         setup=_with_ds("omni", lambda ds: (ds / "frames.csv").write_text(
             "name,stamp\n" + "x.png,0\n" * 1_000_001))),
    *[Case(f"build-map {field} --resolution {res}: refused, not a minute of CPU (trial P1)",
           "hang", ["build-map", field, "-o", W + "/m.h5", "--resolution", res], 1,
           "a map may hold with a 2 m spiral (about 75 us of CPU a cell)")
      for field, res in (("msl-2015", "0.012"), ("spl", "0.01"))],
    Case("build-map with a 49.9 m spiral at 2.9 cm: refused, not a minute of CPU (trial Q5)",
         "hang", ["build-map", "msl-2015", "--resolution", "0.029", "--max-range", "50",
                  "--spiral-end-radius", "49.9", "-o", W + "/m.h5"], 1,
         "687 x 481 cells, more than the 23,121 a map may hold with a 49.9 m spiral"),
    Case("truth.csv of a million and one rows ending in CR: refused unread (trial Q2)", "hang",
         ["evaluate", "{poses}", "--truth", W + "/t.csv", "-o", W + "/r"], 1,
         "t.csv: more than 1,000,000 rows; a CSV fieldloc reads holds at most that many",
         setup=lambda w, ws: (ws / "t.csv").write_text(
             "stamp,x,y,theta\r" + "0.1,0,0,0\r" * 1_000_001, newline="") and {}),
    Case("truth.csv of a million and one rows, the last without its line end (trial U1-5)",
         "silent", ["evaluate", "{poses}", "--truth", W + "/t.csv", "-o", W + "/r"], 1,
         "t.csv: more than 1,000,000 rows; a CSV fieldloc reads holds at most that many",
         setup=lambda w, ws: (ws / "t.csv").write_text(
             "stamp,x,y,theta" + "\n0.1,0,0,0" * 1_000_001) and {}),
    Case("truth.csv of 256 MB and a byte (sparse): refused by its size, unread (trial U1-4)",
         "hang", ["evaluate", "{poses}", "--truth", W + "/t.csv", "-o", W + "/r"], 1,
         "t.csv: 256 MB, more than the 256 MB a CSV fieldloc reads may weigh",
         setup=lambda w, ws: ((ws / "t.csv").write_text("stamp,x,y,theta\n"),
                              os.truncate(ws / "t.csv", 256_000_001)) and {}),
    Case("inspect a poses file of 1001 root attributes: not listed (trial U1-3)", "hang",
         ["inspect", W + "/p.h5"], 0, "root attributes, not listed: an artifact holds",
         setup=_setup_damaged("poses", "p.h5", lambda f: [f.attrs.create(f"a{i}", i)
                                                         for i in range(1001)])),
    Case("inspect a poses file of groups nested 20 deep: listed 8 deep (trial U1-3)", "hang",
         ["inspect", W + "/p.h5"], 0, "/junk/ ... (nested more than 8 deep)",
         setup=_setup_damaged("poses", "p.h5",
                              lambda f: f.create_group("/".join(["junk"] * 20)))),
    *[Case(f"export of poses whose {what} (trial U1-7, U1-8: Python's or numpy's text)",
           "silent", ["export", W + "/p.h5", "--format", "csv", "-o", W + "/o.csv"], 1, msg,
           setup=_setup_damaged("poses", "p.h5", change))
      for what, change, msg in (
        ("covariance is text", _replace("poses/covariance", lambda d: np.full(
            d.shape, b"abc")), "/poses/covariance holds text; expected numbers"),
        ("names are not UTF-8", _replace("poses/name", lambda d: np.array(
            [b"\xff%d" % i for i in range(len(d))])), "/poses/name holds text that is not UTF-8"),
        ("schema is an array of numbers", _attr("schema", np.arange(3)),
         "expected a 'fieldloc.poses' file, but it is a 'ndarray [0 1 2]' file"))],
    Case("fit on a map whose distance table is NaN (trial V1-1: a StopIteration traceback)",
         "traceback", [*LOCALIZE[:3], W + "/m.h5", *LOCALIZE[4:], "--method", "fit", "-o",
                       W + "/p.h5"], 1,
         "m.h5: damaged map file (/tables/distance holds nan where finite numbers belong)",
         setup=_setup_damaged("map", "m.h5", _fill("tables/distance", math.nan))),
    Case("mcl on a map whose L crossing table points past the field's crossings (trial V1-3)",
         "silent", ["localize", "{kid}", "--map", W + "/m.h5", "--features", "{kid_features}",
                    "--method", "mcl", "-o", W + "/p.h5"], 1,
         "/tables/crossing_lut_L holds the index 30000; the field has",
         setup=_setup_damaged("kmap", "m.h5", _fill("tables/crossing_lut_L", 30000))),
    Case("localize on features of a damaged compressed block (trial V1-4: frames failed"
         " without a word)", "silent", [*LOCALIZE[:5], W + "/f.h5", "-o", W + "/p.h5"], 1,
         "f.h5: damaged features file (frame ",
         setup=_setup_damaged("features", "f.h5", _corrupt_chunk("data/radial"))),
    Case("localize on a map whose grid shape is three numbers (trial V1-5)", "silent",
         [*LOCALIZE[:3], W + "/m.h5", *LOCALIZE[4:], "-o", W + "/p.h5"], 1,
         "must be two real numbers and two whole numbers",
         setup=_setup_damaged("map", "m.h5", lambda f: f.attrs.__setitem__(
             "shape", np.append(f.attrs["shape"], 3)))),
    Case("localize on a map whose field YAML weighs 11 MB (trial V1-8)", "hang",
         [*LOCALIZE[:3], W + "/m.h5", *LOCALIZE[4:], "-o", W + "/p.h5"], 1,
         "/field/spec_yaml is no field YAML of at most 10 MB",
         setup=_setup_damaged("map", "m.h5", _replace(
             "field/spec_yaml", lambda d: (d.decode() if isinstance(d, bytes) else d)
             + "#" * (11 << 20)))),
    Case("templates whose names are numbers (trial V1-6)", "silent",
         ["localize", "{omni}", "--method", "templates", "--templates", W + "/t.h5", "-o",
          W + "/p.h5"], 1, "names hold int64 values where text belongs",
         setup=_setup_damaged("templates", "t.h5", _replace(
             "names", lambda d: np.arange(len(d))))),
    *[Case(f"extract resuming features of a {what} (trial V2-1, V2-6)", "silent",
           ["extract", "{ds}"], 1, f"features.h5 was extracted {said}; use --overwrite",
           setup=_with_ds(name, change))
      for what, name, change, said in (
        ("head.csv changed since", "kid", _extracted_then(lambda ds: (ds / "head.csv").write_text(
            (ds / "head.csv").read_text() + "\n")), "with another head.csv"),
        ("dataset that had no mask", "omni", _extracted_then(_add_mask), "without a mask"))],
    Case("batch into a results folder another batch is writing (trial V3-1)", "silent",
         ["batch", W + "/spec.yaml", "-o", W + "/b", "--serial"], 1,
         "another fieldloc run (pid 1) is writing", setup=lambda w, ws: (
             _setup_spec(_spec_with())(w, ws), (ws / ".b.fieldloc-lock").write_text("1\n"))
         and {}),
    Case("extract of a dataset whose frames.csv lists a JPEG 2000 frame (trial V2-3: left out"
         " without a word)", "silent", ["extract", "{ds}", "-o", W + "/f.h5"], 0,
         "frames.csv: 1 frames are files of a kind fieldloc does not read or none of the"
         " images is (first: 000002.jp2",
         setup=_with_ds("omni", _as_jp2)),
    *[Case(f"{args[0]} whose output's lock name is {what} (trial W3-1: blocked for ever)",
           "hang", [*args, "-o", W + "/" + out], 1, f".{out}.fieldloc-lock is no lock fieldloc"
           " wrote (not a regular file)", setup=lambda w, ws, out=out, make=make: (
               _setup_spec(_spec_with())(w, ws), make(ws / f".{out}.fieldloc-lock")) and {})
      for what, make in (("a FIFO", os.mkfifo),
                         ("a link to /dev/zero", lambda p: os.symlink("/dev/zero", p)))
      for args, out in ((["batch", W + "/spec.yaml", "--serial"], "b"),
                        (["extract", "{omni}"], "f.h5"))],
    Case("batch rerun over RESULTS holding only maps/ (trial W3-2: stopped while it built its"
         " map, refused as a folder of other files)", "silent",
         ["batch", W + "/spec.yaml", "-o", W + "/b", "--serial"], 0, "runs finished",
         setup=lambda w, ws: (_setup_spec(_spec_with())(w, ws),
                              (ws / "b" / "maps").mkdir(parents=True)) and {}),
    *[Case(f"bench --json onto a {kind} file --overwrite (trial W1-5: replaced by JSON)",
           "data-lost", ["bench", "--only", "none", "--json", W + "/x.h5", "--overwrite"], 1,
           f"x.h5 is a fieldloc.{kind} file; this output is no fieldloc artifact",
           setup=lambda w, ws, kind=kind: _copy(w[kind], ws / "x.h5"))
      for kind in ("poses", "features", "map")],
    *[Case(f"localize on a {what} whose {key} attribute is JSON nested 100,000 deep (trial"
           " W1-1, W1-2: RecursionError)", "traceback", args, 1, msg,
           setup=_setup_damaged(kind, name, _attr(key, "[" * 100_000 + "]" * 100_000)))
      for what, kind, name, key, args, msg in (
        ("map", "map", "m.h5", "scanlines",
         [*LOCALIZE[:3], W + "/m.h5", *LOCALIZE[4:], "-o", W + "/p.h5"],
         "m.h5: damaged map file (its scanlines attribute is JSON nested too deep)"),
        ("features file", "features", "f.h5", "scanlines",
         [*LOCALIZE[:5], W + "/f.h5", "-o", W + "/p.h5"],
         "f.h5: damaged features file (scanlines: attribute 'scanlines' holds JSON nested"),
        ("features file", "features", "f.h5", "field",
         [*LOCALIZE[:5], W + "/f.h5", "-o", W + "/p.h5"],
         "f.h5: damaged features file (attribute 'field' holds JSON nested too deep)"))],
    Case("fit on a map whose distance table is float64 of -1e300 (trial W1-3: inf in float32)",
         "traceback", [*LOCALIZE[:3], W + "/m.h5", *LOCALIZE[4:], "--method", "fit", "-o",
                       W + "/p.h5"], 1, "/tables/distance is (33, 45) float64; expected float32",
         setup=_setup_damaged("map", "m.h5", _replace("tables/distance", lambda d: np.full(
             d.shape, -1e300)))),
    Case("localize on features whose line points are all inf (trial X1-1: every frame placed"
         " at one pose, rc 0)", "silent", [*LOCALIZE[:5], W + "/f.h5", "-o", W + "/p.h5"], 1,
         "'points' holds inf where finite numbers belong",
         setup=_setup_damaged("features", "f.h5", _fill("data/points", math.inf))),
    *[Case(f"extract whose output's lock holds {pid!r} (trial X3-1, X3-2, B3-4: a user's notes"
           " removed as a stale lock)", "traceback", ["extract", "{omni}", "-o", W + "/f.h5"], 1,
           ".f.h5.fieldloc-lock is no lock fieldloc wrote (it holds no process id)",
           setup=lambda w, ws, pid=pid: (ws / ".f.h5.fieldloc-lock").write_text(f"{pid}\n")
           and {})
      for pid in ("2147483648", "99999999999999999999", "-1", "0", "my notes")],
    *[Case(f"batch into RESULTS whose {rel} is a link to a user's (trial B3-1, B3-2, B3-7)",
           "data-lost", ["batch", W + "/spec.yaml", "-o", W + "/b", "--serial"], 1,
           f"b/{rel} is a symbolic link: batch writes only its own files in RESULTS",
           setup=lambda w, ws, rel=rel: (
               _setup_spec(_spec_with())(w, ws), (ws / "u.h5").write_text("mine\n"),
               (ws / "b" / rel).parent.mkdir(parents=True, exist_ok=True),
               (ws / "b" / rel).symlink_to(ws / "u.h5")) and {})
      for rel in ("features/d.default.features.h5", "maps/spl.map.h5")],
    Case("batch --overwrite into a user's folder of notes and maps/ (trial X3-3)", "data-lost",
         ["batch", W + "/spec.yaml", "-o", W + "/b", "--serial", "--overwrite"], 1,
         "b holds other files: batch results go into a new folder",
         setup=lambda w, ws: (_setup_spec(_spec_with())(w, ws),
                              (ws / "b" / "maps").mkdir(parents=True),
                              (ws / "b" / "notes.txt").write_text("mine\n")) and {}),
    Case("calibrate omni of 1001 pairs (trial X2-1: 300,000 ran past a minute)", "hang",
         ["calibrate", "omni", W + "/m.csv", "-o", W + "/c.yaml", "--centre", "240", "240",
          "--image-size", "480", "480", "--valid-radius", "40", "230"], 1,
         "m.csv: 1,001 pairs, more than the 1000 a mirror table holds",
         setup=lambda w, ws: (ws / "m.csv").write_text("radius_px,distance_m\n" + "".join(
             f"{45 + 0.15 * i:.4f},{0.3 + 0.003 * i:.5f}\n" for i in range(1001))) and {}),
    *[Case(f"batch SPEC whose {what} is refused before anything runs (trial {trial})",
           "silent", ["batch", W + "/spec.yaml", "-o", W + "/b", "--serial"], 1, msg,
           setup=_setup_spec(text))
      for what, trial, text, msg in (
        ("build_map resolution gives a map of 1e19 cells", "X3-5",
         "build_map: {{resolution: 1.0e-9}}\ndatasets:\n  - name: d\n    simulate:"
         " {{preset: omni-clean, field: spl, frames: 2, seed: 1}}\nmethods: [lut]\n",
         "spec.yaml: build_map: build-map of spl at 1e-09 m:"),
        ("template grid of 0.1 mm gives 1e10 captures", "X3-4",
         "build_map: {{resolution: 0.5}}\ntemplates: {{grid: 0.0001, seed: 3}}\ndatasets:\n"
         "  - name: d\n    simulate: {{preset: omni-clean, field: spl, frames: 2, seed: 1}}\n"
         "methods: [templates]\n", "frames must be a whole number from 1 to 1000000"))],
    *[Case(f"batch into RESULTS whose {rel} is a link to a user's folder (trial Y3-1: the"
           " user's poses replaced through it)", "data-lost",
           ["batch", W + "/spec.yaml", "-o", W + "/b", "--serial", "--overwrite"], 1,
           f"b/{rel} is a symbolic link: batch writes only into its own folders",
           setup=lambda w, ws, rel=rel: (
               _setup_spec(_spec_with())(w, ws), (ws / "u").mkdir(),
               (ws / "u" / "poses.h5").write_text("mine\n"),
               (ws / "b" / rel).parent.mkdir(parents=True, exist_ok=True),
               (ws / "b" / rel).symlink_to(ws / "u")) and {})
      for rel in ("runs", "runs/d", "runs/d/lut-default")],
    *[Case(f"localize on features whose {key} attribute is {value} (trial Y1-1, Y1-2, Y1-5)",
           "traceback", [*LOCALIZE[:5], W + "/f.h5", "-o", W + "/p.h5"], 1,
           f"f.h5: damaged features file (attribute '{key}' is",
           setup=_setup_damaged("features", "f.h5", _attr(key, value)))
      for key, value in (("field", "[1, 2]"), ("field", '{"name": "spl", "size": "ab"}'),
                         ("field", '{"name": "spl", "size": [1]}'),
                         ("scanlines", '{"a": 1}'))],
    Case("evaluate --table over a report.json whose frames is a 5001-digit number (trial"
         " Y1-3)", "traceback", ["evaluate", "--table", W + "/r"], 1,
         "report.json: not valid JSON (an integer of 5,001 digits)",
         setup=lambda w, ws: ((ws / "r").mkdir(), (ws / "r" / "report.json").write_text(
             '{"schema": "fieldloc.report", "frames": 1' + "0" * 5000 + "}")) and {}),
    *[Case(f"{args[0]} -o a calib.yaml fieldloc wrote, --overwrite (trial Y2-5: replaced by an"
           " HDF5 file)", "data-lost", [*args, "-o", W + "/c.yaml", "--overwrite"], 1,
           f"c.yaml is no fieldloc artifact; this command writes fieldloc.{schema} files",
           setup=lambda w, ws: _copy(Path(w["omni"]) / "calib.yaml", ws / "c.yaml"))
      for args, schema in ((["extract", "{omni}"], "features"),
                           (["build-templates", "{omni}"], "templates"))],
    Case("calibrate --line-images of 1001 images: refused before any is read (trial Y2-1)",
         "hang", ["calibrate", "omni", "--from-minho", "{m}", "--line-images", W + "/li",
                  "-o", W + "/c.yaml", "--image-size", "480", "480"], 1,
         "li: 1,001 line images, more than the 1000 pairs a calibration holds",
         setup=lambda w, ws: ((ws / "li").mkdir(), [
             (ws / "li" / f"{0.5 + 0.001 * i:.3f}.png").write_bytes(b"") for i in range(1001)],
             _setup_minho()(w, ws))[-1]),
    Case("field import -o a calib.yaml fieldloc wrote, --overwrite (trial Z2-1: replaced)",
         "data-lost", ["field", "import", W + "/f.json", "--format", "hulks", "-o",
                       W + "/c.yaml", "--overwrite"], 1,
         "c.yaml is another kind of file fieldloc wrote: --overwrite replaces only this",
         setup=lambda w, ws: (_copy(Path(w["omni"]) / "calib.yaml", ws / "c.yaml"),
                              (ws / "f.json").write_text(
                                  '{"field_dimensions": {"length": 9.0, "width": 6.0}}'))
         and {}),
    Case("extract -o the features of another dataset, no --overwrite (trial Z2-2: its frames"
         " dropped as gone)", "data-lost", ["extract", "{ds}", "-o", "{features}"], 1,
         "was extracted from another dataset (", setup=_with_ds("omni", lambda ds: None)),
    Case("batch SPEC whose glob runs through a link loop (trial Z3-1: 4^11 paths listed past a"
         " minute)", "hang", ["batch", W + "/spec.yaml", "-o", W + "/b", "--serial"], 1,
         "datasets[0].glob: ", setup=lambda w, ws: (
             (ws / "loop").mkdir(), [(ws / "loop" / n).symlink_to(".") for n in "abcd"],
             (ws / "spec.yaml").write_text(
                 f"map: {w['map']}\ndatasets:\n  - glob: loop/{'/'.join(['*'] * 11)}\n"
                 "methods: [lut]\n")) and {}),
    Case("report of a report.json whose frames is a 401-digit number (trial Z1-2: an"
         " OverflowError)", "traceback", ["report", W + "/r", "-o", W + "/r.html"], 1,
         "report.json: not valid JSON (an integer of 401 digits)",
         setup=lambda w, ws: ((ws / "r").mkdir(), (ws / "r" / "report.json").write_text(
             '{"schema": "fieldloc.report", "frames": 1' + "0" * 400 + "}")) and {}),
    Case("localize on features whose field size is a 401-digit number (trial Z1-1: an"
         " OverflowError)", "traceback", [*LOCALIZE[:5], W + "/f.h5", "-o", W + "/p.h5"], 1,
         "f.h5: damaged features file (attribute 'field' is",
         setup=_setup_damaged("features", "f.h5", _attr(
             "field", '{"name": "spl", "size": [1' + "0" * 400 + ', 6]}'))),
    Case("extract resuming features whose dataset attribute is bytes not UTF-8 (trial A2-1: a"
         " UnicodeDecodeError)", "traceback", ["extract", "{ds}", "-o", W + "/f.h5"], 1,
         "f.h5 was extracted from another dataset (",
         setup=lambda w, ws: (_with_ds("omni", lambda ds: None)(w, ws), _copy(
             w["features"], ws / "f.h5"), _setup_damaged("features", "f.h5", _attr(
                 "dataset", np.bytes_(b"\xff\xfe/work")))(w, ws))[0]),
    Case("batch SPEC glob through a link loop that matches nothing (trial A3-2: 4^13 folders"
         " walked)", "hang", ["batch", W + "/spec.yaml", "-o", W + "/b", "--serial"], 1,
         "datasets[0].glob: ", setup=lambda w, ws: (
             (ws / "loop").mkdir(), [(ws / "loop" / n).symlink_to(".") for n in "abcd"],
             (ws / "spec.yaml").write_text(
                 f"map: {w['map']}\ndatasets:\n  - glob: loop/{'/'.join(['*'] * 13)}/none\n"
                 "methods: [lut]\n")) and {}),
    Case("batch into RESULTS whose simulated dataset's folder is a link to a user's dataset"
         " (trial A3-1: re-rendered through it)", "data-lost",
         ["batch", W + "/spec.yaml", "-o", W + "/b", "--serial"], 1,
         "b/datasets/d is a symbolic link: batch writes only its own files in RESULTS",
         setup=lambda w, ws: (
             _setup_spec(_spec_with())(w, ws), (ws / "u").mkdir(),
             (ws / "u" / "notes.txt").write_text("mine\n"),
             (ws / "b" / "datasets").mkdir(parents=True),
             (ws / "b" / "datasets" / "d").symlink_to(ws / "u")) and {}),
    Case("calibrate --from-minho of a folder named with a byte not UTF-8 (trial B2-1: a"
         " calib.yaml its own reader refused)", "traceback",
         ["calibrate", "omni", "--from-minho", W + "/mh\udcff", "-o", W + "/c.yaml",
          "--image-size", "480", "480"], 0, "wrote ",
         setup=lambda w, ws: shutil.copytree(w["minho"], ws / "mh\udcff") and {}),
    Case("field import of a team file whose name holds line breaks (trial B2-3: a traceback)",
         "traceback", ["field", "import", W + "/a\nlength: 99\nx.json", "--format", "hulks",
                       "--name", "hx", "--base", "spl", "-o", W + "/f.yaml"], 0, "wrote ",
         setup=lambda w, ws: (ws / "a\nlength: 99\nx.json").write_text(
             '{"field_dimensions": {"length": 9.0, "width": 6.0}}') and {}),
    *[Case(f"localize on features whose failures are {what} (trial B1-1, B1-3)", kind,
           [*LOCALIZE[:5], W + "/f.h5", "-o", W + "/p.h5"], 1,
           "f.h5: damaged features file (/failures is",
           setup=_setup_damaged("features", "f.h5", change))
      for what, kind, change in (
        ("a scalar", "traceback", lambda f: (f.__delitem__("failures"), f.create_dataset(
            "failures", data="x", dtype=h5py.string_dtype()))),
        ("50 million float rows", "hang", lambda f: (f.__delitem__("failures"),
                                                       f.create_dataset(
            "failures", shape=(50_000_000,), dtype="<f8", chunks=True,
            compression="gzip"))))],
    Case("localize on a map whose /field is a soft link to itself (trial B1-2: RuntimeError)",
         "traceback", [*LOCALIZE[:3], W + "/m.h5", *LOCALIZE[4:], "-o", W + "/p.h5"], 1,
         "m.h5: damaged 'fieldloc.map' file (/field is a soft link",
         setup=_setup_damaged("map", "m.h5", lambda f: (f.__delitem__("field"), f.__setitem__(
             "field", h5py.SoftLink("/field"))))),
    Case("localize --write-calib onto the TUM twin of -o (trial C1-5: the calibration replaced"
         " by the TUM after a success line)", "data-lost",
         [*LOCALIZE, "-o", W + "/p.h5", "--write-calib", W + "/p.tum"], 1,
         "p.tum is the poses' TUM twin this command writes beside p.h5"),
    Case("localize --min-confidence 0_1: refused, not read as 1 (trial Q7)", "silent",
         [*LOCALIZE, "-o", W + "/p.h5", "--min-confidence", "0_1"], 2,
         "'0_1' is no decimal number (underscores)"),
    *[Case(f"{args[0]} of a {kind} whose {name} is a link to another file (trial R: a FIFO"
           " there blocked the reader)", "hang", [*args, "-o", W + out], 1,
           f"m.h5: damaged 'fieldloc.{kind}' file (/{name} is a link to another file",
           setup=_setup_damaged(kind, "m.h5", _external(name)))
      for kind, name, args, out in (
        ("map", "tables/distance",
         ["localize", "{omni}", "--features", "{features}", "--map", W + "/m.h5"], "/p.h5"),
        ("features", "index/stamp",
         ["localize", "{omni}", "--map", "{map}", "--features", W + "/m.h5"], "/p.h5"),
        ("poses", "poses/x", ["export", W + "/m.h5", "--format", "csv"], "/o.csv"))],
    *[Case(f"export of poses whose {what} (trial S: minutes, or 10 GB read)", "hang",
           ["export", W + "/p.h5", "--format", "csv", "-o", W + "/o.csv"], 1, msg,
           setup=_setup_damaged("poses", "p.h5", change))
      for what, change, msg in (
        ("groups nest 20 deep", lambda f: f.create_group("/".join(["junk"] * 20)),
         "/junk/junk/junk/junk/junk/junk/junk is nested more than 8 deep"),
        ("x's elements are arrays", _subarray("poses/x", (30, 30)),
         "/poses/x holds elements of 7,200 bytes"),
        ("hypotheses outnumber the frames", _replace("hypotheses", lambda d: np.concatenate(
            [d, d])), "for N = 4 frames (/poses/name)"),
        ("name is a group (trial T: an AttributeError)", _as_group("poses/name"),
         "/poses/name is a Group, not a dataset"),
        ("root holds 1001 attributes (trial T: a million took a minute)",
         lambda f: [f.attrs.create(f"a{i}", i) for i in range(1001)],
         "root attributes (more than 1000)"))],
    *[Case(f"{args[0]} of a {kind} whose {what} (trial T: gigabytes read, or h5py's text)",
           "hang", [*args, "-o", W + "/o.png"], 1, msg,
           setup=_setup_damaged(kind, "m.h5", change))
      for kind, what, change, args, msg in (
        ("map", "field lines' elements are arrays", _subarray("field/segments", (30, 30)),
         ["show", "map", W + "/m.h5"], "/field/segments holds elements of 7,200 bytes"),
        ("map", "distance table is not of its grid's shape", _replace(
            "tables/distance", lambda d: np.zeros((d.shape[0] + 1, d.shape[1]), d.dtype)),
         ["show", "map", W + "/m.h5"],
         "/tables/distance is (34, 45) float32; expected float32 of shape (33, 45)"),
        ("map", "grid holds a million cells", _attr("shape", np.array([1000, 1000])),
         ["show", "map", W + "/m.h5"], "a map holds 1 to 300,000 cells"),
        ("features", "points' elements are arrays", _subarray("data/points", (600,)),
         ["show", "points", "{omni}", "--features", W + "/m.h5", "--frame", "0"],
         "/data/points holds elements of 4,800 bytes"),
        ("features", "frame names are a group", _as_group("index/name"),
         ["show", "points", "{omni}", "--features", W + "/m.h5", "--frame", "0"],
         "/index/name is a Group, not a dataset"),
        ("features", "points have three columns", _replace(
            "data/points", lambda d: np.zeros((len(d), 3), d.dtype)),
         ["show", "points", "{omni}", "--features", W + "/m.h5", "--frame", "0"],
         "expected rows of (2,) numbers"))],
    *[Case(f"localize --method templates on templates whose {what} (trial T)", "hang",
           ["localize", "{omni}", "--method", "templates", "--templates", W + "/t.h5", "-o",
            W + "/p.h5"], 1, msg, setup=_setup_damaged("templates", "t.h5", change))
      for what, change, msg in (
        ("offsets are 3e8 long", lambda f: (f.__delitem__("offsets"), f.create_dataset(
            "offsets", shape=(300_000_000,), dtype="<i8", chunks=True, compression="gzip")),
         "offsets has shape (300000000,), expected"),
        ("names are a group", _as_group("names"), "/names is a Group, not a dataset"))],
    Case("build-map --robot-radius 0: refused, no numpy warnings (trial Q8)", "silent",
         ["build-map", "spl", "--robot-radius", "0", "-o", W + "/m.h5"], 1,
         "conf 'robot_radius' must be >= 0.01 and <= 2, got 0.0"),
    Case("simulate --frames 1e12", "traceback",
         ["simulate", "omni", "--field", "spl", "-o", W + "/sim", "--frames",
          "1000000000000"], 1, "frames must be a whole number from 1 to 1000000"),
    Case("simulate --frames that fill the disk", "traceback",  # 1e6 frames of 36 Mpx: 59 TiB
         ["simulate", "perspective", "--field", "kidsize", "-o", W + "/sim", "--frames",
          "1000000", "-c", "perspective.image_size=[7520, 4800]", "-c",
          "perspective.intrinsics.fx=3300", "-c", "perspective.intrinsics.fy=3300"],
         1, "would write about"),
    Case("show map --heading-deg nan", "traceback",
         ["show", "map", "{map}", "--table", "radial", "--cell", "0", "0", "--heading-deg",
          "nan", "-o", W + "/m.png"], 2, "is not a finite number"),
    Case("build-map --resolution inf", "traceback",
         ["build-map", "spl", "-o", W + "/m.h5", "--resolution", "inf"], 2,
         "is not a finite number"),
    Case("-c hypotheses=abc", "traceback",
         [*LOCALIZE, "-o", W + "/p.h5", "-c", "hypotheses=abc"], 1,
         "conf 'hypotheses' must be a whole number"),
    Case("-c min_confidence=nan", "traceback",
         [*LOCALIZE, "-o", W + "/p.h5", "-c", "min_confidence=.nan"], 1,
         "conf 'min_confidence' must be a finite number"),
    Case("-c radial_correction=1 (a group of keys)", "traceback",
         [*LOCALIZE, "-o", W + "/p.h5", "-c", "radial_correction=1"], 1, "is a group of keys"),
    Case("-c radial_correction.enabled=maybe", "silent",
         [*LOCALIZE, "-o", W + "/p.h5", "-c", "radial_correction.enabled=maybe"], 1,
         "conf 'radial_correction.enabled' must be true or false, got 'maybe'"),
    Case("-c a=1 -c a.b=2", "traceback",
         [*LOCALIZE, "-o", W + "/p.h5", "-c", "radial_correction=1", "-c",
          "radial_correction.enabled=true"], 1, "cannot also hold keys"),
    Case("a truncated map file", "traceback",
         [*LOCALIZE[:3], W + "/cut.map.h5", *LOCALIZE[4:], "-o", W + "/p.h5"], 1,
         "not an HDF5 file", setup=_setup_corrupt_map),
    Case("a map file without its attributes", "traceback",
         [*LOCALIZE[:3], W + "/hollow.map.h5", *LOCALIZE[4:], "-o", W + "/p.h5"], 1,
         "damaged map file", setup=_setup_corrupt_map),
    Case("a field YAML that is binary", "traceback",
         ["build-map", "{poses}", "-o", W + "/m.h5"], 1, "not a text YAML file"),
    # ------------------------------------------------------------------ silent or misleading
    Case("a map of another field than the features", "silent",
         [*LOCALIZE[:3], "{kmap}", *LOCALIZE[4:], "-o", W + "/p.h5"], 1,
         "the dataset was recorded on field 'spl' (9 x 6 m), the map"),
    Case("... unless --allow-field-mismatch", "silent",
         [*LOCALIZE[:3], "{kmap}", *LOCALIZE[4:], "-o", W + "/p.h5",
          "--allow-field-mismatch"], 0, ""),
    Case("a map with other scan lines than the features", "silent",
         [*LOCALIZE[:3], "{map3}", *LOCALIZE[4:], "-o", W + "/p.h5"], 1,
         "scan lines have max_range = 4, the map"),
    Case("lut on perspective features", "silent",
         ["localize", "{kid}", "--map", "{kmap}", "--features", "{kid_features}", "-o",
          W + "/p.h5"], 1, "--method lut needs omni features"),
    Case("mcl on omni features", "silent",
         [*LOCALIZE, "--method", "mcl", "-o", W + "/p.h5"], 1, "mcl needs perspective"),
    Case("two images with the same stem", "silent",
         ["extract", W + "/omni", "-o", W + "/f.h5"], 1,
         "000003.jpg and 000003.png would both be frame '000003'", setup=_setup_same_stem),
    Case("an unreadable frame is a failed frame of poses.h5", "silent",
         ["localize", W + "/omni", "--map", "{map}", "-o", W + "/p.h5"], 0,
         "frame 000002 skipped: unreadable image", setup=_setup_unreadable,
         check=_check_unreadable_counted),
    Case("... and evaluate scores every dataset frame", "silent",
         ["evaluate", W + "/p.h5", "--truth", W + "/omni", "-o", W + "/rep"], 0, "",
         setup=lambda w, ws: _setup_unreadable(w, ws, localised=True),
         check=_check_report_over_all_frames),
    Case("no frames.csv: stamps from file names meet no imu row", "silent",
         ["localize", W + "/omni", "--map", "{map}", "-o", W + "/p.h5"], 0,
         "3 of 4 frames have no imu.csv row within 0.02 s: the frame"
         " stamps (from the image file names (000005.png = 5 s; there is no frames.csv)",
         setup=_setup_no_frames_csv),
    Case("--points with integer frame ids", "silent",
         ["localize", "{omni}", "--map", "{map}", "--points", W + "/pts.csv", "-o",
          W + "/p.h5"], 0, "", setup=lambda w, ws: _points_csv(w, ws, range(4)),
         check=_check_integer_ids),
    Case("--points with an unknown frame id", "silent",
         ["localize", "{omni}", "--map", "{map}", "--points", W + "/pts.csv", "-o",
          W + "/p.h5"], 0, "1 of 4 frame ids of",
         setup=lambda w, ws: _points_csv(w, ws, ["000000", "000001", "000002", "x9"])),
    Case("--points matching no frame", "silent",
         ["localize", "{omni}", "--map", "{map}", "--points", W + "/pts.csv", "-o",
          W + "/p.h5"], 1, "no frame id matches a frame of",
         setup=lambda w, ws: _points_csv(w, ws, ["a", "b", "c", "d"])),
    Case("evaluate from another folder than localize ran in", "silent",
         ["evaluate", W + "/rel.h5", "-o", W + "/rep"], 0, "", setup=_setup_relative_run),
    Case("output files get the umask's mode, not 0600", "silent",
         [*LOCALIZE, "-o", W + "/p.h5"], 0, "", check=_check_modes),
    Case("stale parts of a killed run are removed by the next run", "silent",
         ["build-map", "spl", "--resolution", "0.5", "-o", W + "/m.h5"], 0,
         "left by an interrupted run writing", setup=_setup_stale, check=_check_stale_removed,
         removes_parts=True),
    # ------------------------------------------------------------------ newcomer
    Case("localize DIR reuses a matching DIR/features.h5", "newcomer",
         ["localize", W + "/omni", "--map", "{map}", "-o", W + "/p.h5"], 0, "",
         setup=_setup_own_features, check=_check_reused_features),
    Case("localize DIR -o DIR/features.h5 --overwrite, the features it would reuse",
         "data-lost", ["localize", W + "/omni", "--map", "{map}", "-o",
                       W + "/omni/features.h5", "--overwrite"], 1,
         # refused as a features file before the reuse of DIR/features.h5 is decided
         "features.h5 is a fieldloc.features file; this command writes fieldloc.poses files",
         setup=_setup_own_features),
    Case("inspect report.json", "newcomer", ["inspect", "{omni}/runs/r/report.json"], 0,
         "schema fieldloc.report"),
    Case("inspect a FIFO", "hang", ["inspect", W + "/pipe.h5"], 1, "not a regular file",
         setup=lambda w, ws: os.mkfifo(ws / "pipe.h5") or {}),
    Case("inspect a file fieldloc does not read", "newcomer", ["inspect", "{marks}.x"], 1,
         "file not found"),
    Case("inspect a README", "newcomer", ["inspect", str(ROOT / "README.md")], 1,
         "not a file fieldloc reads (inspect reads HDF5"),
    # ------------------------------------------------------------------ the later review
    Case("report r -o r/report.json --overwrite", "data-lost",
         ["report", "{omni}/runs/r", "-o", "{omni}/runs/r/report.json", "--overwrite"], 1,
         "is an input of this command (a file of the report)"),
    Case("report r -o r/errors.csv --overwrite", "data-lost",
         ["report", "{omni}/runs/r", "-o", "{omni}/runs/r/errors.csv", "--overwrite"], 1,
         "is an input of this command (a file of the report)"),
    Case("report runs -o runs/a/poses.h5 --overwrite", "data-lost",
         ["report", W + "/runs", "-o", W + "/runs/a/poses.h5", "--overwrite"], 1,
         "is an input of this command", setup=_setup_report_copy),
    Case("report -o the poses file the report names --overwrite", "data-lost",
         ["report", "{omni}/runs/r", "-o", "{poses}", "--overwrite"], 1,
         "(the run's poses or features)"),
    Case("report --overwrite onto a user's own page", "data-lost",
         ["report", W + "/runs", "-o", W + "/mine.html", "--overwrite"], 1,
         "was not written by fieldloc", setup=_setup_report_copy),
    Case("import rosbag d/x.bag -o d --overwrite", "data-lost",
         ["import", "rosbag", W + "/d/x.bag", "-o", W + "/d", "--image-topic", "/cam",
          "--overwrite"], 1, "holds an input of this command (bag", setup=_setup_bags),
    Case("import rosbag -o a user's folder --overwrite", "data-lost",
         ["import", "rosbag", W + "/x.bag", "-o", W + "/thesis", "--image-topic", "/cam",
          "--overwrite"], 1, "not a dataset made by fieldloc import rosbag",
         setup=_setup_bags),
    Case("import rosbag -o inside the ROS 2 bag folder", "data-lost",
         ["import", "rosbag", W + "/r2", "-o", W + "/r2/out", "--image-topic", "/cam"], 1,
         "lies inside the bag folder", setup=_setup_bags),
    Case("import rosbag of a zero-byte .bag", "traceback",
         ["import", "rosbag", W + "/zero.bag", "-o", W + "/out", "--image-topic", "/cam"], 1,
         "cannot read the bag, it is empty or damaged", setup=_setup_bags),
    Case("import rosbag of random bytes", "traceback",
         ["import", "rosbag", W + "/random.bag", "-o", W + "/out", "--image-topic", "/cam"],
         1, "cannot read the bag, it is empty or damaged", setup=_setup_bags),
    Case("import rosbag of a truncated bag", "traceback",
         ["import", "rosbag", W + "/cut.bag", "-o", W + "/out", "--image-topic", "/cam"], 1,
         "cannot read the bag, it is empty or damaged", setup=_setup_bags),
    Case("import rosbag of a ROS 2 folder whose metadata.yaml is not YAML", "traceback",
         ["import", "rosbag", W + "/r2-yaml", "-o", W + "/out", "--image-topic", "/cam"], 1,
         "cannot read the bag, it is empty or damaged", setup=_setup_bags),
    Case("import rosbag of a ROS 2 folder with an empty .db3", "traceback",
         ["import", "rosbag", W + "/r2-empty", "-o", W + "/out", "--image-topic", "/cam"], 1,
         "cannot read the bag, it is empty or damaged", setup=_setup_bags),
    Case("evaluate a poses.h5 whose /poses/x is shorter", "traceback",
         ["evaluate", W + "/p.h5", "--truth", "{omni}", "-o", W + "/rep"], 1,
         "damaged poses file (/poses/x has shape (2,)", setup=_setup_poses_edit(_shorten_x)),
    Case("export --format json of a malformed /hypotheses", "traceback",
         ["export", W + "/p.h5", "--format", "json", "-o", W + "/p.json"], 1,
         "damaged poses file (/hypotheses has shape (1, 2)",
         setup=_setup_poses_edit(_flat_hypotheses)),
    Case("report on a report.json whose position_error_m is a list", "traceback",
         ["report", W + "/r", "-o", W + "/r.html"], 1,
         "'position_error_m' must be a table (a JSON object), got [1, 2]",
         setup=_setup_bad_report(lambda r: r.update(position_error_m=[1, 2]))),
    Case("simulate omni --seed -1", "traceback",
         ["simulate", "omni", "--field", "spl", "-o", W + "/sim", "--seed", "-1"], 2,
         "-1 is not in the range x>=0"),
    Case("simulate omni -c seed=-1", "traceback",
         ["simulate", "omni", "--field", "spl", "-o", W + "/sim", "-c", "seed=-1"], 1,
         "seed must be a whole number >= 0, got '-1'"),
    Case("alias bomb in a batch method's conf", "hang",
         ["batch", W + "/spec.yaml", "-o", W + "/res", "--serial"], 1,
         "YAML aliases expand to more than",
         setup=_setup_spec("map: {map}\ndatasets: [x]\nmethods:\n  - method: lut\n    conf: "
                           + ALIAS_BOMB + "\n")),
    Case("alias bomb in a field's name (build-map)", "hang",
         ["build-map", W + "/f.yaml", "-o", W + "/m.h5"], 1, "YAML aliases expand to more than",
         setup=_setup_field_name_bomb),
    Case("a features frame without its radial dataset", "silent",
         [*LOCALIZE[:5], W + "/f.h5", "-o", W + "/p.h5"], 1,
         "damaged features file (frame 000001 has no 'radial' dataset)",
         setup=_setup_features_edit(_drop_radial)),
    Case("a features frame whose radial is (72, 3)", "silent",
         [*LOCALIZE[:5], W + "/f.h5", "-o", W + "/p.h5"], 1,
         "data/radial is (288, 3) float32; expected rows of (4,) numbers",
         setup=_setup_features_edit(_cut_radial)),
    Case("features of camera_kind fisheye", "silent",
         [*LOCALIZE[:5], W + "/f.h5", "-o", W + "/p.h5"], 1,
         "camera_kind 'fisheye' is not one of omni, perspective",
         setup=_setup_features_edit(lambda f, i: f.attrs.__setitem__("camera_kind", "fisheye"))),
    Case("show map of a map whose segments are NaN", "silent",
         ["show", "map", W + "/nan.map.h5", "-o", W + "/m.png"], 1,
         "/field/segments holds values that are not finite", setup=_setup_nan_segments),
    Case("simulate --calib-error 1e6 0 1", "silent",
         ["simulate", "omni", "--field", "spl", "-o", W + "/sim", "--frames", "1",
          "--calib-error", "1e6", "0", "1"], 1,
         "calib_error would write a calibration extract refuses"),
    Case("show map --cell 1e9 1e9", "silent",
         ["show", "map", "{map}", "--table", "radial", "--cell", "1e9", "1e9", "-o",
          W + "/m.png"], 1, "lies outside the map's world"),
    Case("show map --spirals -1", "silent",
         ["show", "map", "{map}", "--table", "spiral", "--cell", "0", "0", "--spirals", "-1",
          "-o", W + "/m.png"], 2, "-1 is not in the range x>=1"),
    Case("report --worst -1", "silent",
         ["report", "{omni}/runs/r", "-o", W + "/r.html", "--worst", "-1"], 2,
         "-1 is not in the range x>=0"),
    Case("report -c worst=-1", "silent",
         ["report", "{omni}/runs/r", "-o", W + "/r.html", "-c", "worst=-1"], 1,
         "worst must be 0 or more frames, got -1"),
    Case("a batch dataset's frames: -1, refused before anything runs", "silent",
         ["batch", W + "/spec.yaml", "-o", W + "/res", "--serial"], 1,
         "datasets[0].simulate: frames must be a whole number from 1 to 1000000, got -1",
         setup=_setup_spec("field: spl\ndatasets:\n  - simulate: {{preset: omni-clean, field:"
                           " spl, frames: -1}}\nmethods: [lut]\n")),
    Case("--points naming frame 0 only: the other frames failed, said", "silent",
         ["localize", "{omni}", "--map", "{map}", "--points", W + "/pts.csv", "-o",
          W + "/p.h5"], 0, "3 frames of",
         setup=lambda w, ws: _points_csv(w, ws, ["000000"]), check=_check_one_frame_of_four),
    Case("import rosbag --calib x.bag", "silent",
         ["import", "rosbag", W + "/x.bag", "-o", W + "/out", "--image-topic", "/cam",
          "--calib", W + "/x.bag"], 1, "--calib: ", setup=_setup_bags),
    Case("extract while another run writes the same output", "silent",
         ["extract", "{omni}", "-o", W + "/f.h5"], 1, "another fieldloc run (pid ",
         setup=_setup_live_lock, check=_check_lock_holder_untouched),
    Case("show hypotheses of poses made with a custom field's map", "silent",
         ["show", "hypotheses", W + "/p.h5", "--frame", "1", "-o", W + "/h.png"], 0, "",
         setup=_setup_custom_field_poses),
    # ------------------------------------------------------------------ found in its rerun
    Case("field import fd.cfg -o fd.cfg --overwrite", "data-lost",
         ["field", "import", W + "/fd.cfg", "--format", "bhuman", "-o", W + "/fd.cfg",
          "--overwrite"], 1, "is an input of this command (the team file)",
         setup=_setup_team_file),
    Case("field import --base b.yaml -o b.yaml --overwrite", "data-lost",
         ["field", "import", W + "/fd.cfg", "--format", "bhuman", "--base", W + "/base.yaml",
          "-o", W + "/base.yaml", "--overwrite"], 1, "is an input of this command (base)",
         setup=_setup_team_file),
    Case("export -o the dataset's truth.csv --overwrite", "data-lost",
         ["export", "{poses}", "--format", "csv", "-o", "{omni}/truth.csv", "--overwrite"], 1,
         "(the run's dataset: truth.csv)"),
    Case("export -o the run's map --overwrite", "data-lost",
         ["export", "{poses}", "--format", "json", "-o", "{map}", "--overwrite"], 1,
         "(the run's map)"),
    Case("export -o the run's features --overwrite", "data-lost",
         ["export", "{poses}", "--format", "tum", "-o", "{features}", "--overwrite"], 1,
         "(the run's features)"),
    Case("show hypotheses -o the dataset's truth.csv --overwrite", "data-lost",
         ["show", "hypotheses", "{poses}", "--frame", "1", "-o", "{omni}/truth.csv",
          "--overwrite"], 1, "(the run's dataset: truth.csv)"),
    Case("show hypotheses -o the run's map (which it reads) --overwrite", "data-lost",
         ["show", "hypotheses", "{poses}", "--frame", "1", "-o", "{map}", "--overwrite"], 1,
         "(the run's map)"),
    Case("localize --map a FIFO", "hang",
         [*LOCALIZE[:3], W + "/pipe.h5", *LOCALIZE[4:], "-o", W + "/p.h5"], 1,
         "is not a regular file (a device, pipe or socket)",
         setup=lambda w, ws: os.mkfifo(ws / "pipe.h5") or {}),
    Case("evaluate a FIFO as the poses", "hang",
         ["evaluate", W + "/pipe.h5", "--truth", "{omni}", "-o", W + "/rep"], 1,
         "is not a regular file (a device, pipe or socket)",
         setup=lambda w, ws: os.mkfifo(ws / "pipe.h5") or {}),
    Case("extract a dataset whose image is a FIFO", "hang",
         ["extract", "{ds}", "-o", W + "/f.h5"], 0,
         "frame 000002 skipped: unreadable image", setup=_setup_fifo_image,
         check=_check_fifo_frame_failed),
    Case("localize a dataset whose odometry.csv is a FIFO", "hang",
         ["localize", "{ds}", "--map", "{map}", "--features", "{features}", "-o", W + "/p.h5"],
         1, "odometry.csv: not a regular file", setup=_setup_fifo_file("odometry.csv")),
    Case("extract a dataset whose frames.csv is a FIFO", "hang",
         ["extract", "{ds}", "-o", W + "/f.h5"], 1, "frames.csv: not a regular file",
         setup=_setup_fifo_file("frames.csv")),
    Case("extract a dataset whose calib.yaml is a FIFO", "hang",
         ["extract", "{ds}", "-o", W + "/f.h5"], 1, "calib.yaml: not a regular file",
         setup=_setup_fifo_file("calib.yaml")),
    Case("evaluate against a truth.csv that is a FIFO", "hang",
         ["evaluate", "{poses}", "--truth", "{ds}", "-o", W + "/rep"], 1,
         "truth.csv: not a regular file", setup=_setup_fifo_file("truth.csv")),
    Case("calibrate --from-minho whose first image is a FIFO", "hang",
         ["calibrate", "omni", "--from-minho", "{m}", "-o", W + "/c.yaml"], 1,
         "0001.png (not a regular file)", setup=_setup_minho_fifo_image),
    Case("export -o a FIFO --overwrite", "data-lost",
         ["export", "{poses}", "--format", "csv", "-o", W + "/pipe.csv", "--overwrite"], 1,
         "not a regular file (a device, pipe or socket)", setup=_setup_special("pipe.csv"),
         check=_check_still_special("pipe.csv")),
    Case("localize -o a device node --overwrite (as root: /dev/full was replaced)",
         "data-lost", [*LOCALIZE, "-o", W + "/full", "--overwrite"], 1,
         "not a regular file (a device, pipe or socket)", setup=_setup_special("full", "chr"),
         check=_check_still_special("full")),
    Case("report on a report.json nested 100,000 deep", "traceback",
         ["report", W + "/deep", "-o", W + "/r.html"], 1, "report.json: not valid JSON",
         setup=_setup_deep_json("report.json")),
    Case("evaluate --table on a batch.json nested 100,000 deep", "traceback",
         ["evaluate", "--table", W + "/deep"], 1, "batch.json: not a readable JSON file",
         setup=_setup_deep_json("batch.json")),
    Case("calibrate --from-cnc -o the CarpetCalibrator.conf --overwrite", "data-lost",
         ["calibrate", "omni", "--from-cnc", W + "/cnc/CarpetCalibrator.conf", "--rings",
          "detected", "-o", W + "/cnc/CarpetCalibrator.conf", "--overwrite"], 1,
         "is an input of this command (the CNC calibration file)", setup=_setup_team_files),
    Case("calibrate --from-hulks X.json -o X.json --overwrite", "data-lost",
         ["calibrate", "perspective", "--from-hulks", "{capture}", "-o", "{capture}",
          "--overwrite"], 1, "is an input of this command (the HULKs capture)",
         setup=_setup_team_files),
    Case("calibrate --from-hulks FOLDER -o FOLDER/out (M9: written into its source)", "silent",
         ["calibrate", "perspective", "--from-hulks", W + "/hulks", "-o", W + "/hulks/out"], 1,
         "hulks/out lies inside the HULKs capture folder", setup=_setup_team_files),
    Case("calibrate --from-hulks FOLDER -o a user's folder --overwrite", "data-lost",
         ["calibrate", "perspective", "--from-hulks", W + "/hulks", "-o", W + "/thesis",
          "--overwrite"], 1, "is not a dataset made by fieldloc calibrate perspective",
         setup=_setup_team_files),
    Case("export -o another dataset's truth.csv --overwrite", "data-lost",
         ["export", "{poses}", "--format", "csv", "-o", "{kid}/truth.csv", "--overwrite"], 1,
         "is a file of the dataset"),
    Case("show map -o another dataset's image --overwrite", "data-lost",
         ["show", "map", "{map}", "-o", "{kid}/images/000000.png", "--overwrite"], 1,
         "is an image of the dataset"),
    Case("show map -o a name whose suffix is no picture format", "silent",
         ["show", "map", "{map}", "-o", W + "/map.xyz"], 1,
         "a picture is written as .png, .pdf, .svg"),
    Case("report -o r.pdf (an HTML page named PDF)", "silent",
         ["report", "{omni}/runs/r", "-o", W + "/r.pdf"], 1, "the report is an HTML page"),
    # conf values outside the range a method runs in (each a traceback, a segfault or a run
    # of hours before): one line naming the key and its range
    *[Case(f"localize -c {kv}", "traceback", [*LOCALIZE, "-o", W + "/p.h5", "-c", kv], 1,
           msg) for kv, msg in (
        ("hypotheses=-1", "conf 'hypotheses' must be >= 1 and <= 1000"),
        ("hypotheses=1e12", "conf 'hypotheses' must be >= 1 and <= 1000"),
        ("min_confidence=2", "conf 'min_confidence' must be >= 0 and <= 1"),
        ("min_confidence=-0.5", "conf 'min_confidence' must be >= 0 and <= 1"),
        ("start_half_error=2", "start_half_error must lie in [0, 1]"),
        ("stamp_tolerance=-1", "conf 'stamp_tolerance' must be >= 0"))],
    *[Case(f"localize --method mcl -c {kv}", "traceback",
           ["localize", "{kid}", "--map", "{kmap}", "--features", "{kid_features}",
            "--method", "mcl", "-o", W + "/p.h5", "-c", kv], 1, msg) for kv, msg in (
        ("hypotheses=0", "conf 'hypotheses' must be >= 1 and <= 1000"),
        ("seed=-1", "conf 'seed' must be >= 0"),
        ("init_spread=-1", "conf 'init_spread' must be a list of 3 numbers"),
        ("init_spread=[0.3,-0.3,0.2]", "conf 'init_spread[1]' must be >= 0"))],
    Case("localize --method mcl -c init=pose -c init_pose=[1e12,0,0]", "silent",
         ["localize", "{kid}", "--map", "{kmap}", "--features", "{kid_features}", "--method",
          "mcl", "-o", W + "/p.h5", "-c", "init=pose", "-c", "init_pose=[1e12,0,0]"], 1,
         "init_pose (1e+12, 0) m lies off the field"),
    *[Case(f"extract -c {kv}", "traceback", ["extract", "{omni}", "-o", W + "/f.h5", "-c", kv],
           1, msg) for kv, msg in (
        ("scanlines.max_range=0", "conf 'scanlines.max_range' must be > 0 and <= 50"),
        ("colour.green_axes=0", "conf 'colour.green_axes' must be a list of 2 numbers"),
        ("scanlines.spiral_end_radius=0",
         "conf 'scanlines.spiral_end_radius' must be > 0 and <= 50"))],
    # the perspective extractor, the templates method and build-templates: refused
    # when the conf is resolved, before any input is read (the templates file is not there)
    *[Case(f"extract perspective -c {kv}", kind, ["extract", "{kid}", "-o", W + "/f.h5", "-c",
                                                   kv], 1, msg) for kv, kind, msg in (
        ("cell=0", "traceback", "conf 'cell' must be >= 1 and <= 64"),
        ("colour_step=0", "traceback", "conf 'colour_step' must be >= 1 and <= 64"),
        ("posts.post_diameter=1e12", "hang", "conf 'posts.post_diameter' must be > 0"))],
    Case("localize --method templates -c hypotheses=1e12", "hang",
         ["localize", "{omni}", "--method", "templates", "--templates", W + "/t.h5", "-o",
          W + "/p.h5", "-c", "hypotheses=1e12"], 1,
         "conf 'hypotheses' must be >= 1 and <= 1000"),
    *[Case(f"build-templates {' '.join(args)}", kind, ["build-templates", "{omni}", "-o",
                                                       W + "/t.h5", *args], 1, msg)
      for args, kind, msg in (
        (["-c", "field.colour.green_axes=0"], "traceback",
         "conf 'field.colour.green_axes' must be a list of 2 numbers"),
        (["--features", "sift", "-c", "features.octave_layers=0"], "hang",
         "conf 'features.octave_layers' must be >= 1 and <= 10"))],
    # list-valued conf keys given a list of the wrong length or content, a reversed range or
    # a value outside what a list element can be: refused when the conf is resolved, one line
    # naming the key (the key's BOUNDS, common.conf.check_bounds), before anything is rendered
    # or read (a traceback, a run on a wrong value, or a message blaming something else before)
    *[Case(f"simulate omni -c {kv}", kind, [*SIM_OMNI, "-c", kv], 1, msg) for kv, kind, msg in (
        ("scene.carpet_bgr=[]", "traceback", "conf 'scene.carpet_bgr' must be a list of 3"),
        ("scene.floor_bgr=[1e12,0,0]", "silent", "conf 'scene.floor_bgr[0]' must be >= 0 and"),
        ("scene.line_bgr=[244,242,250,250]", "traceback", "conf 'scene.line_bgr' must be a list"),
        ("scene.ball_bgr=[-30,110,235]", "silent", "conf 'scene.ball_bgr[0]' must be >= 0"),
        ("scene.line_brightness=[1.0,0.8]", "silent",
         "conf 'scene.line_brightness' must be a range [low, high] with low <= high"),
        ("scene.robot_speed=[0.2]", "traceback",
         "conf 'scene.robot_speed' must be a list of 2 numbers [low, high], got [0.2]"),
        ("scene.person_speed=[0.2,1e12]", "silent",
         "conf 'scene.person_speed[1]' must be > 0 and <= 10"),
        ("scene.handler_distance=[2.5,0.8]", "silent",
         "conf 'scene.handler_distance' must be a range [low, high]"),
        ("scene.lighting.gain=[0,1]", "traceback",
         "conf 'scene.lighting.gain[0]' must be > 0 and <= 10"),
        ("scene.lighting.periods=[25,3]", "traceback",
         "conf 'scene.lighting.periods' must be a range [low, high]"),
        ("trajectory.heading_hold=[6,2]", "traceback",
         "conf 'trajectory.heading_hold' must be a range [low, high]"),
        ("trajectory.start=[a,b,c]", "traceback",
         "conf 'trajectory.start[0]' must be a number, got 'a'"),
        ("trajectory.start=7", "traceback",
         "conf 'trajectory.start' must be [x, y, theta] or touchline, got 7"),
        ("trajectory.start=[.nan,0,0]", "traceback",
         "conf 'trajectory.start[0]' must be a finite number, got nan"),
        ("imu.collision_frames=[5,2]", "traceback",
         "conf 'imu.collision_frames' must be a range [low, high]"),
        ("omni.image_size=[0,0]", "traceback", "conf 'omni.image_size[0]' must be >= 1 and"),
        ("omni.centre=[1e12,1e12]", "traceback",
         "conf 'omni': 'centre' (1e+12, 1e+12) lies outside the 480 x 480 image"),
        ("omni.polynomial=[]", "traceback", "conf 'omni.polynomial' must be a list of 6"),
        ("omni.polynomial=[1e12,1e12,1e12,1e12,1e12,1e12]", "traceback",
         "'polynomial' f(r) is 1.05e+20 m at r = 40.0 px"),
        ("omni.valid_radius=[40,193,193]", "silent",
         "conf 'omni.valid_radius' must be a list of 2 numbers [low, high]"),
        ("omni.struts_deg=[1e12]", "silent",
         "conf 'omni.struts_deg[0]' must be >= -360 and <= 360"))],
    *[Case(f"simulate perspective-nao -c {kv}", kind, [*SIM_NAO, "-c", kv], 1, msg)
      for kv, kind, msg in (
        ("perspective.image_size=[640]", "traceback",
         "conf 'perspective.image_size' must be a list of 2 numbers"),
        ("perspective.head.tilt_periods=[12,4]", "traceback",
         "conf 'perspective.head.tilt_periods' must be a range [low, high]"),
        ("perspective.sheen_bgr=[196,204,204,204]", "traceback",
         "conf 'perspective.sheen_bgr' must be a list of 3"),
        ("calib_error.centre_shift=[1e12,1e12]", "silent",
         "conf 'calib_error.centre_shift[0]' must be >= -100 and <= 100"),
        ("scene.sun_strength=[1.2,0.5]", "traceback",
         "conf 'scene.sun_strength' must be a range [low, high]"),
        ("scene.shadow_strength=[0.25,2]", "silent",
         "conf 'scene.shadow_strength[1]' must be >= 0 and <= 1"))],
    *[Case(f"build-templates -c {kv}", "silent", ["build-templates", "{omni}", "-o",
                                                  W + "/t.h5", "-c", kv], 1, msg)
      for kv, msg in (
        ("field.colour.green_hue_deg=[-75,-170]",
         "conf 'field.colour.green_hue_deg' must be a range [low, high]"),
        ("field.colour.green_search_y=[240,15]",
         "conf 'field.colour.green_search_y' must be a range [low, high]"))],
    Case("evaluate -c thresholds=[1e12]", "silent",
         ["evaluate", "{poses}", "--truth", "{omni}", "-o", W + "/rep", "-c",
          "thresholds=[1e12]"], 1, "conf 'thresholds[0]' must be > 0 and <= 100"),
    *[Case(f"localize --method mcl -c {' -c '.join(kvs)}", kind,
           ["localize", "{kid}", "--map", "{kmap}", "--features", "{kid_features}",
            "--method", "mcl", "-o", W + "/p.h5", *[a for kv in kvs for a in ("-c", kv)]], 1,
           msg) for kvs, kind, msg in (
        (["init_spread=[1e12,1e12,1e12]"], "silent",
         "conf 'init_spread[0]' must be >= 0 and <= 100"),
        (["init=pose", "init_pose=[a,b,c]"], "traceback",
         "conf 'init_pose[0]' must be a number, got 'a'"),
        (["init=pose", "init_pose=7"], "traceback",
         "conf 'init_pose' must be a list of 3 numbers, got 7"))],
    *[Case(f"calibrate perspective --from-hulks of a capture {what}: refused", kind,
           ["calibrate", "perspective", "--from-hulks", W + "/h.json", "-o", W + "/c.yaml"],
           1, msg, setup=_setup_hulks_capture(old, new)) for what, kind, old, new, msg in (
        ("giving focal_length twice (M3: the last won)", "silent", '"optical_center"',
         '"focal_length": [500.0, 500.0], "optical_center"',
         "h.json: not a readable JSON file (key 'focal_length' given twice)"),)],
    *[Case(f"calibrate perspective --from-hulks -c {kv}", kind,
           ["calibrate", "perspective", "--from-hulks", "{capture}", "-o", W + "/calib.yaml",
            "-c", kv], 1, msg, setup=_setup_team_files) for kv, kind, msg in (
        ("image_size=[640]", "traceback", "conf 'image_size' must be a list of 2 numbers"),
        ("image_size=[1e12,1e12]", "silent", "conf 'image_size[0]' must be >= 1 and <= 8192"))],
    *[Case(f"a batch SPEC's {what}, refused before anything runs", "silent",
           ["batch", W + "/spec.yaml", "-o", W + "/res", "--serial"], 1, msg,
           setup=_setup_spec(text)) for what, text, msg in (
        ("simulate conf with a reversed robot_speed",
         _spec_with("{{scene: {{robot_speed: [1.5, 0.2], robots: 1}}}}"),
         "datasets[0].simulate: conf 'scene.robot_speed' must be a range [low, high]"),
        ("template grid conf with four floor_bgr numbers",
         _spec_with(templates="{{grid: 1.0, seed: 7, conf: {{scene: {{floor_bgr: [1, 2, 3,"
                              " 4]}}}}}}"),
         "templates: conf 'scene.floor_bgr' must be a list of 3 numbers"),
        ("evaluate thresholds: []", _spec_with(evaluate="{{thresholds: []}}"),
         "evaluate: conf 'thresholds' must be a list of 1 to 20 numbers"),
        ("mcl conf init_spread=[1e12,1,1]",
         _spec_with(methods='[{{method: mcl, conf: ["init_spread=[1e12,1,1]"]}}]',
                    preset="perspective-clean"),
         "methods[0]: conf 'init_spread[0]' must be >= 0 and <= 100"),
        ("method conf list naming min_confidence twice (M4: the last won)",
         _spec_with(methods='[{{method: lut, conf: ["min_confidence=0.5",'
                            ' "min_confidence=0.9"]}}]'),
         "methods[0].conf: the key 'min_confidence' is given twice"))],
    Case("a field key whose value is 300 kB of text", "silent",
         ["build-map", W + "/f.yaml", "-o", W + "/m.h5"], 1,
         "key 'length' must be a number, got 'xxxxxxxx", setup=_setup_field({"length": LONG}),
         check=_check_short_message),
    Case("a field key named with 300 kB of text", "silent",
         ["build-map", W + "/f.yaml", "-o", W + "/m.h5"], 1, "unknown key 'xxxxxxxx",
         setup=_setup_field({LONG: 1.0}), check=_check_short_message),
    Case("-c with a key of 300 kB", "silent",
         [*LOCALIZE, "-o", W + "/p.h5", "-c", LONG + "=1"], 1, "unknown conf key 'xxxxxxxx",
         check=_check_short_message),
    Case("build-map of a field path of 300 kB", "silent",
         ["build-map", LONG, "-o", W + "/m.h5"], 1, "fieldloc: error: xxxxxxxx",
         check=_check_short_message),
    Case("localize --method of 300 kB", "silent",
         [*LOCALIZE, "-o", W + "/p.h5", "--method", LONG], 2, "Invalid value for '--method'",
         check=_check_short_message),
    Case("localize with a map path of 300 kB", "silent",
         ["localize", "{omni}", "--map", W + "/" + LONG, "-o", W + "/p.h5"], 1,
         "fieldloc: error: ", check=_check_short_message),
    # ------------------------------------------------------------------ damaged artifacts read
    # by commands (fixA): each refused in one line by the module that owns the artifact
    *[Case(f"a map whose {what}", "traceback", [*args, W + "/m.h5", "-o", W + out], 1,
           "damaged map file (origin", setup=_setup_damaged("map", "m.h5", _attr(*attr)))
      for what, args, out, attr in (
        ("resolution is 0", ["localize", "{omni}", "--features", "{features}", "--map"],
         "/p.h5", ("resolution", 0.0)),
        ("resolution is NaN", ["localize", "{omni}", "--features", "{features}", "--map"],
         "/p.h5", ("resolution", math.nan)),
        ("origin holds NaN (show map)", ["show", "map"], "/m.png",
         ("origin", [math.nan, 1.0])))],
    Case("features whose first stamp is NaN (the frame went to the end of the track)",
         "silent", [*LOCALIZE[:5], W + "/f.h5", "-o", W + "/p.h5"], 1,
         "stamp nan is not a finite number",
         setup=_setup_damaged("features", "f.h5", _nan_first("index/stamp"))),
    Case("localize --method mcl --smooth on features whose first stamp is NaN", "traceback",
         ["localize", "{kid}", "--map", "{kmap}", "--features", W + "/f.h5", "--method", "mcl",
          "--smooth", "-o", W + "/p.h5"], 1,
         "stamp nan is not a finite number",
         setup=_setup_damaged("kid_features", "f.h5", _nan_first("index/stamp"))),
    *[Case(f"poses whose {what}", "traceback",
           [*args, W + "/p.h5", *more], 1, msg, setup=_setup_damaged("poses", "p.h5", change))
      for what, args, more, msg, change in (
        ("/poses/x holds text (export csv)", ["export"], ["--format", "csv", "-o", W + "/o.csv"],
         "damaged poses file (/poses/x holds text; expected numbers)", _as_text("poses/x")),
        ("/poses/x holds text (evaluate)", ["evaluate"],
         ["--truth", "{omni}", "-o", W + "/rep"],
         "damaged poses file (/poses/x holds text; expected numbers)", _as_text("poses/x")),
        ("inputs attribute is a JSON list", ["export"], ["--format", "csv", "-o", W + "/o.csv"],
         "(attribute 'inputs' is '[1]'; expected a JSON object)", _attr("inputs", "[1]")),
        ("inputs attribute is a JSON list (show hypotheses)", ["show", "hypotheses"],
         ["--frame", "1", "-o", W + "/h.png"],
         "(attribute 'inputs' is '[1]'; expected a JSON object)", _attr("inputs", "[1]")),
        ("field attribute is a number (export json)", ["export"],
         ["--format", "json", "-o", W + "/o.json"],
         "(attribute 'field' is '5'; expected text)", _attr("field", 5)))],
    *[Case(f"poses whose {what}", "silent",
           [*args, W + "/p.h5", *more], 1, msg, setup=_setup_damaged("poses", "p.h5", change))
      for what, args, more, msg, change in (
        ("/poses/x is NaN on accepted frames (M7: export tum wrote 'nan' rows)", ["export"],
         ["--format", "tum", "-o", W + "/o.tum"], "damaged poses file (x not finite on accepted"
         " frame", _replace("poses/x", lambda d: np.full(d.shape, np.nan))),
        ("/poses/theta is NaN on accepted frames (M7: evaluate scored them)", ["evaluate"],
         ["--truth", "{omni}", "-o", W + "/rep"], "damaged poses file (theta not finite on"
         " accepted frame", _replace("poses/theta", lambda d: np.full(d.shape, np.nan))),
        ("schema_version is the text '2' (M8: read as 2)", ["export"],
         ["--format", "csv", "-o", W + "/o.csv"], "damaged 'fieldloc.poses' file"
         " (schema_version '2' is not a whole number)", _attr("schema_version", "2")),
        ("inputs give the map as a number (M8)", ["show", "hypotheses"],
         ["--frame", "1", "-o", W + "/h.png"], "(attribute 'inputs' gives 'map' '5'; expected"
         " a path as text)", _attr("inputs", '{"map": 5}')),
        ("method_report is not JSON (M8)", ["evaluate"], ["--truth", "{omni}", "-o", W + "/rep"],
         "(attribute 'method_report' is '[[['; expected a JSON object)",
         _attr("method_report", "[[[")))],
    Case("poses whose /poses/failed holds 2 (read as true)", "silent",
         ["export", W + "/p.h5", "--format", "csv", "-o", W + "/o.csv"], 1,
         "(/poses/failed holds int64 values; expected true/false (or 0/1))",
         setup=_setup_damaged("poses", "p.h5",
                              _replace("poses/failed", lambda d: np.full(d.shape, 2)))),
    Case("report of a report.json whose values are null", "traceback",
         ["report", W + "/r", "-o", W + "/r.html"], 1, "'run' must be text, got null",
         setup=_setup_bad_report(_nulls)),
    *[Case(f"localize --method templates on templates whose {what}", "traceback",
           ["localize", "{omni}", "--method", "templates", "--templates", W + "/t.h5", "-o",
            W + "/p.h5"], 1, msg, setup=_setup_damaged("templates", "t.h5", change))
      for what, msg, change in (
        ("field attribute is a JSON list", "attribute 'field' is '[1]', not a JSON object",
         _attr("field", "[1]")),
        ("laplacian holds text", "laplacian holds text where numbers belong",
         _as_text("laplacian")))],
    *[Case(f"localize --method templates on templates whose {what}", "silent",
           ["localize", "{omni}", "--method", "templates", "--templates", W + "/t.h5", "-o",
            W + "/p.h5"], 1, msg, setup=_setup_damaged("templates", "t.h5", change))
      for what, msg, change in (
        ("feature kind is unknown", "feature_kind 'akaze' is none of", _attr("feature_kind",
                                                                          "akaze")),
        ("descriptor metric is another kind's", "descriptor_metric 'hamming' is not surf's",
         _attr("descriptor_metric", "hamming")),
        ("template count is wrong", "n_templates is 99, the file holds",
         _attr("n_templates", 99)))],
    Case("extract of a dataset whose simulation.yaml has field_size [NaN, 1]", "silent",
         ["extract", "{ds}", "-o", W + "/f.h5"], 1,
         "field_size [nan, 1.0] must be two finite numbers > 0",
         setup=_with_ds("omni", _field_size_nan)),
    # ------------------------------------------------- images and numbers (hostile review s53)
    # an empty image, or one whose header claims more pixels than any frame: a failed frame
    # of extract and a frame left out of build-templates, one line naming the file for
    # calibrate (an OpenCV assertion's traceback before)
    Case("extract a dataset with a zero-byte frame", "traceback",
         ["extract", W + "/omni", "-o", W + "/f.h5"], 0,
         "frame 000002 skipped: unreadable image",
         setup=_with_ds("omni", lambda ds: (ds / "images" / "000002.png").write_bytes(b"")),
         check=_check_fifo_frame_failed),
    Case("extract a frame whose PNG header claims 60000 x 60000 px", "traceback",
         ["extract", W + "/omni", "-o", W + "/f.h5"], 0,
         "000002.png (its header claims 60000 x 60000 px",
         setup=_with_ds("omni", lambda ds: _claim_size(ds / "images" / "000002.png", 60000,
                                                       60000)),
         check=_check_fifo_frame_failed),
    Case("extract a frame that is a BigTIFF whose header claims 9000 x 9000 px (trial V2-5:"
         " refused without its reason)", "newcomer",
         ["extract", W + "/omni", "-o", W + "/f.h5"], 0,
         "000002.tif (its header claims 9000 x 9000 px",
         setup=_with_ds("omni", _as_bigtiff), check=_check_fifo_frame_failed),
    Case("calibrate --from-minho whose image is a zero-byte file", "traceback",
         ["calibrate", "omni", "--from-minho", "{m}", "-o", W + "/c.yaml"], 1,
         "0001.png (empty file)", setup=_setup_minho(image=b"")),
    Case("calibrate --from-cnc with a zero-byte CarpetCalibImage.png", "traceback",
         ["calibrate", "omni", "--from-cnc", W + "/cnc/CarpetCalibrator.conf", "--rings",
          "detected", "-o", W + "/c.yaml"], 1, "CarpetCalibImage.png (empty file)",
         setup=_setup_cnc(lambda d: (d / "CarpetCalibImage.png").write_bytes(b""))),
    Case("build-templates on a dataset with a zero-byte frame", "traceback",
         ["build-templates", W + "/omni", "-o", W + "/t.h5"], 0,
         "1 of 4 frames left out (first: 000000: unreadable image",
         setup=_with_ds("omni", lambda ds: (ds / "images" / "000000.png").write_bytes(b""))),
    # numbers of a dataset CSV: plain ASCII decimals, no value beyond 1e6 but a stamp
    Case("odometry.csv with dx = 1e300", "traceback",
         ["localize", W + "/omni", "--map", "{map}", "--features", "{features}", "-o",
          W + "/p.h5"], 1, "'dx' is 1e300; no robot's value is larger",
         setup=_odometry_dx("1e300")),
    Case("odometry.csv with dx = 1_000", "silent",
         ["localize", W + "/omni", "--map", "{map}", "--features", "{features}", "-o",
          W + "/p.h5"], 1, "'dx' is not a number ('1_000')", setup=_odometry_dx("1_000")),
    Case("odometry.csv with an Arabic-Indic digit", "silent",
         ["localize", W + "/omni", "--map", "{map}", "--features", "{features}", "-o",
          W + "/p.h5"], 1, "'dx' is not a number", setup=_odometry_dx("\u0663")),
    # sizes estimated before anything is made
    Case("simulate --grid 5 --grid-headings 100000000", "silent",
         ["simulate", "omni", "--field", "msl-2015", "-o", W + "/d", "--grid", "5",
          "--grid-headings", "100000000"], 1,
         "'trajectory.grid_headings' must be >= 1 and <= 360"),
    *[Case(f"show error-surface {opt} {v}", "traceback",
           ["show", "error-surface", W + "/t.h5", "{omni}", "-o", W + "/e.png", opt, v], 1,
           "would need about") for opt, v in (("--step", "1e-9"), ("--half-size", "1e9"))],
    # values no robot, mirror or field has
    Case("build-map --resolution 1e9", "silent",
         ["build-map", "spl", "-o", W + "/m.h5", "--resolution", "1e9"], 1,
         "resolution 1e+09 m is coarser than 1 m"),
    Case("calib.yaml whose polynomial coefficients are 1e300", "traceback",
         ["extract", W + "/omni", "-o", W + "/f.h5"], 1,
         "'polynomial' f(r) is 1.05e+308 m at r = 40.0 px",
         setup=_with_ds("omni", lambda ds: edit_calib(ds, polynomial=[1e300] * 6))),
    Case("MINHO mirror.cfg whose PIXEL_DISTANCES end in 1e300", "silent",
         ["calibrate", "omni", "--from-minho", "{m}", "-o", W + "/c.yaml", "--image-size",
          "480", "480"], 1, "pair 4 has radius 1e+300 px",
         setup=_setup_minho(mirror="STEP=0.25\nPIXEL_DISTANCES=60,100,130,1e300\n")),
    Case("CarpetCalibrator.conf with dist9 = 1e300", "silent",
         ["calibrate", "omni", "--from-cnc", W + "/cnc/CarpetCalibrator.conf", "--rings",
          "detected", "-o", W + "/c.yaml"], 1, "has distance 1e+297 m; no mirror sees",
         setup=_setup_cnc(lambda d: (d / "CarpetCalibrator.conf").write_text(
             (d / "CarpetCalibrator.conf").read_text().replace("dist9 = 7000",
                                                                "dist9 = 1e300")))),
    Case("show points --frame -1", "silent",
         ["show", "points", "{omni}", "--frame", "-1", "-o", W + "/h.png"], 1,
         "frame index -1 out of range (0..3)"),
    Case("a field YAML whose penalty mark lies 30 m into a 9 m field", "silent",
         ["build-map", W + "/f.yaml", "-o", W + "/m.h5"], 1,
         "'penalty_mark.distance' (30 m) reaches past the halfway line",
         setup=_setup_field({"penalty_mark": {"distance": 30, "size": 0.1}})),
    # numbers as a logger writes them, in every reader of numbers (a dataset CSV's cells were
    # made strict by afc0ccb): "1_000" was read as 1000 by float()
    Case("localize --points whose x is written 1_000", "silent",
         ["localize", "{omni}", "--map", "{map}", "--points", W + "/pts.csv", "-o",
          W + "/p.h5"], 1, "line 2: x and y must be numbers",
         setup=_first_row_with("pts.csv", 1, "1_000",
                               make=lambda w, ws: _points_csv(w, ws, range(4)))),
    Case("calibrate omni on pairs whose distance is written 1_0", "silent",
         ["calibrate", "omni", W + "/m.csv", "-o", W + "/c.yaml", "--centre", "240", "240",
          "--image-size", "480", "480", "--valid-radius", "40", "230"], 1,
         "expected two numbers 'radius_px,distance_m'",
         setup=_first_row_with("m.csv", 1, "1_0", source="marks")),
    Case("calibrate omni --from-minho whose STEP is written 0_25", "silent",
         ["calibrate", "omni", "--from-minho", W + "/minho", "-o", W + "/c.yaml"], 1,
         "STEP must be a number, got '0_25'", setup=_minho_with("STEP=0_25")),
    Case("localize mcl -c of keys without a preset value in exponent notation", "newcomer",
         ["localize", "{kid}", "--map", "{kmap}", "--features", "{kid_features}", "--method",
          "mcl", "-o", W + "/p.h5", "-c", "observation.camera_height=5e-1", "-c",
          "imu_heading_sigma=1e-1"], 0, "p.h5: 2 frames"),
    *[Case(f"a field YAML whose {key} is {value} m", "silent",
           ["build-map", W + "/f.yaml", "-o", W + "/m.h5"], 1,
           f"key '{key}' ({value} m) is more than", setup=_setup_field(change))
      for key, value, change in (("line_width", 5, {"line_width": 5}),
                                 ("goal.depth", 100, {"goal": {"width": 1.6, "depth": 100,
                                                               "post_diameter": 0.1}}))],
    # ------------------------------------------------------------------ data lost (s53): an
    # output replaced a user's file of the same name
    Case("localize -o X.h5 onto a user's X.tum", "data-lost",
         [*LOCALIZE, "-o", W + "/mine.h5"], 1, "mine.tum exists (use --overwrite",
         setup=_setup_user_tum),
    Case("localize -o DIR/truth.h5 --overwrite onto the user's DIR/truth.tum", "data-lost",
         ["localize", "{ds}", "--map", "{map}", "--features", "{features}", "-o",
          "{ds}/truth.h5", "--overwrite"], 1,
         "truth.tum is not the TUM twin of truth.h5 as fieldloc wrote it",
         setup=_setup_truth_tum_in_dataset),
    Case("localize --overwrite over a TUM twin fieldloc wrote, without its poses beside it",
         "data-lost", [*LOCALIZE, "-o", W + "/p.h5", "--overwrite"], 1,
         "p.tum is not the TUM twin of p.h5 as fieldloc wrote it", setup=_setup_fieldloc_tum),
    Case("evaluate -o a user's folder holding report.json --overwrite", "data-lost",
         ["evaluate", "{poses}", "--truth", "{omni}", "-o", W + "/u", "--overwrite"], 1,
         "u/report.json is not part of a report written by fieldloc evaluate",
         setup=_setup_user_report_folder(report_json=True)),
    Case("evaluate -o a user's folder holding errors.csv", "data-lost",
         ["evaluate", "{poses}", "--truth", "{omni}", "-o", W + "/u"], 1,
         "u/errors.csv is not part of a report written by fieldloc evaluate",
         setup=_setup_user_report_folder(report_json=False)),
    Case("extract --debug-images into a user's folder", "data-lost",
         ["extract", "{omni}", "-o", W + "/f.h5", "--debug-images", W + "/dbg"], 1,
         "holds files extract did not write", setup=_setup_user_debug_folder),
    Case("extract --debug-images into a user's folder --overwrite", "data-lost",
         ["extract", "{omni}", "-o", W + "/f.h5", "--debug-images", W + "/dbg",
          "--overwrite"], 1, "holds files extract did not write (no debug-images.yaml)",
         setup=_setup_user_debug_folder),
    Case("extract --debug-images into a user's folder with a debug-images.yaml of theirs",
         "data-lost", ["extract", "{omni}", "-o", W + "/f.h5", "--debug-images", W + "/dbg",
                       "--overwrite"], 1,
         "holds files extract did not write (its debug-images.yaml is not extract's)",
         setup=_setup_user_debug_folder_with_record),
    Case("extract --debug-images onto overlays extract made", "data-lost",
         ["extract", "{omni}", "-o", W + "/f.h5", "--debug-images", W + "/dbg"], 1,
         "dbg/000000.png exists (use --overwrite", setup=_setup_debug_folder_made),
    Case("extract --debug-images --overwrite onto overlays extract made", "data-lost",
         ["extract", "{omni}", "-o", W + "/f.h5", "--debug-images", W + "/dbg",
          "--overwrite"], 0, "f.h5: 4 frames", setup=_setup_debug_folder_made,
         check=_check_overlays_redrawn),
    Case("report of a plot that links to /etc/passwd", "data-lost",
         ["report", W + "/r", "-o", W + "/r.html"], 0,
         "trajectory.png not shown: a link to a file outside the report folder",
         setup=_setup_report_with_plots, check=_check_no_foreign_plot),
    Case("simulate --overwrite of its dataset holding the user's notes", "data-lost",
         ["simulate", "omni", "--field", "spl", "-o", W + "/data", "--frames", "1",
          "--overwrite"], 1, "notes.txt, which simulate did not write",
         setup=_setup_simulated_with_notes),
    # ------------------------------------------------------------------ s53 hostile2, group D
    Case("batch -o a folder of a user's comparison tables and batch.json", "data-lost",
         ["batch", W + "/spec.yaml", "-o", W + "/res", "--serial"], 1,
         "batch.json exists and no earlier batch wrote it",
         setup=_setup_user_summaries('{"mine": 1}\n')),
    Case("batch --overwrite -o a folder with runs/ and a user's comparison tables", "data-lost",
         ["batch", W + "/spec.yaml", "-o", W + "/res", "--serial", "--overwrite"], 1,
         "comparison.csv exists and no earlier batch wrote it",
         setup=_setup_user_summaries(None, dirs=("runs",))),
    *[Case(f"build-map of a field named {name!r}", "silent",
           ["build-map", W + "/f.yaml", "--resolution", "0.5"], 1,
           "is not a plain name (letters, digits", setup=_setup_field({"name": name}))
      for name in ("../escaped", "/tmp/abs-x", "", "a\nb")],
    Case("batch of a field named ../../escaped-batch", "silent",
         ["batch", W + "/spec.yaml", "-o", W + "/sb/res", "--serial"], 1,
         "field name '../../escaped-batch' is not a plain name", setup=_setup_batch_field_name),
    Case("field import --name with a newline and a YAML key", "silent",
         ["field", "import", W + "/fd.cfg", "--format", "bhuman", "--name",
          "a\ncorner_arc_radius: 2 #", "-o", W + "/x.yaml"], 1,
         "--name: field name 'a\\ncorner_arc_radius: 2 #' is not a plain name",
         setup=_setup_team_file),
    *[Case(f"extract -c {kv}", kind, ["extract", "{omni}", "-o", W + "/f.h5", "-c", kv], 1, msg)
      for kv, kind, msg in (
        ("scanlines.max_range=0.1", "traceback",
         "conf 'scanlines': need 0 <= robot_radius < spiral_end_radius <= max_range, got 0.25,"
         " 2, 0.1"),
        ("scanlines.robot_radius=5", "silent",
         "need 0 <= robot_radius < spiral_end_radius <= max_range, got 5, 2, 4"),
        ("scanlines.spiral_end_radius=0.1", "silent",
         "need 0 <= robot_radius < spiral_end_radius <= max_range, got 0.25, 0.1, 4"),
        ("max_white_m=-1", "silent", "conf 'max_white_m' must be > 0 and <= 5"),
        ("max_white_m=1e9", "silent", "conf 'max_white_m' must be > 0 and <= 5"))],
    Case("show points -c scanlines.max_range=0.1", "traceback",
         ["show", "points", "{omni}", "--frame", "0", "-o", W + "/p.png", "-c",
          "scanlines.max_range=0.1"], 1, "need 0 <= robot_radius < spiral_end_radius"),
    Case("extract of a calib.yaml with an unknown key under intrinsics", "silent",
         ["extract", W + "/kid", "-o", W + "/f.h5"], 1,
         "unknown key 'intrinsics.extra' (intrinsics: fx, fy, cx, cy)",
         setup=_edit_intrinsics(extra=1)),
    *[Case(f"extract of a calib.yaml with intrinsics {values}", "traceback",
           ["extract", W + "/kid", "-o", W + "/f.h5"], 1, msg,
           setup=_edit_intrinsics(**values)) for values, msg in (
        ({"fx": 1e-9}, "focal lengths fx, fy must be > 0, between 0.05 and 100 times"),
        ({"fy": 1e9}, "focal lengths fx, fy must be > 0, between 0.05 and 100 times"),
        ({"cx": 1e9}, "the principal point cx, cy must lie in the image"),
        ({"cy": -5000}, "the principal point cx, cy must lie in the image"))],
    *[Case(f"a batch SPEC's extract: {text} on {ds} only", "silent",
           ["batch", W + "/spec.yaml", "-o", W + "/res", "--serial"], 1, msg,
           setup=_setup_extract_spec(ds, text, method)) for ds, text, method, msg in (
        ("omni", "{omni: real, perspective: bogus}", "lut", "extract.perspective: unknown"),
        ("kid", "{omni: bogus}", "mcl", "extract.omni: unknown"))],
    # ------------------------------------------------ s53 hostile2 F5-F7, simulate's scalars
    *[Case(f"simulate scalar -c {key}={value}", kind,
           [*(SIM_NAO if key.startswith("perspective.") else SIM_OMNI), "-c", f"{key}={value}"],
           1, SCALAR_FRAGMENTS.get(key, f"conf '{key}' must be"))
      for key, value, kind in SIMULATE_SCALAR_FAULTS],
    *[Case(f"simulate scalar -c {kv}", "traceback", [*SIM_OMNI, "-c", kv], 1, msg)
      for kv, msg in (  # keys in range that disagree with the mirror (omni_renderer.check_conf)
        ("omni.rim_radius=10", "'omni.body_radius' must be below the outer valid radius and"),
        ("omni.body_radius=300", "'omni.body_radius' must be below the outer valid radius and"))],
    # ------------------------------------------------------- s54: stamps beyond 1e11 s
    *[Case(f"{name} stamps x {factor:g}", "traceback", args, 1,
           "s is beyond 1e+11 s (the year 5000); stamps are seconds, not ms or ns",
           setup=_with_ds("omni", _stamp_times(name, factor)))
      for name, factor, args in (
        ("frames.csv", 1e12, ["localize", W + "/omni", "--map", "{map}", "-o", W + "/p.h5"]),
        ("odometry.csv", 1e299, ["localize", W + "/omni", "--map", "{map}", "-o",
                                 W + "/p.h5"]),
        ("truth.csv", 1e12, ["evaluate", "{poses}", "--truth", W + "/omni", "-o",
                             W + "/rep"]))],
    Case("features whose first stamp is 1e300", "traceback",
         [*LOCALIZE[:5], W + "/f.h5", "-o", W + "/p.h5"], 1,
         "stamp 1e+300 s is beyond 1e+11 s",
         setup=_setup_damaged("features", "f.h5", _nan_first("index/stamp", 1e300))),
    # --------------------------------------------- s54: the s53 leftovers ("worth a look")
    *[Case(f"calibrate --valid-radius {lo} {hi}", "silent",
           ["calibrate", "omni", "{marks}", "-o", W + "/c.yaml", "--centre", "240", "240",
            "--image-size", "480", "480", "--valid-radius", lo, hi], 1,
           "px lies beyond the 480 x 480 image (its farthest corner is 339 px from the centre)")
      for lo, hi in (("40", "1e300"), ("1e300", "1e301"), ("40", "1e9"))],
    *[Case(f"show map {' '.join(more)} on a table that ignores it", "silent",
           ["show", "map", "{map}", "-o", W + "/m.png", *more], 1, msg) for more, msg in (
        (["--cell", "1", "1"], "cell: drawn only from a cell of the radial or spiral table"),
        (["--heading-deg", "30"], "heading: drawn only from a cell of the radial or spiral"),
        (["--table", "radial", "--cell", "1", "1", "--spirals", "3"],
         "family, spirals: drawn only on the spiral table"))],
    *[Case(f"a batch SPEC with {what}, refused before anything runs", "silent",
           ["batch", W + "/spec.yaml", "-o", W + "/res", "--serial"], 1, msg,
           setup=_setup_spec(head + "datasets:\n  - simulate: {{preset: omni-clean, field:"
                             " spl, frames: 2}}\nmethods: " + methods + "\n"))
      for what, head, methods, msg in (
        ("build_map resolution -1", "field: spl\nbuild_map: {{resolution: -1}}\n", "[lut]",
         "build_map: resolution must be > 0 and border >= 0"),
        ("a method's heading 'nosuch'", "field: spl\n",
         "[{{method: lut, conf: ['heading=nosuch']}}]", "unknown heading source 'nosuch'"),
        ("a field YAML as its map", "map: {field}\n", "[lut]", "not an HDF5 file"))],
    Case("a batch dataset's frames: 10000000, refused before anything runs", "silent",
         ["batch", W + "/spec.yaml", "-o", W + "/res", "--serial"], 1,
         "frames must be a whole number from 1 to 1000000, got 10000000",
         setup=_setup_spec("field: spl\ndatasets:\n  - simulate: {{preset: omni-clean, field:"
                           " spl, frames: 10000000}}\nmethods: [lut]\n")),
    Case("simulate perspective --pitch-deg 1e9: the range in degrees, as given", "newcomer",
         [*SIM_NAO, "--pitch-deg", "1e9"], 2, "1e+09 is not within [-180, 180]"),
    Case("field import /dev/null", "newcomer",
         ["field", "import", "/dev/null", "--format", "bhuman", "-o", W + "/x.yaml"], 1,
         "field file is not a regular file (a device, pipe or"),
    Case("a user's files in the map's .lookup folder stay", "data-lost",
         ["localize", "{omni}", "--map", W + "/m.map.h5", "--features", "{features}", "-o",
          W + "/p.h5"], 0, "4 frames", setup=_setup_lookup_with_notes),
    Case("--overwrite onto a poses file made read-only (chmod 444)", "data-lost",
         ["localize", "{omni}", "--map", "{map}", "--features", "{features}", "-o",
          W + "/kept.h5", "--overwrite"], 1, "kept.h5 is read-only: --overwrite does not",
         setup=_setup_read_only_poses),
    Case("evaluate --overwrite onto a report folder whose errors.csv is read-only", "data-lost",
         ["evaluate", "{poses}", "-o", W + "/runs/a", "--overwrite"], 1,
         "errors.csv is read-only: --overwrite does not",
         setup=_setup_report_copy_read_only),
    # ------------------------------------- s54: --overwrite onto a user's file of the name
    *[Case(f"--overwrite onto a user's file: {' '.join(args[:2])} -o {Path(args[-1]).name}",
           "data-lost",
           [*args, "--overwrite"], 1, "was not written by fieldloc: --overwrite replaces only",
           setup=_setup_users_outputs) for args in (
        ["localize", "{omni}", "--map", "{map}", "--features", "{features}", "-o",
         W + "/mine.h5"],
        ["build-map", "spl", "-o", W + "/mine.h5"],
        ["export", "{poses}", "--format", "csv", "-o", W + "/notes.csv"],
        ["export", "{poses}", "--format", "json", "-o", W + "/notes.json"],
        ["export", "{poses}", "--format", "tum", "-o", W + "/traj.tum"],
        ["show", "map", "{map}", "-o", W + "/photo.png"],
        ["show", "map", "{map}", "-o", W + "/photo.jpg"],
        ["calibrate", "omni", "{marks}", "--centre", "240", "240", "--image-size", "480",
         "480", "--valid-radius", "40", "230", "-o", W + "/calib.yaml"],
        ["field", "import", W + "/fd.cfg", "--format", "bhuman", "-o", W + "/field.yaml"])],
    # ---- s54 group H2: mcl conf, show belief, warnings
    *[Case(f"localize --method mcl -c {kv}", kind,
           ["localize", "{kid}", "--map", "{kmap}", "--features", "{kid_features}",
            "--method", "mcl", "-o", W + "/p.h5", "-c", kv], 1, msg) for kv, kind, msg in (
        ("imu_heading_sigma=1e-308", "traceback",
         "conf 'imu_heading_sigma' must be >= 0.001 and <= 3.14159, got 1e-308"),
        ("imu_heading_sigma=[0.2]", "traceback", "conf 'imu_heading_sigma' must be a number"),
        ("observation.camera_height=[1, 2]", "traceback",
         "conf 'observation.camera_height' must be a number, got [1, 2]"),
        ("observation.camera_height=1e-308", "silent",
         "conf 'observation.camera_height' must be >= 0.001 and <= 10, got 1e-308"),
        ("min_confidence=-1", "silent", "conf 'min_confidence' must be >= 0 and <= 1, got -1"),
        ("min_confidence=1e308", "silent", "conf 'min_confidence' must be >= 0 and <= 1"))],
    Case("localize --method mcl -c init=pose -c init_pose=[0,0,1e308]", "silent",
         ["localize", "{kid}", "--map", "{kmap}", "--features", "{kid_features}", "--method",
          "mcl", "-o", W + "/p.h5", "-c", "init=pose", "-c", "init_pose=[0,0,1e308]"], 1,
         "init_pose heading 1e+308 rad is not within +-2 pi"),
    Case("a batch SPEC's mcl conf {min_confidence: -1}, refused before anything runs", "silent",
         ["batch", W + "/spec.yaml", "-o", W + "/res", "--serial"], 1,
         "methods[0]: conf 'min_confidence' must be >= 0 and <= 1, got -1",
         setup=_setup_spec(_spec_with(methods="[{{method: mcl, conf: {{min_confidence: -1}}}}]",
                                      preset="perspective-clean"))),
    *[Case(f"show belief {' '.join(more)}", kind,
           ["show", "belief", "{kid}", "--frame", "0", "--map", "{kmap}", "--features",
            "{kid_features}", "-o", W + "/b.png", *more], 1, msg) for more, kind, msg in (
        (["--resolution", "1e-308"], "traceback",
         "belief grid: resolution 1e-308 m is finer than 0.01 m"),
        (["--heading-step-deg", "1e-308"], "traceback",
         "belief grid: heading step 1e-308 deg is finer than 0.1 deg"),
        (["--resolution", "1e-3"], "hang", "belief grid: resolution 0.001 m is finer than"),
        (["--heading-step-deg", "1e-3"], "hang",
         "belief grid: heading step 0.001 deg is finer than 0.1 deg"),
        (["--heading-step-deg", "1e-4"], "hang", "heading step 0.0001 deg is finer than"),
        (["--resolution", "0.01", "--heading-step-deg", "0.01"], "hang",
         "heading step 0.01 deg is finer than 0.1 deg"),
        (["--resolution", "0.01", "--heading-step-deg", "0.1"], "hang",
         "belief grid: 1001 x 701 positions x 3600 headings is 2.53e+09 poses, more than 2e+08"),
        (["-c", "margin=1e308"], "traceback", "conf 'margin' must be >= 0 and <= 10"),
        (["-c", "arrow_spacing=1e308"], "traceback", "conf 'arrow_spacing' must be > 0"),
        (["-c", "observation.camera_height=[1, 2]"], "traceback",
         "conf 'observation.camera_height' must be a number, got [1, 2]"),
        (["-c", "observation.camera_height=1e-308"], "silent",
         "conf 'observation.camera_height' must be >= 0.001 and <= 10"))],
    *[Case(f"simulate {kind_} --calib-error {' '.join(err)}", "newcomer",
           ["simulate", kind_, "--field", "spl", "--frames", "2", "-o", W + "/sim",
            "--calib-error", *err], 1, "conf 'calib_error.scale' must be >= 0.5 and <= 2")
      for kind_ in ("omni", "perspective") for err in (("1", "0", "1e308"),
                                                      ("1e308", "1e308", "1e308"))],
    Case("perspective calib.yaml distortion[0] 1e308", "newcomer",
         ["extract", W + "/kid", "-o", W + "/f.h5"], 1,
         "'distortion' coefficients must lie within +-100, got [1e+308, 0,",
         setup=_with_ds("kid", lambda ds: edit_calib(ds, distortion=[1e308, 0, 0, 0, 0]))),
    Case("perspective calib.yaml height 1e-308", "silent",
         ["extract", W + "/kid", "-o", W + "/f.h5"], 1, "'height' must be >= 0.001 and <= 10 m",
         setup=_with_ds("kid", lambda ds: edit_calib(ds, height=1e-308))),
    *[Case(f"show points --map M --pose {' '.join(pose)}", "newcomer",
           ["show", "points", "{omni}", "--frame", "0", "--features", "{features}", "--map",
            "{map}", "-o", W + "/p.png", "--pose", *pose], 1, msg) for pose, msg in (
        (("1e308", "1e308", "1e308"), "pose (1e+308, 1e+308) is off the field and its border"),
        (("0", "20", "0"), "pose (0, 20) is off the field and its border"),
        (("0", "0", "1e308"), "pose heading 1e+308 deg is not within +-360 deg"))],
    # ---- s54 group H3: damaged artifacts (map resolution, poses values, features distances,
    # templates numbers, rosbag odometry/IMU values)
    *[Case(f"a map whose resolution is {value:g} ({args[0]})", kind,
           [*args, W + "/m.h5", *more], 1, msg,
           setup=_setup_damaged("map", "m.h5", _attr("resolution", value)))
      for value, kind, msg in (
        (1e308, "traceback", "the resolution a finite number > 0 and <= 1 m"),
        (1e-308, "traceback", "its cells do not span the field spl"))
      for args, more in ((["localize", "{omni}", "--features", "{features}", "--map"],
                          ["-o", W + "/p.h5"]),
                         (["show", "map"], ["-o", W + "/m.png"]))],
    Case("evaluate of poses whose method attribute is 100,000 characters", "hang",
         ["evaluate", W + "/p.h5", "--truth", "{omni}", "-o", W + "/rep"], 1,
         "(attribute 'method' holds 100000 characters, 'xxxxxxxxxxxxxxxxxxxx'...; expected at"
         " most 64)", setup=_setup_damaged("poses", "p.h5", _attr("method", "x" * 100000))),
    *[Case(f"{' '.join(cmd)}{' ' + more[1] if cmd == ['export'] else ''} of poses whose"
           f" /poses/{col} is all {value}", kind, [*cmd, W + "/p.h5", *more], 1, msg,
           setup=_setup_damaged("poses", "p.h5", _fill(f"poses/{col}", value)))
      for col, value, kind, cmd, more, msg in (
        ("stamp", math.nan, "silent", ["evaluate"], EVALUATE_MORE,
         "(frame 000000: stamp nan is not a finite number)"),
        ("confidence", math.nan, "silent", ["evaluate"], EVALUATE_MORE,
         "(/poses/confidence of frame 000000 is nan; expected a probability from 0 to 1)"),
        ("confidence", 1e30, "silent", ["evaluate"], EVALUATE_MORE,
         "(/poses/confidence of frame 000000 is 1e+30; expected a probability from 0 to 1)"),
        ("confidence", -0.5, "silent", ["export"],
         ["--format", "csv", "-o", W + "/o.csv"],
         "(/poses/confidence of frame 000000 is -0.5; expected a probability from 0 to 1)"),
        ("theta", math.inf, "silent", ["export"], ["--format", "csv", "-o", W + "/o.csv"],
         "(/poses/theta of frame 000000 is inf; expected NaN or a number within 1e+06)"),
        ("theta", math.inf, "silent", ["export"],
         ["--format", "json", "-o", W + "/o.json"],
         "(/poses/theta of frame 000000 is inf; expected NaN or a number within 1e+06)"),
        ("x", 1e300, "silent", ["show", "hypotheses"],
         ["--frame", "1", "-o", W + "/h.png"],
         "(/poses/x of frame 000000 is 1e+300; expected NaN or a number within 1e+06)"))],
    Case("export of poses whose hypotheses hold a probability of 7", "silent",
         ["export", W + "/p.h5", "--format", "csv", "-o", W + "/o.csv"], 1,
         "/hypotheses of frame 000000: row 0 column 3 is 7; expected a pose within 1e+06 and a"
         " probability from 0 to 1", setup=_setup_damaged("poses", "p.h5", _fill(
             "hypotheses", 7.0))),
    *[Case(f"localize of features whose /data/radial is all {value:g}", "silent",
           [*LOCALIZE[:5], W + "/f.h5", "-o", W + "/p.h5"], 1,
           f"'radial' holds the distance {value:g} m; expected 0 to 100 m, or NaN for none",
           setup=_setup_damaged("features", "f.h5", _fill("data/radial", value)))
      for value in (-5.0, 1e30)],
    Case("show points of features whose /data/spiral is all -1", "silent",
         ["show", "points", "{omni}", "--frame", "0", "--features", W + "/f.h5", "-o",
          W + "/p.png"], 1, "'spiral' holds the distance -1 m",
         setup=_setup_damaged("features", "f.h5", _fill("data/spiral", -1.0))),
    *[Case(f"localize --method templates on templates whose {path} are all {value:g}", "silent",
           ["localize", "{omni}", "--method", "templates", "--templates", W + "/t.h5", "-o",
            W + "/p.h5"], 1, msg, setup=_setup_damaged("templates", "t.h5", _fill(path, value)))
      for path, value, msg in (
        ("poses", math.nan, "damaged 'fieldloc.templates' file: poses holds nan where finite"),
        ("poses", 1e300, "poses holds 1e+300 m; positions on a field lie within 1e+06 m"),
        ("descriptors", math.nan, "descriptors holds nan where finite numbers belong"),
        ("points", math.nan, "points holds nan where finite numbers belong"))],
    *[Case(f"import rosbag whose {what}", "silent", IMPORT_BAG, 1, msg,
           setup=_setup_odometry_bag(odometry, imu))
      for what, odometry, imu, msg in (
        ("odometry x is 1e308 in every message",
         [(t, 1e308, 0.0, 0.0) for t, *_ in GOOD_ODOMETRY], GOOD_IMU,
         "none of the 9 odometry message(s) on /odom is usable (first: position (1e+308,"),
        ("odometry x is NaN in every message",
         [(t, math.nan, 0.0, 0.0) for t, *_ in GOOD_ODOMETRY], GOOD_IMU,
         "none of the 9 odometry message(s) on /odom is usable (first: values (nan,"),
        ("IMU yaw is NaN in every message", GOOD_ODOMETRY,
         [(t, math.nan) for t, _ in GOOD_IMU],
         "none of the 9 IMU message(s) on /imu is usable (first: values"))],
    *[Case(f"import rosbag whose {what}: dropped with one warning", "silent", IMPORT_BAG, 0,
           msg, setup=_setup_odometry_bag(odometry, imu, stamps),
           check=_check_dataset_readable)
      for what, odometry, imu, stamps, msg in (
        ("one odometry message holds NaN",
         [*GOOD_ODOMETRY[:4], (GOOD_ODOMETRY[4][0], math.nan, 0.0, 0.0), *GOOD_ODOMETRY[5:]],
         GOOD_IMU, (1.0, 1.1, 1.2, 1.3),
         "/odom: 1 of 9 odometry message(s) dropped as unusable (first: values (nan,"),
        ("one IMU message holds a yaw of NaN", GOOD_ODOMETRY,
         [*GOOD_IMU[:3], (GOOD_IMU[3][0], math.nan), *GOOD_IMU[4:]], (1.0, 1.1, 1.2, 1.3),
         "/imu: 1 of 9 IMU message(s) dropped as unusable"),
        ("frames repeat a stamp", GOOD_ODOMETRY, GOOD_IMU, (1.0, 1.1, 1.1, 1.1, 1.2),
         "/cam: 2 frame(s) repeat an earlier frame's stamp; dropped"))],
    # ---- s54 group H1: numbers (one strict reading of a number a user wrote: no bool, no
    # integer beyond the float range, finite; stages.common.user_numbers)
    *[Case(f"-c {key}=<400 digits>: {' '.join(args[:2])}", "traceback",
           [*args, "-c", f"{key}={HUGE}"], 1,
           f"conf '{key}' must be a {kind}number within the float range, got an integer too",
           setup=_setup_one_bag if args[0] == "import" else None)
      for args, key, kind in (
        ([*LOCALIZE, "-o", W + "/p.h5", "--method", "lut"], "hypotheses", "whole "),
        ([*LOCALIZE, "-o", W + "/p.h5", "--method", "lut"], "min_confidence", ""),
        ([*LOCALIZE, "-o", W + "/p.h5", "--method", "mcl"], "observation.camera_height", ""),
        ([*LOCALIZE, "-o", W + "/p.h5", "--method", "mcl"], "particles_max", "whole "),
        (["extract", "{omni}", "-o", W + "/f.h5"], "max_white_m", ""),
        ([*SIM_OMNI], "scene.robots", "whole "),
        (["import", "rosbag", W + "/x.bag", "-o", W + "/ds", "--image-topic", "/cam"],
         "png_compression", "whole "))],
    Case("-c thresholds=[<400 digits>] (a list element)", "traceback",
         ["evaluate", "{poses}", "--truth", "{omni}", "-o", W + "/r", "-c",
          f"thresholds=[0.1, {HUGE}]"], 1,
         "conf 'thresholds[1]' must be a number within the float range"),
    Case("report --worst <400 digits>", "traceback",
         ["report", "{omni}/runs/r", "-o", W + "/r.html", "--worst", HUGE], 1,
         "conf 'worst' must be a whole number within the float range"),
    Case("batch SPEC conf {hypotheses: <400 digits>}", "traceback",
         ["batch", W + "/spec.yaml", "-o", W + "/res", "--serial"], 1,
         "'hypotheses' must be a whole number within the float range",
         setup=_setup_huge_spec),
    *[Case(f"{name} calib.yaml {key}: <400 digits>", "traceback",
           ["extract", W + f"/{name}", "-o", W + "/f.h5"], 1,
           f"'{shown_key}' must be a {kind}number within the float range",
           setup=_with_yaml_value(name, "calib.yaml", key, HUGE))
      for name, key, shown_key, kind in (
        ("omni", "polynomial.1", "polynomial[1]", ""),
        ("omni", "centre.0", "centre[0]", ""),
        ("omni", "image_size.0", "image_size[0]", "whole "),
        ("omni", "forward_angle", "forward_angle", ""),
        ("kid", "intrinsics.fx", "intrinsics.fx", ""),
        ("kid", "distortion.0", "distortion[0]", ""),
        ("kid", "height", "height", ""),
        ("kid", "image_size.1", "image_size[1]", "whole "))],
    Case("simulation.yaml field_size: [<400 digits>, 6]", "traceback",
         ["extract", W + "/omni", "-o", W + "/f.h5"], 1,
         "field_size[0] must be a number within the float range",
         setup=_with_yaml_value("omni", "simulation.yaml", "field_size.0", HUGE)),
    *[Case(f"field import of a {fmt} file holding a 400-digit integer", "traceback",
           ["field", "import", W + f"/{file}", "-o", W + "/out.yaml"], 1,
           f"'{key}' must be a number within the float range",
           setup=_setup_number_file(file, text)) for fmt, file, key, text in (
        ("hulks", "field.json", "length",
         '{"field_dimensions": {"length": HUGE, "width": 6.0}}'),
        ("cambada", "field.json", "field_length",
         '{"field_length": HUGE, "field_width": 12000, "line_thickness": 125,'
         ' "center_circle_radius": 2000, "goal_band_width": 1000, "side_band_width": 1000}'),
        ("bitbots", "config.yaml", "size.x",
         "parameter_blackboard:\n  ros__parameters:\n    field:\n      size: {x: HUGE}\n"),
        ("falcons", "DefaultParams.json", "A", '{"model": {"A": HUGE, "B": 12000, "K": 125}}'))],
    Case("simulate --grid 1e-308", "traceback",
         ["simulate", "omni", "--field", "spl", "-o", W + "/sim", "--grid", "1e-308"], 1,
         "makes more than 1000000 nodes along one side"),
    *[Case(f"{name} calib.yaml {key}: {raw} (a YAML boolean)", "silent",
           ["extract", W + f"/{name}", "-o", W + "/f.h5"], 1,
           f"'{shown_key}' must be a {kind}number, got True",
           setup=_with_yaml_value(name, "calib.yaml", key, raw))
      for name, key, shown_key, raw, kind in (
        ("omni", "polynomial.1", "polynomial[1]", "yes", ""),
        ("omni", "forward_angle", "forward_angle", "yes", ""),
        ("omni", "image_size.0", "image_size[0]", "true", "whole "),
        ("kid", "height", "height", "yes", ""),
        ("kid", "distortion.0", "distortion[0]", "yes", ""),
        ("kid", "intrinsics.cx", "intrinsics.cx", "true", ""))],
    *[Case(f"calib image_size {size}: one line, not a warning per frame", "newcomer",
           ["extract", W + "/omni", "-o", W + "/f.h5"], 1,
           "'image_size' must be [width, height] in whole pixels from 1 to 8192",
           setup=_with_ds("omni", lambda ds, size=size: edit_calib(ds, image_size=size)))
      for size in ([1e308, 480], [480, 8193])],
    # ---- s54 group H4: files and interruptions
    Case("simulate --overwrite of its dataset holding a user's picture in images/", "data-lost",
         ["simulate", "omni", "--field", "spl", "-o", W + "/data", "--frames", "1",
          "--overwrite"], 1, "images/000005.png, which simulate did not write",
         setup=_setup_simulated_with_picture),
    Case("bench --from-json a FIFO", "hang", ["bench", "--from-json", W + "/fifo"], 1,
         "fifo: is not a regular file (a device, pipe or socket), not a bench --json file",
         setup=_setup_fifo),
    Case("bench --from-json of a file larger than any bench run's", "silent",
         ["bench", "--from-json", W + "/big.json"], 1,
         "big.json: larger than 16 MiB, not a bench --json file", setup=_setup_big_json),
    Case("localize -o a name with a line break: its summary on one line", "newcomer",
         ["localize", "{omni}", "--map", "{map}", "--features", "{features}", "-o",
          W + "/o\nut.h5"], 0, "o ut.h5: 4 frames", check=_check_one_summary_line),
    Case("simulate -o a name with a line break: its summary on one line", "newcomer",
         ["simulate", "omni", "--field", "spl", "--frames", "1", "-o", W + "/s\nx"], 0,
         "/s x", check=_check_one_summary_line),
    # ---- s54 trial C: forged marks, an empty bag topic
    *[Case(f"--overwrite onto {name}, which only mentions fieldloc", "data-lost",
           ["build-map", "spl", "--resolution", "0.5", "-o", W + "/" + name, "--overwrite"], 1,
           "was not written by fieldloc", setup=_setup_forged_marks)
      for name in ("note.h5", "mine.h5")],
    Case("import rosbag --imu-topic of a topic without a message", "traceback",
         IMPORT_BAG, 1, "the IMU topic /imu holds no message",
         setup=_setup_odometry_bag(GOOD_ODOMETRY, [])),
    # ---- s54 trial C: YAML 1.1 numbers, huge integers in a field YAML
    *[Case(f"build-map of a field YAML with corner_arc_radius: {text[:12]}", kind,
           ["build-map", W + "/f.yaml", "-o", W + "/m.h5"], 1, msg,
           setup=_setup_field_text(f"corner_arc_radius: {text}\n"))
      for text, kind, msg in (
        ("1:30", "silent", "'1:30' is no decimal number (YAML 1.1's base 60"),
        ("0x1", "silent", "'0x1' is no decimal number"),
        ("1_0", "silent", "'1_0' is no decimal number"),
        ("9" * 400, "traceback", "an integer too large for it"))],
    Case("localize -c hypotheses=0x10: no hex", "silent",
         [*LOCALIZE, "-o", W + "/p.h5", "-c", "hypotheses=0x10"], 1, "'0x10'"),
    # ---- s54 trial C: a batch.json's version, inspect of a PNG claiming 1e10 px
    *[Case(f"evaluate --table on a batch.json of schema_version {value}", "traceback",
           ["evaluate", "--table", W + "/res"], 1,
           f"'fieldloc.batch' version {shown_as} is not supported",
           setup=_setup_batch_version(value))
      for value, shown_as in (("null", "nan"), ("[1]", "[1]"), ("true", "True"),
                              ("1.5", "1.5"))],
    Case("inspect a PNG whose header claims 100000 x 100000 px", "traceback",
         ["inspect", W + "/x.png"], 0, "image file that cannot be decoded",
         setup=_setup_png_claiming),
    Case("calibrate --from-cnc with a 1 x 1 px CarpetCalibImage.png", "traceback",
         ["calibrate", "omni", "--from-cnc", W + "/cnc/CarpetCalibrator.conf", "--rings",
          "detected", "-o", W + "/c.yaml"], 1,
         "the calibration picture is 1 x 1 px: too small to hold the rings",
         setup=_setup_cnc(lambda d: cv2.imwrite(str(d / "CarpetCalibImage.png"),
                                                np.zeros((1, 1, 3), np.uint8)))),
    Case("localize --points with a point at 1e308 m", "silent",
         ["localize", "{omni}", "--map", "{map}", "--points", W + "/pts.csv", "-o",
          W + "/p.h5"], 1, "x and y are metres from the robot, at most 1e+06; got 1e+308",
         setup=lambda w, ws: (ws / "pts.csv").write_text("frame,x,y\n000000,1e308,0\n")
         and {}),
    Case("build-map -o a symbolic link to a missing file", "newcomer",
         ["build-map", "spl", "--resolution", "0.5", "-o", W + "/dang.h5"], 1,
         "is a symbolic link to /nonexistent/x.h5, which does not exist",
         setup=lambda w, ws: os.symlink("/nonexistent/x.h5", ws / "dang.h5") or {}),
    # ---- s55 group F2: an image cut short (the one-line output is tested in a subprocess,
    # tests/test_cut_images_bags_and_signals.py: libjpeg and libpng print on the process's stderr)
    Case("extract of a dataset whose first frame is a JPEG cut in half", "silent",
         ["extract", "{ds}", "-o", W + "/f.h5"], 0,
         "(a JPEG file cut short: no end marker)",
         setup=_with_ds("omni", _cut_first_frame_to_jpeg)),
    # ---- s55 lead: the rerun's extract --overwrite over a user's file (A1 was not fixed
    # for extract, whose existing output is otherwise resumed)
    *[Case(f"extract --overwrite onto a user's {what}", "data-lost",
           ["extract", "{omni}", "-o", W + "/u.h5", "--overwrite"], 1,
           "u.h5 was not written by fieldloc: --overwrite replaces only fieldloc's",
           setup=lambda w, ws, data=data: (ws / "u.h5").write_bytes(data) and {})
      for what, data in (("text file", b"my notes\n"),
                         ("HDF5 file", b"\x89HDF\r\n\x1a\n" + bytes(600)))],
    # ---- s55 lead: trial D2's files of a user in extract's resume folder (P1-P3): extract
    # removes there only what it writes, and refuses a folder holding anything else
    *[Case(f"extract whose resume folder holds {what}", "data-lost",
           ["extract", "{omni}", "-o", W + "/f.h5"], 1,
           f"holds {name!r}, which extract did not write; move it out of the folder",
           setup=_setup_parts_of_this_run(_write(name, data)))
      for what, name, data in (
          ("a user's notes", "notes.txt", b"my notes\n"),
          ("a user's hidden file", ".mine", b"hidden\n"),
          ("a user's .npz that is no chunk", "results.npz", b"PK\x05\x06" + bytes(18)))],
    Case("extract whose resume folder holds another run's run.json and a user's file",
         "data-lost", ["extract", "{omni}", "-o", W + "/f.h5"], 1,
         "holds 'thesis.txt', which extract did not write",
         setup=_setup_parts_of_this_run(lambda d: (
             (d / "run.json").write_text('{"camera_kind": "omni", "calib_hash": "x",'
                                         ' "mask_hash": null, "conf": {}, "scanlines": null}'),
             (d / "thesis.txt").write_text("two years of work")))),
    Case("extract whose resume folder's name is a link to a user's folder", "data-lost",
         ["extract", "{omni}", "-o", W + "/f.h5"], 1,
         "is a link where extract keeps its resume folder",
         setup=lambda w, ws: ((ws / "mine").mkdir(), (ws / "mine" / ".hidden").write_text("h"),
                              os.symlink("mine", ws / ".f.h5.parts")) and {}),
    # ---- s55 lead: trial D1's user folder at extract's resume name
    Case("extract beside a user's folder at the name of its resume folder", "data-lost",
         ["extract", "{omni}", "-o", W + "/f.h5"], 1,
         "holds 'thesis.txt', which extract did not write; move it out of the folder",
         setup=_setup_users_parts_folder),
    # ---- s55 group F1: fieldloc folders' files replaced only as written (C4), features of
    # another dataset in the pictures (C17)
    *[Case(f"evaluate --overwrite of a report whose {name} was edited", "data-lost",
           ["evaluate", "{poses}", "--truth", "{omni}", "-o", W + "/rep", "--overwrite"], 1,
           f"rep/{name} was edited since fieldloc wrote it" if name[0] != "p" else
           f"rep/{name} is not among the files",  # no trajectory plot of 4 frames: a new file
           setup=_setup_report_edited(name, text))
      for name, text in (("errors.csv", b"# mine\n"), ("truth.tum", b"# mine\n"),
                         ("plots/trajectory.png", b"my own picture"))],
    *[Case(f"simulate --overwrite of a dataset whose {name} was edited", "data-lost",
           ["simulate", "omni", "--preset", "omni-clean", "--field", "spl", "--frames", "1",
            "-o", W + "/data", "--overwrite"], 1,
           f"data/{name} was edited since fieldloc wrote it; --overwrite replaces only",
           setup=_setup_simulated_edited(name))
      for name in ("truth.csv", "images/000000.png", "calib.yaml")],
    Case("extract --debug-images --overwrite over a user's picture named as an overlay",
         "data-lost",
         ["extract", "{omni}", "-o", W + "/f.h5", "--debug-images", W + "/dbg", "--overwrite"],
         1, "dbg's debug-images.yaml lists no written_files (an older fieldloc's record",
         setup=_setup_debug_folder_with_picture),
    Case("import rosbag --overwrite of a dataset whose odometry.csv was edited", "data-lost",
         [*IMPORT_BAG, "--overwrite"], 1, "ds/odometry.csv was edited since fieldloc wrote it",
         setup=_setup_imported_edited(
             lambda ds: (ds / "odometry.csv").write_text("stamp,dx,dy,dtheta\n"))),
    Case("import rosbag --overwrite of a dataset holding a user's notes", "data-lost",
         [*IMPORT_BAG, "--overwrite"], 1,
         "ds/notes.txt was not written by fieldloc import rosbag: --overwrite would delete it",
         setup=_setup_imported_edited(lambda ds: (ds / "notes.txt").write_text("mine"))),
    Case("show belief of an omni dataset with a perspective dataset's features", "silent",
         ["show", "belief", "{omni}", "--map", "{map}", "--features", "{kid_features}",
          "--frame", "0", "--resolution", "0.5", "-o", W + "/b.png"], 1,
         "features of a 'perspective' camera, "),
    Case("show points of an omni dataset with a perspective dataset's features", "silent",
         ["show", "points", "{omni}", "--features", "{kid_features}", "--frame", "0", "-o",
          W + "/s.png"], 1, "features of a 'perspective' camera, "),
    *[Case(f"{what} with features of another recording (other stamps)", "silent",
           args, 1, "frame 000001 is at", setup=_setup_other_stamps)
      for what, args in (
          ("show points", ["show", "points", "{ds}", "--features", "{features}", "--frame",
                           "0", "-o", W + "/s.png"]),
          ("show belief", ["show", "belief", "{ds}", "--map", "{map}", "--features",
                           "{features}", "--frame", "0", "--resolution", "0.5", "-o",
                           W + "/b.png"]),
          ("localize", ["localize", "{ds}", "--map", "{map}", "--features", "{features}",
                        "-o", W + "/p.h5"]))],
    # ---- s55 group F5: an importer's folder with a damaged written_files table (W1)
    *[Case(f"import rosbag --overwrite of a dataset holding a user's notes, {what}",
           "data-lost", [*IMPORT_BAG, "--overwrite"], 1,
           "ds's import.yaml lists no written_files (an older fieldloc's record, or damaged)",
           setup=_setup_imported_edited(_f5_damaged_table(value)))
      for what, value in (("written_files a list", [1]), ("written_files a string", "a"),
                          ("no written_files", "del"))],
    *[Case(f"calibrate --from-hulks FOLDER --overwrite of its dataset holding {extra}, {what}",
           "data-lost", ["calibrate", "perspective", "--from-hulks", W + "/hulks", "-o",
                         W + "/out", "--overwrite"], 1,
           "out's import.yaml lists no written_files (an older fieldloc's record, or damaged)",
           setup=_setup_hulks_imported(value, extra))
      for what, value, extra in (("written_files a list", [1], "notes.txt"),
                                 ("no written_files", "del", "images/mine.txt"))],
    # ---- s55 group F5: a file simulate's written_files table does not list (W4)
    *[Case(f"simulate --overwrite of its dataset of frames: {n!r} holding a user's picture",
           "data-lost", ["simulate", "omni", "--field", "spl", "-o", W + "/data", "--frames",
                         "1", "--overwrite"], 1,
           "data/images/000009.png, which simulate did not write",
           setup=_setup_simulated_frames_with_picture(n))
      for n in (99999999, "many", 20)],
    # ---- s55 group F5: a user's file at a report's plots/ (W3)
    Case("evaluate --overwrite of a report whose plots/ is a user's file", "data-lost",
         ["evaluate", "{poses}", "--truth", "{omni}", "-o", W + "/rep", "--overwrite"], 1,
         "rep/plots is not part of a report written by fieldloc evaluate",
         setup=_setup_report_plots_a_file),
    # ---- s56 group G1: --overwrite replaces only a file fieldloc can vouch for (W2, W5)
    *[Case(f"simulate --overwrite of its dataset whose record's written_files is {what}, {edit}",
           "data-lost", ["simulate", "omni", "--preset", "omni-clean", "--field", "spl",
                         "--frames", "1", "-o", W + "/data", "--overwrite"], 1,
           "data's simulation.yaml lists no written_files (an older fieldloc's record, or"
           " damaged): --overwrite cannot tell an edited file from fieldloc's",
           setup=_g1_simulated_table(value, change))
      for what, value, edit, change in (
          ("a list", [1, 2], "truth.csv edited", lambda d: _g1_same_size_edit(d / "truth.csv")),
          ("a string", "x", "truth.csv edited", lambda d: _g1_same_size_edit(d / "truth.csv")),
          ("null", None, "truth.csv edited", lambda d: _g1_same_size_edit(d / "truth.csv")),
          ("absent", "del", "truth.csv edited", lambda d: _g1_same_size_edit(d / "truth.csv")),
          ("absent", "del", "a row added to truth.csv",
           lambda d: (d / "truth.csv").write_text((d / "truth.csv").read_text() + "9,9,9,9\n")),
          ("absent", "del", "a user's picture as its image",
           lambda d: (d / "images" / "000000.png").write_bytes(b"my own picture")))],
    *[Case(f"evaluate --overwrite of a report whose written_files is {what}, {name} edited",
           "data-lost", ["evaluate", "{poses}", "--truth", "{omni}", "-o", W + "/rep",
                         "--overwrite"], 1,
           "rep's report.json lists no written_files (an older fieldloc's record, or damaged)",
           setup=_g1_report_table(value, name))
      for what, value, name in (("a list", [1], "errors.csv"), ("absent", "del", "errors.csv"),
                                ("absent", "del", "truth.tum"))],
    Case("extract --debug-images --overwrite over an overlay edited keeping its mark",
         "data-lost",
         ["extract", "{omni}", "-o", W + "/f.h5", "--debug-images", W + "/dbg", "--overwrite"],
         1, "dbg/000001.png was edited since fieldloc wrote it",
         setup=_g1_overlay_edited_keeping_mark),
    *[Case(f"localize --overwrite over a TUM twin: {what}", "data-lost",
           ["localize", "{omni}", "--map", "{map}", "--features", "{features}", "--method",
            "lut", "-o", W + "/p.h5", "--overwrite"], 1,
           "p.tum is not the TUM twin of p.h5 as fieldloc wrote it",
           setup=_g1_twin(change))
      for what, change in (("edited below its header", _g1_note_below_header),
                           ("a user's file with its header, no poses beside it",
                            _g1_users_copy_without_poses))],

    # ---- s56 group G2: features of another recording whose frames are named and stamped
    # alike, or of a frame re-encoded since (F1); a dataset cut after its extraction; frames of
    # other image kinds (I3); a PNG damaged under right CRCs (I2)
    *[Case(f"{what} with another simulated recording's features (same names and stamps)",
           "silent", args, 1, "frame 000000 was extracted from another image than",
           setup=_setup_other_recording)
      for what, args in (
          ("localize", ["localize", "{ds}", "--map", "{map}", "--features", "{features}",
                        "-o", W + "/p.h5"]),
          ("show belief", ["show", "belief", "{ds}", "--map", "{map}", "--features",
                           "{features}", "--frame", "1", "--resolution", "0.5", "-o",
                           W + "/b.png"]),
          ("show points", ["show", "points", "{ds}", "--features", "{features}", "--frame",
                           "1", "-o", W + "/s.png"]))],
    Case("localize with features of a frame re-encoded since its extraction", "silent",
         ["localize", "{ds}", "--map", "{map}", "--features", "{features}", "-o", W + "/p.h5"],
         1, "frame 000001 was extracted from another image than", setup=_setup_reencoded),
    Case("localize of a dataset cut to 2 frames with its features of 4: its frames only",
         "silent", ["localize", "{ds}", "--map", "{map}", "--features", "{features}", "-o",
                    W + "/p.h5"], 0, "", setup=_setup_cut_to_two, check=_check_two_frames),
    Case("show belief of a frame cut from the dataset, named, with the features of all",
         "silent", ["show", "belief", "{ds}", "--map", "{map}", "--features", "{features}",
                    "--frame", "000003", "--resolution", "0.5", "-o", W + "/b.png"], 1,
         "no frame named '000003'", setup=_setup_cut_to_two),
    *[Case(f"extract of a dataset with a {suffix} frame listed in frames.csv", "silent",
           ["extract", "{ds}", "-o", W + "/f.h5"], 0, "", setup=_setup_frame_as(suffix),
           check=_check_frames_extracted(4))
      for suffix in (".bmp", ".tiff", ".webp")],
    Case("extract of a dataset with a .gif frame listed in frames.csv", "silent",
         ["extract", "{ds}", "-o", W + "/f.h5"], 0,
         "1 frames are files of a kind fieldloc does not read or none of the images is"
         " (first: 000001.gif",
         setup=_setup_frame_as(".gif"), check=_check_frames_extracted(3)),
    Case("extract of a PNG frame whose IDAT data is damaged under right CRCs", "silent",
         ["extract", "{ds}", "-o", W + "/f.h5"], 0,
         "frame 000001 skipped: unreadable image: ", setup=_setup_idat_damaged_crc_right,
         check=_check_frames_extracted(3)),
    # ---- s56 group G3: one bounded line whatever a name holds (N2); inspect's specific line
    Case("inspect a simulation.yaml whose seed is 1_0", "newcomer",
         ["inspect", W + "/simulation.yaml"], 1,
         "('seed: 1_0'): '1_0' is no decimal number", setup=_g3_seed_1_0),
    *[Case(f"localize --features at a 3600-character path of {what}", "newcomer",
           ["localize", "{omni}", "--map", "{map}", "--features", W + "/" + path, "-o",
            W + "/p.h5"], 1, "fieldloc: error: file not found: ", check=_g3_bounded_line)
      # 3600+ characters: within the system's 4096 for a path with any test folder
      for what, path in (("spaced words", "/".join(["a " * 100] * 18) + "/none.h5"),
                         ("names without a space", "/".join(["b" * 200] * 18) + "/none.h5"))],
    # ---- s56 group W1: a fieldloc folder's record itself is never replaced once edited
    *[Case(f"simulate --overwrite of its dataset whose simulation.yaml has a user's {how}",
           "data-lost", ["simulate", "omni", "--preset", "omni-clean", "--field", "spl",
                         "--frames", "1", "-o", W + "/data", "--overwrite"], 1,
           "data/simulation.yaml was edited since fieldloc wrote it; --overwrite replaces only",
           setup=_w1_simulated(lambda rec, how=how: _w1_note(rec, how)))
      for how in ("comment", "key")],
    Case("simulate --overwrite of its dataset whose record does not list itself (older)",
         "data-lost", ["simulate", "omni", "--preset", "omni-clean", "--field", "spl",
                       "--frames", "1", "-o", W + "/data", "--overwrite"], 1,
         "data/simulation.yaml does not list itself in its written_files (an older fieldloc's",
         setup=_w1_simulated(_w1_self_entry_removed)),
    *[Case(f"import rosbag --overwrite of a dataset whose import.yaml has a user's {how}",
           "data-lost", [*IMPORT_BAG, "--overwrite"], 1,
           "ds/import.yaml was edited since fieldloc wrote it",
           setup=_setup_imported_edited(lambda ds, how=how: _w1_note(ds / "import.yaml", how)))
      for how in ("comment", "key")],
    *[Case(f"calibrate --from-hulks FOLDER --overwrite of its dataset, import.yaml with a {how}",
           "data-lost", ["calibrate", "perspective", "--from-hulks", W + "/hulks", "-o",
                         W + "/out", "--overwrite"], 1,
           "out/import.yaml was edited since fieldloc wrote it", setup=_w1_hulks_imported(how))
      for how in ("comment", "key")],
    *[Case(f"extract --debug-images --overwrite, debug-images.yaml with a user's {how}",
           "data-lost", ["extract", "{omni}", "-o", W + "/f.h5", "--debug-images", W + "/dbg",
                         "--overwrite"], 1,
           "dbg/debug-images.yaml was edited since fieldloc wrote it",
           setup=_w1_debug_images(how))
      for how in ("comment", "key")],
    Case("evaluate --overwrite of a report whose report.json has a key of the user's",
         "data-lost", ["evaluate", "{poses}", "--truth", "{omni}", "-o", W + "/rep",
                       "--overwrite"], 1, "rep/report.json was edited since fieldloc wrote it",
         setup=_w1_report),
    # ---- s57 group J: JPEG frames decoded by simplejpeg, a damaged scan in one line (and
    # nothing of libjpeg's: tests/test_cut_images_bags_and_signals.py runs a real process);
    # a header claiming too many pixels says how many; a frame given by its position whose
    # image was deleted is refused, not taken for the next
    Case("extract of a dataset whose first frame is a JPEG with damaged scan data", "silent",
         ["extract", "{ds}", "-o", W + "/f.h5"], 0,
         "000000.jpg (a damaged JPEG file: Corrupt JPEG data: ",
         setup=_with_ds("omni", _j_damaged_first_frame)),
    Case("show points of a frame that is a JPEG with damaged scan data", "silent",
         ["show", "points", "{ds}", "--frame", "0", "-o", W + "/b.png"], 1,
         "000000.jpg (a damaged JPEG file: Corrupt JPEG data: ",
         setup=_with_ds("omni", _j_damaged_first_frame)),
    *[Case(f"extract of a frame whose {kind} header claims {w} x {h} px", "hang",
           ["extract", W + "/omni", "-o", W + "/f.h5"], 0,
           f"000002.{kind} (its header claims {w} x {h} px, more than the 67,108,864 pixels"
           " fieldloc reads)", setup=_with_ds("omni", _j_claiming(kind, w, h)),
           check=_check_fifo_frame_failed)
      for kind, w, h in (("tiff", 20000, 20000), ("webp", 16383, 16383),
                         ("jpg", 65000, 65000), ("bmp", 30000, 30000))],
    *[Case(f"show points --frame {frame} --features, frame 000000's image deleted", "silent",
           ["show", "points", "{ds}", "--frame", frame, "--features", "{features}", "-o",
            W + "/b.png"], 1,
           "images/000000.png cannot be read: there is no such file (frames.csv lists it)",
           setup=_j_first_image_deleted)
      for frame in ("0", "000000")],
    # ---- s57 group K: image decoding (trial F)
    *[Case(f"extract of a frame that is a {kind} JPEG of trial F (damaged behind what went "
           "to OpenCV)", "silent", ["extract", "{ds}", "-o", W + "/f.h5"], 0,
           f"000002.jpg (a damaged JPEG file: {said}", setup=_with_ds("omni", _k_frame(
               "000002", kind)), check=_check_fifo_frame_failed)
      for kind, said in (("cmyk", "Corrupt JPEG data: "),
                         ("jfif", "Corrupt JPEG data: premature end of data segment)"),
                         ("adobe", "Corrupt JPEG data: "), ("sos", "Corrupt JPEG data: "),
                         ("marker", "Unsupported marker type 0x1c)"))],
    Case("show points of a frame that is a damaged CMYK JPEG", "silent",
         ["show", "points", "{ds}", "--frame", "2", "-o", W + "/b.png"], 1,
         "000002.jpg (a damaged JPEG file: Corrupt JPEG data: ",
         setup=_with_ds("omni", _k_frame("000002", "cmyk"))),
    Case("extract of a dataset whose mask is a damaged CMYK JPEG", "silent",
         ["extract", "{ds}", "-o", W + "/f.h5"], 1,
         "mask.png (a damaged JPEG file: Corrupt JPEG data: ",
         setup=_with_ds("omni", _k_cmyk_mask)),
    *[Case(f"extract of a perspective frame whose EXIF says turn it ({kind}): as stored",
           "silent", ["extract", "{ds}", "-o", W + "/f.h5"], 0,
           "frames (perspective camera)", setup=_with_ds("kid", _k_frame("000001", kind)),
           check=_check_all_frames_extracted)
      for kind in ("xmp-exif6", "png-exif6")],
    Case("extract of a frame of more JPEG segments than a camera's file has", "hang",
         ["extract", "{ds}", "-o", W + "/f.h5"], 0,
         "000002.jpg (a JPEG file of more than 4,096 marker segments)",
         setup=_with_ds("omni", _k_frame("000002", "segments")),
         check=_check_fifo_frame_failed),
    # ---- s57 group L: frames, names, signals (trial F)
    Case("show points --frame 0, its dotted-stem image deleted (1687078170.100)", "silent",
         ["show", "points", "{ds}", "--frame", "0", "-o", W + "/b.png"], 1,
         "frame 1687078170.100's image ", setup=_l_dotted_stems_first_deleted),
    Case("show points --frame 1, the dotted-stem image before it deleted", "silent",
         ["show", "points", "{ds}", "--frame", "1", "-o", W + "/b.png"], 0,
         "b.png: frame 1687078170.200, ", setup=_l_dotted_stems_first_deleted),
    Case("show points, a deleted frame listed by name and stem", "silent",
         ["show", "points", "{ds}", "--frame", "1", "-o", W + "/b.png"], 1,
         "frames.csv: line 6: frame '000000' is given twice (line 2 as '000000.png')",
         setup=_l_deleted_frame_listed_twice),
    *[Case(f"show belief --features --frame {frame}, that frame's extraction failed",
           "silent", ["show", "belief", "{ds}", "--frame", frame, "--features", W + "/f.h5",
                      "--map", "{kmap}", "-o", W + "/b.png"], 1,
           "f.h5: no frame '000000' (its extraction failed, or extract it first)",
           setup=_l_perspective_first_frame_failed)
      for frame in ("000000", "0")],
    Case("show belief --features --frame 1 says the name of the frame it drew", "silent",
         ["show", "belief", "{ds}", "--frame", "1", "--features", W + "/f.h5", "--map",
          "{kmap}", "-o", W + "/b.png"], 0, "b.png: belief of frame 000001",
         setup=_l_perspective_first_frame_failed),
    Case("evaluate --overwrite of a report.json holding a note as a repeated key",
         "data-lost", ["evaluate", "{poses}", "--truth", "{omni}", "-o", W + "/rep",
                       "--overwrite"], 1, "rep/report.json was edited since fieldloc wrote it",
         setup=_l_report_with_a_repeated_key),
    Case("localize --method lut of a perspective dataset without features", "newcomer",
         ["localize", "{kid}", "--map", "{kmap}", "--method", "lut", "-o", W + "/p.h5"], 1,
         "kid: a 'perspective' camera (its calib.yaml); --method lut needs omni features"),
    # ---- s58 group H: a frames.csv row naming a folder (trial H)
    *[Case(f"{cmd} of a dataset whose frames.csv has a row '{row}'", "silent",
           [*args, "-o", W + "/out"], 1, f"frames.csv: line 3: '{row}' names a folder, not a"
           " frame's image", setup=_h_folder_row(row))
      for row in (".", "images/", "a/b/")
      for cmd, args in (("extract", ["extract", "{ds}"]),
                        ("show points", ["show", "points", "{ds}", "--frame", "1"]))],
    # ---- s58 group G: frames.csv rows and positions (trial G)
    *[Case(f"{cmd} of a frame listed by its file name and by its stem at two stamps",
           "silent", [*args, "-o", W + "/out"], 1,
           "frames.csv: line 6: frame '000003' is given twice (line 5 as '000003.png')",
           setup=_g_listed_by_name_and_stem)
      for cmd, args in (("extract", ["extract", "{ds}"]),
                        ("show points", ["show", "points", "{ds}", "--frame", "000003"]))],
    Case("show points --frame 1, frames.csv rows of no frame before it", "silent",
         ["show", "points", "{ds}", "--frame", "1", "--features", "{features}", "-o",
          W + "/b.png"], 0, "b.png: frame 000001, ", setup=_g_rows_of_no_frame("omni")),
    Case("show points --frame 1 (perspective), frames.csv rows of no frame before it",
         "silent", ["show", "points", "{ds}", "--frame", "1", "--features", "{kid_features}",
                    "-o", W + "/b.png"], 0, "b.png: frame 000001, ",
         setup=_g_rows_of_no_frame("kid")),
    Case("show belief --frame 1, frames.csv rows of no frame before it", "silent",
         ["show", "belief", "{ds}", "--frame", "1", "--features", "{kid_features}", "--map",
          "{kmap}", "-o", W + "/b.png"], 0, "b.png: belief of frame 000001",
         setup=_g_rows_of_no_frame("kid")),
    *[Case(f"show points --frame {frame}, the deleted frame 0 listed in a folder", "silent",
           ["show", "points", "{ds}", "--frame", frame, "-o", W + "/b.png"], rc, said,
           setup=_g_deleted_frame_in_a_folder)
      for frame, rc, said in (
          ("0", 1, "omni/images/000000.png cannot be read: there is no such file (frames.csv"
                   " lists it as 'sub/000000.png')"), ("1", 0, "b.png: frame 000001, "))],
    # ---- s59 group H: frames.csv rows of the dataset's kinds and of others (trial H)
    *[Case(f"show points --frame {frame}, the deleted frame f1.v2 listed by its stem",
           "silent", ["show", "points", "{ds}", "--frame", frame, "-o", W + "/b.png"], rc,
           said, setup=_h_stems_with_a_dot_second_deleted)
      for frame, rc, said in (("1", 1, "frame f1.v2's image "), ("2", 0, "frame f2.v2, "))],
    *[Case(f"show points --frame {frame}, a deleted JPG frame among PNG and JPG frames",
           "silent", ["show", "points", "{ds}", "--frame", frame, "-o", W + "/b.png"], rc,
           said, setup=_h_jpg_frame_deleted)
      for frame, rc, said in (("1", 1, "images/000001.jpg cannot be read: there is no such"
                                       " file"), ("2", 0, "b.png: frame 000002, "))],
    Case("extract of a dataset whose frames.csv lists an image as images/000000.png",
         "newcomer", ["extract", "{ds}", "-o", W + "/f.h5"], 0, "",
         setup=_with_ds("omni", lambda ds: edit_csv(ds / "frames.csv", 2,
                                                    "images/000000.png,0.000000")),
         check=_check_frames_extracted(4)),
    Case("extract of a dataset whose frames.csv lists 000001.png as 000001.PNG", "newcomer",
         ["extract", "{ds}", "-o", W + "/f.h5"], 1,
         "frames.csv: line 3: '000001.PNG' is no image in images/; frame 000001's image is"
         " 000001.png", setup=_with_ds("omni", lambda ds: edit_csv(ds / "frames.csv", 3,
                                                                   "000001.PNG,0.100000"))),
    Case("show points --frame 2, frames.csv lists 000001.jpg beside 000001.png (PNG frames)",
         "silent", ["show", "points", "{ds}", "--frame", "2", "-o", W + "/b.png"], 0,
         "1 frames are files of a kind fieldloc does not read or none of the images is"
         " (first: 000001.jpg", setup=_rows_after_frame_0("omni", ["000001.jpg,0.15"]),
         check=_check_drew("000002")),
    # ---- s59 group I: frames.csv rows written on Windows, folder names, stems (trial I)
    *[Case(f"show points --frame {frame}, the deleted frame 1 listed as {row}", "silent",
           ["show", "points", "{ds}", "--frame", frame, "-o", W + "/b.png"], rc, said,
           setup=_i_second_frame_deleted_listed_as(row))
      for row in ("cam\\000001.png",)  # a row leading out with ..: refused (N11, below)
      for frame, rc, said in (("1", 1, "omni/images/000001.png cannot be read: there is no"
                                       f" such file (frames.csv lists it as '{row}')"),
                              ("2", 0, "b.png: frame 000002, "))],
    Case("extract of a dataset whose frames.csv lists every image as images\\000000.png ..",
         "newcomer", ["extract", "{ds}", "-o", W + "/f.h5"], 0, "",
         setup=_with_ds("omni", _i_rows_in_images_backslash), check=_check_frames_extracted(4)),
    *[Case(f"{cmd} of a dataset whose frames.csv has a row '{row}'", "silent",
           [*args, "-o", W + "/out"], 1, f"frames.csv: line 3: '{row}' {said}", setup=setup)
      for row, said, setup in (
          ("images", "names a folder, not a frame's image", _h_folder_row("images")),
          (".png", "names no frame: its file name has no stem before its suffix",
           _i_hidden_image_listed))
      for cmd, args in (("extract", ["extract", "{ds}"]),
                        ("show points", ["show", "points", "{ds}", "--frame", "1"]))],
    Case("extract of a dataset whose frames.csv lists image a0.png as A0.png", "newcomer",
         ["extract", "{ds}", "-o", W + "/f.h5"], 1,
         "frames.csv: line 2: 'A0.png' is no image in images/; image a0.png differs from it"
         " only in letter case", setup=_with_ds("omni", _i_image_listed_in_another_case)),
    # ---- s60 group J: output folders that are recordings, drive letters in rows (trial J)
    Case("extract of a dataset whose frames.csv lists every image as C:000000.png ..",
         "newcomer", ["extract", "{ds}", "-o", W + "/f.h5"], 0, "",
         setup=_with_ds("omni", _j_rows_on_drive_c), check=_check_frames_extracted(4)),
    Case("extract of a dataset whose frames.csv lists 000001.png as cam0|000001.png",
         "newcomer", ["extract", "{ds}", "-o", W + "/f.h5"], 1,
         "frames.csv: no stamp for image 000001.png (no row lists it; line 3's"
         " 'cam0|000001.png' names no image in images/, a deleted frame)",
         setup=_with_ds("omni", lambda ds: edit_csv(ds / "frames.csv", 3,
                                                    "cam0|000001.png,0.100000"))),
    *[Case(f"{what} -o a recording's folder (it holds {held})", "silent",
           [*args, "{rec}"], 1, f"is a recording (holds {held}); name another folder for"
           " the outputs", setup=_j_recording(held))
      for held in ("frames.csv", "images/")
      for what, args in (
          ("evaluate", ["evaluate", "{poses}", "--truth", "{omni}", "-o"]),
          ("evaluate --overwrite", ["evaluate", "{poses}", "--truth", "{omni}", "--overwrite",
                                    "-o"]),
          ("evaluate of two poses files", ["evaluate", "{poses}", W + "/b.h5", "--truth",
                                           "{omni}", "-o"]),
          ("batch", ["batch", W + "/spec.yaml", "--serial", "-o"]),
          ("extract --debug-images", ["extract", "{omni}", "-o", W + "/f.h5",
                                      "--debug-images"]))],
    Case("evaluate without -o of poses.h5 in a dataset folder", "silent",
         ["evaluate", "{ds}/poses.h5", "--truth", "{omni}"], 0,
         "poses-eval (beside the poses file; -o to choose)", setup=_j_poses_in_dataset,
         check=_check_report_beside_the_poses),
    # ---- s60 trial K
    *[Case(f"bench --from-json whose rows are {what}", kind,
           ["bench", "--from-json", W + "/b.json"], 1,
           f"b.json: not a bench --json file ({why})", setup=_setup_number_file("b.json", text))
      for what, kind, text, why in (
        ("a mapping", "traceback", '{"rows": {"a": 1}}', "no list of rows"),
        ("a string", "traceback", '{"rows": "abc"}', "no list of rows"),
        ("a list of numbers", "traceback", '{"rows": [1, 2]}', "row 0: not an object"),
        ("named by a number", "silent", '{"rows": [{"name": 5, "median_ms": 1}]}',
         "row 0: name is not text"),
        ("timed in text", "silent", '{"rows": [{"name": "a", "median_ms": "x"}]}',
         "row 0: median_ms is not a number"))],
    *[Case(f"build-map {opt} {value}", kind,
           ["build-map", "spl", opt, value, "--resolution", "1", "-o", W + "/m.h5"], 1,
           f"conf '{key}' must be {low} and <= {high}, got {value}")
      for opt, key, value, kind, low, high in (
        ("--max-range", "max_range", "1e+308", "traceback", "> 0", 50),
        ("--max-range", "max_range", "1000000.0", "silent", "> 0", 50),
        ("--border", "border", "1e+308", "traceback", ">= 0", 10))],
    *[Case(f"{what} a FIFO: not a regular file, not 'not found'", "silent", args, 1,
           f"/{name} is not a regular file (a device, pipe or socket)",
           setup=_setup_special(name))
      for what, name, args in (
        ("batch SPEC", "s.yaml", ["batch", W + "/s.yaml", "-o", W + "/b", "--serial"]),
        ("calibrate omni POINTS", "p.csv",
         ["calibrate", "omni", W + "/p.csv", "-o", W + "/c.yaml", "--image-size", "480", "480",
          "--valid-radius", "40", "230", "--centre", "240", "240"]),
        ("localize --points", "p.csv",
         ["localize", "{omni}", "--map", "{map}", "--points", W + "/p.csv", "-o", W + "/p.h5"]),
        ("calibrate --from-cnc", "c.conf",
         ["calibrate", "omni", "--from-cnc", W + "/c.conf", "-o", W + "/c.yaml"]),
        ("evaluate --table", "report.json",
         ["evaluate", "--table", W + "/report.json"]))],
    *[Case(f"extract of a dataset whose simulation.yaml is {what}: run, and said", "silent",
           ["extract", "{ds}", "-o", W + "/f.h5"], 0,
           f"simulation.yaml: ignored, the field it records is not read ({why}",
           setup=setup)
      for what, why, setup in (
        ("not YAML", "not YAML: line 2",
         _with_ds("omni", _write("simulation.yaml", b"{{{ not yaml\n"))),
        ("an alias bomb", "not YAML: line 2",
         _with_ds("omni", _write("simulation.yaml",
                                 f"field: spl\nnotes: {ALIAS_BOMB}\n".encode()))),
        ("a FIFO", "is not a regular file", _setup_fifo_file("simulation.yaml")),
        ("a sparse 3 GB file", "3221 MB, more than the 10 MB",
         _with_ds("omni", _sparse("simulation.yaml", 3 << 30))))],
    Case("extract of a dataset whose calib.yaml is a sparse 3 GB file: not read whole", "hang",
         ["extract", "{ds}", "-o", W + "/f.h5"], 1,
         "calib.yaml: cannot be read (3221 MB, more than the 10 MB",
         setup=_with_ds("omni", _sparse("calib.yaml", 3 << 30))),
    Case("build-map of a sparse 3 GB field YAML: not read whole", "hang",
         ["build-map", W + "/f.yaml", "-o", W + "/m.h5"], 1,
         "f.yaml: cannot be read (3221 MB, more than the 10 MB",
         setup=lambda w, ws: _sparse("f.yaml", 3 << 30)(ws)),
    Case("simulate -o a folder in a missing folder: the missing folder named, not a part",
         "newcomer", ["simulate", "omni", "--field", "spl", "--frames", "1", "-o",
                      W + "/sp ace/\u00fc"], 1, "/sp ace/\u00fc: folder ",
         check=lambda paths, res: res.stderr.rstrip().endswith("/sp ace does not exist")
         or pytest.fail(res.stderr)),
    *[Case(f"{args[0]} -o a {found} file --overwrite: not its own kind, kept", "data-lost",
           [*args, "-o", W + "/x.h5", "--overwrite"], 1,
           f"x.h5 is a fieldloc.{found} file; this command writes fieldloc.{schema} files:"
           " --overwrite replaces only its own kind",
           setup=lambda w, ws, found=found: _copy(w[found], ws / "x.h5"))
      for args, found, schema in (
        (["build-templates", "{omni}"], "map", "templates"),
        (["build-map", "spl", "--resolution", "1"], "poses", "map"),
        (["localize", "{omni}", "--map", "{map}", "--features", "{features}"], "map", "poses"),
        (["build-templates", "{omni}"], "features", "templates"),
        (["extract", "{omni}"], "poses", "features"))],
    Case("evaluate spl poses against a kidsize dataset's truth: said", "silent",
         ["evaluate", "{poses}", "--truth", "{kid}", "-o", W + "/r"], 0,
         "of a dataset recorded on field 'kidsize', not the poses' 'spl'"),
    Case("evaluate against a same-field dataset's other truth: said", "silent",
         ["evaluate", "{poses}", "--truth", "{ds}", "-o", W + "/r"], 0,
         "not the truth of the dataset the poses were made from",
         setup=_with_ds("omni", _shift_truth)),
    *[Case(f"{what} a symbolic link loop: one line, no RuntimeError", "traceback", args, 1,
           "loop: it is a symbolic link loop; remove the link", setup=_setup_loops_and_spec)
      for what, args in (
        ("export -o", ["export", "{poses}", "--format", "csv", "-o", W + "/loop"]),
        ("export --overwrite -o", ["export", "{poses}", "--format", "csv", "-o", W + "/loop",
                                   "--overwrite"]),
        ("batch -o", ["batch", W + "/spec.yaml", "-o", W + "/loop", "--serial"]))],
    *[Case(f"{what} a symbolic link loop: said so, not 'not found'", "silent", args, 1,
           "(a symbolic link loop)", setup=_setup_loops_and_spec)
      for what, args in (
        ("localize --features", ["localize", "{omni}", "--map", "{map}", "--features",
                                 W + "/loop", "-o", W + "/p.h5"]),
        ("localize --map", ["localize", "{omni}", "--map", W + "/loop", "--features",
                            "{features}", "-o", W + "/p.h5"]),
        ("export POSES (K1: a RuntimeError)", ["export", W + "/loop", "--format", "tum"]),
        ("export POSES -o -", ["export", W + "/loop", "--format", "json", "-o", "-"]),
        ("evaluate POSES", ["evaluate", W + "/loop", "--truth", "{omni}", "-o", W + "/r"]),
        ("evaluate of two POSES of one stem (K4: a RuntimeError), the second",
         ["evaluate", "{poses}", W + "/d/poses.h5", "--truth", "{omni}", "-o", W + "/r"]),
        ("inspect", ["inspect", W + "/loop"]),
        ("show hypotheses POSES", ["show", "hypotheses", W + "/loop", "--frame", "0", "-o",
                                   W + "/o.png"]),
        ("show map FIELD", ["show", "map", W + "/loop.yaml", "-o", W + "/o.png"]),
        ("report of a folder whose report.json is", ["report", W + "/R", "-o", W + "/r.html"]),
        *((f"batch SPEC's datasets[0].{key}", ["batch", W + f"/{key}.yaml", "-o", W + "/b",
                                               "--serial"]) for key in LOOP_SPECS))],
    Case("batch SPEC whose top-level field no dataset uses is not found (trial P5)", "silent",
         ["batch", W + "/spec.yaml", "-o", W + "/b", "--serial"], 1,
         "spec.yaml: field: field file not found",
         setup=_setup_spec("field: nofield.yaml\ndatasets:\n  - name: d\n    map: {map}\n"
                           "    simulate: {{preset: omni-clean, field: spl, frames: 2, seed:"
                           " 1}}\nmethods: [lut]\n")),
    Case("batch SPEC building its map of another robot_radius than extract's (trial N7)",
         "silent", ["batch", W + "/spec.yaml", "-o", W + "/b", "--serial"], 1,
         "datasets[0].extract: its scan lines have robot_radius = 0.25, the map's 0.3: give"
         " the SPEC 'extract: {omni: {scanlines: {robot_radius: 0.3}}}'",
         setup=_setup_spec("field: spl\nbuild_map: {{resolution: 0.5, robot_radius: 0.3}}\n"
                           "datasets:\n  - name: d\n    simulate: {{preset: omni-clean, field:"
                           " spl, frames: 2, seed: 1}}\nmethods: [lut]\n")),
    Case("batch SPEC's map a symbolic link loop: the key said once", "silent",
         ["batch", W + "/top.yaml", "-o", W + "/b", "--serial"], 1,
         "top.yaml: map: /", setup=_setup_loop_map_spec, check=_check_said_once("map: map:")),
    *[Case(f"field import of a {fmt} JSON file giving {key} twice: refused", "silent",
           ["field", "import", W + "/field.json", "--format", fmt, "-o", W + "/out.yaml"], 1,
           f"key '{key}' given twice", setup=_setup_number_file("field.json", text))
      for fmt, key, text in (
        ("hulks", "length", '{"field_dimensions": {"length": 9.0, "length": 90, "width": 6.0}}'),
        ("cambada", "field_length",
         '{"field_length": 18000, "field_length": 30000, "field_width": 12000,'
         ' "line_thickness": 125, "center_circle_radius": 2000, "goal_band_width": 1000,'
         ' "side_band_width": 1000}'))],
    Case("field import of a JSON file giving length twice, no --format: the key named",
         "silent", ["field", "import", W + "/field.json", "-o", W + "/out.yaml"], 1,
         "field.json: key 'length' given twice", setup=_setup_number_file(
             "field.json", '{"field_dimensions": {"length": 9.0, "length": 90, "width": 6}}')),
    *[Case(f"bench --from-json of {what}: refused", "silent",
           ["bench", "--from-json", W + "/b.json"], 1,
           f"b.json: not a bench --json file (row 0: {why}",
           setup=_setup_number_file("b.json", text))
      for what, text, why in (
        ("a median of 400 digits", '{"rows": [{"name": "a", "median_ms": HUGE}]}',
         "median_ms 99999999999999999... is beyond 1e+300"),
        ("a ratio of -Infinity", '{"rows": [{"name": "a", "ratio": -Infinity}]}',
         "ratio -inf is beyond 1e+300"),
        ("repeats -5", '{"rows": [{"name": "a", "repeats": -5}]}',
         "repeats -5 is not a whole number >= 0"),
        ("a name holding ESC [31m and a line break",
         '{"rows": [{"name": "a\\u001b[31mRED\\nb"}]}', "name 'a\\x1b[31mRED\\nb' holds"))],
    Case("frames.csv row 000000.png:Zone.Identifier (an NTFS stream): its line named",
         "newcomer", ["extract", "{ds}", "-o", W + "/f.h5"], 1,
         "line 2's '000000.png:Zone.Identifier' is read as a file of another kind",
         setup=_with_ds("omni", lambda ds: edit_csv(ds / "frames.csv", 2,
                                                    "000000.png:Zone.Identifier,0.0"))),
    Case("field import --format carpenoctem --section '': refused, not the CurrentField",
         "silent", ["field", "import", W + "/f.conf", "--format", "carpenoctem", "--section",
                    "", "-o", W + "/out.yaml"], 1, "--section '' names no section (sections: Lab)",
         setup=_setup_number_file("f.conf", "[FootballField]\nCurrentField = Lab\n[Lab]\n"
                                  "FieldLength = 18000\n[!Lab]\n[!FootballField]\n")),
    Case("build-map --max-range 1_0: refused, not read as 10", "silent",
         ["build-map", "spl", "--max-range", "1_0", "-o", W + "/m.h5"], 2,
         "'1_0' is no decimal number (underscores)"),
    *[Case(f"{' '.join(args[:2])} {opt} 1_0: refused, not read as 10", "silent",
           [*args, opt, "1_0"], 2, "'1_0' is no decimal number (underscores)")
      for args, opt in ((["simulate", "omni", "--field", "spl", "-o", W + "/s"], "--frames"),
                        (["report", W + "/r", "-o", W + "/r.html"], "--worst"))],
    Case("bench --only '': refused, not every row", "silent", ["bench", "--only", ""], 1,
         "--only '' names no row"),
    # ---------------------------------------------------------- trial N (issue 25, session 61)
    *[Case(f"{what} giving {key} twice: refused, not the last kept (N1-N3)", "silent", args, 1,
           f"{key} given twice", setup=setup)
      for what, key, setup, args in (
        ("field import of a B-Human .cfg", "key 'xPosOpponentGoalLine'",
         _setup_number_file("f.cfg", "xPosOpponentGoalLine = 4500;\nxPosOpponentGoalLine ="
                            " 4400;\n"),
         ["field", "import", W + "/f.cfg", "--format", "bhuman", "-o", W + "/o.yaml"]),
        ("field import of a Carpe Noctem .conf", "key 'CurrentField'",
         _setup_number_file("f.conf", "[FootballField]\nCurrentField = Lab\nCurrentField ="
                            " Official\n[Lab]\nFieldLength = 18000\n[!Lab]\n[!FootballField]\n"),
         ["field", "import", W + "/f.conf", "--format", "carpenoctem", "-o", W + "/o.yaml"]),
        ("calibrate --from-cnc of a CarpetCalibrator.conf", "key dist1",
         _setup_number_file("c.conf", "[Dist]\ndist0 = 0\ndist1 = 1000\ndist1 = 1200\n"
                            "dist2 = 2000\n[!Dist]\n"),
         ["calibrate", "omni", "--from-cnc", W + "/c.conf", "-o", W + "/c.yaml"]),
        ("calibrate --from-cnc of a CarpetCalibrator.conf", "section [Dist]",
         _setup_number_file("c.conf", "[Dist]\ndist0 = 0\ndist1 = 1000\ndist2 = 2000\n"
                            "[!Dist]\n" * 2),
         ["calibrate", "omni", "--from-cnc", W + "/c.conf", "-o", W + "/c.yaml"]),
        ("calibrate --from-minho of an image.cfg", "image.cfg: key TILT",
         _minho_plus("image.cfg", "TILT=10\n"),
         ["calibrate", "omni", "--from-minho", W + "/minho", "-o", W + "/c.yaml"]),
        ("calibrate --from-minho of a mirror.cfg (once run into a comment)",
         "mirror.cfg: key STEP",
         _minho_plus("mirror.cfg", "#DONT CHANGE THE ORDER OF THE CONFIGURATIONSSTEP=0.5\n"),
         ["calibrate", "omni", "--from-minho", W + "/minho", "-o", W + "/c.yaml"]))],
    *[Case(f"field import of a {what}: refused, not a {size} field (N5)", "silent",
           ["field", "import", W + "/f.json", "--format", "falcons", "--base", "msl-2015", "-o",
            W + "/o.yaml"], 1, f"the field's {key} would be {size}, not a soccer field's (1-40 m)",
           setup=_setup_number_file("f.json", f'{{"model": {{{letters}, "K": 0.125}}}}'))
      for what, letters, key, size in (
        ("Falcons letters list in mm", '"A": 22000, "B": 14', "length", "21999.9 m"),
        ("Falcons letters list with B 0.14 m", '"A": 22, "B": 0.14', "width", "0.015 m"))],
    *[Case(f"{what} of a dataset with a 1 x 1 px frame: the frame left out, named (N6)",
           "newcomer", args, 0, msg, setup=_setup_tiny_frame)
      for what, args, msg in (
        ("build-templates", ["build-templates", "{ds}", "-o", W + "/t2.h5"],
         "/omni/images/000001.png: image is 1 x 1 px, the calibration's is 480 x 480)"),
        ("localize --method templates",
         ["localize", "{ds}", "--method", "templates", "--templates", W + "/t.h5", "-o",
          W + "/p.h5"], "frame 000001 skipped: image is 1 x 1 px, the calibration's is"))],
    *[Case(f"localize {ds} --method mcl --points: the points file named, not None (N4)",
           "newcomer", ["localize", ds, "--method", "mcl", "--map", "{map}", "--points",
                        W + "/pts.csv", "-o", W + "/p.h5"], 1,
           "/pts.csv: line points, read as an omni camera's scan lines; --method mcl needs"
           " perspective features: use --method lut or fit",
           setup=lambda w, ws: _points_csv(w, ws, range(2)))
      for ds in ("{omni}", "{kid}")],
    *[Case(f"frames.csv whose {what}: refused, naming the row (N9, N11)", "silent",
           ["extract", "{ds}", "-o", W + "/f.h5"], 1, msg,
           setup=_with_ds("omni", lambda ds, row=row: edit_csv(ds / "frames.csv", 4, row)))
      for what, row, msg in (
        ("stamp of 000002 goes back", "000002.png,-5.0",
         "frames.csv: line 4: frame 000002's stamp -5.0 is before frame 000001's 0.1 (line 3);"
         " stamps must not decrease in the order of the frames' names"),
        ("row names ../../D/images/000002.png", "../../D/images/000002.png,0.2",
         "frames.csv: line 4: '../../D/images/000002.png' leads out of the dataset (..)"))],
    Case("show points --frame 1, the deleted frame 1 listed as ../../../../etc/000001.png:"
         " refused, naming the row (N11)", "silent",
         ["show", "points", "{ds}", "--frame", "1", "-o", W + "/b.png"], 1,
         "frames.csv: line 3: '../../../../etc/000001.png' leads out of the dataset (..)",
         setup=_i_second_frame_deleted_listed_as("../../../../etc/000001.png")),
    *[Case(f"localize --method mcl -c {' -c '.join(kvs)}: refused, whatever the init (N8)",
           "silent", ["localize", "{kid}", "--map", "{kmap}", "--features", "{kid_features}",
                      "--method", "mcl", "-o", W + "/p.h5", *[a for kv in kvs for a in ("-c", kv)]],
           1, "init_pose (1e+09, 0) m lies off the field and its margin (x within")
      for kvs in (["init_pose=[1e9,0,0]"], ["init=uniform", "init_pose=[1e9,0,0]"])],
    *[Case(f"calibrate --from-minho whose {what}: said so, naming the file (N10)", "newcomer",
           ["calibrate", "omni", "--from-minho", W + "/minho", "-o", W + "/c.yaml",
            "--image-size", "480", "480"], 1, msg, setup=_minho_replaced(name, text))
      for what, name, text, msg in (
        ("mirror.cfg is a folder", "mirror.cfg", None, "/minho/mirror.cfg is a folder"),
        ("IMG_CENTER lies outside the image", "image.cfg", "IMG_CENTER=5000,233\nTILT=90\n",
         "minho/image.cfg: IMG_CENTER (5000, 233) lies outside the 480 x 480 image"))],
    *[Case(f"poses whose {what}: refused as damaged (O5-O7)", "silent",
           [*args, W + "/p.h5", *more], 1, f"damaged poses file ({msg}",
           setup=_setup_damaged("poses", "p.h5", change))
      for what, args, more, msg, change in (
        ("runtime is -5 s (O5: evaluate's median runtime -5000 ms)", ["evaluate"],
         ["--truth", "{omni}", "-o", W + "/rep"], "/poses/runtime of frame 000000 is -5;"
         " expected a finite time of 0 s or more", _replace("poses/runtime", lambda d: d * 0 - 5)),
        ("runtime is NaN (O5)", ["export"], ["--format", "tum", "-o", W + "/o.tum"],
         "/poses/runtime of frame 000000 is nan", _nan_first("poses/runtime")),
        ("frames are both accepted and failed (O6: export wrote them, evaluate not)",
         ["export"], ["--format", "tum", "-o", W + "/o.tum"], "frame 000000 both accepted and"
         " failed)", lambda f: [_replace(f"poses/{k}", np.ones_like)(f)
                                for k in ("failed", "accepted")]),
        ("covariance is infinite (O7)", ["export"], ["--format", "json", "-o", W + "/o.json"],
         "/poses/covariance of frame 000000 is neither finite nor all NaN",
         _replace("poses/covariance", lambda d: np.full(d.shape, np.inf, d.dtype))),
        ("hypotheses are all padding on frames that did not fail (O7)", ["evaluate"],
         ["--truth", "{omni}", "-o", W + "/rep"], "/hypotheses of frame 000000 holds none",
         _replace("hypotheses", lambda d: np.full(d.shape, np.nan))),
        ("hypotheses' probabilities are NaN beside poses (O7)", ["export"],
         ["--format", "json", "-o", W + "/o.json"], "/hypotheses of frame 000000: row 0"
         " column 3 is nan", _replace("hypotheses", lambda d: np.concatenate(
             [d[..., :3], np.full(d.shape[:2] + (1,), np.nan)], axis=2))),
        ("error is -1 (O7)", ["export"], ["--format", "csv", "-o", W + "/o.csv"],
         "/poses/error of frame 000000 is -1", _replace("poses/error", lambda d: d * 0 - 1)),
        ("frames are all named 000000 (O7)", ["export"], ["--format", "tum", "-o", W + "/o.tum"],
         "frame name '000000' is given twice", _replace("poses/name",
                                                        lambda d: np.array([b"000000"] * len(d)))),
        ("frame is named ../../etc/passwd (O7)", ["evaluate"],
         ["--truth", "{omni}", "-o", W + "/rep"], "frame name '../../etc/passwd' is not a plain"
         " image name", _replace("poses/name", lambda d: np.array(
             [b"../../etc/passwd", *d[1:]]))),
        ("hypotheses hold none a frame (trial Q1: an IndexError)", ["export"],
         ["--format", "csv", "-o", W + "/o.csv"], "/hypotheses of frame 000000 holds none",
         _replace("hypotheses", lambda d: d[:, :0, :])),
        ("hypotheses are 10,001 a frame (trial Q10: read a minute into 'out of memory')",
         ["export"], ["--format", "csv", "-o", W + "/o.csv"],
         "/hypotheses has shape (4, 10001, 4); expected (N, K <= 10,000, 4) for N = 4",
         _replace("hypotheses", lambda d: np.full((len(d), 10_001, 4), np.nan))),
        ("hypotheses are a group (trial R: an AttributeError)", ["export"],
         ["--format", "csv", "-o", W + "/o.csv"], "/hypotheses is a Group, not a dataset)",
         _as_group("hypotheses")),
        ("first frame is named with a line break (trial Q9)", ["export"],
         ["--format", "csv", "-o", W + "/o.csv"],
         "frame name '000000.png\\n' is not a plain image name",
         _replace("poses/name", lambda d: np.array([b"000000.png\n", *d[1:]]))),
        ("mode is 'bogus' (O7)", ["export"], ["--format", "csv", "-o", W + "/o.csv"],
         "/poses/mode 'bogus' is none of failed, global,",
         _replace("poses/mode", lambda d: np.array([b"bogus"] * len(d)))),
        ("flags are numbers (O7)", ["export"], ["--format", "json", "-o", W + "/o.json"],
         "/poses/flags holds int64 values; expected text",
         _replace("poses/flags", lambda d: np.arange(len(d)))))],
    *[Case(f"frames.csv whose {what}: refused, naming the row (O9)", "silent",
           ["extract", "{ds}", "-o", W + "/f.h5"], 1, msg,
           setup=_with_ds("omni", lambda ds, row=row: edit_csv(ds / "frames.csv", 4, row)))
      for what, row, msg in (
        ("row names /tmp/D/images/000002.png (matched by its file name)",
         "/tmp/D/images/000002.png,0.2", "frames.csv: line 4: '/tmp/D/images/000002.png' is an"
         " absolute path; a row names an image in images/"),
        ("row names \\D\\images\\000002.png", "\\D\\images\\000002.png,0.2",
         "is an absolute path; a row names an image in images/"))],
    Case("frames.csv whose stamp of 000002 is 0.0999999999, just before 000001's 0.1: both"
         " told apart (O10: said '0.1 is before 0.1')", "newcomer",
         ["extract", "{ds}", "-o", W + "/f.h5"], 1, "frames.csv: line 4: frame 000002's stamp"
         " 0.0999999999 is before frame 000001's 0.1 (line 3)",
         setup=_with_ds("omni", lambda ds: edit_csv(ds / "frames.csv", 4,
                                                    "000002.png,0.0999999999"))),
    *[Case(f"{' '.join(args[:2])} {opt} {text}: refused, not read as 6 (O11)", "silent",
           [*args, opt, text], 2, f"{text!r} is no decimal number (characters outside ASCII)")
      for args, opt in ((["simulate", "omni", "--field", "spl", "-o", W + "/s"], "--frames"),
                        (["build-map", "spl", "-o", W + "/m.h5"], "--max-range"))
      for text in ("\u0666", "\uff16")],
    Case("evaluate of poses whose recorded dataset is gone, no --truth: said so (O8)",
         "newcomer", ["evaluate", W + "/p.h5", "-o", W + "/rep"], 1, "the poses' dataset"
         " /nonexistent/D (recorded in the poses file) is not there: pass --truth",
         setup=_setup_damaged("poses", "p.h5", _attr("dataset", "/nonexistent/D"))),
    *[Case(f"field import of a Carpe Noctem conf {what} (O12, O13)", "newcomer",
           ["field", "import", W + "/f.conf", "--format", "carpenoctem", "-o", W + "/f.yaml"],
           1, msg, setup=_setup_number_file("f.conf", text))
      for what, text, msg in (
        ("whose [FootballField] is never closed, [Team] after it: named with its line",
         "[Globals]\n[FootballField]\nFieldLength = 18000\n[Team]\n[mops]\nX = 1\n[!mops]\n"
         "[!Team]\n[!Globals]\n", "f.conf:2: [FootballField] is never closed"
         " ([!FootballField]); line 5's [mops] lies within it"),
        ("whose [FootballField] is closed by [!Globals]: named with its line",
         "[Globals]\n[FootballField]\nFieldLength = 18000\n[!Globals]\n",
         "f.conf:2: [FootballField] is never closed ([!FootballField]) before line 4's"
         " [!Globals]"),
        ("that ends inside [FootballField]: named with its line",
         "[FootballField]\nFieldLength = 18000\n", "f.conf:1: [FootballField] is never closed"),
        ("without any [FootballField] (a Vision.conf)", "[Vision]\nX = 1\n[!Vision]\n",
         "f.conf: no [FootballField] block"))],
    Case("calibrate omni --image-size 1000000 1000000: --image-size named, not the output"
         " (O14)", "newcomer",
         ["calibrate", "omni", "{marks}", "--centre", "240", "240", "--image-size", "1000000",
          "1000000", "--valid-radius", "40", "230", "-o", W + "/calib.yaml"], 2,
         "Invalid value for '--image-size': 1000000 is not in the range 1<=x<=8192"),
    # s62 trial U2: a line image's distance, and frames beyond the pixel bound at import
    *[Case(f"calibrate --from-minho --line-images of {name}: refused naming it (U2-{n})",
           "silent", ["calibrate", "omni", "--from-minho", "{m}", "--line-images", W + "/li",
                      "-o", W + "/c.yaml", "--image-size", "480", "480"], 1,
           f"li/{name}: a line image's distance must be 0.1 to 20 m (nearer lies under the"
           f" robot, farther no mirror shows a line), not {name[:-4][:24]} m",
           setup=_setup_line_image(name))
      for n, name in ((1, "1000.png"), (1, "125.png"), (2, "0.000000001.png"),
                      (3, "99999999999999999999.png"))],
    Case("import rosbag of one 8193 x 8193 px raw frame: refused, not written (U2-9)",
         "silent", ["import", "rosbag", W + "/x.bag", "-o", W + "/ds", "--image-topic", "/cam"],
         1, "x.bag: no frame written from /cam (image of 8193 x 8193 px, more than the"
         " 67,108,864 pixels fieldloc reads)", setup=_setup_bag_of_frames("raw 8193x8193")),
    Case("import rosbag of one compressed Bayer PNG of 9000 x 9000 px: the pixels named, in"
         " one line (U2-10: 'not a one-channel mosaic' after a warning)", "newcomer",
         ["import", "rosbag", W + "/x.bag", "-o", W + "/ds", "--image-topic", "/cam"], 1,
         "x.bag: no frame written from /cam (compressed image of 9000 x 9000 px, more than the"
         " 67,108,864 pixels fieldloc reads)", setup=_setup_bag_of_frames("bayer 9000x9000")),
    Case("import rosbag of a frame, a 9000 x 9000 px Bayer PNG and a frame: the large one"
         " skipped with a warning naming it (U2-9)", "silent",
         ["import", "rosbag", W + "/x.bag", "-o", W + "/ds", "--image-topic", "/cam"], 0,
         "image message 1 skipped: compressed image of 9000 x 9000 px",
         setup=_setup_bag_of_frames("grey", "bayer 9000x9000", "grey"),
         check=lambda paths, res: _check_frames_written(paths["ws"] / "ds", 2)),
    Case("import rosbag of a 9000 x 9000 px Bayer PNG, then a frame: the skip still said"
         " (U2-9)", "silent",
         ["import", "rosbag", W + "/x.bag", "-o", W + "/ds", "--image-topic", "/cam"], 0,
         "image message 0 skipped: compressed image of 9000 x 9000 px",
         setup=_setup_bag_of_frames("bayer 9000x9000", "grey"),
         check=lambda paths, res: _check_frames_written(paths["ws"] / "ds", 1)),
]


@pytest.fixture(scope="module")
def world_report(world):
    """A report inside the shared dataset for the inspect case (made once)."""
    from stages import evaluate

    evaluate.main(None, world["poses"], world["omni"], world["omni"] / "runs" / "r")
    return world


@contextlib.contextmanager
def _deadline(seconds):
    """A hang case fails after ``seconds`` instead of blocking the suite (SIGALRM interrupts
    the blocked open or read)."""
    if seconds is None or not hasattr(signal, "SIGALRM"):
        yield
        return

    def hung(signum, frame):
        raise TimeoutError(f"the command still ran after {seconds} s (a hang)")

    old = signal.signal(signal.SIGALRM, hung)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_fault(case, world_report, tmp_path, caplog):
    world = world_report
    paths = {k: v for k, v in world.items()}
    paths["ws"] = tmp_path
    if case.setup is not None:
        paths.update(case.setup(world, tmp_path) or {})
    args = [str(a).format(**paths) for a in case.args]
    before = snapshot(world["root"], tmp_path)
    with caplog.at_level(logging.WARNING), _deadline(30 if case.kind == "hang" else None):
        res = CliRunner().invoke(cli, args)
    text = res.output + caplog.text
    assert res.exception is None or isinstance(res.exception, SystemExit), (
        f"traceback: {res.exception!r}\n{text}")
    assert "Traceback" not in text
    assert res.exit_code == case.rc, text
    assert case.fragment in text, text
    if case.rc == 1:
        assert len(res.stderr.strip().splitlines()) == 1, res.stderr  # one line
    elif case.rc == 2:  # a usage error: click's usage lines and one error line
        assert res.stderr.count("Error:") == 1, res.stderr
    after = snapshot(world["root"], tmp_path)
    changed = [p for p, h in before.items() if after.get(p) != h
               and not (case.removes_parts and p.endswith((".part", LOCK_SUFFIX)))]
    assert not changed, f"inputs changed or removed: {changed}"
    if case.rc:
        assert set(after) == set(before), f"a refused command wrote {set(after) - set(before)}"
    if case.check is not None:
        case.check(paths, res)


def _list_keys(conf: dict, prefix: str = "") -> list[tuple[str, list]]:
    """(dotted key, preset value) of every list-valued key of a nested conf."""
    out = []
    for k, v in conf.items():
        if isinstance(v, dict):
            out += _list_keys(v, f"{prefix}{k}.")
        elif isinstance(v, list):
            out.append((f"{prefix}{k}", v))
    return out


# list keys whose length may vary: (fewest, most) elements
LIST_LENGTHS = {"omni.struts_deg": (0, 16), "perspective.distortion": (4, 5)}
SIMULATE_LIST_KEYS = sorted({(simulate.confs[p]["camera"], p, k, len(v))
                             for p in ("omni-default", "perspective-nao")
                             for k, v in _list_keys(simulate.confs[p])})


def _wrong_shapes(key: str, n: int) -> list[str]:
    """Values of a list key of ``n`` numbers that no run can take: one element fewer or more
    (unless its length may vary so), lists in it, texts, NaN."""
    fewest, most = LIST_LENGTHS.get(key, (n, n))
    out = ["[" + ", ".join(["1"] * m) + "]" for m in (fewest - 1, most + 1) if m >= 0]
    return out + ["[[1, 2], [3, 4]]", "[" + ", ".join(["a"] * n) + "]",
                  "[" + ", ".join([".nan"] * n) + "]"]


@pytest.mark.parametrize("kind,preset,key,n", SIMULATE_LIST_KEYS,
                         ids=[f"{p}:{k}" for _, p, k, _ in SIMULATE_LIST_KEYS])
def test_simulate_list_keys_of_a_wrong_shape_are_refused_in_one_line(kind, preset, key, n,
                                                                       tmp_path):
    """Every list-valued key of simulate's presets (walked from the presets, so a new one is
    swept too) given a list of the wrong length or content through the command line: one line
    naming the key, exit 1, nothing written, before anything is rendered."""
    field = "spl" if kind == "omni" else "kidsize"
    for value in _wrong_shapes(key, n):
        r = CliRunner().invoke(cli, ["simulate", kind, "--preset", preset, "--field", field,
                                     "--frames", "1", "-o", str(tmp_path / "sim"), "-c",
                                     f"{key}={value}"])
        said = f"{key}={value}: {r.output}"
        assert r.exception is None or isinstance(r.exception, SystemExit), said
        assert r.exit_code == 1 and len(r.stderr.strip().splitlines()) == 1, said
        assert f"'{key}" in r.stderr, said
        assert not any(tmp_path.iterdir()), said



def _scalar_keys(conf: dict, prefix: str = "") -> list[str]:
    """The dotted keys of every number (not a flag) of a nested conf."""
    out = []
    for k, v in conf.items():
        if isinstance(v, dict):
            out += _scalar_keys(v, f"{prefix}{k}.")
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            out.append(f"{prefix}{k}")
    return out


# numbers of simulate's presets held by checks of their own, not by simulate.SCALAR_BOUNDS:
# frames, seeds, the rate (simulate's _check_conf), the mount's calibration error
# (check_calib_error) and the camera's geometry (camera_from_conf)
SCALARS_CHECKED_ELSEWHERE = {
    "frames", "seed", "rate_hz", "calib_error.pitch_offset", "calib_error.roll_offset",
    "calib_error.height_offset",
    "omni.forward_angle", "perspective.intrinsics.fx", "perspective.intrinsics.fy",
    "perspective.intrinsics.cx", "perspective.intrinsics.cy", "perspective.height",
    "perspective.pitch", "perspective.roll"}


@pytest.mark.parametrize("preset", sorted(simulate.confs))
def test_simulate_presets_lie_in_their_scalar_bounds(preset):
    """Every simulate preset's defaults pass the scalar bounds (and the whole conf check), and
    every number of it is bounded: by SCALAR_BOUNDS or by a check of its own."""
    conf = simulate.confs[preset]
    check_bounds(conf, simulate.SCALAR_BOUNDS, optional=True)
    simulate.check_conf(copy.deepcopy(conf))
    unbounded = [k for k in _scalar_keys(conf) if k not in simulate.SCALAR_BOUNDS
                 and k not in SCALARS_CHECKED_ELSEWHERE]
    assert not unbounded, unbounded

@pytest.mark.parametrize("kind,args", [
    ("map", ["build-map", "spl", "--resolution", "0.5", "-o", "{out}"]),
    *[("picture", ["show", "map", "{map}", "-o", "{out}" + suffix])
      for suffix in (".png", ".jpg", ".pdf", ".svg", ".eps", ".tiff")],
    *[("export", ["export", "{poses}", "--format", fmt, "-o", "{out}"])
      for fmt in ("csv", "json", "tum")],
    ("calibration", ["calibrate", "omni", "{marks}", "--centre", "240", "240", "--image-size",
                     "480", "480", "--valid-radius", "40", "230", "-o", "{out}.yaml"]),
    ("poses", ["localize", "{omni}", "--map", "{map}", "--features", "{features}", "-o",
               "{out}.h5"])], ids=lambda v: v if isinstance(v, str) else " ".join(v[:2]))
def test_overwrite_replaces_what_fieldloc_wrote(world, tmp_path, kind, args):
    """The other side of the data-lost cases above: a second run with --overwrite replaces
    the file the first run wrote, in every format an output takes (each carries fieldloc's
    mark or schema)."""
    paths = {**world, "out": tmp_path / "out"}
    args = [a.format(**paths) for a in args]
    out = Path(args[-1])
    first = CliRunner().invoke(cli, ["-q", *args])
    assert first.exit_code == 0 and out.is_file(), first.output
    out.touch()
    stamp = out.stat().st_mtime_ns
    again = CliRunner().invoke(cli, ["-q", *args])
    assert again.exit_code == 1 and "exists (use --overwrite" in again.output, again.output
    time.sleep(0.01)
    replaced = CliRunner().invoke(cli, ["-q", *args, "--overwrite"])
    assert replaced.exit_code == 0, replaced.output
    assert out.stat().st_mtime_ns != stamp


def test_export_to_stdout_writes_no_file(world, tmp_path, monkeypatch):
    """`export -o -` writes the export to standard output (for a pipe), in each format, and no
    file named '-'."""
    monkeypatch.chdir(tmp_path)
    for fmt, head in (("csv", "name,stamp,x,y,theta"), ("json", '{\n "schema": "fieldloc.'),
                      ("tum", "# stamp x y z qx qy qz qw")):
        r = CliRunner().invoke(cli, ["export", str(world["poses"]), "--format", fmt, "-o", "-"])
        assert r.exit_code == 0, r.output
        assert r.stdout.startswith(head), r.stdout[:80]
        assert not r.stderr.strip(), r.stderr
    assert not any(tmp_path.iterdir())


def test_list_keys_of_another_legal_size_keep_working(world, tmp_path):
    """Values the list checks must not refuse: frames of another size (with a centre and
    ring inside them; the clean preset: no team's mirror table to read off the smaller ring),
    no struts, four distortion coefficients, one threshold, a start pose."""
    for args in ([*SIM_OMNI[:-1], str(tmp_path / "a"), "--preset", "omni-clean", "-c",
                  "omni.image_size=[320, 240]",
                  "-c", "omni.centre=[160, 120]", "-c", "omni.valid_radius=[30, 110]",
                  "-c", "omni.struts_deg=[]", "-c", "trajectory.start=[1, 0.5, 0.2]"],
                 [*SIM_NAO[:-3], str(tmp_path / "b"), "-c", "perspective.image_size=[640, 480]",
                  "-c", "perspective.distortion=[-0.2, 0.04, 0, 0]"],
                 ["evaluate", str(world["poses"]), "--truth", str(world["omni"]), "-o",
                  str(tmp_path / "rep"), "-c", "thresholds=0.5"]):
        r = CliRunner().invoke(cli, ["-q", *[a.replace("{ws}", str(tmp_path)) for a in args]])
        assert r.exit_code == 0, f"{args}: {r.output}"
    assert cv2.imread(str(tmp_path / "a" / "images" / "000000.png")).shape == (240, 320, 3)
    assert cv2.imread(str(tmp_path / "b" / "images" / "000000.png")).shape == (480, 640, 3)


# ---------------------------------------------------------------------------- output rules


def test_quiet_prints_no_summaries_and_results_go_to_stdout(world, tmp_path):
    r = CliRunner().invoke(cli, ["-q", "extract", str(world["omni"]), "-o",
                                 str(tmp_path / "f.h5")])
    assert r.exit_code == 0 and r.stdout == "" and r.stderr == "", r.output
    r = CliRunner().invoke(cli, ["extract", str(world["omni"]), "-o", str(tmp_path / "f.h5")])
    assert r.stdout == "" and "4 frames (omni camera)" in r.stderr
    r = CliRunner().invoke(cli, ["-q", "simulate", "omni", "--field", "spl", "-o",
                                 str(tmp_path / "sim"), "--frames", "1"])
    assert r.exit_code == 0 and r.stdout == "" and r.stderr == ""
    r = CliRunner().invoke(cli, ["-q", "evaluate", str(world["poses"]), "--truth",
                                 str(world["omni"]), "-o", str(tmp_path / "rep")])
    assert r.exit_code == 0 and "median cm" in r.stdout and r.stderr == ""  # the result


def test_dataset_moved_aside_by_a_killed_replacement_is_restored(tmp_path, caplog):
    """simulate --overwrite moves the old dataset aside, then the new one in: killed between
    the two, the old one is under .data.fieldloc-<pid>-*.old/data. The next run puts it back
    (instead of removing it as a stale part) and then refuses without --overwrite."""
    data = simulate.main(dict(simulate.confs["omni-clean"], frames=1), "spl", tmp_path / "data")
    before = snapshot(data)
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    aside = tmp_path / f".data.fieldloc-{p.pid}-x1y2z3.old"
    aside.mkdir()
    os.replace(data, aside / "data")
    with caplog.at_level(logging.WARNING):
        r = CliRunner().invoke(cli, ["simulate", "omni", "--field", "spl", "-o", str(data),
                                     "--frames", "1"])
    assert r.exit_code == 1 and "exists and is not empty" in r.output, r.output
    assert "restored" in caplog.text
    assert snapshot(data) == before
    assert sorted(q.name for q in tmp_path.iterdir()) == ["data"]


def test_an_imported_dataset_moved_aside_by_a_killed_replacement_is_restored(tmp_path, caplog):
    """The same for a folder an importer writes whole (import rosbag; artifacts.atomic_dir and
    commit_dir): killed between moving the old dataset aside and moving the new one in, the
    next run puts the old one back instead of leaving it hidden in a part (s54 trial C, C5),
    then refuses without --overwrite; with --overwrite it replaces it and leaves no part."""
    _setup_odometry_bag(GOOD_ODOMETRY, GOOD_IMU)(None, tmp_path)
    args = ["import", "rosbag", str(tmp_path / "x.bag"), "-o", str(tmp_path / "ds"),
            "--image-topic", "/cam"]
    assert CliRunner().invoke(cli, args).exit_code == 0
    before = snapshot(tmp_path / "ds")
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    aside = tmp_path / f".ds.fieldloc-{p.pid}-x1y2z3.old"
    aside.mkdir()
    os.replace(tmp_path / "ds", aside / "data")
    with caplog.at_level(logging.WARNING):
        r = CliRunner().invoke(cli, args)
    assert r.exit_code == 1 and "exists and is not empty" in r.output, r.output
    assert "restored" in caplog.text
    assert snapshot(tmp_path / "ds") == before
    assert sorted(q.name for q in tmp_path.iterdir()) == ["ds", "x.bag"]
    assert CliRunner().invoke(cli, [*args, "--overwrite"]).exit_code == 0
    assert sorted(q.name for q in tmp_path.iterdir()) == ["ds", "x.bag"]

def test_simulate_overwrite_of_a_record_claiming_1e8_frames_does_not_hang(tmp_path):
    """simulate --overwrite listed every image name a record's frames count implies before it
    replaced a dataset: a record claiming 1e8 frames ran for minutes (s54 trial C, C10). A
    count beyond MAX_FRAMES is a damaged record, judged by the names' pattern."""
    _setup_record_of_frames(10**8)(None, tmp_path)
    with _deadline(30):
        r = CliRunner().invoke(cli, ["simulate", "omni", "--field", "spl", "--preset",
                                     "omni-clean", "--frames", "1", "-o",
                                     str(tmp_path / "data"), "--overwrite"])
    assert r.exit_code == 0, r.output
    assert yaml.safe_load((tmp_path / "data" / "simulation.yaml").read_text())["frames"] == 1

def test_an_eps_picture_prints_no_warning(world, tmp_path, caplog):
    """PostScript has no transparency: matplotlib logged a warning (twice) for every .eps
    picture drawn with translucent artists (s54 trial C, C19); the picture is written, and
    nothing but its summary is said."""
    with caplog.at_level(logging.WARNING):
        r = CliRunner().invoke(cli, ["show", "hypotheses", str(world["poses"]), "-o",
                                     str(tmp_path / "h.eps")])
    assert r.exit_code == 0, r.output
    assert "WARNING" not in r.output + caplog.text, r.output + caplog.text
    assert (tmp_path / "h.eps").stat().st_size > 0

def test_csv_files_have_lf_line_endings(world):
    for name in ("truth.csv", "odometry.csv", "imu.csv", "frames.csv"):
        assert b"\r" not in (world["omni"] / name).read_bytes()


def test_poses_flags_stored_as_integers_0_1_are_read(world, tmp_path):
    """Flags written as 0/1 integers (by another tool) are read; only other values are
    refused (the case "poses whose /poses/failed holds 2")."""
    _setup_damaged("poses", "p.h5", _replace("poses/failed", lambda d: d.astype(np.int8)))(
        world, tmp_path)
    cols = _poses_columns(tmp_path / "p.h5")
    assert (cols["failed"] == _poses_columns(world["poses"])["failed"]).all()


def test_errors_csv_has_lf_line_endings(world_report):
    assert b"\r" not in (world_report["omni"] / "runs" / "r" / "errors.csv").read_bytes()


def test_simulated_folder_has_the_umask_mode(world):
    umask = os.umask(0o022)
    os.umask(umask)
    assert stat.S_IMODE(world["omni"].stat().st_mode) == 0o777 & ~umask
    assert stat.S_IMODE((world["omni"] / "truth.csv").stat().st_mode) == 0o666 & ~umask


def test_conf_override_of_a_float_key_accepts_1e_minus_4():
    from stages.common.conf import parse_overrides, resolve_conf

    conf = resolve_conf(localize.method_confs("lut"), "default",
                        parse_overrides(["min_confidence=1e-4", "hypotheses=6.0"]))
    assert conf["min_confidence"] == pytest.approx(1e-4) and conf["hypotheses"] == 6
    assert isinstance(conf["hypotheses"], int)


def _umask() -> int:
    umask = os.umask(0o022)
    os.umask(umask)
    return umask


def test_import_export_field_import_report_summaries_go_to_stderr_and_q_silences(world_report,
                                                                                 tmp_path):
    """import rosbag, field import, export (and report) printed their summaries on
    stdout and -q did not silence them; as extract and localize: stderr, nothing with -q.
    The imported folder has the umask's mode, not mkdtemp's 0700."""
    world = world_report
    bag = _bag(tmp_path)
    r = CliRunner().invoke(cli, ["-q", "import", "rosbag", str(bag), "-o", str(tmp_path / "a"),
                                 "--image-topic", "/cam"])
    assert r.exit_code == 0 and r.stdout == "" and r.stderr == "", r.output
    r = CliRunner().invoke(cli, ["import", "rosbag", str(bag), "-o", str(tmp_path / "b"),
                                 "--image-topic", "/cam"])
    assert r.exit_code == 0 and r.stdout == "", r.output
    assert "2 frames of 2 image messages" in r.stderr
    for folder in (tmp_path / "a", tmp_path / "b"):
        assert stat.S_IMODE(folder.stat().st_mode) == 0o777 & ~_umask()
    team = tmp_path / "fd.cfg"
    team.write_text("".join(f"{k} = {v};\n" for k, v in {
        "xPosOpponentFieldBorder": 5200, "xPosOpponentGoal": 5055, "xPosOpponentGoalLine": 4500,
        "xPosOpponentGoalArea": 3900, "xPosOpponentPenaltyMark": 3200,
        "xPosOpponentPenaltyArea": 2850, "yPosLeftFieldBorder": 3700, "yPosLeftTouchline": 3000,
        "yPosLeftPenaltyArea": 2000, "yPosLeftGoalArea": 1100, "yPosLeftGoal": 800,
        "fieldLinesWidth": 50, "centerCircleRadius": 750, "goalPostRadius": 50,
        "penaltyMarkSize": 100}.items()))
    commands = [
        ["field", "import", str(team), "--format", "bhuman", "-o", str(tmp_path / "f.yaml")],
        ["export", str(world["poses"]), "--format", "json", "-o", str(tmp_path / "p.json")],
        ["report", str(world["omni"] / "runs" / "r"), "-o", str(tmp_path / "r.html"),
         "--worst", "0"],
    ]
    for args in commands:
        r = CliRunner().invoke(cli, ["-q", *args])
        assert r.exit_code == 0 and r.stdout == "" and r.stderr == "", (args, r.output)
        r = CliRunner().invoke(cli, [*args, "--overwrite"])
        assert r.exit_code == 0 and r.stdout == "" and "wrote" in r.stderr, (args, r.output)


def test_evaluate_without_o_says_where_the_report_went(world, tmp_path):
    """evaluate without -o wrote into the dataset folder (beside its poses file)
    without a word: the summary (stderr, -q silences it) names the folder."""
    poses = tmp_path / "poses.h5"
    shutil.copyfile(world["poses"], poses)
    r = CliRunner().invoke(cli, ["evaluate", str(poses), "--truth", str(world["omni"])])
    assert r.exit_code == 0, r.output
    assert f"written to {tmp_path / 'poses-eval'} (beside the poses file" in r.stderr
    assert (tmp_path / "poses-eval" / "report.json").is_file()


def test_localised_frames_are_the_accepted_ones(world_report, tmp_path):
    """The report counted not-accepted frames as 'localised' at infinite error.
    localised.* are over the matched frames with an accepted pose: their errors are finite,
    and the HTML page shows the same count."""
    import json

    rep = json.loads((world_report["omni"] / "runs" / "r" / "report.json").read_text())
    cols = _poses_columns(world_report["poses"])
    assert rep["localised"]["frames"] == rep["accepted"] == int(cols["accepted"].sum())
    assert rep["not_accepted"] > 0  # the case the issue names is in this run
    assert rep["localised"]["position_error_m"]["max"] not in ("inf", None)
    out = tmp_path / "r.html"
    r = CliRunner().invoke(cli, ["report", str(world_report["omni"] / "runs" / "r"), "-o",
                                 str(out), "--worst", "0"])
    assert r.exit_code == 0, r.output
    cell = re.search(r'data-key="localised/frames" data-value="([^"]*)"', out.read_text())
    assert cell and float(cell.group(1)) == rep["accepted"]


def test_plot_titles_name_the_method_and_dataset(world_report):
    """Plot titles said 'lut on report' (the report folder's name)."""
    from stages.common.report_file import load_report
    from stages.show.report_plots import plot_title

    report = load_report(world_report["omni"] / "runs" / "r", raw=True)
    assert plot_title(report) == "lut on omni"
    assert plot_title({"method": "mcl", "poses": "/a/b/poses-mcl.h5"}) == "mcl: poses-mcl.h5"


def test_trajectory_legend_estimate_has_a_marker(world):
    """The trajectory legend's 'estimate' (a colour-mapped scatter) had no marker."""
    from stages.common.dataset import read_csv
    from stages.evaluate.metrics import frame_errors
    from stages.show.figure import new_figure
    from stages.show.report_plots import plot_trajectories

    fe = frame_errors(_poses_columns(world["poses"]), read_csv(world["omni"] / "truth.csv",
                                                               "truth"), 0.02)
    fig = new_figure(6, 4)
    ax = fig.add_subplot()
    plot_trajectories(ax, fe)
    handles, labels = ax.get_legend_handles_labels()
    est = [h for h, lab in zip(handles, labels) if lab.startswith("estimate")]
    assert len(est) == 1
    assert est[0].get_marker() not in ("", "None", None) and est[0].get_markersize() > 0


def test_summary_picture_says_none_accepted():
    """The batch summary picture showed '0% inf' where no frame was accepted."""
    from stages.show.comparison import draw_summary
    from stages.show.figure import new_figure

    none = {"within": {"0.4": 0.0}, "position_error_m": {"median": math.inf}, "accepted": 0,
            "matched": 4}
    some = {"within": {"0.4": 0.5}, "position_error_m": {"median": 0.2}, "accepted": 2,
            "matched": 4}
    rows = [{"dataset": "d", "method": "a", "report": none},
            {"dataset": "d", "method": "b", "report": some}]
    fig = new_figure(4, 3)
    ax = fig.add_subplot()
    draw_summary(ax, rows)
    texts = [t.get_text() for t in ax.texts]
    assert texts == ["none\naccepted", "50%\n20.0 cm"], texts


def test_show_points_on_a_perspective_frame_gives_no_nan_share(world, tmp_path):
    """'nan% within 15 cm' for a perspective frame (it has lines, not points)."""
    r = CliRunner().invoke(cli, ["show", "points", str(world["kid"]), "--frame", "0",
                                 "--features", str(world["kid_features"]), "--map",
                                 str(world["kmap"]), "-o", str(tmp_path / "p.png")])
    assert r.exit_code == 0, r.output
    assert "nan" not in r.stderr and re.search(r"frame 000000, \d+ lines?\b", r.stderr)


def test_one_frame_is_one_frame(tmp_path):
    """simulate said 'wrote 1 frames'."""
    r = CliRunner().invoke(cli, ["simulate", "omni", "--field", "spl", "-o",
                                 str(tmp_path / "s"), "--frames", "1"])
    assert r.exit_code == 0, r.output
    assert f"wrote 1 frame to {tmp_path / 's'}" in r.stderr


def test_show_hypotheses_title_without_truth(world, tmp_path, monkeypatch):
    """The title said 'dashed white: truth' when the dataset has none (and was
    one line too long for the picture)."""
    from stages.show import hypotheses

    ds = copy_dataset(world, "omni", tmp_path)
    (ds / "truth.csv").unlink()
    poses = tmp_path / "p.h5"
    shutil.copyfile(world["poses"], poses)
    with h5py.File(poses, "a") as f:
        f.attrs["dataset"] = str(ds)
    seen = {}
    draw = hypotheses.draw_hypotheses

    def spy(*args, **kwargs):
        seen.update(kwargs)
        return draw(*args, **kwargs)

    monkeypatch.setattr(hypotheses, "draw_hypotheses", spy)
    hypotheses.main(None, poses, tmp_path / "h.png", frame=1)
    assert seen["truth"] is None and "truth" not in seen["title"].replace("no truth", "")
    assert all(len(line) <= 90 for line in seen["title"].splitlines()), seen["title"]


def test_dask_stop_message_of_our_own_cluster_is_not_shown():
    """A normal batch printed the nanny's 'Worker process still alive after 4.0
    seconds, killing' at the stop of its own cluster; the filter set there drops that line
    (to the debug log) and nothing else."""
    from stages.pipelines.batch import _quiet_stop

    def record(msg):
        return logging.LogRecord("distributed.nanny", logging.WARNING, __file__, 1, msg, None,
                                 None)

    assert not _quiet_stop(record("Worker process still alive after 4.0 seconds, killing"))
    assert _quiet_stop(record("Worker process 123 was killed by signal 9"))


def test_batch_results_inside_the_glob_rerun_resumes_without_a_cluster(world, tmp_path,
                                                                        monkeypatch):
    """A results folder inside the SPEC's own glob made every rerun refuse (it
    matched as a dataset holding RESULTS); a batch with nothing left to do must not start a
    Dask cluster."""
    import distributed

    (tmp_path / "rec").mkdir()
    copy_dataset(world, "omni", tmp_path / "rec")
    os.replace(tmp_path / "rec" / "omni", tmp_path / "rec" / "a")
    (tmp_path / "spec.yaml").write_text(f"map: {world['map']}\ndatasets:\n  - glob: rec/*\n"
                                        "methods: [lut]\n")
    args = ["batch", str(tmp_path / "spec.yaml"), "-o", str(tmp_path / "rec" / "results")]
    r = CliRunner().invoke(cli, [*args, "--serial"])
    assert r.exit_code == 0, r.output

    def no_cluster(*a, **k):
        raise AssertionError("a cluster was started with nothing to do")

    monkeypatch.setattr(distributed, "LocalCluster", no_cluster)
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    assert "1 runs: 1 finished before, 0 to do" in r.stderr


def test_start_half_warning_when_the_track_starts_in_the_other_half():
    """A wrong --start-half gave a track on the other half without a word. Warned when the
    track's first accepted poses lie on the other half beyond the margin of the halfway line;
    not for 'any', not for a track that starts in the given half and then walks across the
    halfway line (as a robot plays), not for a start at the centre, not on a handful of
    frames; frames not accepted do not count."""
    from stages.localize.symmetry import CENTRE_MARGIN_M, start_half_warning

    def warn(x, half="own", accepted=None):
        x = np.asarray(x, float)
        acc = np.isfinite(x) if accepted is None else np.asarray(accepted)
        return start_half_warning({"x": x, "accepted": acc}, {"conf": {"start_half": half}})

    starts_over = [np.nan, 2.0, 2.1, -1.0, 2.3, 2.4, -3.0, -3.5, -4.0]
    msg = warn(starts_over)
    assert msg and ("4 of the run's first 5 accepted poses place its start in the opponent"
                    " half") in msg
    assert warn(starts_over, "opponent") is None and warn(starts_over, "any") is None
    mirrored = -np.asarray(starts_over)
    assert "in the own half (x < 0)" in warn(mirrored, "opponent")
    walks_across = [-2.0, -1.5, -1.0, -0.6, -0.3] + [0.5 + 0.3 * i for i in range(30)]
    assert warn(walks_across) is None
    at_centre = [0.9 * CENTRE_MARGIN_M] * 5 + [3.0] * 10  # a kick-off, then upfield
    assert warn(at_centre) is None
    assert warn([2.0, 2.1, 2.2, 2.3]) is None  # too few to say
    x = [-2.0, 2.0, 2.1, 2.2, -1.8, -1.7, -1.6, 3.0, 3.0]
    assert warn(x) is not None
    assert warn(x, accepted=[True, False, False, False, True, True, True, True, True]) is None


def test_localize_warns_when_the_heading_overrules_the_start_half(msl2015_map, tmp_path,
                                                                 caplog):
    """On the product path: a rendered recording that starts in the opponent half, lut with
    its default field-aligned IMU heading. Told `--start-half own`, the heading overrules it
    (the poses are the truth's, not its mirror's) and localize says so; told the right half,
    nothing."""
    conf = dict(simulate.confs["omni-default"], frames=12, seed=4)
    data = simulate.main(conf, "msl-2015", tmp_path / "omni")
    truth = np.loadtxt(data / "truth.csv", delimiter=",", skiprows=1)
    assert truth[0, 1] > 2.0  # the walk starts well inside the opponent half
    feats = extract.main(None, data, tmp_path / "f.h5")
    for half, warned in (("own", True), ("opponent", False)):
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            r = CliRunner().invoke(cli, ["-q", "localize", str(data), "--map", str(msl2015_map),
                                         "--features", str(feats), "--method", "lut",
                                         "--start-half", half, "-o",
                                         str(tmp_path / f"p-{half}.h5")])
        assert r.exit_code == 0, r.output
        assert ("overruled the given half" in caplog.text) == warned, caplog.text
        cols, _ = read_poses(tmp_path / f"p-{half}.h5")
        acc = np.asarray(cols["accepted"], bool)
        assert acc.sum() >= 8 and np.all(np.asarray(cols["x"])[acc] > 0)  # the truth's half


def test_evaluate_warns_when_the_truth_starts_on_the_other_half(tmp_path, caplog):
    """100 mirrored frames at 0.99 and no warning. When the truth starts on the
    other half than the given start_half, evaluate says so (the numbers stay as they are);
    not for the right half, nor for 'any'."""
    from stages.common.artifacts import root_attrs
    from stages.common.poses_file import PoseTrack, write_poses

    n = 12
    t = np.arange(n) * 0.1
    tx, ty, th = 2.0 + 0.1 * np.arange(n), np.full(n, 1.0), np.zeros(n)
    (tmp_path / "truth.csv").write_text("stamp,x,y,theta\n" + "".join(
        f"{a:.3f},{b:.3f},{c:.3f},{d:.3f}\n" for a, b, c, d in zip(t, tx, ty, th)))
    for half, warned in (("own", True), ("opponent", False), ("any", False)):
        track = PoseTrack()
        for i in range(n):
            track.add(f"{i:06d}", t[i], (-tx[i], -ty[i], math.pi), confidence=0.99)
        attrs = root_attrs("fieldloc.poses", 2, {"method": "lut", "start_half": half}, {})
        attrs.update(method="lut", field="spl", dataset=str(tmp_path))
        poses = write_poses(tmp_path / f"p-{half}.h5", track, attrs)
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            r = CliRunner().invoke(cli, ["-q", "evaluate", str(poses), "--truth",
                                         str(tmp_path / "truth.csv"), "-o",
                                         str(tmp_path / f"rep-{half}")])
        assert r.exit_code == 0, r.output
        said = ("given start_half own, but the truth starts at x = 2.00 m, in the opponent"
                " half; 12 of 12 frames' top hypotheses are the truth's mirror image"
                in caplog.text)
        assert said == warned, caplog.text


def test_stale_extract_lock_is_taken_over(world, tmp_path, caplog):
    """A lock left by a killed extract (its pid gone) is taken over with a warning; the run
    finishes and leaves no lock."""
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    (tmp_path / ".f.h5.fieldloc-lock").write_text(f"{p.pid}\n")
    with caplog.at_level(logging.WARNING):
        r = CliRunner().invoke(cli, ["-q", "extract", str(world["omni"]), "-o",
                                     str(tmp_path / "f.h5")])
    assert r.exit_code == 0, r.output
    assert f"removed the lock of an interrupted run (pid {p.pid})" in caplog.text
    assert sorted(q.name for q in tmp_path.iterdir()) == ["f.h5"]


def test_full_disk_ends_in_one_line_naming_the_file(world_report, tmp_path, monkeypatch):
    """On a full disk build-map printed HDF5's raw two-line message, extract and
    report 'No space left on device' without the file (and extract could crash in HDF5).
    build-map and extract check the room first; a write that meets a full disk anyway (here
    made to: the system's ENOSPC, and HDF5's message of one) ends in one line naming the
    target, and nothing is left under its name."""
    import errno
    from collections import namedtuple

    from stages.common import resources

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(resources.shutil, "disk_usage", lambda p: usage(10**6, 10**6, 20000))
    for args, said in ((["build-map", "spl", "-o", str(tmp_path / "m.h5")],
                        f"the map {tmp_path / 'm.h5'} would write about"),
                       (["extract", str(world_report["omni"]), "-o", str(tmp_path / "f.h5")],
                        f"extract into {tmp_path / 'f.h5'} would write about")):
        r = CliRunner().invoke(cli, ["-q", *args])
        assert r.exit_code == 1 and said in r.stderr, r.output
        assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    monkeypatch.undo()

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_text", full)
    out = tmp_path / "r.html"
    r = CliRunner().invoke(cli, ["-q", "report", str(world_report["omni"] / "runs" / "r"),
                                 "-o", str(out), "--worst", "0"])
    assert r.exit_code == 1 and f"cannot write {out}: no space left" in r.stderr, r.output
    assert len(r.stderr.strip().splitlines()) == 1 and not out.exists()
    monkeypatch.undo()

    def hdf5_full(*a, **k):
        raise OSError("Can't write data (file write failed: time = now\n, filename = 'x',"
                      " file descriptor = 3, errno = 28, error message = 'No space left on"
                      " device', buf = 0x0, total write size = 8)")

    monkeypatch.setattr(h5py.Group, "create_dataset", hdf5_full)
    target = tmp_path / "m2.h5"
    r = CliRunner().invoke(cli, ["-q", "build-map", "spl", "--resolution", "0.5", "-o",
                                 str(target)])
    assert r.exit_code == 1 and f"cannot write {target}: no space left" in r.stderr, r.output
    assert len(r.stderr.strip().splitlines()) == 1 and not target.exists()


# ---------------------------------------------------------------------------- newcomer


def _yaml_blocks(text: str) -> list[str]:
    return re.findall(r"```yaml\n(.*?)```", text, flags=re.S)


def test_readme_yaml_examples_parse(tmp_path):
    """Every calib.yaml and field YAML example of the manual reads as the code reads it."""
    blocks = _yaml_blocks((ROOT / "docs" / "manual.md").read_text())
    kinds = []
    for i, block in enumerate(blocks):
        d = yaml.safe_load(block)
        path = tmp_path / f"example{i}.yaml"
        path.write_text(block)
        if "kind" in d:
            cam = load_calib(path)
            kinds.append(cam.kind + ("-table" if getattr(cam, "radial_table", None) is not None
                                     else ""))
        else:
            field_from_spec(d, str(path), block)
            kinds.append("field")
    assert sorted(kinds) == ["field", "omni", "omni-table", "perspective"]


def test_bench_table_of_the_readme_comes_from_a_bench_json(tmp_path):
    """docs/results.md's performance table is `bench --from-json --format markdown` of one run:
    rows survive the JSON round trip (NaN as null) and become one table line each."""
    from stages.pipelines.bench import harness

    rows = [harness.Row("a row", median_ms=1.5, goal="<= 2 ms", meets_goal=True,
                      baseline="the other", baseline_ms=3.0, ratio=0.5, note="a note"),
            harness.Row("no numbers")]
    path = harness.write_json(rows, tmp_path / "b.json")
    r = CliRunner().invoke(cli, ["bench", "--from-json", str(path), "--format", "markdown"])
    assert r.exit_code == 0, r.output
    lines = r.stdout.splitlines()
    assert lines[2] == "| a row | 1.5 ms |  | the other: 3 ms | 0.5 |  | <= 2 ms | yes |"
    assert lines[3].startswith("| no numbers |") and "- a row: a note" in lines
    text = (ROOT / "docs" / "results.md").read_text()
    assert "<!-- bench:begin -->\n| row | median | CPU |" in text


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
def test_make_pipeline_with_mcl_prints_the_table_once(world, tmp_path):
    """`make pipeline METHOD=mcl` on a perspective dataset: no --heading passed to mcl, and
    the table printed once."""
    data = tmp_path / "kid"
    shutil.copytree(world["kid"], data)
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}"
               f"{os.environ.get('PATH', '')}")
    venv = Path(sys.executable).parents[1]
    stamp = tmp_path / "installed"  # the venv is there: make must not install it again
    stamp.touch()
    r = subprocess.run(["make", "--no-print-directory", "pipeline", f"DATA={data}",
                        "FIELD=kidsize", "METHOD=mcl", f"OUT={tmp_path / 'build'}",
                        f"VENV={venv}", f"STAMP={stamp}"],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "--heading" not in r.stdout
    assert r.stdout.count("median cm") == 1, r.stdout


# ---------------------------------------------------------------------------- the figures


KIND_NAMES = {"data-lost": "data lost", "traceback": "tracebacks", "hang": "hangs",
              "silent": "silent or misleading", "newcomer": "newcomer"}


def figures_block() -> str:
    """docs/pipeline.md's figures, from what this suite holds."""
    import test_fuzz_readers
    import test_kill

    counts = {k: sum(c.kind == k for c in CASES) for k in KIND_NAMES}
    checks = [n for n, f in globals().items() if n.startswith("test_") and n not in
              ("test_fault", "test_readme_states_the_figures")
              and not any(m.name == "xfail" for m in getattr(f, "pytestmark", []))]
    fuzz = [n for n in dir(test_fuzz_readers) if n.startswith("test_")]
    stages = sorted({s for s, _ in test_kill.INTERRUPTIONS})
    n_fuzz = len(fuzz) * test_fuzz_readers.EXAMPLES
    tried = len(CASES) + len(checks) + len(test_kill.INTERRUPTIONS) + n_fuzz
    by_kind = ", ".join(f"{counts[k]} {v}" for k, v in KIND_NAMES.items())
    return "\n".join([
        f"- {len(CASES)} command cases ({by_kind}), each checked for its exit code, its one-line"
        " message, the hashes of every input file afterwards, and that a refused command"
        f" writes nothing; {len(checks)} more checks of the output rules and the manual's"
        " examples;",
        f"- {len(test_kill.INTERRUPTIONS)} interruptions at seeded random moments (kill -9 of"
        f" {', '.join(stages)}; Ctrl-C of extract), each followed by a run that must clean up,"
        " resume and match an uninterrupted run;",
        f"- {n_fuzz} fuzzed inputs ({test_fuzz_readers.EXAMPLES} each for {len(fuzz)} readers:"
        " field YAML, calib.yaml, dataset CSVs, points and calibration-pair CSVs, MINHO .cfg,"
        " -c overrides);",
        f"- in all {tried} inputs tried, {len(CASES) + len(test_kill.INTERRUPTIONS)} deliberate"
        f" faults injected beside the fuzzed inputs; survived: all {tried}; tracebacks 0; data"
        " lost 0 (any of them is a failing test).",
    ])


def test_readme_states_the_figures():
    text = (ROOT / "docs" / "pipeline.md").read_text()
    m = re.search(r"<!-- faults:begin -->\n(.*?)<!-- faults:end -->", text, flags=re.S)
    assert m, "docs/pipeline.md lacks the faults figures block"
    want = figures_block()
    got = " ".join(m.group(1).split())
    assert got == " ".join(want.split()), f"update docs/pipeline.md's figures to:\n{want}"


def test_evaluate_draws_a_custom_fields_poses_on_the_maps_field(world_report, tmp_path, caplog):
    """Poses made with a custom field's map (its name no preset, its YAML gone): evaluate and
    report draw them on the field the map carries, with no warning about the name."""
    _setup_custom_field_poses(world_report, tmp_path)
    with caplog.at_level(logging.WARNING):
        res = CliRunner().invoke(cli, ["evaluate", str(tmp_path / "p.h5"), "-o",
                                       str(tmp_path / "r")])
        page = CliRunner().invoke(cli, ["report", str(tmp_path / "r"), "-o",
                                        str(tmp_path / "r.html")])
    text = res.output + page.output + caplog.text
    assert res.exit_code == 0 and page.exit_code == 0, text
    assert "unknown field preset" not in text and "without field lines" not in text, text
    assert (tmp_path / "r" / "plots").is_dir() and (tmp_path / "r.html").is_file()


# ---- s54 group H4: files and interruptions


@pytest.mark.parametrize("command,args,note", [
    # stopped before a frame was finished: nothing kept (a run that kept frames says so:
    # tests/test_kill.py)
    ("extract", ["extract", "{omni}", "-o", "{ws}/f.h5"],
     "no half-written file was left; a rerun starts over"),
    ("build_map", ["build-map", "spl", "-o", "{ws}/m.h5"],
     "no half-written file was left; a rerun starts over"),
    ("simulate", ["simulate", "omni", "--field", "spl", "--frames", "1", "-o", "{ws}/s"],
     "no half-written file was left; a rerun starts over"),
])
@pytest.mark.parametrize("stop,word,rc", [(KeyboardInterrupt, "interrupted", 130),
                                          ("Terminated", "terminated", 143)])
def test_an_interrupt_says_what_a_rerun_of_the_command_does(world, tmp_path, monkeypatch,
                                                           command, args, note, stop, word, rc):
    """Ctrl-C said "extract resumes where it stopped" after any command, and SIGTERM said
    nothing: each command now says whether its rerun resumes, and SIGTERM (raised as the
    interrupt Terminated) says "terminated" with exit code 143."""
    import importlib

    from fieldloc_cli import lazy_group

    stop = getattr(lazy_group, stop) if isinstance(stop, str) else stop

    def stopped(*a, **k):
        raise stop()

    monkeypatch.setattr(importlib.import_module(f"stages.{command}"), "main", stopped)
    res = CliRunner().invoke(cli, [a.format(ws=tmp_path, **world) for a in args])
    assert res.exit_code == rc, res.output
    assert res.stderr == f"fieldloc: {word} ({note})\n"


def test_sigterm_ends_a_command_as_an_interrupt_cleaning_up(tmp_path):
    """A terminated simulate (SIGTERM, as `kill` or a job's time limit sends) removes the
    temporary folder it was rendering into and says so in one line, exit code 143 (it ended
    without a word, leaving its part)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", "from fieldloc_cli.main import cli; cli()", "simulate", "omni",
         "--field", "spl", "--frames", "200", "-o", str(tmp_path / "s")],
        stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    end = time.monotonic() + 120
    while not any(tmp_path.glob(".s.fieldloc-*.part/images/*.png")):
        assert proc.poll() is None and time.monotonic() < end, proc.stderr.read()
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _out, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert err.splitlines() == ["fieldloc: terminated (no half-written file was left; a rerun"
                                " starts over)"], err
    assert list(tmp_path.iterdir()) == []


def test_evaluate_stopped_while_drawing_leaves_no_report_json(world, tmp_path, monkeypatch):
    """report.json was written before the plots: an evaluate stopped while drawing left a
    folder that looked finished without its plots, and `report` made a page of it. Now
    report.json comes last (after the plots), so `report` refuses the folder, and the rerun
    writes the whole report."""
    from stages.common.report_file import PLOT_NAMES
    from stages.show import figure

    save = figure.save_figure
    calls = []

    def stop_at_the_second(*a, **k):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return save(*a, **k)

    monkeypatch.setattr("stages.show.report_plots.save_figure", stop_at_the_second)
    r = tmp_path / "r"
    args = ["evaluate", str(world["poses"]), "--truth", str(world["omni"] / "truth.csv"),
            "-o", str(r)]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 130, res.output
    assert not (r / "report.json").exists()
    page = CliRunner().invoke(cli, ["report", str(r), "-o", str(tmp_path / "r.html")])
    assert page.exit_code == 1 and not (tmp_path / "r.html").exists(), page.output
    monkeypatch.setattr("stages.show.report_plots.save_figure", save)
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    assert (r / "report.json").is_file()
    assert sorted(p.name for p in (r / "plots").iterdir()) == sorted(PLOT_NAMES)


def test_a_damaged_chunk_of_an_interrupted_extract_is_discarded(world, tmp_path, caplog):
    """A chunk a crash left unreadable in extract's resume folder (random bytes, or empty)
    gave a Python traceback or click's bare "Aborted!" (trial D2, P3): it is discarded with
    one warning and its frames are extracted again."""
    from stages.common.features_file import FeaturesFile

    for data in (bytes(range(256)) + b"x" * 44, b""):
        ws = tmp_path / f"ws{len(data)}"
        ws.mkdir()
        _setup_parts_of_this_run(_write("000000.png+2.npz", data))(world, ws)
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            res = CliRunner().invoke(cli, ["extract", str(world["omni"]), "-o",
                                           str(ws / "f.h5")])
        assert res.exit_code == 0, res.output
        assert "a damaged chunk of an interrupted run" in caplog.text, caplog.text
        assert "Traceback" not in res.output
        with FeaturesFile(ws / "f.h5") as ff:
            assert len(ff.names) == 4
        assert not (ws / ".f.h5.parts").exists()
