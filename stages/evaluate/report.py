"""Evaluation results on disk: report.json (schema ``fieldloc.report``), errors.csv, and the
table across runs.

report.json is strict JSON. Infinite numbers (the errors of failed frames, see metrics.py) are
written as the strings ``"inf"`` / ``"-inf"``; a statistic over no frames (e.g. the localised
frames of a run where every frame failed) is ``null``. ``load_report`` turns them back into
floats (inf and NaN).
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from stages.common.artifacts import atomic_path
from stages.common.errors import FieldlocError, SchemaError

from .metrics import FrameErrors

SCHEMA = "fieldloc.report"
VERSION = 1
REPORT_NAME = "report.json"
ERRORS_NAME = "errors.csv"
PLOTS_DIR = "plots"

ERRORS_COLUMNS = (
    "name", "stamp", "matched", "truth_stamp", "x", "y", "theta", "truth_x", "truth_y",
    "truth_theta", "failed", "position_error_m", "heading_error_deg", "mode", "runtime_ms",
)


# ---------------------------------------------------------------------------- JSON


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
    text = json.dumps(encode_numbers(report), indent=2, allow_nan=False) + "\n"
    with atomic_path(path, suffix=".json") as tmp:
        tmp.write_text(text)
    return path


def report_path(path: str | Path) -> Path:
    """report.json of a report folder, or the given JSON file itself."""
    p = Path(path)
    return p / REPORT_NAME if p.is_dir() else p


def load_report(path: str | Path, *, raw: bool = False) -> dict:
    """Read a report folder or report.json, checking the schema. Numbers decoded (inf, NaN)
    unless ``raw``."""
    p = report_path(path)
    if not p.is_file():
        where = f"no {REPORT_NAME} in folder {path}" if Path(path).is_dir() else f"{p}"
        raise FieldlocError(f"report not found: {where}")
    try:
        data = json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise SchemaError(f"{p}: not valid JSON ({e})") from None
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
    return data if raw else decode_numbers(data)


# ---------------------------------------------------------------------------- errors.csv


def _num(v: float, fmt: str) -> str:
    if math.isnan(v):
        return ""
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return format(v, fmt)


def write_errors_csv(path: str | Path, fe: FrameErrors) -> Path:
    """One row per frame. Unmatched frames have empty truth and error cells; failed frames
    have empty pose cells and errors "inf"."""
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
    if not path.is_file():
        raise FieldlocError(f"file not found: {path}")
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


# ---------------------------------------------------------------------------- table


def _label(item) -> str:
    if isinstance(item, dict):
        return str(item.get("run", "?"))
    p = Path(item)
    return str(p.parent if p.name == REPORT_NAME or p.suffix == ".json" else p)


def _fmt(v, digits: int, scale: float = 1.0) -> str:
    if v is None or (isinstance(v, str) and v not in ("inf", "-inf")):
        return "-"
    v = float(v)
    if math.isnan(v):
        return "-"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return f"{v * scale:.{digits}f}"


def table_rows(items) -> tuple[list[str], list[list[str]]]:
    """Header and rows of the runs table; ``items`` are report folders, report.json paths or
    loaded report dicts."""
    reports = [(_label(it), it if isinstance(it, dict) else load_report(it)) for it in items]
    keys = sorted({k for _, r in reports for k in r.get("within", {})}, key=float)
    header = ["run", "method", "frames", "matched", "failures", "accepted", "median cm",
              "p90 cm", "heading median deg"]
    header += [f"<={float(k) * 100:g}cm %" for k in keys]
    header += ["top <=40cm %", "top-K <=40cm %", "mirror %", "AUROC", "runtime ms"]
    rows = []
    for label, r in reports:
        pos = r.get("position_error_m", {})
        head = r.get("heading_error_deg", {})
        row = [
            label,
            str(r.get("method") or "-"),
            str(r.get("frames", "-")),
            str(r.get("matched", "-")),
            str(r.get("failures", "-")),
            str(r.get("accepted", "-")),
            _fmt(pos.get("median"), 1, 100.0),
            _fmt(pos.get("p90"), 1, 100.0),
            _fmt(head.get("median"), 2),
        ]
        row += [_fmt(r.get("within", {}).get(k), 1, 100.0) for k in keys]
        hyp = r.get("hypotheses", {})
        row += [_fmt(hyp.get("top_within", {}).get("0.4"), 1, 100.0),
                _fmt(hyp.get("best_within", {}).get("0.4"), 1, 100.0),
                _fmt(hyp.get("top_mirrored"), 1, 100.0),
                _fmt(r.get("calibration", {}).get("auroc"), 3),
                _fmt(r.get("runtime_ms", {}).get("median"), 3)]
        rows.append(row)
    return header, rows


def reliability_table(report: dict) -> str:
    """The reliability table of a report as text: per confidence bin the frames, their mean
    confidence and the observed share whose top hypothesis is within the calibration
    threshold, with its standard error; then the AUROC."""
    cal = report.get("calibration") or {}
    rows = cal.get("reliability") or []
    if not rows:
        return f"{report.get('run', '?')}: no frame with a hypothesis"
    lines = [f"{report.get('run', '?')}: reliability of the confidence (top hypothesis within"
             f" {_fmt(cal.get('threshold_m'), 0, 100.0)} cm), {cal.get('frames')} frames"]
    lines.append("  confidence   frames  mean conf  observed  +-")
    for b in rows:
        lo, hi = b["bin"]
        lines.append(f"  {lo:.1f}-{hi:.1f}    {b['frames']:7d}  {_fmt(b['confidence'], 3):>9}"
                     f"  {_fmt(b['observed'], 3):>8}  {_fmt(b['stderr'], 3)}")
    lines.append(f"  AUROC {_fmt(cal.get('auroc'), 3)}, largest gap {_fmt(cal.get('max_gap'), 3)},"
                 f" Brier {_fmt(cal.get('brier'), 3)}")
    return "\n".join(lines)


def tabulate(items, fmt: str = "text") -> str:
    """One row per run: run, method, frames, matched, failures, accepted, median and p90
    position error (cm, frames without an accepted pose count as failures), median heading
    error (deg), share within each threshold (%), share of frames whose top hypothesis (or best
    of the top K) is within 40 cm, share whose truth is the top's mirror image, AUROC of the
    confidence, median runtime per frame (ms). ``fmt``: "text" (aligned columns), "markdown"
    or "csv". inf prints as "inf"; a value a report does not have as "-"."""
    if fmt not in ("text", "markdown", "csv"):
        raise FieldlocError(f"unknown table format '{fmt}' (text, markdown, csv)")
    header, rows = table_rows(items)
    if fmt == "csv":
        import io

        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(header)
        w.writerows(rows)
        return buf.getvalue().rstrip("\n")
    left = {0, 1}  # text columns
    widths = [max(len(c) for c in col) for col in zip(header, *rows)]

    def line(cells):
        out = [c.ljust(w) if j in left else c.rjust(w) for j, (c, w) in
               enumerate(zip(cells, widths))]
        return ("| " + " | ".join(out) + " |") if fmt == "markdown" else "  ".join(out).rstrip()

    if fmt == "markdown":
        rule = "|" + "|".join(
            ("-" * (w + 2)) if j in left else ("-" * (w + 1) + ":") for j, w in enumerate(widths)
        ) + "|"
        return "\n".join([line(header), rule] + [line(r) for r in rows])
    return "\n".join([line(header)] + [line(r) for r in rows])
