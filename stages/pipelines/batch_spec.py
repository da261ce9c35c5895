"""The SPEC of ``fieldloc batch``: which datasets, which map, which methods, which runs. Read
and checked at once (``read_spec``), before anything runs: a key it does not know, a value of
the wrong kind, a preset or conf key the stage does not have is one line naming the file and
the place (``methods[2].conf``), never a traceback.

    field: msl-2015            # the map of datasets naming none: built into RESULTS/maps/
    # map: maps/msl-2015.map.h5   (or a map you have; not both)
    build_map: {resolution: 0.1}   # optional: build-map conf of the maps built
    datasets:
      - path: recordings/lab-1         # a dataset folder (named by its folder)
      - glob: recordings/hall-*        # every folder matching, sorted (but RESULTS)
      - name: omni-clean               # rendered into RESULTS/datasets/, rebuilt from this
        simulate: {preset: omni-clean, field: msl-2015, frames: 60, seed: 1}
      - name: minho-lab                # a recording whose calibration is made elsewhere
        path: ../shared/realdata/minho-lab
        calib: {from_minho: ../shared/realdata/minho-lab}   # or a calib.yaml
        field: minho-lab.yaml          # its own field (or map:)
    extract: {omni: default}           # optional: extract preset or conf per camera kind
    evaluate: numbers                  # optional: evaluate preset or conf (default numbers)
    templates: {grid: 1.0, seed: 7}    # optional: the template database of every omni dataset
                                       # that gives none (a grid: of the simulated ones only)
    methods:
      - lut                            # a method (its default preset) or <method>-<preset>
      - {method: lut, preset: default, conf: {heading: histogram}, name: lut-histogram}
      - {method: mcl, conf: ["init=uniform"]}     # -c overrides as on the command line
      - templates                      # reads a template database in place of features
      - fit                            # a method not registered (yet): skipped, with a line
      - lut+smooth                     # a method smoothed offline (conf smooth: true)
    runs:                              # default: all, every method on every dataset whose
      - lut, fit x omni-*              # camera it takes; else "METHODS x DATASETS" lines of
      - mcl x persp-*                  # comma-separated name patterns (fnmatch)

Relative paths are relative to the SPEC's folder. A simulated dataset is named by its simulate
options (``name`` optional: ``<preset>-<field>-f<frames>-s<seed>``, plus a hash of further
``conf`` overrides). A dataset's map: its own ``map`` or ``field``, else the field it is
simulated on, else the SPEC's ``map`` or ``field``. Methods come from the registry
(stages.localize.METHODS): a method the registry lacks is skipped with a line, so a SPEC may
list methods that land later. Which camera kinds a method reads is its module's
``camera_kinds`` (every kind when it does not say).

Method templates (a module with ``INPUT = "templates"``) reads a template database (the
SURF template paper; stages.build_templates) in place of features, from the dataset's ``templates``
(else the SPEC's ``templates``, for omni datasets; ``templates: null`` on a dataset declines it):

    templates: path/to/templates.h5    # a database of the user's, read as it is
    templates: {captures: lab/grid, build: default}   # a folder of captures at measured poses
                                       # (frames with a truth.csv), built into RESULTS/templates/
    templates:                         # a simulated dataset: captures rendered for it
      grid: 1.0                        # node spacing (m): simulate's trajectory kind grid
      headings: 1                      # optional: headings per node (the preset's otherwise)
      centre: [0, 0]                   # optional, with half_size: only that square's nodes
      half_size: 2.0
      seed: 7                          # the capture session's (another than the dataset's)
      conf: {scene: {robots: 0}}       # optional: simulate overrides of the capture session
      build: default                   # optional: build-templates preset or conf

A grid's captures are the dataset's robot in its venue: the dataset's simulate conf (camera,
calibration error, conditions) with its calib_seed and world_seed (each its seed when unset),
``conf``'s overrides, the robot placed at the grid's nodes, and the session's own ``seed``
(movers, clutter, noise; the dataset's seed is refused: the captures would hold its session).
The grid is rendered into ``RESULTS/templates/grids/<field>-grid<spacing>-s<seed>-<hash>/``
(hash of its simulate conf and the field's YAML: datasets of one robot in one venue share it),
its database is ``RESULTS/templates/<grid>.<build tag>.templates.h5``, each made once however
many runs read it. A template run of a dataset without templates is skipped with a line.

Runs are named by their key ``<dataset>/<method>-<preset>[-<hash of the overrides>]`` (as hloc
names its outputs), and their outputs go to ``RESULTS/runs/<key>/``.
"""

from __future__ import annotations

import copy
import fnmatch
import glob as globmod
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from .. import evaluate, extract, localize, simulate
from ..common.artifacts import file_hash, text_hash
from ..common.camera import camera_can
from ..common.conf import (
    check_bounds,
    load_yaml,
    parse_overrides,
    read_record,
    resolve_conf,
    stage_conf,
)
from ..common.errors import FieldlocError, check_file, file_problem, link_loop, real_path, shown
from ..common.map_file import MapFile

TOP_KEYS = ("field", "map", "build_map", "datasets", "extract", "evaluate", "templates",
            "methods", "runs")
DATASET_KEYS = ("name", "path", "glob", "simulate", "calib", "field", "map", "extract",
                "templates")
TEMPLATES_KEYS = ("grid", "headings", "centre", "half_size", "seed", "conf", "captures", "build")
# keys of a template grid's simulate conf that are the dataset's robot and venue, or the grid's
GRID_OWN_KEYS = ("camera", "frames", "seed", "calib_seed", "world_seed", "trajectory")
SIMULATE_KEYS = ("preset", "field", "frames", "seed", "conf")
METHOD_KEYS = ("name", "method", "preset", "conf")
# a dataset's or method's name: a folder name and a column of the comparison tables, so plain
# and short enough to read there (NAME_MAX characters)
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]*$")
NAME_MAX = 64


@dataclass
class DatasetSpec:
    name: str
    kind: str  # folder | simulate | calibrated (a folder with its calibration made elsewhere)
    camera: str  # omni | perspective
    dir: Path  # the dataset folder the stages read (a folder of RESULTS for the others)
    source: Path | None = None  # the user's folder (folder, calibrated)
    simulate: dict | None = None  # the resolved simulate conf
    sim_field: str | None = None
    calib: str | dict | None = None  # calibrated: a calib.yaml path or {"from_minho": DIR}
    map: str = ""  # the map file its runs use
    extract: dict = field(default_factory=dict)  # the resolved extract conf
    features: str = ""  # the features file its runs read
    truth: bool = True
    templates: TemplatesSpec | None = None  # the template database of method templates


@dataclass
class TemplatesSpec:
    """A template database a dataset's template runs read: a file of the user's (``file``),
    built from a folder of captures at measured poses (``captures``), or built from a grid of
    captures rendered for the dataset's robot in its venue (``grid``; module doc)."""
    kind: str  # file | captures | grid
    path: str  # the templates.h5 the runs read
    captures: Path | None = None  # the captures folder (grid: rendered into RESULTS)
    build: dict | None = None  # the resolved build-templates conf (captures, grid)
    simulate: dict | None = None  # grid: the resolved simulate conf of the captures
    sim_field: str | None = None


@dataclass
class MethodSpec:
    name: str  # as the tables call it
    method: str
    preset: str
    overrides: dict
    key: str  # <method>-<preset>[-<hash>]
    conf: dict | None = None  # the resolved localize conf (None: not registered)
    cameras: tuple | None = None
    templates: bool = False  # it reads a template database in place of features


@dataclass
class RunSpec:
    dataset: DatasetSpec
    method: MethodSpec

    @property
    def key(self) -> str:
        return f"{self.dataset.name}/{self.method.key}"

    @property
    def dir(self) -> str:
        return f"runs/{self.key}"


@dataclass
class Plan:
    spec: Path
    spec_hash: str
    results: Path
    datasets: list[DatasetSpec]
    methods: list[MethodSpec]
    runs: list[RunSpec]
    maps: dict  # map file -> (field argument, build-map conf); files of the user: absent
    evaluate: dict
    skipped: list[str]
    templates: dict = field(default_factory=dict)  # database path -> TemplatesSpec, each once
    # dataset name -> the features file its runs read, decided once per batch (batch.py)
    features_read: dict = field(default_factory=dict)


def short_hash(value) -> str:
    return text_hash(json.dumps(value, sort_keys=True, default=str)).split(":")[1][:6]


class _Where:
    """Error messages that name the SPEC file and the place in it."""

    def __init__(self, spec: Path):
        self.spec = spec

    def fail(self, where: str, message: str):
        raise FieldlocError(f"{self.spec}: {where + ': ' if where else ''}{message}")

    def file(self, path: Path, where: str, what: str) -> None:
        """Fail unless ``path`` is a regular file: "<what> not found", or why it is none (a
        link loop, a FIFO: not "not found"). ``what`` is left out where ``where`` ends with
        it ("map: map: ..." said it twice)."""
        why = file_problem(path)
        named = where.rsplit(".", 1)[-1] != what
        if why == "not found":
            self.fail(where, f"{what} not found: {path}" if named else f"{path} not found")
        if why:
            self.fail(where, f"{what + ': ' if named else ''}{path} {why}")

    def folder(self, path: Path, where: str, what: str) -> None:
        """Fail unless ``path`` is a folder: "<what> not found", or that it is a link loop."""
        if not path.is_dir():
            self.fail(where, f"{what}: {path} is not a folder (a symbolic link loop)"
                      if link_loop(path) else f"{what} not found: {path}")

    def keys(self, d, where: str, allowed, required=()) -> dict:
        if not isinstance(d, dict):
            self.fail(where, f"expected a mapping of {', '.join(allowed)}, got {shown(d)}")
        unknown = [k for k in d if k not in allowed]
        if unknown:
            self.fail(where, f"unknown key {shown(unknown[0])} (known: {', '.join(allowed)})")
        for k in required:
            if k not in d:
                self.fail(where, f"missing key '{k}'")
        return d

    def text(self, v, where: str) -> str:
        if not isinstance(v, str) or not v.strip():
            self.fail(where, f"expected a text, got {shown(v)}")
        return v.strip()

    def overrides(self, v, where: str) -> dict:
        """A conf's overrides: a mapping, or a list of key=value (as ``-c`` takes them)."""
        over = v or {}
        if isinstance(over, list):
            try:
                over = parse_overrides(over, once=True)
            except FieldlocError as e:
                self.fail(where, str(e))
        if not isinstance(over, dict):
            self.fail(where, "expected a mapping or a list of key=value")
        return over


def read_spec(spec_path: str | Path, results: str | Path) -> Plan:
    """The plan of the SPEC at ``spec_path`` for the results folder ``results`` (module doc)."""
    spec_path = Path(spec_path)
    check_file(spec_path, "SPEC")
    try:
        data = load_yaml(read_record(spec_path).decode())
    except OSError as e:
        raise FieldlocError(f"{spec_path}: cannot be read ({e.strerror or e})") from None
    except (yaml.YAMLError, UnicodeDecodeError) as e:
        line = getattr(getattr(e, "problem_mark", None), "line", None)
        where = f" line {line + 1}" if line is not None else ""
        first = str(e).splitlines()[0][:80] if str(e) else type(e).__name__
        raise FieldlocError(f"{spec_path}: not valid YAML ({first}{';' if where else ''}"
                            f"{where})") from None
    w = _Where(spec_path)
    base = real_path(spec_path).parent
    results = Path(results)
    w.keys(data, "", TOP_KEYS, required=("datasets", "methods"))
    if "field" in data and "map" in data:
        w.fail("", "give either 'field' (the map is built) or 'map', not both")
    default_map = _map_source(w, data, "", base)
    build_conf = data.get("build_map")
    try:
        from .. import build_map

        build_conf = stage_conf(build_map.confs, build_conf)
        build_map.check_conf(build_conf)
    except FieldlocError as e:
        w.fail("build_map", str(e))
    extract_default = data.get("extract") or {}
    w.keys(extract_default, "extract", tuple(extract.KINDS))
    for kind, ex in extract_default.items():  # every one named, used by a dataset or not
        try:
            extract.resolve_extract_conf(kind, ex)
        except FieldlocError as e:
            w.fail(f"extract.{kind}", str(e))
    try:
        evaluate_conf = evaluate.check_conf(stage_conf(evaluate.confs, data.get("evaluate"),
                                                       default="numbers"))
    except FieldlocError as e:
        w.fail("evaluate", str(e))
    maps: dict = {}
    templates: dict = {}
    datasets = _datasets(w, data["datasets"], base, results, default_map, build_conf,
                         extract_default, maps, data.get("templates"), templates)
    skipped: list[str] = []
    methods = _methods(w, data["methods"], skipped)
    runs = _runs(w, data.get("runs", "all"), datasets, methods, skipped)
    return Plan(spec=real_path(spec_path), spec_hash=file_hash(spec_path), results=results,
                datasets=datasets, methods=methods, runs=runs, maps=maps,
                evaluate=evaluate_conf, skipped=skipped, templates=templates)


# ---------------------------------------------------------------------------- datasets


def _path(base: Path, v: str) -> Path:
    p = Path(v).expanduser()
    return p if p.is_absolute() else base / p


def _field_arg(base: Path, v: str) -> str:
    """A field preset name as it is, a YAML file as its absolute path."""
    p = _path(base, v)
    return str(p) if p.suffix.lower() in (".yaml", ".yml") or p.exists() else v


def _map_source(w: _Where, d: dict, where: str, base: Path):
    """("map", path) or ("field", argument) of an entry, or None."""
    if "map" in d:
        p = _path(base, w.text(d["map"], f"{where}map".lstrip(".")))
        w.file(p, f"{where}map".lstrip("."), "map")
        try:  # a map's head read (no table): a calib.yaml or poses file is refused here
            with MapFile(p):
                pass
        except FieldlocError as e:
            w.fail(f"{where}map".lstrip("."), str(e))
        return ("map", p)
    if "field" in d:
        arg = _field_arg(base, w.text(d["field"], f"{where}field".lstrip(".")))
        from ..common.field import load_field

        try:  # read now, whether a dataset uses it or not (trial P5: a SPEC's unused field)
            load_field(arg)
        except FieldlocError as e:
            w.fail(f"{where}field".lstrip("."), str(e))
        return ("field", arg)
    return None


def _map_scanlines(source, build_conf: dict) -> dict:
    """The scan lines (robot_radius, max_range, spiral_end_radius) of a map source's map: a
    map file's own, a field's map built with ``build_conf``."""
    from .. import build_map

    kind, value = source
    if kind == "map":
        with MapFile(value) as mf:
            return mf.scanlines.as_dict()
    return build_map.scanlines_of(build_conf).as_dict()


def _check_scanlines(w: _Where, where: str, extract_conf: dict, map_lines: dict) -> None:
    """An omni dataset's extract conf walks the scan lines its map was built with, or the SPEC
    is refused before anything runs (trial N7: a build_map robot_radius of 0.3 failed every
    run at localize, extract's being 0.25)."""
    mine = extract_conf.get("scanlines") or {}
    for k, v in mine.items():
        if k in map_lines and abs(float(v) - float(map_lines[k])) > 1e-6:
            w.fail(f"{where}.extract", f"its scan lines have {k} = {float(v):g}, the map's"
                   f" {float(map_lines[k]):g}: give the SPEC 'extract: {{omni: {{scanlines: {{{k}:"
                   f" {float(map_lines[k]):g}}}}}}}' (or the dataset its own), or build the map"
                   f" with {float(v):g}")


def _map_for(w: _Where, source, where: str, results: Path, build_conf: dict, maps: dict) -> str:
    """The map file of a map source; a field's map is planned under RESULTS/maps/."""
    kind, value = source
    if kind == "map":
        return str(real_path(value))
    from ..common.field import load_field

    try:
        fm = load_field(value)
    except FieldlocError as e:
        w.fail(where, str(e))
    from .. import build_map

    try:  # a grid of more cells than a map holds: refused now, not when its run builds it
        build_map.check_size(fm, build_conf)
    except FieldlocError as e:
        w.fail("build_map", str(e))
    plain = not Path(str(value)).suffix and build_conf == build_map.confs["default"]
    name = fm.name if plain else f"{fm.name}-{short_hash([fm.spec_text, build_conf])}"
    path = str(real_path(results / "maps" / f"{name}.map.h5"))
    maps[path] = (value, build_conf)
    return path


def _within(inner: Path, outer: Path) -> bool:
    return Path(os.path.realpath(inner)).is_relative_to(os.path.realpath(outer))


def _datasets(w, entries, base, results, default_map, build_conf, extract_default, maps,
              templates_default, templates):
    if not isinstance(entries, list) or not entries:
        w.fail("datasets", "expected a list of datasets")
    out: list[DatasetSpec] = []
    for i, d in enumerate(entries):
        where = f"datasets[{i}]"
        if isinstance(d, str):
            d = {"path": d}
        w.keys(d, where, DATASET_KEYS)
        given = [k for k in ("path", "glob", "simulate") if k in d]
        if len(given) != 1:
            w.fail(where, "give one of 'path', 'glob' or 'simulate'")
        if "calib" in d and "path" not in d:
            w.fail(where, "'calib' goes with 'path' (a recording whose calibration is made"
                   " elsewhere)")
        if "glob" in d and "name" in d:
            w.fail(where, "a glob names its datasets by their folders; 'name' goes with"
                   " 'path' or 'simulate'")
        own_map = _map_source(w, d, f"{where}.", base)
        found = []
        if "simulate" in d:
            found.append(_simulated(w, d, where, results, base))
            if own_map is None:
                own_map = ("field", found[0].sim_field)
        elif "glob" in d:
            pattern = str(_path(base, w.text(d["glob"], f"{where}.glob")))
            # RESULTS is never one of its own datasets (a results folder beside the recordings
            # the glob names would otherwise be a dataset holding RESULTS on every rerun)
            folders = sorted(Path(p) for p in _matches(w, pattern, f"{where}.glob")
                             if os.path.isdir(p) and not _within(Path(p), results))
            if not folders:
                w.fail(f"{where}.glob", f"no folder matches {pattern}")
            found += [_folder(w, p, p.name, where, results, None) for p in folders]
        else:
            p = _path(base, w.text(d["path"], f"{where}.path"))
            name = w.text(d["name"], f"{where}.name") if "name" in d else p.name
            found.append(_folder(w, p, name, where, results, d.get("calib"), base))
        source = own_map or default_map
        if source is None:
            w.fail(where, "no map: give the SPEC (or the dataset) a 'map' or a 'field'")
        for ds in found:
            ds.map = _map_for(w, source, f"{where}.field", results, build_conf, maps)
            ex = d.get("extract", extract_default.get(ds.camera))
            try:
                ds.extract = extract.resolve_extract_conf(ds.camera, ex)
            except FieldlocError as e:
                w.fail(f"{where}.extract", str(e))
            tag = ex if isinstance(ex, str) else ("default" if ex is None else
                                                  f"custom-{short_hash(ds.extract)}")
            if "scanlines" in ds.extract:  # walked along scan lines (omni): the map's
                _check_scanlines(w, where, ds.extract, _map_scanlines(source, build_conf))
            ds.features = str(real_path(results / "features" / f"{ds.name}.{tag}.features.h5"))
            if "templates" in d:
                ds.templates = _templates(w, d["templates"], ds, f"{where}.templates", base,
                                          results, templates)
            elif templates_default is not None and camera_can(ds.camera, "ground_image") \
                    and (ds.kind == "simulate" or not _is_grid(templates_default)):
                ds.templates = _templates(w, templates_default, ds, "templates", base, results,
                                          templates)
            out.append(ds)
    _check_names(w, "datasets", "dataset", [ds.name for ds in out],
                 ": give it another 'name'")
    return out


def _check_names(w, where: str, what: str, names: list[str], remedy: str = "") -> None:
    """Dataset or method names: plain (NAME_RE), at most NAME_MAX characters, no two alike."""
    for n in names:
        if not NAME_RE.match(n) or len(n) > NAME_MAX:
            w.fail(where, f"{what} name {shown(n)} is not a plain name (letters, digits,"
                   f" . _ + -, at most {NAME_MAX} characters){remedy}")
        if names.count(n) > 1:
            w.fail(where, f"two {what}s are named {shown(n)}: give one a 'name'")


def _folder(w, path: Path, name: str, where: str, results: Path, calib, base=None):
    from ..common.camera import load_calib

    w.folder(path, f"{where}.path", "dataset folder")
    if calib is None:
        calib_file = path / "calib.yaml"
        if not calib_file.is_file():
            w.fail(where, f"{path} has no calib.yaml (give the dataset a 'calib')")
        camera = load_calib(calib_file).kind
        return DatasetSpec(name=name, kind="folder", camera=camera, dir=real_path(path),
                           source=real_path(path), truth=(path / "truth.csv").is_file())
    if isinstance(calib, dict):
        w.keys(calib, f"{where}.calib", ("from_minho",), required=("from_minho",))
        minho = _path(base, w.text(calib["from_minho"], f"{where}.calib.from_minho"))
        w.folder(minho, f"{where}.calib.from_minho", "folder")
        calib, camera = {"from_minho": str(real_path(minho))}, "omni"
    else:
        c = _path(base, w.text(calib, f"{where}.calib"))
        w.file(c, f"{where}.calib", "calibration")
        camera = load_calib(c).kind
        calib = str(real_path(c))
    return DatasetSpec(name=name, kind="calibrated", camera=camera,
                       dir=real_path(results / "datasets" / name), source=real_path(path),
                       calib=calib, truth=(path / "truth.csv").is_file())


def _simulated(w, d, where, results, base: Path):
    s = w.keys(d["simulate"], f"{where}.simulate", SIMULATE_KEYS, required=("field",))
    preset = w.text(s.get("preset", "default"), f"{where}.simulate.preset")
    if preset not in simulate.confs:
        w.fail(f"{where}.simulate.preset", f"unknown preset '{preset}' (presets:"
               f" {', '.join(sorted(simulate.confs))})")
    over = s.get("conf") or {}
    over = parse_overrides(over) if isinstance(over, list) else copy.deepcopy(over)
    for k in ("frames", "seed"):
        if k in s:
            over[k] = s[k]
    try:
        conf = resolve_conf(simulate.confs, preset, over)
        simulate.check_conf(conf)  # frames, seeds: refused before anything runs
    except FieldlocError as e:
        w.fail(f"{where}.simulate", str(e))
    # a field YAML's path relative to the SPEC's folder, as every path of the SPEC
    field_arg = _field_arg(base, w.text(s["field"], f"{where}.simulate.field"))
    from ..common.field import load_field

    try:
        fm = load_field(field_arg)
    except FieldlocError as e:
        w.fail(f"{where}.simulate.field", str(e))
    extra = {k: v for k, v in over.items() if k not in ("frames", "seed")}
    name = d.get("name") or (f"{preset}-{fm.name}-f{conf['frames']}-s{conf['seed']}"
                             + (f"-{short_hash(extra)}" if extra else ""))
    return DatasetSpec(name=w.text(name, f"{where}.name"), kind="simulate",
                       camera=conf["camera"], dir=real_path(results / "datasets" / name),
                       simulate=conf, sim_field=field_arg)


# ---------------------------------------------------------------------------- templates


# the most paths a dataset glob may match: a batch of a thousand recordings is beyond any
# team's; a glob through a link loop (loop/*/*/... of four links: 4^11 paths) or over the
# whole file system was listed whole for minutes (trial Z3-1)
MAX_GLOB_MATCHES = 1000


# the most folder entries a dataset glob may look at: a glob through a link loop that
# matches nothing (loop/*/.../nothere: 4^13 folders) walked past a minute (trial A3-2)
MAX_GLOB_SCAN = 100_000


def _matches(w: _Where, pattern: str, where: str) -> list[str]:
    """The paths the absolute ``pattern`` matches, as glob.glob gives them (``*``, ``?`` and
    ``[...]`` within a path component; names starting with a dot only where the component
    does; folders it may not read left out), walked one component at a time: at most
    MAX_GLOB_MATCHES paths and MAX_GLOB_SCAN folder entries looked at, else the SPEC is
    refused naming ``where``."""
    parts = Path(pattern).parts
    level, scanned = [parts[0]], 0
    for part in parts[1:]:
        found = []
        for folder in level:
            if not globmod.has_magic(part):
                path = os.path.join(folder, part)
                if os.path.lexists(path):
                    found.append(path)
                continue
            try:
                with os.scandir(folder) as it:
                    for e in it:
                        scanned += 1
                        if scanned > MAX_GLOB_SCAN:
                            w.fail(where, f"{pattern[:80]} looks at more than"
                                   f" {MAX_GLOB_SCAN:,} folder entries")
                        if (fnmatch.fnmatchcase(e.name, part)
                                and (part.startswith(".") or not e.name.startswith("."))):
                            found.append(os.path.join(folder, e.name))
            except OSError:  # no folder, or one it may not read: as glob, nothing there
                continue
        if len(found) > MAX_GLOB_MATCHES:
            w.fail(where, f"{pattern[:80]} matches more than {MAX_GLOB_MATCHES} paths")
        level = found
    return level


def _is_grid(entry) -> bool:
    return isinstance(entry, dict) and "grid" in entry


def _templates(w, entry, ds: DatasetSpec, where: str, base: Path, results: Path,
               planned: dict) -> TemplatesSpec | None:
    """The template database of dataset ``ds`` from its SPEC entry (module doc); databases
    planned alike are one (``planned``: path -> TemplatesSpec)."""
    if entry is None:
        return None  # none for this dataset (a venue's default declined)
    if not camera_can(ds.camera, "ground_image"):
        w.fail(where, f"dataset {ds.name} has a {ds.camera} camera; templates are made from"
               " omni frames (the SURF template paper)")
    if isinstance(entry, str):
        p = _path(base, w.text(entry, where))
        w.file(p, where, "template database")
        spec = TemplatesSpec(kind="file", path=str(real_path(p)))
        return planned.setdefault(spec.path, spec)
    w.keys(entry, where, TEMPLATES_KEYS)
    if ("grid" in entry) == ("captures" in entry):
        w.fail(where, "give 'grid' (captures rendered for the dataset's robot) or 'captures'"
               " (a folder of captures at measured poses), or a templates.h5 path")
    from .. import build_templates

    try:
        build = build_templates.resolve_build_conf(entry.get("build"))
    except FieldlocError as e:
        w.fail(f"{where}.build", str(e))
    b = entry.get("build")
    tag = b if isinstance(b, str) else ("default" if b is None else
                                        f"custom-{short_hash(build)}")
    folder = results / "templates"
    if "captures" in entry:
        extra = [k for k in entry if k not in ("captures", "build")]
        if extra:
            w.fail(where, f"'{extra[0]}' goes with 'grid' (captures rendered), not 'captures'")
        c = _path(base, w.text(entry["captures"], f"{where}.captures"))
        if not (c / "truth.csv").is_file():
            w.fail(f"{where}.captures", f"{c} is not a folder of captures with a truth.csv")
        c = real_path(c)
        name = f"{c.name}-{short_hash(str(c))}"
        spec = TemplatesSpec(kind="captures", captures=c, build=build,
                             path=str(real_path(folder / f"{name}.{tag}.templates.h5")))
        return planned.setdefault(spec.path, spec)
    if ds.kind != "simulate":
        w.fail(where, f"dataset {ds.name} is a recording: a rendered grid is for a simulated"
               " dataset (give a recording 'captures' or a templates.h5 path)")
    conf, name = _grid_conf(w, entry, ds, where)
    spec = TemplatesSpec(kind="grid", captures=real_path(folder / "grids" / name),
                         build=build, simulate=conf, sim_field=ds.sim_field,
                         path=str(real_path(folder / f"{name}.{tag}.templates.h5")))
    return planned.setdefault(spec.path, spec)


def _grid_conf(w, entry: dict, ds: DatasetSpec, where: str) -> tuple[dict, str]:
    """The simulate conf of a dataset's template grid and the grid's name: the dataset's conf
    (its camera, calibration error and calib_seed: the same robot; its world_seed: the same
    venue) with ``conf``'s overrides (the capture session: clutter, lighting), the robot placed
    at the grid's nodes, and the session's own ``seed`` (movers, clutter, noise)."""
    from ..common.field import load_field
    from ..simulate import trajectory

    if "seed" not in entry:
        w.fail(where, "missing key 'seed' (the capture session's: its clutter, movers and"
               " noise)")
    seed = entry["seed"]
    if isinstance(seed, bool) or not isinstance(seed, int):
        w.fail(f"{where}.seed", f"expected a whole number, got {seed!r}")
    if seed == ds.simulate["seed"]:
        w.fail(f"{where}.seed", f"seed {seed} is dataset {ds.name}'s own: the captures would"
               " hold its session's clutter and movers; give them another seed")
    over = w.overrides(entry.get("conf"), f"{where}.conf")
    own = [k for k in over if k in GRID_OWN_KEYS]
    if own:
        w.fail(f"{where}.conf", f"'{own[0]}' is the dataset's robot and venue or the grid's"
               " own (grid, headings, centre, half_size, seed)")
    try:
        conf = resolve_conf({}, ds.simulate, over)
    except FieldlocError as e:
        w.fail(f"{where}.conf", str(e))
    sim = ds.simulate
    conf["calib_seed"] = sim["seed"] if sim.get("calib_seed") is None else sim["calib_seed"]
    conf["world_seed"] = sim["seed"] if sim.get("world_seed") is None else sim["world_seed"]
    conf["seed"] = seed
    traj = conf["trajectory"]
    traj["kind"] = "grid"
    for key, name in (("grid", "grid_spacing"), ("headings", "grid_headings"),
                      ("centre", "grid_centre"), ("half_size", "grid_half_size")):
        if key in entry:
            traj[name] = entry[key]
    fm = load_field(ds.sim_field)
    try:
        simulate.check_conf(conf)  # the overrides and the grid's centre: before anything runs
        conf["frames"] = trajectory.grid_count(fm, traj)  # as simulate counts them
        simulate.check_conf(conf)  # its count too (a 0.1 mm grid: 2e10 captures, X3-4)
    except FieldlocError as e:
        w.fail(where, f"{e} (the grid's captures)")
    name = (f"{fm.name}-grid{traj['grid_spacing']:g}-s{seed}-"
            f"{short_hash([conf, fm.spec_text])}")
    return conf, name


# ---------------------------------------------------------------------------- methods


def _methods(w, entries, skipped) -> list[MethodSpec]:
    if not isinstance(entries, list) or not entries:
        w.fail("methods", "expected a list of methods")
    out: list[MethodSpec] = []
    for i, m in enumerate(entries):
        where = f"methods[{i}]"
        if isinstance(m, str):
            m = _method_of_name(w, m, where)
        w.keys(m, where, METHOD_KEYS, required=("method",))
        method = w.text(m["method"], f"{where}.method")
        preset = w.text(m.get("preset", "default"), f"{where}.preset")
        over = w.overrides(m.get("conf"), f"{where}.conf")
        if "method" in over:
            w.fail(f"{where}.conf", "the method is the entry's 'method', not a conf key")
        key = f"{method}-{preset}" + (f"-{short_hash(over)}" if over else "")
        name = w.text(m.get("name", key), f"{where}.name")
        spec = MethodSpec(name=name, method=method, preset=preset, overrides=over, key=key)
        if method not in localize.available_methods():
            skipped.append(f"method {shown(method)} ({where}): not registered in"
                           f" stages.localize.METHODS (known: {', '.join(localize.METHODS)})")
        else:
            try:
                spec.conf = resolve_conf(localize.confs, localize.preset_name(method, preset),
                                         over)
                # the method's own check of its keys (its BOUNDS and choices; not the files
                # of a dataset), refused before anything runs; a method module without one:
                # its BOUNDS
                module = localize.method_module(method)
                check = getattr(module, "check_conf", None)
                if check is not None:
                    check(spec.conf)
                else:
                    check_bounds(spec.conf, getattr(module, "BOUNDS", {}))
            except FieldlocError as e:
                w.fail(where, str(e))
            spec.cameras = localize.method_camera_kinds(method)
            spec.templates = localize.uses_templates(method)
        out.append(spec)
    _check_names(w, "methods", "method", [m.name for m in out])
    return out


SMOOTHED = "+smooth"  # a method's name with this suffix: the method with conf smooth: true


def _method_of_name(w, text: str, where: str) -> dict:
    """'lut' -> lut's default preset; 'lut-no-fusion' -> that preset of lut (a registered
    method's preset it lacks is an error); 'lut+smooth' -> lut with ``smooth: true`` (the
    whole-recording smoother, stages.localize.smooth); any other name is a method (maybe not
    registered)."""
    text = w.text(text, where)
    if text.endswith(SMOOTHED):  # lut+smooth, lut-grid+smooth: the run smoothed offline
        m = _method_of_name(w, text[:-len(SMOOTHED)], where)
        return {**m, "conf": {"smooth": True}, "name": text}
    for method in localize.available_methods():
        if text.startswith(f"{method}-"):
            return {"method": method, "preset": text[len(method) + 1:], "name": text}
    return {"method": text, "preset": "default", "name": text}


# ---------------------------------------------------------------------------- runs


def _runs(w, runs, datasets, methods, skipped) -> list[RunSpec]:
    if runs == "all" or runs is None:
        lines = ["* x *"]
    elif isinstance(runs, list) and runs and all(isinstance(r, str) for r in runs):
        lines = runs
    else:
        w.fail("runs", "expected 'all' or a list of 'METHODS x DATASETS' lines")
    pairs: list[tuple[DatasetSpec, MethodSpec]] = []
    for i, line in enumerate(lines):
        where = f"runs[{i}]" if runs not in ("all", None) else "runs"
        parts = re.split(r"\s+x\s+", line.strip())
        if len(parts) != 2:
            w.fail(where, f"{shown(line)} is not of the form 'METHODS x DATASETS'")
        mp, dp = ([p.strip() for p in part.split(",") if p.strip()] for part in parts)
        ms = _matching(w, mp, [m.name for m in methods], where, "method")
        ds = _matching(w, dp, [d.name for d in datasets], where, "dataset")
        for d in datasets:
            for m in methods:
                if d.name in ds and m.name in ms and (d, m) not in pairs:
                    pairs.append((d, m))
    out = []
    mismatched, untemplated = [], []
    for d, m in pairs:
        if m.conf is None:
            continue  # not registered: said once in skipped
        if m.cameras is not None and d.camera not in m.cameras:
            mismatched.append(f"{m.name} x {d.name}")
            continue
        if m.templates and d.templates is None:
            untemplated.append(f"{m.name} x {d.name}")
            continue
        out.append(RunSpec(d, m))
    for runs_, why in ((mismatched, "whose method does not read the dataset's camera kind"),
                       (untemplated, "of a template method on a dataset without templates"
                                     " (give it 'templates')")):
        if runs_:
            more = ", ..." if len(runs_) > 6 else ""
            skipped.append(f"{len(runs_)} runs {why}: {', '.join(runs_[:6])}{more}")
    keys = [r.key for r in out]
    for k in keys:
        if keys.count(k) > 1:
            w.fail("methods", f"two method entries run the same conf ({k}); drop one")
    return out


def _matching(w, patterns, names, where, what) -> set[str]:
    out = set()
    for p in patterns:
        hit = [n for n in names if fnmatch.fnmatchcase(n, p)]
        if not hit:
            more = ", ..." if len(names) > 8 else ""
            w.fail(where, f"{shown(p)} names no {what} of the SPEC ({what}s:"
                   f" {', '.join(names[:8])}{more})")
        out.update(hit)
    return out
