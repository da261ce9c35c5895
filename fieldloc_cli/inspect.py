"""`fieldloc inspect FILE`: what any file fieldloc writes or reads holds."""

from __future__ import annotations

import click

from stages.common.describe import READS, describe_file


@click.command("inspect", help=f"Print what FILE holds. Reads {READS}.")
@click.argument("file", type=click.Path())
def inspect(file):
    click.echo(describe_file(file))
