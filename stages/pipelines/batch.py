"""``fieldloc batch SPEC.yaml -o RESULTS/``: every method of a SPEC on every dataset, each run
one task of extract (shared by the runs that read the same features), localize and evaluate,
on Dask (dask.distributed), then one comparison.

    main(conf, spec, results, *, overwrite=False, progress=False) -> Path   # RESULTS

A chain of stage mains (simulate, calibrate, build_map, extract, localize, evaluate) and of the
comparison pictures (stages.show.comparison), so it lives here in pipelines (docs/manual.md
"Architecture": a stage may import no other stage, and no stage draws). The SPEC is read by
stages.pipelines.batch_spec; RESULTS holds:

    datasets/<name>/         rendered datasets (simulate), and recordings with a calibration
                             made elsewhere (links to their files, and the calib.yaml made)
    maps/<field>.map.h5      maps built from the SPEC's fields (with their lookup caches)
    features/<dataset>.<extract preset>.features.h5
    templates/grids/<grid>/  template captures rendered for a dataset's robot (batch_spec)
    templates/<grid or captures>.<build tag>.templates.h5   the template databases built
    runs/<dataset>/<method>-<preset>[-<hash>]/   poses.h5, poses.tum, report/ (evaluate's
                             report.json, errors.csv, truth.tum), run.json (written last)
    batch.json               the index of the runs (stages.common.batch_file)
    comparison.csv, comparison.md   methods x datasets (stages.evaluate.report.comparison_table)
    plots/cdf-<dataset>.png, plots/summary.png   (stages.show.comparison)

Resumable: a run whose run.json says it finished from the same inputs (the map, the features or
the template database and the truth by content hash, the dataset's simulate options, the
localize and evaluate confs) is not run again; an interrupted batch leaves every finished run
as it is (every file is written atomically, run.json last), and the next one does only what is
missing. A failed run is recorded with its error (run.json, the summary, the comparison) and
the others go on; it is tried again by the next batch. When every run failed, ``main`` raises
FieldlocError after writing the index (the command exits 1). ``overwrite``: every run again. A
template database built here is reused while it is what build-templates would make now
(``reusable_templates``: its grid rendered from the same options, its captures' calib.yaml,
truth.csv and mask by content hash, the same build conf), else built again (its grid rendered
again first when the grid is not).

Where the runs go (``conf``): ``serial`` runs them one after the other in this process;
otherwise on Dask: ``scheduler`` (an address, ``tcp://host:8786``) is an existing cluster
(``dask scheduler``, ``dask worker``), else a LocalCluster of ``workers`` worker processes (0:
one per core) with one thread each, started and stopped here. The tasks pass only paths and
small records: workers read datasets, maps and features from the shared folder (RESULTS and
the SPEC's paths must be the same paths on every worker), and the table search maps its error
lookup from beside the map (stages.localize.lookup_cache). Results do not depend on where a run
ran: poses and every error figure are the same as with ``serial`` value for value (runtimes
are measurements, and differ).
"""

from __future__ import annotations

import collections
import contextlib
import json
import logging
import math
import os
import shutil
import signal
import threading
import time
import traceback
from pathlib import Path

from ..common import templates as templates_file
from ..common.artifacts import (
    check_output,
    file_hash,
    open_artifact,
    output_lock,
    read_json_attr,
    refuse_inputs,
    text_hash,
)
from ..common.batch_file import RUN_NAME, read_json, write_batch, write_json
from ..common.conf import stage_conf
from ..common.errors import FieldlocError, real_path
from .batch_spec import DatasetSpec, Plan, RunSpec, TemplatesSpec, read_spec

log = logging.getLogger("fieldloc.batch")

confs = {
    "default": {"workers": 0, "scheduler": "", "serial": False},
    "serial": {"workers": 0, "scheduler": "", "serial": True},
}

REPORT_DIR = "report"
MAX_WORKERS_PER_CORE = 4  # --workers beyond this many per core is refused (_check_conf)


def _check_conf(conf: dict) -> dict:
    if conf["workers"] < 0:
        raise FieldlocError(f"conf 'workers' must be >= 0 (0: one per core), got"
                            f" {conf['workers']}")
    most = MAX_WORKERS_PER_CORE * core_count()
    if conf["workers"] > most:
        # each worker process holds a map and its caches (hundreds of MB): a thousand of
        # them would exhaust the memory, and runs that use the CPU gain nothing from them
        raise FieldlocError(f"--workers {conf['workers']} on {core_count()} cores: at most"
                            f" {MAX_WORKERS_PER_CORE} per core ({most})")
    if conf["serial"] and (conf["scheduler"] or conf["workers"]):
        raise FieldlocError("a serial batch takes no scheduler and no workers")
    if conf["scheduler"] and conf["workers"]:
        raise FieldlocError("an existing scheduler brings its own workers: give --workers only"
                            " with a LocalCluster")
    return conf


def core_count() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


# ---------------------------------------------------------------------------- main


def main(conf, spec, results, *, overwrite: bool = False, progress: bool = False,
         report=None) -> Path:
    """Run the SPEC ``spec`` into the folder ``results`` (module doc) and return it.
    ``report``: a callable taking one line for the person at the terminal (what runs where,
    the dashboard link, skipped methods, the summary); default: the log."""
    conf = _check_conf(stage_conf(confs, conf))
    say = report or log.info
    plan = read_spec(spec, results)
    if not plan.runs:  # refused before anything is made: a batch of no run is a SPEC's mistake
        why = "; ".join(plan.skipped) or "its 'runs' pair no method with a dataset"
        raise FieldlocError(f"{plan.spec}: nothing to run: {why}")
    results = _check_results(plan)
    with output_lock(results):  # a second batch into RESULTS refuses (trial V3-1)
        return _run_plan(plan, results, conf, overwrite=overwrite, progress=progress, say=say)


def _run_plan(plan: Plan, results: Path, conf: dict, *, overwrite: bool, progress: bool,
              say) -> Path:
    """``main``'s runs of ``plan`` into ``results`` (checked, locked): those not finished
    before (all with ``overwrite``), then the index and summaries."""
    for line in plan.skipped:
        say(f"skipped: {line}")
    todo, done = [], []
    for run in plan.runs:
        (done if not overwrite and finished(plan, run) else todo).append(run)
    say(f"{len(plan.runs)} runs: {len(done)} finished before, {len(todo)} to do")
    records = {r.key: _record_of(results, r) for r in done}

    def summarise(drawn=frozenset()) -> dict:
        """batch.json, the comparison tables and pictures (the CDFs of the datasets in
        ``drawn`` are a Dask worker's); returns the index."""
        index = _index(plan, records)
        write_batch(results, index)
        from ..common.artifacts import atomic_path
        from ..evaluate.report import comparison_table

        for fmt, name in (("csv", "comparison.csv"), ("markdown", "comparison.md")):
            with atomic_path(results / name, suffix=Path(name).suffix) as tmp:
                tmp.write_text(comparison_table(results, fmt=fmt) + "\n")
        from ..show import comparison

        comparison.main(None, results, overwrite=True, drawn=drawn)
        return index

    if todo and not conf["serial"]:
        index = _execute_dask(plan, todo, conf, progress, say, records, summarise)
    else:
        if todo:
            records.update(_execute_serial(plan, todo, progress, say))
        index = summarise()
    failed = [r for r in index["runs"] if r["status"] != "ok"]
    say(f"{len(index['runs']) - len(failed)} of {len(index['runs'])} runs finished, "
        f"{len(failed)} failed" + ("" if not failed else ":"))
    for r in failed:
        say(f"  {r['key']}: {r['error']}")
    if index["runs"] and len(failed) == len(index["runs"]):
        raise FieldlocError(f"every run failed ({len(failed)} of {len(failed)}; their errors are"
                            f" in {results}/batch.json and each run's run.json)")
    return results


# the folders a batch makes in RESULTS before its index: one stopped while it built its maps
# or templates left only maps/ (trial W3-2: every rerun refused as a folder of other files)
BATCH_FOLDERS = ("runs", "datasets", "features", "maps", "templates")


def _check_results(plan: Plan) -> Path:
    """RESULTS: a new folder, or one an earlier batch wrote; never one holding the SPEC's own
    inputs."""
    results = Path(plan.results)
    inputs = {"the SPEC": plan.spec}
    for ds in plan.datasets:
        if ds.source is not None:
            inputs[f"dataset {ds.name}"] = ds.source
        if isinstance(ds.calib, str):
            inputs[f"calibration of {ds.name}"] = ds.calib
    for t in plan.templates.values():
        if t.kind == "file":
            inputs[f"templates {Path(t.path).name}"] = t.path
        elif t.kind == "captures":
            inputs[f"captures {t.captures.name}"] = t.captures
    inputs["maps"] = sorted({ds.map for ds in plan.datasets} - set(plan.maps))
    refuse_inputs(results, inputs, kind="folder")
    check_output(results, None, overwrite=None, kind="folder")
    from ..common.batch_file import is_batch_folder

    entries = list(results.iterdir()) if results.is_dir() else []
    # runs/, datasets/ or features/ mark a batch's folder; one stopped before them holds its
    # maps/ or templates/ alone (a user's folder of maps/ and notes is no batch's, trial X3-3)
    alone = all(e.is_dir() and e.name in BATCH_FOLDERS for e in entries)
    if entries and not is_batch_folder(results) and not alone \
            and not any((results / d).is_dir() for d in ("runs", "datasets", "features")):
        raise FieldlocError(f"{results} holds other files: batch results go into a new folder"
                            " or one an earlier batch wrote")
    _refuse_foreign_summaries(plan, results)
    _refuse_linked_folders(plan, results)
    results.mkdir(parents=True, exist_ok=True)
    return results


def _refuse_linked_folders(plan: Plan, results: Path) -> None:
    """RESULTS' own folders (runs/, a dataset's and a run's under it, plots/, features/,
    maps/, templates/, its grids/, datasets/) and what batch makes in them are never
    symbolic links: batch writes into them, and through a link it replaced a user's poses.h5
    and pictures (trial Y3-1, Y3-2), features and maps (B3-1), and rendered or rewrote a
    user's dataset (A3-1, B3-2, B3-7) outside RESULTS. The files inside a recording's view
    (datasets/<name>/) are batch's own links to the recording (``_calibrated_view``)."""
    folders = {Path(d) for d in ("plots", *BATCH_FOLDERS)}
    folders |= {Path("datasets"), Path("templates", "grids")}
    for run in plan.runs:
        parts = Path(run.dir).parts  # runs/<dataset>/<method>
        folders |= {Path(*parts[:i]) for i in range(1, len(parts) + 1)}
    for rel in sorted(folders, key=lambda p: len(p.parts)):
        if (results / rel).is_symlink():
            raise FieldlocError(f"{results / rel} is a symbolic link: batch writes only into"
                                " its own folders in RESULTS; remove the link")
    # nor is anything batch makes in them: its features, maps, template databases and grids,
    # and each dataset's folder
    for rel in ("features", "maps", "templates", "templates/grids", "datasets"):
        try:
            with os.scandir(results / rel) as it:
                linked = sorted(e.name for e in it if e.is_symlink())
        except OSError:  # not there yet
            continue
        if linked:
            raise FieldlocError(f"{results / rel / linked[0]} is a symbolic link: batch"
                                " writes only its own files in RESULTS; remove the link")


def _refuse_foreign_summaries(plan: Plan, results: Path) -> None:
    """The index, comparison tables and pictures a batch writes at RESULTS' top are replaced
    only when an earlier batch wrote them (its batch.json vouches for the files beside it,
    stages.common.batch_file.written_by_batch), --overwrite included: never a user's own
    comparison.csv or summary.png."""
    from ..common.batch_file import BATCH_NAME, written_by_batch
    from ..show.comparison import PLOTS_DIR, SUMMARY_NAME

    names = [BATCH_NAME, "comparison.csv", "comparison.md", f"{PLOTS_DIR}/{SUMMARY_NAME}",
             *(f"{PLOTS_DIR}/cdf-{ds.name}.png" for ds in plan.datasets)]
    present = [n for n in names if os.path.lexists(results / n)]
    if present and not written_by_batch(results):
        raise FieldlocError(f"{results / present[0]} exists and no earlier batch wrote it (no"
                            f" '{BATCH_NAME}' index of a batch beside it): batch never replaces"
                            " it, --overwrite or not; choose another RESULTS folder")


# ---------------------------------------------------------------------------- resume


def _hash(path) -> str:
    """Content hash of a file (file_hash, memoised by its inode, size and mtime); "" when it
    does not exist."""
    try:
        return file_hash(path)
    except OSError:
        return ""


def _dataset_identity(ds: DatasetSpec) -> str:
    """What a run's outputs depend on in the dataset beyond its files' hashes: how it is made."""
    if ds.kind == "simulate":
        return text_hash(json.dumps([ds.simulate, ds.sim_field], sort_keys=True))
    if ds.kind == "calibrated":
        return text_hash(json.dumps([str(ds.source), ds.calib], sort_keys=True))
    return str(ds.dir)


def run_inputs(plan: Plan, run: RunSpec) -> dict:
    """What a finished run was made from, as recorded in its run.json: a template method's
    template database in place of the features."""
    ds = run.dataset
    source = ({"templates": _hash(ds.templates.path)} if run.method.templates
              else {"features": _hash(_features_path(ds, plan))})
    return {"dataset": _dataset_identity(ds), "map": _hash(ds.map), **source,
            "truth": _hash(ds.dir / "truth.csv") if ds.truth else "",
            "localize": run.method.conf, "evaluate": plan.evaluate}


def finished(plan: Plan, run: RunSpec) -> bool:
    """Whether the run finished before from the inputs it would read now."""
    path = Path(plan.results) / run.dir / RUN_NAME
    if not path.is_file():
        return False
    try:
        rec = read_json(path, raw=True)  # the inputs as written (a None conf value stays None)
    except FieldlocError:
        return False
    if rec.get("status") != "ok":
        return False
    ds = run.dataset
    if ds.kind == "simulate" and not _simulated_as_asked(ds):
        return False
    if run.method.templates and reusable_templates(ds.templates) is not None:
        return False
    return _same(rec.get("inputs"), run_inputs(plan, run))


def _same(a, b) -> bool:
    """Equal as written to JSON (stages.common.report_file.encode_numbers)."""
    from ..common.report_file import encode_numbers

    return (json.dumps(encode_numbers(a), sort_keys=True, default=str)
            == json.dumps(encode_numbers(b), sort_keys=True, default=str))


def _record_of(results: Path, run: RunSpec) -> dict:
    return read_json(results / run.dir / RUN_NAME)


# ---------------------------------------------------------------------------- tasks
# Module functions: Dask ships them to the workers by reference. Each takes and returns paths
# and small records only.


def prepare_dataset(ds: DatasetSpec) -> str:
    """The dataset folder the stages read: a user's folder as it is; a rendered one simulated
    (again, when it was rendered from other options); a recording with a calibration made
    elsewhere as links to its files beside the calib.yaml made for it."""
    if ds.kind == "folder":
        return str(ds.dir)
    if ds.kind == "simulate":
        if not _simulated_as_asked(ds):
            from .. import simulate

            ds.dir.parent.mkdir(parents=True, exist_ok=True)
            # the features of an earlier rendering of this name, and the frames of an
            # extraction of it that was interrupted (extract would resume from them: it knows
            # the calibration and conf a frame was made with, not the images)
            feats = ds.dir.parent.parent / "features"
            for old in feats.glob(f"{ds.name}.*.features.h5"):
                old.unlink()
            for old in feats.glob(f".{ds.name}.*.features.h5.parts"):
                shutil.rmtree(old)
            simulate.main(ds.simulate, ds.sim_field, ds.dir, overwrite=True)
        return str(ds.dir)
    return _calibrated_view(ds)


def _simulated_as_asked(ds: DatasetSpec) -> bool:
    return _rendered_as_asked(ds.dir, ds.simulate, ds.sim_field)


def _rendered_as_asked(folder: Path, conf: dict, field_arg: str) -> bool:
    """Whether ``folder`` holds a rendering by simulate of ``conf`` on ``field_arg``."""
    import yaml

    from ..common.dataset import read_simulation_record

    try:  # one not read (missing, damaged, too large, an alias bomb) is rendered again
        got = read_simulation_record(folder)
    except (OSError, UnicodeDecodeError, yaml.YAMLError, FieldlocError):
        return False
    from ..common.field import load_field

    want = json.loads(json.dumps(conf))
    return (isinstance(got, dict) and _same(got.get("conf"), want)
            and got.get("field_yaml_hash") == text_hash(load_field(field_arg).spec_text))


def _calibrated_view(ds: DatasetSpec) -> str:
    """RESULTS/datasets/<name>: a link to each file of the recording but calib.yaml, and the
    calib.yaml of the SPEC (copied, or made by calibrate from the team's files)."""
    from .. import calibrate

    out = ds.dir
    out.mkdir(parents=True, exist_ok=True)
    for entry in sorted(ds.source.iterdir()):
        if entry.name == "calib.yaml" or entry.name.startswith("."):
            continue
        link = out / entry.name
        if link.is_symlink() and os.readlink(link) == str(entry):
            continue
        if link.is_symlink() or link.exists():
            link.unlink()
        link.symlink_to(entry)
    calib = out / "calib.yaml"
    if isinstance(ds.calib, dict):
        made = calibrate.from_minho(None, ds.calib["from_minho"], out / ".calib.new.yaml",
                                    overwrite=True)
    else:
        made = out / ".calib.new.yaml"
        shutil.copyfile(ds.calib, made)
    if calib.is_file() and calib.read_bytes() == made.read_bytes():
        made.unlink()  # unchanged: the features stay valid
    else:
        os.replace(made, calib)
    return str(out)


def prepare_map(path: str, field_arg: str, build_conf: dict) -> str:
    """The map built from ``field_arg`` into ``path``, unless it is there, built from the same
    field and conf."""
    from .. import build_map
    from ..common.field import load_field
    from ..common.map_file import MapFile

    p = Path(path)
    fm = load_field(field_arg)
    if p.is_file():
        try:
            with MapFile(p) as mf:
                inputs = read_json_attr(mf.h5, "inputs")
                same = (mf.conf == build_conf and isinstance(inputs, dict)
                        and inputs.get("field_yaml") == text_hash(fm.spec_text))
        except (FieldlocError, ValueError, TypeError, RecursionError):
            same = False  # a damaged map (trial U1-6: inputs an array) is built again
        if same:
            return path
    p.parent.mkdir(parents=True, exist_ok=True)
    build_map.main(build_conf, field_arg, p, overwrite=True)
    return path


def reusable_templates(t: TemplatesSpec) -> str | None:
    """Why the template database of ``t`` cannot be read as it is (None: it can): a file of
    the user's always can; one built here must exist, from the captures as they are (a grid
    rendered from its simulate conf; their calib.yaml, truth.csv and mask by content hash) and
    with the build conf of the SPEC."""
    if t.kind == "file":
        return None
    path = Path(t.path)
    if not path.is_file():
        return f"{path} does not exist"
    if t.kind == "grid" and not _rendered_as_asked(t.captures, t.simulate, t.sim_field):
        return f"{t.captures} is not rendered from the SPEC's grid"
    try:  # a damaged one (attributes of another kind, JSON nested 100k deep) is built again
        with open_artifact(path, templates_file.SCHEMA, templates_file.VERSION) as f:
            conf, inputs = read_json_attr(f, "conf"), read_json_attr(f, "inputs")
    except (FieldlocError, OSError, KeyError, ValueError, TypeError, RecursionError):
        return f"{path} is not a template database"
    want = {"dataset": os.path.abspath(t.captures), "calib_hash": _hash(t.captures / "calib.yaml"),
            "truth_hash": _hash(t.captures / "truth.csv")}
    if (t.captures / "mask.png").is_file():
        want["mask_hash"] = _hash(t.captures / "mask.png")
    if not _same(inputs, want):
        return f"{path} was built from other captures"
    if not _same(conf, t.build):
        return f"{path} was built with another conf"
    return None


def prepare_templates(t: TemplatesSpec) -> str:
    """The template database of ``t``: a file of the user's as it is; one built here reused
    when it is what build-templates would make now (``reusable_templates``), else built, from
    the grid rendered first (again, when it was rendered from other options)."""
    from .. import build_templates

    if reusable_templates(t) is None:
        return t.path
    path = Path(t.path)
    if t.kind == "grid" and not _rendered_as_asked(t.captures, t.simulate, t.sim_field):
        from .. import simulate

        t.captures.parent.mkdir(parents=True, exist_ok=True)
        for old in path.parent.glob(f"{t.captures.name}.*.templates.h5"):
            old.unlink()  # built from an earlier rendering of this grid
        simulate.main(t.simulate, t.sim_field, t.captures, overwrite=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    build_templates.main(t.build, t.captures, path, overwrite=True)
    return t.path


def _features_path(ds: DatasetSpec, plan: Plan | None = None) -> Path:
    """The features a dataset's runs read: the folder's own features.h5 when it is what extract
    would make now with the SPEC's conf, else RESULTS/features/... (planned in the SPEC).
    With ``plan``, decided once per batch (``Plan.features_read``: checking the own file reads
    it and the dataset's records, and a batch never writes it)."""
    if plan is not None:
        if ds.name not in plan.features_read:
            plan.features_read[ds.name] = _features_path(ds)
        return plan.features_read[ds.name]
    if ds.kind == "folder":
        own = ds.dir / "features.h5"
        if own.is_file():
            from .. import extract

            try:
                if extract.reusable_features(own, ds.dir, ds.extract) is None:
                    return own
            except FieldlocError:
                pass
    return Path(ds.features)


def prepare_features(ds: DatasetSpec, dataset_dir: str) -> str:
    """The dataset's features: reused when complete, else extracted (resumed when an earlier
    extraction of the same conf stopped; extracted anew when it cannot be continued)."""
    from .. import extract

    path = _features_path(ds)
    if path.is_file() and extract.reusable_features(path, dataset_dir, ds.extract) is None:
        return str(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        extract.main(ds.extract, dataset_dir, path)
    except FieldlocError:
        if not path.exists():
            raise
        extract.main(ds.extract, dataset_dir, path, overwrite=True)  # ours, from other inputs
    return str(path)


class _Captured(logging.Handler):
    """The warnings of one run, kept for its run.json instead of printed by whichever process
    ran it."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record):
        self.lines.append(f"{record.name}: {record.getMessage()}")


@contextlib.contextmanager
def _captured_logs():
    handler = _Captured()
    loggers = [logging.getLogger(n) for n in ("stages", "fieldloc")]
    saved = [(lg.propagate, lg.level) for lg in loggers]
    for lg in loggers:
        lg.addHandler(handler)
        lg.propagate = False
        lg.setLevel(logging.WARNING)
    try:
        yield handler.lines
    finally:
        for lg, (prop, level) in zip(loggers, saved):
            lg.removeHandler(handler)
            lg.propagate = prop
            lg.setLevel(level)


def do_run(run: RunSpec, results: str, evaluate_conf: dict, inputs_plan: dict,
           dataset_dir: str, map_path: str, source: str) -> dict:
    """One run: localize from ``source`` (the features file, or a template method's template
    database), then evaluate against the dataset's truth (without truth: the poses' frame
    counts and runtimes), then run.json. Never raises: a failure is the record's."""
    from .. import evaluate, localize
    from ..common.poses_file import read_poses
    from . import images_to_poses

    out = Path(results) / run.dir
    t0 = time.perf_counter()
    rec = {"key": run.key, "dataset": run.dataset.name, "method": run.method.name,
           "localize_method": run.method.method, "preset": run.method.preset,
           "overrides": run.method.overrides, "dir": run.dir, "status": "failed", "error": "",
           "report": "", "summary": {}, "seconds": math.nan, "warnings": [],
           "worker": f"{os.uname().nodename}:{os.getpid()}"}
    with _captured_logs() as warnings:
        try:
            out.mkdir(parents=True, exist_ok=True)
            (out / RUN_NAME).unlink(missing_ok=True)
            given = ({"templates": source} if run.method.templates
                     else {"features": source})
            if run.method.templates:
                poses = localize.main(run.method.conf, dataset_dir, map_path, out / "poses.h5",
                                      overwrite=True, **given)
            else:  # as `fieldloc localize --features`: with smooth, two rounds
                poses = images_to_poses.main(run.method.conf, dataset_dir, map_path,
                                             out / "poses.h5", overwrite=True, **given)
            if run.dataset.truth:
                evaluate.main(evaluate_conf, poses, Path(dataset_dir) / "truth.csv",
                              out / REPORT_DIR, overwrite=True)
                rec["report"] = f"{run.dir}/{REPORT_DIR}"
            else:
                rec["summary"] = _summary_without_truth(read_poses(poses)[0])
            rec["status"] = "ok"
        except Exception as e:  # recorded, and the batch goes on
            rec["error"] = one_line(e)
            log.debug("run %s failed:\n%s", run.key, traceback.format_exc())
    rec["warnings"] = warnings
    rec["seconds"] = time.perf_counter() - t0
    # hashed here, where they exist: a Dask batch plans its runs before their datasets are made
    rec["inputs"] = {**inputs_plan, "map": _hash(map_path), _source_key(run): _hash(source),
                     "truth": _hash(Path(dataset_dir) / "truth.csv") if run.dataset.truth
                     else ""}
    write_json(out / RUN_NAME, rec)
    return rec


def _source_key(run: RunSpec) -> str:
    return "templates" if run.method.templates else "features"


def one_line(e: BaseException) -> str:
    """A failure as one line: a FieldlocError's message, otherwise the type and message."""
    text = str(e).strip().splitlines()[0] if str(e).strip() else ""
    return text if isinstance(e, FieldlocError) else f"{type(e).__name__}: {text}"


def _summary_without_truth(cols) -> dict:
    """The figures of a run that has no truth, with evaluate's definitions (its
    ``percentile``): frames, failures, failure_rate, runtime_ms."""
    import numpy as np

    from ..evaluate.metrics import percentile

    failed = np.asarray(cols["failed"], bool)
    rt = np.asarray(cols["runtime"], float)
    rt = rt[np.isfinite(rt)] * 1000.0
    return {"frames": int(len(failed)), "failures": int(failed.sum()),
            "failure_rate": float(failed.mean()) if len(failed) else math.nan,
            "runtime_ms": {"median": percentile(rt, 50),
                           "mean": float(np.mean(rt)) if rt.size else math.nan}}


# ---------------------------------------------------------------------------- execution


def _steps(plan: Plan, todo: list[RunSpec]):
    """The preparation steps the runs need, each once: (datasets by name, maps by path, the
    names of the datasets whose features are read, template databases by path)."""
    datasets = {r.dataset.name: r.dataset for r in todo}
    maps = {r.dataset.map: plan.maps[r.dataset.map] for r in todo
            if r.dataset.map in plan.maps}
    featured = [n for n in datasets if any(r.dataset.name == n and not r.method.templates
                                           for r in todo)]
    templates = {r.dataset.templates.path: r.dataset.templates for r in todo
                 if r.method.templates}
    return datasets, maps, featured, templates


def _inputs_plan(plan: Plan, run: RunSpec) -> dict:
    """What a run's record says of its inputs but the files it reads (hashed by do_run)."""
    i = run_inputs(plan, run)
    for key in ("map", _source_key(run), "truth"):
        i.pop(key)
    return i


def _bar(total: int, progress: bool):
    from tqdm import tqdm

    return tqdm(total=total, desc="batch", unit="run", disable=not progress)


def _execute_serial(plan: Plan, todo, progress, say) -> dict:
    say(f"running {len(todo)} runs one after the other in this process")
    datasets, maps, _featured, _templates = _steps(plan, todo)
    records = {}
    ready_ds: dict[str, str | Exception] = {}
    ready_feat: dict[str, str | Exception] = {}
    ready_map: dict[str, str | Exception] = {}
    ready_tpl: dict[str, str | Exception] = {}
    with _bar(len(todo), progress) as bar:
        for run in todo:
            ds = run.dataset
            try:
                if ds.name not in ready_ds:
                    ready_ds[ds.name] = _attempt(prepare_dataset, ds)
                if ds.map in maps and ds.map not in ready_map:
                    ready_map[ds.map] = _attempt(prepare_map, ds.map, *maps[ds.map])
                d = _ok(ready_ds[ds.name])
                m = _ok(ready_map.get(ds.map, ds.map))
                if run.method.templates:
                    t = ds.templates.path
                    if t not in ready_tpl:
                        ready_tpl[t] = _attempt(prepare_templates, ds.templates)
                    f = _ok(ready_tpl[t])
                else:
                    if ds.name not in ready_feat:
                        ready_feat[ds.name] = _attempt(prepare_features, ds, d)
                    f = _ok(ready_feat[ds.name])
            except Exception as e:
                records[run.key] = _failed_before(plan, run, e)
            else:
                records[run.key] = do_run(run, str(plan.results), plan.evaluate,
                                          _inputs_plan(plan, run), d, m, f)
            bar.update(1)
    return records


def _attempt(fn, *args):
    try:
        return fn(*args)
    except Exception as e:
        return e


def _ok(value):
    if isinstance(value, Exception):
        raise value
    return value


def _failed_before(plan: Plan, run: RunSpec, e: BaseException) -> dict:
    """The record of a run whose dataset, map or features could not be made."""
    rec = {"key": run.key, "dataset": run.dataset.name, "method": run.method.name,
           "localize_method": run.method.method, "preset": run.method.preset,
           "overrides": run.method.overrides, "dir": run.dir, "status": "failed",
           "error": one_line(e), "report": "", "summary": {}, "seconds": math.nan,
           "warnings": [], "inputs": {}}
    out = Path(plan.results) / run.dir
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / RUN_NAME, rec)
    return rec


def _quiet_stop(record: logging.LogRecord) -> bool:
    """A logging filter for the stop of our own LocalCluster, every run's files written:
    the nanny's "Worker process still alive after 4.0 seconds, killing" (a worker slow to
    exit on a loaded machine; nothing of ours is lost) goes to our debug log, not the
    terminal."""
    if record.getMessage().startswith("Worker process still alive after"):
        log.debug("dask: %s", record.getMessage())
        return False
    return True


def _local_worker_setup() -> None:
    """Run in each local worker process as it joins (in its main thread, the one its event
    loop runs in). A Ctrl-C in a terminal goes to the whole process group: the workers ignore
    it, and this process, which gets it too, stops them in order (``_hush_if_interrupted``),
    rather than each dying of it mid-task with its own lines. tqdm's bars there lock with a
    thread lock instead of the multiprocessing lock tqdm makes by default, a semaphore that
    a worker stopped mid-task leaves behind for Python's resource tracker to warn of at exit
    (the workers' bars are never shown, so no process shares them). A stage's warning in a
    worker (extract's "frame skipped") is one line as in the CLI's process, with the same
    prefix (``stderr_handler``): without a handler of its own, Python's last resort printed
    its bare message, a name's line break and escape sequences raw."""
    import threading

    from tqdm import tqdm

    from ..common.one_line import stderr_handler

    root = logging.getLogger()
    if not any(getattr(h, "fieldloc_stderr", False) for h in root.handlers):
        root.addHandler(stderr_handler())

    with contextlib.suppress(ValueError):  # not the main thread: nothing to ignore it in
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    tqdm.set_lock(threading.RLock())


def _hush_if_interrupted(client, done: list):
    """An exit callback, run before the cluster is stopped: after a Ctrl-C or SIGTERM the stop
    says nothing (Dask's lines of closing, of tasks cancelled and of workers killed mid-task,
    here and in the workers) and a second Ctrl-C does not break it off half way (which left a
    cluster for the atexit hook of distributed to trip over with a traceback). ``_unhush``
    undoes it in this process after the stop, except that distributed's loggers stay silent
    (``done`` gets True): the process is ending, and what distributed still closes at exit
    (its atexit hook, a nanny's "closed") must not print after fieldloc's "terminated"."""

    def on_exit(exc_type, exc, tb) -> bool:
        if exc_type is not None and issubclass(exc_type, KeyboardInterrupt) and not done:
            done.append(True)
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            _silence_dask()
            logging.disable(logging.CRITICAL)
            with contextlib.suppress(Exception):  # a worker out of reach is stopped anyway
                client.run(logging.disable, logging.CRITICAL)
        return False

    return on_exit


# above every level distributed logs at: its loggers print nothing
DASK_SILENT = logging.CRITICAL + 1


def _silence_dask() -> None:
    """distributed's loggers print nothing from now on: "distributed" and each of its
    children that exists (a child given its own level, as LocalCluster's ``silence_logs``
    gives the nanny's, would still print its "Nanny at ... closed." at exit)."""
    names = ["distributed"] + [n for n in list(logging.root.manager.loggerDict)
                               if n.startswith("distributed.")]
    for name in names:
        logging.getLogger(name).setLevel(DASK_SILENT)


def _restore_dask_level(level: int, interrupted: list):
    """An exit callback, run after the cluster stopped: distributed's logger back to
    ``level``, unless the batch was interrupted (``_hush_if_interrupted``) or a Ctrl-C or
    SIGTERM came as the cluster was stopping, the runs done. Then its loggers are silenced
    instead: the signal breaks off the stop's wait (distributed's ``sync``), which cancels
    the stop in Dask's event loop thread, and each nanny logs its "Nanny at ... closed." there
    at once, racing this process's unwinding; restored to INFO, the nannies' lines came
    before or after fieldloc's "terminated" line (5 of 8 SIGTERMs 0-0.6 s after the batch's
    last picture; the lines were this process's, of its "IO loop" thread)."""

    def on_exit(exc_type, exc, tb) -> bool:
        if exc_type is not None and issubclass(exc_type, KeyboardInterrupt):
            _silence_dask()
        elif not interrupted:
            logging.getLogger("distributed").setLevel(level)
        return False

    return on_exit


@contextlib.contextmanager
def _interrupts_held():
    """While the cluster and its client are made, a Ctrl-C or SIGTERM waits until they are
    made and in the ExitStack that stops them, and is raised then, once. Raised half way
    (LocalCluster starts in seconds on a loaded machine), it left a cluster half started for
    the atexit hook of distributed to close: its INFO lines and an AssertionError traceback
    after fieldloc's one "terminated" line. Only in the main thread, where Python handles
    signals.

    SIGINT is also blocked meanwhile: the threads made meanwhile (Dask's loop, and those that
    start the worker processes) and the worker processes inherit the block, so a Ctrl-C in a
    terminal, which goes to the whole process group, never reaches a worker still starting up
    (before ``_local_worker_setup`` makes it ignore SIGINT, each died of it with its own
    traceback: 79-109 lines). A Ctrl-C that came meanwhile is pending, and is delivered here
    when unblocked. multiprocessing's resource tracker is started first: starting it unblocks
    SIGINT in the thread that starts it (Dask's loop, had it been started there)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    got: list[int] = []
    old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    for s, handler in old.items():
        if handler not in (signal.SIG_IGN, None):
            signal.signal(s, lambda signum, frame: got.append(signum))
    mask = None
    if hasattr(signal, "pthread_sigmask"):
        from multiprocessing import resource_tracker

        resource_tracker.ensure_running()
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        for s, handler in old.items():
            if handler is not None:
                signal.signal(s, handler)
        if mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # a pending Ctrl-C raises here
        if got:
            signal.raise_signal(got[0])


def _unhush(handler) -> None:
    logging.disable(logging.NOTSET)
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, handler)


def _execute_dask(plan: Plan, todo, conf, progress, say, records: dict, summarise) -> dict:
    """Run ``todo`` on Dask, adding their records to ``records`` (which holds the finished
    runs' before), then ``summarise`` them; returns its index. A dataset's CDF picture
    (show.comparison.draw_dataset_cdf) is drawn by a worker as soon as the dataset's last run
    is done, beside the other runs rather than after them all, and the last ones while this
    process summarises; one a worker could not draw is drawn here."""
    from dask.distributed import Client, LocalCluster, as_completed

    from ..show import comparison

    with contextlib.ExitStack() as stack:
        stack.callback(_unhush, signal.getsignal(signal.SIGINT))  # last, after the stop
        # Dask's own lines (cluster start and stop, its warnings) only when our log shows
        # INFO; distributed sets its logger to INFO, and its records reach our log's handler
        dask_log = logging.getLogger("distributed")
        interrupted: list = []
        stack.push(_restore_dask_level(dask_log.level, interrupted))
        dask_shown = logging.getLogger().isEnabledFor(logging.INFO)
        if not dask_shown:
            dask_log.setLevel(logging.ERROR)
        if conf["scheduler"]:
            with _interrupts_held():
                try:
                    client = stack.enter_context(Client(conf["scheduler"], timeout="10s"))
                except (OSError, TimeoutError) as e:
                    raise FieldlocError(f"cannot reach the Dask scheduler {conf['scheduler']}"
                                        f" ({one_line(e)})") from None
                hush = stack.push(_hush_if_interrupted(client, interrupted))
            where = f"the Dask cluster at {conf['scheduler']}"
        else:
            n = min(conf["workers"] or core_count(), len(todo))  # no idle workers
            nanny_log = logging.getLogger("distributed.nanny")
            stack.callback(nanny_log.removeFilter, _quiet_stop)  # after the cluster stopped
            # the workers' own lines (a run's failure as a "Compute Failed" block with its
            # traceback, "Async instruction ... CancelledError") only where Dask's lines are
            # shown: the batch reports each failed run itself, in one line and its run.json
            worker_logs = logging.WARNING if dask_shown else DASK_SILENT
            with _interrupts_held():
                cluster = stack.enter_context(LocalCluster(
                    n_workers=n, threads_per_worker=1, processes=True,
                    dashboard_address=":0", silence_logs=worker_logs))
                client = stack.enter_context(Client(cluster))
                stack.callback(nanny_log.addFilter, _quiet_stop)  # before it stops
                hush = stack.push(_hush_if_interrupted(client, interrupted))  # first out
                client.register_worker_callbacks(_local_worker_setup)
            where = f"a local Dask cluster of {n} worker processes"
        nw = len(client.scheduler_info().get("workers", {}))
        say(f"running {len(todo)} runs on {where} ({nw} workers)")
        if _has_dashboard() and client.dashboard_link:
            say(f"dashboard: {client.dashboard_link}")
        datasets, maps, featured, templates = _steps(plan, todo)
        f_ds = {n: client.submit(prepare_dataset, ds, key=f"dataset-{n}-{_tag()}", pure=False)
                for n, ds in datasets.items()}
        f_map = {p: client.submit(prepare_map, p, *a, key=f"map-{Path(p).name}-{_tag()}",
                                  pure=False) for p, a in maps.items()}
        f_feat = {n: client.submit(prepare_features, datasets[n], f_ds[n],
                                   key=f"features-{n}-{_tag()}", pure=False)
                  for n in featured}
        f_tpl = {p: client.submit(prepare_templates, t, key=f"templates-{Path(p).name}-{_tag()}",
                                  pure=False) for p, t in templates.items()}
        # A run is submitted only once its inputs are made, with their paths as plain
        # arguments, and only while a worker thread is free, the longest first. Passed as
        # futures, its inputs would pin it to the worker that made them (Dask places a task
        # beside its dependencies), and all its dataset's runs would queue there while
        # another worker idles; submitted all at once, the runs would be spread before their
        # lengths are known.
        needs = {}
        for run in todo:
            ds = run.dataset
            source = f_tpl[ds.templates.path] if run.method.templates else f_feat[ds.name]
            needs[run.key] = (f_ds[ds.name], f_map.get(ds.map, ds.map), source)
        waiting = longest_first(plan, todo)
        running: dict = {}
        left = collections.Counter(r.dataset.name for r in todo)
        pictures = {}
        events = as_completed([*f_ds.values(), *f_map.values(), *f_feat.values(),
                               *f_tpl.values()])

        def finish(run, rec):
            records[run.key] = rec
            bar.update(1)
            name = run.dataset.name
            left[name] -= 1
            if not left[name]:
                runs = [_public(records[r.key]) for r in plan.runs
                        if r.dataset.name == name and r.key in records]
                pictures[name] = client.submit(
                    comparison.draw_dataset_cdf, str(plan.results), name, runs,
                    key=f"cdf-{name}-{_tag()}", pure=False)

        def launch():
            """Submit the waiting runs whose inputs are made, while threads are free."""
            if not waiting:  # all submitted: no need to ask the scheduler for its threads
                return
            free = max(1, sum(client.nthreads().values())) - len(running)
            for run in list(waiting):
                if free <= 0:
                    break
                inputs = needs[run.key]
                futs = [f for f in inputs if not isinstance(f, str)]
                if any(f.status == "pending" for f in futs):
                    continue
                waiting.remove(run)
                failed = [f for f in futs if f.status != "finished"]
                if failed:  # its dataset, map or features could not be made
                    bad = failed[0]
                    e = (bad.exception() if bad.status == "error"
                         else RuntimeError(f"{bad.key}: {bad.status}"))
                    finish(run, _failed_before(plan, run, e))
                    continue
                d, m, f = (x if isinstance(x, str) else x.result() for x in inputs)
                fut = client.submit(do_run, run, str(plan.results), plan.evaluate,
                                    _inputs_plan(plan, run), d, m, f,
                                    key=f"run-{run.key}-{_tag()}", pure=False)
                running[fut] = run
                events.add(fut)
                free -= 1

        with _bar(len(todo), progress) as bar:
            try:
                launch()
                for fut in events:
                    run = running.pop(fut, None)
                    if run is not None:
                        try:
                            rec = fut.result()
                        except Exception as e:  # the worker died, say
                            rec = _failed_before(plan, run, e)
                        finish(run, rec)
                    launch()
                index = summarise(drawn=set(pictures))
                for name, fut in pictures.items():
                    try:
                        fut.result()
                    except Exception as e:  # drawn again, and reported, by this process
                        log.debug("the CDF of %s on a worker failed: %s", name, one_line(e))
                        comparison.draw_dataset_cdf(plan.results, name, index["runs"])
            except KeyboardInterrupt:
                hush(KeyboardInterrupt, None, None)  # before the cancelled tasks' warnings
                client.cancel(list(running) + list(pictures.values()))
                raise
    return index


def longest_first(plan: Plan, todo: list[RunSpec]) -> list[RunSpec]:
    """``todo`` in the order Dask should start them: the longest first, so that the batch
    does not end with one worker on a long run while the others wait (longest-processing-
    time-first scheduling). A run's length is the seconds its run.json recorded when it ran
    before (an overwritten or failed run); runs that never ran come first, in the SPEC's
    order, since nothing says they are short."""

    def seconds(run: RunSpec) -> float:
        try:
            s = float(_record_of(Path(plan.results), run).get("seconds", math.nan))
        except (FieldlocError, TypeError, ValueError):
            return math.inf
        return s if math.isfinite(s) else math.inf

    return sorted(todo, key=seconds, reverse=True)  # stable: equal lengths keep SPEC order


def _tag() -> str:
    return os.urandom(4).hex()


def _has_dashboard() -> bool:
    import importlib.util

    return importlib.util.find_spec("bokeh") is not None


# ---------------------------------------------------------------------------- index


def _index(plan: Plan, records: dict) -> dict:
    results = Path(plan.results)
    return {
        "spec": {"path": str(plan.spec), "hash": plan.spec_hash},
        "datasets": {ds.name: {"dir": str(ds.dir), "camera": ds.camera, "map": ds.map,
                               "features": str(_features_path(ds, plan)), "truth": ds.truth,
                               "templates": ds.templates.path if ds.templates else ""}
                     for ds in plan.datasets},
        "runs": [_public(records[r.key]) for r in plan.runs if r.key in records],
        "skipped": plan.skipped,
        "results": str(real_path(results)),
    }


def _public(rec: dict) -> dict:
    return {k: v for k, v in rec.items() if k != "inputs"}
