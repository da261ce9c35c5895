"""From a dataset's images to poses, as ``fieldloc localize DIR`` runs without ``--features``:
the features of the dataset, then stages.localize.

    main(conf, dataset_dir, map_path, output, *, overwrite=False, progress=False,
         allow_field_mismatch=False, write_calib=None) -> Path

The features are the dataset's own ``DIR/features.h5`` when it was extracted from the same
calibration, mask and default conf and holds every frame (stages.extract.reusable_features),
and otherwise extracted now (stages.extract, default conf) into ``<output stem>.features.h5``
beside the output, resumed if present. Everything localize would refuse (its outputs, the
dataset's time series, the method, the map) is refused before a frame is extracted.
"""

from __future__ import annotations

import logging
from pathlib import Path

from .. import extract, localize
from ..common.artifacts import check_output

log = logging.getLogger(__name__)


def default_features_path(output: str | Path) -> Path:
    """Where the features extracted for ``output`` go: ``<output stem>.features.h5``."""
    output = Path(output)
    return output.with_name(output.stem + ".features.h5")


def features_for(dataset_dir: str | Path, output: str | Path, inputs: dict,
                 progress: bool = False) -> Path:
    """The features of a dataset localised without a features file: DIR/features.h5 when it
    matches what extract would make now, else extracted beside ``output``. ``inputs``: the
    files the extracted features must not be written over."""
    dataset_dir = Path(dataset_dir)
    own = dataset_dir / "features.h5"
    why = extract.reusable_features(own, dataset_dir) if own.exists() else None
    if own.exists() and why is None:
        log.info("no features given: using %s (same calibration, mask and conf, every frame)",
                 own)
        return own
    target = default_features_path(output)
    check_output(target, inputs, overwrite=None)
    log.info("no features given: extracting %s into %s%s", dataset_dir, target,
             f" ({own} is not used: {why})" if why else "")
    extract.main(None, dataset_dir, target, progress=progress)
    return target


def main(conf, dataset_dir: str | Path, map_path: str | Path, output: str | Path, *,
         overwrite: bool = False, progress: bool = False,
         allow_field_mismatch: bool = False, write_calib: str | Path | None = None) -> Path:
    """Localise the images of ``dataset_dir`` on ``map_path`` into ``output`` (localize's
    conf and options), extracting their features first when the dataset has none to reuse."""
    _conf, _ds, _series, inputs = localize.check_run(conf, dataset_dir, map_path, output,
                                                     overwrite=overwrite)
    if write_calib is not None:
        localize.check_write_calib(write_calib, _conf, _ds, None, output, inputs, overwrite)
    features = features_for(dataset_dir, output, inputs, progress)
    return localize.main(conf, dataset_dir, map_path, output, features=features,
                         overwrite=overwrite, progress=progress,
                         allow_field_mismatch=allow_field_mismatch, write_calib=write_calib)
