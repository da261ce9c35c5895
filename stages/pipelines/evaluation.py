"""An evaluated run as ``fieldloc evaluate`` writes it: the report of stages.evaluate (numbers:
report.json, errors.csv, truth.tum), then its plots by stages.show.report_plots when the conf
asks for them.

    main(conf, poses, truth, output_dir, *, overwrite=False, field=None, progress=False) -> Path

A report written anew has its plots drawn before its report.json (stages.evaluate.main's
``draw``), so a run stopped at any moment leaves no report.json without its plots, and the
next run writes the report again. The plots of an up-to-date report are drawn again only
where one is missing (a user removed it); an up-to-date report with its plots is left as it
is.
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
    out = evaluate.main(conf, poses, truth, output_dir, overwrite=overwrite, field=field,
                        draw=lambda report, folder: report_plots.draw(report, folder,
                                                                      overwrite=True))
    # an up-to-date report kept as it was: its plots, if one is missing, drawn again
    listed = load_report(out, raw=True)["files"]["plots"]
    if any(not (out / p).is_file() for p in listed):
        report_plots.main(None, out, overwrite=True)
    return out
