"""Small CLI helpers shared by subcommands: conf overrides, progress settings."""

from __future__ import annotations

import sys

import click

from stages.common.conf import parse_overrides


def conf_option(f):
    """`-c key=value` overrides of a stage's preset (repeatable)."""
    return click.option(
        "-c", "--conf", "overrides", multiple=True, metavar="KEY=VALUE",
        help="Override one conf value of the preset (repeatable).",
    )(f)


def progress_enabled(ctx: click.Context) -> bool:
    """Progress bars only on a terminal and never with --quiet."""
    obj = ctx.find_root().obj or {}
    return not obj.get("quiet") and sys.stderr.isatty()


def overrides_dict(overrides) -> dict:
    return parse_overrides(overrides)
