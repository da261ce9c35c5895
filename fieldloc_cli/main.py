"""`fieldloc`: one click group; subcommands live in their own modules and are imported lazily,
so `fieldloc inspect` does not pay for OpenCV, and are listed from the table below, so
`fieldloc --help` imports none of them (nor, through them, a stage). User errors
(FieldlocError) and what the system refuses (OSError: permission, disk full; MemoryError) end
in one line on stderr and exit code 1; `--debug` shows the traceback instead."""

from __future__ import annotations

import importlib.util
import logging
import re
import sys

import click

from stages import __version__
from stages.common.errors import FieldlocError

# a run of this many characters without a space in an error line is a value the user gave (a
# path or a name of kilobytes), not the message: it is quoted by its first few dozen
LONG_RUN = 200
QUOTED = 57


def _short(text: str) -> str:
    """An error on one line, each run of more than LONG_RUN characters without a space cut
    to its first QUOTED (a 100 kB argument made a 100 kB "one-line" error)."""
    text = " ".join(str(text).split())
    return re.sub(rf"\S{{{LONG_RUN + 1},}}", lambda m: m.group(0)[:QUOTED] + "...", text)

# command name -> ("module:attribute", its short help as the listing shows it). Each module only
# parses options and calls a stage, which it imports inside its callback; the short help is here
# so that listing the commands imports none of them (tests/test_cli_startup.py checks it is the
# first sentence of the command's own help).
COMMANDS = {
    "build-map": ("fieldloc_cli.build_map:build_map",
                  "Build the map of FIELD: a preset (msl-2015, msl, spl, kidsize, adultsize) or"
                  " a YAML."),
    "build-templates": ("fieldloc_cli.build_templates:build_templates",
                        "Templates of the omni frames of DATASET (a `simulate omni --grid`"
                        " folder, or a real one with truth.csv): one per frame, its floor's local"
                        " features and its pose."),
    "simulate": ("fieldloc_cli.simulate:simulate",
                 "Render a dataset folder (images, calib.yaml, odometry, IMU, truth) from"
                 " ground-truth poses."),
    "calibrate": ("fieldloc_cli.calibrate:calibrate",
                  "Write a camera calibration (calib.yaml) from measurements."),
    "extract": ("fieldloc_cli.extract:extract",
                "Per-frame features of the images in DATASET (omni: scan-line distances and line"
                " points; perspective: lines, crossings, boundary) into an HDF5 features file."),
    "localize": ("fieldloc_cli.localize:localize",
                 "Poses of the frames of DATASET on the field of MAP (poses.h5 + poses.tum)."),
    "evaluate": ("fieldloc_cli.evaluate:evaluate",
                 "Position and heading errors of POSES files (poses.h5) against truth:"
                 " report.json, errors.csv and plots per run, and a table of all runs on"
                 " stdout."),
    "show": ("fieldloc_cli.show:show",
             "Draw maps, extracted points, beliefs and error surfaces as PNG files."),
    "bench": ("fieldloc_cli.bench:bench",
              "Time the stages on generated inputs and print a table."),
    "inspect": ("fieldloc_cli.inspect:inspect", "Print what FILE holds."),
    "import": ("fieldloc_cli.import_cmd:import_group",
               "Turn a team's recordings into a dataset folder."),
    "field": ("fieldloc_cli.field:field",
              "Field definitions: import a team's own field file."),
    "export": ("fieldloc_cli.export:export",
               "Write POSES (poses.h5 from `fieldloc localize`) as CSV, TUM or JSON."),
    "report": ("fieldloc_cli.report:report",
               "One HTML page of the evaluation report(s) in SOURCE (a report folder, or a folder"
               " of runs with reports below it): table, plots, reliability, worst frames with"
               " overlays."),
    "batch": ("fieldloc_cli.batch:batch",
              "Run the datasets x methods of SPEC (YAML; see docs/manual.md \"Batch runs\") into"
              " RESULTS:"
              " extract, localize and evaluate per run, finished runs kept, and the comparison"
              " of the methods on every dataset (`fieldloc evaluate --table RESULTS` prints it"
              " again)."),
}


class LazyGroup(click.Group):
    """A click group whose subcommands are imported only when used, and listed without being
    imported: ``lazy_commands`` maps a name to ("module:attribute", short help)."""

    def __init__(self, *args, lazy_commands=None, **kwargs):
        super().__init__(*args, **kwargs)
        self.lazy_commands = COMMANDS if lazy_commands is None else lazy_commands

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


if __name__ == "__main__":  # python -m fieldloc_cli.main, as the fieldloc command
    cli()
