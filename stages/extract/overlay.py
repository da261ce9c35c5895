"""Pictures of extracted features for a person to check by eye (``fieldloc show points``).

``points_figure`` draws one frame: the image with the extracted line points (omni: ``points_px``;
perspective: line segments and crossings in the image), and, given a field model and a pose,
the points moved into the field frame over the field drawing, with the share of points within
``near`` metres of a field line. ``show_points`` loads a dataset frame (features from a file or
extracted on the spot) and writes the PNG.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from ..common.dataset import frame_index, open_dataset, read_image, truth_at
from ..common.errors import FieldlocError
from ..common.geometry import robot_to_field

log = logging.getLogger(__name__)

POINT_COLOUR = "#ff2a7f"


def line_point_share(field_model, pose, points_robot, near: float = 0.15) -> float:
    """Share of line points (robot frame) within ``near`` metres of a field line at ``pose``."""
    p = np.asarray(points_robot, float).reshape(-1, 2)
    if len(p) == 0:
        return math.nan
    d = field_model.distance_to_lines(robot_to_field(pose, p))
    return float(np.mean(d <= near))


def points_figure(image_bgr, arrays: dict, *, field_model=None, pose=None, title: str = "",
                  near: float = 0.15):
    """A matplotlib figure (Agg canvas): the frame with its extracted features, and the line
    points on the field at ``pose`` when a field model and a pose are given."""
    from ..show.field import draw_field
    from ..show.figure import new_figure

    on_field = field_model is not None and pose is not None
    fig = new_figure(12.0 if on_field else 6.5, 6.0)
    ax = fig.add_subplot(1, 2 if on_field else 1, 1)
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
    if on_field:
        ax2 = fig.add_subplot(1, 2, 2)
        draw_field(ax2, field_model)
        x, y, th = pose
        pts = arrays.get("points", np.zeros((0, 2)))
        if len(pts):
            f = robot_to_field(pose, pts)
            ax2.scatter(f[:, 0], f[:, 1], s=5, c=POINT_COLOUR, edgecolors="none", zorder=5)
        ax2.plot([x], [y], "o", color="black", ms=5, zorder=6)
        ax2.arrow(x, y, 0.5 * math.cos(th), 0.5 * math.sin(th), width=0.03, color="black",
                  zorder=6)
        share = line_point_share(field_model, pose, pts, near)
        ax2.set_title(f"pose x {x:.2f} m, y {y:.2f} m, heading {math.degrees(th):.1f} deg;"
                      f" {share:.0%} of points within {near * 100:.0f} cm of a line"
                      if np.isfinite(share) else "no line points", fontsize=9)
    return fig


def show_points(dataset_dir, frame, output, *, features=None, field=None, pose=None,
                conf=None, overrides=None, overwrite=False,
                field_file=None) -> tuple[Path, dict]:
    """Write the overlay of one frame to ``output`` (PNG). ``features``: a features file to
    read the frame from (default: extract it now with ``conf`` (preset name or dict) and
    ``overrides``, see stages.extract.resolve_extract_conf); ``field``: a FieldModel;
    ``pose``: (x, y, theta) in metres and radians (default: truth.csv's pose at the frame, if
    any); ``field_file``: the map or field YAML it came from. ``output`` is never an input
    and an existing one is replaced only with ``overwrite``. Returns the path and a summary
    (points, share near lines, pose used)."""
    from ..common.artifacts import check_output
    from ..show.figure import save_figure
    from . import kind_module, read_mask, resolve_extract_conf

    ds = open_dataset(dataset_dir)
    check_output(output, {**ds.files(), "features": features, "map or field": field_file},
                 overwrite=overwrite)
    i = frame_index(ds.names, frame, str(ds.root))
    name, stamp = ds.names[i], float(ds.stamps[i])
    image = read_image(ds.images[i])
    if features is not None:
        from ..common.features_file import FeaturesFile

        with FeaturesFile(features) as ff:
            if name not in ff.names:
                raise FieldlocError(f"{features}: no frame '{name}' (extract it first)")
            arrays = ff.frame(name)
    else:
        camera = ds.camera()
        c = resolve_extract_conf(camera.kind, conf, overrides)
        info = {}
        if camera.kind == "omni" and (ds.root / "mask.png").is_file():
            info["mask"] = read_mask(ds.root / "mask.png", camera.image_size)
        arrays = kind_module(camera.kind).extract_frame(image, camera, c, **info)
    if pose is None and field is not None:
        pose = truth_at(ds.optional("truth"), stamp)
        if pose is None:
            log.warning("no --pose and no truth at frame %s: drawing the image only", name)
    fig = points_figure(image, arrays, field_model=field, pose=pose,
                        title=f"{ds.root.name} frame {name}")
    path = save_figure(fig, output)
    summary = {"frame": name, "points": int(len(arrays.get("points", ()))), "pose": pose}
    if field is not None and pose is not None:
        summary["share_near_lines"] = line_point_share(field, pose, arrays.get("points", ()))
    return path, summary
