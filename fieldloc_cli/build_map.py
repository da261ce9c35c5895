"""`fieldloc build-map FIELD`: field model and lookup tables into one HDF5 map."""

from __future__ import annotations

from pathlib import Path

import click

from stages import build_map as stage
from stages.common.field import load_field

from .common import FINITE, summary

D = stage.confs["default"]


@click.command("build-map")
@click.argument("field")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path),
              help="Output map file [default: FIELD.map.h5].")
@click.option("--resolution", type=FINITE, default=D["resolution"], show_default=True,
              help="Table cell size (m).")
@click.option("--border", type=FINITE, default=D["border"], show_default=True,
              help="World margin around the field (m).")
@click.option("--max-range", type=FINITE, default=D["max_range"], show_default=True,
              help="Radial scan-line range (m).")
@click.option("--robot-radius", type=FINITE, default=D["robot_radius"], show_default=True,
              help="Scan lines start outside this radius (m).")
@click.option("--spiral-end-radius", type=FINITE, default=D["spiral_end_radius"],
              show_default=True, help="Spiral radius after one turn (m).")
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
@click.pass_context
def build_map(ctx, field, output, resolution, border, max_range, robot_radius, spiral_end_radius,
              overwrite):
    """Build the map of FIELD: a preset (msl-2015, msl, spl, kidsize, adultsize) or a YAML."""
    fm = load_field(field)
    output = output or Path(f"{fm.name}.map.h5")
    conf = dict(resolution=resolution, border=border, max_range=max_range,
                robot_radius=robot_radius, spiral_end_radius=spiral_end_radius)
    path = stage.main(conf, field, output, overwrite=overwrite)  # the name: main checks it
    s = fm.summary()
    c = s["crossings"]
    summary(ctx, f"{path}: field {fm.name} {fm.length:g} x {fm.width:g} m, "
            f"{s['segments']} segments, {s['arcs']} arcs, "
            f"crossings L {c['L']} T {c['T']} X {c['X']}")
