"""Issue 8: bad input and faults, each as a case of the command line.

A case is a command, the exit code it must end with, a fragment of its message (stderr or a
warning), and what it must not do: no command ends in a traceback, none changes or removes a
file it was given (every file of the shared inputs and of the case's folder is hashed before
and after), and a refused command writes nothing at all (not even a temporary part). Some cases
also check what a successful command wrote. The classes follow the issue: data lost,
tracebacks, silent or misleading results, what a newcomer hit. Interruptions are in
tests/test_kill.py, the readers' fuzzing in tests/test_fuzz_readers.py; the figures of all
three are stated in the README and checked against the suite at the end of this file.
"""

from __future__ import annotations

import hashlib
import logging
import os
import re
import shutil
import stat
import subprocess
import sys
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
from stages.common.camera import load_calib
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
    p["poses"] = localize.main({"method": "lut"}, p["omni"], p["map"], root / "poses.h5",
                               features=p["features"])
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
    kind: str  # data-lost | traceback | silent | newcomer (the classes)
    args: list[str]
    rc: int
    fragment: str
    setup: object = None  # (world, ws) -> dict of more placeholders
    check: object = None  # (paths, result) -> None, extra assertions
    removes_parts: bool = False  # stale temporary parts set up by the case may vanish


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


LOCALIZE = ["localize", "{omni}", "--map", "{map}", "--features", "{features}"]
W = "{ws}"

CASES = [
    # ------------------------------------------------------------------ data lost
    Case("localize -o the map --overwrite", "data-lost",
         [*LOCALIZE, "-o", "{map}", "--overwrite"], 1, "is an input of this command (map)"),
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
         ["build-map", W + "/f.yaml", "-o", W + "/m.h5"], 1, "would need about",
         setup=_setup_field({"length": 100000.0})),
    Case("field length: 1e5 (simulate)", "traceback",
         ["simulate", "omni", "--field", W + "/f.yaml", "-o", W + "/sim", "--frames", "1"], 1,
         "would need about", setup=_setup_field({"length": 100000.0})),
    Case("alias bomb in a field's notes (build-map)", "hang",
         ["build-map", W + "/f.yaml", "-o", W + "/m.h5"], 1, "YAML aliases expand to more than",
         setup=_setup_field_text(f"\nnotes: {ALIAS_BOMB}\n")),
    Case("alias bomb in calib.yaml (extract)", "hang",
         ["extract", "{ds}", "-o", W + "/f.h5"], 1, "YAML aliases expand to more than",
         setup=_setup_calib_text(f"\nbomb: {ALIAS_BOMB}\n")),
    Case("alias bomb as a -c value (localize)", "hang",
         [*LOCALIZE, "-o", W + "/p.h5", "-c", f"temperature={ALIAS_BOMB}"], 1,
         "must be a number, got '[&a0 [lol, lol"),
    Case("a field key given twice (build-map)", "silent",
         ["build-map", W + "/f.yaml", "-o", W + "/m.h5"], 1, "the key 'name' is given twice",
         setup=_setup_field_text("\nname: twice\n")),
    Case("build-map --resolution 0.001", "traceback",
         ["build-map", "spl", "-o", W + "/m.h5", "--resolution", "0.001"], 1,
         "would need about"),
    Case("simulate --frames 1e12", "traceback",
         ["simulate", "omni", "--field", "spl", "-o", W + "/sim", "--frames",
          "1000000000000"], 1, "would need about"),
    Case("simulate --frames that fill the disk", "traceback",
         ["simulate", "omni", "--field", "spl", "-o", W + "/sim", "--frames", "3000000000"],
         1, "would"),
    Case("show map --heading-deg nan", "traceback",
         ["show", "map", "{map}", "--table", "radial", "--cell", "0", "0", "--heading-deg",
          "nan", "-o", W + "/m.png"], 2, "is not a finite number"),
    Case("build-map --resolution inf", "traceback",
         ["build-map", "spl", "-o", W + "/m.h5", "--resolution", "inf"], 2,
         "is not a finite number"),
    Case("-c min_observations=abc", "traceback",
         [*LOCALIZE, "-o", W + "/p.h5", "-c", "min_observations=abc"], 1,
         "conf 'min_observations' must be a whole number"),
    Case("-c temperature=nan", "traceback",
         [*LOCALIZE, "-o", W + "/p.h5", "-c", "temperature=.nan"], 1,
         "conf 'temperature' must be a finite number"),
    Case("-c search=1 (a group of keys)", "traceback",
         [*LOCALIZE, "-o", W + "/p.h5", "-c", "search=1"], 1, "is a group of keys"),
    Case("-c a=1 -c a.b=2", "traceback",
         [*LOCALIZE, "-o", W + "/p.h5", "-c", "search=1", "-c", "search.c=2"], 1,
         "cannot also hold keys"),
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
         "is an input of this command (features)", setup=_setup_own_features),
    Case("inspect report.json", "newcomer", ["inspect", "{omni}/runs/r/report.json"], 0,
         "schema fieldloc.report"),
    Case("inspect a FIFO", "hang", ["inspect", W + "/pipe.h5"], 1, "not a regular file",
         setup=lambda w, ws: os.mkfifo(ws / "pipe.h5") or {}),
    Case("inspect a file fieldloc does not read", "newcomer", ["inspect", "{marks}.x"], 1,
         "file not found"),
    Case("inspect a README", "newcomer", ["inspect", str(ROOT / "README.md")], 1,
         "not a file fieldloc reads (inspect reads HDF5"),
]


@pytest.fixture(scope="module")
def world_report(world):
    """A report inside the shared dataset for the inspect case (made once)."""
    from stages import evaluate

    evaluate.main(None, world["poses"], world["omni"], world["omni"] / "runs" / "r")
    return world


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_fault(case, world_report, tmp_path, caplog):
    world = world_report
    paths = {k: v for k, v in world.items()}
    paths["ws"] = tmp_path
    if case.setup is not None:
        paths.update(case.setup(world, tmp_path) or {})
    args = [str(a).format(**paths) for a in case.args]
    before = snapshot(world["root"], tmp_path)
    with caplog.at_level(logging.WARNING):
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
               and not (case.removes_parts and p.endswith(".part"))]
    assert not changed, f"inputs changed or removed: {changed}"
    if case.rc:
        assert set(after) == set(before), f"a refused command wrote {set(after) - set(before)}"
    if case.check is not None:
        case.check(paths, res)


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


def test_csv_files_have_lf_line_endings(world):
    for name in ("truth.csv", "odometry.csv", "imu.csv", "frames.csv"):
        assert b"\r" not in (world["omni"] / name).read_bytes()


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
                        parse_overrides(["inlier_error=1e-4", "min_observations=6.0"]))
    assert conf["inlier_error"] == pytest.approx(1e-4) and conf["min_observations"] == 6
    assert isinstance(conf["min_observations"], int)


# ---------------------------------------------------------------------------- newcomer


def _yaml_blocks(text: str) -> list[str]:
    return re.findall(r"```yaml\n(.*?)```", text, flags=re.S)


def test_readme_yaml_examples_parse(tmp_path):
    """Every calib.yaml and field YAML example of the README reads as the code reads it."""
    blocks = _yaml_blocks((ROOT / "README.md").read_text())
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
    """The README's performance table is `bench --from-json --format markdown` of one run:
    rows survive the JSON round trip (NaN as null) and become one table line each."""
    from stages.pipelines import bench

    rows = [bench.Row("a row", median_ms=1.5, goal="<= 2 ms", meets_goal=True,
                      baseline="the other", baseline_ms=3.0, ratio=0.5, note="a note"),
            bench.Row("no numbers")]
    path = bench.write_json(rows, tmp_path / "b.json")
    r = CliRunner().invoke(cli, ["bench", "--from-json", str(path), "--format", "markdown"])
    assert r.exit_code == 0, r.output
    lines = r.stdout.splitlines()
    assert lines[2] == "| a row | 1.5 ms |  | the other: 3 ms | 0.5 |  | <= 2 ms | yes |"
    assert lines[3].startswith("| no numbers |") and "- a row: a note" in lines
    text = (ROOT / "README.md").read_text()
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
    """The README's figures, from what this suite holds."""
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
        f" writes nothing; {len(checks)} more checks of the output rules and the README's"
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
    text = (ROOT / "README.md").read_text()
    m = re.search(r"<!-- faults:begin -->\n(.*?)<!-- faults:end -->", text, flags=re.S)
    assert m, "README lacks the faults figures block"
    want = figures_block()
    got = " ".join(m.group(1).split())
    assert got == " ".join(want.split()), f"update the README's figures to:\n{want}"
