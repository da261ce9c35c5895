"""The belief of one frame's observations on a grid of poses, drawn like fig. 3 of Schulz et al.
(2011).

The likelihood of the frame's observations under the particle filter's observation model
(stages.localize.belief.belief_grid) in four panels: lines only, crossings only, goal posts
only, all together. Each shows the likelihood (relative to the panel's best pose; one colour
bar for all four) as an image, with arrows of the best heading every ``arrow_spacing`` metres
where the likelihood is at least ``arrow_min`` of the best, sized by it, as the paper draws its
particles. A panel with no observations (or a flat likelihood) says so instead of marking a
"best pose".

    from stages.show import belief
    belief.main(None, "data/walk", "kidsize.map.h5", "belief.png", frame=12)
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np

from ..common.artifacts import check_output
from ..common.conf import stage_conf
from ..common.dataset import frame_index, open_dataset, readable_truth, truth_at
from ..common.errors import DatasetError, FieldlocError
from ..common.features_file import REQUIRED, FeaturesFile
from ..common.map_file import MapFile
from ..common.observations import Observations
from ..localize.belief import belief_grid
from ..localize.observation_model import DEFAULTS as OBSERVATION_DEFAULTS
from ..localize.observation_model import ObservationModel
from .field import draw_field
from .figure import new_figure, save_figure

confs = {
    "default": {
        "resolution": 0.1,  # m between grid positions
        "heading_step": math.radians(5.0),  # rad between grid headings
        "margin": 0.5,  # m of surroundings shown around the field
        "arrow_spacing": 0.5,  # m between the arrows of the best heading
        "arrow_min": 0.25,  # arrows only where the likelihood is this share of the best
        "observation": copy.deepcopy(OBSERVATION_DEFAULTS),
    },
}

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


# ---------------------------------------------------------------------------- inputs


def frame_observations(dataset_dir: Path, frame: str | int, features: Path | None):
    """(name, stamp, Observations) of one frame: from ``features``, else DIR/features.h5 if
    present, else extracted from the frame's image on the fly (extract's default conf)."""
    if features is None and (dataset_dir / "features.h5").is_file():
        features = dataset_dir / "features.h5"
    if features is not None:
        with FeaturesFile(features) as ff:
            name = ff.names[frame_index(ff.names, frame, str(features))]
            data = ff.frame(name)
            return name, float(data["stamp"]), Observations.from_features(data)
    from .. import extract

    ds = open_dataset(dataset_dir)
    i = frame_index(ds.names, frame, str(dataset_dir))
    camera = ds.camera()
    if not {"lines", "crossings", "posts"} <= set(REQUIRED.get(camera.kind, ())):
        raise FieldlocError(
            f"{dataset_dir}: a '{camera.kind}' camera; the belief needs perspective features"
            " (lines, crossings, goal posts)")
    result = extract.extract_dataset_frame(ds, i, extract.resolve_extract_conf(camera.kind))
    return ds.names[i], float(ds.stamps[i]), Observations.from_features(result)


# ---------------------------------------------------------------------------- main


def main(conf: dict | str | None, dataset_dir: str | Path, map_path: str | Path,
         output: str | Path, *, frame: str | int = 0, features: str | Path | None = None,
         overwrite: bool = False, progress: bool = False) -> Path:
    """Draw the belief of one frame's observations on the map's field into ``output`` (PNG).
    ``frame``: a frame name or position."""
    conf = stage_conf(confs, conf)
    output = Path(output)
    dataset_dir = Path(dataset_dir)
    if not dataset_dir.is_dir():
        raise DatasetError(f"dataset folder not found: {dataset_dir}")
    check_output(output, {**open_dataset(dataset_dir, need_images=False).files(),
                          "map": map_path, "features": features}, overwrite=overwrite)
    name, stamp, obs = frame_observations(dataset_dir, frame,
                                          None if features is None else Path(features))
    with MapFile(map_path) as mf:
        model = ObservationModel.from_map(mf, conf["observation"])
        grid = belief_grid(model, obs, resolution=float(conf["resolution"]),
                           heading_step=float(conf["heading_step"]),
                           margin=float(conf["margin"]))
        fig = new_figure(12.0, 8.5)
        draw_belief(fig.subplots(2, 2), mf.field, grid,
                    truth=truth_at(readable_truth(dataset_dir), stamp),
                    arrow_spacing=float(conf["arrow_spacing"]),
                    arrow_min=float(conf["arrow_min"]),
                    title=f"{dataset_dir.name} frame {name} (t = {stamp:.2f} s): belief from"
                    " one frame's observations; yellow: best pose, white: truth")
    return save_figure(fig, output)
