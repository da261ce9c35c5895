"""From a dataset's images to poses, as ``fieldloc localize DIR`` runs: the features of the
dataset, then stages.localize, and with ``smooth`` a second round on features extracted with
the camera calibration the first round's poses show.

    main(conf, dataset_dir, map_path, output, *, features=None, overwrite=False,
         progress=False, allow_field_mismatch=False, write_calib=None) -> Path

**The features.** Those given (``features``: a features file, or a team's line points as
stages.localize.LinePoints), else the dataset's
own ``DIR/features.h5`` when it was extracted from the same calibration, mask and default conf
and holds every frame (stages.extract.reusable_features), and otherwise extracted now
(stages.extract, default conf) into ``<output stem>.features.h5`` beside the output, resumed if
present. Everything localize would refuse (its outputs, the dataset's time series, the method,
the map) is refused before a frame is extracted.

**Two rounds** (``smooth`` and ``recalibrate``, on a camera whose calibration the method's
poses can correct: stages.localize.RECORDING_CALIBRATIONS). A team's calibration is rarely
exact (an omni mirror's distance mapping off by centimetres, a camera's mount by a degree),
and every fix of the first round is pulled by the mismatch. An offline run has the whole
recording, so it does what bundle adjustment does with a camera (Triggs et al. 2000): it
estimates the calibration jointly with the smoothed poses of every frame
(docs/recording-calibration.md), extracts the frames again with it, and smooths again.

- The first round's poses are kept beside the output as ``<output stem>.first-round.h5``, the
  calibration the second round used as ``<output stem>.recalibrated.yaml``, and its features
  as ``<output stem>.recalibrated.features.h5``; the poses name them as their inputs.
- A frame the second round places elsewhere than the first turns on a few centimetres of
  calibration: the two places hold at most half each, and it is flagged ``rounds-disagree``
  (stages.localize.against_reference).
- A calibration the first round's poses cannot give (too few sure frames, a fit whose halves
  disagree) is not used: the first round's poses are the run's, and a warning says why.
- ``write_calib`` writes the calibration estimated again from the second round's poses, on the
  features of the dataset's own calib.yaml (the same estimate with better poses).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import yaml

from .. import extract, localize
from ..common.artifacts import check_output, commit_file
from ..common.errors import FieldlocError
from ..common.poses_file import check_tum_output, drop_twin

log = logging.getLogger(__name__)


def default_features_path(output: str | Path) -> Path:
    """Where the features extracted for ``output`` go: ``<output stem>.features.h5``."""
    output = Path(output)
    return output.with_name(output.stem + ".features.h5")


def recalibrated_paths(output: str | Path) -> tuple[Path, Path, Path]:
    """(calib.yaml, features, first round's poses) of the two rounds of ``output``: ``<output
    stem>.recalibrated.yaml``, ``<output stem>.recalibrated.features.h5`` and ``<output
    stem>.first-round.h5`` (its poses.tum beside it)."""
    output = Path(output)
    return (output.with_name(output.stem + ".recalibrated.yaml"),
            output.with_name(output.stem + ".recalibrated.features.h5"),
            output.with_name(output.stem + ".first-round.h5"))


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
         features: str | Path | localize.LinePoints | None = None,
         overwrite: bool = False, progress: bool = False,
         allow_field_mismatch: bool = False, write_calib: str | Path | None = None) -> Path:
    """Localise the frames of ``dataset_dir`` on ``map_path`` into ``output`` (localize's
    conf and options) from ``features`` (a features file or LinePoints), or from the
    dataset's features, extracted first when it has none to reuse; in two rounds with
    ``smooth`` and ``recalibrate`` (module doc)."""
    resolved, ds, _series, inputs = localize.check_run(
        conf, dataset_dir, map_path, output, features=features, overwrite=overwrite)
    points = localize.split_features(features)[1]
    if write_calib is not None:
        localize.check_write_calib(write_calib, resolved, ds, points, output, inputs, overwrite)
    rounds = (points is None and resolved.get("smooth") and resolved.get("recalibrate")
              and localize.recording_calibration(ds.camera().kind, resolved["method"]))
    if rounds:
        calib, features2, first = recalibrated_paths(output)
        given = {**inputs, "poses": output, "calib": write_calib}
        from ..common import features_file, poses_file

        for path, kind, schema in ((calib, "calibration", None),
                                   (features2, "file", features_file.SCHEMA),
                                   (first, "file", poses_file.SCHEMA)):
            check_output(path, given, overwrite=overwrite, kind=kind, schema=schema)
        check_tum_output(first, given, overwrite)  # its twin, as the first poses record it
    if features is None:
        features = features_for(dataset_dir, output, inputs, progress)
    kw = {"progress": progress, "allow_field_mismatch": allow_field_mismatch}
    if not rounds:
        return localize.main(conf, dataset_dir, map_path, output, features=features,
                             overwrite=overwrite, write_calib=write_calib, **kw)
    return _two_rounds(conf, Path(dataset_dir), map_path, Path(output), Path(features),
                       overwrite=overwrite, write_calib=write_calib, **kw)


def _two_rounds(conf, dataset_dir: Path, map_path, output: Path, features: Path, *,
                overwrite: bool, write_calib, progress: bool, allow_field_mismatch: bool) -> Path:
    """The first round, the calibration its poses show, the features extracted with it, the
    second round into ``output`` against the first (module doc)."""
    calib, features2, first = recalibrated_paths(output)
    kw = {"progress": progress, "allow_field_mismatch": allow_field_mismatch}
    localize.main(conf, dataset_dir, map_path, first, features=features, overwrite=overwrite,
                  **kw)
    try:  # written atomically, or refused before anything is written
        localize.calibrate_from_poses(calib, dataset_dir, features, first, map_path,
                                      source=os.path.abspath(first))
    except FieldlocError as e:
        log.warning("no second round: the first round's poses give no calibration (%s)", e)
        drop_twin(output)  # stopped between the two commits: no stale twin beside new poses
        for src in (first, first.with_suffix(".tum")):  # the first round is the run: committed
            # as the output is (never over a file another run wrote there meanwhile)
            commit_file(src, output.with_suffix(src.suffix))
        _remove_earlier_second_round(calib, features2)
        if write_calib is not None:
            raise FieldlocError(f"{e}; the poses are written: {output}") from None
        return output
    log.info("second round: extracting %s with %s into %s", dataset_dir, calib, features2)
    extract.main(extract.conf_of(features), dataset_dir, features2, overwrite=overwrite,
                 progress=progress, calib=calib)
    path = localize.main(conf, dataset_dir, map_path, output, features=features2,
                         overwrite=overwrite, reference=first, **kw)
    if write_calib is not None:
        try:
            localize.calibrate_from_poses(write_calib, dataset_dir, features, path, map_path)
        except FieldlocError as e:
            raise FieldlocError(f"{e}; the poses are written: {path}") from None
    return path


def _remove_earlier_second_round(calib: Path, features2: Path) -> None:
    """After a run with no second round, the second-round files an earlier run of the same
    output left (the run's own outputs, which --overwrite let it replace: check_output) are
    removed, so that nothing beside the poses claims a calibration this run did not learn. A
    file is removed only when it is what a second round writes (a calib.yaml whose
    ``calibration`` mapping says ``method: recording``, a features file of fieldloc's schema);
    anything else at those names is left, with a warning."""
    for path, ours in ((calib, _learnt_calibration), (features2, _features_artifact)):
        if not path.exists():
            continue
        if ours(path):
            os.remove(path)
            log.info("removed %s: an earlier run's second round, which this run has not", path)
        else:
            log.warning("%s is not a second round's file: left as it is; these poses do not"
                        " use it", path)


def _learnt_calibration(path: Path) -> bool:
    """Whether ``path`` is a calib.yaml a recording's calibration wrote."""
    from ..common.camera import read_calibration_record

    try:
        return read_calibration_record(path).get("method") == "recording"
    except (OSError, ValueError, yaml.YAMLError):  # not text, not YAML: not ours
        return False


def _features_artifact(path: Path) -> bool:
    """Whether ``path`` is a features file of fieldloc's schema."""
    from ..common.artifacts import open_artifact
    from ..common.features_file import SCHEMA, VERSION

    try:
        open_artifact(path, SCHEMA, VERSION).close()
    except FieldlocError:
        return False
    return True
