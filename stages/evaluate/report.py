"""The table across evaluated runs (``fieldloc evaluate`` and ``evaluate --table``), the
reliability table of one report, and the comparison of a batch's runs (``fieldloc batch``,
``evaluate --table RESULTS``: methods x datasets), all from report.json files
(stages.common.report_file; a batch's runs listed by its batch.json, stages.common.batch_file)."""

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
    or "csv". inf prints as "inf"; a value a report does not have as "-".

    Items that are batch results folders (written by ``fieldloc batch``) give their comparison
    instead (``comparison_table``), one after the other; they are not mixed with reports."""
    if fmt not in ("text", "markdown", "csv"):
        raise FieldlocError(f"unknown table format '{fmt}' (text, markdown, csv)")
    from stages.common.batch_file import is_batch_folder

    batches = [it for it in items if not isinstance(it, dict) and is_batch_folder(it)]
    if batches:
        if len(batches) != len(items):
            raise FieldlocError("give either report folders or batch results folders, not"
                                " both")
        return "\n\n".join(comparison_table(b, fmt) for b in batches)
    header, rows = table_rows(items)
    if fmt == "csv":
        import io

        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(header)
        w.writerows(rows)
        return buf.getvalue().rstrip("\n")
    return _aligned(header, rows, fmt, left={0, 1})


# ---------------------------------------------------------------------------- batch comparison

COMPARISON_HEADER = ["dataset", "method", "frames", "median cm", "p90 cm", "<=40cm %",
                     "failed %", "AUROC", "ms/frame"]
COMPARISON_THRESHOLD = "0.4"  # the within share of the comparison: 40 cm, failures counted


def comparison_rows(results_dir) -> list[dict]:
    """One row per run of a batch results folder (stages.common.batch_file), in the SPEC's
    order: dataset, method, run key, status, error, and the figures of its report.json read
    as the runs table reads them (frames; median and p90 position error, frames without an
    accepted pose as failures; share within 40 cm of the matched frames, failures never within;
    the share of failed frames; AUROC of the confidence; median runtime per frame). A run
    without truth has frames, failed share and runtime only (from its poses); a failed run
    none."""
    from stages.common.batch_file import load_batch

    results_dir = Path(results_dir)
    index = load_batch(results_dir)
    out = []
    for run in index.get("runs", []):
        row = {"dataset": run["dataset"], "method": run["method"], "run": run["key"],
               "status": run["status"], "error": run.get("error") or "", "report": None}
        if run["status"] == "ok" and run.get("report"):
            rep = load_report(results_dir / run["report"])
            row["report"] = rep
        elif run["status"] == "ok":
            row["report"] = run.get("summary") or {}
        out.append(row)
    return out


def _comparison_cells(rep: dict | None) -> list[str]:
    if rep is None:
        return ["-"] * (len(COMPARISON_HEADER) - 2)
    pos = rep.get("position_error_m", {})
    return [str(rep.get("frames", "-")), _fmt(pos.get("median"), 1, 100.0),
            _fmt(pos.get("p90"), 1, 100.0),
            _fmt(rep.get("within", {}).get(COMPARISON_THRESHOLD), 1, 100.0),
            _fmt(rep.get("failure_rate"), 1, 100.0),
            _fmt(rep.get("calibration", {}).get("auroc"), 3),
            _fmt(rep.get("runtime_ms", {}).get("median"), 3)]


def comparison_table(results_dir, fmt: str = "text") -> str:
    """The comparison of a batch (``fieldloc batch``; ``evaluate --table RESULTS/``): one row
    per run, methods x datasets, with ``comparison_rows``' figures; failed runs are rows
    without figures, and their errors follow the table (csv: columns run, status, error)."""
    if fmt not in ("text", "markdown", "csv"):
        raise FieldlocError(f"unknown table format '{fmt}' (text, markdown, csv)")
    rows = comparison_rows(results_dir)
    if fmt == "csv":
        import io

        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(COMPARISON_HEADER + ["run", "status", "error"])
        for r in rows:
            w.writerow([r["dataset"], r["method"], *_comparison_cells(r["report"]), r["run"],
                        r["status"], r["error"]])
        return buf.getvalue().rstrip("\n")
    body = [[r["dataset"], r["method"], *_comparison_cells(r["report"])] for r in rows]
    text = _aligned(COMPARISON_HEADER, body, fmt, left={0, 1})
    failed = [r for r in rows if r["status"] != "ok"]
    if failed:
        text += "\n\n" + "\n".join(
            [f"failed runs ({len(failed)}):"] + [f"- {r['run']}: {r['error']}" for r in failed])
    return text


def _aligned(header, rows, fmt: str, left) -> str:
    """Text (aligned columns) or markdown lines of a table; ``left``: text columns."""
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
