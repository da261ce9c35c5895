"""`fieldloc localize DIR --map MAP [--features FILE | --points FILE.csv]
[--method lut|mcl|fit|templates] [--templates templates.h5 (--method templates; --map then
optional)] [--heading imu|histogram|truth] [--start-half own|opponent|any]
[--start-side left|right|any] [--init placement|uniform] [--independent] [--smooth]
[--write-calib calib.yaml] [--min-confidence P] [-o poses.h5]
[--preset NAME] [-c key=value] [--overwrite]`."""

from __future__ import annotations

import logging
from pathlib import Path

import click

from .common import (
    FilePath,
    FiniteFloat,
    conf_option,
    count,
    overrides_dict,
    progress_enabled,
    summary,
)
from .lazy_group import RESUMES, outputs_complete, set_resumes
from .stage_defaults import LOCALIZE, LOCALIZE_DEFAULT_METHOD, LOCALIZE_METHODS

log = logging.getLogger("fieldloc.localize")

TABLE_METHODS = ("lut", "fit")  # the omni methods: heading source, start half
# the methods with a smoother's scorer (stages.localize.smooth)
SMOOTH_METHODS = ("lut", "fit", "mcl", "templates")


@click.command()
@click.argument("dataset", type=FilePath(path_type=Path))
@click.option("--map", "map_path", default=None, type=FilePath(dir_okay=False, path_type=Path),
              help="Map file from `fieldloc build-map` (tables for lut and mcl; required but"
              " for --method templates, where it only names the field).")
@click.option("--templates", "templates", default=None,
              type=FilePath(dir_okay=False, path_type=Path),
              help="Template database from `fieldloc build-templates` (--method templates).")
@click.option("--pose-solver", type=click.Choice(["descent", "closed-form"]), default=None,
              help="templates: the pose of the SURF template paper's eq. 4 by its coordinate"
              " descent or in closed form (2D Kabsch) [default: descent].")
@click.option("--features", type=FilePath(dir_okay=False, path_type=Path), default=None,
              help="Features file from `fieldloc extract` [default: DATASET/features.h5 if it"
              " matches the calibration, mask and default conf and holds every frame, else"
              " extract on the fly into OUTPUT-stem.features.h5].")
@click.option("--points", type=FilePath(dir_okay=False, path_type=Path), default=None,
              help="CSV of your own line points instead of images: columns frame,x,y"
              " (robot frame, m).")
@click.option("--method", type=click.Choice(LOCALIZE_METHODS), default=LOCALIZE_DEFAULT_METHOD,
              show_default=True, help="Localisation method.")
@click.option("--heading", type=click.Choice(["imu", "histogram", "truth"]), default=None,
              help=f"lut, fit: heading source [default: {LOCALIZE['lut', 'heading']}].")
@click.option("--start-half", type=click.Choice(["own", "opponent", "any"]), default=None,
              help="lut, fit, mcl: where the robot's first pose lies (own: x < 0), which"
              " resolves the field's 180 deg symmetry when no field-aligned IMU heading does"
              " (mcl: the half its uniform start or placement is drawn on)"
              f" [default: {LOCALIZE['fit', 'start_half']}].")
@click.option("--start-side", type=click.Choice(["left", "right", "any"]), default=None,
              help="mcl: the touch line the placement stands on (left: y > 0, on the left"
              " looking from the own goal to the opponent's)"
              f" [default: {LOCALIZE['mcl', 'start_side']}].")
@click.option("--init", type=click.Choice(["placement", "uniform"]), default=None,
              help="mcl: initial belief, the game's placement (own half, at the touch"
              f" lines) or anywhere on the field [default: {LOCALIZE['mcl', 'init']}].")
@click.option("--independent", is_flag=True, default=None,
              help="localise every frame on its own, globally, with no prior and no"
              " odometry (snapshots at unknown poses; mcl: each from a uniform start).")
@click.option("--smooth", is_flag=True, default=None,
              help="decide every frame with the whole recording (offline: a"
              " forward-backward pass over the method's candidates, then a pose graph;"
              " docs/smoothing.md). Same as -c smooth=true.")
@click.option("--write-calib", type=FilePath(dir_okay=False, path_type=Path), default=None,
              help="lut, fit (omni): also write the dataset's calib.yaml corrected by the"
              " mirror's distance error learnt from the run's poses; mcl (perspective): by the"
              " camera's mount (pitch and roll offsets, height) learnt from them (with"
              " --smooth: from the smoothed ones; docs/recording-calibration.md), to this"
              " file.")
@click.option("--min-confidence", type=FiniteFloat(0.0, 1.0), default=None,
              help="Accept a frame when the probability of its top hypothesis reaches"
              f" this [default: the method's, lut {LOCALIZE['lut', 'min_confidence']}, fit"
              f" {LOCALIZE['fit', 'min_confidence']}].")
@click.option("-o", "--output", type=FilePath(dir_okay=False, path_type=Path), default=None,
              help="Poses file, poses.tum is written beside it"
              " [default: DATASET/poses-METHOD.h5].")
@click.option("--preset", default="default", show_default=True, help="Preset of the method.")
@conf_option
@click.option("--overwrite", is_flag=True,
              help="Replace an existing output file (its .tum only if fieldloc wrote it).")
@click.option("--allow-field-mismatch", is_flag=True,
              help="Localise even when the features were recorded on another field or with"
              " other scan lines than the map's.")
@click.pass_context
def localize(ctx, dataset, map_path, templates, pose_solver, features, points, method, heading,
             start_half, start_side, init, independent, smooth, write_calib, min_confidence,
             output, preset, overrides, overwrite, allow_field_mismatch):
    """Poses of the frames of DATASET on the field of MAP (poses.h5 + poses.tum)."""
    from stages import localize as stage
    from stages.common.conf import resolve_conf

    conf = overrides_dict(overrides)
    if "method" in conf:
        raise click.UsageError("the method is chosen with --method, not -c method=...")
    if heading is not None:
        if method not in TABLE_METHODS:
            raise click.UsageError("--heading applies to --method lut and fit")
        conf["heading"] = heading
    if start_half is not None:
        if method not in (*TABLE_METHODS, "mcl"):
            raise click.UsageError("--start-half applies to --method lut, fit and mcl")
        conf["start_half"] = start_half
    if start_side is not None:
        if method != "mcl":
            raise click.UsageError("--start-side applies to --method mcl")
        conf["start_side"] = start_side
    if init is not None:
        if method != "mcl":
            raise click.UsageError("--init applies to --method mcl")
        conf["init"] = init
    if method == "templates":
        if write_calib is not None:
            raise click.UsageError("--write-calib applies to --method lut, fit (omni) and mcl"
                                   " (perspective)")
        if templates is None:
            raise click.UsageError("--method templates needs --templates FILE (from"
                                   " fieldloc build-templates)")
        if features is not None or points is not None:
            raise click.UsageError("--method templates reads the images: no --features or"
                                   " --points")
    else:
        if templates is not None:
            raise click.UsageError("--templates applies to --method templates")
        if features is not None and points is not None:
            raise click.UsageError("give either --features or --points, not both")
        if map_path is None:
            raise click.UsageError("Missing option '--map'.")
    if pose_solver is not None:
        if method != "templates":
            raise click.UsageError("--pose-solver applies to --method templates")
        conf["pose_solver"] = pose_solver
    if independent:
        if method == "mcl":
            if init not in (None, "uniform") or start_side not in (None, "any"):
                raise click.UsageError("--independent starts every frame from a uniform"
                                       " belief: no --init placement or --start-side")
            conf.setdefault("init", "uniform")  # a -c init=... given is the stage's to judge
        conf["independent"] = True
    if smooth:
        if method not in SMOOTH_METHODS:
            raise click.UsageError(f"--smooth applies to --method {', '.join(SMOOTH_METHODS)}")
        conf["smooth"] = True
    if min_confidence is not None:
        conf["min_confidence"] = min_confidence
    conf = resolve_conf(stage.confs, stage.preset_name(method, preset), conf)
    output = output or Path(dataset) / f"poses-{method}.h5"
    if features is not None or points is not None or method == "templates":
        set_resumes(ctx, None)  # nothing extracted on the fly: nothing a rerun resumes
    else:  # the features extracted on the fly, where it kept a finished frame
        set_resumes(ctx, lambda: RESUMES["localize"] if _kept(output) else None)
    if method == "templates":
        path = stage.main(conf, dataset, map_path, output, templates=templates,
                          overwrite=overwrite, progress=progress_enabled(ctx))
        outputs_complete(ctx)
    else:  # the features given, or extracted first (or reused); two rounds with --smooth
        from stages.pipelines import images_to_poses

        given = stage.LinePoints(points) if points is not None else features
        path = images_to_poses.main(conf, dataset, map_path, output, features=given,
                                    overwrite=overwrite,
                                    progress=progress_enabled(ctx),
                                    allow_field_mismatch=allow_field_mismatch,
                                    write_calib=write_calib)
        outputs_complete(ctx)
    from stages.common.poses_file import read_poses

    cols, attrs = read_poses(path)
    n = len(cols["name"])
    failed = int(cols["failed"].sum())
    low = int((~cols["failed"] & ~cols["accepted"]).sum())
    ok = ~cols["failed"]
    rt = float(cols["runtime"].mean()) * 1e3 if n else 0.0
    msg = (f"{path}: {count(n, 'frame')}, {n - failed - low} accepted, {low} low-confidence,"
           f" {failed} failed, mean runtime {rt:.2f} ms/frame")
    if ok.any():
        modes = {m: int((cols["mode"][ok] == m).sum()) for m in sorted(set(cols["mode"][ok]))}
        msg += " (" + ", ".join(f"{m} {c}" for m, c in modes.items()) + ")"
    if write_calib is not None:
        msg += f"; calib.yaml corrected from the recording -> {write_calib}"
    summary(ctx, msg)


def _kept(output: Path) -> bool:
    """Whether the extraction localize ran on the fly for ``output`` kept finished frames
    (in the features file beside it, or its parts), or used the dataset's own features."""
    from stages.common.features_file import kept_frames
    from stages.pipelines.images_to_poses import default_features_path

    target = default_features_path(output)
    return target.is_file() or kept_frames(target)
