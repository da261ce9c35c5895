"""Stage extract: per-frame features of a dataset folder's images into features.h5.

    from stages import extract
    extract.main("default", "data/run1", "data/run1/features.h5")

The camera kind of the dataset's calib.yaml picks the extractor module (``KINDS``); each exposes
``confs`` (named presets) and ``extract_frame(image_bgr, camera, conf, **frame_info) -> dict``
whose keys are FRAME_DATASETS names of stages.common.features_file. ``confs`` here lists the
presets of every kind as ``<kind>-<preset>`` (``omni-dense``); ``main``'s conf is a preset
name of the dataset's kind (``dense`` or ``omni-dense``), None (the kind's ``default``), or a
dict of overrides on the kind's default preset (``resolve_extract_conf``):

- ``omni`` (stages.extract.omni, Ribeiro et al. 2015): scan-line distances and line points;
  frame_info ``mask`` (the dataset's mask.png, see ``read_mask``);
- ``perspective`` (stages.extract.perspective, Schulz et al. 2011, imported only when used): field
  boundary, lines, crossings, goal posts; frame_info ``pitch``/``roll`` (and ``yaw``,
  ``height``, ``x``, ``y`` where recorded) from DIR/head.csv (nearest stamp within
  ``HEAD_STAMP_TOLERANCE``) when that file exists.

One frame per image, named by the image's file stem. Frames already in the output are skipped
(resume) unless ``overwrite``, but for those of images or stamps changed since, extracted
again, and those frames.csv no longer lists, dropped (``_stale_frames``); a frame that
cannot be read or processed is logged, recorded in the file's ``failures`` and skipped. If
no frame at all can be extracted (images of another size than calib.yaml says, every image
unreadable), that is an error and nothing is written.

Finished frames are committed as they come, a chunk every half second
(stages.common.features_file.FrameParts), so a run that is killed keeps its frames and the
next run resumes there; the features file itself appears
atomically when the run completes, and a run with nothing left to do (every frame extracted;
frames recorded as failed are tried again) leaves it untouched. The
output is never one of the dataset's own files (calib.yaml, images, CSVs), --overwrite or not.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
from pathlib import Path

import numpy as np

from ..common.artifacts import (
    WRITTEN_FILES,
    as_stored,
    atomic_path,
    check_output,
    fieldloc_wrote,
    file_hash,
    output_lock,
    record_text,
    refuse_edited,
    root_attrs,
    storable_text,
    writing,
    written_by,
    written_files,
)
from ..common.camera import camera_can
from ..common.conf import KindPresets, check_bounds, registered_module, resolve_conf, stage_conf
from ..common.dataset import STAMP_SOURCES, open_dataset, read_frame, read_image, read_mask
from ..common.errors import FieldlocError, SchemaError, real_path
from ..common.features_file import (
    SAME_STAMP_S,
    SCHEMA,
    VERSION,
    FeaturesFile,
    FrameParts,
    file_bytes,
    frame_columns,
    write_features,
)
from ..common.head_angles import (  # noqa: F401
    HEAD_STAMP_TOLERANCE,
    frames_without_head,
    head_at,
    head_table,
)
from ..common.png import with_mark
from ..common.resources import check_disk, opencv_single_threaded

log = logging.getLogger(__name__)

KINDS = {"omni": "stages.extract.omni", "perspective": "stages.extract.perspective"}
GENERATOR = "fieldloc extract"
# in a --debug-images folder extract made: the marker of folders whose overlays it may replace,
# and their WRITTEN_FILES table (each overlay's size and SHA-256 as drawn), by which an overlay
# is replaced only as it was drawn (``_DebugOverlays``)
DEBUG_RECORD = "debug-images.yaml"
DEFAULT_PRESET = "default"
MASK_NAME = "mask.png"


def kind_module(kind: str):
    """The extractor module of a camera kind (imported on first use)."""
    return registered_module(KINDS, kind, "camera kind")


def kind_confs(kind: str) -> dict:
    """The named presets of a camera kind's extractor."""
    return kind_module(kind).confs


# the presets of every kind: "<kind>-<preset>" -> conf, a kind's extractor imported only when
# one of its presets is asked for (localising from stored features imports none)
confs = KindPresets(KINDS, kind_confs)


def resolve_extract_conf(kind: str, conf: str | dict | None = None,
                         overrides: dict | None = None) -> dict:
    """The conf for a camera kind: a preset name of the kind (``dense``, or ``omni-dense`` as
    in ``confs``; None: ``DEFAULT_PRESET``) or a dict of overrides on the kind's default
    preset, then ``overrides``. Unknown preset names and keys are user errors."""
    presets = kind_confs(kind)
    if isinstance(conf, str) and conf not in presets and conf in confs:
        if not conf.startswith(f"{kind}-"):
            raise FieldlocError(f"preset '{conf}' is one of {conf.split('-')[0]} cameras; the"
                                f" dataset's camera is {kind}")
        conf = conf[len(kind) + 1:]
    resolved = resolve_conf(presets, stage_conf(presets, conf, DEFAULT_PRESET), overrides)
    module = kind_module(kind)
    check_bounds(resolved, getattr(module, "BOUNDS", {}))
    if hasattr(module, "check_conf"):  # what ranges alone do not say (keys that must agree)
        module.check_conf(resolved)
    return resolved


def camera_kind(dataset_dir: str | Path) -> str:
    """The camera kind of a dataset folder (its calib.yaml), which picks the presets."""
    return open_dataset(dataset_dir).camera().kind


_head_angles = head_table  # head.csv sorted by stamp (stages.common.head_angles)


def _frame_info(kind: str, mask, head, stamp: float) -> dict:
    """The frame_info of one frame for its kind's ``extract_frame`` (module doc)."""
    return {"mask": mask} if camera_can(kind, "robot_mask") else head_at(head, stamp)


def _check_resumable(output: Path, attrs: dict, *, same_dataset: bool = False):
    """An existing output may only be continued if it was made from the same calibration,
    mask, head angles (head.csv) and conf, and, with ``same_dataset`` (extract resuming it,
    which drops the frames the dataset lacks), from the same dataset folder; otherwise the
    user has to ask for --overwrite. A file of before head.csv was recorded counts as made
    without one. Features reused as they are need not be of the same folder: a copied
    recording's are its (localize checks the images they were made from)."""
    try:
        with FeaturesFile(output) as old:
            keys = ("dataset",) * same_dataset + ("camera_kind", "calib_hash", "mask_hash",
                                                  "head_hash")
            same = {k: old.h5.attrs.get(k, "") for k in keys}
            old_conf = old.conf
    except SchemaError as e:
        raise FieldlocError(f"{e}; use --overwrite to replace it") from None
    for k, v in same.items():
        v = v.decode(errors="replace") if isinstance(v, bytes) else v  # not UTF-8: A2-1
        if k == "dataset" and isinstance(v, str) and v:
            # the folder behind a link, as attrs["dataset"] is, stored as storable_text
            # writes a name of bytes not UTF-8 (trial B2-5); a NUL is no folder (B2-4)
            mine = storable_text(attrs[k])
            same_folder = v == mine or ("\0" not in v and os.path.realpath(v) == mine)
            if same_folder:
                continue
        if not (isinstance(v, str) and v == attrs[k]):
            what = {"mask_hash": "mask", "head_hash": "head.csv"}.get(k)
            if k == "dataset":  # another recording's frames (trial Z2-2: dropped as gone)
                said = f"from another dataset ({str(v)[:60]})"
            elif what is None:
                said = f"with another {k.replace('_', ' ')} ({str(v)[:40]})"
            elif not v:
                said = f"without a {what}"
            else:
                said = f"with {'another' if attrs[k] else 'a'} {what}" + (
                    "" if attrs[k] else " the dataset no longer has")
            raise FieldlocError(f"{output} was extracted {said}; use --overwrite to extract"
                                " again")
    conf = json.loads(attrs["conf"])
    former = getattr(kind_module(attrs["camera_kind"]), "former_layout", dict)()
    if not _same_conf(old_conf, conf, as_stored(former)):
        raise FieldlocError(
            f"{output} was extracted with another conf; use --overwrite to extract again")


def _warn_head_stamps(ds, head) -> None:
    """Warn once when frames have no head.csv row near their stamp (they take the nominal
    head pose), in localize's words for imu.csv and odometry.csv."""
    missing = frames_without_head(head, ds.stamps)
    if missing:
        source = STAMP_SOURCES.get(ds.stamp_source, ds.stamp_source)
        stamps = np.asarray(ds.stamps, float)
        log.warning(
            "%d of %d frames have no head.csv row within %g s: the frame stamps"
            " (%s, %.10g..%.10g s) and head.csv (%.10g..%.10g s) do not meet; those frames"
            " take the calibration's head pose", missing, len(stamps), HEAD_STAMP_TOLERANCE,
            source, stamps.min(), stamps.max(), head[0][0], head[0][-1])


def _stale_frames(output: Path, ds) -> tuple[set[str], set[str]]:
    """(the frames of the features file ``output`` a resumed run keeps, those it does not):
    a frame the dataset no longer has (taken out of frames.csv) is dropped, one whose image
    changed since (``FeaturesFile.changed_images``) or whose stamp in frames.csv did is
    extracted again, so that the file holds the dataset's frames, of its images, only.
    Kept, they were counted as the dataset's and refused by localize's check (trial U2,
    U2-5 and U2-6)."""
    stamp_of = dict(zip(ds.names, (float(s) for s in ds.stamps)))
    with FeaturesFile(output) as old:
        names = set(old.names)
        stale = {n for n, s in zip(old.names, old.stamps)
                 if n not in stamp_of or not abs(stamp_of[n] - float(s)) <= SAME_STAMP_S}
        stale |= {n for n, *_ in old.changed_images(ds)}
    if stale:
        dropped = len(stale - set(stamp_of))
        log.info("extract: %s of %s; %d frames dropped (not in frames.csv), %d extracted"
                 " again (image or stamp changed)", output, ds.root, dropped,
                 len(stale) - dropped)
    return names - stale, stale


def _copy_frames(source: Path, writer, keep: set[str], names: set[str]) -> None:
    """The frames ``keep`` of the features file ``source``, with their image identities,
    and its failures of frames in ``names``, added to ``writer``."""
    with FeaturesFile(source) as old:
        for name in old.names:
            if name in keep:
                arrays = old.frame(name)
                stamp = float(arrays.pop("stamp"))
                writer.add_frame(name, stamp, arrays, old.image(name))
        for failure in old.failures:  # "name: reason"
            name, _sep, reason = failure.partition(": ")
            if name in names:
                writer.add_failure(name, reason)


_ABSENT = object()


def _same_conf(stored, conf, former) -> bool:
    """Whether a features file's ``stored`` conf is what extracting with the resolved ``conf``
    would store now, group by group. A file written before some keys became tuned constants
    of their extractor stored those keys too: each must equal the constant's value now
    (``former``: the extractor's ``former_layout``), or the file was made with another conf
    (a user's override, or a constant since changed)."""
    if isinstance(stored, dict) and (isinstance(conf, dict) or isinstance(former, dict)):
        conf = conf if isinstance(conf, dict) else {}
        former = former if isinstance(former, dict) else {}
        return set(conf) <= set(stored) and all(
            _same_conf(v, conf.get(k, _ABSENT), former.get(k, _ABSENT))
            for k, v in stored.items())
    if conf is not _ABSENT:
        return stored == conf
    return former is not _ABSENT and stored == former


def _run_attrs(ds, camera, module, conf: dict):
    """(root attributes of the features file, mask, head angles) of extracting ``ds``."""
    kind = camera.kind
    mask = None
    mask_hash = ""
    mask_path = ds.root / MASK_NAME
    if camera_can(kind, "robot_mask") and mask_path.is_file():
        mask = read_mask(mask_path, camera.image_size)
        mask_hash = file_hash(mask_path)
    head = _head_angles(ds) if camera_can(kind, "head_angles") else None
    # head.csv places a perspective frame's points: features of another head.csv are stale
    head_path = ds.root / "head.csv"
    head_hash = file_hash(head_path) if head is not None and head_path.is_file() else ""
    calib_hash = file_hash(ds.calib_path)
    root = os.path.abspath(ds.root)
    inputs = {"dataset": root, "calib": os.path.abspath(ds.calib_path),
              "calib_hash": calib_hash}
    if mask is not None:
        inputs.update(mask=os.path.abspath(mask_path), mask_hash=mask_hash)
    if head_hash:
        inputs.update(head=os.path.abspath(head_path), head_hash=head_hash)
    attrs = root_attrs(SCHEMA, VERSION, conf, inputs)
    # the folder itself, behind any link: a link moved to another recording between runs
    # had a resume drop the first's frames (trial A3-3)
    attrs.update(camera_kind=kind, dataset=os.path.realpath(ds.root), calib_hash=calib_hash,
                 mask_hash=mask_hash, head_hash=head_hash, field=json.dumps(ds.field_record()))
    if hasattr(module, "scanlines_of"):  # an extractor along scan lines records their layout
        attrs["scanlines"] = json.dumps(module.scanlines_of(conf).as_dict())
    return attrs, mask, head


def extract_dataset_frame(ds, index: int, conf: dict) -> dict:
    """The features of frame ``index`` of the dataset ``ds`` (stages.common.dataset.Dataset)
    with the resolved ``conf``, as ``main`` extracts them (the omni mask, the perspective head
    angles of head.csv): for pictures that need one frame without a features file."""
    camera = ds.camera()
    module = kind_module(camera.kind)
    _attrs, mask, head = _run_attrs(ds, camera, module, conf)
    info = _frame_info(camera.kind, mask, head, float(ds.stamps[index]))
    return module.extract_frame(read_image(ds.images[index]), camera, conf, **info)


def conf_of(features: str | Path) -> dict:
    """The user's keys of the conf a features file was extracted with (a stored key the
    kind's preset no longer holds is a tuned constant's: ``_same_conf``), to extract the same
    recording again the same way."""
    with FeaturesFile(features) as ff:
        stored, kind = ff.conf, ff.camera_kind

    def held(stored, preset):
        if not isinstance(stored, dict) or not isinstance(preset, dict):
            return stored
        return {k: held(v, preset[k]) for k, v in stored.items() if k in preset}

    return held(stored, kind_confs(kind)[DEFAULT_PRESET])


def reusable_features(path: str | Path, dataset_dir: str | Path, conf=None) -> str | None:
    """Why the features file ``path`` cannot stand for extracting ``dataset_dir`` now with
    ``conf`` (None: it can): it must exist, be made from the same calibration, mask and conf
    and from the dataset's images, and hold every frame of the dataset (extracted or recorded
    as failed)."""
    path = Path(path)
    if not path.is_file():
        return f"{path} does not exist"
    ds = open_dataset(dataset_dir)
    camera = ds.camera()
    module = kind_module(camera.kind)
    attrs, _mask, _head = _run_attrs(ds, camera, module,
                                     resolve_extract_conf(camera.kind, conf))
    try:
        _check_resumable(path, attrs)
        with FeaturesFile(path) as ff:
            ff.check_of(ds)  # of the dataset's images, as localize will check
            have = set(ff.names) | {f.split(":", 1)[0] for f in ff.failures}
    except FieldlocError as e:
        return str(e).split(";")[0]
    missing = [n for n in ds.names if n not in have]
    if missing:
        return f"{path} lacks {len(missing)} frames of {ds.root} (first: {missing[0]})"
    return None


def main(conf: str | dict | None, dataset_dir: str | Path, output: str | Path | None = None, *,
         overwrite: bool = False, progress: bool = False,
         debug_images: str | Path | None = None, calib: str | Path | None = None) -> Path:
    """Extract every frame of ``dataset_dir`` into ``output`` (default DIR/features.h5) and
    return its path. ``conf``: a preset name of the dataset's camera kind, None, or a dict of
    overrides on the kind's default preset (``resolve_extract_conf``).
    ``debug_images``: a folder that receives one overlay PNG per extracted frame (the kind's
    ``debug_overlay``: for perspective frames the paper's fig. 1): a new or empty folder, or
    one an earlier extract made (its DEBUG_RECORD), whose overlays are replaced only with
    ``overwrite``; never a user's folder with files in it. ``calib``: a calib.yaml of
    the same camera kind to extract with instead of the dataset's own (a calibration learnt
    from a recording); the features record it as their calibration."""
    from tqdm import tqdm

    ds = open_dataset(dataset_dir)
    if calib is not None:
        ds.calib = Path(calib)
        if camera_kind(dataset_dir) != ds.camera().kind:
            raise FieldlocError(f"{calib}: a calibration of another camera kind than"
                                f" {ds.root}'s")
    camera = ds.camera()
    kind = camera.kind
    module = kind_module(kind)
    conf = resolve_extract_conf(kind, conf)
    output = Path(output) if output is not None else ds.root / "features.h5"
    # without --overwrite an existing output is resumed (_check_resumable decides); with it,
    # only a file fieldloc wrote is replaced, never a user's file of the output's name
    check_output(output, {**ds.files(), "calibration": ds.calib_path},
                 overwrite=True if overwrite else None, schema=SCHEMA)
    if debug_images is not None:
        debug_images = _check_debug_folder(Path(debug_images), ds)

    # one run at a time per output: a second run would take the first one's committed
    # frames for an interrupted run's and resume them while they are being written
    leftovers = _Leftovers()
    with output_lock(output), leftovers:
        attrs, mask, head = _run_attrs(ds, camera, module, conf)
        _warn_head_stamps(ds, head)
        resume = output.exists() and not overwrite
        in_output: set[str] = set()
        stale: set[str] = set()  # frames of the output it no longer may hold
        if resume:
            _check_resumable(output, attrs, same_dataset=True)
            in_output, stale = _stale_frames(output, ds)
        pending = sum(1 for n in ds.names if n not in in_output)
        folder = output.parent if str(output.parent) else Path(".")
        kept = output.stat().st_size if resume else 0  # the old file stays until the commit
        if pending:  # the least the run writes (a file's index), refused before any frame
            check_disk(f"extract into {output}", folder, file_bytes({}, pending) + kept)
        parts = FrameParts(output, attrs)
        if overwrite:
            parts.discard("--overwrite extracts every frame again")
        resumed = parts.open()
        leftovers.parts = parts
        todo = [(p, n, s) for p, n, s in zip(ds.images, ds.names, ds.stamps)
                if n not in in_output and not parts.has(n)]
        log.info("extract %s (%s camera, %d frames) -> %s; conf %s", ds.root, kind,
                 len(ds.images), output, json.dumps(conf, sort_keys=True))
        if resume and not todo and not resumed and not stale:
            parts.remove()
            log.info("extract: all %d frames of %s are already in %s", len(in_output), ds.root,
                     output)
            return output

        if debug_images is not None:
            # an overlay of a frame still to do that is newer than the parts folder was drawn
            # by the interrupted run this one resumes (its frame not yet committed): drawn again
            clash = [] if overwrite else [
                png for _i, n, _s in todo if (png := debug_images / f"{n}.png").exists()
                and png.stat().st_mtime_ns < parts.began_ns]
            if clash:
                raise FieldlocError(f"{clash[0]} exists (use --overwrite to replace it)")
            overlays = _DebugOverlays(debug_images, ds, [f"{n}.png" for _i, n, _s in todo])
            leftovers.debug_folder = None if debug_images.exists() else debug_images
            with writing(debug_images):
                debug_images.mkdir(parents=True, exist_ok=True)
        done = failed = 0
        with opencv_single_threaded():  # small calls: resources' doc
            try:
                for path, name, stamp in tqdm(todo, desc="extract", unit="frame",
                                              disable=not progress):
                    try:
                        image, identity = read_frame(path)
                        arrays = module.extract_frame(image, camera, conf,
                                                      **_frame_info(kind, mask, head, float(stamp)))
                    except FieldlocError as e:
                        log.warning("frame %s skipped: %s", name, e)
                        parts.add_failure(name, str(e))
                        failed += 1
                        continue
                    if not done:  # the first frame's columns: the least the file takes,
                        # refused before anything is kept (the parts folder goes, as empty;
                        # frames an interrupted run finished stay: the full disk's line)
                        check_disk(f"extract into {output}", folder, kept + file_bytes(
                            frame_columns(arrays), pending),
                            target=output if parts.frame_names else None)
                    if debug_images is not None:  # before the frame is committed: a
                        # committed frame, which a resumed run skips, has its overlay
                        overlays.draw(f"{name}.png", module.debug_overlay(image, arrays))
                    parts.add_frame(name, float(stamp), arrays, identity)
                    done += 1
            finally:  # Ctrl-C or an error: the finished frames are kept for the next run
                parts.flush()
                if debug_images is not None:
                    overlays.record()
        good = len(in_output) + len(parts.frame_names)
        if good == 0:
            first = next(iter(sorted(parts.failures.items())), None)
            n_failed = len(parts.failures)
            parts.remove()
            raise FieldlocError(
                f"no frame of {ds.root} could be extracted ({n_failed} of {len(ds.images)} failed"
                + (f"; first: {first[0]}: {first[1]}" if first else "") + ")")
        # the file the frames make, before it is built: a disk without that room is the full
        # disk's line naming it (the finished frames stay in the parts, for a rerun)
        check_disk(f"extract into {output}", folder, parts.bytes_needed() + kept, target=output)
        with write_features(output, attrs, resume=resume and not stale) as writer:
            if resume and stale:  # the file again, without its stale frames
                _copy_frames(output, writer, in_output, set(ds.names))
            parts.merge_into(writer)
        parts.remove()
        log.info("extract: %d frames extracted, %d already done (%d of them by an interrupted run),"
                 " %d failed -> %s", done, len(in_output) + resumed, resumed, failed, output)
        return output


def _check_debug_folder(folder: Path, ds) -> Path:
    """The ``debug_images`` folder, refused before any work: a file, a folder holding a frame
    of the dataset, one that cannot be made or written into, or a folder with files in it
    that extract did not make (no DEBUG_RECORD naming it: a user's folder, whose pictures an
    overlay of the same name would replace).
    Overlays already in a folder extract made are replaced only with ``overwrite`` (``main``
    checks that once it knows the frames to draw)."""
    if folder.exists() and not folder.is_dir():
        raise FieldlocError(f"--debug-images {folder}: it is a file, not a folder")
    if folder.is_dir():
        for name, img in zip(ds.names, ds.images):  # never written over a frame of the dataset
            check_output(folder / f"{name}.png", {"dataset image": img}, overwrite=None)
    check_output(folder, None, overwrite=None, kind="folder")  # writable, or refused now
    if folder.is_dir() and any(folder.iterdir()) and not written_by(folder, DEBUG_RECORD,
                                                                     GENERATOR):
        record = ("its " + DEBUG_RECORD + " is not extract's"  # a user's file of that name
                  if (folder / DEBUG_RECORD).exists() else "no " + DEBUG_RECORD)
        raise FieldlocError(f"--debug-images {folder} holds files extract did not write"
                            f" ({record}); they are never replaced, --overwrite or not:"
                            " choose a new or empty folder")
    return folder


class _DebugOverlays:
    """The overlays a run draws into its --debug-images ``folder``, and their record
    (DEBUG_RECORD's WRITTEN_FILES table).

    Before any work, each overlay the run will draw again (``names``) that is there must be
    as the table lists it (``refuse_edited``: an overlay edited by hand, even by an editor
    that keeps the PNG text chunks holding fieldloc's mark, or a user's picture saved under
    a frame's name, is never replaced); a record without a table (an older extract's, or a
    damaged one) refuses the folder. The first ``draw`` takes those overlays out of the
    table, and ``record`` (at the end of the run, however it ends but a SIGKILL) puts every overlay
    drawn back in with its new size and hash. So an overlay the table does not list while
    its name is there was drawn by a run killed before it could record it: that one is
    judged by its mark (``fieldloc_wrote``), so that a killed run's overlays are redrawn, not
    refused forever."""

    def __init__(self, folder: Path, ds, names: list[str]):
        self.folder, self.names, self.drawn = folder, names, []
        self.head = {"generator": GENERATOR, "dataset": str(real_path(ds.root))}
        record = folder / DEBUG_RECORD
        self.table = {}
        if written_by(folder, DEBUG_RECORD, GENERATOR):
            from ..common.conf import load_yaml

            self.table = load_yaml(record.read_text()).get(WRITTEN_FILES)
        refuse_edited(folder, self.table, names, record=DEBUG_RECORD, unlisted=fieldloc_wrote)
        if not isinstance(self.table, dict):  # none of ``names`` is there: nothing to vouch
            self.table = {}

    def _write(self, table: dict) -> None:
        text = record_text({**self.head, WRITTEN_FILES: table}, DEBUG_RECORD)
        with atomic_path(self.folder / DEBUG_RECORD, suffix=".yaml") as tmp:
            tmp.write_bytes(text.encode())

    def draw(self, name: str, image: np.ndarray) -> None:
        """Write the overlay ``name``; before the first, the record without the overlays the
        run draws again (``names``), so that one a killed run drew is unlisted."""
        if not self.drawn:
            todo = set(self.names)
            self._write({k: v for k, v in self.table.items() if k not in todo})
        self.drawn.append(name)
        _write_debug_image(self.folder / name, image)

    def record(self) -> None:
        """The record with every overlay drawn by this run (a disk too full to take it
        leaves those unlisted, judged by their mark next time: nothing said, the run's own
        error, if any, is the one line)."""
        if not self.drawn:
            return
        with contextlib.suppress(OSError, FieldlocError):
            self._write({**self.table, **written_files(self.folder, self.drawn)})


class _Leftovers:
    """What a run of extract made before its first frame finished (its parts folder, the
    --debug-images folder it made), removed when the run then fails (a refusal, a full disk,
    Ctrl-C): a failed command leaves nothing of its own. A parts folder holding finished
    frames is kept, for the run that resumes them."""

    parts: FrameParts | None = None
    debug_folder: Path | None = None

    def __enter__(self):
        return self

    def __exit__(self, kind, _value, _tb) -> bool:
        parts = self.parts
        if kind is not None and parts is not None and not (parts.frame_names
                                                            or parts.failures):
            parts.remove()
            if self.debug_folder is not None:
                _remove_debug_folder(self.debug_folder)
        return False


def _remove_debug_folder(folder: Path) -> None:
    """Remove the --debug-images ``folder`` a run made and then failed before it finished a
    frame: its record and the overlays it drew; the folder itself only where that empties it."""
    (folder / DEBUG_RECORD).unlink(missing_ok=True)
    for png in folder.glob("*.png"):
        if fieldloc_wrote(png):
            png.unlink(missing_ok=True)
    with contextlib.suppress(OSError):
        folder.rmdir()


def _write_debug_image(path: Path, image: np.ndarray) -> None:
    import cv2

    with atomic_path(path, suffix=".png") as tmp:
        ok, buf = cv2.imencode(".png", image)
        if not ok:
            raise FieldlocError(f"could not encode the debug image {path}")
        tmp.write_bytes(with_mark(buf.tobytes()))
