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
from stages.common.resources import check_memory

from .observation_model import PARTS, ObservationModel

# the finest grid drawn: a centimetre between positions (a line is 5 cm wide and a cell of the
# picture a few centimetres; finer shows nothing more) and a tenth of a degree between headings
# (the observation model's heading sigmas are degrees)
MIN_RESOLUTION = 0.01  # m
MIN_HEADING_STEP = math.radians(0.1)  # rad
# the most poses (positions x headings) one grid evaluates: the default grid of a 9 x 6 m field
# holds half a million (10 cm, 5 deg), a second; 1 cm at 5 deg 50 million, 15 s of CPU; this
# many take about a minute
MAX_GRID_POSES = 200_000_000
# bytes per position while the grid is evaluated: its coordinates, the best value and heading
# of each part, their new values for one heading and the kernel's (about 50 float64 arrays;
# measured: 1 cm on a 9 x 6 m field peaks at 400 MB)
BYTES_PER_POSITION = 50 * 8


def grid_axes(length: float, width: float, resolution: float, heading_step: float,
              margin: float) -> tuple[int, int, int]:
    """(positions along x, along y, headings) of the grid over a ``length`` x ``width`` field
    and ``margin`` around it; a grid finer than MIN_RESOLUTION / MIN_HEADING_STEP or of more
    than MAX_GRID_POSES poses, or beyond this machine's memory, is refused (FieldlocError)
    before anything is allocated."""
    if not resolution >= MIN_RESOLUTION:
        raise FieldlocError(f"belief grid: resolution {resolution:g} m is finer than"
                            f" {MIN_RESOLUTION:g} m")
    if not heading_step >= MIN_HEADING_STEP:
        raise FieldlocError(f"belief grid: heading step {math.degrees(heading_step):g} deg is"
                            f" finer than {math.degrees(MIN_HEADING_STEP):g} deg")
    # float arithmetic: a size beyond the largest integer compares, never overflows
    nx = max(math.floor((length + 2 * margin) / resolution + 1e-9), 0) + 1.0
    ny = max(math.floor((width + 2 * margin) / resolution + 1e-9), 0) + 1.0
    nh = max(math.ceil(2 * math.pi / heading_step - 1e-9), 1)
    poses = nx * ny * nh
    if poses > MAX_GRID_POSES:
        raise FieldlocError(
            f"belief grid: {nx:.0f} x {ny:.0f} positions x {nh} headings is {poses:.3g} poses,"
            f" more than {MAX_GRID_POSES:.3g}; choose a coarser resolution or heading step")
    check_memory(f"the belief grid of {nx:.0f} x {ny:.0f} positions",
                 {"positions": nx * ny * BYTES_PER_POSITION})
    return int(nx), int(ny), int(nh)


def belief_grid(model: ObservationModel, obs: Observations, *, resolution: float = 0.1,
                heading_step: float = math.radians(5.0), margin: float = 0.5) -> dict:
    """Log-likelihood of ``obs`` over a grid of poses, best heading per position.

    Returns a dict with ``xs`` (nx,), ``ys`` (ny,) and, per part ("lines", "crossings",
    "posts", "all"), ``<part>`` (ny, nx) the best log-likelihood over the headings and
    ``<part>_theta`` (ny, nx) that heading; ``counts``: observations used per part. The grid's
    size is checked first (``grid_axes``)."""
    fm = model.field
    nx, ny, nh = grid_axes(fm.length, fm.width, resolution, heading_step, margin)
    hx, hy = fm.length / 2 + margin, fm.width / 2 + margin
    xs = -hx + resolution * np.arange(nx)
    ys = -hy + resolution * np.arange(ny)
    thetas = -math.pi + heading_step * np.arange(nh)
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
