"""`fieldloc calibrate omni POINTS.csv -o calib.yaml ...`: fit the mirror's radial mapping."""

from __future__ import annotations

import math
from pathlib import Path

import click

from stages.calibrate import confs
from stages.common.conf import resolve_conf

from .common import conf_option, overrides_dict


@click.group()
def calibrate():
    """Write a camera calibration (calib.yaml) from measurements."""


@calibrate.command("omni")
@click.argument("points", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="calib.yaml to write.")
@click.option("--centre", nargs=2, type=float, required=True, metavar="U V",
              help="Image centre of the mirror (px).")
@click.option("--image-size", nargs=2, type=int, required=True, metavar="W H",
              help="Image width and height (px).")
@click.option("--valid-radius", nargs=2, type=float, required=True, metavar="RMIN RMAX",
              help="Radii (px) of the robot-body mask and of the outer limit of the floor.")
@click.option("--forward-angle-deg", type=float, default=90.0, show_default=True,
              help="Image angle of the robot's forward direction, counter-clockwise from +u"
                   " with v up.")
@click.option("--mirrored", is_flag=True, help="The image shows the floor mirrored.")
@click.option("--preset", default="default", show_default=True, type=click.Choice(sorted(confs)),
              help="Named conf preset of the stage.")
@click.option("--overwrite", is_flag=True, help="Replace OUTPUT if it exists.")
@conf_option
@click.pass_context
def calibrate_omni(ctx, points, output, centre, image_size, valid_radius, forward_angle_deg,
                   mirrored, preset, overwrite, overrides):
    """Least-squares fit of the fifth-order f(r) (pixel radius -> floor distance in metres,
    seed 004 eq. 2) to measured pairs in POINTS (CSV header: radius_px,distance_m).

    \b
    Example:
      fieldloc calibrate omni marks.csv -o calib.yaml --centre 241 233 \\
          --image-size 480 480 --valid-radius 40 230
    """
    from stages.calibrate import main, residual_report
    from stages.common.camera import load_calib

    conf = resolve_conf(confs, preset, overrides_dict(overrides))
    out = main(conf, points, output, centre=centre, image_size=image_size,
               valid_radius=valid_radius, forward_angle=math.radians(forward_angle_deg),
               mirrored=mirrored, overwrite=overwrite)
    report = residual_report(load_calib(out), points)
    obj = ctx.find_root().obj or {}
    if obj.get("verbose", 0) >= 1:
        click.echo("radius_px,distance_m,fitted_m,residual_m")
        fitted = report.distance_m + report.residuals_m
        for r, d, fd, e in zip(report.radius_px, report.distance_m, fitted,
                               report.residuals_m):
            click.echo(f"{r:g},{d:g},{fd:.4f},{e:+.4f}")
    click.echo(
        f"wrote {out}: {len(report.radius_px)} pairs, residual RMS {report.rms * 100:.2f} cm,"
        f" max {report.max_abs * 100:.2f} cm; floor visible to"
        f" {report.camera.max_distance:.2f} m at {report.camera.valid_radius[1]:g} px"
    )


@calibrate.command("perspective")
@click.option("--from-hulks", "hulks_source", required=True,
              type=click.Path(exists=True, path_type=Path), metavar="FILE.json|FOLDER",
              help="A HULKs capture JSON (camera matrix of one NAO frame), or a folder of them "
                   "beside their images.")
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path),
              help="calib.yaml to write (from a file) or the dataset folder (from a folder).")
@click.option("--overwrite", is_flag=True, help="Replace OUTPUT if it exists.")
@conf_option
def calibrate_perspective(hulks_source, output, overwrite, overrides):
    """A perspective calib.yaml from a team's camera file: intrinsics, height, pitch, roll
    (and yaw, position) of HULKs' camera_to_ground. From a folder of captures
    (<stamp>.json + <stamp>.jpg) it writes a dataset: images/, calib.yaml and head.csv with
    each frame's own camera pose, ready for `fieldloc extract`.

    \b
    Example:
      fieldloc calibrate perspective --from-hulks 1687078170.json -o calib.yaml
      fieldloc calibrate perspective --from-hulks measurements/ -o data/hulks
    """
    from stages.calibrate import hulks

    conf = resolve_conf(hulks.confs, "default", overrides_dict(overrides))
    out = hulks.main(conf, hulks_source, output, overwrite=overwrite)
    click.echo(f"wrote {out}")
