"""The extracted features of one frame for a person to check by eye (``fieldloc show points``).

``draw_image_features`` draws the frame with its extracted features into an ``ax`` (omni: the
line points ``points_px``; perspective: line segments, crossings and the field boundary in the
image); ``draw_points_on_field`` draws the line points moved into the field frame at a pose
over the field, with the share of points within ``near`` metres of a field line.
``points_figure`` puts the two side by side; ``main`` loads a dataset frame (features from a
file, or extracted on the spot) and writes the PNG.

    main(conf, dataset_dir, output, *, frame=0, features=None, field=None, pose=None,
         overwrite=False) -> Path
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from ..common.artifacts import check_output
from ..common.dataset import frame_index, open_dataset, read_image, truth_at
from ..common.errors import FieldlocError
from ..common.features_file import FeaturesFile
from ..common.geometry import robot_to_field
from .field import draw_field
from .figure import new_figure, save_figure

log = logging.getLogger(__name__)

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


def write_picture(conf, dataset_dir, output, *, frame: str | int = 0, features=None,
                  field=None, pose=None, overwrite: bool = False,
                  field_file=None) -> tuple[Path, dict]:
    """``main``, returning the path and a summary of the frame drawn: its name, its number of
    line points, the pose used and the share of points near a line at that pose."""
    from .. import extract

    ds = open_dataset(dataset_dir)
    check_output(output, {**ds.files(), "features": features, "map or field": field_file},
                 overwrite=overwrite)
    i = frame_index(ds.names, frame, str(ds.root))
    name, stamp = ds.names[i], float(ds.stamps[i])
    image = read_image(ds.images[i])
    if features is not None:
        with FeaturesFile(features) as ff:
            if name not in ff.names:
                raise FieldlocError(f"{features}: no frame '{name}' (extract it first)")
            arrays = ff.frame(name)
    else:
        # as extract.main does it: the omni mask, the perspective head angles of head.csv
        c = extract.resolve_extract_conf(ds.camera().kind, conf)
        arrays = extract.extract_dataset_frame(ds, i, c)
    if pose is None and field is not None:
        pose = truth_at(ds.optional("truth"), stamp)
        if pose is None:
            log.warning("no --pose and no truth at frame %s: drawing the image only", name)
    fig = points_figure(image, arrays, field_model=field, pose=pose,
                        title=f"{ds.root.name} frame {name}")
    path = save_figure(fig, output)
    summary = {"frame": name, "pose": pose}
    if "points" in arrays:  # omni: line points; perspective: lines (no share over no points)
        summary["points"] = int(len(arrays["points"]))
        if field is not None and pose is not None and len(arrays["points"]):
            summary["share_near_lines"] = line_point_share(field, pose, arrays["points"])
    else:
        summary["lines"] = int(len(arrays.get("lines", ())))
    return path, summary


def main(conf, dataset_dir, output, *, frame: str | int = 0, features=None, field=None,
         pose=None, overwrite: bool = False, field_file=None, progress: bool = False) -> Path:
    """Write the picture of one frame (name or position) of ``dataset_dir`` to ``output``
    (PNG). ``features``: a features file to read the frame from (default: extract it now with
    ``conf``, an extract preset name or dict, see stages.extract); ``field``: a FieldModel to
    place the points on; ``pose``: (x, y, theta) in metres and radians (default: truth.csv's
    pose at the frame, if any); ``field_file``: the map or field YAML the field came from.
    ``output`` is never an input, and an existing one is replaced only with ``overwrite``."""
    return write_picture(conf, dataset_dir, output, frame=frame, features=features,
                         field=field, pose=pose, overwrite=overwrite, field_file=field_file)[0]
