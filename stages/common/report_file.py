"""The evaluation report on disk (written by evaluate, read by the report pictures, the HTML
page and the table across runs): report.json (schema ``fieldloc.report``, version 1) and
errors.csv in a report folder, with its plots in plots/.

report.json starts with the keys every artifact starts with (``report_head``: schema,
schema_version, fieldloc_version, created; stages.common.artifacts.provenance). It is strict
JSON. Infinite numbers (the errors of failed frames, see metrics.py) are
written as the strings ``"inf"`` / ``"-inf"``; a statistic over no frames (e.g. the localised
frames of a run where every frame failed) is ``null``. ``load_report`` turns them back into
floats (inf and NaN).
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from .artifacts import (
    WRITTEN_FILES,
    atomic_path,
    cannot_read,
    commit_dir,
    fieldloc_wrote,
    give_default_mode,
    part_name,
    provenance,
    record_text,
    refuse_edited,
    remove_stale_parts,
    restore_interrupted_replacement,
    starts_with,
    writing,
)
from .conf import read_record
from .errors import DiskFullError, FieldlocError, SchemaError, check_file, file_problem
from .stops import raise_deferred_stop

SCHEMA = "fieldloc.report"
VERSION = 1
REPORT_NAME = "report.json"
ERRORS_NAME = "errors.csv"
TRUTH_TUM = "truth.tum"  # the truth as a TUM trajectory: evo_ape tum truth.tum poses.tum
PLOTS_DIR = "plots"
PLOT_NAMES = ("error_cdf.png", "trajectory.png", "error_over_time.png", "reliability.png")

ERRORS_COLUMNS = (
    "name", "stamp", "matched", "truth_stamp", "x", "y", "theta", "truth_x", "truth_y",
    "truth_theta", "failed", "position_error_m", "heading_error_deg", "mode", "runtime_ms",
)


# ---------------------------------------------------------------------------- JSON


def report_head() -> dict:
    """The first keys of a report.json: schema, schema_version, fieldloc_version, created."""
    return provenance(SCHEMA, VERSION)


def encode_numbers(obj):
    """A copy of ``obj`` that strict JSON accepts: inf -> "inf", -inf -> "-inf", NaN -> None,
    numpy scalars and arrays -> Python numbers and lists."""
    if isinstance(obj, dict):
        return {str(k): encode_numbers(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [encode_numbers(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return encode_numbers(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        if math.isnan(v):
            return None
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return v
    if isinstance(obj, Path):
        return str(obj)
    return obj


def decode_numbers(obj):
    """Inverse of ``encode_numbers`` for report values: "inf" -> inf, None -> NaN."""
    if isinstance(obj, dict):
        return {k: decode_numbers(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [decode_numbers(v) for v in obj]
    if obj == "inf":
        return math.inf
    if obj == "-inf":
        return -math.inf
    if obj is None:
        return math.nan
    return obj


def write_report(path: str | Path, report: dict) -> Path:
    """Write report.json atomically (strict JSON, see module docstring)."""
    path = Path(path)
    text = record_text(encode_numbers(report), REPORT_NAME)  # vouches for itself too
    with atomic_path(path, suffix=".json") as tmp:
        tmp.write_bytes(text.encode())
    return path


def is_fieldloc_report(path: str | Path) -> bool:
    """Whether ``path`` (a report.json) says it is a report fieldloc evaluate wrote: a JSON
    object whose ``schema`` is ``fieldloc.report`` (its figures are not checked here). One
    fieldloc may not read is FieldlocError (``cannot_read``), not another's file."""
    try:
        data = json.loads(read_record(path).decode())
    except PermissionError as e:
        raise cannot_read(path, e) from None
    except (OSError, ValueError, RecursionError):  # ValueError: bad JSON or bad UTF-8
        return False
    return isinstance(data, dict) and data.get("schema") == SCHEMA


def foreign_report_file(folder: str | Path) -> Path | None:
    """The first of the files evaluate writes into a report folder (report.json, errors.csv,
    truth.tum, the plots) that is there and that fieldloc did not write, or None: what
    evaluate may never replace, --overwrite or not. A folder whose report.json is a fieldloc
    report is fieldloc's; without one, an errors.csv, a truth.tum and plots that an
    interrupted evaluate left (report.json is written last) are recognised by their header
    lines and the plots' mark (``fieldloc_wrote``), and anything else of those names is a
    user's file. A plots/ that is not a folder (a user's file of that name) is never
    replaced either: the plots could not be written into it."""
    folder = Path(folder)
    plots = folder / PLOTS_DIR
    if os.path.lexists(plots) and not plots.is_dir():
        return plots
    report = folder / REPORT_NAME
    if report.exists():
        return None if is_fieldloc_report(report) else report
    return next((p for n in report_files() if (p := folder / n).exists()
                 and not (p.is_file() and _report_file_ours(p))), None)


def report_files() -> tuple[str, ...]:
    """The files evaluate writes into a report folder besides report.json (relative names)."""
    return (ERRORS_NAME, TRUTH_TUM, *(f"{PLOTS_DIR}/{n}" for n in PLOT_NAMES))


def _report_file_ours(path: Path) -> bool:
    """A report folder's file judged on its own where no report.json records it (an
    evaluate interrupted before its report.json): errors.csv and truth.tum by their header
    lines, a plot by its mark."""
    from .poses_file import is_fieldloc_tum

    if path.name == ERRORS_NAME:
        return _is_errors_csv(path)
    if path.name == TRUTH_TUM:
        return is_fieldloc_tum(path)
    return fieldloc_wrote(path)


def refuse_edited_report_files(folder: str | Path) -> None:
    """Before evaluate replaces a report: each of its files must be as the report folder's
    report.json lists it (its WRITTEN_FILES; artifacts' ``refuse_edited``: one line naming
    the file, or the folder where report.json has no table). No report.json:
    ``foreign_report_file`` judged each file already."""
    folder = Path(folder)
    try:
        data = json.loads(read_record(folder / REPORT_NAME).decode())
    except (OSError, ValueError, RecursionError):
        return
    recorded = data.get(WRITTEN_FILES) if isinstance(data, dict) else None
    refuse_edited(folder, recorded, report_files(), record=REPORT_NAME)


@contextlib.contextmanager
def building_report(folder: str | Path):
    """Yield a temporary folder beside the report folder ``folder`` to write a whole report
    into (report.json, errors.csv, truth.tum, plots/); on success it takes ``folder``'s place
    in one rename (``commit_dir``) where ``folder`` is new or holds nothing but a report's
    files; where a user keeps other files in it too, the report's files are moved in one by
    one (renames, which need no room), report.json last. On any failure (a full disk) the
    temporary folder is removed and ``folder`` stays exactly as it was: the old report whole,
    never a report.json without its files nor files without their report.json."""
    folder = Path(folder)
    parent = folder.parent if str(folder.parent) else Path(".")
    restore_interrupted_replacement(folder)
    remove_stale_parts(folder)  # those of killed runs (tagged with their pid)
    whole = _only_report_files(folder)
    made = [p for p in (parent, *parent.parents) if not p.exists()]  # removed on failure
    prefix, suffix = part_name(folder, ".part")
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=prefix, suffix=suffix, dir=parent))
    except OSError as e:
        raise FieldlocError(f"cannot write {folder}: {e.strerror or e}") from None
    done = False
    try:
        try:
            with writing(folder):
                yield tmp
        except DiskFullError as e:  # its line is made from its path: that path, renamed
            raise DiskFullError(str(e.path).replace(str(tmp), str(folder))) from None
        except FieldlocError as e:  # name the file where it goes, not the temporary folder
            raise type(e)(str(e).replace(str(tmp), str(folder))) from None
        give_default_mode(tmp)  # mkdtemp makes it 0700
        if whole:
            commit_dir(tmp, folder)
        else:
            _move_report_files(tmp, folder)
        done = True
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
        for p in [] if done else made:  # the folders made for it, innermost first
            with contextlib.suppress(OSError):
                p.rmdir()


def _only_report_files(folder: Path) -> bool:
    """Whether ``folder`` is absent or holds nothing but a report's files (what
    ``building_report`` may replace as a whole)."""
    if not folder.is_dir():
        return True
    names = {REPORT_NAME, ERRORS_NAME, TRUTH_TUM, PLOTS_DIR}
    plots = folder / PLOTS_DIR
    if not all(p.name in names for p in folder.iterdir()):
        return False
    return not plots.exists() or (plots.is_dir() and not plots.is_symlink()
                                  and all(p.name in PLOT_NAMES for p in plots.iterdir()))


def _move_report_files(tmp: Path, folder: Path) -> None:
    """Move the report written in ``tmp`` into ``folder``, which holds a user's files too:
    the old report.json goes first and the new one comes last, so that a report.json is
    there only beside its files; an old plot the new report does not draw goes."""
    raise_deferred_stop()  # a stop a callback dropped: nothing moved after it
    (folder / REPORT_NAME).unlink(missing_ok=True)
    for name in report_files():
        src, dst = tmp / name, folder / name
        if src.is_file():
            dst.parent.mkdir(exist_ok=True)
            os.replace(src, dst)
        elif os.path.lexists(dst):
            dst.unlink()
    os.replace(tmp / REPORT_NAME, folder / REPORT_NAME)


def _is_errors_csv(path: Path) -> bool:
    """Whether ``path`` starts with the header line ``write_errors_csv`` writes."""
    return starts_with(path, (",".join(ERRORS_COLUMNS) + "\n").encode())


# a PNG file's first bytes (stages.common.png holds them too; importing it would load numba
# into every command that reads a report)
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def read_plot(report_dir: str | Path, name: str) -> tuple[bytes | None, str]:
    """(the bytes of the plot ``plots/<name>`` of a report folder, "") or (None, why not):
    only a PNG file (its signature) inside the report folder is given, so that a page made
    of the report never carries another file (a symlink to /etc/passwd, an empty file)."""
    report_dir = Path(report_dir)
    p = report_dir / PLOTS_DIR / name
    if not p.is_file():
        return None, "not a regular file" if p.exists() else "no such file"
    real = Path(os.path.realpath(p))
    if not real.is_relative_to(os.path.realpath(report_dir)):
        return None, "a link to a file outside the report folder"
    try:
        with open(real, "rb") as f:
            if f.read(len(PNG_SIGNATURE)) != PNG_SIGNATURE:
                return None, "not a PNG image"
            return PNG_SIGNATURE + f.read(), ""
    except OSError as e:
        return None, f"unreadable ({e.strerror or e})"


def report_path(path: str | Path) -> Path:
    """report.json of a report folder, or the given JSON file itself."""
    p = Path(path)
    return p / REPORT_NAME if p.is_dir() else p


# the most digits of an integer a report or batch index holds: counts of frames and runs (a
# float's range is 309 digits; more ended the reports' float() in an OverflowError, trial
# Z1-2)
MAX_INT_DIGITS = 20


def bounded_int(text: str) -> int:
    """A JSON integer of at most MAX_INT_DIGITS digits; ValueError (not JSON fieldloc wrote)
    otherwise."""
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        raise ValueError(f"an integer of {len(text.lstrip('-')):,} digits")
    return int(text)


def load_report(path: str | Path, *, raw: bool = False) -> dict:
    """Read a report folder or report.json, checking the schema. Numbers decoded (inf, NaN)
    unless ``raw``."""
    p = report_path(path)
    if Path(path).is_dir() and file_problem(p) == "not found":
        raise FieldlocError(f"report not found: no {REPORT_NAME} in folder {path}")
    check_file(p, "report")
    try:
        data = json.loads(read_record(p).decode(), parse_int=bounded_int)
    except OSError as e:  # more than a report weighs (a few kB)
        raise SchemaError(f"{p}: cannot be read ({e.strerror or e})") from None
    except (ValueError, RecursionError) as e:  # bad JSON or UTF-8, nested deep, an integer
        raise SchemaError(f"{p}: not valid JSON ({str(e)[:120]})") from None  # of 5000 digits
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        got = data.get("schema") if isinstance(data, dict) else None
        raise SchemaError(
            f"{p}: expected a '{SCHEMA}' report (written by fieldloc evaluate), got"
            f" {repr(got) if got else 'no schema'}"
        )
    if not 1 <= int(data.get("schema_version", -1)) <= VERSION:
        raise SchemaError(
            f"{p}: '{SCHEMA}' version {data.get('schema_version')} is not supported (this"
            f" fieldloc reads versions 1..{VERSION})"
        )
    _check_figures(data, p)
    return data if raw else decode_numbers(data)


# the figures of a report whose shape every reader relies on: counts are numbers, these
# sections are tables whose leaves are numbers ("inf", "-inf" and null included)
_COUNTS = ("frames", "matched", "unmatched", "failures", "matched_failures", "failure_rate",
           "mirrored", "accepted", "not_accepted", "confidently_wrong")
_TABLES = ("position_error_m", "heading_error_deg", "within", "runtime_ms",
           "stamp_difference_ms", "modes", "localised/position_error_m",
           "localised/heading_error_deg", "localised/within", "hypotheses/top_within",
           "hypotheses/best_within")


def _is_number(v) -> bool:
    return (v is None or v in ("inf", "-inf")
            or (isinstance(v, (int, float)) and not isinstance(v, bool)))


def _short(v) -> str:
    text = json.dumps(v)
    return text if len(text) <= 40 else text[:37] + "..."


# the other keys evaluate writes, by what each holds where present (null for field_override:
# no --field given); the report page, its plots and the tables read them as such
_TEXT = ("run", "method", "field", "dataset", "poses", "truth")
_MAPPINGS = ("inputs", "conf", "evaluate_conf", "conventions", "files")
_ABSENT = object()


def _at(data: dict, path: str):
    """The value at ``path`` (keys joined by /), or _ABSENT where a key is missing."""
    v = data
    for k in path.split("/"):
        if not isinstance(v, dict) or k not in v:
            return _ABSENT
        v = v[k]
    return v


def _check_figures(data: dict, p: Path) -> None:
    """A report.json edited or damaged by hand is refused in one line, naming the key: each
    key evaluate writes holds what it writes there, or is absent."""
    for key in _COUNTS:
        if key in data and not _is_number(data[key]):
            raise SchemaError(f"{p}: '{key}' must be a number, got {_short(data[key])}")
    for key in _TEXT:
        if key in data and not isinstance(data[key], str):
            raise SchemaError(f"{p}: '{key}' must be text, got {_short(data[key])}")
    if not isinstance(data.get("field_override"), (str, type(None))):
        raise SchemaError(f"{p}: 'field_override' must be text or null, got"
                          f" {_short(data['field_override'])}")
    for path in (*_MAPPINGS, "localised", "hypotheses", "calibration", *_TABLES):
        v = _at(data, path)
        if v is _ABSENT:
            continue
        if not isinstance(v, dict):
            raise SchemaError(f"{p}: '{path}' must be a table (a JSON object), got {_short(v)}")
        if path in _TABLES:
            bad = [k for k, x in v.items() if not _is_number(x)]
            if bad:
                raise SchemaError(f"{p}: '{path}/{bad[0]}' must be a number, got"
                                  f" {_short(v[bad[0]])}")


# ---------------------------------------------------------------------------- errors.csv


def _num(v: float, fmt: str) -> str:
    if math.isnan(v):
        return ""
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return format(v, fmt)


def write_errors_csv(path: str | Path, fe) -> Path:
    """One row per frame of ``fe`` (stages.evaluate.metrics.FrameErrors). Unmatched frames
    have empty truth and error cells; failed frames have empty pose cells and errors "inf"."""
    path = Path(path)
    deg = np.degrees(fe.heading_error)
    with atomic_path(path, suffix=".csv") as tmp:
        with open(tmp, "w", newline="") as f:
            w = csv.writer(f, lineterminator="\n")
            w.writerow(ERRORS_COLUMNS)
            for i in range(len(fe)):
                w.writerow([
                    fe.name[i], _num(fe.stamp[i], ".6f"), int(fe.matched[i]),
                    _num(fe.truth_stamp[i], ".6f"), _num(fe.x[i], ".4f"), _num(fe.y[i], ".4f"),
                    _num(fe.theta[i], ".5f"), _num(fe.truth_x[i], ".4f"),
                    _num(fe.truth_y[i], ".4f"), _num(fe.truth_theta[i], ".5f"),
                    int(fe.failed[i]), _num(fe.position_error[i], ".5f"), _num(deg[i], ".4f"),
                    fe.mode[i], _num(fe.runtime[i] * 1000.0, ".4f"),
                ])
    return path


def read_errors_csv(path: str | Path) -> dict[str, np.ndarray]:
    """errors.csv back as columns (numbers as floats, empty cells NaN)."""
    path = Path(path)
    check_file(path, "file")
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if not rows or tuple(rows[0]) != ERRORS_COLUMNS:
        raise SchemaError(f"{path}: expected columns '{','.join(ERRORS_COLUMNS)}'")
    out = {}
    for j, c in enumerate(ERRORS_COLUMNS):
        cells = [r[j] for r in rows[1:]]
        if c in ("name", "mode"):
            out[c] = np.array(cells, dtype=object)
        else:
            out[c] = np.array([float(v) if v else math.nan for v in cells], dtype=float)
    return out
