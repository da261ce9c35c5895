"""`fieldloc show belief DIR --frame N --map MAP [--features F] [--resolution M]
[--heading-step-deg D] [-c key=value] [--overwrite] -o FILE.png`: the particle filter's
belief from one frame's observations on a grid of poses, in four panels (lines only, crossings
only, goal posts only, all), like fig. 3 of Schulz et al. (2011)."""

from __future__ import annotations

import math
from pathlib import Path

import click

from .common import FINITE, FilePath, conf_option, overrides_dict, summary
from .lazy_group import outputs_complete
from .stage_defaults import SHOW_BELIEF as D


@click.command("belief")
@click.argument("dataset", type=FilePath(path_type=Path))
@click.option("--frame", required=True, help="Frame index (0-based) or name (image stem).")
@click.option("--map", "map_path", required=True,
              type=FilePath(dir_okay=False, path_type=Path),
              help="Map file from `fieldloc build-map` (field and crossing tables).")
@click.option("--features", type=FilePath(dir_okay=False, path_type=Path), default=None,
              help="Features file to read the frame from [default: DATASET/features.h5 if"
              " present, else extract the frame now].")
@click.option("--resolution", type=FINITE, default=None,
              help=f"Grid spacing of positions (m) [default: {D['resolution']}].")
@click.option("--heading-step-deg", type=FINITE, default=None,
              help=f"Grid spacing of headings (degrees) [default: {D['heading_step_deg']}].")
@conf_option
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
@click.option("-o", "--output", type=FilePath(dir_okay=False, path_type=Path), required=True,
              help="PNG file to write.")
@click.pass_context
def show_belief(ctx, dataset, frame, map_path, features, resolution, heading_step_deg, overrides,
                overwrite, output):
    """Draw the belief of one frame of DATASET on the field of MAP: the likelihood of its
    observations at every position (best heading per position), per kind of observation."""
    from stages.pipelines import frame_belief as stage

    conf = overrides_dict(overrides)  # options left out: the stage's preset
    if resolution is not None:
        conf["resolution"] = resolution
    if heading_step_deg is not None:
        conf["heading_step"] = math.radians(heading_step_deg)
    path, name = stage.write_picture(conf, dataset, map_path, output, frame=frame,
                                     features=features, overwrite=overwrite)
    outputs_complete(ctx)
    summary(ctx, f"{path}: belief of frame {name}")
