"""The field as every picture draws it: white lines at their true width (segments and arcs of
the field model), penalty marks, goals and posts on the green, in metres in the field frame."""

from __future__ import annotations

import math

import numpy as np
from matplotlib.collections import LineCollection, PatchCollection
from matplotlib.patches import Circle, Polygon, Rectangle, Wedge

from ..common.field import FieldModel

FIELD_GREEN = "#3a8a3a"
BORDER_GREEN = "#2f7330"
LINE_WHITE = "white"


def _segment_polygon(p0, p1, width: float) -> np.ndarray:
    """The rectangle (4, 2) a line of ``width`` covers along p0 -> p1, ends extended by
    width / 2 so that lines meeting at a corner close it."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d = p1 - p0
    u = d / np.linalg.norm(d)
    n = np.array([-u[1], u[0]]) * width / 2
    a, b = p0 - u * width / 2, p1 + u * width / 2
    return np.array([a + n, b + n, b - n, a - n])


def draw_field(ax, field_model: FieldModel, *, border: bool = True, line_colour=LINE_WHITE,
               field_colour=FIELD_GREEN, border_colour=BORDER_GREEN, goals: bool = True,
               zorder: float = 0.0):
    """Draw a field's white lines at their true width (segments and arcs of the model),
    penalty marks, goals and posts into ``ax``, in metres in the field frame. Sets equal aspect
    and limits to the field plus its border (``border=False``: the field only)."""
    fm = field_model
    xmin, xmax, ymin, ymax = fm.world_bounds(None if border else 0.0)
    ax.add_patch(Rectangle((xmin, ymin), xmax - xmin, ymax - ymin, facecolor=border_colour,
                           edgecolor="none", zorder=zorder))
    hx, hy = fm.length / 2, fm.width / 2
    ax.add_patch(Rectangle((-hx, -hy), fm.length, fm.width, facecolor=field_colour,
                           edgecolor="none", zorder=zorder))
    lw = fm.line_width
    patches = [Polygon(_segment_polygon(p0, p1, lw), closed=True) for p0, p1 in fm.segments]
    for cx, cy, r, a0, sweep in fm.arcs:
        t0, t1 = math.degrees(a0), math.degrees(a0 + sweep)
        patches.append(Wedge((cx, cy), r + lw / 2, t0, t1, width=lw))
    for px, py in fm.penalty_marks:
        size = float(fm.spec.get("penalty_mark", {}).get("size", lw))
        patches.append(Rectangle((px - size / 2, py - lw / 2), size, lw))
        patches.append(Rectangle((px - lw / 2, py - size / 2), lw, size))
    ax.add_collection(PatchCollection(patches, facecolor=line_colour, edgecolor="none",
                                      zorder=zorder + 0.1))
    if goals and len(fm.goal_posts):
        goal = fm.spec.get("goal", {})
        depth = float(goal.get("depth", 0.0))
        post_d = float(goal.get("post_diameter", lw))
        frames = []
        for sx in (-1.0, 1.0):
            posts = fm.goal_posts[np.sign(fm.goal_posts[:, 0]) == sx]
            if len(posts) == 2 and depth > 0:
                y0, y1 = sorted(posts[:, 1])
                gx = sx * hx
                frames.append([(gx, y0), (gx + sx * depth, y0), (gx + sx * depth, y1), (gx, y1)])
        ax.add_collection(LineCollection(frames, colors="0.85", linewidths=1.5,
                                         zorder=zorder + 0.2))
        ax.add_collection(PatchCollection(
            [Circle((px, py), post_d / 2) for px, py in fm.goal_posts],
            facecolor="0.95", edgecolor="0.3", linewidth=0.5, zorder=zorder + 0.3))
    ax.set_xlim(xmin, xmax)
    ax.set_ylim(ymin, ymax)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    return ax
