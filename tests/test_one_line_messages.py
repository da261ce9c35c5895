"""s56 group G3: every line fieldloc prints on stderr is one line a terminal shows as it is, of
a bounded length, whatever a name it quotes holds (N1: escape sequences; N2: a path of
kilobytes; N3: batch's workers), and a signal as a command ends gives its one line, or none
when the command was over (T1); the "terminated" and full-disk lines say "kept" only for
what was kept (localize given its features, evaluate's first report)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from fieldloc_cli.lazy_group import Terminated
from fieldloc_cli.main import cli
from stages.common.errors import DiskFullError
from stages.common.one_line import LINE_MAX, NAME_MAX, one_line

ROOT = Path(__file__).resolve().parents[1]
# a name as trial D2 made one: a line break, a tab, and escape sequences that move a terminal's
# cursor up, erase the line above and turn the text red
HOSTILE = "d\nINFO fake line\t\x1b[1A\x1b[2K\x1b[31mred\x7f\x9b"
ESCAPED = "d INFO fake line\\t\\x1b[1A\\x1b[2K\\x1b[31mred\\x7f\\x9b"
SPACED_PATH = "/".join(["a " * 100] * 18) + "/nonexist.h5"  # 3600+ characters of words
# 3600+ characters, no space: with a test folder of up to 480 characters, still within
# the system's 4096 for a path (beyond it the error is "File name too long")
BARE_PATH = "/".join(["b" * 200] * 18) + "/nonexist.h5"


def _fieldloc(*args, cwd, timeout: float = 180, env=None) -> subprocess.CompletedProcess:
    """The fieldloc of this tree run as a user runs it: its own process and stderr (the log's
    lines formatted by the CLI's handler, not by pytest's capture)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), **(env or {}))
    return subprocess.run([sys.executable, "-m", "fieldloc_cli.main", *map(str, args)],
                          cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def _no_control_characters(text: str) -> bool:
    """Whether ``text`` (a stderr, its line ends aside) holds no control character."""
    return not any(ord(c) < 32 and c != "\n" or 0x7f <= ord(c) <= 0x9f for c in text)


def test_one_line_escapes_control_characters_as_repr_does():
    assert one_line(HOSTILE) == ESCAPED
    assert one_line("a\r\nb\u2028c\x85d") == "a b c d"  # every kind of line break: a space
    assert one_line("plain text, unchanged") == "plain text, unchanged"


@pytest.mark.parametrize("path", [SPACED_PATH, BARE_PATH], ids=["spaced-words", "no-space"])
def test_one_line_bounds_a_line_quoting_a_path_of_4000_characters(path):
    line = one_line(f"fieldloc: error: file not found: {path} (and the reason)")
    assert len(line) <= LINE_MAX, len(line)
    assert line.startswith("fieldloc: error: file not found: ")
    assert line.endswith("/nonexist.h5 (and the reason)")  # which file, and why


def test_one_line_cuts_a_long_name_but_keeps_the_words_around_it():
    line = one_line(f"features of {'x' * 5000} are not of {'y' * 5000}, see the manual")
    assert line.startswith("features of xxx") and " are not of yyy" in line
    assert line.endswith(", see the manual") and len(line) <= 2 * NAME_MAX + 40


@pytest.mark.parametrize("path", [SPACED_PATH, BARE_PATH], ids=["spaced-words", "no-space"])
def test_an_error_quoting_a_path_of_4000_characters_is_one_bounded_line(small_omni_run,
                                                                         tmp_path, path):
    """localize --features at a 4000-character path printed a "one-line" error of 2858
    characters (trial D2, N2): the line is at most LINE_MAX characters, its path's head and
    tail kept."""
    w = small_omni_run
    res = CliRunner().invoke(cli, ["-q", "localize", str(w["ds"]), "--map", str(w["map"]),
                                   "--features", str(tmp_path / path), "-o",
                                   str(tmp_path / "p.h5")])
    assert res.exit_code == 1, res.output
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("fieldloc: error: file not found: "), lines
    assert len(lines[0]) <= LINE_MAX and lines[0].endswith("/nonexist.h5"), lines[0]


def test_an_error_line_shows_a_names_escape_sequences_escaped(small_omni_run, tmp_path):
    w = small_omni_run
    res = CliRunner().invoke(cli, ["-q", "localize", str(w["ds"]), "--map", str(w["map"]),
                                   "--features", str(tmp_path / HOSTILE / "f.h5"), "-o",
                                   str(tmp_path / "p.h5")])
    assert res.exit_code == 1, res.output
    assert len(res.stderr.splitlines()) == 1 and ESCAPED + "/f.h5" in res.stderr, res.stderr
    assert _no_control_characters(res.stderr), repr(res.stderr)


# extract's one line about the frame of ``hostile_dataset`` cut short
CUT_FRAME = ("WARNING stages.extract: frame 000001 skipped: unreadable image: {where}" + ESCAPED
             + "/images/000001.png (a PNG file cut short or damaged)")


@pytest.fixture()
def hostile_dataset(small_omni_run, tmp_path):
    """A copy of the 2-frame dataset in a folder named HOSTILE, its frame 000001 cut short
    (extract skips it with a WARNING quoting its path)."""
    ds = tmp_path / HOSTILE
    shutil.copytree(small_omni_run["ds"], ds)
    image = ds / "images" / "000001.png"
    image.write_bytes(image.read_bytes()[:1000])
    return ds


def test_a_warning_shows_a_names_escape_sequences_escaped(hostile_dataset, tmp_path):
    """extract's WARNING quoting a folder with escape sequences wrote them raw: on a terminal
    the line above was erased and the rest turned red (trial D2, N1)."""
    r = _fieldloc("-q", "extract", hostile_dataset.name, "-o", "f.h5", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stderr.splitlines() == [CUT_FRAME.format(where="")], r.stderr


def test_a_batch_workers_warning_is_one_line_with_its_prefix(hostile_dataset, small_omni_run,
                                                             tmp_path):
    """In batch, extract's warning about the cut frame ran in a Dask worker, which had no
    handler of fieldloc's: Python printed its bare message, the name's line break splitting
    it over two lines, the second posing as an "INFO fake line" (trial D2, N3)."""
    spec = tmp_path / "spec.yaml"
    spec.write_text(yaml.safe_dump({"map": str(small_omni_run["map"]),
                                    "datasets": [{"path": str(hostile_dataset), "name": "d"}],
                                    "methods": ["lut"]}))
    r = _fieldloc("-q", "batch", spec, "-o", "res", "--workers", "1", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stderr.splitlines() == [CUT_FRAME.format(where=f"{tmp_path}/")], r.stderr


# a command run as `fieldloc` is, sent `signal` as its process ends (an atexit hook: the
# command is over, its outputs complete), the moment a signal killed it without a word
AT_EXIT = """
import atexit, os, signal, sys
atexit.register(lambda: os.kill(os.getpid(), signal.{sig}))
from fieldloc_cli.main import cli
sys.argv = ["fieldloc", *sys.argv[1:]]
cli()
"""


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGINT"])
def test_a_signal_once_the_command_is_over_changes_nothing(small_omni_run, tmp_path, sig):
    """SIGTERM to localize or evaluate just as they finished exited 143 with no line at all,
    their outputs complete (trial D2, T1): the handler had been put back to the default as
    the command returned. Once the command is over, the signals are ignored: the process
    exits as the command ended (0, its output printed)."""
    r = subprocess.run([sys.executable, "-c", AT_EXIT.format(sig=sig), "inspect",
                        small_omni_run["poses"]], cwd=tmp_path, capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=120)
    assert (r.returncode, r.stderr) == (0, ""), (r.returncode, r.stderr)
    assert "poses" in r.stdout


def test_localize_given_its_features_says_no_extraction_resumes(small_omni_run, tmp_path,
                                                                monkeypatch):
    """localize's "terminated" line said "a rerun resumes an extraction it had begun" when
    given --features (nothing extracted), and when its extraction on the fly had kept no
    frame yet; it says so only once a frame is kept."""
    from stages.pipelines import images_to_poses

    w = small_omni_run

    def stopped(*args, **kwargs):
        raise Terminated()

    monkeypatch.setattr(images_to_poses, "main", stopped)
    args = ["-q", "localize", str(w["ds"]), "--map", str(w["map"]), "-o", str(tmp_path / "p.h5")]
    res = CliRunner().invoke(cli, [*args, "--features", str(w["features"])])
    assert res.exit_code == 128 + signal.SIGTERM
    assert res.stderr == ("fieldloc: terminated (no half-written file was left; a rerun starts"
                          " over)\n"), res.stderr
    res = CliRunner().invoke(cli, args)  # extracted on the fly, stopped before a frame
    assert "no half-written file was left; a rerun starts over" in res.stderr, res.stderr

    def stopped_with_a_frame(*args, **kwargs):
        parts = tmp_path / ".p.features.h5.parts"
        parts.mkdir()
        (parts / "000000+1.npz").write_bytes(b"")
        raise Terminated()

    monkeypatch.setattr(images_to_poses, "main", stopped_with_a_frame)
    res = CliRunner().invoke(cli, args)  # extracted on the fly: a rerun resumes it
    assert "a rerun resumes an extraction it had begun" in res.stderr, res.stderr


def test_evaluate_on_a_full_disk_says_kept_only_for_finished_reports(small_omni_run, tmp_path,
                                                                    monkeypatch):
    """evaluate's line on a full disk said "finished reports were kept" for its one report,
    which was not (rerun2, D13)."""
    from stages.pipelines import evaluation

    w = small_omni_run
    real = evaluation.main

    def full_for_b(conf, poses, truth, out, **kwargs):
        if Path(out).name == "b":
            raise DiskFullError(out)
        return real(conf, poses, truth, out, **kwargs)

    monkeypatch.setattr(evaluation, "main", full_for_b)
    shutil.copyfile(w["poses"], tmp_path / "b.h5")
    res = CliRunner().invoke(cli, ["-q", "evaluate", str(tmp_path / "b.h5"), "--truth",
                                   str(w["ds"]), "-o", str(tmp_path / "b")])
    assert res.exit_code == 1
    assert res.stderr == (f"fieldloc: error: cannot write {tmp_path / 'b'}: no space left on"
                          " its disk (free some space or write elsewhere)\n"), res.stderr
    shutil.copyfile(w["poses"], tmp_path / "a.h5")
    res = CliRunner().invoke(cli, ["-q", "evaluate", str(tmp_path / "a.h5"),
                                   str(tmp_path / "b.h5"), "--truth", str(w["ds"]), "-o",
                                   str(tmp_path / "r")])
    assert res.exit_code == 1 and (tmp_path / "r" / "a" / "report.json").is_file()
    assert res.stderr.endswith("(free some space or write elsewhere; finished reports were"
                               " kept; a rerun writes the others)\n"), res.stderr


# the start of `fieldloc` (the console script of that name) up to the command: its package
# imported, a signal then (while click is imported and the arguments parsed)
AT_START = """
import os, signal, sys
sys.argv[0] = "fieldloc"
import fieldloc_cli
os.kill(os.getpid(), signal.{sig})
import fieldloc_cli.main
"""


@pytest.mark.parametrize("sig,rc,what", [("SIGINT", 130, "interrupted"),
                                         ("SIGTERM", 143, "terminated")])
def test_a_signal_as_fieldloc_starts_is_one_line(tmp_path, sig, rc, what):
    """Ctrl-C to `batch --serial` 0.3 s after its start printed a KeyboardInterrupt traceback
    from the middle of importing click (20 lines), at 0.36 s click's "Aborted!" after an
    empty line (s56, item 7): before the command runs, a signal ends it in one line."""
    r = subprocess.run([sys.executable, "-c", AT_START.format(sig=sig)], cwd=tmp_path,
                       capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                       timeout=120)
    assert (r.returncode, r.stderr) == (
        rc, f"fieldloc: {what} (before it started; nothing was written)\n"), r.stderr


@pytest.mark.parametrize("sig, rc", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_signal_a_library_turns_into_its_own_error_is_still_one_line(tmp_path, monkeypatch,
                                                                        sig, rc):
    """A signal that comes while a C extension's module initialises (SIGTERM during `import
    gtsam` in localize --smooth) is turned by it into an error of its own that names no cause
    (pybind11: ImportError "initialization failed"): the command says it was stopped, in one
    line, with the signal's exit code, not a traceback of that error."""
    import time

    import stages.common.describe as describe

    def stopped_in_an_init(_path):
        try:
            os.kill(os.getpid(), sig)
            time.sleep(5)  # the signal's handler raises before this ends
        except KeyboardInterrupt:
            raise ImportError("initialization failed") from None
        raise AssertionError("no signal came")

    monkeypatch.setattr(describe, "describe_file", stopped_in_an_init)
    (tmp_path / "f.yaml").write_text("a: 1\n")
    res = CliRunner().invoke(cli, ["inspect", str(tmp_path / "f.yaml")])
    assert res.exit_code == rc, res.output
    assert res.output.startswith(("fieldloc: terminated", "fieldloc: interrupted"))
    assert len(res.output.splitlines()) == 1 and "Traceback" not in res.output


def test_a_dataset_folder_named_with_bytes_no_utf8_is_extracted_and_localised(small_omni_run,
                                                                              tmp_path):
    """A folder whose name holds bytes that are no UTF-8 (0xff 0xfe): extract and localize
    write their artifacts (the name stored with those bytes as \\xff), where h5py's refusal
    of the name was a traceback on every run. Run as the program, in bytes: such a name in
    a test's own report would stop pytest-xdist, which sends reports as UTF-8."""
    root = os.fsencode(tmp_path)
    ds = root + b"/d\xff\xfex"
    try:
        shutil.copytree(os.fsencode(small_omni_run["ds"]), ds)
    except OSError:
        pytest.skip("the file system takes no such name")
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    for args in ([b"extract", ds, b"-o", ds + b"/f.h5"],
                 [b"localize", ds, b"--map", os.fsencode(small_omni_run["map"]),
                  b"--features", ds + b"/f.h5", b"--method", b"lut", b"-o", ds + b"/p.h5"]):
        res = subprocess.run([os.fsencode(sys.executable), b"-m", b"fieldloc_cli.main", b"-q",
                              *args], capture_output=True, env=env, timeout=300)
        assert res.returncode == 0, res.stderr.decode(errors="backslashreplace")[-2000:]
    assert os.path.isfile(ds + b"/p.h5")


@pytest.mark.parametrize("kept, note", [
    (False, "no half-written file was left; a rerun starts over"),
    (True, "finished frames were kept; a rerun resumes where it stopped")])
def test_an_extract_stopped_says_whether_it_kept_frames(small_omni_run, tmp_path, monkeypatch,
                                                        kept, note):
    """extract stopped (Ctrl-C) before it finished a frame kept nothing: its line says a
    rerun starts over; stopped once a chunk of finished frames is in its parts folder, that
    a rerun resumes."""
    import stages.extract as stage

    def stopped(*_a, **_k):
        if kept:
            parts = tmp_path / ".f.h5.parts"
            parts.mkdir()
            (parts / "000000+1.npz").write_bytes(b"")
        raise KeyboardInterrupt

    monkeypatch.setattr(stage, "main", stopped)
    res = CliRunner().invoke(cli, ["extract", str(small_omni_run["ds"]), "-o",
                                   str(tmp_path / "f.h5")])
    assert res.exit_code == 130
    assert res.output.strip() == f"fieldloc: interrupted ({note})"
