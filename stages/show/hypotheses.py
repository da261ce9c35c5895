"""The hypotheses of one frame of a poses file, drawn on the field: each hypothesis as a robot
(a disc with its heading) labelled with its probability, and the frame's line points placed on
the field at each of them (the points of a good hypothesis lie on the lines), the truth when
the dataset has it.

    main(conf, poses, output, *, frame=0, features=None, field=None, overwrite=False) -> Path
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..common.conf import stage_conf
from ..common.dataset import frame_index, readable_truth, truth_at
from ..common.errors import FieldlocError
from ..common.field import field_file, load_field
from ..common.geometry import robot_to_field

confs = {"default": {"max_hypotheses": 5, "min_probability": 0.0, "robot_radius": 0.25}}

COLOURS = ("#ffd400", "#00c8ff", "#ff4fa3", "#a0ff40", "#ff8c00", "#c080ff", "#ffffff")


def draw_hypotheses(ax, field_model, hypotheses: np.ndarray, points: np.ndarray | None = None,
                    *, truth=None, robot_radius: float = 0.25, title: str = ""):
    """Draw ``hypotheses`` ((k, 4) x, y, theta, probability, ranked) on the field in ``ax``,
    with ``points`` ((n, 2) robot frame) placed at each, and ``truth`` (x, y, theta)."""
    from .field import draw_field

    draw_field(ax, field_model, zorder=0)
    h = np.asarray(hypotheses, float).reshape(-1, 4)
    h = h[np.isfinite(h[:, 0])]
    if not len(h):
        ax.text(0.5, 0.5, "no hypothesis (the frame failed)", transform=ax.transAxes,
                ha="center", va="center", color="white", fontsize=12,
                bbox={"facecolor": "black", "alpha": 0.6})
    for k, (x, y, th, p) in enumerate(h):
        colour = COLOURS[k % len(COLOURS)]
        if points is not None and len(points):
            q = robot_to_field((x, y, th), points)
            ax.scatter(q[:, 0], q[:, 1], s=4, color=colour, alpha=0.8, zorder=2 + k * 0.01)
        ax.add_patch(_robot(x, y, robot_radius, colour))
        ax.annotate("", xy=(x + 2.2 * robot_radius * math.cos(th),
                            y + 2.2 * robot_radius * math.sin(th)), xytext=(x, y),
                    arrowprops={"arrowstyle": "->", "color": colour, "lw": 2}, zorder=5)
        ax.text(x + robot_radius, y + robot_radius, f"{k + 1}: {p:.2f}", color=colour,
                fontsize=9, fontweight="bold", zorder=6,
                bbox={"facecolor": "black", "alpha": 0.5, "pad": 1, "lw": 0})
    if truth is not None:
        x, y, th = truth
        ax.add_patch(_robot(x, y, robot_radius, "none", edge="white"))
        ax.annotate("", xy=(x + 2.2 * robot_radius * math.cos(th),
                            y + 2.2 * robot_radius * math.sin(th)), xytext=(x, y),
                    arrowprops={"arrowstyle": "->", "color": "white", "lw": 1.5,
                                "ls": "--"}, zorder=5)
    ax.set_aspect("equal")
    if title:
        ax.set_title(title, fontsize=10)


def _robot(x, y, r, colour, edge="black"):
    from matplotlib.patches import Circle

    return Circle((x, y), r, facecolor=colour, edgecolor=edge, lw=1.2, alpha=0.8, zorder=4)


def main(conf: str | dict | None, poses: str | Path, output: str | Path, *,
         frame: str | int = 0, features: str | Path | None = None,
         field: str | Path | None = None, overwrite: bool = False,
         progress: bool = False) -> Path:
    """Draw the hypotheses of one frame (name or index) of ``poses`` into ``output`` (PNG).
    Points from ``features`` (default: the features file the poses were made from), the field
    from ``field`` (default: the poses file's)."""
    from ..common.features_file import FeaturesFile
    from ..common.poses_file import read_poses, run_inputs
    from .figure import check_picture_output, new_figure, save_figure

    conf = stage_conf(confs, conf)
    output = Path(output)
    cols, attrs = read_poses(poses)
    check_picture_output(output, {"poses": poses, "features": features,
                                  "field": field_file(field), **run_inputs(attrs)},
                         overwrite=overwrite)
    names = [str(n) for n in cols["name"]]
    i = frame_index(names, frame, str(poses))
    fm = poses_field(attrs, field)
    h = cols["hypotheses"][i]
    h = h[np.isfinite(h[:, 3]) & (h[:, 3] >= conf["min_probability"])][:conf["max_hypotheses"]]
    points = None
    features = features or attrs.get("inputs", {}).get("features")
    if features and Path(features).is_file():
        with FeaturesFile(features) as ff:
            if names[i] in ff.names:
                data = ff.frame(names[i])
                if "points" in data:
                    points = np.asarray(data["points"], float)
                elif "line_ends" in data:
                    points = np.asarray(data["line_ends"], float).reshape(-1, 2)
    truth = truth_at(readable_truth(attrs.get("dataset")), float(cols["stamp"][i]))
    xmin, xmax, ymin, ymax = fm.world_bounds()
    fig = new_figure(10.0, max(4.0, 10.0 * (ymax - ymin) / (xmax - xmin)))
    ax = fig.add_subplot()
    state = ("failed: " + str(cols["flags"][i]).split(",")[-1]) if cols["failed"][i] else (
        "accepted" if cols["accepted"][i] else "low confidence")
    draw_hypotheses(ax, fm, h, points, truth=truth, robot_radius=conf["robot_radius"],
                    title=f"{Path(poses).name} frame {names[i]} ({state})\nhypotheses with"
                    " their probabilities, the frame's points at each"
                    + ("; dashed white: truth" if truth is not None else "; no truth"))
    return save_figure(fig, output)


def poses_field(attrs: dict, field=None):
    """The field to draw a poses file's frames on: ``field`` when given, else the field of
    the map the poses were made with (a custom field's map carries its field; its name is no
    preset), else the field the poses file names."""
    if field:
        return load_field(field)
    map_path = (attrs.get("inputs") or {}).get("map")
    if isinstance(map_path, str) and Path(map_path).is_file():
        from ..common.map_file import MapFile

        with MapFile(map_path) as m:
            return m.field
    name = attrs.get("field") or ""
    if not name:
        raise FieldlocError("the poses file names no field and no map: give --field")
    try:
        return load_field(name)
    except FieldlocError as e:
        raise FieldlocError(f"{e}; the map the poses were made with is not at hand"
                            f" ({map_path or 'none named'}): give --field") from None


