"""Hostile inputs: property-based fuzzing of every reader of user input.

Field YAML, calib.yaml (omni and perspective), the dataset CSVs, the points and calibration
pair CSVs, the MINHO team's .cfg files and ``-c key=value`` overrides of every stage's presets,
each from a few hundred generated inputs: valid files with one value or key changed to
something hostile (wrong type, NaN, huge, negative, missing, extra), and raw text or bytes. The
only outcomes allowed are success or a FieldlocError (one clear line for the user), never
another exception; what succeeds must also be usable (a camera that extracts a frame, a field
with its crossings, values of the preset's type, finite CSV values in time order).

Examples are derandomised (the same inputs every run); ``EXAMPLES`` sets how many per reader.
"""

from __future__ import annotations

import math
import numbers
import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from stages.common.camera import load_calib
from stages.common.dataset import CSV_COLUMNS, NAN_ALLOWED, TIME_SERIES, read_csv
from stages.common.errors import FieldlocError
from stages.common.field import load_field

EXAMPLES = int(__import__("os").environ.get("FIELDLOC_FUZZ_EXAMPLES", "200"))
FUZZ = settings(max_examples=EXAMPLES, deadline=None, database=None,
                derandomize=__import__("os").environ.get("FIELDLOC_FUZZ_RANDOM") is None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
ROOT = Path(__file__).resolve().parents[1]

# hostile scalars: what a typo, a wrong unit, a spreadsheet export or an attacker writes
HOSTILE = st.one_of(
    st.none(), st.booleans(), st.integers(-10**12, 10**12),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, -1, 1e-300, 1e300, 1e5, -0.0, "nan", "1e-4", "", "abc", "0x10",
                     [], {}, [1], [1, 2, 3], [[1, 2]], {"a": 1}, [None, None], [-480, 0]]),
    st.text(max_size=12),
    st.lists(st.one_of(st.floats(allow_nan=True), st.integers(-1000, 1000), st.text(max_size=3)),
             max_size=8),
)
# plausible values: what a careful user writes, or one slip from it (these reach the code past
# the checks, where a crash would hide)
PLAUSIBLE = st.one_of(st.floats(0.0, 50.0), st.integers(0, 800),
                      st.lists(st.floats(-1.0, 600.0), min_size=2, max_size=6))
VALUE = st.one_of(PLAUSIBLE, PLAUSIBLE, HOSTILE)
TEXT = st.one_of(st.text(max_size=300),
                 st.binary(max_size=200).map(lambda b: b.decode("latin-1")))


def _write(folder: Path, name: str, content) -> Path:
    p = folder / name
    if isinstance(content, bytes):
        p.write_bytes(content)
    else:
        p.write_text(content if isinstance(content, str) else yaml.safe_dump(content),
                     encoding="utf-8", errors="surrogatepass")
    return p


def _mutated(base: dict, data) -> dict:
    """``base`` with one (possibly nested) key changed, removed or added."""
    d = yaml.safe_load(yaml.safe_dump(base))
    target = d
    keys = list(d)
    key = data.draw(st.sampled_from(keys + ["unexpected"]), label="key")
    while isinstance(target.get(key), dict) and data.draw(st.booleans(), label="descend"):
        target = target[key]
        key = data.draw(st.sampled_from(list(target) + ["unexpected"]), label="subkey")
    action = data.draw(st.sampled_from(["set", "set", "set", "delete"]), label="action")
    if action == "delete":
        target.pop(key, None)
    else:
        target[key] = data.draw(VALUE, label="value")
    return d


# ---------------------------------------------------------------------------- field YAML


FIELD = yaml.safe_load((ROOT / "maps" / "spl.yaml").read_text())
MSL = yaml.safe_load((ROOT / "maps" / "msl.yaml").read_text())


@pytest.mark.filterwarnings("error::RuntimeWarning")  # no overflow or 0/0 in what is read
@FUZZ
@given(data=st.data())
def test_field_yaml_reader(data):
    with tempfile.TemporaryDirectory() as tmp:
        kind = data.draw(st.sampled_from(["mutated", "mutated-msl", "text"]), label="kind")
        if kind == "text":
            content = data.draw(TEXT, label="text")
        else:
            content = _mutated(FIELD if kind == "mutated" else MSL, data)
        path = _write(Path(tmp), "field.yaml", content)
        try:
            fm = load_field(path)
        except FieldlocError:
            event("refused")
            return
        event("read")
        assert fm.length > 0 and fm.width > 0 and math.isfinite(fm.length * fm.width)
        assert len(fm.crossings) == len(fm.crossing_types)
        assert np.all(np.isfinite(fm.segments)) and np.all(np.isfinite(fm.crossings))


# ---------------------------------------------------------------------------- calib.yaml


def _omni_base(table: bool) -> dict:
    d = {"kind": "omni", "image_size": [160, 120], "centre": [80.0, 60.0],
         "valid_radius": [8.0, 55.0], "forward_angle": 1.5708, "mirrored": False}
    if table:
        d.update(version=2, radial_model="table",
                 radial_table={"radius_px": [10.0, 25.0, 40.0, 55.0],
                               "distance_m": [0.3, 0.8, 1.6, 3.0]})
    else:
        d["polynomial"] = [0.0, 0.02, 0.0, 0.0, 0.0, 1e-8]
    return d


def _perspective_base() -> dict:
    from stages.common.perspective_camera import PerspectiveCamera

    d = PerspectiveCamera(image_size=(160, 100), fx=70.0, fy=70.0, cx=79.5, cy=49.5).to_dict()
    return yaml.safe_load(yaml.safe_dump(d))


@FUZZ
@given(data=st.data())
def test_calib_yaml_reader(data):
    from stages.extract import omni

    with tempfile.TemporaryDirectory() as tmp:
        kind = data.draw(st.sampled_from(["omni", "omni-table", "perspective", "text"]),
                         label="kind")
        if kind == "text":
            content = data.draw(TEXT, label="text")
        elif kind == "perspective":
            content = _mutated(_perspective_base(), data)
        else:
            content = _mutated(_omni_base(kind == "omni-table"), data)
        path = _write(Path(tmp), "calib.yaml", content)
        try:
            cam = load_calib(path)
        except FieldlocError:
            event("refused")
            return
        event(f"read {cam.kind}")
        w, h = cam.image_size
        assert w > 0 and h > 0
        if cam.kind == "omni" and w * h <= 400 * 400:
            # what the camera is for: extracting a frame must work or say why, in one line
            image = np.full((h, w, 3), 90, np.uint8)
            try:
                out = omni.extract_frame(image, cam, omni.confs["default"])
            except FieldlocError:
                event("frame refused")
                return
            event("frame extracted")
            assert out["radial"].shape == (72, 4)


# ---------------------------------------------------------------------------- CSV files


def _csv_text(data, kind: str) -> str:
    """A valid table of ``kind`` with at most one fault injected: a hostile cell, a row too
    short or too long, stamps swapped or repeated, a wrong header, CRLF or blank lines."""
    cols = list(CSV_COLUMNS[kind])
    n = data.draw(st.integers(0, 8), label="rows")
    rows = []
    for i in range(n):
        row = [f"{0.1 * i:.3f}" if c == "stamp" else
               (f"{i:06d}.png" if c == "name" else
                f"{data.draw(st.floats(-10.0, 10.0), label='v'):.4f}") for c in cols]
        rows.append(row)
    fault = data.draw(st.sampled_from(["none", "cell", "cell", "short", "long", "swap",
                                       "repeat", "header", "blank"]), label="fault")
    header = cols
    if rows and fault == "cell":
        i = data.draw(st.integers(0, n - 1), label="row")
        j = data.draw(st.integers(0, len(cols) - 1), label="col")
        rows[i][j] = data.draw(st.one_of(
            st.floats(allow_nan=True, allow_infinity=True).map(repr),
            st.sampled_from(["nan", "inf", "-inf", "", " 1.0 ", "1e-4", "abc", "0x1", '"1,5"',
                             "000003.png", "#", "1e400"]),
            st.text(max_size=4)), label="cell")
    elif rows and fault in ("short", "long"):
        i = data.draw(st.integers(0, n - 1), label="row")
        rows[i] = rows[i][:-1] if fault == "short" else rows[i] + ["0"]
    elif n >= 2 and fault in ("swap", "repeat"):
        i = data.draw(st.integers(0, n - 2), label="row")
        if fault == "swap":
            rows[i], rows[i + 1] = rows[i + 1], rows[i]
        else:
            rows[i + 1] = list(rows[i])
    elif fault == "header":
        header = data.draw(st.one_of(st.permutations(cols),
                                     st.lists(st.sampled_from(cols + ["x", ""]), max_size=5)),
                           label="header")
    sep = data.draw(st.sampled_from(["\n", "\r\n"]), label="sep")
    lines = [",".join(header), *(",".join(r) for r in rows)]
    if fault == "blank":
        lines.insert(data.draw(st.integers(1, len(lines)), label="at"),
                     data.draw(st.sampled_from(["", "# a comment", " , ", ","]), label="blank"))
    return sep.join(lines) + sep


@FUZZ
@given(data=st.data())
def test_dataset_csv_reader(data):
    kind = data.draw(st.sampled_from(sorted(CSV_COLUMNS)), label="kind")
    with tempfile.TemporaryDirectory() as tmp:
        if data.draw(st.integers(0, 9), label="raw") == 0:
            content = data.draw(st.one_of(TEXT, st.binary(max_size=100)), label="content")
        else:
            content = _csv_text(data, kind)
        path = _write(Path(tmp), f"{kind}.csv", content)
        try:
            cols = read_csv(path, kind)
        except FieldlocError:
            event("refused")
            return
        event("read")
        n = len(cols[CSV_COLUMNS[kind][0]])
        assert n >= 1
        for name, v in cols.items():
            if name == "name":
                continue
            bad = ~np.isfinite(v)
            if name in NAN_ALLOWED.get(kind, ()):
                bad &= ~np.isnan(v)
            assert not bad.any(), (name, v)
        if kind in TIME_SERIES:
            assert np.all(np.diff(cols["stamp"]) > 0)


@FUZZ
@given(data=st.data())
def test_points_and_calibration_pair_readers(data):
    from stages.calibrate import read_points
    from stages.localize import _read_points_csv

    which = data.draw(st.sampled_from(["points", "pairs"]), label="which")
    header = "frame,x,y" if which == "points" else "radius_px,distance_m"
    good = st.floats(0.0, 300.0).map(lambda v: f"{v:.3f}")
    cell = st.one_of(good, good, good, st.floats(allow_nan=True, allow_infinity=True).map(repr),
                     st.sampled_from(["", "nan", "abc", "000001", "3", "-1"]),
                     st.text(max_size=4))
    width = 3 if which == "points" else 2
    row = st.one_of(st.lists(cell, min_size=width, max_size=width),
                    st.lists(cell, min_size=width, max_size=width),
                    st.lists(cell, min_size=0, max_size=4)).map(",".join)
    rows = data.draw(st.lists(row, max_size=10), label="rows")
    head = data.draw(st.sampled_from([header, header, header, header.upper(), "", "a,b"]),
                     label="head")
    with tempfile.TemporaryDirectory() as tmp:
        path = _write(Path(tmp), "p.csv", "\n".join([head, *rows]) + "\n")
        try:
            out = _read_points_csv(path) if which == "points" else read_points(path)
        except FieldlocError:
            event("refused")
            return
        event("read")
        if which == "points":
            assert out and all(math.isfinite(x) and math.isfinite(y) for _n, x, y in out)
        else:
            assert np.all(np.isfinite(out[0])) and np.all(np.isfinite(out[1]))


@FUZZ
@given(mirror=TEXT, image=TEXT)
def test_minho_cfg_reader(mirror, image):
    from stages.calibrate.minho import read_minho

    with tempfile.TemporaryDirectory() as tmp:
        _write(Path(tmp), "mirror.cfg", mirror)
        _write(Path(tmp), "image.cfg", image)
        try:
            read_minho(tmp)
        except FieldlocError:
            return


# ---------------------------------------------------------------------------- -c overrides


def _all_presets() -> dict[str, dict]:
    from stages import build_map, calibrate, evaluate, localize, simulate
    from stages.extract import kind_confs
    from stages.pipelines import frame_belief as belief

    out = {}
    for stage, confs in (("build-map", build_map.confs), ("simulate", simulate.confs),
                         ("extract-omni", kind_confs("omni")),
                         ("extract-perspective", kind_confs("perspective")),
                         ("lut", localize.method_confs("lut")),
                         ("mcl", localize.method_confs("mcl")), ("evaluate", evaluate.confs),
                         ("calibrate", calibrate.confs), ("belief", belief.confs)):
        out[stage] = confs
    return out


PRESETS = _all_presets()


def _key_paths(d: dict, prefix="") -> list[str]:
    out = []
    for k, v in d.items():
        out.append(prefix + str(k))
        if isinstance(v, dict):
            out += _key_paths(v, prefix + str(k) + ".")
    return out


def _at(d: dict, path: str):
    for p in path.split("."):
        d = d[p]
    return d


@FUZZ
@given(data=st.data())
def test_conf_overrides(data):
    from stages.common.conf import parse_overrides, resolve_conf

    stage = data.draw(st.sampled_from(sorted(PRESETS)), label="stage")
    confs = PRESETS[stage]
    preset = data.draw(st.sampled_from(sorted(confs)), label="preset")
    keys = _key_paths(confs[preset])
    items = []
    for _ in range(data.draw(st.integers(1, 3), label="n")):
        key = data.draw(st.one_of(st.sampled_from(keys), st.text(max_size=8)), label="key")
        value = data.draw(st.one_of(
            st.sampled_from(["1", "1e-4", "-3", "0", "1.5", "abc", "true", "no", ".nan",
                             ".inf", "[1, 2]", "[a]", "{a: 1}", "", "null", "1e400", "'x'",
                             "[1, [2]]", "{", "- 1", "[0.1, 0.2]", "imu", "default"]),
            st.floats(-100, 100).map(repr), st.integers(-5, 500).map(str),
            st.text(max_size=10)), label="value")
        sep = data.draw(st.sampled_from(["=", "=", "=", "=", ":", ""]), label="sep")
        items.append(f"{key}{sep}{value}")
    try:
        conf = resolve_conf(confs, preset, parse_overrides(items))
    except FieldlocError:
        event("refused")
        return
    event("accepted")
    for item in items:  # what was accepted has the preset's type
        key = item.split("=", 1)[0].strip()
        try:
            old, new = _at(confs[preset], key), _at(conf, key)
        except (KeyError, TypeError):
            continue  # overridden again by a later item
        if isinstance(old, bool):
            assert isinstance(new, bool)
        elif isinstance(old, numbers.Real) and old is not None:
            assert isinstance(new, numbers.Real) and not isinstance(new, bool)
            assert math.isfinite(new)
            if isinstance(old, numbers.Integral):
                assert isinstance(new, numbers.Integral)
        elif isinstance(old, str):
            assert isinstance(new, str)
        elif isinstance(old, list):
            assert isinstance(new, list)
