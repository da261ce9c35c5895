"""The click group of `fieldloc` and of its groups of subcommands (`fieldloc show`): subcommands
imported only when used and listed from a table without being imported; user errors
(FieldlocError) and what the system refuses end in one line on stderr and exit code 1."""

from __future__ import annotations

import importlib.util
import re
import sys

import click

from stages.common.errors import FieldlocError

# a run of this many characters without a space in an error line is a value the user gave (a
# path or a name of kilobytes), not the message: it is quoted by its first few dozen
LONG_RUN = 200
QUOTED = 57


def _caused_by_interrupt(e: BaseException | None) -> bool:
    """Whether a KeyboardInterrupt is in the chain of causes of ``e``."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def _interrupted(ctx) -> None:
    """Say that the user interrupted the command, and exit 130 (128 + SIGINT, as a shell)."""
    click.echo("fieldloc: interrupted (finished files were kept; extract resumes where it"
               " stopped)", err=True)
    ctx.exit(130)


def _short(text: str) -> str:
    """An error on one line, each run of more than LONG_RUN characters without a space cut
    to its first QUOTED (a 100 kB argument made a 100 kB "one-line" error)."""
    text = " ".join(str(text).split())
    return re.sub(rf"\S{{{LONG_RUN + 1},}}", lambda m: m.group(0)[:QUOTED] + "...", text)

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
            return super().invoke(ctx)
        except click.ClickException as e:  # a usage error: click says it, the value cut short
            e.message = _short(e.message)
            raise
        except FieldlocError as e:
            if debug:
                raise
            click.echo(f"fieldloc: error: {_short(e)}", err=True)
            ctx.exit(1)
        except BrokenPipeError:  # stdout closed by its reader (| head): nothing more to say
            import os

            try:  # so that the interpreter's own flush at exit finds no closed pipe either
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            except (OSError, ValueError):
                pass
            ctx.exit(1)
        except OSError as e:  # the system refused: permission, disk full, a path that vanished
            if debug:
                raise
            where = f"{e.filename}: " if e.filename else ""
            text = " ".join(str(e.strerror or e).split())  # HDF5's messages span lines
            if "errno = 28," in text:
                text = "No space left on device"
            click.echo(f"fieldloc: error: {_short(where + text[:300])}", err=True)
            ctx.exit(1)
        except MemoryError:
            if debug:
                raise
            click.echo("fieldloc: error: out of memory (try a coarser resolution or fewer"
                       " frames)", err=True)
            ctx.exit(1)
        except KeyboardInterrupt:
            if debug:
                raise
            _interrupted(ctx)
        except SystemError as e:
            # Ctrl-C as a numba kernel returns or unpickles its constants: CPython reports the
            # KeyboardInterrupt raised then as a SystemError caused by it ("returned a result
            # with an exception set"), through as many such SystemErrors as calls return;
            # that is an interrupt all the same
            if debug or not _caused_by_interrupt(e):
                raise
            _interrupted(ctx)
