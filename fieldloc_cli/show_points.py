"""`fieldloc show points DIR --frame N [--features F] [--map MAP] [--pose X Y THETA_DEG]
-o FILE.png`: extracted line points over the image, and over the field at a pose."""

from __future__ import annotations

import math
from pathlib import Path

import click

from .common import FINITE, FilePath, conf_option, count, overrides_dict, summary
from .lazy_group import outputs_complete
from .stage_defaults import EXTRACT_DEFAULT_PRESET


def _field(map_or_field: str):
    """A field model from a map file (fieldloc.map) or a field preset name / YAML."""
    p = Path(map_or_field)
    if p.suffix.lower() in (".h5", ".hdf5"):
        from stages.common.map_file import MapFile

        with MapFile(p) as m:
            return m.field
    from stages.common.field import load_field

    return load_field(map_or_field)


@click.command("points")
@click.argument("dataset", type=FilePath(path_type=Path))
@click.option("--frame", required=True, help="Frame index (0-based) or name (image stem).")
@click.option("--features", type=FilePath(dir_okay=False, path_type=Path), default=None,
              help="Features file to read the frame from [default: extract it now].")
@click.option("--map", "map_or_field", default=None,
              help="Map file or field (preset name or YAML) to draw the points on.")
@click.option("--pose", nargs=3, type=FINITE, default=None, metavar="X Y THETA_DEG",
              help="Robot pose for the field drawing: metres, metres, degrees"
              " [default: truth.csv at the frame].")
@click.option("--preset", default=EXTRACT_DEFAULT_PRESET, show_default=True,
              help="Extraction preset when extracting now.")
@conf_option
@click.option("-o", "--output", type=FilePath(dir_okay=False, path_type=Path), required=True,
              help="PNG file to write.")
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
@click.pass_context
def show_points(ctx, dataset, frame, features, map_or_field, pose, preset, overrides, output,
                overwrite):
    """Draw the extracted line points of one frame of DATASET over its image, and over the
    field at a pose (given with --pose, or truth.csv's) when --map is given."""
    from stages.pipelines import frame_points as stage

    field = _field(map_or_field) if map_or_field else None
    pose_rad = None if not pose else (pose[0], pose[1], math.radians(pose[2]))
    field_file = Path(map_or_field) if map_or_field and Path(map_or_field).exists() else None
    conf = preset
    if overrides:  # the preset of the dataset's camera kind with the -c values
        from stages import extract

        conf = extract.resolve_extract_conf(extract.camera_kind(dataset), preset,
                                            overrides_dict(overrides))
    path, s = stage.write_picture(conf, dataset, output, frame=frame, features=features,
                                  field=field, pose=pose_rad, overwrite=overwrite,
                                  field_file=field_file)
    outputs_complete(ctx)
    msg = (f"{path}: frame {s['frame']}, " + (count(s["points"], "line point") if "points" in s
                                              else count(s["lines"], "line")))
    if "share_near_lines" in s:
        x, y, th = s["pose"]
        msg += (f"; at pose ({x:.2f}, {y:.2f}, {math.degrees(th):.1f} deg)"
                f" {s['share_near_lines']:.0%} within 15 cm of a line")
    summary(ctx, msg)
