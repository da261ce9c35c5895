"""`fieldloc calibrate omni [POINTS.csv | --from-minho DIR | --from-cnc FILE | --from-nubot DIR]
[--line-images DIR] -o calib.yaml`: the mirror's radial mapping from measured pairs, a team's
files or images of a line."""

from __future__ import annotations

import math
from pathlib import Path

import click

from stages.common.errors import FieldlocError

from .common import FINITE, FilePath, WholeNumber, conf_option, overrides_dict, summary
from .lazy_group import outputs_complete
from .stage_defaults import CALIBRATE_MAX_IMAGE_PX, CALIBRATE_PRESETS

DEFAULT_PRESET = {"points": "default", "minho": "minho", "cnc": "cnc", "nubot": "nubot"}


@click.group()
def calibrate():
    """Write a camera calibration (calib.yaml) from measurements."""


@calibrate.command("omni")
@click.argument("points", required=False, type=FilePath(dir_okay=False))
@click.option("-o", "--output", required=True, type=FilePath(dir_okay=False),
              help="calib.yaml to write.")
@click.option("--from-minho", "minho_dir", type=FilePath(file_okay=False), metavar="DIR",
              help="Convert the MINHO team's DIR/mirror.cfg and DIR/image.cfg (centre, TILT)"
                   " instead of POINTS; image size from the first image in DIR/images.")
@click.option("--from-cnc", "cnc_conf", type=FilePath(dir_okay=False), metavar="FILE",
              help="The Carpe Noctem team's CarpetCalibrator.conf (ring distances) instead of"
                   " POINTS; ring radii by --rings.")
@click.option("--from-nubot", "nubot_dir", type=FilePath(file_okay=False), metavar="DIR",
              help="The NuBot team's DIR/mirror_calib.xml (range = 100 a tan(b rho) cm, the"
                   " image centre) and DIR/ROI.xml (the usable ring) instead of POINTS; image"
                   " size from the first image in DIR.")
@click.option("--rings", metavar="SPEC",
              help="With --from-cnc: 'detected' (the rings of the calibration picture, in"
                   " order) or one radius in px per conf distance, '-' for a ring not seen.")
@click.option("--calib-image", type=FilePath(dir_okay=False), metavar="FILE",
              help="With --from-cnc: the rings' picture [default: CarpetCalibImage.png beside"
                   " FILE]; gives the centre and image size unless given.")
@click.option("--line-images", type=FilePath(file_okay=False), metavar="DIR",
              help="Images of a straight line ahead at known distances, each named by the"
                   " distance in metres (1.25.png): their measured pairs replace the other"
                   " source's pairs over the distances they cover.")
@click.option("--mask", type=FilePath(dir_okay=False),
              help="Mask image for the line images (default with --from-minho: DIR/mask.png).")
@click.option("--centre", nargs=2, type=FINITE, metavar="U V",
              help="Image centre of the mirror (px); with POINTS.")
@click.option("--image-size", nargs=2, type=WholeNumber(1, CALIBRATE_MAX_IMAGE_PX),
              metavar="W H",
              help="Image width and height (px); with POINTS, or when DIR/images is empty.")
@click.option("--valid-radius", nargs=2, type=FINITE, metavar="RMIN RMAX",
              help="Radii (px) of the robot-body mask and of the outer limit of the floor"
                   " (with POINTS; with --from-minho default: the first and last table radius).")
@click.option("--forward-angle-deg", type=FINITE, default=None,
              help="Image angle of the robot's forward direction, counter-clockwise from +u"
                   " with v up; with POINTS (default 90). --from-minho reads TILT.")
@click.option("--mirrored", is_flag=True, help="The image shows the floor mirrored (POINTS).")
@click.option("--preset", default=None, type=click.Choice(CALIBRATE_PRESETS),
              help="Named conf preset of the stage [default: 'default' (fifth-order polynomial)"
                   " for POINTS, 'minho' (monotone table) for --from-minho].")
@click.option("--overwrite", is_flag=True, help="Replace OUTPUT if it exists.")
@conf_option
@click.pass_context
def calibrate_omni(ctx, points, output, minho_dir, cnc_conf, nubot_dir, rings, calib_image,
                   line_images, mask, centre, image_size, valid_radius, forward_angle_deg,
                   mirrored, preset, overwrite, overrides):
    """Pixel radius -> floor distance of an omnidirectional camera, into calib.yaml.

    From POINTS (CSV header radius_px,distance_m: marks measured on the robot), by default the
    least-squares fifth-order f(r) of the SURF template paper's eq. 2; or from a team's mirror table
    (--from-minho), by default the monotone cubic through its pairs. --line-images measures
    pairs in images of a line at known distances and puts them in place of the other source's
    pairs where they overlap; the report then shows how far the other source was off there.

    \b
    Examples:
      fieldloc calibrate omni marks.csv -o calib.yaml --centre 241 233 \\
          --image-size 480 480 --valid-radius 40 230
      fieldloc calibrate omni --from-minho robot1/ -o calib.yaml
      fieldloc calibrate omni --from-minho robot1/ --line-images robot1/images -o calib.yaml
      fieldloc calibrate omni --from-cnc etc/CarpetCalibrator.conf --rings detected -o calib.yaml
      fieldloc calibrate omni --from-nubot calib_results/1 -o calib.yaml
    """
    from stages.calibrate import (
        MirrorGeometry,
        confs,
        from_cnc,
        from_minho,
        from_nubot,
        main,
        report,
    )
    from stages.common.conf import resolve_conf

    sources = {"points": points, "minho": minho_dir, "cnc": cnc_conf, "nubot": nubot_dir}
    given_sources = [k for k, v in sources.items() if v is not None]
    if len(given_sources) != 1:
        raise FieldlocError("calibrate omni needs POINTS or --from-minho DIR or --from-cnc FILE"
                            " or --from-nubot DIR (one of them)")
    kind = given_sources[0]
    if kind != "cnc" and (rings or calib_image):
        raise FieldlocError("--rings and --calib-image go with --from-cnc")
    conf = resolve_conf(confs, preset or DEFAULT_PRESET[kind], overrides_dict(overrides))
    if kind == "nubot":
        given = [name for name, v in (("--centre", centre), ("--mirrored", mirrored),
                                      ("--forward-angle-deg", forward_angle_deg is not None),
                                      ("--line-images", line_images), ("--mask", mask)) if v]
        if given:
            raise FieldlocError(f"{', '.join(given)}: not with --from-nubot (the centre and the"
                                " axes come from mirror_calib.xml)")
        out = from_nubot(conf, nubot_dir, output, image_size=image_size or None,
                         valid_radius=valid_radius or None, overwrite=overwrite)
        _echo_report(ctx, out, report(out))
        return
    if kind == "cnc":
        if line_images or mask:
            raise FieldlocError("--line-images and --mask do not go with --from-cnc")
        if not rings:
            raise FieldlocError(_rings_needed(cnc_conf, calib_image, centre, image_size,
                                              conf))
        forward = math.radians(90.0 if forward_angle_deg is None else forward_angle_deg)
        geometry = MirrorGeometry(centre or None, image_size or None, valid_radius or None,
                                  forward, mirrored)
        out = from_cnc(conf, cnc_conf, output, rings=rings, calib_image=calib_image,
                       geometry=geometry, overwrite=overwrite)
        _echo_report(ctx, out, report(out))
        return
    if kind == "points":
        missing = [name for name, v in (("--centre", centre), ("--image-size", image_size),
                                        ("--valid-radius", valid_radius)) if not v]
        if missing:
            raise FieldlocError(f"calibrate omni POINTS needs {', '.join(missing)}")
        forward = math.radians(90.0 if forward_angle_deg is None else forward_angle_deg)
        geometry = MirrorGeometry(centre, image_size, valid_radius, forward, mirrored)
        out = main(conf, points, output, geometry=geometry, line_images=line_images,
                   mask=mask, overwrite=overwrite)
    else:
        given = [name for name, v in (("--centre", centre), ("--mirrored", mirrored),
                                      ("--forward-angle-deg", forward_angle_deg is not None))
                 if v]
        if given:
            raise FieldlocError(
                f"{', '.join(given)}: --from-minho reads the centre and TILT from image.cfg")
        out = from_minho(conf, minho_dir, output, image_size=image_size or None,
                         valid_radius=valid_radius or None, line_images=line_images,
                         mask=mask, overwrite=overwrite)
    outputs_complete(ctx)
    _echo_report(ctx, out, report(out))


def _rings_needed(cnc_conf, calib_image, centre, image_size, conf) -> str:
    """The message when --rings is missing: the conf's distances and the picture's rings."""
    from pathlib import Path

    from stages.calibrate import cnc

    d = cnc.read_distances(cnc_conf)
    text = (f"--from-cnc needs --rings: {Path(cnc_conf).name} lists {len(d)} ring distances"
            f" ({', '.join(f'{v:g}' for v in d)} m) and no radii")
    image = calib_image or (Path(cnc_conf).parent / cnc.IMAGE_NAME)
    if Path(image).is_file():
        from stages.common.dataset import read_image

        img = read_image(image)
        rings = cnc.detect_rings(img, centre=cnc.search_centre(img.shape[1::-1], centre or None,
                                                               image_size or None),
                                 conf=conf.get("rings"))
        text += f"; {Path(image).name} shows {len(rings.radius_px)} rings" + (
            f" at {', '.join(f'{v:.1f}' for v in rings.radius_px)} px" if len(rings.radius_px)
            else "")
    return (text + ". Pair them: --rings detected (in order, as many rings as distances) or"
            " one radius per distance, '-' for a ring not seen (see stages/calibrate/cnc.py)")


def _echo_report(ctx, out, rec: dict) -> None:
    from stages.common.camera import load_calib

    verbose = (ctx.find_root().obj or {}).get("verbose", 0)
    camera = load_calib(out)
    pairs = rec["pairs"]
    if verbose >= 1:
        if rec["model"] == "table":
            click.echo("radius_px,distance_m,source,leave_one_out_m")
            for p in pairs:
                loo = p.get("leave_one_out_m")
                click.echo(f"{p['radius_px']:g},{p['distance_m']:g},{p['source']},"
                           + ("" if loo is None else f"{loo:+.4f}"))
        else:
            click.echo("radius_px,distance_m,fitted_m,residual_m")
            for p in pairs:
                click.echo(f"{p['radius_px']:g},{p['distance_m']:g},{p['fitted_m']:.4f},"
                           f"{p['residual_m']:+.4f}")
    marks = rec.get("line_images")
    if marks:
        click.echo("line images: image,distance_m,radius_px,rays,other_source_radius_px,"
                   "other_source_error_m")
        for m in marks:
            src_r = m.get("source_radius_px")
            src_e = m.get("source_error_m")
            click.echo(f"  {m['image']},{m['distance_m']:g},{m['radius_px']:.2f},{m['rays']},"
                       + ("" if src_r is None else f"{src_r:.2f}") + ","
                       + ("" if src_e is None else f"{src_e:+.3f}"))
    if rec["model"] == "table":
        loo = [(p["leave_one_out_m"], p["distance_m"]) for p in pairs if "leave_one_out_m" in p]
        if loo:
            rms = math.sqrt(sum(e * e for e, _ in loo) / len(loo))
            worst = max(loo, key=lambda t: abs(t[0]))
            fit_text = (f"monotone table; leave-one-out RMS {rms * 100:.2f} cm, max"
                        f" {abs(worst[0]) * 100:.2f} cm at {worst[1]:g} m")
        else:
            fit_text = "monotone table"
    else:
        res = [p["residual_m"] for p in pairs]
        rms = math.sqrt(sum(e * e for e in res) / len(res))
        fit_text = (f"residual RMS {rms * 100:.2f} cm, max"
                    f" {max(abs(e) for e in res) * 100:.2f} cm")
    mf = rec.get("model_fit")
    if mf:  # a team's closed-form model written as the table: how far the table is from it
        fit_text = (f"monotone table sampled from the team's model; off it by at most"
                    f" {mf['max_error_m'] * 1000:.2g} mm (relative {mf['max_relative_error']:.1e};"
                    f" at {mf['at_radius_px']:g} px, {mf['at_range_m']:g} m)")
    summary(ctx,
            f"wrote {out}: {len(pairs)} pairs, {fit_text}; floor visible to"
            f" {camera.max_distance:.2f} m at {camera.valid_radius[1]:.1f} px")
    nm = rec.get("nubot_model")
    if nm and any(nm["correction_cm_not_applied"]):
        cx, cy = nm["correction_cm_not_applied"]
        summary(ctx, f"note: the mirror's offset from the robot centre ({cx:+.1f}, {cy:+.1f})"
                     " cm is not applied (the omni model has no offset)")



@calibrate.command("perspective")
@click.option("--from-hulks", "hulks_source", required=True,
              type=FilePath(exists=True, path_type=Path), metavar="FILE.json|FOLDER",
              help="A HULKs capture JSON (camera matrix of one NAO frame), or a folder of them "
                   "beside their images.")
@click.option("-o", "--output", required=True, type=FilePath(path_type=Path),
              help="calib.yaml to write (from a file) or the dataset folder (from a folder).")
@click.option("--overwrite", is_flag=True, help="Replace OUTPUT if it exists.")
@conf_option
@click.pass_context
def calibrate_perspective(ctx, hulks_source, output, overwrite, overrides):
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
    from stages.common.conf import resolve_conf

    conf = resolve_conf(hulks.confs, "default", overrides_dict(overrides))
    out = hulks.main(conf, hulks_source, output, overwrite=overwrite)
    outputs_complete(ctx)
    summary(ctx, f"wrote {out}")
