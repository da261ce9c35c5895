"""An evaluated run as ``fieldloc evaluate`` writes it: the report of stages.evaluate (numbers:
report.json, errors.csv, truth.tum), then its plots by stages.show.report_plots when the conf
asks for them.

    main(conf, poses, truth, output_dir, *, overwrite=False, field=None, progress=False) -> Path

The plots are drawn when the report lists a plot that is missing: after a report written anew
(evaluate removes the plots of the one it replaces), or after a run stopped while drawing; an
up-to-date report with its plots is left as it is.
"""

from __future__ import annotations

from pathlib import Path

from .. import evaluate
from ..common.report_file import load_report
from ..show import report_plots


def main(conf, poses, truth, output_dir, *, overwrite: bool = False, field=None,
         progress: bool = False) -> Path:
    """Evaluate ``poses`` against ``truth`` into the report folder ``output_dir`` (see
    stages.evaluate.main) and draw the report's plots; returns the report folder."""
    out = evaluate.main(conf, poses, truth, output_dir, overwrite=overwrite, field=field)
    listed = load_report(out, raw=True)["files"]["plots"]
    if any(not (out / p).is_file() for p in listed):
        report_plots.main(None, out, overwrite=True)
    return out
