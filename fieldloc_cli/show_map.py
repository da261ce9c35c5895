"""`fieldloc show map MAP`: the field with a table as heat map, or scan lines from one cell."""

from __future__ import annotations

import math
from pathlib import Path

import click

from .common import FINITE, FilePath, WholeNumber, summary
from .lazy_group import outputs_complete
from .stage_defaults import SHOW_MAP as D
from .stage_defaults import SHOW_MAP_FAMILIES, SHOW_MAP_TABLES


@click.command("map")
@click.argument("map_file", type=FilePath(dir_okay=False))
@click.option("--table", type=click.Choice(SHOW_MAP_TABLES), default=None,
              help=f"What to draw [default: {D['table']}].")
@click.option("--cell", nargs=2, type=FINITE, metavar="X Y",
              help="Field position (m) of the robot for radial/spiral.")
@click.option("--heading-deg", type=FINITE, default=None,
              help="Robot heading for radial/spiral (rounded to 5 deg)"
              f" [default: {D['heading_deg']}].")
@click.option("--family", type=click.Choice(SHOW_MAP_FAMILIES), default=None,
              help=f"Spirals: the counter-clockwise or clockwise family [default: {D['family']}].")
@click.option("--spirals", type=WholeNumber(min=1), default=None,
              help="Spirals: how many of the family's 36 to draw (evenly spaced)"
              f" [default: {D['spirals']}].")
@click.option("-o", "--output", type=FilePath(dir_okay=False, path_type=Path), required=True,
              help="PNG file to write.")
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
@click.pass_context
def show_map(ctx, map_file, table, cell, heading_deg, family, spirals, output, overwrite):
    """Draw MAP's field with a table, so a person can check it by eye."""
    from stages.show import map as stage

    given = {"table": table, "cell": cell, "family": family, "spirals": spirals,
             "heading": None if heading_deg is None else math.radians(heading_deg)}
    conf = {k: v for k, v in given.items() if v is not None}  # the rest: the stage's preset
    path = stage.main(conf, map_file, output, overwrite=overwrite)
    outputs_complete(ctx)
    summary(ctx, str(path))
