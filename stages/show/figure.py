"""Figures of the pictures: built with ``matplotlib.figure.Figure`` on the Agg canvas, never
pyplot, so no global backend or figure state is touched and nothing opens a window; written
atomically as PNG."""

from __future__ import annotations

from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..common.artifacts import atomic_path


def new_figure(width: float = 8.0, height: float = 5.0, dpi: int = 120) -> Figure:
    """A figure on the Agg canvas (no pyplot)."""
    fig = Figure(figsize=(width, height), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path: str | Path, dpi: int | None = None) -> Path:
    """Write ``fig`` as PNG to ``path`` atomically."""
    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", dpi=dpi or fig.dpi, bbox_inches="tight")
    return path
