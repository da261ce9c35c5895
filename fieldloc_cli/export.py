"""`fieldloc export POSES.h5 --format csv|tum|json [-o FILE]`: poses for a team's own tools."""

from __future__ import annotations

import click

from .common import FilePath, summary
from .lazy_group import outputs_complete
from .stage_defaults import EXPORT_FORMATS


@click.command()
@click.argument("poses", type=FilePath(dir_okay=False))
@click.option("--format", "fmt", required=True, type=click.Choice(EXPORT_FORMATS),
              help="csv: one row per frame; tum: accepted frames for evo; json: frames with"
                   " their ranked hypotheses.")
@click.option("-o", "--output", type=FilePath(dir_okay=False),
              help="File to write, or - for standard output [default: beside POSES with the"
                   " format's suffix].")
@click.option("--overwrite", is_flag=True, help="Replace OUTPUT if it exists.")
@click.pass_context
def export(ctx, poses, fmt, output, overwrite):
    """Write POSES (poses.h5 from `fieldloc localize`) as CSV, TUM or JSON.

    \b
    Examples:
      fieldloc export run/poses.h5 --format csv
      fieldloc export run/poses.h5 --format json -o run/poses-with-hypotheses.json
      fieldloc export run/poses.h5 --format csv -o - | head
    """
    from stages.evaluate.export import STDOUT, main

    out = main(None, poses, output, fmt=fmt, overwrite=overwrite)
    outputs_complete(ctx)
    if str(out) != STDOUT:
        summary(ctx, f"wrote {out}")
