"""`fieldloc build-templates DIR -o templates.h5 [--features surf|surf-rotating|sift|orb]
[-c key=value] [--overwrite]`: the SURF template paper's template database from captures at known
poses."""

from __future__ import annotations

from pathlib import Path

import click

from .common import FilePath, conf_option, overrides_dict, progress_enabled, summary
from .lazy_group import outputs_complete
from .stage_defaults import BUILD_TEMPLATES_FEATURES


@click.command("build-templates")
@click.argument("dataset", type=FilePath(path_type=Path))
@click.option("-o", "--output", type=FilePath(dir_okay=False, path_type=Path), default=None,
              help="Templates file [default: DATASET/templates.h5].")
@click.option("--features", "features", type=click.Choice(BUILD_TEMPLATES_FEATURES),
              default="surf", show_default=True,
              help="Local features: our SURF (upright, in the field's axes; surf-rotating:"
              " rotation-invariant, in the robot's), OpenCV's SIFT or ORB.")
@conf_option
@click.option("--overwrite", is_flag=True, help="Replace an existing output file.")
@click.pass_context
def build_templates(ctx, dataset, output, features, overrides, overwrite):
    """Templates of the omni frames of DATASET (a `simulate omni --grid` folder, or a real one
    with truth.csv): one per frame, its floor's local features and its pose."""
    import numpy as np

    from stages import build_templates as stage
    from stages.common.conf import resolve_conf

    conf = resolve_conf(stage.confs, stage.FEATURE_PRESETS[features], overrides_dict(overrides))
    output = output or Path(dataset) / "templates.h5"
    path = stage.main(conf, dataset, output, overwrite=overwrite,
                      progress=progress_enabled(ctx))
    outputs_complete(ctx)
    from stages.common.templates import read_templates

    db = read_templates(path)
    n = len(db.points)
    summary(ctx, f"{path}: {len(db)} templates, {n} {db.feature_kind} features"
            f" (median {int(np.median(np.diff(db.offsets)))}"
            f" per template), {path.stat().st_size / 1e6:.2f} MB")
