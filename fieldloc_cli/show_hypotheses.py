"""`fieldloc show hypotheses POSES --frame N [--features F] [--field F] [--overwrite] -o F.png`:
a frame's hypotheses drawn on the field with their probabilities and the frame's points."""

from __future__ import annotations

from pathlib import Path

import click

from .common import FilePath, conf_option, overrides_dict, summary
from .lazy_group import outputs_complete


@click.command("hypotheses")
@click.argument("poses", type=FilePath(dir_okay=False, path_type=Path))
@click.option("--frame", default="0", show_default=True,
              help="Frame index (0-based) or name.")
@click.option("--features", type=FilePath(dir_okay=False, path_type=Path), default=None,
              help="Features file with the frame's points [default: the one the poses were"
              " made from].")
@click.option("--field", default=None,
              help="Field (preset or YAML) [default: the poses file's].")
@conf_option
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
@click.option("-o", "--output", type=FilePath(dir_okay=False, path_type=Path), required=True,
              help="PNG file to write.")
@click.pass_context
def show_hypotheses(ctx, poses, frame, features, field, overrides, overwrite, output):
    """Draw the hypotheses of one frame of POSES (poses.h5) on the field: each as a robot with
    its probability, with the frame's line points placed at each."""
    from stages.show import hypotheses as stage

    path = stage.main(overrides_dict(overrides), poses, output, frame=frame, features=features,
                      field=field, overwrite=overwrite)
    outputs_complete(ctx)
    summary(ctx, f"{path}: hypotheses of frame {frame}")
