"""Small CLI helpers shared by subcommands: conf overrides, progress settings, finite numbers,
and the one output rule: results on stdout, summaries, logs and progress on stderr (summaries
hidden by -q)."""

from __future__ import annotations

import math
import sys

import click

from stages.common.conf import parse_overrides


def conf_option(f):
    """`-c key=value` overrides of a stage's preset (repeatable)."""
    return click.option(
        "-c", "--conf", "overrides", multiple=True, metavar="KEY=VALUE",
        help="Override one conf value of the preset (repeatable).",
    )(f)


class FiniteFloat(click.ParamType):
    """A float option that refuses nan and inf (click's FLOAT accepts both)."""

    name = "number"

    def convert(self, value, param, ctx):
        if isinstance(value, float) and math.isfinite(value):
            return value
        try:
            v = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        if not math.isfinite(v):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return v


FINITE = FiniteFloat()


class DeferredHelp(click.Option):
    """An option whose help text names a stage's defaults: ``help`` is a callable, called only
    when the help is shown, so parsing a command does not import every method's module (their
    compiled kernels cost a process's start time)."""

    def __init__(self, *args, help=None, **kwargs):  # noqa: A002 (click's name)
        self._help_text = help if callable(help) else None
        super().__init__(*args, help=None if callable(help) else help, **kwargs)

    def get_help_record(self, ctx):
        if self._help_text is not None and self.help is None:
            self.help = self._help_text()
        return super().get_help_record(ctx)


def progress_enabled(ctx: click.Context) -> bool:
    """Progress bars only on a terminal and never with --quiet."""
    obj = ctx.find_root().obj or {}
    return not obj.get("quiet") and sys.stderr.isatty()


def summary(ctx: click.Context, message: str) -> None:
    """A command's closing summary ("wrote X: N frames"): stderr, and nothing with -q."""
    if not (ctx.find_root().obj or {}).get("quiet"):
        click.echo(message, err=True)


def overrides_dict(overrides) -> dict:
    return parse_overrides(overrides)
