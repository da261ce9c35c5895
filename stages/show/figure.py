"""Figures of the pictures: built with ``matplotlib.figure.Figure`` on the Agg canvas, never
pyplot, so no global backend or figure state is touched and nothing opens a window; written
atomically in the format their file's suffix names (PNG without one)."""

from __future__ import annotations

import contextlib
import logging
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..common.artifacts import WRITTEN_MARK, atomic_path, check_output, storable_text
from ..common.errors import FieldlocError


def new_figure(width: float = 8.0, height: float = 5.0, dpi: int = 120) -> Figure:
    """A figure on the Agg canvas (no pyplot)."""
    fig = Figure(figsize=(width, height), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


# picture formats by file suffix (matplotlib's Agg canvas writes each); no suffix: PNG
FORMATS = {".png": "png", ".pdf": "pdf", ".svg": "svg", ".jpg": "jpg", ".jpeg": "jpg",
           ".eps": "eps", ".tif": "tiff", ".tiff": "tiff", "": "png"}


def picture_format(path: str | Path) -> str:
    """The format a picture at ``path`` is written in, by its suffix (FORMATS); another suffix
    is a FieldlocError (a picture named .xyz or .html would hold a PNG), and so is ``-``,
    which names standard output for export: a show command wrote a PNG file named ``-``
    (trial I), and a picture on a terminal is of no use."""
    if str(path) == "-":
        raise FieldlocError("-: a picture is written to a file, not to standard output; name a"
                            " .png file (or .pdf, .svg, .jpg, .eps, .tif)")
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        known = ", ".join(s for s in FORMATS if s)
        raise FieldlocError(f"{path}: a picture is written as {known} (by its suffix), not"
                            f" {suffix[:20]}")
    return FORMATS[suffix]


def _marked(fmt: str) -> dict:
    """savefig's arguments that put WRITTEN_MARK into a picture of format ``fmt`` (how
    --overwrite tells it from a user's picture): PNG's Software text, the creator of PDF, SVG
    and EPS, a JPEG comment, a TIFF's image description."""
    if fmt == "png":
        return {"metadata": {"Software": WRITTEN_MARK}}
    if fmt in ("pdf", "svg", "eps"):
        return {"metadata": {"Creator": WRITTEN_MARK}}
    if fmt == "jpg":
        return {"pil_kwargs": {"comment": WRITTEN_MARK.encode()}}
    return {"pil_kwargs": {"description": WRITTEN_MARK}}  # tiff


def check_picture_output(path: str | Path, inputs: dict | None, *, overwrite: bool) -> None:
    """A picture's output checked before anything is drawn: ``-`` refused as a picture's
    (``picture_format``), then the file rules (artifacts.check_output, with the command's
    ``inputs``: an input named as the output is said as such first), then its format by the
    suffix. Checked only at ``save_figure``, the refusal came after the drawing, and a file
    named ``-`` left by an older version said "exists" first."""
    if str(path) == "-":
        picture_format(path)
    check_output(path, inputs, overwrite=overwrite)
    picture_format(path)


def save_figure(fig: Figure, path: str | Path, dpi: int | None = None) -> Path:
    """Write ``fig`` to ``path`` atomically, in the format its suffix names (FORMATS), marked
    as fieldloc's (``_marked``)."""
    path = Path(path)
    fmt = picture_format(path)
    drawable_texts(fig)
    with atomic_path(path, suffix=path.suffix or ".png") as tmp, _opaque_in_postscript(fmt):
        fig.savefig(tmp, format=fmt, dpi=dpi or fig.dpi, bbox_inches="tight", **_marked(fmt))
    return path


def drawable_texts(fig: Figure) -> Figure:
    """``fig`` with each of its texts that holds a name the file system gave that is no UTF-8
    (a dataset folder or frame file named with bytes 0xff 0xfe: Python holds them as
    surrogates) written with those bytes as ``\\xff`` (``storable_text``): matplotlib's font
    code refused such a title with an 80-line traceback. Called before every figure is
    drawn into a file (``save_figure``, the report page's pictures)."""
    from matplotlib.text import Text

    for text in fig.findobj(Text):
        shown = text.get_text()
        if isinstance(shown, str) and storable_text(shown) != shown:
            text.set_text(storable_text(shown))
    return fig


@contextlib.contextmanager
def _opaque_in_postscript(fmt: str):
    """PostScript has no transparency: matplotlib draws a translucent artist opaque in an .eps
    and logs a warning for each figure (twice), on every picture fieldloc draws with alpha. The
    picture is what .eps can hold; the warning is held back while an .eps is written."""
    logger = logging.getLogger("matplotlib.backends.backend_ps")
    if fmt != "eps":
        yield
        return
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)
