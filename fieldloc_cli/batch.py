"""`fieldloc batch SPEC.yaml -o RESULTS/ [--workers N | --scheduler ADDRESS | --serial]
[--overwrite]`: every method of the SPEC on every dataset, on Dask, and one comparison."""

from __future__ import annotations

from pathlib import Path

import click

from .common import FilePath, WholeNumber, progress_enabled, summary
from .lazy_group import outputs_complete


@click.command()
@click.argument("spec", type=FilePath(dir_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=FilePath(file_okay=False, path_type=Path),
              help="Results folder: runs, comparison.csv/.md, plots/ (a rerun resumes it).")
@click.option("--workers", type=WholeNumber(min=1), default=None,
              help="Worker processes of the local Dask cluster [default: one per core].")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Run on an existing Dask cluster (tcp://host:8786; `dask scheduler`,"
              " `dask worker`), whose workers see the same paths.")
@click.option("--serial", is_flag=True,
              help="No Dask: the runs one after the other in this process.")
@click.option("--overwrite", is_flag=True, help="Run every run again, finished or not.")
@click.pass_context
def batch(ctx, spec, output, workers, scheduler, serial, overwrite):
    """Run the datasets x methods of SPEC (YAML; see docs/manual.md "Batch runs") into RESULTS:
    extract, localize and evaluate per run, finished runs kept, and the comparison of the
    methods on every dataset (`fieldloc evaluate --table RESULTS` prints it again)."""
    from stages.common.errors import FieldlocError
    from stages.pipelines import batch as stage

    if sum(bool(v) for v in (workers, scheduler, serial)) > 1:
        raise FieldlocError("give one of --workers, --scheduler and --serial")
    conf = {"serial": bool(serial), "scheduler": scheduler or "", "workers": workers or 0}
    results = stage.main(conf, spec, output, overwrite=overwrite,
                         progress=progress_enabled(ctx), report=lambda s: summary(ctx, s))
    outputs_complete(ctx)
    from stages.evaluate.report import comparison_table

    click.echo(comparison_table(results))
    summary(ctx, f"wrote {results}/comparison.csv, comparison.md and plots/")
