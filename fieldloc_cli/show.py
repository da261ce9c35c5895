"""`fieldloc show ...`: pictures for a person to check by eye. Each picture kind is its own
module; register it in SHOW_COMMANDS."""

from __future__ import annotations

import click

from .main import LazyGroup

SHOW_COMMANDS = {
    "map": "fieldloc_cli.show_map:show_map",
    "points": "fieldloc_cli.show_points:show_points",
    "belief": "fieldloc_cli.show_belief:show_belief",
    "hypotheses": "fieldloc_cli.show_hypotheses:show_hypotheses",
    "error-surface": "fieldloc_cli.show_error_surface:show_error_surface",
}


@click.group(cls=LazyGroup, lazy_commands=SHOW_COMMANDS)
def show():
    """Draw maps, extracted points, beliefs and error surfaces as PNG files."""
