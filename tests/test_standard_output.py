"""Standard output that cannot be written (trial H, H9): a full disk (`> /dev/full`) is one
line saying it was standard output, and whether the command's output files are complete; a
reader that closed the pipe (`| head -1`) ends the command quietly with exit code 1, with
nothing of Python's at exit ("Exception ignored ... BrokenPipeError"). Each command runs as a
user runs it, in its own process: what Python prints as it shuts down is part of it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from stages import build_map, extract, localize, simulate

ROOT = Path(__file__).resolve().parents[1]
FULL = "could not write to standard output (No space left on device)"


@pytest.fixture(scope="module")
def poses(tmp_path_factory):
    """A 2-frame omni dataset on spl and its poses (lut, a coarse map)."""
    root = tmp_path_factory.mktemp("stdout")
    ds = simulate.main(dict(simulate.confs["omni-clean"], frames=2, seed=5), "spl", root / "ds")
    mp = build_map.main({"resolution": 0.5}, "spl", root / "spl.map.h5")
    feats = extract.main(None, ds, root / "f.h5")
    return localize.main({"method": "lut"}, ds, mp, root / "p.h5", features=feats), ds


def _fieldloc(args, stdout) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "fieldloc_cli.main", *map(str, args)],
                          stdout=stdout, stderr=subprocess.PIPE, text=True, env=env,
                          timeout=300)


def _closed_pipe():
    """The write end of a pipe whose reader is gone (a write to it fails with EPIPE)."""
    read, write = os.pipe()
    os.close(read)
    return write


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full")
@pytest.mark.parametrize("args, complete", [
    (["evaluate", "{poses}", "--truth", "{ds}", "-o", "{out}"], True),
    (["inspect", "{poses}"], False),
    (["--help"], False),
    (["--version"], False),
])
def test_a_full_standard_output_is_one_line_saying_so(poses, tmp_path, args, complete):
    """`evaluate > /dev/full` said "No space left on device" as if an output file were cut
    short, and `--help`, `--version` ended in a traceback: now one line, naming standard
    output and, once a command's output files are written, that they are complete."""
    values = {"poses": poses[0], "ds": poses[1], "out": tmp_path / "rep"}
    with open("/dev/full", "w") as full:
        r = _fieldloc(["-q", *(str(a).format(**values) for a in args)], full)
    said = FULL + ("; its output files are complete" if complete else "")
    assert r.returncode == 1 and r.stderr == f"fieldloc: error: {said}\n", r.stderr
    if complete:
        assert json.loads((tmp_path / "rep" / "report.json").read_text())["frames"] == 2


@pytest.mark.parametrize("args", [
    ["evaluate", "{poses}", "--truth", "{ds}", "-o", "{out}"],
    ["export", "{poses}", "--format", "csv", "-o", "-"],
    ["inspect", "{poses}"],
    ["--help"],
])
def test_a_closed_pipe_ends_the_command_quietly(poses, tmp_path, args):
    """`evaluate ... | true`: exit code 1 and no line (the reader wanted no more, as with
    any Unix tool), nothing of Python's as it shuts down, and the outputs written."""
    values = {"poses": poses[0], "ds": poses[1], "out": tmp_path / "rep"}
    pipe = _closed_pipe()
    try:
        r = _fieldloc(["-q", *(str(a).format(**values) for a in args)], pipe)
    finally:
        os.close(pipe)
    assert r.returncode == 1 and r.stderr == "", r.stderr
    if args[0] == "evaluate":
        assert (tmp_path / "rep" / "report.json").is_file()


PICTURES = [
    ["show", "map", "{map}"],
    ["show", "points", "{ds}", "--frame", "1"],
    ["show", "hypotheses", "{poses}", "--frame", "1"],
]


@pytest.mark.parametrize("args", PICTURES)
def test_a_picture_to_standard_output_is_refused(poses, tmp_path, monkeypatch, args):
    """Trial I (I1): `show map M -o -` wrote a PNG file named `-` in the current folder (and
    a rerun said "- exists"), where `export -o -` writes to standard output. A picture is
    of no use on a terminal: refused in one line naming a file to give, nothing written."""
    from click.testing import CliRunner

    from fieldloc_cli.main import cli

    values = {"poses": poses[0], "ds": poses[1], "map": poses[0].parent / "spl.map.h5"}
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(cli, [*(str(a).format(**values) for a in args), "-o", "-"])
    assert r.exit_code == 1 and r.stderr == (
        "fieldloc: error: -: a picture is written to a file, not to standard output; name a"
        " .png file (or .pdf, .svg, .jpg, .eps, .tif)\n"), r.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args", PICTURES)
def test_a_picture_to_standard_output_is_refused_before_a_file_named_so(poses, tmp_path,
                                                                        monkeypatch, args):
    """A file named `-` left by an older version (or the user's): the refusal still comes
    first, before "- exists", and before anything is drawn; the file is left as it was."""
    from click.testing import CliRunner

    from fieldloc_cli.main import cli

    values = {"poses": poses[0], "ds": poses[1], "map": poses[0].parent / "spl.map.h5"}
    monkeypatch.chdir(tmp_path)
    (tmp_path / "-").write_bytes(b"the user's")
    r = CliRunner().invoke(cli, [*(str(a).format(**values) for a in args), "-o", "-"])
    assert r.exit_code == 1 and "not to standard output" in r.stderr, r.stderr
    assert (tmp_path / "-").read_bytes() == b"the user's"


@pytest.mark.parametrize("args", [
    ["build-map", "spl"],
    ["simulate", "omni", "--field", "spl", "--frames", "1", "--seed", "1896"],
    ["extract", "{ds}"],
    ["localize", "{ds}", "--map", "{map}"],
    ["evaluate", "{poses}"],
])
def test_an_output_named_standard_output_is_refused(poses, tmp_path, monkeypatch, args):
    """Trial J (J2): `-o -` made extract, localize (and its `-.tum`), build-map, simulate and
    evaluate write a file or folder named `-`; only export writes to standard output. Refused
    in one line before any work, nothing written."""
    from click.testing import CliRunner

    from fieldloc_cli.main import cli

    values = {"poses": poses[0], "ds": poses[1], "map": poses[0].parent / "spl.map.h5"}
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(cli, [*(str(a).format(**values) for a in args), "-o", "-"])
    assert r.exit_code == 1 and r.stderr.startswith(
        "fieldloc: error: -: this output is a file or folder, not standard output"), r.stderr
    assert r.stderr.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_a_closed_standard_output_is_one_line_or_no_matter(poses, tmp_path):
    """Started with standard output closed (`>&-`: Python's sys.stdout is None), a command
    that prints says so in one line and exits 1 (trial M: an AttributeError traceback); one
    that writes only files runs as ever."""
    def closed(*args):
        return subprocess.run([sys.executable, "-c", "import os, runpy, sys; os.close(1);"
                               " sys.stdout = None; sys.argv = ['fieldloc', *sys.argv[1:]];"
                               " runpy.run_module('fieldloc_cli.main', run_name='__main__')",
                               *map(str, args)], capture_output=True, text=True,
                              env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=300)

    for args in (["--version"], ["export", poses[0], "--format", "json", "-o", "-"]):
        res = closed(*args)
        assert res.returncode == 1
        assert res.stderr.strip().splitlines() == [
            "fieldloc: error: could not write to standard output (standard output is closed)"]
    res = closed("-q", "export", poses[0], "--format", "csv", "-o", tmp_path / "p.csv")
    assert res.returncode == 0 and res.stderr == "", res.stderr
    assert (tmp_path / "p.csv").stat().st_size > 0


def test_a_path_holding_a_nul_byte_is_said_to_be_none(tmp_path):
    """os.stat raises ValueError for a NUL byte: a batch spec's path holding one ended in a
    traceback from the link-loop check (trial M, M1)."""
    from stages.common.errors import FieldlocError, check_file, file_problem

    assert file_problem(tmp_path / "a\0b") == "is no path (it holds a NUL byte)"
    with pytest.raises(FieldlocError, match="holds a NUL byte"):
        check_file(tmp_path / "a\0b", "SPEC")
