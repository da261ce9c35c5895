"""`fieldloc show ...`: pictures for a person to check by eye. Each picture kind is its own
module; register it in SHOW_COMMANDS with its short help."""

from __future__ import annotations

import click

from .lazy_group import LazyGroup

# name -> ("module:attribute", short help: the first sentence of the command's help)
SHOW_COMMANDS = {
    "map": ("fieldloc_cli.show_map:show_map",
            "Draw MAP's field with a table, so a person can check it by eye."),
    "points": ("fieldloc_cli.show_points:show_points",
               "Draw the extracted line points of one frame of DATASET over its image, and over"
               " the field at a pose (given with --pose, or truth.csv's) when --map is given."),
    "belief": ("fieldloc_cli.show_belief:show_belief",
               "Draw the belief of one frame of DATASET on the field of MAP: the likelihood of"
               " its observations at every position (best heading per position), per kind of"
               " observation."),
    "hypotheses": ("fieldloc_cli.show_hypotheses:show_hypotheses",
                   "Draw the hypotheses of one frame of POSES (poses.h5) on the field: each as a"
                   " robot with its probability, with the frame's line points placed at each."),
    "error-surface": ("fieldloc_cli.show_error_surface:show_error_surface",
                      "Draw the SURF template paper's error surfaces of one template of TEMPLATES"
                      " against QUERIES (omni frames with truth.csv near it): (a) the white-point"
                      " table's eq."),
}


@click.group(cls=LazyGroup, lazy_commands=SHOW_COMMANDS)
def show():
    """Draw maps, extracted points, beliefs and error surfaces as PNG files."""
