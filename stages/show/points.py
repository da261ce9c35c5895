"""The extracted features of one frame for a person to check by eye (``fieldloc show points``).

``draw_image_features`` draws the frame with its extracted features into an ``ax`` (omni: the
line points ``points_px``; perspective: line segments, crossings and the field boundary in the
image); ``draw_points_on_field`` draws the line points moved into the field frame at a pose
over the field, with the share of points within ``near`` metres of a field line.
``points_figure`` puts the two side by side (stages.pipelines.frame_points reads or extracts
the frame's features and writes the picture: ``fieldloc show points``).
"""

from __future__ import annotations

import math

import numpy as np

from ..common.geometry import robot_to_field
from .field import draw_field
from .figure import new_figure

POINT_COLOUR = "#ff2a7f"
NEAR = 0.15  # m: a line point this close to a field line counts as on it


def line_point_share(field_model, pose, points_robot, near: float = NEAR) -> float:
    """Share of line points (robot frame) within ``near`` metres of a field line at ``pose``."""
    p = np.asarray(points_robot, float).reshape(-1, 2)
    if len(p) == 0:
        return math.nan
    d = field_model.distance_to_lines(robot_to_field(pose, p))
    return float(np.mean(d <= near))


def draw_image_features(ax, image_bgr, arrays: dict, *, title: str = ""):
    """The frame (BGR) with its extracted features in image coordinates."""
    ax.imshow(image_bgr[..., ::-1])
    n_pts = 0
    if "points_px" in arrays and len(arrays["points_px"]):
        px = arrays["points_px"]
        ax.scatter(px[:, 0], px[:, 1], s=6, c=POINT_COLOUR, edgecolors="none")
        n_pts = len(px)
    if "line_ends_px" in arrays and len(arrays["line_ends_px"]):
        for u0, v0, u1, v1 in arrays["line_ends_px"]:
            ax.plot([u0, u1], [v0, v1], "-", color=POINT_COLOUR, lw=1.5)
    if "crossings_px" in arrays and len(arrays["crossings_px"]):
        c = arrays["crossings_px"]
        ax.scatter(c[:, 0], c[:, 1], s=40, facecolors="none", edgecolors="cyan")
    if "boundary" in arrays and len(arrays["boundary"]):
        b = arrays["boundary"]
        ax.plot(b[:, 0], b[:, 1], "-", color="yellow", lw=1)
    ax.set_title(f"{title}  {n_pts} line points" if n_pts else title, fontsize=9)
    ax.set_axis_off()


def draw_points_on_field(ax, field_model, pose, points, *, near: float = NEAR):
    """The line points (robot frame) placed on the field at ``pose`` (x, y, theta), the robot
    as a dot and an arrow, and the share of points near a line in the title."""
    draw_field(ax, field_model)
    x, y, th = pose
    pts = points
    if len(pts):
        f = robot_to_field(pose, pts)
        ax.scatter(f[:, 0], f[:, 1], s=5, c=POINT_COLOUR, edgecolors="none", zorder=5)
    ax.plot([x], [y], "o", color="black", ms=5, zorder=6)
    ax.arrow(x, y, 0.5 * math.cos(th), 0.5 * math.sin(th), width=0.03, color="black",
             zorder=6)
    share = line_point_share(field_model, pose, pts, near)
    ax.set_title(f"pose x {x:.2f} m, y {y:.2f} m, heading {math.degrees(th):.1f} deg;"
                 f" {share:.0%} of points within {near * 100:.0f} cm of a line"
                 if np.isfinite(share) else "no line points", fontsize=9)


def points_figure(image_bgr, arrays: dict, *, field_model=None, pose=None, title: str = "",
                  near: float = NEAR):
    """A figure: the frame with its extracted features, and the line points on the field at
    ``pose`` beside it when a field model and a pose are given."""
    on_field = field_model is not None and pose is not None
    fig = new_figure(12.0 if on_field else 6.5, 6.0)
    draw_image_features(fig.add_subplot(1, 2 if on_field else 1, 1), image_bgr, arrays,
                        title=title)
    if on_field:
        draw_points_on_field(fig.add_subplot(1, 2, 2), field_model, pose,
                             arrays.get("points", np.zeros((0, 2))), near=near)
    return fig
