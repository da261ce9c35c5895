"""`fieldloc simulate KIND ...`: render a dataset folder with ground truth.

One subcommand per camera kind; each only maps its options onto the stage's conf (defaults from
``stages.simulate.confs``, which the help shows through ``stage_defaults.SIMULATE``) and calls
``stages.simulate.main``. A new camera kind adds a preset and a renderer in the stage, its preset
names and shown defaults in ``stage_defaults``, and a subcommand here: a function decorated with
``@simulate.command`` and ``@simulate_options("<kind>-default", "<kind>")`` that calls
``run_simulation``.
"""

from __future__ import annotations

import math

import click

from .common import (
    FINITE,
    FilePath,
    FiniteFloat,
    WholeNumber,
    conf_option,
    count,
    overrides_dict,
    progress_enabled,
    summary,
)
from .lazy_group import outputs_complete
from .stage_defaults import SIMULATE, SIMULATE_PATH_KINDS, SIMULATE_PRESETS


def simulate_options(preset: str, camera: str):
    """The options every `simulate KIND` subcommand shares; the help names ``preset``'s
    values, the presets offered are ``camera``'s."""
    base = SIMULATE[preset]

    def decorate(f):
        options = [
            click.option("--field", "field", required=True, metavar="FIELD",
                         help="Field preset name (msl-2015, spl, ...) or a field YAML file."),
            click.option("-o", "--output", "output", required=True,
                         type=FilePath(file_okay=False), help="Dataset folder to write."),
            click.option("--frames", type=WholeNumber(min=1), default=None,
                         help=f"Number of frames [preset: {base['frames']}]."),
            click.option("--seed", type=WholeNumber(min=0), default=None,
                         help=f"Seed of every random choice [preset: {base['seed']}]."),
            click.option("--trajectory", "trajectory_kind", type=click.Choice(SIMULATE_PATH_KINDS),
                         default=None,
                         help="Path of the robot: random waypoints or a loop of the field"
                              f" [preset: {base['trajectory']}]."),
            click.option("--calib-error", nargs=3, type=FINITE, default=None,
                         metavar="DU DV SCALE",
                         help="Write calib.yaml off from the rendering camera: centre (principal"
                              " point) shifted by DU, DV px and the radial mapping scaled by"
                              " SCALE, and no other error (omni: no mirror-table error) [preset: "
                              f"{' '.join(str(v) for v in base['calib_error'])}]."),
            click.option("--preset", default=preset, show_default=True,
                         type=click.Choice(SIMULATE_PRESETS[camera]),
                         help="Named conf preset of the stage."),
            click.option("--overwrite", is_flag=True,
                         help="Replace a dataset folder simulate made (simulation.yaml) that"
                              " holds nothing else."),
            conf_option,
        ]
        for opt in reversed(options):
            f = opt(f)
        return f

    return decorate


def run_simulation(ctx, *, field, output, frames, seed, trajectory_kind, preset, overwrite,
                   overrides, calib_error=None):
    from stages.common.conf import resolve_conf
    from stages.simulate import confs, main

    conf = resolve_conf(confs, preset, overrides_dict(overrides))
    # options given on the command line win over the preset and -c overrides
    if frames is not None:
        conf["frames"] = frames
    if seed is not None:
        conf["seed"] = seed
    if trajectory_kind is not None:
        conf["trajectory"]["kind"] = trajectory_kind
    if calib_error is not None:
        du, dv, scale = calib_error  # exactly this error: omni's mirror-table error off
        ce = conf["calib_error"]
        ce.update(centre_shift=[du, dv], scale=scale)
        if "distance_error" in ce:
            ce["distance_error"] = 0.0
    out = main(conf, field, output, overwrite=overwrite, progress=progress_enabled(ctx))
    outputs_complete(ctx)
    n = sum(1 for _ in (out / "images").glob("*.png"))  # a grid's count is the grid's
    summary(ctx, f"wrote {count(n, 'frame')} to {out}")
    return out


@click.group()
def simulate():
    """Render a dataset folder (images, calib.yaml, odometry, IMU, truth) from ground-truth
    poses."""


@simulate.command("omni")
@simulate_options("omni-default", "omni")
@click.option("--grid", "grid_spacing", type=FINITE, default=None, metavar="SPACING",
              help="Template captures (the SURF template paper): the robot placed at the nodes of"
              " a grid of SPACING m over the field instead of a path (one frame per node and"
              " heading, no odometry.csv; --frames and --trajectory do not apply).")
@click.option("--grid-headings", type=WholeNumber(min=1), default=None, metavar="N",
              help="With --grid: N headings per node, 360/N deg apart from 0"
              f" [preset: {SIMULATE['omni-default']['grid_headings']}].")
@click.option("--calib-seed", type=WholeNumber(), default=None,
              help="Seed of the calibration error calib.yaml states [default: --seed]: the"
              " same for two datasets makes them one robot's (a template grid and a run).")
@click.option("--world-seed", type=WholeNumber(), default=None,
              help="Seed of the venue (carpet, paint, walls) [default: --seed]: the same for"
              " two datasets records both in one lab.")
@click.pass_context
def simulate_omni(ctx, field, output, frames, seed, trajectory_kind, calib_error, preset,
                  overwrite, overrides, grid_spacing, grid_headings, calib_seed, world_seed):
    """An omnidirectional (catadioptric) camera on a MSL robot.

    \b
    Examples:
      fieldloc simulate omni --field msl-2015 -o data/omni --frames 100 --seed 1
      fieldloc simulate omni --field msl-2015 -o data/grid --grid 1.0 --seed 2 --calib-seed 1
    """
    extra = list(overrides)
    if grid_spacing is not None:
        if frames is not None or trajectory_kind is not None:
            raise click.UsageError("--grid places the robot at the grid's nodes: --frames and"
                                   " --trajectory do not apply")
        if not grid_spacing > 0:
            raise click.UsageError(f"--grid must be > 0 m, got {grid_spacing:g}")
        extra += ["trajectory.kind=grid", f"trajectory.grid_spacing={grid_spacing!r}"]
    if grid_headings is not None:
        if grid_spacing is None:
            raise click.UsageError("--grid-headings applies to --grid")
        extra.append(f"trajectory.grid_headings={grid_headings}")
    if calib_seed is not None:
        extra.append(f"calib_seed={calib_seed}")
    if world_seed is not None:
        extra.append(f"world_seed={world_seed}")
    run_simulation(ctx, field=field, output=output, frames=frames, seed=seed,
                   trajectory_kind=trajectory_kind, preset=preset, overwrite=overwrite,
                   overrides=tuple(extra), calib_error=calib_error)


@simulate.command("perspective")
@simulate_options("perspective-default", "perspective")
@click.option("--camera-height", type=FINITE, default=None, metavar="M",
              help="Camera height above the floor (m) [preset: "
                   f"{SIMULATE['perspective-default']['height']}].")
@click.option("--pitch-deg", type=FiniteFloat(-180, 180), default=None,
              help="Nominal camera pitch (degrees, > 0 looks down) [preset: "
                   f"{SIMULATE['perspective-default']['pitch_deg']:.1f}].")
@click.pass_context
def simulate_perspective(ctx, field, output, frames, seed, trajectory_kind, calib_error, preset,
                         overwrite, overrides, camera_height, pitch_deg):
    """A wide-angle head camera on a walking KidSize humanoid (Schulz et al. 2011): 752 x 480
    frames, head pitch and roll wobbling with the walk (head.csv), starting at a touch line of the
    own half. With --calib-error the principal point is shifted and the focal lengths scaled.

    \b
    Example:
      fieldloc simulate perspective --field kidsize -o data/kid --frames 300 --seed 1
    """
    extra = list(overrides)
    if camera_height is not None:
        extra.append(f"perspective.height={camera_height}")
    if pitch_deg is not None:
        extra.append(f"perspective.pitch={math.radians(pitch_deg)}")
    run_simulation(ctx, field=field, output=output, frames=frames, seed=seed,
                   trajectory_kind=trajectory_kind, preset=preset, overwrite=overwrite,
                   overrides=tuple(extra), calib_error=calib_error)
