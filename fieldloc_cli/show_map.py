"""`fieldloc show map MAP`: the field with a table as heat map, or scan lines from one cell."""

from __future__ import annotations

import math
from pathlib import Path

import click

from stages.show import map as stage

from .common import FINITE, summary

D = stage.confs["default"]


@click.command("map")
@click.argument("map_file", type=click.Path(dir_okay=False))
@click.option("--table", type=click.Choice(stage.TABLES), default=D["table"],
              show_default=True, help="What to draw.")
@click.option("--cell", nargs=2, type=FINITE, metavar="X Y",
              help="Field position (m) of the robot for radial/spiral.")
@click.option("--heading-deg", type=FINITE, default=math.degrees(D["heading"]), show_default=True,
              help="Robot heading for radial/spiral (rounded to 5 deg).")
@click.option("--family", type=click.Choice(sorted(stage.FAMILIES)), default=D["family"],
              show_default=True, help="Spirals: the counter-clockwise or clockwise family.")
@click.option("--spirals", type=int, default=D["spirals"], show_default=True,
              help="Spirals: how many of the family's 36 to draw (evenly spaced).")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="PNG file to write.")
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
@click.pass_context
def show_map(ctx, map_file, table, cell, heading_deg, family, spirals, output, overwrite):
    """Draw MAP's field with a table, so a person can check it by eye."""
    conf = {"table": table, "cell": cell, "heading": math.radians(heading_deg),
            "family": family, "spirals": spirals}
    path = stage.main(conf, map_file, output, overwrite=overwrite)
    summary(ctx, str(path))
