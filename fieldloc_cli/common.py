"""Small CLI helpers shared by subcommands: conf overrides, progress settings, finite numbers,
and the one output rule: results on stdout, summaries, logs and progress on stderr (summaries
hidden by -q)."""

from __future__ import annotations

import math
import sys

import click

from stages.common.one_line import one_line


def conf_option(f):
    """`-c key=value` overrides of a stage's preset (repeatable)."""
    return click.option(
        "-c", "--conf", "overrides", multiple=True, metavar="KEY=VALUE",
        help="Override one conf value of the preset (repeatable).",
    )(f)


class FilePath(click.Path):
    """click.Path without its check that an existing file is readable (click's default
    ``readable=True``): a file that cannot be read then gave click's three-line usage error
    (exit 2) naming no reason, and an output (-o) that existed unreadable was refused before
    the output rule ran. The stage that reads a file reports it in one line instead ("cannot
    read FILE: permission denied", stages.common.artifacts.cannot_read)."""

    def __init__(self, *args, readable: bool = False, **kwargs):
        super().__init__(*args, readable=readable, **kwargs)


def refuse_underscores(kind: click.ParamType, value, param, ctx) -> None:
    """A number option's text with an underscore or a character outside ASCII refused
    (click's usage error), as the YAML confs refuse them: Python's float and int read ``1_0``
    as 10 and the digits of other scripts (Arabic-Indic ``٦``, fullwidth ``６``) as 6."""
    if isinstance(value, str) and "_" in value:
        kind.fail(f"{value[:40]!r} is no decimal number (underscores); write it in decimal",
                  param, ctx)
    if isinstance(value, str) and not value.isascii():
        kind.fail(f"{value[:40]!r} is no decimal number (characters outside ASCII); write it"
                  " in the digits 0-9", param, ctx)


class WholeNumber(click.IntRange):
    """The CLI's whole-number option type: click's IntRange (``min``/``max`` optional),
    refusing underscores as FiniteFloat does (``--frames 1_0`` ran 10 frames)."""

    def __init__(self, min: int | None = None, max: int | None = None):
        super().__init__(min=min, max=max)
        if min is None and max is None:
            self.name = "integer"  # help as click's INT: no "RANGE", no range line

    def _describe_range(self) -> str:
        return "" if self.min is None and self.max is None else super()._describe_range()

    def convert(self, value, param, ctx):
        refuse_underscores(self, value, param, ctx)
        return super().convert(value, param, ctx)


class FiniteFloat(click.ParamType):
    """A float option that refuses nan and inf (click's FLOAT accepts both) and underscores
    (as the YAML confs do: float reads ``1_0`` as 10), and, given
    ``low``/``high``, a value outside [low, high] in the option's own units."""

    name = "number"

    def __init__(self, low: float | None = None, high: float | None = None):
        self.low, self.high = low, high

    def convert(self, value, param, ctx):
        refuse_underscores(self, value, param, ctx)
        try:
            v = float(value)
        except (TypeError, ValueError):
            self.fail(f"{str(value)[:40]!r} is not a number", param, ctx)
        if not math.isfinite(v):
            self.fail(f"{str(value)[:40]!r} is not a finite number", param, ctx)
        if (self.low is not None and v < self.low) or (self.high is not None and v > self.high):
            lo, hi = (f"{b:g}" if b is not None else "" for b in (self.low, self.high))
            self.fail(f"{v:g} is not within [{lo}, {hi}]", param, ctx)
        return v


FINITE = FiniteFloat()


def progress_enabled(ctx: click.Context) -> bool:
    """Progress bars only on a terminal and never with --quiet."""
    obj = ctx.find_root().obj or {}
    return not obj.get("quiet") and sys.stderr.isatty()


def summary(ctx: click.Context, message: str) -> None:
    """A command's closing summary ("wrote X: N frames"): stderr, and nothing with -q. One
    line, as an error is (stages.common.one_line: a line break in a name it quotes, a file
    called "o\\nut.h5", is shown as a space, an escape sequence escaped, a long name cut)."""
    if not (ctx.find_root().obj or {}).get("quiet"):
        click.echo(one_line(message), err=True)


def count(n: int, noun: str, plural: str | None = None) -> str:
    """``n`` and the noun in its number: "1 frame", "4 frames", "0 frames"."""
    return f"{n} {noun if n == 1 else (plural or noun + 's')}"


def overrides_dict(overrides) -> dict:
    """The ``-c key=value`` options as a dict of overrides (stages.common.conf's parser)."""
    from stages.common.conf import parse_overrides

    return parse_overrides(overrides)
