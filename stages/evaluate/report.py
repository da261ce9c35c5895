"""The table across evaluated runs (``fieldloc evaluate`` and ``evaluate --table``) and the
reliability table of one report, from report.json files (stages.common.report_file)."""

from __future__ import annotations

import csv
import math
from pathlib import Path

from stages.common.errors import FieldlocError
from stages.common.report_file import REPORT_NAME, load_report


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
