"""The belief of one frame's observations on a grid of poses, drawn like fig. 3 of Schulz et al.
(2011).

The likelihood of the frame's observations under the particle filter's observation model
(stages.localize.belief.belief_grid) in four panels: lines only, crossings only, goal posts
only, all together. Each shows the likelihood (relative to the panel's best pose; one colour
bar for all four) as an image, with arrows of the best heading every ``arrow_spacing`` metres
where the likelihood is at least ``arrow_min`` of the best, sized by it, as the paper draws its
particles. A panel with no observations (or a flat likelihood) says so instead of marking a
"best pose".

``draw_belief`` draws a computed grid (stages.pipelines.frame_belief computes it and writes
the picture: ``fieldloc show belief``).
"""

from __future__ import annotations

import math

import numpy as np

from .field import draw_field

PANELS = (("lines", "lines only"), ("crossings", "crossings only"),
          ("posts", "goal posts only"), ("all", "lines, crossings and posts"))


def draw_belief(axes, field_model, grid: dict, *, truth=None, arrow_spacing: float = 0.5,
                arrow_min: float = 0.25, title: str | None = None):
    """Draw the four panels of ``grid`` (from ``belief_grid``) into ``axes`` (2, 2) of one
    figure, with one colour bar. Returns the axes."""
    fig = axes.flat[0].figure
    xs, ys = grid["xs"], grid["ys"]
    res = float(xs[1] - xs[0]) if len(xs) > 1 else 0.1
    extent = (xs[0] - res / 2, xs[-1] + res / 2, ys[0] - res / 2, ys[-1] + res / 2)
    counts = grid["counts"]
    every = max(1, int(round(arrow_spacing / res)))
    image = None
    for ax, (key, label) in zip(axes.ravel(), PANELS):
        draw_field(ax, field_model, zorder=0)
        ll = grid[key]
        n = sum(counts.values()) if key == "all" else counts[key]
        ax.set_title(f"{label} ({n} observation{'s' if n != 1 else ''})", fontsize=9)
        ax.set_xlim(extent[0], extent[1])
        ax.set_ylim(extent[2], extent[3])
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
        finite = ll[np.isfinite(ll)]
        if n == 0 or not finite.size or float(finite.max() - finite.min()) < 1e-9:
            what = label.replace(" only", "")
            ax.text(0.5, 0.5, f"no {what} observed:\nthe likelihood is flat" if n == 0 else
                    "flat likelihood: no pose is preferred", transform=ax.transAxes,
                    ha="center", va="center", fontsize=10, color="white", zorder=7,
                    bbox={"facecolor": "black", "alpha": 0.6, "edgecolor": "none"})
            _draw_truth(ax, truth)
            continue
        rel = np.exp(ll - ll.max())  # likelihood relative to the panel's best pose
        image = ax.imshow(rel, origin="lower", extent=extent, cmap="magma", vmin=0.0,
                          vmax=1.0, alpha=0.75, interpolation="nearest", zorder=2)
        sub = (slice(every // 2, None, every), slice(every // 2, None, every))
        gx, gy = np.meshgrid(xs, ys)
        th = grid[f"{key}_theta"][sub]
        size = rel[sub]
        keep = size >= arrow_min
        ax.quiver(gx[sub][keep], gy[sub][keep], (np.cos(th) * size)[keep],
                  (np.sin(th) * size)[keep], color="cyan", angles="xy", scale_units="xy",
                  scale=1.0 / (res * every * 0.8), width=0.005, zorder=3)
        i, j = np.unravel_index(int(np.argmax(ll)), ll.shape)
        bt = grid[f"{key}_theta"][i, j]
        ax.plot(xs[j], ys[i], "o", ms=6, mfc="none", mec="yellow", zorder=5)
        ax.annotate("", xy=(xs[j] + 0.5 * math.cos(bt), ys[i] + 0.5 * math.sin(bt)),
                    xytext=(xs[j], ys[i]), zorder=5,
                    arrowprops={"arrowstyle": "->", "color": "yellow", "lw": 1.5})
        _draw_truth(ax, truth)
    if image is not None:
        fig.colorbar(image, ax=axes.ravel().tolist(), shrink=0.8,
                     label="likelihood relative to the panel's best pose")
    if title:
        fig.suptitle(title, fontsize=10)
    return axes


def _draw_truth(ax, truth):
    if truth is None:
        return
    tx, ty, tt = truth
    ax.plot(tx, ty, "+", ms=10, mew=2, color="white", zorder=6)
    ax.annotate("", xy=(tx + 0.5 * math.cos(tt), ty + 0.5 * math.sin(tt)), xytext=(tx, ty),
                zorder=6, arrowprops={"arrowstyle": "->", "color": "white", "lw": 1.5})
