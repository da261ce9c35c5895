"""`fieldloc build-map FIELD`: field model and lookup tables into one HDF5 map."""

from __future__ import annotations

from pathlib import Path

import click

from .common import FINITE, FilePath, summary
from .lazy_group import outputs_complete
from .stage_defaults import BUILD_MAP as D


@click.command("build-map")
@click.argument("field")
@click.option("-o", "--output", type=FilePath(dir_okay=False, path_type=Path),
              help="Output map file [default: FIELD.map.h5].")
@click.option("--resolution", type=FINITE, default=None,
              help=f"Table cell size (m), at most 1 [default: {D['resolution']}].")
@click.option("--border", type=FINITE, default=None,
              help=f"World margin around the field (m) [default: {D['border']}].")
@click.option("--max-range", type=FINITE, default=None,
              help=f"Radial scan-line range (m) [default: {D['max_range']}].")
@click.option("--robot-radius", type=FINITE, default=None,
              help=f"Scan lines start outside this radius (m) [default: {D['robot_radius']}].")
@click.option("--spiral-end-radius", type=FINITE, default=None,
              help=f"Spiral radius after one turn (m) [default: {D['spiral_end_radius']}].")
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
@click.pass_context
def build_map(ctx, field, output, resolution, border, max_range, robot_radius, spiral_end_radius,
              overwrite):
    """Build the map of FIELD: a preset (msl-2015, msl, spl, kidsize, adultsize) or a YAML."""
    from stages import build_map as stage
    from stages.common.field import load_field

    fm = load_field(field)
    output = output or Path(f"{fm.name}.map.h5")
    given = dict(resolution=resolution, border=border, max_range=max_range,
                 robot_radius=robot_radius, spiral_end_radius=spiral_end_radius)
    conf = {k: v for k, v in given.items() if v is not None}  # the rest: the stage's preset
    path = stage.main(conf, field, output, overwrite=overwrite)  # the name: main checks it
    outputs_complete(ctx)
    s = fm.summary()
    c = s["crossings"]
    summary(ctx, f"{path}: field {fm.name} {fm.length:g} x {fm.width:g} m, "
            f"{s['segments']} segments, {s['arcs']} arcs, "
            f"crossings L {c['L']} T {c['T']} X {c['X']}")
