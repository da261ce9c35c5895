"""The index of a batch's results (written by stages.pipelines.batch, read by the comparison
table of stages.evaluate and the comparison pictures of stages.show): ``RESULTS/batch.json``,
schema ``fieldloc.batch``, version 1, strict JSON as report.json is (stages.common.report_file:
inf as "inf", NaN as null).

    schema, schema_version, fieldloc_version, created   (stages.common.artifacts.provenance)
    spec           the SPEC file's absolute path and content hash
    datasets       name -> {"dir": dataset folder, "camera": omni|perspective, "map": map file,
                   "truth": whether it has truth.csv}
    runs           one per (dataset, method, conf), in the SPEC's order:
                   {"key": "<dataset>/<method>-<preset>[-<overrides hash>]", "dataset",
                    "method" (the SPEC's name of the method entry), "localize_method",
                    "preset", "overrides", "dir" (relative to RESULTS), "status": ok | failed,
                    "error" (failed: one line, else ""), "report" (the report folder relative
                    to RESULTS, "" without truth), "summary" (without truth: frames,
                    failures, failure_rate, runtime_ms of the poses), "seconds", "warnings"}
    skipped        lines saying what the SPEC asked for and the batch did not run, and why

Texts are never null (an empty text is ""), so null always reads back as a number (NaN).
Each run folder holds ``run.json`` (the run's entry above, written last: a run without it did
not finish).
"""

from __future__ import annotations

import json
from pathlib import Path

from .artifacts import atomic_path, cannot_read, provenance
from .conf import read_record
from .errors import FieldlocError, SchemaError, shown
from .report_file import bounded_int, decode_numbers, encode_numbers

# the most a batch.json or run.json may weigh: an index holds about 700 bytes a run, so 64 MB
# is some 90,000 runs
MAX_INDEX_BYTES = 64 << 20

SCHEMA = "fieldloc.batch"
VERSION = 1
BATCH_NAME = "batch.json"
RUN_NAME = "run.json"


def write_json(path: str | Path, data: dict) -> Path:
    """Strict JSON (inf as "inf"), atomically."""
    path = Path(path)
    text = json.dumps(encode_numbers(data), indent=2, allow_nan=False) + "\n"
    with atomic_path(path, suffix=".json") as tmp:
        tmp.write_text(text)
    return path


def read_json(path: str | Path, *, raw: bool = False) -> dict:
    """A JSON file written by ``write_json`` (numbers decoded unless ``raw``), or
    SchemaError."""
    path = Path(path)
    try:  # a batch.json of 3 GB was read whole for 11 s to be refused (trial U1)
        data = json.loads(read_record(path, MAX_INDEX_BYTES).decode(), parse_int=bounded_int)
    except PermissionError as e:
        raise cannot_read(path, e) from None
    except (OSError, ValueError, RecursionError) as e:  # ValueError: bad JSON or UTF-8, or an
        # integer of more than 4300 digits (trial Y1-3: a traceback)
        raise SchemaError(f"{path}: not a readable JSON file ({str(e)[:120]})") from None
    if not isinstance(data, dict):
        raise SchemaError(f"{path}: expected a JSON object")
    return data if raw else decode_numbers(data)


def write_batch(results_dir: str | Path, index: dict) -> Path:
    """RESULTS/batch.json: the provenance keys, then ``index``."""
    return write_json(Path(results_dir) / BATCH_NAME, {**provenance(SCHEMA, VERSION), **index})


def is_batch_folder(path: str | Path) -> bool:
    return (Path(path) / BATCH_NAME).is_file()


def written_by_batch(results_dir: str | Path) -> bool:
    """Whether ``results_dir``'s batch.json is an index a batch wrote (a JSON object with this
    schema): only then are it and the comparison files beside it a batch's own, which a rerun
    may replace (a user's batch.json, or a damaged one, which a batch never leaves since it
    writes atomically, is not)."""
    path = Path(results_dir) / BATCH_NAME
    if not path.is_file():
        return False
    try:
        return read_json(path, raw=True).get("schema") == SCHEMA
    except SchemaError:
        return False


def load_batch(results_dir: str | Path) -> dict:
    """The index of a results folder, its schema checked."""
    path = Path(results_dir) / BATCH_NAME
    if not path.is_file():
        raise FieldlocError(f"no {BATCH_NAME} in {results_dir}: not a folder written by"
                            " `fieldloc batch`")
    data = read_json(path)
    if data.get("schema") != SCHEMA:
        raise SchemaError(f"{path}: expected a '{SCHEMA}' file, got {data.get('schema')!r}")
    v = data.get("schema_version")
    if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= VERSION:
        raise SchemaError(f"{path}: '{SCHEMA}' version {shown(v, 40)} is not supported (this"
                          f" fieldloc reads versions 1..{VERSION})")
    return data
