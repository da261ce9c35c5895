"""The belief of one frame's observations on a grid of poses, drawn like seed 000's fig. 3.

The observation model of the particle filter (stages.localize.observation_model) is evaluated
at every pose of a regular grid: positions every ``resolution`` metres over the field and its
surroundings, headings every ``heading_step`` radians; per position the best heading is kept.
Four panels: lines only, crossings only, goal posts only, all together. Each shows the
likelihood (relative to the panel's best pose; one colour bar for all four) as an image, with
arrows of the best heading every ``arrow_spacing`` metres where the likelihood is at least
``arrow_min`` of the best, sized by it, as the seed draws its particles. A panel with no
observations (or a flat likelihood) says so instead of marking a "best pose".

    from stages.localize import belief
    belief.main(belief.confs["default"], "data/walk", "kidsize.map.h5", "belief.png", frame=12)
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np

from stages.common.conf import resolve_conf
from stages.common.dataset import frame_index, readable_truth, truth_at
from stages.common.errors import DatasetError, FieldlocError
from stages.common.observations import Observations

from .observation_model import DEFAULTS as OBSERVATION_DEFAULTS
from .observation_model import PARTS, ObservationModel

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


def belief_grid(model: ObservationModel, obs: Observations, *, resolution: float = 0.1,
                heading_step: float = math.radians(5.0), margin: float = 0.5) -> dict:
    """Log-likelihood of ``obs`` over a grid of poses, best heading per position.

    Returns a dict with ``xs`` (nx,), ``ys`` (ny,) and, per part ("lines", "crossings",
    "posts", "all"), ``<part>`` (ny, nx) the best log-likelihood over the headings and
    ``<part>_theta`` (ny, nx) that heading; ``counts``: observations used per part."""
    if resolution <= 0 or heading_step <= 0:
        raise FieldlocError("belief grid: resolution and heading step must be > 0")
    fm = model.field
    hx, hy = fm.length / 2 + margin, fm.width / 2 + margin
    xs = np.arange(-hx, hx + 1e-9, resolution)
    ys = np.arange(-hy, hy + 1e-9, resolution)
    thetas = np.arange(-math.pi, math.pi - 1e-9, heading_step)
    gx, gy = np.meshgrid(xs, ys)
    px, py = gx.ravel(), gy.ravel()
    prep = model.prepare(obs)
    best = {k: np.full(px.shape, -np.inf) for k in (*PARTS, "all")}
    best_th = {k: np.zeros(px.shape) for k in best}
    for th in thetas:  # one heading at a time: every position is one "particle"
        parts = model.log_likelihood(px, py, np.full(px.shape, th), prep, parts=True)
        parts["all"] = parts["lines"] + parts["crossings"] + parts["posts"]
        for k, v in parts.items():
            better = v > best[k]
            best[k] = np.where(better, v, best[k])
            best_th[k] = np.where(better, th, best_th[k])
    shape = gx.shape
    out = {"xs": xs, "ys": ys, "thetas": thetas}
    for k in best:
        out[k] = best[k].reshape(shape)
        out[f"{k}_theta"] = best_th[k].reshape(shape)
    o = prep.obs
    out["counts"] = {"lines": len(o.lines), "crossings": len(o.crossings),
                     "posts": len(o.posts)}
    return out


def draw_belief(fig, field_model, grid: dict, *, truth=None, arrow_spacing: float = 0.5,
                arrow_min: float = 0.25, title: str | None = None):
    """Draw the four panels of ``grid`` (from ``belief_grid``) into ``fig``, with one colour
    bar. Returns the axes (2, 2)."""
    axes = fig.subplots(2, 2)
    xs, ys = grid["xs"], grid["ys"]
    res = float(xs[1] - xs[0]) if len(xs) > 1 else 0.1
    extent = (xs[0] - res / 2, xs[-1] + res / 2, ys[0] - res / 2, ys[-1] + res / 2)
    counts = grid["counts"]
    every = max(1, int(round(arrow_spacing / res)))
    image = None
    for ax, (key, label) in zip(axes.ravel(), PANELS):
        _draw_field(ax, field_model)
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


def _draw_field(ax, field_model):
    try:
        from stages.show.field import draw_field
    except ImportError:  # a plain drawing of the centre lines
        for (x0, y0), (x1, y1) in field_model.segments:
            ax.plot([x0, x1], [y0, y1], color="white", lw=1, zorder=1)
        ax.set_facecolor("#3a8a3a")
        return
    draw_field(ax, field_model, zorder=0)


# ---------------------------------------------------------------------------- inputs


def frame_observations(dataset_dir: Path, frame: str | int, features: Path | None):
    """(name, stamp, Observations) of one frame: from ``features``, else DIR/features.h5 if
    present, else extracted from the frame's image on the fly."""
    from stages.common.dataset import open_dataset
    from stages.common.features_file import FeaturesFile

    if features is None and (dataset_dir / "features.h5").is_file():
        features = dataset_dir / "features.h5"
    if features is not None:
        with FeaturesFile(features) as ff:
            name = ff.names[frame_index(ff.names, frame, str(features))]
            data = ff.frame(name)
            return name, float(data["stamp"]), Observations.from_features(data)
    ds = open_dataset(dataset_dir)
    i = frame_index(ds.names, frame, str(dataset_dir))
    name = ds.names[i]
    from stages import extract
    from stages.common.dataset import read_image

    camera = ds.camera()
    if camera.kind != "perspective":
        raise FieldlocError(
            f"{dataset_dir}: a '{camera.kind}' camera; the belief needs perspective features"
            " (lines, crossings, goal posts)")
    module = extract.kind_module(camera.kind)
    conf = extract.resolve_extract_conf(camera.kind)
    info = {}
    head = ds.optional("head")
    if head is not None and len(head["stamp"]):
        k = int(np.argmin(np.abs(head["stamp"] - ds.stamps[i])))
        if abs(head["stamp"][k] - ds.stamps[i]) <= extract.HEAD_STAMP_TOLERANCE:
            info = {"pitch": float(head["pitch"][k]), "roll": float(head["roll"][k])}
    result = module.extract_frame(read_image(ds.images[i]), camera, conf, **info)
    return name, float(ds.stamps[i]), Observations.from_features(result)


# ---------------------------------------------------------------------------- main


def main(conf: dict | str | None, dataset_dir: str | Path, map_path: str | Path,
         output: str | Path, *, frame: str | int = 0, features: str | Path | None = None,
         overwrite: bool = False) -> Path:
    """Draw the belief of one frame's observations on the map's field into ``output`` (PNG).
    ``frame``: a frame name or index."""
    from stages.common.map_file import MapFile
    from stages.show.figure import new_figure, save_figure

    conf = resolve_conf(confs, conf) if not isinstance(conf, dict) else resolve_conf(
        confs, "default", conf)
    from stages.common.artifacts import check_output
    from stages.common.dataset import open_dataset

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
        draw_belief(fig, mf.field, grid, truth=truth_at(readable_truth(dataset_dir), stamp),
                    arrow_spacing=float(conf["arrow_spacing"]),
                    arrow_min=float(conf["arrow_min"]),
                    title=f"{dataset_dir.name} frame {name} (t = {stamp:.2f} s): belief from"
                    " one frame's observations; yellow: best pose, white: truth")
    return save_figure(fig, output)
