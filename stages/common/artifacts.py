"""HDF5 artifacts: atomic writing, common root attributes, schema checks, and a tree listing.

Each artifact schema (map, features, poses, templates) is owned by one module in this package
that builds on these helpers. Writing always goes to a temporary file beside the target that is
renamed over it at the end, so an interrupted run leaves neither a half file under the real name
nor a damaged earlier result.

Temporary parts are named ``.<target name>.fieldloc-<pid>-<random><suffix>``: a run that was
killed (kill -9, power loss) leaves its part behind, and the next run writing the same target
removes the parts whose process no longer runs, with a warning (``remove_stale_parts``). A
finished file gets the mode a plain ``open()`` would give it (0666 less the umask), not the
temporary file's 0600, so teammates can read shared maps.

``check_output`` is the one rule every command applies to what it writes: never one of its own
inputs (with ``--overwrite`` or without), never an existing file without ``--overwrite``, with
it only a file fieldloc wrote (``fieldloc_wrote``), a folder that exists and is writable, and
no folder output that is a recording's (but for the commands that write recordings whole).
It also records, per output, whether the final rename may replace what it then finds there
(``may_replace``): an output that did not exist when a run checked it without ``--overwrite``
is committed without replacing (``commit_file``, ``commit_dir``), so of two runs writing one
output at once the second to finish refuses instead of silently replacing the first one's.
"""

from __future__ import annotations

import contextlib
import contextvars
import datetime as _dt
import errno
import hashlib
import itertools
import json
import logging
import os
import re
import shutil
import stat
import tempfile
from collections.abc import Mapping
from pathlib import Path

import h5py
import numpy as np

from .. import __version__
from .dataset_layout import OWN_FILES
from .errors import DiskFullError, FieldlocError, SchemaError, check_file, link_loop
from .stops import raise_deferred_stop

log = logging.getLogger(__name__)

PART_TAG = "fieldloc"  # temporary parts: .<name>.fieldloc-<pid>-<random><suffix>
# parts of fieldloc versions before the pid tag: .<name>.<8 random characters><suffix>
_LEGACY_PART = r"[a-z0-9_]{8}\.(part|old|png|csv|json|yaml|tum)"


_HASHES: dict[tuple, str] = {}  # file_hash by (file, inode, size, mtime ns, algo)


def file_hash(path: str | Path, algo: str = "sha256") -> str:
    """``algo:`` and the first 16 hex digits of the file's digest. A file hashed before in this
    process, with the same inode, size and modification time (ns), is not read again."""
    st = os.stat(path)
    key = (os.path.realpath(path), st.st_ino, st.st_size, st.st_mtime_ns, algo)
    if key not in _HASHES:
        h = hashlib.new(algo)
        with open(path, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
        _HASHES[key] = f"{algo}:{h.hexdigest()[:16]}"
    return _HASHES[key]


def text_hash(text: str) -> str:
    return "sha256:" + hashlib.sha256(text.encode()).hexdigest()[:16]


def provenance(schema: str, version: int) -> dict:
    """What every artifact says first of itself (HDF5 root attributes, report.json): its schema
    and version, the fieldloc that wrote it, and when."""
    return {
        "schema": schema,
        "schema_version": int(version),
        "fieldloc_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }


def root_attrs(schema: str, version: int, conf: dict | None = None, inputs: dict | None = None):
    """The attributes every HDF5 artifact carries at its root: ``provenance``, and the conf
    and inputs (content hashes) as JSON."""
    return {
        **provenance(schema, version),
        "conf": json.dumps(conf or {}, sort_keys=True, default=_json_default),
        "inputs": json.dumps(inputs or {}, sort_keys=True, default=_json_default),
    }


def as_stored(value):
    """``value`` as an artifact's JSON attributes store it and read it back (tuples become
    lists, mappings dicts, numpy scalars numbers): what a stored conf is compared with."""
    return json.loads(json.dumps(value, default=_json_default))


def _json_default(o):
    if isinstance(o, Mapping):  # a read-only mapping of constants (types.MappingProxyType)
        return dict(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")


def _check_writable(path: Path, kind: str = "file"):
    parent = path.parent if str(path.parent) else Path(".")
    if kind == "folder":  # folders are made with their parents: the nearest existing one counts
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
    if not parent.exists():
        raise FieldlocError(f"cannot write {path}: folder {parent} does not exist")
    if not parent.is_dir():
        raise FieldlocError(f"cannot write {path}: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise FieldlocError(f"cannot write {path}: folder {parent} is not writable")
    if kind == "file" and path.is_dir():
        raise FieldlocError(f"cannot write {path}: it is a folder")
    if path.is_symlink() and not path.exists():  # the commit would find the link, not a file
        leads = ("a symbolic link loop" if link_loop(path) else
                 f"a symbolic link to {str(os.readlink(path))[:60]}, which does not exist")
        raise FieldlocError(f"cannot write {path}: it is {leads}; remove the link or choose"
                            " another output")
    if path.exists() and not path.is_file() and not path.is_dir():
        # a device, a FIFO or a socket: an atomic write would rename a file over it (as root,
        # /dev/full became a CSV), and writing into it is no artifact
        raise FieldlocError(f"cannot write {path}: not a regular file (a device, pipe or"
                            " socket), which fieldloc never replaces")
    if kind == "folder" and path.exists() and not path.is_dir():
        raise FieldlocError(f"cannot write the folder {path}: it is a file")
    if kind == "folder" and path.is_dir() and not os.access(path, os.W_OK | os.X_OK):
        raise FieldlocError(f"cannot write into {path}: the folder is not writable")


def _stat(path: Path) -> os.stat_result | None:
    """The file ``path`` names (symlinks followed), or None where there is none."""
    try:
        return os.stat(path)
    except (OSError, ValueError):
        return None


def _same_path(a_stat: os.stat_result | None, a_real: str, b: Path) -> bool:
    """Whether a path (``a_stat``: its ``_stat``; ``a_real``: its real path) and ``b`` name
    one file: the same file where both exist, none where only one does, the same real path
    where neither does. One stat of ``b`` (a dataset's inputs are its images, thousands of
    them), and its real path only where neither exists."""
    b_stat = _stat(b)
    if a_stat is not None and b_stat is not None:
        return os.path.samestat(a_stat, b_stat)
    if (a_stat is None) != (b_stat is None):
        return False
    return a_real == os.path.realpath(b)


def _inside(inner: Path, outer: Path) -> bool:
    return Path(os.path.realpath(inner)).is_relative_to(os.path.realpath(outer))


# The mark every text file and picture fieldloc writes carries near its start or end (a
# comment line, a PNG text chunk, a PDF's or SVG's creator): how --overwrite tells a file
# fieldloc wrote from a user's file of the same name. The token in brackets is what is looked
# for: prose that says "written by fieldloc" (a note, a log of fieldloc's own refusals) is
# no mark. HDF5 artifacts carry one of HDF5_SCHEMAS instead.
WRITTEN_BY = "[fieldloc-output]"
WRITTEN_MARK = f"written by fieldloc {__version__} {WRITTEN_BY}"
_MARK_SPAN = 8192  # bytes read at each end of a file for the mark (PDF keeps it at the end)
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
# the schemas of the HDF5 artifacts (each owned by its module: map_file, features_file,
# poses_file, templates); another schema, "fieldloc.mine" say, is no artifact of fieldloc's
HDF5_SCHEMAS = ("fieldloc.map", "fieldloc.features", "fieldloc.poses", "fieldloc.templates")


def cannot_read(path: str | Path, e: OSError) -> FieldlocError:
    """The one line for a file that exists but that the system does not let fieldloc read
    (its mode, its folder's): said as such, not as a file that is damaged or not fieldloc's,
    which is what the checks that read it would conclude."""
    reason = "permission denied" if isinstance(e, PermissionError) else (e.strerror or str(e))
    return FieldlocError(f"cannot read {path}: {reason}")


def fieldloc_wrote(path: str | Path) -> bool:
    """Whether the file ``path`` is one fieldloc wrote: an HDF5 file whose root ``schema`` is
    one of HDF5_SCHEMAS, or a file carrying ``WRITTEN_BY`` within its first or last
    ``_MARK_SPAN`` bytes. False for anything it cannot read as a file (a folder, a file gone
    meanwhile); a file it is not allowed to read is FieldlocError (``cannot_read``)."""
    try:
        with open(path, "rb") as f:
            head = f.read(_MARK_SPAN)
            if head.startswith(HDF5_SIGNATURE):
                return _hdf5_schema(path) in HDF5_SCHEMAS
            f.seek(0, os.SEEK_END)
            f.seek(max(f.tell() - _MARK_SPAN, len(head)))
            tail = f.read(_MARK_SPAN)
    except PermissionError as e:
        raise cannot_read(path, e) from None
    except OSError:
        return False
    mark = WRITTEN_BY.encode()
    return mark in head or mark in tail


# the first line of a calib.yaml fieldloc writes, before its WRITTEN_MARK
CALIB_TITLE = "# camera calibration, "


def first_line_says(pattern: str):
    """An ``ours`` test of check_output: a file fieldloc wrote whose first line starts as the
    regular expression ``pattern`` says (what a command writes: --overwrite replaced a
    calib.yaml by a field YAML and back, trial Z2-1, as each was fieldloc's; a team file
    named "# camera calibration, x.json" in a field's first line passed a test of the text
    anywhere in it, trial A2-2)."""
    start = re.compile(pattern.encode())

    def ours(path) -> bool:
        if not fieldloc_wrote(path):
            return False
        with open(path, "rb") as f:
            return start.match(f.readline(_MARK_SPAN)) is not None
    return ours


def _hdf5_schema(path: str | Path) -> str:
    """The root ``schema`` attribute of an HDF5 file ('' if it has none or cannot be read)."""
    try:
        with h5py.File(path, "r") as f:
            v = f.attrs.get("schema", "")
    except (OSError, ValueError, RuntimeError):
        return ""
    return v.decode(errors="replace") if isinstance(v, bytes) else str(v)


# A fieldloc folder's record (simulation.yaml, report.json, import.yaml, debug-images.yaml)
# lists the files fieldloc wrote into the folder under this key, each with its size and
# SHA-256 as written: --overwrite replaces such a file only while it is still as fieldloc
# wrote it (a user's edits, a file saved under its name, are never replaced). The one rule of
# every fieldloc folder (``refuse_edited``): fieldloc replaces only what it can vouch for. A
# record whose table is absent (an older fieldloc's) or damaged (not a mapping) vouches for
# nothing, and a file's own mark does not either: a CSV or YAML edited in a text editor, a
# PNG saved by an image editor that keeps its text chunks, keep the mark (and CSV files carry
# none). The folder is then refused whole, in one line naming it.
WRITTEN_FILES = "written_files"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def written_files(folder: str | Path, names) -> dict[str, str]:
    """``{name: "<size in bytes> <SHA-256 hex>"}`` of the files ``names`` (paths relative to
    ``folder``, with / between parts) that are there: what a folder's record keeps under
    WRITTEN_FILES, made from the files just written (one read of each). One short text per
    file, so that a record of a thousand images stays quick to read."""
    folder = Path(folder)
    out = {}
    for name in names:
        p = folder / name
        if p.is_file() and not p.is_symlink():
            out[name] = file_entry(p)
    return out


def file_entry(path: str | Path) -> str:
    """``"<size in bytes> <SHA-256 hex>"`` of the file ``path``: a record's entry for a file
    fieldloc just wrote (``written_files``; a poses file's of its TUM twin)."""
    return f"{os.stat(path).st_size} {_sha256(Path(path))}"


def as_written(path: str | Path, want) -> bool:
    """Whether the file ``path`` holds what its record entry ``want`` (``file_entry``) says
    was written."""
    size, _, digest = str(want).partition(" ")
    try:
        if os.stat(path).st_size != int(size):
            return False  # cheaper than a hash, and most edits change the size
        return _sha256(path) == digest
    except (OSError, ValueError):
        return False


def edited_file(folder: str | Path, recorded: Mapping, names, unlisted=None) -> Path | None:
    """The first of the files ``names`` (relative to ``folder``) that is there and is not as
    fieldloc wrote it, or None: what --overwrite may not replace in a fieldloc folder. A file
    must still have the size and SHA-256 its record's WRITTEN_FILES table ``recorded`` gives;
    a file the table does not list is not vouched for (returned), unless ``unlisted`` (the
    owner's test of a file that cannot be in the table yet, say an overlay a killed run drew)
    says it is fieldloc's. A link or a folder under a file's name is never fieldloc's."""
    folder = Path(folder)
    for name in names:
        p = folder / name
        if not os.path.lexists(p):
            continue  # gone: nothing to lose
        if p.is_symlink() or not p.is_file():
            return p
        if name in recorded:
            if not as_written(p, recorded[name]):
                return p
        elif unlisted is None or not unlisted(p):
            return p
    return None


def tree_files(folder: str | Path, skip=()) -> list[str]:
    """The files (and links) anywhere under ``folder``, as sorted relative names with /
    between parts, but those named in ``skip``: what a folder written whole holds."""
    folder = Path(folder)
    out = []
    for root, dirs, files in os.walk(folder):
        rel = Path(root).relative_to(folder)
        out += [(rel / n).as_posix() for n in files]
        out += [(rel / d).as_posix() for d in dirs if os.path.islink(os.path.join(root, d))]
    return sorted(n for n in out if n not in skip)


def refuse_edited(folder: str | Path, recorded, names, *, record: str, unlisted=None,
                  error: type[FieldlocError] = FieldlocError) -> None:
    """Before --overwrite replaces the files ``names`` of ``folder`` (relative names) and its
    record: each that is there must be as ``folder``'s ``record`` (its file name) lists it in
    the table ``recorded`` (``edited_file``); else one line naming the file. The record, where
    it is there, must then be as fieldloc wrote it (``record_as_written``): a user's notes in
    it are lost when it is replaced. Where ``recorded`` is no table (absent: an older
    fieldloc's record; or damaged) and the record or any of ``names`` is there, one line
    naming the folder: fieldloc cannot vouch for any of its files."""
    folder = Path(folder)
    for n in (record, *names):
        _refuse_read_only(folder / n, error)
    if not isinstance(recorded, Mapping):
        if any(os.path.lexists(folder / n) for n in (record, *names)):
            raise error(f"{folder}'s {record} lists no {WRITTEN_FILES} (an older fieldloc's"
                        " record, or damaged): --overwrite cannot tell an edited file from"
                        " fieldloc's; remove the folder yourself or write elsewhere")
        return
    p = edited_file(folder, recorded, names, unlisted)
    if p is None:
        _refuse_edited_record(folder / record, error)
        return
    name = p.relative_to(folder).as_posix()
    if name in recorded:
        raise error(f"{p} was edited since fieldloc wrote it; --overwrite replaces only"
                    " fieldloc's files as it wrote them: move it aside or choose another"
                    " output")
    raise error(f"{p} is not among the files {folder}'s {record} lists as fieldloc wrote"
                " them: --overwrite replaces only those; move it aside or choose another"
                " output")


# A record vouches for itself too: its WRITTEN_FILES table holds an entry under the record's
# own name, so that --overwrite never replaces a record a user wrote notes into (a comment
# line, a key). A YAML record is written as its text without the table, then the table's
# block; its entry is "<bytes of that text> <SHA-256 of that text and the table's block
# without the entry>", and the record is as written where the rest of the file is exactly
# the block fieldloc dumps of the table it holds: an edit anywhere is seen, a comment line
# included. JSON has no comments: report.json's entry is "<length> <SHA-256>" of the
# canonical dump of the parsed object without the entry, so a reformat of its whitespace
# (which loses nothing) is no edit; a key given twice (which parsing loses) is one.


def _yaml_table_block(table: Mapping) -> str:
    import yaml

    return yaml.safe_dump({WRITTEN_FILES: dict(table)}, sort_keys=False)


def _canonical_json(data) -> bytes:
    return json.dumps(data, sort_keys=True, separators=(",", ":")).encode()


def _digest_entry(data: bytes) -> str:
    return f"{len(data)} {hashlib.sha256(data).hexdigest()}"


def record_text(data: Mapping, name: str) -> str:
    """The text of a fieldloc folder's record ``name`` (simulation.yaml, import.yaml,
    debug-images.yaml; report.json: JSON) holding ``data``, whose WRITTEN_FILES table (made
    where ``data`` has none) gains the record's own entry, so that the record vouches for
    itself (``record_as_written``): what every writer of a record writes."""
    table = {k: v for k, v in dict(data.get(WRITTEN_FILES) or {}).items() if k != name}
    body = storable({k: v for k, v in data.items() if k != WRITTEN_FILES})
    if name.endswith(".json"):
        whole = json.loads(json.dumps({**body, WRITTEN_FILES: table}, allow_nan=False))
        table[name] = _digest_entry(_canonical_json(whole))
        return json.dumps({**body, WRITTEN_FILES: table}, indent=2, allow_nan=False) + "\n"
    import yaml

    head = yaml.safe_dump(body, sort_keys=False) if body else ""
    entry = _digest_entry((head + _yaml_table_block(table)).encode())
    table[name] = f"{len(head.encode())} {entry.partition(' ')[2]}"
    return head + _yaml_table_block(table)


def record_as_written(path: str | Path) -> bool | None:
    """Whether the record ``path`` is as fieldloc wrote it (``record_text``): True; False
    where it was edited (or cannot be read as a record); None where its WRITTEN_FILES table
    holds no entry for it (an older fieldloc's record). One fieldloc may not read is
    FieldlocError (``cannot_read``)."""
    import yaml

    from .conf import load_json, load_yaml

    path = Path(path)
    name = path.name
    try:
        raw = path.read_bytes()
    except PermissionError as e:
        raise cannot_read(path, e) from None
    except OSError:
        return False
    try:
        data = load_json(raw) if name.endswith(".json") else load_yaml(raw)
    except (ValueError, RecursionError, yaml.YAMLError, FieldlocError):
        return False
    table = data.get(WRITTEN_FILES) if isinstance(data, dict) else None
    if not isinstance(table, Mapping):
        return False
    if name not in table:
        return None
    rest = {k: v for k, v in table.items() if k != name}
    if name.endswith(".json"):
        return table[name] == _digest_entry(_canonical_json({**data, WRITTEN_FILES: rest}))
    size, _, digest = str(table[name]).partition(" ")
    if not re.fullmatch(r"[0-9]{1,15}", size):
        return False
    head, tail = raw[:int(size)], raw[int(size):]
    try:
        block, block_rest = _yaml_table_block(table), _yaml_table_block(rest)
    except yaml.YAMLError:  # a value the dumper cannot write: not what fieldloc wrote
        return False
    return (tail == block.encode()
            and hashlib.sha256(head + block_rest.encode()).hexdigest() == digest)


def _refuse_read_only(path: Path, error: type[FieldlocError]) -> None:
    """One line where ``path`` is a file without any write permission bit: made read-only
    by someone, a wish to keep it that --overwrite does not override (the mode bits are read:
    os.access says writable to root)."""
    if path.is_file() and not path.is_symlink() and not path.stat().st_mode & 0o222:
        raise error(f"{path} is read-only: --overwrite does not replace a file made read-only;"
                    " make it writable (chmod u+w) or choose another output")


def _refuse_edited_record(path: Path, error: type[FieldlocError]) -> None:
    """Before --overwrite replaces the record ``path`` (where it is there): one line naming
    it unless it is as fieldloc wrote it (``record_as_written``)."""
    if not os.path.lexists(path):
        return
    if path.is_symlink() or not path.is_file():
        raise error(f"{path} is a link or not a file, which fieldloc never writes as its"
                    " record: --overwrite would replace it; move it aside or choose another"
                    " output")
    state = record_as_written(path)
    if state is None:
        raise error(f"{path} does not list itself in its {WRITTEN_FILES} (an older"
                    " fieldloc's record, or damaged): --overwrite cannot tell an edit of it"
                    " from fieldloc's text; remove the folder yourself or write elsewhere")
    if not state:
        raise error(f"{path} was edited since fieldloc wrote it; --overwrite replaces only"
                    " fieldloc's files as it wrote them, its record of them too: move it"
                    " aside or choose another output")


def check_output(path: str | Path, inputs: Mapping[str, object] | None = None, *,
                 overwrite: bool | None = False, kind: str = "file",
                 error: type[FieldlocError] = FieldlocError,
                 ours=fieldloc_wrote, recording: bool = False,
                 schema: str | None = None) -> Path:
    """Check an output path before any work is done, and return it as a Path.

    - never one of the command's ``inputs`` (role -> path, or an iterable of paths; None
      entries are ignored), with ``overwrite`` or without; for ``kind="folder"`` (a folder the
      command replaces as a whole) no input may lie inside it either;
    - an existing output needs ``overwrite`` (``overwrite=None``: the caller decides itself),
      and even then a file is replaced only where ``ours(path)`` says fieldloc wrote it
      (``fieldloc_wrote``; a format without the mark passes its own test): never a user's
      file that happens to have the output's name; given the ``schema`` the command writes,
      nor a fieldloc HDF5 artifact of another schema (a map under a features file's name is
      no earlier run of this command: build-templates -o msl.map.h5 --overwrite replaced the
      map), nor a file without write permission (made read-only to keep it);
    - never a recording's own file (an image, odometry.csv, truth.csv, ... of any dataset
      folder; its calib.yaml only for ``kind="calibration"``, which is a file otherwise);
    - the folder it goes into must exist and be writable; a file output must not be a folder
      and a folder output not a file;
    - never ``-``: standard output, which only export writes to (before this check); taken
      as a name, a file or folder called ``-`` was written (trial J: extract, localize,
      build-map, simulate, evaluate);
    - a folder output is never a recording's folder (``_refuse_recording_folder``), but for
      a command that writes recordings whole (``recording``: simulate, the importers, whose
      own rules replace only a recording they wrote).
    """
    if str(path) == "-":  # standard output: only export writes there, before this check
        raise error("-: this output is a file or folder, not standard output (`fieldloc export"
                    " -o -` writes poses there); name a file or folder")
    path = Path(path)
    refuse_inputs(path, inputs, kind=kind, error=error)
    _refuse_dataset_files(path, kind, error)
    if kind == "folder" and not recording:
        _refuse_recording_folder(path, error)
    if kind == "calibration":
        kind = "file"
        ours = (first_line_says(re.escape(CALIB_TITLE + "written by fieldloc "))
                if ours is fieldloc_wrote else ours)
    try:
        _check_writable(path, kind)
    except FieldlocError as e:
        raise error(str(e)) from None
    if overwrite is not None and not overwrite and path.exists():
        if kind == "file" or any(path.iterdir()):
            raise error(f"{path} exists (use --overwrite to replace it)")
    found = _hdf5_schema(path) if overwrite and kind == "file" and path.is_file() else None
    writes = (f"this command writes {schema} files" if schema
              else "this output is no fieldloc artifact")
    if found in HDF5_SCHEMAS and found != schema:
        # a fieldloc artifact of another schema, or any artifact where the command writes
        # none (bench --json, report, export: a poses file replaced by JSON, trial W1-5)
        raise error(f"{path} is a {found} file; {writes}: --overwrite replaces only its own"
                    " kind: choose another output")
    if found is not None and not ours(path):
        if ours is not fieldloc_wrote and fieldloc_wrote(path):  # fieldloc's, of another kind
            raise error(f"{path} is another kind of file fieldloc wrote: --overwrite replaces"
                        " only this command's own kind: choose another output")
        raise error(f"{path} was not written by fieldloc: --overwrite replaces only fieldloc's"
                    " own outputs, never a user's file; choose another output")
    if found is not None and schema is not None and found != schema:
        # fieldloc's own file of no artifact (a calib.yaml replaced by features, trial Y2-5)
        raise error(f"{path} is no fieldloc artifact; {writes}: --overwrite replaces only its"
                    " own kind: choose another output")
    if overwrite and kind == "file":
        _refuse_read_only(path, error)
    found = path.exists() and (kind == "file" or not path.is_dir() or any(path.iterdir()))
    if found and (overwrite is None or kind != "file"):
        _note_decision(path, True)  # the caller's own rules decided (folders, companions)
    elif found or (overwrite and _REPLACE.get(os.path.realpath(path)) is not False):
        # a file replaced at the commit only if what is there then is still fieldloc's (a
        # user's file saved there meanwhile is kept); an internal re-check with overwrite (a
        # second round writing the run's own output) keeps the first check's False
        _note_decision(path, ours if kind == "file" else True)
    else:
        _note_decision(path, False)
    return path


# Whether the final commit of an output may replace what it finds at the output's name, per
# output this process checked (check_output), by real path. An output that did not exist (or,
# a folder, was empty) when it was checked without --overwrite is False: a run that finds it
# there at the commit refuses ("... was written by another run meanwhile") instead of
# silently replacing the other run's result; a file output with --overwrite holds the test
# ``ours`` (fieldloc_wrote or the format's own), applied again at the commit to what is there
# then; where the caller itself decided (overwrite=None) or a folder, True. A file under a
# checked folder takes the folder's decision unless it was checked itself; a file this
# process committed is its own and may be replaced afterwards (True). Files under no checked
# output (the lookup cache's) are replaced, as they always were. Recorded here rather than
# passed down as a flag, so that every writer (atomic_path, write_artifact, commit_dir) applies the
# command's decision without each of dozens of callers passing it on.
_REPLACE: dict[str, object] = {}


def _note_decision(path: str | Path, replace) -> None:
    _REPLACE[os.path.realpath(path)] = replace


def may_replace(path: str | Path):
    """Whether committing ``path`` may replace an existing file or folder of that name: the
    decision of ``check_output`` for it or its nearest checked folder (see ``_REPLACE``):
    True, False, or the test what is there must pass."""
    key = os.path.realpath(path)
    while True:
        if key in _REPLACE:
            return _REPLACE[key]
        parent = os.path.dirname(key)
        if parent == key:
            return True
        key = parent


def _written_meanwhile(path: Path) -> FieldlocError:
    return FieldlocError(f"{path} was written by another run meanwhile (it did not exist when"
                         " this run checked it) and is kept as that run wrote it: use"
                         " --overwrite to replace it, or choose another output")


# Tests only (tests/test_concurrent_runs.py): the path of a gate file. A run given it in its
# environment stops just before its first commit of a file or folder, creates
# ``<gate>.reached``, and waits while the gate file exists (at most _GATE_WAIT_S), so that a
# test can let a second run write the same output meanwhile, however loaded the machine. The
# variable is taken out of the environment at once: the run's own child processes (Dask
# workers) and later commits do not wait.
TEST_COMMIT_GATE = "FIELDLOC_TEST_COMMIT_GATE"
_GATE_WAIT_S = 300.0  # bounded, so a test that forgets its gate cannot hang a run forever


def _test_gate() -> None:
    gate = os.environ.pop(TEST_COMMIT_GATE, "")
    if not gate:
        return
    import time

    Path(gate + ".reached").touch()
    end = time.monotonic() + _GATE_WAIT_S
    while os.path.exists(gate) and time.monotonic() < end:
        time.sleep(0.05)


def commit_file(tmp: str | Path, path: str | Path) -> None:
    """Move the finished part ``tmp`` to ``path``: replacing what is there only where
    ``may_replace(path)``; otherwise by a hard link, which fails where ``path`` exists (a
    run that wrote it since this one checked it), then FieldlocError (``tmp`` is left for the
    caller to remove)."""
    path = Path(path)
    raise_deferred_stop()  # a stop a callback dropped: nothing moved after it
    _test_gate()
    rule = may_replace(path)
    if callable(rule) and os.path.lexists(path) and not rule(path):
        raise FieldlocError(f"{path} was replaced meanwhile by a file fieldloc did not write; it"
                            " is kept: choose another output")
    if rule:
        os.replace(tmp, path)
    else:
        try:
            os.link(tmp, path)
        except FileExistsError:
            raise _written_meanwhile(path) from None
        except OSError:  # a file system without hard links: check, then rename
            if os.path.lexists(path):
                raise _written_meanwhile(path) from None
            os.replace(tmp, path)
        else:
            os.unlink(tmp)
    _note_decision(path, True)  # ours now: this process may write it again


def commit_dir(tmp: str | Path, path: str | Path, replace: bool | None = None) -> None:
    """Move the finished folder ``tmp`` to ``path``. Where it may replace (``replace``; None:
    ``may_replace(path)``), an existing folder is first moved aside into a pid-tagged
    ``.old`` part (restored or removed by the next run if this one is killed in between).
    Otherwise a plain rename, which the system refuses onto a folder that is not empty (an
    empty one holds nothing to lose): the folder another run wrote meanwhile is kept and this
    run refuses (FieldlocError; ``tmp`` is left for the caller to remove)."""
    path, tmp = Path(path), Path(tmp)
    raise_deferred_stop()  # a stop a callback dropped: nothing moved after it
    _test_gate()
    if replace is None:
        replace = bool(may_replace(path))  # a folder's own rules were applied when checked
    if replace and path.exists():
        prefix, suffix = part_name(path, ".old")
        old = Path(tempfile.mkdtemp(prefix=prefix, suffix=suffix, dir=path.parent))
        try:
            os.replace(path, old / "data")
            os.replace(tmp, path)
        except BaseException:  # interrupted (Ctrl-C, SIGTERM) or failed in between: the old
            # folder goes back under its name (a SIGKILL there: restore_interrupted_replacement)
            if not os.path.lexists(path) and (old / "data").exists():
                os.replace(old / "data", path)
                shutil.rmtree(old, ignore_errors=True)
            raise
        _remove_replaced(old, path)
    else:
        try:
            os.rename(tmp, path)
        except OSError as e:
            if e.errno in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR, errno.EISDIR):
                raise _written_meanwhile(path) from None
            raise
    _note_decision(path, True)


def _remove_replaced(old: Path, path: Path) -> None:
    """Remove the folder ``old`` holding what ``path`` held before ``commit_dir`` replaced it.
    Its ``data`` is renamed first, so that a copy the system will not let go of in full (a
    read-only subfolder) is never taken for a replacement to restore
    (``restore_interrupted_replacement``). What is left is named in one warning: a later run
    writing ``path`` removes it when it can (``remove_stale_parts``)."""
    with contextlib.suppress(OSError):
        os.rename(old / "data", old / "replaced")
    shutil.rmtree(old, ignore_errors=True)
    if not os.path.lexists(old):
        return
    try:
        shutil.rmtree(old)
    except OSError as e:
        # the copy's own name, beside the output: a line cut to its bound (one_line) keeps
        # a short name whole, where the copy's full path may lose its middle
        log.warning("could not remove the old %s, moved aside beside it to %s (%s: %s): remove"
                    " it (a later run writing %s removes it when it can)", path, old.name,
                    e.strerror or e, Path(e.filename or old).name, path.name)


def _refuse_dataset_files(path: Path, kind: str, error: type[FieldlocError]) -> None:
    """No output is a recording's own file: an image of a dataset folder's images/, or its
    odometry, IMU, truth, frames, head or mask files (and calib.yaml, but for a calibration:
    ``kind="calibration"``), whichever command writes and whatever dataset it read. A
    dataset folder is one holding images/ and calib.yaml."""
    real = Path(os.path.realpath(path))
    for folder, inside_images in ((real.parent, False), (real.parent.parent, True)):
        if not ((folder / "images").is_dir() and (folder / "calib.yaml").is_file()):
            continue
        if inside_images and real.parent.name == "images":
            raise error(f"{path} is an image of the dataset {folder}: a recording's files are"
                        " never written over, --overwrite or not: choose another output")
        own = set(OWN_FILES) - ({"calib.yaml"} if kind == "calibration" else set())
        if not inside_images and (real.name in own or real.name == "images"):
            raise error(f"{path} is a file of the dataset {folder}: a recording's files are"
                        " never written over, --overwrite or not: choose another output")


def _refuse_recording_folder(path: Path, error: type[FieldlocError]) -> None:
    """No folder output (reports, batch results, overlays) is a recording's folder, one that
    holds frames.csv or an images/ folder (what stages.common.dataset opens as a dataset), nor
    its images/: a recording is a user's input, and ``evaluate -o DATASET`` wrote its report,
    errors.csv and plots/ among the recording's files (trial J)."""
    if not path.is_dir():
        return
    for folder in (path, path.parent) if path.name == "images" else (path,):
        held = ("frames.csv" if os.path.lexists(folder / "frames.csv") else
                "images/" if (folder / "images").is_dir() else None)
        if held is not None:
            what = "" if folder == path else f"the images of {folder}, "
            raise error(f"{path} is {what}a recording (holds {held}); name another folder for"
                        " the outputs")


def check_importer_target(output: Path, inputs: Mapping[str, object], overwrite: bool, *,
                          record: str, generator: str,
                          error: type[FieldlocError] = FieldlocError) -> None:
    """The dataset folder an importer writes whole: none of its ``inputs``, nor holding one, nor
    inside one that is a folder (a folder of captures), and, where it exists and is not empty,
    replaced only with ``overwrite`` and only when the importer wrote it (its ``record`` YAML
    names ``generator``): never a user's own folder, whose other files the replacement would
    delete. Every file of the folder must be one the
    record's WRITTEN_FILES table lists, as written (``refuse_edited``: a record without a
    table, an older fieldloc's, or with a damaged one vouches for none, and the folder is
    refused), so that a user's file added to the folder, or one of the importer's files
    edited since, is never deleted."""
    restore_interrupted_replacement(output)  # a folder a killed replacement moved aside
    check_output(output, inputs, overwrite=None, kind="folder", error=error, recording=True)
    for role, given in inputs.items():  # a source folder: the dataset goes beside it
        if isinstance(given, (str, os.PathLike)) and Path(given).is_dir() \
                and _inside(output, given):
            raise error(f"{output} lies inside {role} ({given}), an input of this command: a"
                        " dataset written into its source mixes with it; choose another output")
    if not (output.is_dir() and any(output.iterdir())):
        return
    if not overwrite:
        raise error(f"folder {output} exists and is not empty (use --overwrite to replace a"
                    f" folder {generator} wrote)")
    if not written_by(output, record, generator):
        raise error(f"{output} is not a dataset made by {generator} (no {record} naming it):"
                    " --overwrite replaces only those; choose another output")
    from .conf import load_yaml

    table = load_yaml((output / record).read_text()).get(WRITTEN_FILES)
    names = tree_files(output, skip={record})
    if isinstance(table, Mapping):
        extra = next((n for n in names if n not in table), None)
        if extra is not None:
            raise error(f"{output / extra} was not written by {generator}: --overwrite would"
                        " delete it; move it out of the folder or choose another output")
    refuse_edited(output, table, names, record=record, error=error)


def starts_with(path: str | Path, head: bytes) -> bool:
    """Whether the file ``path`` begins with the bytes ``head`` (False if it cannot be read):
    how a file fieldloc wrote without a record of its own (a TUM file, errors.csv, a PNG) is
    told from a user's file of the same name. A file it is not allowed to read is
    FieldlocError (``cannot_read``), not a file of another kind."""
    try:
        with open(path, "rb") as f:
            return f.read(len(head)) == head
    except PermissionError as e:
        raise cannot_read(path, e) from None
    except OSError:
        return False


def written_by(folder: Path, record: str, generator: str) -> bool:
    """Whether ``folder``'s ``record`` YAML says ``generator`` wrote it (a record it is not
    allowed to read: FieldlocError, ``cannot_read``)."""
    import yaml

    from .conf import load_yaml

    rec = Path(folder) / record
    if not rec.is_file():
        return False
    try:
        d = load_yaml(rec.read_text())
    except PermissionError as e:
        raise cannot_read(rec, e) from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError, FieldlocError):
        return False
    return isinstance(d, dict) and d.get("generator") == generator


def refuse_inputs(path: str | Path, inputs: Mapping[str, object] | None, *, kind: str = "file",
                  error: type[FieldlocError] = FieldlocError) -> None:
    """The part of ``check_output`` about inputs: ``path`` is none of them (and, for a folder
    replaced as a whole, holds none of them)."""
    path = Path(path)
    path_stat, path_real = _stat(path), os.path.realpath(path)
    for role, given in (inputs or {}).items():
        if given is None:
            continue
        items = [given] if isinstance(given, (str, os.PathLike)) else list(given)
        for item in items:
            if item is None:
                continue
            item = Path(item)
            if _same_path(path_stat, path_real, item):
                raise error(
                    f"{path} is an input of this command ({role}); it is never written over,"
                    " --overwrite or not: choose another output")
            if kind == "folder" and item.exists() and _inside(item, path):
                raise error(
                    f"{path} holds an input of this command ({role}: {item}); replacing the"
                    " folder would delete it: choose another output")


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` still runs (ours counts as running)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    except OSError:
        return False
    return True


# one more than the largest process id: Linux's pid_max is at most 2**22, a C int's bound 2**31
MAX_PID = 2**31
LOCK_SUFFIX = ".fieldloc-lock"  # .<target name>.fieldloc-lock: the pid of the run writing it


def _lock_pid(lock: Path) -> int | None:
    """The pid a lock holds (None where it holds none); FieldlocError where the lock is no
    regular file fieldloc wrote (a FIFO there blocked the read forever, a link to /dev/zero
    read without end, trial W3-1): one line, and it is left where it is."""
    try:
        if not stat.S_ISREG(os.lstat(lock).st_mode):
            raise FieldlocError(f"{lock} is no lock fieldloc wrote (not a regular file):"
                                " remove it if no run is writing")
        with open(lock, "rb") as f:
            text = f.read(64).strip()
    except OSError:  # gone meanwhile: no run holds it
        return None
    # fieldloc writes a process's id, whole, before the lock has its name (_create_lock):
    # anything else is a file fieldloc did not write, kept (trial B3-4: a user's notes there
    # were removed as a stale lock), as are 0, -1 (every process to os.kill) and 2**31 or
    # more (os.kill's OverflowError, trial X3-1)
    pid = int(text) if text.isdigit() and len(text) < 12 else 0
    if not 0 < pid < MAX_PID:
        raise FieldlocError(f"{lock} is no lock fieldloc wrote (it holds no process id):"
                            " remove it if no run is writing")
    return pid


def _create_lock(lock: Path, path: Path) -> None:
    """Create ``lock`` holding our pid, atomically (a hard link of a finished part, so no
    reader ever sees it empty); FileExistsError when it exists."""
    prefix, suffix = part_name(path, ".lock")
    fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=lock.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(f"{os.getpid()}\n")
        try:
            os.link(tmp, lock)
        except FileExistsError:
            raise
        except OSError:  # a file system without hard links: exclusive creation instead
            fd = os.open(lock, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            with os.fdopen(fd, "w") as f:
                f.write(f"{os.getpid()}\n")
    finally:
        with contextlib.suppress(OSError):
            os.unlink(tmp)


@contextlib.contextmanager
def output_lock(path: str | Path):
    """Hold ``.<name>.fieldloc-lock`` beside ``path`` while writing it, so a second run on the
    same output refuses (FieldlocError naming the first run's pid) instead of taking the first
    one's work in progress for an interrupted run's. The lock holds the writer's pid; a lock
    whose process no longer runs (a run that was killed) is stale and taken over, with a
    warning. Released (removed) when the block ends, however it ends."""
    path = Path(path)
    lock = (path.parent if str(path.parent) else Path(".")) / f".{path.name}{LOCK_SUFFIX}"
    for _attempt in range(3):
        try:
            _create_lock(lock, path)
            break
        except FileExistsError:
            pid = _lock_pid(lock)
            if pid is not None and pid_alive(pid):
                raise FieldlocError(
                    f"another fieldloc run (pid {pid}) is writing {path}: wait for it to"
                    f" finish or stop it (its lock: {lock.name})") from None
            with contextlib.suppress(FileNotFoundError):
                lock.unlink()
            log.warning("removed the lock of an interrupted run (%s) writing %s",
                        f"pid {pid}" if pid is not None else "no pid in it", path)
        except OSError as e:
            raise FieldlocError(f"cannot write {path}: {e.strerror or e}") from None
    else:
        raise FieldlocError(f"cannot take the lock {lock}: other runs keep taking it")
    try:
        yield lock
    finally:
        with contextlib.suppress(OSError, FieldlocError):
            if _lock_pid(lock) == os.getpid():
                lock.unlink()


def part_pattern(path: Path) -> re.Pattern:
    """Names of the temporary parts of target ``path`` (group 1: the writer's pid, if any)."""
    name = re.escape(path.name)
    return re.compile(rf"^\.{name}\.(?:{PART_TAG}-(\d+)-[^/]+|{_LEGACY_PART})$")


def restore_interrupted_replacement(path: str | Path) -> None:
    """A run killed between moving the old folder aside (``commit_dir``:
    ``.<name>.fieldloc-<pid>-*.old/data``) and moving the new one in leaves no folder under
    the real name: put the old one back, before the stale parts are removed (which would
    delete it)."""
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if os.path.lexists(path) or not parent.is_dir():
        return
    pat = part_pattern(path)
    for entry in sorted(parent.iterdir()):
        m = pat.match(entry.name)
        if (m and entry.name.endswith(".old") and (entry / "data").is_dir()
                and not (m.group(1) and pid_alive(int(m.group(1))))):
            os.replace(entry / "data", path)
            shutil.rmtree(entry, ignore_errors=True)
            log.warning("restored %s from %s, left by a run killed while replacing it", path,
                        entry)
            return


def remove_stale_parts(path: str | Path) -> list[Path]:
    """Remove temporary parts (files or folders) of target ``path`` left by runs that were
    killed: those whose writing process no longer runs (untagged parts of older versions
    always). Each removal is logged as a warning. Returns the removed paths."""
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        return []
    pat = part_pattern(path)
    removed = []
    try:
        entries = list(parent.iterdir())
    except OSError:
        return []
    for entry in entries:
        m = pat.match(entry.name)
        if not m or (m.group(1) and pid_alive(int(m.group(1)))):
            continue
        try:
            size = _tree_size(entry)
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
        except OSError as e:
            # the entry's own name, beside the output: kept whole in a line cut to its
            # bound (one_line), where a long path loses its middle
            log.warning("could not remove %s beside it, left by an earlier run writing %s"
                        " (%s: %s): remove it", entry.name, path, e.strerror or e,
                        Path(e.filename or entry).name)
            continue
        log.warning("removed %s (%s) beside it, left by an interrupted run writing %s",
                    entry.name, _human_bytes(size), path)
        removed.append(entry)
    return removed


def _tree_size(p: Path) -> int:
    if p.is_dir() and not p.is_symlink():
        return sum(f.stat().st_size for f in p.rglob("*") if f.is_file())
    return p.stat().st_size


def _human_bytes(n: float) -> str:
    """``n`` bytes in B, KiB, ... PiB; an absurd estimate in PiB with three digits (``:g``),
    not the hundreds of digits of a float such as 1e300."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            if unit == "B":
                return f"{n:.0f} B"
            return f"{n:.1f} {unit}" if n < 1e6 else f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g} PiB"


human_bytes = _human_bytes


_FULL = (errno.ENOSPC, errno.EDQUOT)


def disk_full(e: BaseException) -> bool:
    """Whether ``e`` is the system refusing a write for lack of space (or quota), as an
    OSError with its errno or as HDF5's message about one ("errno = 28")."""
    if not isinstance(e, OSError):
        return False
    if e.errno in _FULL:
        return True
    text = str(e)
    return ("No space left on device" in text or "Disk quota exceeded" in text
            or any(f"errno = {n}," in text for n in _FULL))


def full_disk_error(path: str | Path) -> DiskFullError:
    """The one line for a write of ``path`` the disk had no room for."""
    return DiskFullError(path)


# the outputs being written in this thread or task, outermost first: a file written into a
# temporary folder (a dataset's truth.csv in .ds.fieldloc-PID-*.part/) is part of the output
# the user named, and the full disk is reported as that output's
_WRITING: contextvars.ContextVar[tuple[Path, ...]] = contextvars.ContextVar("_WRITING",
                                                                             default=())


@contextlib.contextmanager
def writing(path: str | Path):
    """Turn a full disk met while writing ``path`` into one line naming it (the system's
    message names no file, HDF5's spans two lines); another error of the system that names no
    file is given ``path`` as its file, so that its one line says what could not be written.
    Nested, the outermost ``path`` is named: the output the user gave, not a temporary part
    of it (which is removed as the error passes)."""
    outer = _WRITING.get()
    token = _WRITING.set((*outer, Path(path)))
    try:
        yield
    except OSError as e:
        if disk_full(e):
            raise full_disk_error(outer[0] if outer else path) from None
        if not e.filename:
            e.filename = str(path)
        raise
    finally:
        _WRITING.reset(token)


def current_umask() -> int:
    """The process's umask (read without changing it where the system allows)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    old = os.umask(0o022)
    os.umask(old)
    return old


def give_default_mode(path: str | Path) -> None:
    """Give a finished file (0666) or folder (0777) the mode less the umask, as ``open()`` and
    ``mkdir()`` would."""
    path = Path(path)
    base = 0o777 if path.is_dir() else 0o666
    os.chmod(path, base & ~current_umask())


def part_name(path: Path, suffix: str = ".part") -> tuple[str, str]:
    """(prefix, suffix) for tempfile.mkstemp/mkdtemp: a part of ``path`` tagged with our pid."""
    return f".{path.name}.{PART_TAG}-{os.getpid()}-", suffix


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None):
    """Yield a temporary path beside ``path``; rename it onto ``path`` only on success
    (``commit_file``: without replacing a file another run wrote there since this run's
    ``check_output``, unless it was given --overwrite). Stale parts of the same target from
    killed runs are removed first."""
    path = Path(path)
    _check_writable(path)
    remove_stale_parts(path)
    prefix, suffix = part_name(path, suffix or ".part")
    try:
        fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=path.parent)
    except OSError as e:
        if disk_full(e):  # no room for one more file (no inode left): the full disk's line
            outer = _WRITING.get()
            raise full_disk_error(outer[0] if outer else path) from None
        raise FieldlocError(f"cannot write {path}: {e.strerror or e}") from None
    os.close(fd)
    tmp = Path(tmp)
    try:
        with writing(path):
            yield tmp
        if tmp.exists():
            give_default_mode(tmp)
        commit_file(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def part_dir(path: Path) -> Path:
    """A new temporary folder beside the folder output ``path`` (its part, tagged with our
    pid), to be renamed onto ``path`` when complete. The folder ``path`` goes in must exist
    and be writable: refused in one line naming that folder (the part's name is no name the
    user gave)."""
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise FieldlocError(f"cannot write {path}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise FieldlocError(f"cannot write {path}: folder {parent} is not writable")
    prefix, suffix = part_name(path, ".part")
    return Path(tempfile.mkdtemp(prefix=prefix, suffix=suffix, dir=parent))


@contextlib.contextmanager
def atomic_dir(path: str | Path, *, overwrite: bool = False):
    """Yield a temporary folder beside ``path``; on success it replaces ``path`` (an existing
    folder only with ``overwrite``, ``commit_dir``: without it, never one another run wrote
    meanwhile), so an interrupted run leaves neither a half folder under the real name nor a
    damaged earlier one."""
    path = Path(path)
    restore_interrupted_replacement(path)
    if path.exists() and not path.is_dir():
        raise FieldlocError(f"cannot write folder {path}: it is a file")
    if path.is_dir() and any(path.iterdir()) and not overwrite:
        raise FieldlocError(f"folder {path} exists and is not empty (use --overwrite to"
                            " replace it)")
    remove_stale_parts(path)  # those of killed runs (tagged with their pid, as this one is)
    tmp = part_dir(path)
    try:
        with writing(path):
            yield tmp
        give_default_mode(tmp)  # mkdtemp makes it 0700; a dataset folder is shared like any
        commit_dir(tmp, path, replace=overwrite)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


# HDF5 builds an artifact in memory (its "core" driver, growing by this much at a time: few
# reallocations for a map of megabytes, little waste for a poses file of kilobytes)
_CORE_BLOCK = 1 << 20


def storable_text(value):
    """``value``, a text holding a name the file system gave that is no UTF-8 (a folder named
    with bytes 0xff 0xfe: Python holds them as surrogates) with those bytes written as
    ``\xff``: HDF5 stores text as UTF-8 and refused it (a traceback of h5py's). Other values
    as they are."""
    if not isinstance(value, str):
        return value
    try:
        value.encode("utf-8")
        return value
    except UnicodeEncodeError:  # a lone surrogate of no byte (\ud800, from JSON: trial Z1-3)
        return (value.encode("utf-8", "surrogateescape") if _bytes_only(value) else
                value.encode("utf-8", "backslashreplace")).decode("utf-8", "backslashreplace")


def storable(value):
    """``value`` (a record's mapping, list or text) with every text ``storable_text``: a path
    of bytes not UTF-8 written into a YAML record as "\udcff" made the record unreadable to
    fieldloc's own reader (trial B2-1, B2-2)."""
    if isinstance(value, Mapping):
        return {storable(k): storable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [storable(v) for v in value]
    return storable_text(value)


def _bytes_only(value: str) -> bool:
    """Whether every surrogate of ``value`` stands for a byte (U+DC80-U+DCFF), as the file
    system's names not UTF-8 are held."""
    return all(not 0xD800 <= ord(c) <= 0xDFFF or 0xDC80 <= ord(c) <= 0xDCFF for c in value)


@contextlib.contextmanager
def write_artifact(path: str | Path, attrs: dict, *, resume: bool = False,
                   before_commit=None):
    """Open a new HDF5 artifact for writing, atomically.

    The file is built in memory and written to its temporary part in one plain write at the
    end: HDF5 itself never meets a full disk, which it cannot recover from (a write or close
    that fails leaves its objects unable to close: "Exception ignored" tracebacks for each,
    then a segmentation fault at exit). A disk that has no room for the finished file is the
    plain OSError of that one write, which ``atomic_path`` turns into one line naming ``path``.

    With ``resume`` and an existing file of the same schema, its content is copied into the
    temporary file first so per-frame stages can skip frames already done; the original stays
    untouched until the new file is complete. ``before_commit``: called once the file is
    written in full to its part, just before it is committed; never after a failure.
    """
    path = Path(path)
    with atomic_path(path) as tmp:
        if resume and path.exists():
            shutil.copyfile(path, tmp)
            mode = "r+"
        else:
            mode = "w"
        f = h5py.File(tmp, mode, libver="latest", driver="core", backing_store=False,
                      block_size=_CORE_BLOCK)
        try:
            for k, v in attrs.items():
                f.attrs[k] = storable_text(v)
            yield f
            f.flush()
            image = f.id.get_file_image()
        finally:
            f.close()  # in memory: closing cannot fail for lack of room
        with open(tmp, "wb") as out:
            out.write(image)
        del image
        if before_commit is not None:
            before_commit()


def _open_hdf5(path: Path) -> h5py.File:
    """Open an HDF5 file for reading, or fail with one clear line."""
    if not path.is_dir():  # absent, or a FIFO (which would block the open forever), a link loop
        check_file(path, "file")
    if path.is_file():  # HDF5 says "unable to open" for any reason: an unreadable one is that
        try:
            with open(path, "rb"):
                pass
        except OSError as e:
            raise cannot_read(path, e) from None
    try:
        return h5py.File(path, "r")
    except OSError:
        raise SchemaError(
            f"{path}: not an HDF5 file (corrupt or not a fieldloc artifact)"
        ) from None


def open_artifact(path: str | Path, schema: str, max_version: int) -> h5py.File:
    """Open an artifact for reading, checking that it exists and is of ``schema``."""
    path = Path(path)
    f = _open_hdf5(path)
    got = f.attrs.get("schema")
    if isinstance(got, bytes):
        got = got.decode(errors="replace")
    if not isinstance(got, (str, type(None))):  # an array of numbers: no comparison of text
        got = f"{type(got).__name__} {str(got)[:30]}"
    if got != schema:
        f.close()
        what = f"a '{got}' file" if got else "not a fieldloc artifact"
        raise SchemaError(f"{path}: expected a '{schema}' file, but it is {what}")
    version = f.attrs.get("schema_version", -1)
    if not isinstance(version, (int, np.integer)) or isinstance(version, bool):
        f.close()  # written as an integer; "2" or 1.9 is damage (int() read them as 2 and 1)
        raise SchemaError(f"{path}: damaged '{schema}' file (schema_version"
                          f" {str(version)[:40]!r} is not a whole number)")
    if not 1 <= version <= max_version:
        f.close()
        raise SchemaError(
            f"{path}: '{schema}' version {version} is not supported (this fieldloc reads"
            f" versions 1..{max_version})"
        )
    why = _stored_outside(f) or (f"it holds {len(f.attrs):,} root attributes (more than"
                                 f" {MAX_OBJECTS})" if len(f.attrs) > MAX_OBJECTS else None)
    if why:
        f.close()
        raise SchemaError(f"{path}: damaged '{schema}' file ({why}; fieldloc writes its data"
                          " in the file, a few dozen objects)")
    return f


# what an artifact's walk (``_stored_outside``) visits at most, and the most root attributes
# it may hold: fieldloc's artifacts hold 9-19 objects at most 3 deep and about a dozen
# attributes; a file of thousands of nested groups or a million links took the walk minutes
# (trial S), a million attributes took a reader past a minute (trial T), so more is damage
MAX_OBJECTS, MAX_DEPTH = 1000, 8


def _stored_outside(f: h5py.File) -> str | None:
    """Why ``f`` is no artifact fieldloc wrote, its data not all in the file: an object that
    is a link to another file, a virtual dataset or external storage (a FIFO behind any of
    them blocked every reader, trial R), a soft link (fieldloc writes none; one to itself
    looped every reader, trial B1-2), or more objects or deeper nesting than an artifact
    holds (MAX_OBJECTS, MAX_DEPTH); None where none is. Links are read without being followed
    and no data is read."""
    todo, seen = [(f, "", 1)], 0
    while todo:
        group, prefix, depth = todo.pop()
        for name in group:
            seen += 1
            where = f"/{prefix}{name}"[:60]
            if seen > MAX_OBJECTS:
                return f"it holds more than {MAX_OBJECTS} objects (at {where})"
            link = group.get(name, getlink=True)
            if isinstance(link, h5py.ExternalLink):
                return f"{where} is a link to another file"
            if not isinstance(link, h5py.HardLink):  # fieldloc writes none; one to itself
                # ended every reader going through it in h5py's RuntimeError (trial B1-2)
                return f"{where} is a soft link"
            obj = group[name]
            if isinstance(obj, h5py.Group):
                if depth >= MAX_DEPTH:
                    return f"{where} is nested more than {MAX_DEPTH} deep"
                todo.append((obj, f"{prefix}{name}/", depth + 1))
            elif isinstance(obj, h5py.Dataset) and (obj.is_virtual or obj.external):
                return f"{where} is stored outside the file"
    return None


# the most frames an artifact holds (poses, features): a dataset's most (dataset.MAX_CSV_ROWS,
# simulate's MAX_FRAMES); more is damage, refused before a column is read
MAX_FRAMES = 1_000_000
# the largest element of an artifact's dataset: numbers are at most 8 bytes, text a frame or
# image name (a file name, at most 255 bytes) or a few words; field YAML is stored as text of
# any length (a variable-length string, 16 bytes an element)
MAX_ITEM_BYTES = 4096


def stored_dataset(h5: h5py.File, name: str, what: str) -> h5py.Dataset:
    """The dataset ``name`` of an artifact opened by open_artifact, checked before a byte of
    it is read: in the file under its own name (not missing, a group or a soft link; data
    outside the file is open_artifact's to refuse) and of elements fieldloc writes, numbers
    and short text, not arrays (a subarray type) and at most MAX_ITEM_BYTES each: a 230 kB
    file of such elements read 3-12 GB for half a minute before a misleading line (trials Q,
    T). ``what`` names the file in the message ("poses file"). Shapes are the schema's own."""
    def damaged(why: str) -> SchemaError:
        return SchemaError(f"{h5.filename}: damaged {what} (/{name[:60]} {why})")

    link = h5.get(name, getlink=True)
    if link is None:
        raise damaged("is missing")
    if not isinstance(link, h5py.HardLink):
        raise damaged(f"is a {type(link).__name__}; fieldloc writes its data in the file")
    d = h5[name]
    if not isinstance(d, h5py.Dataset):
        raise damaged(f"is a {type(d).__name__}, not a dataset")
    if d.dtype.subdtype is not None or d.dtype.itemsize > MAX_ITEM_BYTES:
        raise damaged(f"holds elements of {d.dtype.itemsize:,} bytes ({str(d.dtype)[:40]});"
                      " fieldloc writes numbers and short text")
    return d


def read_json_attr(f: h5py.File, key: str):
    """The JSON root attribute ``key`` of ``f`` parsed ({} where absent); ValueError where it
    is no JSON text: numbers, bytes not UTF-8, or JSON nested past Python's recursion limit
    (a RecursionError traceback through every reader but the poses', trial W1-2)."""
    v = f.attrs.get(key, "{}")
    try:
        return json.loads(v.decode() if isinstance(v, bytes) else v)
    except RecursionError:
        raise ValueError(f"attribute '{key}' holds JSON nested too deep") from None
    except TypeError:
        raise ValueError(f"attribute '{key}' is {type(v).__name__} {str(v)[:30]}, not JSON"
                         " text") from None


def describe(path: str | Path) -> str:
    """A text listing of an artifact's root attributes and tree (datasets with shape, dtype and
    units), for ``fieldloc inspect``; of a damaged file too, bounded as open_artifact bounds
    it: at most MAX_OBJECTS attributes and objects listed, MAX_DEPTH deep, links named and not
    followed (a million attributes or thousands of nested groups listed for minutes, trial
    U1)."""
    path = Path(path)
    f = _open_hdf5(path)
    lines = [f"{path}"]
    with f:
        if "schema" not in f.attrs:
            lines.append("  (no 'schema' attribute: not a fieldloc artifact)")
        n = len(f.attrs)
        if n > MAX_OBJECTS:
            lines.append(f"  ({n:,} root attributes, not listed: an artifact holds about a"
                         " dozen)")
        else:
            for k in sorted(f.attrs):
                lines.append(f"  @{k} = {_fmt_attr(f.attrs[k])}")
        lines += _tree_lines(f)
    return "\n".join(lines)


def _tree_lines(f: h5py.File) -> list[str]:
    """The objects under ``f`` in name order, one line each: datasets with shape, dtype and
    units, groups, links (named, not followed); of a per-frame group (/frames, /templates)
    the first three and a count; at most MAX_OBJECTS lines, MAX_DEPTH deep."""
    lines: list[str] = []
    todo: list = []

    def push(group, prefix: str, depth: int) -> None:
        # at most MAX_OBJECTS names of a group read (a million links in one: seconds each)
        names = sorted(itertools.islice(iter(group), MAX_OBJECTS))
        if depth == 1 and prefix.strip("/") in ("frames", "templates") and len(group) > 3:
            todo.append(f"  {'  ' * depth}... ({len(group)} groups in /{prefix.strip('/')})")
            names = names[:3]
        todo.extend((group, name, prefix, depth) for name in reversed(names))

    push(f, "", 0)
    while todo:
        if len(lines) >= MAX_OBJECTS:
            lines.append(f"  ... (more than {MAX_OBJECTS} objects: not listed)")
            break
        item = todo.pop()
        if isinstance(item, str):
            lines.append(item)
            continue
        group, name, prefix, depth = item
        where, indent = f"{prefix}{name}", "  " * (depth + 1)
        link = group.get(name, getlink=True)
        if isinstance(link, h5py.SoftLink):
            lines.append(f"{indent}/{where} -> {link.path[:60]}")
            continue
        if isinstance(link, h5py.ExternalLink):
            lines.append(f"{indent}/{where} -> {link.filename[:60]}:{link.path[:60]}")
            continue
        obj = group[name]
        if isinstance(obj, h5py.Dataset):
            units = obj.attrs.get("units", "")
            units = units.decode(errors="replace") if isinstance(units, bytes) else units
            u = f" [{str(units)[:40]}]" if isinstance(units, str) and units else ""
            lines.append(f"{indent}/{where}  {obj.shape} {obj.dtype}{u}")
        elif depth + 1 >= MAX_DEPTH:
            lines.append(f"{indent}/{where}/ ... (nested more than {MAX_DEPTH} deep)")
        else:
            lines.append(f"{indent}/{where}/")
            push(obj, f"{where}/", depth + 1)
    return lines


def _fmt_attr(v):
    if isinstance(v, bytes):
        v = v.decode(errors="replace")
    if isinstance(v, np.ndarray):
        return np.array2string(v, precision=4, separator=", ")
    s = str(v)
    return s if len(s) <= 300 else s[:297] + "..."
