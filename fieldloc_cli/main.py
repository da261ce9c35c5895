"""`fieldloc`: one click group; subcommands live in their own modules and are imported lazily,
so `fieldloc inspect` does not pay for OpenCV. User errors (FieldlocError) and what the system
refuses (OSError: permission, disk full; MemoryError) end in one line on stderr and exit code 1;
`--debug` shows the traceback instead."""

from __future__ import annotations

import importlib
import logging
import sys

import click

from stages import __version__
from stages.common.errors import FieldlocError

# command name -> "module:attribute" (each module only parses options and calls a stage)
COMMANDS = {
    "build-map": "fieldloc_cli.build_map:build_map",
    "simulate": "fieldloc_cli.simulate:simulate",
    "calibrate": "fieldloc_cli.calibrate:calibrate",
    "extract": "fieldloc_cli.extract:extract",
    "localize": "fieldloc_cli.localize:localize",
    "evaluate": "fieldloc_cli.evaluate:evaluate",
    "show": "fieldloc_cli.show:show",
    "bench": "fieldloc_cli.bench:bench",
    "inspect": "fieldloc_cli.inspect:inspect",
    "import": "fieldloc_cli.import_cmd:import_group",
    "field": "fieldloc_cli.field:field",
    "export": "fieldloc_cli.export:export",
    "report": "fieldloc_cli.report:report",
    "batch": "fieldloc_cli.batch:batch",
}


class LazyGroup(click.Group):
    """A click group whose subcommands are imported only when used.
    ``lazy_commands``: name -> "module:attribute"."""

    def __init__(self, *args, lazy_commands=None, **kwargs):
        super().__init__(*args, **kwargs)
        self.lazy_commands = COMMANDS if lazy_commands is None else lazy_commands

    def list_commands(self, ctx):
        names = list(self.commands)
        for name, target in self.lazy_commands.items():
            mod = target.split(":")[0]
            if importlib.util.find_spec(mod) is not None:
                names.append(name)
        return sorted(names)

    def get_command(self, ctx, name):
        if name in self.commands:
            return self.commands[name]
        target = self.lazy_commands.get(name)
        if target is None:
            return None
        mod, attr = target.split(":")
        if importlib.util.find_spec(mod) is None:
            return None
        return getattr(importlib.import_module(mod), attr)

    def invoke(self, ctx):
        debug = ctx.params.get("debug") or "--debug" in sys.argv
        try:
            return super().invoke(ctx)
        except FieldlocError as e:
            if debug:
                raise
            click.echo(f"fieldloc: error: {e}", err=True)
            ctx.exit(1)
        except OSError as e:  # the system refused: permission, disk full, a path that vanished
            if debug:
                raise
            where = f"{e.filename}: " if e.filename else ""
            click.echo(f"fieldloc: error: {where}{e.strerror or e}", err=True)
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
            click.echo("fieldloc: interrupted (finished files were kept; extract resumes"
                       " where it stopped)", err=True)
            ctx.exit(130)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="fieldloc")
@click.option("-v", "--verbose", count=True, help="More log output on stderr (-vv for debug).")
@click.option("-q", "--quiet", is_flag=True, help="No progress bars or info messages.")
@click.option("--debug", is_flag=True, help="Show tracebacks of errors.")
@click.pass_context
def cli(ctx, verbose, quiet, debug):
    """fieldloc: where a soccer robot stood on the field, from what its camera saw."""
    level = logging.WARNING if quiet else (logging.INFO if verbose <= 1 else logging.DEBUG)
    if verbose == 0 and not quiet:
        level = logging.WARNING
    logging.basicConfig(
        level=level, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr
    )
    ctx.obj = {"verbose": verbose, "quiet": quiet, "debug": debug}
