"""`fieldloc inspect FILE`: an artifact's attributes and tree."""

from __future__ import annotations

import click

from stages.common.artifacts import describe


@click.command("inspect")
@click.argument("file", type=click.Path(dir_okay=False))
def inspect(file):
    """Print FILE's root attributes and its datasets (shape, dtype, units)."""
    click.echo(describe(file))
