"""`fieldloc show error-surface TEMPLATES QUERIES -o FILE.png`: the SURF template paper's comparison
of the white-point table and the template method (figures 3-5), drawn and counted."""

from __future__ import annotations

from pathlib import Path

import click

from .common import FINITE, FilePath, WholeNumber, summary
from .lazy_group import outputs_complete
from .stage_defaults import SHOW_ERROR_SURFACE as D


@click.command("error-surface")
@click.argument("templates", type=FilePath(dir_okay=False, path_type=Path))
@click.argument("queries", type=FilePath(path_type=Path))
@click.option("--template", type=WholeNumber(min=0), default=None,
              help="Template index [default: the one nearest the queries' centre].")
@click.option("--half-size", type=FINITE, default=None,
              help="Surfaces (a), (b): +- this many metres of (dx, dy)"
              f" [default: {D['half_size']}].")
@click.option("--step", type=FINITE, default=None,
              help=f"Surfaces (a), (b): sampling (m) [default: {D['step']}].")
@click.option("--dtheta-deg", type=FINITE, default=None,
              help="Surfaces (a), (b): +- this many degrees of dtheta"
              f" [default: {D['dtheta_deg']}].")
@click.option("--e-none", type=FINITE, default=None,
              help="Eq. 1's penalty (m) of a white point with no table point at its angle"
              f" [default: {D['e_none']}].")
@click.option("-o", "--output", type=FilePath(dir_okay=False, path_type=Path), required=True,
              help="PNG file to write.")
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
@click.pass_context
def show_error_surface(ctx, templates, queries, template, half_size, step, dtheta_deg, e_none,
                       output, overwrite):
    """Draw the SURF template paper's error surfaces of one template of TEMPLATES against QUERIES
    (omni frames with truth.csv near it): (a) the white-point table's eq. 1, (b) the template pairs'
    eq. 4, over (dx, dy) and dtheta, and (c) every query's position and heading error against its
    distance from the template; print the local minima of (a) and (b) and (c) per ring."""
    from stages.pipelines import error_surface as stage
    from stages.show.error_surface import summary_lines

    given = {"template": template, "half_size": half_size, "step": step,
             "dtheta_deg": dtheta_deg, "e_none": e_none}
    conf = {k: v for k, v in given.items() if v is not None}  # the rest: the stage's preset
    path, m = stage.write_picture(conf, templates, queries, output, overwrite=overwrite)
    outputs_complete(ctx)
    for line in summary_lines(m):
        click.echo(line)
    summary(ctx, f"wrote {path}")
