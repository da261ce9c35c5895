"""`fieldloc`: one click group; subcommands live in their own modules and are imported lazily,
so `fieldloc inspect` does not pay for OpenCV, and are listed from the table below, so
`fieldloc --help` imports none of them (nor, through them, a stage). User errors
(FieldlocError) and what the system refuses (OSError: permission, disk full; MemoryError) end
in one line on stderr and exit code 1; `--debug` shows the traceback instead."""

from __future__ import annotations

import logging

import click

from stages import __version__
from stages.common.one_line import stderr_handler

from .lazy_group import LazyGroup

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


@click.group(cls=LazyGroup, lazy_commands=COMMANDS,
             context_settings={"help_option_names": ["-h", "--help"]})
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
    handler = stderr_handler()  # one line each, whatever a name holds
    logging.basicConfig(level=level, handlers=[handler])
    ctx.obj = {"verbose": verbose, "quiet": quiet, "debug": debug}


if __name__ == "__main__":  # python -m fieldloc_cli.main, as the fieldloc command
    cli()
