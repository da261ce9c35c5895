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

Coordinates here are undistorted ("ideal") pixels, where straight lines are straight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

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


@njit(cache=True, nogil=True)
def _similar_kernel(cosine, cen, nor, ends, rows, cos_max, max_offset, upper):
    """_similar_pairs after the directions' cosines: per row part i = rows[a] and part j in
    row-major order, the larger of the ends' distances (max over the two ends of |e . n -
    c . n|, the sums of two products as numpy's einsum and sum form them) and the pairs
    within cos_max and max_offset (not i itself; j > i if ``upper``)."""
    n_rows, n = cosine.shape
    off = np.empty(n_rows * n)
    pi = np.empty(n_rows * n, np.int64)
    pj = np.empty(n_rows * n, np.int64)
    m = 0
    for a in range(n_rows):
        i = rows[a]
        ci = cen[i, 0] * nor[i, 0] + cen[i, 1] * nor[i, 1]
        for j in range(n):
            cj = cen[j, 0] * nor[j, 0] + cen[j, 1] * nor[j, 1]
            to_i = max(abs((ends[j, 0, 0] * nor[i, 0] + ends[j, 0, 1] * nor[i, 1]) - ci),
                       abs((ends[j, 1, 0] * nor[i, 0] + ends[j, 1, 1] * nor[i, 1]) - ci))
            to_j = max(abs((ends[i, 0, 0] * nor[j, 0] + ends[i, 0, 1] * nor[j, 1]) - cj),
                       abs((ends[i, 1, 0] * nor[j, 0] + ends[i, 1, 1] * nor[j, 1]) - cj))
            o = max(to_i, to_j)
            if cosine[a, j] >= cos_max and o <= max_offset and j != i and (i < j or not upper):
                off[m], pi[m], pj[m] = o, i, j
                m += 1
    return off[:m], pi[:m], pj[:m]


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


@njit(cache=True, nogil=True, error_model="numpy")
def _perpendicular_feet(p0, p1, dist, length, at, along):
    """floor_lines_parameters before the arctan2: per line its length, the distance to the
    foot of the perpendicular from the origin (``t = -(p0 . d) / length^2``) and in ``at``
    the (y, x) whose angle is the line's: the foot's, the line's direction where the line
    runs through the origin (``along``: a quarter turn is added), p0's for a line of no
    length."""
    for k in range(p0.shape[0]):
        dx, dy = p1[k, 0] - p0[k, 0], p1[k, 1] - p0[k, 1]
        length[k] = np.hypot(dx, dy)
        along[k] = False
        if length[k] == 0:
            dist[k] = np.hypot(p0[k, 0], p0[k, 1])
            at[k, 0], at[k, 1] = p0[k, 1], p0[k, 0]
            continue
        t = -(p0[k, 0] * dx + p0[k, 1] * dy) / (length[k] * length[k])
        fx, fy = p0[k, 0] + t * dx, p0[k, 1] + t * dy
        dist[k] = np.hypot(fx, fy)
        if dist[k] < 1e-9:
            at[k, 0], at[k, 1] = dy, dx
            along[k] = True
        else:
            at[k, 0], at[k, 1] = fy, fx


# ---------------------------------------------------------------------------- refinement


@dataclass
class RefinedLine:
    """A segment refined on the full-resolution white mask (ideal pixel coordinates)."""

    ends: np.ndarray  # (2, 2) extreme inlier centres projected on the refined line
    fit: LineFit
    centres: np.ndarray  # (n, 2) inlier white-run centres
    widths: np.ndarray  # (n,) white-run widths across the line (ideal px)


# ---------------------------------------------------------------------------- compiled path


@njit(cache=True, nogil=True)
def median(values):
    """``np.median`` of a 1-D array, compiled (the same value: the middle order statistic, or
    the mean of the two middle ones; without numpy's call overhead on short arrays)."""
    return np.median(values)


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


@njit(cache=True, nogil=True, inline="always")
def distort_point(lens, x, y):
    """An ideal pixel (x, y) -> the distorted image pixel (the lens of ``lens_parameters``);
    the compiled one-point form of ``distort_ideal``."""
    return _distort(x, y, lens[0], lens[1], lens[2], lens[3], lens[4], lens[5], lens[6],
                    lens[7], lens[8])


@njit(cache=True, nogil=True, inline="always")
def _distort(x, y, fx, fy, cx, cy, k1, k2, p1, p2, k3):
    """distort_point with the lens's values given one by one (a loop that reads them once
    before it runs on vectors: read from the array inside it, they might change with its
    stores)."""
    nx = (x - cx) / fx
    ny = (y - cy) / fy
    r2 = nx * nx + ny * ny
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = nx * radial + 2 * p1 * nx * ny + p2 * (r2 + 2 * nx * nx)
    yd = ny * radial + p1 * (r2 + 2 * ny * ny) + 2 * p2 * nx * ny
    return xd * fx + cx, yd * fy + cy


@njit(cache=True, nogil=True)
def _distort_all(lens, p, out):
    for i in range(p.shape[0]):
        out[i, 0], out[i, 1] = distort_point(lens, p[i, 0], p[i, 1])


@njit(cache=True, nogil=True, inline="always")
def _bilinear_at(image, x, y):
    """The image bilinearly at (x, y), pixels outside it 0: each of the four pixels read at
    its index clamped to the image and taken where it lies inside (no branch, so that a loop
    of these runs on vectors; adding +0.0 for a pixel outside leaves the sum as skipping it
    would)."""
    h, w = image.shape
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx, fy = x - x0, y - y0
    ix, iy = np.int64(x0), np.int64(y0)
    out = 0.0
    for dy in range(2):
        wy = (1.0 - fy) if dy == 0 else fy
        yi = iy + dy
        in_y = (yi >= 0) and (yi < h)
        yc = min(max(yi, 0), h - 1)
        for dx in range(2):
            wx = (1.0 - fx) if dx == 0 else fx
            xi = ix + dx
            xc = min(max(xi, 0), w - 1)
            v = np.float64(image[yc, xc]) if (in_y and (xi >= 0) and (xi < w)) else 0.0
            out += v * (wx * wy)
    return out


@njit(cache=True, nogil=True)
def _profile_runs(image, lens, ox, oy, ux, uy, along, reach, centre, width, ok):
    """white_profiles + run_centres for one origin/direction: per position along, the centre
    and width of the white run nearest the middle and whether there is one (not touching the
    profile's ends)."""
    nx, ny = -uy, ux
    t = int(round(2 * reach)) + 1  # offsets -reach .. reach, 1 px apart
    mid = t // 2
    prof = np.empty(t)
    xs = np.empty(t)  # the samples' image positions
    ys = np.empty(t)
    fx, fy, cx, cy = lens[0], lens[1], lens[2], lens[3]
    k1, k2, p1, p2, k3 = lens[4], lens[5], lens[6], lens[7], lens[8]
    for s in range(len(along)):
        bx, by = ox + along[s] * ux, oy + along[s] * uy
        # the whole profile, in two passes that run on vectors: the samples' image
        # positions through the lens, then their bilinear values (cheaper than taking only
        # the samples the run search below reads, one by one)
        for k in range(t):
            a = -reach + k
            xs[k], ys[k] = _distort(bx + a * nx, by + a * ny, fx, fy, cx, cy, k1, k2, p1, p2,
                                    k3)
        for k in range(t):
            prof[k] = _bilinear_at(image, xs[k], ys[k])
        best = -1
        for d in range(mid + 1):
            k = mid - d
            if k >= 0 and prof[k] >= 0.5:
                best = k
                break
            k = mid + d
            if k < t and prof[k] >= 0.5:
                best = k
                break
        if best < 0:
            ok[s] = False
            centre[s] = 0.0
            width[s] = 0.0
            continue
        lo, hi = best, best
        while lo > 0 and prof[lo - 1] >= 0.5:
            lo -= 1
        while hi < t - 1 and prof[hi + 1] >= 0.5:
            hi += 1
        mass, wsum = 0.0, 0.0
        for k in range(lo, hi + 1):
            mass += prof[k]
            wsum += prof[k] * (-reach + k)
        centre[s] = wsum / mass if mass > 0 else 0.0
        width[s] = mass
        ok[s] = not (lo == 0 or hi == t - 1)


@njit(cache=True, nogil=True)
def _fit_points(p):
    """fit_line on points (n, 2): centroid, direction, normal and rms."""
    n = p.shape[0]
    cx, cy = 0.0, 0.0
    for i in range(n):
        cx += p[i, 0]
        cy += p[i, 1]
    cx /= n
    cy /= n
    sxx, syy, sxy = 0.0, 0.0, 0.0
    for i in range(n):
        dx, dy = p[i, 0] - cx, p[i, 1] - cy
        sxx += dx * dx
        syy += dy * dy
        sxy += dx * dy
    theta = 0.5 * math.atan2(2.0 * sxy, sxx - syy)  # major axis of the 2 x 2 scatter
    ux, uy = math.cos(theta), math.sin(theta)
    minor = 0.5 * (sxx + syy) - math.hypot(0.5 * (sxx - syy), sxy)
    return cx, cy, ux, uy, -uy, ux, math.sqrt(max(minor, 0.0) / n)


@njit(cache=True, nogil=True)
def _extent(points, idx, cx, cy, ux, uy, out):
    lo, hi = np.inf, -np.inf
    for i in idx:
        t = (points[i, 0] - cx) * ux + (points[i, 1] - cy) * uy
        lo = min(lo, t)
        hi = max(hi, t)
    out[0, 0], out[0, 1] = cx + lo * ux, cy + lo * uy
    out[1, 0], out[1, 1] = cx + hi * ux, cy + hi * uy


@njit(cache=True, nogil=True)
def _split_ranges(p, max_distance, min_nodes, out):
    """split_component on the ordered points p (n, 2): the parts as runs [a, b) of them into
    ``out`` (n, 2), in order; returns their number."""
    n = p.shape[0]
    stack = np.empty((2 * n + 4, 2), np.int64)
    stack[0, 0], stack[0, 1] = 0, n
    top, m = 1, 0
    while top > 0:
        top -= 1
        a, b = stack[top, 0], stack[top, 1]
        if b - a < min_nodes:
            continue
        cx, cy, ux, uy, nx, ny, rms = _fit_points(p[a:b])
        k, dmax = 0, -1.0
        for i in range(b - a):
            d = abs((p[a + i, 0] - cx) * nx + (p[a + i, 1] - cy) * ny)
            if d > dmax:
                k, dmax = i, d
        if dmax <= max_distance:
            out[m, 0], out[m, 1] = a, b
            m += 1
            continue
        last = b - a - 1
        if k == 0 or k == last:
            # the worst node is an end node: the chord between the ends is the better test
            c0, c1 = p[b - 1, 0] - p[a, 0], p[b - 1, 1] - p[a, 1]
            length = math.hypot(c0, c1)
            if length > 0:
                if b - a > 2:
                    k, dmax = 1, -1.0
                    for i in range(1, last):
                        d = abs(((p[a + i, 0] - p[a, 0]) * -c1 + (p[a + i, 1] - p[a, 1]) * c0)
                                / length)
                        if d > dmax:
                            k, dmax = i, d
                else:
                    k = 0
            if k == 0 or k == last:
                stack[top, 0], stack[top, 1] = (a + 1, b) if k == 0 else (a, b - 1)
                top += 1
                continue
        # the right half below the left one: the left is split first
        stack[top, 0], stack[top, 1] = a + k, b
        stack[top + 1, 0], stack[top + 1, 1] = a, a + k + 1
        top += 2
    return m


@njit(cache=True, nogil=True)
def _split_all(points, flat, start, max_distance, min_nodes, out, out_start):
    """split_components, compiled: per component (``flat[start[c]:start[c + 1]]``) its nodes
    with finite points, split by _split_ranges; the parts' node indices one after another
    into ``out``, part k at ``out[out_start[k]:out_start[k + 1]]``. Returns their number."""
    m, k = 0, 0
    for c in range(len(start) - 1):
        a, b = start[c], start[c + 1]
        idx = np.empty(b - a, np.int64)
        n = 0
        for i in range(a, b):
            j = flat[i]
            if np.isfinite(points[j, 0]) and np.isfinite(points[j, 1]):
                idx[n] = j
                n += 1
        if n < min_nodes:
            continue
        p = np.empty((n, 2))
        for i in range(n):
            p[i, 0], p[i, 1] = points[idx[i], 0], points[idx[i], 1]
        ranges = np.empty((n, 2), np.int64)
        parts = _split_ranges(p, max_distance, min_nodes, ranges)
        for r in range(parts):
            for q in range(ranges[r, 0], ranges[r, 1]):
                out[k] = idx[q]
                k += 1
            m += 1
            out_start[m] = k
    return m


@njit(cache=True, nogil=True)
def _fit_parts(points, flat, start, fits, ends):
    """part_fits, compiled: per part (``flat[start[k]:start[k + 1]]``) _fit_points of its
    points and _extent along the fit."""
    for k in range(len(start) - 1):
        idx = flat[start[k]:start[k + 1]]
        p = np.empty((len(idx), 2))
        for i in range(len(idx)):
            p[i, 0], p[i, 1] = points[idx[i], 0], points[idx[i], 1]
        cx, cy, ux, uy, nx, ny, rms = _fit_points(p)
        fits[k, 0], fits[k, 1], fits[k, 2], fits[k, 3] = cx, cy, ux, uy
        fits[k, 4], fits[k, 5], fits[k, 6] = nx, ny, rms
        _extent(points, idx, cx, cy, ux, uy, ends[k])


@njit(cache=True, nogil=True)
def _fit(px, py, keep):
    """fit_line on the kept points: centroid, direction, normal and rms."""
    n = 0
    cx, cy = 0.0, 0.0
    for i in range(len(px)):
        if keep[i]:
            cx += px[i]
            cy += py[i]
            n += 1
    cx /= n
    cy /= n
    sxx, syy, sxy = 0.0, 0.0, 0.0
    for i in range(len(px)):
        if keep[i]:
            dx, dy = px[i] - cx, py[i] - cy
            sxx += dx * dx
            syy += dy * dy
            sxy += dx * dy
    theta = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
    ux, uy = math.cos(theta), math.sin(theta)
    minor = 0.5 * (sxx + syy) - math.hypot(0.5 * (sxx - syy), sxy)
    rms = math.sqrt(max(minor, 0.0) / n)
    return cx, cy, ux, uy, -uy, ux, rms


@njit(cache=True, nogil=True)
def _robust(px, py, min_residual, max_gap, iterations):
    n = len(px)
    keep = np.zeros(n, np.bool_)
    for i in range(n // 4, n - n // 4):
        keep[i] = True
    if keep.sum() < 2:
        keep[:] = True
    cx, cy, ux, uy, nx, ny, rms = _fit(px, py, keep)
    mid = n // 2
    r = np.empty(n)
    for _ in range(iterations):
        for i in range(n):
            r[i] = (px[i] - cx) * nx + (py[i] - cy) * ny
        core = r[keep]
        med = np.median(core)
        sigma = 1.4826 * np.median(np.abs(core - med))
        tol = max(min_residual, 3.0 * sigma)
        ok = np.abs(r) <= tol
        lo, hi = 0, n
        i = 0
        while i < n:
            if ok[i]:
                i += 1
                continue
            j = i
            while j < n and not ok[j]:
                j += 1
            if j - i > max_gap:
                if j <= mid:
                    lo = max(lo, j)
                elif i > mid:
                    hi = min(hi, i)
            i = j
        new = ok.copy()
        new[:lo] = False
        new[hi:] = False
        if new.sum() < 2:
            break
        same = True
        for i in range(n):
            if new[i] != keep[i]:
                same = False
                break
        if same:
            break
        keep = new
        cx, cy, ux, uy, nx, ny, rms = _fit(px, py, keep)
    return keep, cx, cy, ux, uy, nx, ny, rms


@njit(cache=True, nogil=True)
def grow_kernel(image, lens, ex, ey, dx, dy, step, reach, grow, tol):
    """``grow_along`` compiled: the end (ideal px) reached from (ex, ey) along (dx, dy)."""
    n = 0
    v = step
    while v <= grow + 1e-9:
        n += 1
        v = step * (n + 1)
    if n == 0:
        return ex, ey
    # one profile at a time, so that the walk ends with its second miss in a row
    along = np.empty(1)
    centre = np.empty(1)
    width = np.empty(1)
    ok = np.empty(1, np.bool_)
    last, miss = -1, 0
    for k in range(n):
        along[0] = step * (k + 1)
        _profile_runs(image, lens, ex, ey, dx, dy, along, reach, centre, width, ok)
        if ok[0] and abs(centre[0]) <= tol:
            last, miss = k, 0
        else:
            miss += 1
            if miss >= 2:
                break
    if last < 0:
        return ex, ey
    return ex + step * (last + 1) * dx, ey + step * (last + 1) * dy


@njit(cache=True, nogil=True)
def refine_kernel(ends, image, lens, step, reach, extend, min_points, grow, res):
    """``refine_segment`` compiled: the refined ends and their line fit into ``res`` (res[0] =
    0 when it fails); returns the profiles' white points and widths."""
    res[0] = 0.0
    dx, dy = ends[1, 0] - ends[0, 0], ends[1, 1] - ends[0, 1]
    length = math.hypot(dx, dy)
    empty = np.zeros((0, 2))
    if length < 1e-6:
        return empty, np.zeros(0)
    ux, uy = dx / length, dy / length
    n = 0
    while -extend + n * step < length + extend + 1e-9:
        n += 1
    along = np.empty(n)
    for k in range(n):
        along[k] = -extend + k * step
    centre = np.empty(n)
    width = np.empty(n)
    ok = np.empty(n, np.bool_)
    _profile_runs(image, lens, ends[0, 0], ends[0, 1], ux, uy, along, reach, centre, width, ok)
    m = int(ok.sum())
    if m < min_points:
        return empty, np.zeros(0)
    nx, ny = -uy, ux
    px = np.empty(m)
    py = np.empty(m)
    wd = np.empty(m)
    j = 0
    for k in range(n):
        if ok[k]:
            px[j] = ends[0, 0] + along[k] * ux + centre[k] * nx
            py[j] = ends[0, 1] + along[k] * uy + centre[k] * ny
            wd[j] = width[k]
            j += 1
    keep, cx, cy, fux, fuy, fnx, fny, rms = _robust(px, py, 1.5, 12, 3)
    kk = int(keep.sum())
    if kk < min_points:
        return empty, np.zeros(0)
    pts = np.empty((kk, 2))
    widths = np.empty(kk)
    tmin, tmax = np.inf, -np.inf
    j = 0
    for i in range(m):
        if keep[i]:
            pts[j, 0], pts[j, 1] = px[i], py[i]
            widths[j] = wd[i]
            t = (px[i] - cx) * fux + (py[i] - cy) * fuy
            tmin, tmax = min(tmin, t), max(tmax, t)
            j += 1
    lox, loy = cx + tmin * fux, cy + tmin * fuy
    hix, hiy = cx + tmax * fux, cy + tmax * fuy
    if (hix - lox) * ux + (hiy - loy) * uy < 0:
        lox, loy, hix, hiy = hix, hiy, lox, loy
    if grow > 0:
        r = np.empty(kk)
        for i in range(kk):
            r[i] = (pts[i, 0] - cx) * fnx + (pts[i, 1] - cy) * fny
        med = np.median(r)
        tol = max(1.5, 3.0 * 1.4826 * np.median(np.abs(r - med)))
        sx, sy = hix - lox, hiy - loy
        sl = max(math.hypot(sx, sy), 1e-9)
        sx, sy = sx / sl, sy / sl
        lox, loy = grow_kernel(image, lens, lox, loy, -sx, -sy, step, reach, grow, tol)
        hix, hiy = grow_kernel(image, lens, hix, hiy, sx, sy, step, reach, grow, tol)
    res[0] = 1.0
    res[1], res[2], res[3], res[4] = lox, loy, hix, hiy
    res[5], res[6], res[7], res[8], res[9], res[10] = cx, cy, fux, fuy, fnx, fny
    res[11] = rms
    return pts, widths


@njit(cache=True, nogil=True)
def _refine_all(ends, image, lens, rule, res, pts, widths, start):
    """refine_segments, compiled: refine_kernel of each segment into ``res[k]``, its points
    and widths into ``pts`` and ``widths`` from ``start[k]`` on. ``rule``: refine_kernel's
    (step, reach, extend, min_points, grow), one tuple of scalars as refine_segments makes
    it."""
    step, reach, extend, min_points, grow = rule
    for k in range(ends.shape[0]):
        p, w = refine_kernel(ends[k], image, lens, step, reach, extend, min_points, grow,
                             res[k])
        a = start[k]
        if a + p.shape[0] > pts.shape[0]:
            raise ValueError("refine_segments: more points than profiles")
        for i in range(p.shape[0]):
            pts[a + i, 0], pts[a + i, 1] = p[i, 0], p[i, 1]
            widths[a + i] = w[i]
        start[k + 1] = a + p.shape[0]
