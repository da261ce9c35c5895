"""The belief of one frame's observations on a grid of poses (fig. 3 of Schulz et al. 2011, drawn by
stages.show.belief): the observation model of the particle filter
(stages.localize.observation_model) evaluated at every pose of a regular grid, positions every
``resolution`` metres over the field and its surroundings, headings every ``heading_step``
radians, the best heading kept per position; per kind of observation and for all together.
"""

from __future__ import annotations

import math

import numpy as np

from stages.common.errors import FieldlocError
from stages.common.observations import Observations

from .observation_model import PARTS, ObservationModel


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
