"""The click group of `fieldloc` and of its groups of subcommands (`fieldloc show`): subcommands
imported only when used and listed from a table without being imported; user errors
(FieldlocError) and what the system refuses end in one line on stderr and exit code 1."""

from __future__ import annotations

import contextlib
import errno
import importlib.util
import logging
import os
import signal
import sys
import threading

import click

from stages.common.errors import DiskFullError, FieldlocError
from stages.common.one_line import one_line
from stages.common.stops import DEFERRED_STOPS

from . import _stopped_at_start


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, a job's time limit, a system shutting down) raised as an interrupt,
    so that a terminated command cleans up as one stopped by Ctrl-C does (temporary parts
    removed, extract's finished frames committed, its lock released) and says so in one line,
    instead of vanishing without a word."""


# what a rerun does after an interruption, by command (the others leave no half file and start
# over): batch resumes; extract resumes, and localize the extraction it runs on the fly, where
# they kept a finished frame (they say so, as a callable asked when they stop, in
# ctx.obj["resumes"], ``set_resumes``; until then, and where they kept none, a rerun starts
# over; evaluate once it kept a report); a command that knows better for the run at hand says
# so there too (``resumes``)
RESUMES = {
    "extract": "finished frames were kept; a rerun resumes where it stopped",
    "localize": "finished files were kept; a rerun resumes an extraction it had begun",
    "batch": "finished runs were kept; a rerun resumes with the others",
    "evaluate": "finished reports were kept; a rerun writes the others",
}
# the commands whose RESUMES note holds only once they set it (set_resumes)
RESUMES_WHEN_SET = ("extract", "localize", "evaluate")
STARTS_OVER = "no half-written file was left; a rerun starts over"


def resumes(ctx) -> str | None:
    """What a rerun finds after the command ``ctx`` runs stopped (interrupted, or on a full
    disk): ``ctx.obj["resumes"]`` where the command set it (None: nothing was kept; localize
    given its features extracts nothing, evaluate kept no report before the first is
    done), else the command's RESUMES entry."""
    obj = ctx.obj if isinstance(ctx.obj, dict) else {}
    name = ctx.invoked_subcommand or ""
    note = obj.get("resumes", None if name in RESUMES_WHEN_SET else RESUMES.get(name))
    if not callable(note):
        return note
    try:
        return note()
    except Exception:  # a module a signal stopped half imported (below)
        # the note imports what tells it (extract's kept frames: the features file's module);
        # a signal that stopped the first import of a module it needs (PyYAML's C part) left
        # it unimportable in this process ("partially initialized module 'yaml'"): a
        # traceback and exit code 1 instead of the interrupted line (19 of 290 runs of
        # `extract` given SIGTERM at random). The stage imports the same modules before it
        # writes anything, so nothing was kept
        return None


# what a command stopped after its outputs were complete says (``outputs_complete``)
COMPLETE = ("its outputs were complete before it stopped; only what it printed may be cut"
            " short")


def outputs_complete(ctx) -> None:
    """Say (``set_resumes``) that the command's outputs are complete and committed: a signal
    from now on (as it prints its summary or its table, or one Python dropped earlier,
    raised as it returns) still ends it in its one line and exit code 130 or 143, but the
    line says its outputs were complete (COMPLETE), not that a rerun must redo or finish
    them. Called by every command that writes files, at once after its last stage main
    returns (trial G, G5: `evaluate --overwrite` terminated while printing its table, its
    reports complete, said "finished reports were kept; a rerun writes the others")."""
    set_resumes(ctx, COMPLETE)


def set_resumes(ctx, note) -> None:
    """Say (in ``ctx.obj``, which the group's context shares) what a rerun finds if the
    command stops from now on; None: nothing kept, a rerun starts over; a callable: asked
    when the command stops (extract: whether a finished frame was kept by then)."""
    ctx.ensure_object(dict)["resumes"] = note


# the interrupts the command's signals raised (_terminate_as_interrupt's handlers): a library
# may turn one into an error of its own, which names no cause (gtsam's ImportError
# "initialization failed" where SIGTERM came while `import gtsam` ran its module's init)
_RAISED: list[KeyboardInterrupt] = []


def _interrupt_in(e: BaseException | None) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt in the chain of causes of ``e`` (``e`` itself included), else
    the last one a signal raised while the command ran, or None."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return e
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return _RAISED[-1] if _RAISED else None


def _interrupted(ctx, e: KeyboardInterrupt) -> None:
    """Say that the command was interrupted (Ctrl-C) or terminated (SIGTERM) and what a rerun
    does, and exit 130 or 143 (128 + the signal's number, as a shell)."""
    term = isinstance(e, Terminated)
    note = resumes(ctx) or STARTS_OVER
    click.echo(f"fieldloc: {'terminated' if term else 'interrupted'} ({note})", err=True)
    # the last line: what a library still closes as the process ends (Dask's nannies at exit,
    # a signal that came as batch's cluster had just stopped) logs nothing after it on the
    # command's stderr (its handler, main.py's; a caller's own logging is left alone)
    for handler in logging.root.handlers:
        if getattr(handler, "fieldloc_stderr", False):
            handler.setLevel(logging.CRITICAL + 1)
    # nor does an object a stopped library leaves half made, finalised as the interpreter
    # shuts down (llvmlite's "Exception ignored in: <function ValueRef.__del__ ...>")
    sys.unraisablehook = lambda _unraisable: None
    ctx.exit(128 + (signal.SIGTERM if term else signal.SIGINT))


# the exit codes of a command stopped by a signal (``_interrupted``): 128 + its number
STOPPED_CODES = (128 + signal.SIGINT, 128 + signal.SIGTERM)


def _end_stopped_process(code: int) -> None:
    """End the `fieldloc` process whose command a signal stopped, its line said and its
    cleanup done (temporary parts removed as the interrupt unwound the command): Python's
    exit functions run (atexit: logging's flush, tempfile's and weakref's finalizers, Dask's
    and multiprocessing's children, h5py's converters unregistered), standard output and
    error flushed, then ``os._exit(code)``, without the interpreter's finalisation and C's
    exit handlers. A signal that stopped `import h5py` between registering its type
    converters with HDF5 and registering their removal at exit left HDF5's own exit handler
    (H5_term_library) calling h5py's converter after Python was finalised: "Fatal Python
    error: PyThreadState_Get: ... the GIL is released" or a segmentation fault, exit code
    134 or 139 after the interrupted line (trial H, H1: 2 of about 170 `evaluate` runs given
    SIGINT 0.2-0.3 s after the start). Nothing of a stopped command is left to finalise: what
    it wrote is committed or removed, and a worker thread it leaves has nothing to commit
    (Python's finalisation would let it finish its task, for a caller that is gone)."""
    import atexit

    atexit._run_exitfuncs()  # what Python's finalisation would call first (its errors ignored)
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):  # a closed or full stream: nothing more to say
            stream.flush()
    os._exit(code)


def _keeping_dropped_stops(hook):
    """``sys.unraisablehook`` while the command runs: an interrupt the command's signal raised
    inside a callback whose exceptions Python drops (llvmlite's object-cache notifier as numba
    loads a cached kernel, importlib's module-lock weakref callback) printed "Exception ignored
    in: ..." with a traceback, and the run went on to exit 0 as if no signal had come (3 of
    about 500 runs stopped at random). It is kept instead (stages.common.stops), without a
    word, and raised at the run's next commit or, after its last, as the command returns
    (``_raise_swallowed``); anything else goes to ``hook``."""
    def unraisable(unraisable):
        if any(unraisable.exc_value is e for e in _RAISED):
            if not DEFERRED_STOPS:
                DEFERRED_STOPS.append(unraisable.exc_value)
            return
        hook(unraisable)
    return unraisable


def _raise_swallowed() -> None:
    """At the end of a command that returned as if no signal had come: raise the interrupt a
    signal raised while it ran, if any, so that the run ends in its one line and exit code
    130 or 143 (its outputs complete: ``outputs_complete``). Python dropped it in a callback
    after the last commit (``_keeping_dropped_stops``), or a library took it for another
    error and went on: a SIGINT as numba imported scipy stopped the init of scipy's C module,
    which Python then reports as an ImportError, and numba imports scipy in a ``try`` that
    passes on ImportError; `extract` ran to its end with exit code 0 and no word (1 of 250
    runs given SIGINT at random)."""
    DEFERRED_STOPS.clear()
    if _RAISED:
        raise _RAISED[-1]


def _interrupt(signum, frame):
    """Ctrl-C while the command runs: KeyboardInterrupt, as Python's own handler raises it,
    remembered (_RAISED)."""
    _RAISED.append(KeyboardInterrupt())
    raise _RAISED[-1]


@contextlib.contextmanager
def _terminate_as_interrupt(last: bool = False):
    """While the command runs, SIGTERM raises Terminated (where it is not ignored, and only in
    the main thread, where Python handles signals); the earlier handler is put back after.

    ``last``: the command is the program's (``fieldloc`` run from a shell, not called by a
    test), and the process ends after it. Then SIGTERM and SIGINT are ignored from the moment
    the command is over, instead of the earlier handlers put back: by then its outputs are
    committed (or its one error or "interrupted" line is being said), and a signal that came
    in the last milliseconds killed the process by the default action, with exit code 143 and
    no line at all (SIGTERM), or made click add its "Aborted!" (SIGINT). The process exits
    as the command ended: 0 with its outputs complete, or its one line and exit code."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _RAISED.clear()
    DEFERRED_STOPS.clear()
    old_hook = sys.unraisablehook
    sys.unraisablehook = _keeping_dropped_stops(old_hook)
    try:
        yield from _raising_signals(last)
    finally:
        if not last:
            sys.unraisablehook = old_hook


def _raising_signals(last: bool):
    """The signal handlers of ``_terminate_as_interrupt`` around its command."""
    old_int = signal.getsignal(signal.SIGINT)
    if old_int in (_stopped_at_start, signal.default_int_handler):
        signal.signal(signal.SIGINT, _interrupt)  # the start is over (__init__)
    old = signal.getsignal(signal.SIGTERM)
    if old == signal.SIG_IGN:
        try:
            yield
        finally:
            if signal.getsignal(signal.SIGINT) is _interrupt:
                signal.signal(signal.SIGINT, signal.default_int_handler)
        return

    def terminate(signum, frame):
        _RAISED.append(Terminated())
        raise _RAISED[-1]

    signal.signal(signal.SIGTERM, terminate)
    try:
        yield
    finally:
        if last:  # never put back: SIG_IGN stays so as the interpreter shuts down
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
        else:
            signal.signal(signal.SIGTERM, signal.SIG_DFL if old is None else old)
            if signal.getsignal(signal.SIGINT) is _interrupt:
                signal.signal(signal.SIGINT, signal.default_int_handler)


class StdoutError(OSError):
    """A write to standard output failed (``_Stdout``): a full disk (``> /dev/full``), or a
    reader that closed the pipe (``| head``: errno EPIPE)."""


class _Stdout:
    """sys.stdout while `fieldloc` runs: the stream it stands for, its write errors raised as
    StdoutError, so that they are said as standard output's (``_stdout_failed``). A full
    disk said "No space left on device" as if an output file were cut short, and `--help`
    or `--version` into /dev/full ended in a traceback (trial H, H9)."""

    def __init__(self, stream):
        self._stream = stream

    def __getattr__(self, name):  # encoding, isatty, fileno, buffer: the stream's own
        return getattr(self._stream, name)

    def write(self, text):
        with _as_stdout_error():
            try:
                return self._stream.write(text)
            except UnicodeEncodeError:  # a lone surrogate from a file's text (trial Z1-4)
                return self._stream.write(text.encode(
                    "utf-8", "backslashreplace").decode("utf-8"))

    def writelines(self, lines):
        with _as_stdout_error():
            return self._stream.writelines(lines)

    def flush(self):
        with _as_stdout_error():
            return self._stream.flush()


class _ClosedStdout:
    """Standard output when the process has none (started with it closed, `>&-`: sys.stdout
    is None): what is written to it fails as a closed descriptor does, said as standard
    output's; a command that writes nothing there runs as ever (trial M, M2: an
    AttributeError traceback from flushing None)."""

    encoding, errors = "utf-8", "strict"

    def write(self, text):
        raise OSError(errno.EBADF, "standard output is closed")

    def writelines(self, lines):
        self.write("")

    def flush(self):
        pass

    def isatty(self):
        return False

    def fileno(self):
        raise OSError(errno.EBADF, "standard output is closed")


@contextlib.contextmanager
def _as_stdout_error():
    try:
        yield
    except StdoutError:
        raise
    except OSError as e:
        raise StdoutError(e.errno, e.strerror) from e


def _stdout_failed(e: StdoutError, complete: bool) -> int:
    """Say that standard output could not be written (``e``) and return the exit code, 1. A
    reader that closed the pipe (`fieldloc evaluate ... | head -1`) is said nothing: the
    reader wanted no more, as with any Unix tool, and exit code 1 is what click and Python's
    own handling of a closed pipe give. Anything else is one line on stderr, saying whether
    the command's outputs were complete (``outputs_complete``): evaluate's table into a full
    disk, its reports all written. Standard output is then the null device, so that
    Python's flush at exit meets no closed pipe or full disk ("Exception ignored ...
    BrokenPipeError")."""
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.__stdout__.fileno())
    except (OSError, ValueError, AttributeError):  # no file (a caller's stream: a test's)
        pass
    if e.errno != errno.EPIPE:
        done = "; its output files are complete" if complete else ""
        click.echo(one_line(f"fieldloc: error: could not write to standard output"
                            f" ({e.strerror or e}){done}"), err=True)
    return 1


@contextlib.contextmanager
def _stdout_errors_said():
    """Around the whole of `fieldloc` (its options, --help and --version, the command): its
    standard output as ``_Stdout``, flushed at the end, and a write error on it that the
    command did not say already (``LazyGroup.invoke``) said (``_stdout_failed``)."""
    out = sys.stdout if sys.stdout is not None else _ClosedStdout()
    if isinstance(out, _Stdout):  # a group's subcommand group (`fieldloc show`)
        yield
        return
    sys.stdout = _Stdout(out)
    try:
        try:
            yield
        finally:
            sys.stdout = out
            with _as_stdout_error():
                out.flush()
    except StdoutError as e:
        sys.exit(_stdout_failed(e, complete=False))


# command name -> ("module:attribute", its short help as the listing shows it). Each module only
# parses options and calls a stage, which it imports inside its callback; the short help is here
# so that listing the commands imports none of them (tests/test_cli_startup.py checks it is the
# first sentence of the command's own help).


class LazyGroup(click.Group):
    """A click group whose subcommands are imported only when used, and listed without being
    imported: ``lazy_commands`` maps a name to ("module:attribute", short help)."""

    def __init__(self, *args, lazy_commands=None, **kwargs):
        super().__init__(*args, **kwargs)
        self.lazy_commands = {} if lazy_commands is None else lazy_commands
        self.program = False  # run as the program (main without args): see main

    def main(self, args=None, *a, **kwargs):
        """click's main; called without ``args`` (the ``fieldloc`` command: its arguments
        from the command line, not a caller's such as click's test runner) the process ends
        with the command, and the signals that come once it is over are ignored
        (``_terminate_as_interrupt``'s ``last``)."""
        self.program = args is None
        try:
            with _stdout_errors_said():
                return super().main(args, *a, **kwargs)
        except SystemExit as e:
            if self.program and _RAISED and e.code in STOPPED_CODES:
                _end_stopped_process(e.code)
            raise

    def list_commands(self, ctx):
        names = list(self.commands)
        for name, (target, _short_help) in self.lazy_commands.items():
            if importlib.util.find_spec(target.split(":")[0]) is not None:
                names.append(name)
        return sorted(names)

    def get_command(self, ctx, name):
        if name in self.commands:
            return self.commands[name]
        if name not in self.lazy_commands:
            return None
        mod, attr = self.lazy_commands[name][0].split(":")
        if importlib.util.find_spec(mod) is None:
            return None
        return getattr(importlib.import_module(mod), attr)

    def format_commands(self, ctx, formatter):
        """The listing of ``--help`` as click writes it, the lazy commands' short help taken
        from the table instead of from the imported command."""
        rows = []
        for name in self.list_commands(ctx):
            if name in self.commands:
                cmd = self.commands[name]
                if not cmd.hidden:
                    rows.append((name, cmd))
            else:
                rows.append((name, self.lazy_commands[name][1]))
        if not rows:
            return
        limit = formatter.width - 6 - max(len(name) for name, _ in rows)
        with formatter.section("Commands"):
            formatter.write_dl([
                (name, (click.Command(name, help=h) if isinstance(h, str) else h)
                 .get_short_help_str(limit)) for name, h in rows])

    def invoke(self, ctx):
        debug = ctx.params.get("debug") or "--debug" in sys.argv
        try:
            with _terminate_as_interrupt(last=self.program and ctx.parent is None):
                result = super().invoke(ctx)
                _raise_swallowed()
                return result
        except click.ClickException as e:  # a usage error: click says it, the value cut short
            e.message = one_line(e.message)
            raise
        except FieldlocError as e:
            if debug:
                raise
            if isinstance(e, DiskFullError):  # what a rerun finds: kept work, or none
                e = e.line(resumes(ctx) or "")
            click.echo(one_line(f"fieldloc: error: {e}"), err=True)
            ctx.exit(1)
        except StdoutError as e:  # said with what was complete; the output's own error
            ctx.exit(_stdout_failed(e, complete=resumes(ctx) == COMPLETE))
        except OSError as e:  # the system refused: permission, disk full, a path that vanished
            if debug:
                raise
            where = f"{e.filename}: " if e.filename else ""
            text = str(e.strerror or e)  # HDF5's messages span lines (one_line joins them)
            if "errno = 28," in text:
                text = "No space left on device"
            click.echo(one_line(f"fieldloc: error: {where}{text}"), err=True)
            ctx.exit(1)
        except MemoryError:
            if debug:
                raise
            click.echo("fieldloc: error: out of memory (try a coarser resolution or fewer"
                       " frames)", err=True)
            ctx.exit(1)
        except KeyboardInterrupt as e:
            if debug:
                raise
            _interrupted(ctx, e)
        except (click.exceptions.Exit, click.exceptions.Abort):
            # a group's subcommand group (`fieldloc show`) that ended already (its exit code,
            # its "interrupted" line said): not an error of this group's command, and an
            # interrupt in its chain of causes is said once, not again here
            raise
        except Exception as e:
            # Ctrl-C as a numba kernel returns or unpickles its constants: CPython reports the
            # KeyboardInterrupt raised then as a SystemError caused by it ("returned a result
            # with an exception set"), through as many such SystemErrors as calls return; a
            # C extension's module init that a signal stopped says ImportError, naming no
            # cause: after a signal, an interrupt all the same
            interrupt = _interrupt_in(e)
            if debug or interrupt is None:
                raise
            _interrupted(ctx, interrupt)
