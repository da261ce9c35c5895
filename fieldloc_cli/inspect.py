"""`fieldloc inspect FILE`: what any file fieldloc writes or reads holds."""

from __future__ import annotations

import click

from .common import FilePath
from .stage_defaults import INSPECT_READS


@click.command("inspect", help=f"Print what FILE holds. Reads {INSPECT_READS}.")
@click.argument("file", type=FilePath())
def inspect(file):
    from stages.common.describe import describe_file

    click.echo(describe_file(file))
