"""A `show` command stopped by a signal says so once; evaluate stopped before its first report
says nothing was kept; a dataset folder or a frame file named with bytes that are no UTF-8 is
drawn, reported or refused in one line, never a traceback (trial F's S2, M2, X2, X3). Each
run as the program, in its own process: the signal's handlers are the program's, and such a
name in a test's own report would stop pytest-xdist, which sends reports as UTF-8."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from fieldloc_cli.main import cli

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}

# `fieldloc ARGS` as the program runs it, the stage of `show points` replaced by one that
# sends the process ``sig`` and waits for its handler to stop the command
SIGNALLED_SHOW = """
import os, signal, sys, time
import stages.pipelines.frame_points as stage
def stopped(*args, **kwargs):
    os.kill(os.getpid(), signal.{sig})
    time.sleep(30)
    raise AssertionError("no signal came")
stage.write_picture = stopped
from fieldloc_cli.main import cli
sys.argv = ["fieldloc", *sys.argv[1:]]
cli()
"""


@pytest.mark.parametrize("sig,rc,what", [("SIGINT", 130, "interrupted"),
                                         ("SIGTERM", 143, "terminated")])
def test_a_show_command_stopped_says_so_once(small_omni_run, tmp_path, sig, rc, what):
    """Every `show` subcommand stopped by Ctrl-C or SIGTERM printed its line twice (trial F,
    S2): `show` is a group within fieldloc's, and the outer group took the inner one's exit
    for an error caused by the interrupt and said it again."""
    r = subprocess.run([sys.executable, "-c", SIGNALLED_SHOW.format(sig=sig), "show",
                        "points", str(small_omni_run["ds"]), "--frame", "0", "-o", "p.png"],
                       cwd=tmp_path, capture_output=True, text=True, env=ENV, timeout=120)
    assert (r.returncode, r.stderr) == (
        rc, f"fieldloc: {what} (no half-written file was left; a rerun starts over)\n"), r.stderr
    assert not (tmp_path / "p.png").exists()


def test_evaluate_stopped_before_its_report_says_nothing_was_kept(small_omni_run, tmp_path,
                                                                  monkeypatch):
    """evaluate interrupted 0.4-0.6 s in (before it set its note) said "finished reports
    were kept; a rerun writes the others" with nothing written (trial F, M2): its note holds
    only once a report is kept."""
    import stages.common.conf as conf

    def stopped(*args, **kwargs):  # Ctrl-C as evaluate reads its conf, before any report
        raise KeyboardInterrupt()

    monkeypatch.setattr(conf, "resolve_conf", stopped)
    res = CliRunner().invoke(cli, ["-q", "evaluate", str(small_omni_run["poses"]), "--truth",
                                   str(small_omni_run["ds"]), "-o", str(tmp_path / "rep")])
    assert res.exit_code == 130
    assert res.stderr == ("fieldloc: interrupted (no half-written file was left; a rerun"
                          " starts over)\n"), res.stderr
    assert not (tmp_path / "rep").exists()


def _run(*args: bytes, cwd) -> subprocess.CompletedProcess:
    return subprocess.run([os.fsencode(sys.executable), b"-m", b"fieldloc_cli.main", b"-q",
                           *args], capture_output=True, env=ENV, timeout=300, cwd=cwd)


def _no_utf8_copy(src: Path, dst: bytes) -> None:
    try:
        shutil.copytree(os.fsencode(src), dst)
    except OSError:
        pytest.skip("the file system takes no such name")


def test_a_dataset_folder_named_with_bytes_no_utf8_is_drawn_and_reported(small_omni_run,
                                                                         tmp_path):
    """`show points` of a folder named with bytes 0xff 0xfe died in matplotlib (its title
    holds the folder's name: 80 lines), and `report` of a report below it writing the HTML
    page (35 lines) (trial F, X2): the name is drawn and written with those bytes as \\xff."""
    root = os.fsencode(tmp_path)
    ds = root + b"/d\xff\xfex"
    _no_utf8_copy(small_omni_run["ds"], ds)
    for args in ([b"show", b"points", ds, b"--frame", b"1", b"-o", b"p.png"],
                 [b"show", b"points", ds, b"--frame", b"1", b"--features",
                  os.fsencode(small_omni_run["features"]), b"-o", b"q.png"],
                 [b"evaluate", os.fsencode(small_omni_run["poses"]), b"--truth", ds, b"-o",
                  ds + b"/rep"],
                 [b"report", ds + b"/rep", b"-o", b"r.html"]):
        res = _run(*args, cwd=root)
        assert (res.returncode, res.stderr) == (0, b""), res.stderr[-2000:]
    assert (tmp_path / "p.png").is_file() and (tmp_path / "q.png").is_file()
    assert "d\\xff\\xfex" in (tmp_path / "r.html").read_text(encoding="utf-8")


def test_a_frame_file_named_with_bytes_no_utf8_is_refused_in_one_line(small_omni_run,
                                                                      tmp_path):
    """extract of a dataset without frames.csv whose frame file is named with a byte that is
    no UTF-8 (0\\xff1.png) died writing the frame's name into the features file (55 lines,
    on every rerun too), and localize extracting on the fly the same (trial F, X3): a frame's
    name is written as text into every artifact, so such a file is refused in one line,
    naming it, and nothing is written."""
    root = os.fsencode(tmp_path)
    ds = root + b"/ds"
    _no_utf8_copy(small_omni_run["ds"], ds)
    os.remove(ds + b"/frames.csv")
    os.rename(ds + b"/images/000001.png", ds + b"/images/0\xff1.png")
    before = sorted(os.listdir(root))
    for args in ([b"extract", ds, b"-o", b"f.h5"],
                 [b"localize", ds, b"--map", os.fsencode(small_omni_run["map"]), b"--method",
                  b"lut", b"-o", b"p.h5"],
                 [b"show", b"points", ds, b"--frame", b"0\xff1", b"-o", b"q.png"]):
        res = _run(*args, cwd=root)
        assert res.returncode == 1, res.stderr[-2000:]
        assert res.stderr.splitlines() == [
            b"fieldloc: error: " + ds + b"/images: image file name 0\\xff1.png is not UTF-8"
            b" text; frame names are written as text into every artifact: rename it"]
    assert sorted(os.listdir(root)) == before
