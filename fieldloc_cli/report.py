"""`fieldloc report RESULTS_OR_REPORT_DIR -o report.html`: one self-contained HTML page."""

from __future__ import annotations

import click

from .common import FilePath, WholeNumber, conf_option, overrides_dict, summary
from .lazy_group import outputs_complete


@click.command()
@click.argument("source", type=FilePath(exists=False))
@click.option("-o", "--output", required=True, type=FilePath(dir_okay=False),
              help="HTML file to write.")
@click.option("--worst", type=WholeNumber(min=0), default=None,
              help="How many of the worst frames to show with overlays [default: 4].")
@click.option("--overwrite", is_flag=True, help="Replace OUTPUT if it exists.")
@conf_option
@click.pass_context
def report(ctx, source, output, worst, overwrite, overrides):
    """One HTML page of the evaluation report(s) in SOURCE (a report folder, or a folder of
    runs with reports below it): table, plots, reliability, worst frames with overlays. Every
    picture is embedded: the page can be sent on its own.

    \b
    Example:
      fieldloc report build/demo-omni/runs -o demo.html
    """
    from stages.common.conf import resolve_conf
    from stages.show.html_report import confs, main

    conf = resolve_conf(confs, "default", overrides_dict(overrides))
    if worst is not None:
        conf["worst"] = worst
    out = main(conf, source, output, overwrite=overwrite)
    outputs_complete(ctx)
    summary(ctx, f"wrote {out}")
