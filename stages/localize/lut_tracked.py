"""The table search of a track (Ribeiro et al. (2015), section IV-B, the local search around a
tracked prior): the window around the prior ranked by the posterior, the quantised error term
/ temperature plus the prior's capped Mahalanobis term. Functions of the map's tables
(lut_tables.LutTables); a frame's data passes through their arguments only.

A track's fix (``tracked_fix``: the window's best cell by the posterior, the refinement of its
basin and of the prior's, the support, the line points' fit) is one compiled call
(``lut_kernels.tracked_fix``). The window's best cell is found by branch and bound on the
min-pooled lookup (``lut_kernels.tracked_window``, as lut_local's window), and a lower bound of
its score from the min-pooled lookup alone (``tracked_score_bound``) lets lut drop a
hypothesis without computing its window.
"""

from __future__ import annotations

import math

import numpy as np

from . import lut_kernels
from .lut_kernels import LineFit, tracked_window, tracked_window_bound
from .lut_local import SearchResult, local_window
from .lut_matching import Observation
from .lut_tables import LutTables, support_from_sums

_NO_POINTS = np.zeros((0, 2))
_NO_RASTER = np.zeros((2, 2), dtype=np.float32)


def tracked_fix(tables: LutTables, obs: Observation, theta: float, prior_xy,
                prior_information, temperature: float, fix_temperature: float,
                inlier_error: float, *, half_width: float = 1.0, prior_cap: float = math.inf,
                fit=None):
    """The paper's local search around a tracked prior, ranked by the posterior, in one
    compiled call (``lut_kernels.tracked_fix``): in the window (2 half_width square)
    around ``prior_xy`` the cell minimising E(cell) / temperature + min(0.5 d^T
    ``prior_information`` d, ``prior_cap``) (d = cell - prior, the prior's inverse
    position covariance (2, 2); the cap: a prior that may be wrong, a Gaussian with a
    uniform floor), refined to sub-cell in its basin (lut_local.refine). The window's choice
    rests on the lookup's quantised error term: when it lies more than two cells from
    the prior, the basin the prior lies in is refined too and taken when its exact error
    / ``fix_temperature`` + the capped Mahalanobis term is lower. ``fit``: (PointFit, the
    observations' points, max_shift, max_turn): the fix is then moved by the line
    points' fit at its heading (PointFit.refine with ``fixed_heading``) after its support
    is counted (its ``cell``, ``error`` and Hessian stay the table's). Returns (fix, its
    ``support`` with ``inlier_error``, the posterior score of the window's best cell,
    the fix's position (x, y) before the points' fit)."""
    pf, points, max_shift, max_turn = fit if fit is not None else (None, _NO_POINTS, 0, 0)
    line_fit = LineFit(
        pf is not None, *((pf.table, *pf.origin, pf.resolution) if pf is not None
                          else (_NO_RASTER, 0.0, 0.0, 1.0)),
        points, pf.c * pf.c if pf is not None else 1.0, float(theta),
        float(min(max_shift, 1e9)), float(min(max_turn, 1e9)))
    rule = (max(obs.total_weight, 1e-12), float(fix_temperature), float(inlier_error),
            tables.params.c * tables.params.c)  # lut_kernels.FixRule
    out = np.empty(19)
    lut_kernels.tracked_fix(
        tables.quantised, tables.min_pooled, tables.observed(obs), tables.at_heading(theta),
        local_window(tables, prior_xy[0], prior_xy[1], half_width), tables.kernel_grid,
        _posterior(tables, prior_xy, prior_information, temperature, prior_cap), rule,
        line_fit, out)
    x, y, e, e_norm, ci, cj, hxx, hxy, hyy, edge, window_fit, own = out[:12].tolist()
    fix = SearchResult(x=x, y=y, theta=float(theta), error=e, error_norm=e_norm,
                       cell=(int(ci), int(cj)), n_observations=len(obs),
                       hessian=np.array([[hxx, hxy], [hxy, hyy]]),
                       at_window_edge=edge > 0, mode="local")
    n, w_in, rho, sq, fx, fy, fth = out[12:].tolist()
    if pf is not None:
        fix.x, fix.y, fix.theta = fx, fy, fth
    return fix, support_from_sums(obs, n, w_in, rho, sq), window_fit, (x, y)


def tracked_score(tables: LutTables, obs: Observation, theta: float, prior_xy,
                  prior_information, temperature: float, *, half_width: float = 1.0,
                  prior_cap: float = math.inf) -> float:
    """The best posterior score of ``tracked_fix``'s window (quantised error term /
    temperature + capped Mahalanobis term), without refining it."""
    return window_best(tables, obs, theta, prior_xy, prior_information, temperature,
                       half_width, prior_cap)[1]


def tracked_score_bound(tables: LutTables, obs: Observation, theta: float, prior_xy,
                        prior_information, temperature: float, *, half_width: float = 1.0,
                        prior_cap: float = math.inf) -> float:
    """A lower bound of ``tracked_score`` from the min-pooled error lookup (the
    unknown-heading search's; ``tracked_window_bound``): never above it, about
    ``coarse_step``^2 times cheaper, so a score below the bound is below the score."""
    return tracked_window_bound(
        tables.min_pooled, tables.observed(obs), tables.scanlines.heading_index(theta),
        local_window(tables, prior_xy[0], prior_xy[1], half_width), tables.kernel_grid,
        _posterior(tables, prior_xy, prior_information, temperature, prior_cap))


def window_best(tables: LutTables, obs: Observation, theta: float, prior_xy, info,
                temperature: float, half_width: float, cap: float) -> tuple:
    """The window's best cell by the posterior (flat index) and its score (``tracked_score``),
    by branch and bound (``lut_kernels.tracked_window``)."""
    return tracked_window(
        tables.quantised, tables.min_pooled, tables.observed(obs),
        tables.scanlines.heading_index(theta),
        local_window(tables, prior_xy[0], prior_xy[1], half_width), tables.kernel_grid,
        _posterior(tables, prior_xy, info, temperature, cap))


def _posterior(tables: LutTables, prior_xy, info, temperature: float, cap: float) -> tuple:
    """The tracked kernels' ranking (lut_kernels.Posterior, as a plain tuple): the error
    term's scale (1 / (q_levels temperature)), the prior's position, its information
    (xx, xy, yy) and the Mahalanobis term's cap."""
    return (1.0 / (tables.q_levels * temperature), float(prior_xy[0]), float(prior_xy[1]),
            float(info[0, 0]), float(info[0, 1]), float(info[1, 1]),
            float(min(cap, 1e300)))

