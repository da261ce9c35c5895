"""`fieldloc extract DIR [-o features.h5] [--overwrite] [--preset NAME] [-c key=value]`."""

from __future__ import annotations

from pathlib import Path

import click

from .common import FilePath, conf_option, count, overrides_dict, progress_enabled, summary
from .lazy_group import RESUMES, outputs_complete, set_resumes
from .stage_defaults import EXTRACT_DEFAULT_PRESET, EXTRACT_OMNI_PRESETS


@click.command()
@click.argument("dataset", type=FilePath(path_type=Path))
@click.option("-o", "--output", type=FilePath(dir_okay=False, path_type=Path), default=None,
              help="Features file [default: DATASET/features.h5].")
@click.option("--preset", default=EXTRACT_DEFAULT_PRESET, show_default=True,
              help="Preset of the camera kind's extractor (omni: "
              + ", ".join(EXTRACT_OMNI_PRESETS) + ").")
@conf_option
@click.option("--overwrite", is_flag=True,
              help="Extract every frame again (default: resume, skipping frames already done).")
@click.option("--debug-images", type=FilePath(file_okay=False, path_type=Path), default=None,
              help="Folder for one overlay PNG per extracted frame (perspective: the boundary, "
                   "lines used / not used, crossings marked L/T/X): a new or empty folder, or "
                   "one extract made (debug-images.yaml), whose overlays --overwrite replaces.")
@click.pass_context
def extract(ctx, dataset, output, preset, overrides, overwrite, debug_images):
    """Per-frame features of the images in DATASET (omni: scan-line distances and line points;
    perspective: lines, crossings, boundary) into an HDF5 features file."""
    target = output if output is not None else Path(dataset) / "features.h5"
    set_resumes(ctx, lambda: RESUMES["extract"] if _kept(target) else None)  # before imports
    from stages import extract as stage

    conf = stage.resolve_extract_conf(stage.camera_kind(dataset), preset,
                                      overrides_dict(overrides))
    path = stage.main(conf, dataset, output, overwrite=overwrite,
                      progress=progress_enabled(ctx), debug_images=debug_images)
    outputs_complete(ctx)
    from stages.common.features_file import FeaturesFile

    with FeaturesFile(path) as ff:
        n, failures, kind = len(ff), ff.failures, ff.camera_kind
    msg = f"{path}: {count(n, 'frame')} ({kind} camera)"
    if failures:
        msg += f", {len(failures)} failed (first: {failures[0]})"
    summary(ctx, msg)


def _kept(target: Path) -> bool:
    """Whether an extraction into ``target`` that stopped kept finished frames."""
    from stages.common.features_file import kept_frames

    return kept_frames(target)
