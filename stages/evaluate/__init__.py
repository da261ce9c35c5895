"""Evaluate a pose track against ground truth: report.json, errors.csv and plots per run, and a
table across runs.

    main(conf, poses, truth, output_dir, *, overwrite=False, field=None) -> Path
    evaluate_poses(columns, truth, conf) -> (FrameErrors, summary dict)
    tabulate([report dirs or report.json files], fmt="text") -> str

A report folder holds:

    report.json          the numbers (schema ``fieldloc.report``, see
                         stages.common.report_file), written last (after
                         the plots): its presence means the report is whole
    errors.csv           one row per frame: matched truth, position and heading error
    truth.tum            the truth for evo (evo_ape tum truth.tum poses.tum)
    plots/error_cdf.png, plots/trajectory.png, plots/error_over_time.png, plots/reliability.png
                         listed in report.json when the conf's ``plots`` is on, and drawn
                         from the report by stages.show.report_plots (``fieldloc evaluate``,
                         stages.pipelines.evaluation, runs both); a report that is written
                         anew removes the plots of the one it replaces

Failures count as failures (infinite error), never as poses; how that enters each number is
written in metrics.py and repeated in every report under ``conventions``.
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path

from stages.common.artifacts import (
    WRITTEN_FILES,
    check_output,
    file_hash,
    refuse_inputs,
    written_files,
)
from stages.common.conf import check_bounds, stage_conf
from stages.common.dataset import open_dataset, read_csv
from stages.common.errors import FieldlocError, check_file, real_path
from stages.common.field import field_file, load_field
from stages.common.poses_file import read_poses
from stages.common.report_file import (
    ERRORS_NAME,
    PLOT_NAMES,
    PLOTS_DIR,
    REPORT_NAME,
    TRUTH_TUM,
    building_report,
    encode_numbers,
    foreign_report_file,
    load_report,
    refuse_edited_report_files,
    report_files,
    report_head,
    write_errors_csv,
    write_report,
)

from .metrics import FrameErrors, frame_errors, start_half_contradicted, summarize
from .report import reliability_table, tabulate

__all__ = ["confs", "main", "evaluate_poses", "tabulate", "reliability_table", "load_report",
           "FrameErrors"]

log = logging.getLogger("fieldloc.evaluate")

confs = {
    "default": {
        # a frame matches the truth row nearest in stamp if it is this close (s)
        "stamp_tolerance": 0.02,
        # position error thresholds (m) for the "within" shares (Schulz et al. 2011, fig. 4)
        "thresholds": [0.1, 0.2, 0.4],
        "plots": True,
        "dpi": 120,
        # score what a frame decides on a point-symmetric field: the pose up to the field's
        # 180 deg turn (metrics.frame_errors; stages.localize.symmetry)
        "up_to_mirror": False,
    },
    # motion capture or truth logged at a lower rate than the camera
    "loose": {
        "stamp_tolerance": 0.05,
        "thresholds": [0.1, 0.2, 0.4],
        "plots": True,
        "dpi": 120,
        "up_to_mirror": False,
    },
    # numbers only (batch comparisons of many runs)
    "numbers": {
        "stamp_tolerance": 0.02,
        "thresholds": [0.1, 0.2, 0.4],
        "plots": False,
        "dpi": 120,
        "up_to_mirror": False,
    },
}

CONVENTIONS = {
    "matching": "each frame is matched to the truth row nearest in stamp within"
    " stamp_tolerance; unmatched frames are counted but take no part in the errors",
    "failures": "a failed frame has infinite position and heading error: it is never 'within',"
    " makes max and mean inf and raises median and p90 (inf when more than half failed);"
    " 'localised' holds the same statistics over matched frames with an accepted pose",
    "denominators": "position_error_m, heading_error_deg and within are over matched frames;"
    " failures and runtime_ms over all frames",
    "heading": "absolute difference wrapped to [0, 180] deg",
    "json": "infinite values are the string \"inf\"; a statistic over no frames is null",
    "acceptance": "position_error_m, heading_error_deg and within count every matched frame"
    " without an accepted pose (failed, or its confidence below the method's acceptance"
    " threshold) as a failure; hypotheses.* judge the top hypothesis (and the best of the"
    " top K) of every frame that has one",
    "mirror": "with up_to_mirror, each frame is scored against the truth or its mirror image"
    " under the field's 180 deg turn (whichever its pose is nearer), accepted and confident"
    " by accepted_up_to_mirror and confidence_up_to_mirror",
    "calibration": "over matched frames with a hypothesis: correct = top hypothesis within"
    " calibration.threshold_m of the truth; reliability bins the confidence in tenths;"
    " auroc = P(confidence of a correct frame > that of a wrong one), ties half",
}


# the ranges of the list-valued keys (common.conf.check_bounds): a share "within" is one
# column of the tables; a threshold beyond the diagonal of any field holds every frame
MAX_THRESHOLDS = 20
MAX_THRESHOLD_M = 100.0
BOUNDS = {"thresholds": ((0,), MAX_THRESHOLD_M, (1, MAX_THRESHOLDS))}


def report_dirs(poses: list[Path], output: Path | None) -> list[Path]:
    """Where each poses file's report goes: ``output`` for one file; ``output/<stem>`` for
    several (parent folder names prefixed where stems repeat); without ``output``,
    ``<poses folder>/<stem>-eval`` beside each poses file. With several, every poses file
    is checked to be there and ``output`` (the folder of their folders) to be no
    recording's, before any report is written."""
    if len(poses) > 1:
        if output is not None:
            check_output(output, None, overwrite=None, kind="folder")
        for p in poses:
            check_file(p, "file")
    if output is None:
        return [p.parent / f"{p.stem}-eval" for p in poses]
    if len(poses) == 1:
        return [output]
    names = [p.stem for p in poses]
    if len(set(names)) < len(names):
        names = [f"{real_path(p).parent.name}-{p.stem}" if names.count(p.stem) > 1 else p.stem
                 for p in poses]
    if len(set(names)) < len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise FieldlocError(
            f"two poses files would share the report folder {output / dup}; evaluate them"
            " with separate -o folders"
        )
    return [output / n for n in names]


def check_conf(conf: dict) -> dict:
    """A resolved evaluate conf, checked (FieldlocError, one line naming the key), with its
    thresholds sorted: also what a batch SPEC's ``evaluate`` is held to before anything runs."""
    tol = conf["stamp_tolerance"]
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not tol >= 0:
        raise FieldlocError(f"conf 'stamp_tolerance' must be a number >= 0 (s), got {tol!r}")
    th = conf["thresholds"]
    if isinstance(th, (int, float)) and not isinstance(th, bool):
        conf["thresholds"] = th = [th]
    check_bounds(conf, BOUNDS)
    if not isinstance(conf["up_to_mirror"], bool):
        raise FieldlocError(f"conf 'up_to_mirror' must be true or false, got"
                            f" {str(conf['up_to_mirror'])[:40]!r}")
    conf["thresholds"] = sorted(float(t) for t in th)
    conf["stamp_tolerance"] = float(tol)
    return conf


def _resolve(conf) -> dict:
    return check_conf(stage_conf(confs, conf))


def evaluate_poses(columns: dict, truth: dict, conf=None) -> tuple[FrameErrors, dict]:
    """Per-frame errors and the summary numbers of a pose track (columns as from
    ``read_poses``) against truth columns (stamp, x, y, theta), without touching the disk."""
    conf = _resolve(conf)
    fe = frame_errors(columns, truth, conf["stamp_tolerance"],
                      up_to_mirror=conf["up_to_mirror"])
    return fe, summarize(fe, conf["thresholds"])


def _truth_path(truth, attrs: dict, poses: Path) -> Path:
    if truth is None:
        ds = attrs.get("dataset") or ""
        if not ds:
            raise FieldlocError(
                f"no truth given and {poses} does not name its dataset: pass --truth TRUTH.csv"
            )
        truth = Path(ds)
        if not (truth.exists() or truth.is_symlink()):  # moved or deleted since the run
            raise FieldlocError(f"the poses' dataset {ds[:200]} (recorded in the poses file)"
                                " is not there: pass --truth")
    truth = Path(truth)
    if truth.is_dir():
        truth = truth / "truth.csv"
    return truth


def _truth_of_another_recording(attrs: dict, truth: Path) -> str | None:
    """Why ``truth`` looks like another recording's than the poses' (trial K229: the errors
    alone do not show it), or None: the field its dataset records (simulation.yaml) is not
    the poses' (their map's); or the dataset the poses record is still there with a truth.csv
    of other contents than ``truth`` (a copy of the dataset elsewhere is the same truth; a
    moved dataset leaves nothing to compare)."""
    ours = attrs.get("field")
    try:
        recorded = open_dataset(truth.parent, need_images=False).field_record().get("name")
    except FieldlocError:  # truth.csv outside a dataset folder: no field recorded
        recorded = None
    if ours and recorded and recorded != ours:
        return f"of a dataset recorded on field '{recorded}', not the poses' '{ours}'"
    own = Path(attrs.get("dataset") or "") / "truth.csv"
    try:
        if (attrs.get("dataset") and own.is_file() and not own.samefile(truth)
                and own.read_bytes() != truth.read_bytes()):
            return f"not the truth of the dataset the poses were made from ({own.parent})"
    except OSError:  # unreadable either way: the scoring below says so, or has it already
        return None
    return None


def main(conf: str | dict | None, poses, truth, output_dir, *, overwrite: bool = False,
         field=None, progress: bool = False, draw=None) -> Path:
    """Evaluate ``poses`` (poses.h5) against ``truth`` (truth.csv, or a dataset folder holding
    it; None: the dataset the poses file names) into the report folder ``output_dir``.

    ``conf``: a preset name, a dict of overrides of "default", or None. ``field``: the field
    (name or YAML path) to draw trajectories on, instead of the poses file's ``field``
    (checked here, drawn by stages.show.report_plots).
    An existing report of the same inputs and conf is kept as it is; one of other inputs is
    replaced only with ``overwrite``, and only a report fieldloc wrote: a folder holding a
    report.json, errors.csv, truth.tum or plot that is not fieldloc's is refused
    (stages.common.report_file.foreign_report_file). ``draw``: called as ``draw(report,
    folder)`` (the report as report.json will hold it) to draw the plots the report lists,
    before report.json is written (stages.pipelines.evaluation passes the plots' drawing), so
    that a run stopped at any moment leaves no report.json without its plots. Returns the
    report folder."""
    conf = _resolve(conf)
    poses = Path(poses)
    columns, attrs = read_poses(poses)
    missing = [c for c in ("stamp", "x", "y", "theta", "failed") if c not in columns]
    if missing:
        raise FieldlocError(f"{poses}: poses file lacks column(s) {', '.join(missing)}")
    truth = _truth_path(truth, attrs, poses)
    out = Path(output_dir)
    given = {"poses": poses, "truth": truth, "field": field_file(field),
             "poses.tum": poses.with_suffix(".tum")}
    refuse_inputs(out, given)  # files are written into it; it is not replaced as a whole
    check_output(out, None, overwrite=None, kind="folder")
    for written in (REPORT_NAME, ERRORS_NAME, *(f"{PLOTS_DIR}/{n}" for n in PLOT_NAMES)):
        refuse_inputs(out / written, given)
    foreign = foreign_report_file(out)
    if foreign is not None:
        raise FieldlocError(f"{foreign} is not part of a report written by fieldloc evaluate:"
                            " it is never replaced, --overwrite or not; choose another output"
                            " folder")
    truth_cols = read_csv(truth, "truth")
    inputs = {"poses": file_hash(poses), "truth": file_hash(truth)}
    report_file = out / REPORT_NAME
    if report_file.exists() and not overwrite:
        try:
            old = load_report(report_file, raw=True)
        except FieldlocError:
            old = {}
        if (old.get("inputs") == inputs and old.get("evaluate_conf") == conf
                and old.get("field_override") == (str(field) if field else None)):
            log.info("%s is up to date", report_file)
            return out
        raise FieldlocError(
            f"{out} already holds a report of other inputs or settings; pass --overwrite"
            " (overwrite=True) to replace it or choose another output folder"
        )

    if report_file.exists():  # replaced (--overwrite): only files still as evaluate wrote them
        refuse_edited_report_files(out)
    if (out / PLOTS_DIR).is_dir():  # a read-only plots/ is kept as it is: refused up front
        check_output(out / PLOTS_DIR, None, overwrite=None, kind="folder")
    if field:
        load_field(field)  # the plots' field: a user's error is refused before writing
    fe = frame_errors(columns, truth_cols, conf["stamp_tolerance"],
                      up_to_mirror=conf["up_to_mirror"])
    summary = summarize(fe, conf["thresholds"])
    log.info("%s: %d of %d frames matched to truth within %g s, %d failed", poses,
             summary["matched"], summary["frames"], conf["stamp_tolerance"],
             summary["failures"])
    if summary["unmatched"]:
        log.warning("%s: %d of %d frames have no truth stamp within %g s and are not scored",
                    poses, summary["unmatched"], summary["frames"], conf["stamp_tolerance"])
    why = start_half_contradicted(fe, attrs, max(conf["thresholds"], default=0.4))
    if why:
        log.warning("%s: %s", poses, why)
    other = _truth_of_another_recording(attrs, truth)
    if other:
        log.warning("%s: scored against %s, %s: is it this run's truth?", poses, truth, other)

    from .export import write_truth_tum  # truth.tum: evo_ape tum truth.tum poses.tum

    # the whole report is written beside the folder and then takes its place: a run that
    # fails (a full disk) leaves the old report as it was and no part of the new one
    with building_report(out) as folder:
        write_errors_csv(folder / ERRORS_NAME, fe)
        write_truth_tum(folder / TRUTH_TUM, truth_cols)
        report = {
            **report_head(),
            "run": out.name,
            "method": attrs.get("method", ""),
            "field": str(field) if field else attrs.get("field", ""),
            "dataset": attrs.get("dataset", ""),
            "poses": os.path.abspath(poses),
            "truth": os.path.abspath(truth),
            "inputs": inputs,
            "conf": attrs.get("conf", {}),
            "evaluate_conf": conf,
            "field_override": str(field) if field else None,
            "conventions": CONVENTIONS,
            **summary,
            "files": {"errors": ERRORS_NAME,
                      "plots": [f"{PLOTS_DIR}/{n}" for n in PLOT_NAMES] if conf["plots"] else []},
        }
        if draw is not None and report["files"]["plots"]:
            draw(encode_numbers(report), folder)
        # what --overwrite may replace
        report[WRITTEN_FILES] = written_files(folder, report_files())
        write_report(folder / REPORT_NAME, report)
    pos = summary["position_error_m"]
    log.info("%s: median position error %s m, within %s", out, _short(pos["median"]),
             summary["within"])
    return out


def _short(v: float) -> str:
    return "inf" if math.isinf(v) else ("-" if math.isnan(v) else f"{v:.3f}")
