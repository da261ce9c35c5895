"""Field line extraction by split-and-merge (Schulz et al. 2011, section 4.2).

A field line is a connected set of degree-2 nodes of the fine line structure graph plus the
nodes of another degree connected directly to it (``line_components``). Its nodes'
undistorted coordinates are processed by split-and-merge:

- ``fit_line``: least-squares (orthogonal) regression of a line to the nodes;
- ``split_component``: the node farthest from the fitted line splits the component in two if
  its distance exceeds the threshold, recursively; components with fewer than three nodes are
  discarded;
- ``merge_segments``: components whose fitted lines have similar parameters are merged (the
  merged fit must still pass the split threshold);
- ``line_end_points``: the final line's end points are the component's end nodes projected
  onto the fitted line (an end node may belong to another line that barely failed the split
  test; with many nodes its influence on the fit is small).

Coordinates here are undistorted ("ideal") pixels, where straight lines are straight. The
compiled kernels these functions call live in ``line_fit_kernels``; this module prepares their
arrays and turns their results into fits, segments and refined lines.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .line_fit_kernels import (
    _distort_all,
    _extent,
    _fit_parts,
    _fit_points,
    _perpendicular_feet,
    _refine_all,
    _similar_kernel,
    _split_all,
    _split_ranges,
    grow_kernel,
    refine_kernel,
)
from .line_structure import LineGraph, flat_lists, trace_chains


class LinesTuning(NamedTuple):
    """The numbers of the field lines: split-and-merge here, the refinement, width and field
    edge checks of the extractor's ``find_lines``. Tuned on the rendered KidSize and NAO
    frames and the HULKs NAO frames (docs/manual.md "Perspective extraction on real
    frames")."""

    split_distance: float  # undistorted px
    min_nodes: int  # smaller parts are discarded
    min_used_nodes: int  # shorter lines (a ball, a robot's white part) are not used
    merge_angle: float  # rad
    merge_offset: float  # undistorted px
    min_length: float  # m, shorter lines are not used
    max_distance: float  # m, lines whose perpendicular is longer are not used
    full_nodes: int  # nodes at which a line's confidence is 1
    # refinement on the full-resolution white mask (line_fit.refine_segment): profiles across
    # the segment every refine_step px, refine_reach cells to each side, from refine_extend
    # cells before to after its ends
    refine: bool
    refine_step: float
    refine_reach: float
    refine_extend: float
    refine_min_points: int
    refine_grow: float  # cells the ends may grow along the refined line
    # the white runs' median width over a painted line's (line_width m) at their floor
    # positions: a seam or cable is thinner, a robot's leg or a post wider
    line_width: float
    width_ratio: tuple[float, float]
    # the field's edge against a bright hall floor is white against green as a line is; it is
    # no line where no carpet lies beyond it (the cells green_beyond_m across it, away from
    # the robot, hold on average less green than min_green_beyond, the boundary's t_weak:
    # never field) and the field boundary ends less than edge_gap_m beyond it (a line's
    # carpet goes on beyond, the SPL's border strip 0.7 m past its outer lines; a sun patch
    # washes the carpet beyond a line out of the green class, but the field goes on past the
    # patch). On the HULKs frames this drops 14 of the 60 false used lines and 1 of the 520
    # others; green alone dropped 18 and 6, and on rendered NAO walks 59 of 264 true lines
    # (7 with the boundary's gap)
    green_beyond_m: float
    min_green_beyond: float
    edge_gap_m: float


LINES = LinesTuning(split_distance=7.0, min_nodes=3, min_used_nodes=4,
                    merge_angle=math.radians(4.0), merge_offset=7.0, min_length=0.3,
                    max_distance=6.0, full_nodes=8, refine=True, refine_step=4.0,
                    refine_reach=2.0, refine_extend=0.5, refine_min_points=4, refine_grow=4.0,
                    line_width=0.05, width_ratio=(0.4, 2.5), green_beyond_m=0.15,
                    min_green_beyond=0.2, edge_gap_m=1.0)


@dataclass
class LineFit:
    centroid: np.ndarray  # (2,)
    direction: np.ndarray  # (2,) unit
    normal: np.ndarray  # (2,) unit
    rms: float  # rms orthogonal residual


@dataclass
class LineSegment:
    nodes: np.ndarray  # (n,) indices into the point array, in order along the line
    fit: LineFit
    ends: np.ndarray  # (2, 2) end points projected on the fitted line


def line_components(graph: LineGraph) -> list[list[int]]:
    """Ordered node lists: each connected set of degree-2 nodes with the nodes of another
    degree attached directly to it (a closed loop is cut at its first node)."""
    return trace_chains(graph)


def fit_line(points: np.ndarray) -> LineFit:
    """Least-squares line through points (n, 2) minimising orthogonal distances (the major
    axis of their 2 x 2 scatter; compiled: ``_fit_points``)."""
    cx, cy, ux, uy, nx, ny, rms = _fit_points(np.asarray(points, np.float64))
    return LineFit(np.array([cx, cy]), np.array([ux, uy]), np.array([nx, ny]), rms)


def point_line_distance(points: np.ndarray, fit: LineFit) -> np.ndarray:
    rel = points - fit.centroid
    return np.abs(rel[:, 0] * fit.normal[0] + rel[:, 1] * fit.normal[1])


def split_component(points: np.ndarray, idx: np.ndarray, max_distance: float,
                    min_nodes: int = 3) -> list[np.ndarray]:
    """Recursive split of one ordered component (indices into ``points``): fit, find the node
    with the largest distance to the line, split there (the node belongs to both halves) while
    that distance exceeds ``max_distance``. When the farthest node is an end node, the chord
    between the ends is the better split test: its farthest interior node splits, or without
    one the end node is dropped. Parts with fewer than ``min_nodes`` are dropped. Every part
    is a run of ``idx``; the recursion runs compiled (``_split_ranges``), depth first, so the
    parts come in order along the component."""
    idx = np.asarray(idx)
    if len(idx) < min_nodes:
        return []
    ranges = np.empty((len(idx), 2), np.int64)
    m = _split_ranges(np.ascontiguousarray(points[idx], np.float64), float(max_distance),
                      int(min_nodes), ranges)
    return [idx[a:b] for a, b in ranges[:m]]


def _ends_on_line(points: np.ndarray, idx: np.ndarray, fit: LineFit) -> np.ndarray:
    """The extreme points of ``points[idx]`` along the fitted line, projected on it (2, 2)."""
    out = np.empty((2, 2))
    _extent(points, np.asarray(idx, np.int64), fit.centroid[0], fit.centroid[1],
            fit.direction[0], fit.direction[1], out)
    return out


def _similar_pairs(cen: np.ndarray, dirs: np.ndarray, nor: np.ndarray, ends: np.ndarray,
                   rows: np.ndarray, cos_max: float, max_offset: float, upper: bool):
    """(offset, i, j) for parts i in ``rows`` and every part j (j > i if ``upper``) whose lines
    are similar: directions within acos(cos_max), end points of each within ``max_offset`` of
    the other's line. Arrays are per part: centroids, directions, normals (P, 2), end points
    (P, 2, 2)."""
    dr = dirs[rows]
    cosine = np.abs(dr[:, None, 0] * dirs[None, :, 0] + dr[:, None, 1] * dirs[None, :, 1])
    # the rest compiled (_similar_kernel): distance of part j's ends to part i's line, and of
    # part i's ends to part j's line, and the pairs within both limits
    off, pi, pj = _similar_kernel(np.ascontiguousarray(cosine), np.ascontiguousarray(cen),
                                  np.ascontiguousarray(nor), np.ascontiguousarray(ends),
                                  np.asarray(rows, np.int64), float(cos_max), float(max_offset),
                                  bool(upper))
    return list(zip(off.tolist(), pi.tolist(), pj.tolist()))


def merge_segments(points: np.ndarray, parts: list[np.ndarray], max_angle: float,
                   max_offset: float, max_distance: float) -> list[np.ndarray]:
    """Merge parts whose fitted lines are similar: directions within ``max_angle`` (rad), the
    end points of each within ``max_offset`` of the other's line, and the merged fit still
    within ``max_distance`` of every node. Greedy, most similar pairs first, until no pair
    merges."""
    parts = [np.asarray(p) for p in parts]
    if len(parts) < 2:
        return parts
    cos_max = math.cos(max_angle)
    fits, ends = part_fits(points, parts)
    cen, dirs, nor = fits[:, 0:2].copy(), fits[:, 2:4].copy(), fits[:, 4:6].copy()
    alive = [True] * len(parts)
    pairs = _similar_pairs(cen, dirs, nor, ends, np.arange(len(parts)), cos_max, max_offset,
                           upper=True)
    while pairs:
        pairs.sort()
        _, i, j = pairs.pop(0)
        if not (alive[i] and alive[j]):
            continue
        merged = np.unique(np.concatenate([parts[i], parts[j]]))
        fit = fit_line(points[merged])
        if point_line_distance(points[merged], fit).max() > max_distance:
            continue  # not one line after all
        alive[i] = alive[j] = False
        parts.append(merged)
        alive.append(True)
        cen = np.concatenate([cen, fit.centroid[None]])
        dirs = np.concatenate([dirs, fit.direction[None]])
        nor = np.concatenate([nor, fit.normal[None]])
        ends = np.concatenate([ends, _ends_on_line(points, merged, fit)[None]])
        k = len(parts) - 1
        new = _similar_pairs(cen, dirs, nor, ends, np.array([k]), cos_max, max_offset,
                             upper=False)
        pairs += [(o, min(a, b), max(a, b)) for o, a, b in new if alive[b]]
    return [p for p, a in zip(parts, alive) if a]


def split_and_merge(points: np.ndarray, components: list[list[int]],
                    tuning: LinesTuning = LINES) -> list[LineSegment]:
    """Split every component, merge similar parts, and give each final line its fit and its
    end points projected onto the fit."""
    t = tuning
    parts = split_components(points, components, t.split_distance, t.min_nodes)
    parts = merge_segments(points, parts, t.merge_angle, t.merge_offset, t.split_distance)
    if not parts:
        return []
    fits, ends = part_fits(points, parts)  # (the lines' fields are views of these, read only)
    return [LineSegment(np.asarray(p), LineFit(f[0:2], f[2:4], f[4:6], rms), e)
            for p, f, e, rms in zip(parts, fits, ends, fits[:, 6].tolist())]


def split_components(points: np.ndarray, components, max_distance: float, min_nodes: int = 3
                     ) -> list[np.ndarray]:
    """split_component of every component (its nodes with finite points, in order), all in
    one compiled pass (``_split_all``): the parts of all components, in order."""
    if not components:
        return []
    flat, start = flat_lists(components)
    out = np.empty(2 * len(flat) + 2, np.int64)
    out_start = np.zeros(len(flat) + 2, np.int64)
    m = _split_all(np.ascontiguousarray(points, np.float64), flat, start, float(max_distance),
                   int(min_nodes), out, out_start)
    bounds = out_start[:m + 1].tolist()
    return [out[a:b] for a, b in zip(bounds[:-1], bounds[1:])]


def part_fits(points: np.ndarray, parts) -> tuple[np.ndarray, np.ndarray]:
    """fit_line and the end points on the fit (_ends_on_line) of each part (indices into
    ``points``), at once: (P, 7) rows [centroid x, y, direction x, y, normal x, y, rms] and
    (P, 2, 2) end points."""
    flat, start = flat_lists(parts)
    fits = np.empty((len(parts), 7))
    ends = np.empty((len(parts), 2, 2))
    _fit_parts(np.ascontiguousarray(points, np.float64), flat, start, fits, ends)
    return fits, ends


def line_end_points(points: np.ndarray, idx: np.ndarray, fit: LineFit) -> np.ndarray:
    """The component's extreme nodes along the line, projected onto the fitted line (2, 2)."""
    return _ends_on_line(points, idx, fit)


def floor_line_parameters(p0: np.ndarray, p1: np.ndarray) -> tuple[float, float, float]:
    """Egocentric parameters of the floor line through p0, p1 (robot frame): the length of the
    perpendicular dropped from the robot onto the line, the angle of that perpendicular
    (bearing of its foot point), and the segment's length."""
    d = p1 - p0
    length = float(np.hypot(*d))
    if length == 0:
        return float(np.hypot(*p0)), float(np.arctan2(p0[1], p0[0])), 0.0
    t = -float(p0[0] * d[0] + p0[1] * d[1]) / (length * length)
    foot = p0 + t * d
    dist = float(np.hypot(*foot))
    if dist < 1e-9:
        angle = float(np.arctan2(d[1], d[0]) + np.pi / 2)
    else:
        angle = float(np.arctan2(foot[1], foot[0]))
    return dist, angle, length


def floor_lines_parameters(p0: np.ndarray, p1: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """floor_line_parameters of many lines at once (end points p0, p1 (N, 2)): (N,) each of
    the perpendicular distances, their angles and the lengths: the lengths, feet and distances
    compiled (``_perpendicular_feet``), the angles numpy's arctan2 of what each line's angle
    is taken of."""
    p0 = np.ascontiguousarray(p0, np.float64)
    n = len(p0)
    dist, length, at = np.empty(n), np.empty(n), np.empty((n, 2))
    along = np.empty(n, np.bool_)
    _perpendicular_feet(p0, np.ascontiguousarray(p1, np.float64), dist, length, at, along)
    angle = np.arctan2(at[:, 0], at[:, 1])
    angle[along] += np.pi / 2
    return dist, angle, length


# ---------------------------------------------------------------------------- refinement


@dataclass
class RefinedLine:
    """A segment refined on the full-resolution white mask (ideal pixel coordinates)."""

    ends: np.ndarray  # (2, 2) extreme inlier centres projected on the refined line
    fit: LineFit
    centres: np.ndarray  # (n, 2) inlier white-run centres
    widths: np.ndarray  # (n,) white-run widths across the line (ideal px)


def lens_parameters(camera) -> np.ndarray:
    """(9,) fx, fy, cx, cy, k1, k2, p1, p2, k3 of a PerspectiveCamera, for the kernels."""
    return np.array([camera.fx, camera.fy, camera.cx, camera.cy, *camera.distortion.tolist()],
                    np.float64)


def distort_ideal(lens: np.ndarray, ideal) -> np.ndarray:
    """Ideal pixels (N, 2) -> image pixels through the lens's distortion (``lens`` from
    ``lens_parameters``): PerspectiveCamera.distort_points, operation by operation, compiled."""
    p = np.ascontiguousarray(np.asarray(ideal, np.float64).reshape(-1, 2))
    out = np.empty_like(p)
    _distort_all(lens, p, out)
    return out


def refine_segment(ends: np.ndarray, white: np.ndarray, lens: np.ndarray, step: float,
                   reach: float, extend: float, min_points: int, grow: float = 0.0
                   ) -> RefinedLine | None:
    """The coarse segment ``ends`` (2, 2, ideal px) refined on the full-resolution white mask
    ``white`` (uint8 or float32, 1 = white; ``lens`` from ``lens_parameters`` maps ideal pixels
    to the image through the lens's distortion), in one compiled kernel (``refine_kernel``):

    - perpendicular profiles every ``step`` px from ``extend`` px before its first end to
      ``extend`` px beyond its second, each ``reach`` px to either side, 1 px apart, sampled
      bilinearly (pixels outside the image count 0);
    - per profile the white run (samples >= 0.5) nearest its middle: its centre (white-weighted
      mean offset) and width (summed white); none where the run touches a profile's end (a
      white area, e.g. where another line crosses);
    - the centres fitted robustly (``_robust``): first to the middle half, then to the points
      within max(1.5 px, 3 robust sigmas (1.4826 MAD)) of the fit that are connected to the
      middle (at most 12 outliers in a row between them: a segment may bend onto a neighbouring
      line at either end), again until that set stops changing;
    - the refined segment spans the extreme inliers, then grows along the fit at each end for
      up to ``grow`` px while the profiles there still cross a white run on the line within
      the same tolerance (``grow_kernel``: it stops after two profiles without; the grid's skeleton
      stops short of corners).

    None when fewer than ``min_points`` profiles cross a white run or stay inliers."""
    e = np.ascontiguousarray(ends, np.float64)
    res = np.empty(12)
    pts, widths = refine_kernel(e, white, lens, float(step), float(reach), float(extend),
                                int(min_points), float(grow), res)
    if res[0] == 0:
        return None
    fit = LineFit(res[5:7].copy(), res[7:9].copy(), res[9:11].copy(), float(res[11]))
    return RefinedLine(res[1:5].reshape(2, 2).copy(), fit, pts, widths)


def refine_segments(ends: np.ndarray, white: np.ndarray, lens: np.ndarray, step: float,
                    reach: float, extend: float, min_points: int, grow: float = 0.0
                    ) -> list[RefinedLine | None]:
    """refine_segment of every segment (ends (N, 2, 2) ideal px), in one compiled call
    (``_refine_all``: refine_kernel per segment, the points and widths of all of them one
    after another)."""
    ends = np.ascontiguousarray(ends, np.float64).reshape(-1, 2, 2)
    n = len(ends)
    res = np.empty((n, 12))
    # at most one point per profile: (length + 2 extend) / step + 1 per segment
    length = np.hypot(*(ends[:, 1] - ends[:, 0]).T)
    cap = int(np.add.reduce(np.floor((length + 2 * extend) / step) + 2)) if n else 0
    pts = np.empty((cap, 2))
    widths = np.empty(cap)
    start = np.zeros(n + 1, np.int64)
    rule = (float(step), float(reach), float(extend), int(min_points), float(grow))
    _refine_all(ends, white, lens, rule, res, pts, widths, start)
    out: list[RefinedLine | None] = []
    # (the lines' fields are views of the kernel's arrays, read only)
    for r, ok, rms, a, b in zip(res, res[:, 0].tolist(), res[:, 11].tolist(), start[:-1].tolist(),
                                start[1:].tolist()):
        if ok == 0:
            out.append(None)
            continue
        out.append(RefinedLine(r[1:5].reshape(2, 2), LineFit(r[5:7], r[7:9], r[9:11], rms),
                               pts[a:b], widths[a:b]))
    return out


def grow_along(white: np.ndarray, lens: np.ndarray, end: np.ndarray, direction: np.ndarray,
               step: float, reach: float, grow: float, tol: float) -> np.ndarray:
    """The point (2,) ideal px up to which the white line goes on from ``end`` along the unit
    ``direction``, by at most ``grow`` px: profiles across it every ``step`` px, ``reach``
    px to each side, whose white run's centre lies within ``tol`` px of the line; the walk
    stops after two profiles without (the compiled ``grow_kernel`` of refine_segment)."""
    x, y = grow_kernel(white, lens, float(end[0]), float(end[1]), float(direction[0]),
                       float(direction[1]), float(step), float(reach), float(grow), float(tol))
    return np.array([x, y])
