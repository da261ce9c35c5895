"""s56 group W1: a fieldloc folder's record (simulation.yaml, import.yaml, debug-images.yaml,
report.json) vouches for itself in its written_files table, so that --overwrite never
replaces a record a user wrote notes into (the refusals themselves: tests/test_faults.py's
CASES, block "s56 group W1")."""

from __future__ import annotations

import json

import yaml

from stages import evaluate
from stages.common.artifacts import WRITTEN_FILES, record_as_written, record_text

TABLE = {f"images/{i:06d}.png": f"{1000 + i} " + "ab" * 32 for i in range(3)}


def test_a_yaml_record_is_as_written_until_edited_anywhere(tmp_path):
    """The record as written vouches for itself; a comment line (at its end or start), a key
    of the user's, an entry added to its table are each seen; written again from its own
    content, it is the same text; a table without its entry is an older fieldloc's (None)."""
    rec = tmp_path / "simulation.yaml"
    data = {"generator": "fieldloc simulate", "frames": 3, "conf": {"a": 1.5, "b": [1, 2]},
            "note": "x" * 200, WRITTEN_FILES: TABLE}
    text = record_text(data, rec.name)
    rec.write_text(text)
    assert record_as_written(rec) is True
    assert rec.name in yaml.safe_load(text)[WRITTEN_FILES]
    for edited in (text + "# my notes\n", "# my notes\n" + text,
                   text.replace("frames: 3\n", "frames: 3\nmy_notes: keep me\n"),
                   text.replace(f"{WRITTEN_FILES}:\n",
                                f"{WRITTEN_FILES}:\n  notes.txt: 4 {'cd' * 32}\n")):
        rec.write_text(edited)
        assert record_as_written(rec) is False, edited[:60]
    rec.write_text(record_text(yaml.safe_load(text), rec.name))
    assert rec.read_text() == text
    older = yaml.safe_load(text)
    del older[WRITTEN_FILES][rec.name]
    rec.write_text(yaml.safe_dump(older, sort_keys=False))
    assert record_as_written(rec) is None


def test_a_json_record_reformatted_is_as_written_a_key_added_is_not(tmp_path):
    """report.json: JSON has no comments, so its content is what is vouched for; a reformat
    of its whitespace loses nothing and is no edit, a key of the user's is."""
    rep = tmp_path / "report.json"
    rep.write_text(record_text({"schema": "fieldloc.report", "x": [1.0, 2, "inf"],
                                WRITTEN_FILES: {"errors.csv": "1 ab"}}, rep.name))
    assert record_as_written(rep) is True
    data = json.loads(rep.read_text())
    rep.write_text(json.dumps(data))
    assert record_as_written(rep) is True
    data["my_notes"] = "keep me"
    rep.write_text(json.dumps(data, indent=2))
    assert record_as_written(rep) is False


def test_evaluate_overwrites_a_report_whose_json_was_only_reformatted(small_omni_run,
                                                                      tmp_path):
    """A report.json a tool reformatted (one line, keys in their order) is still the report
    evaluate wrote: --overwrite replaces it as before."""
    run = small_omni_run
    rep = evaluate.main(None, run["poses"], run["ds"], tmp_path / "rep")
    data = json.loads((rep / "report.json").read_text())
    (rep / "report.json").write_text(json.dumps(data))
    evaluate.main(None, run["poses"], run["ds"], rep, overwrite=True)
    assert record_as_written(rep / "report.json") is True
