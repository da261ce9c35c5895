"""Line crossing detection on the key node structure (Schulz et al. 2011, section 4.1).

A degree-2 key node whose two edges meet at a corner angle is an L-crossing candidate, a
degree-3 node a T and a degree-4 node an X (``crossing_candidates``). The crossing is placed
where the lines fitted to its arms meet (``place_crossing``; an L's skeleton cuts its
corner). A candidate is verified in the subsampled colour images by two checks
(``verify_crossing``):

- ``circle_transitions``: a state machine walks a circle centred at the crossing and counts the
  green -> white -> green passages (one per arm leaving the crossing); the count must equal the
  candidate's number of arms, on a circle mostly of green and white (a robot's or a person's
  white feet on a line make false corners);
- ``white_path_share``: from the crossing along each arm (to the next node, at most a few
  cells) the straight path must be white.

The candidate's arms are also checked on the floor (``floor_arms``): an L's arms meet at about
90 deg, a T's bar is straight with the stem across it, an X's two lines cross at about 90 deg.
The crossing's orientation follows the convention of ``stages.common.field``: an L's bisector
of its arms, a T's stem, an X's arms folded into [0, pi/2).

``find_crossings`` runs the chain of a frame: the key structure's candidates and the crossings
of pairs of fitted lines (``line_pair_crossings``), each placed, refined on the
full-resolution white mask and verified, then merged.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from numba import njit

from stages.common.features_file import CROSSING_CODES
from stages.common.field import crossing_orientation

from .line_fit import (
    LINES,
    _fit_points,
    distort_ideal,
    distort_point,
    grow_kernel,
    lens_parameters,
    refine_kernel,
)
from .line_structure import KeyStructure, LineGraph, bilinear_at, flat_lists


class CrossingsTuning(NamedTuple):
    """The numbers of the crossings (``find_crossings`` and the checks it runs), in grid cells
    unless said otherwise; tuned on the rendered KidSize and NAO frames and the HULKs NAO
    frames (docs/manual.md "Perspective extraction on real frames")."""

    arm_reach: float  # cells along each arm checked for a white path
    arm_skip: int  # nodes next to the crossing not fitted to its arm (they bend)
    arm_nodes: int  # nodes fitted per arm
    arm_step: float  # cells: arm points projected to the floor for the arm angles
    max_shift: float  # cells from the key node to the arms' intersection
    l_angle: tuple[float, float]  # rad, image angle of L arms
    l_angle_floor: tuple[float, float]  # rad, on the floor
    circle_radii: tuple[float, ...]  # cells (wide near lines need the larger)
    arm_gap: float  # cells between neighbouring arms on an extra, larger circle
    max_radius: float  # cells, of that circle
    t_white: float  # white share on the circle and the paths, at least
    relative: float  # ... and this share of the arms' median white level
    t_green: float
    max_other: float  # share of the circle neither white nor green (an object)
    # cells: no object this near: a 3 x 3-cell window mostly (> 0.5) of other colours (a
    # line's blurred edge makes up to half of a cell "other", not a whole window)
    object_radius: int
    # cells: crossings closer to the field boundary (within two columns) are rejected
    edge_margin: float
    min_path_share: float
    max_misfit: float  # rad: floor angle misfit from the L/T/X shape
    # arms refined on the full-resolution white mask from refine_skip cells off the crossing
    # (see LINES.refine_*)
    refine: bool
    refine_skip: float
    refine_step: float
    refine_reach: float
    refine_min_points: int
    # an arm shorter than min_arm_length by its fitted nodes or line is grown along the white
    # line on the full-resolution mask (crossings._floor_checks): by at most arm_grow cells,
    # while the white run's centre stays within arm_tolerance px of the arm's line
    arm_grow: float
    arm_tolerance: float
    # crossings of pairs of fitted lines (crossings.line_pair_crossings): lines meeting at
    # most pair_gap cells (plus the other line's width) beyond an end
    line_pairs: bool
    pair_gap: float
    merge_distance: float  # cells: of verified crossings closer, the best one stays
    # m of line along each arm at least (a penalty mark next to a line is no corner)
    min_arm_length: float
    post_radius: float  # cells around a goal post's foot without crossings
    # m of floor range one grid cell spans at the crossing, at most: about 0.2 m at 2 m for
    # the KidSize camera (0.55 m high, 330 px focal length), at 2.7 m for the NAO's (0.47 m,
    # 608 px); on rendered walks farther crossings were mostly misplaced or of the wrong type
    max_cell_span: float
    # ... and farther, where one profile step (refine_step px) spans no more, checked on the
    # full-resolution white mask (crossings._verify_fine: the arms' opposites white, green or
    # unknown from one line width to min_arm_length m beyond the crossing); False: rejected
    # as too far
    fine: bool
    fine_px: float  # px of white (or green) at least on which an arm is judged
    # short lines leaving a fitted line's end at a right angle, found on the full-resolution
    # white mask (crossings.stem_lines) where a cell spans more than stem_min_span m of floor
    # along them
    stems: bool
    stem_min_span: float
    # white along an arm is a line's when its runs' median width over a painted line's lies
    # in width_ratio, line_width m wide: the lines' own test (line_fit.LINES)
    line_width: float
    width_ratio: tuple[float, float]


CROSSINGS = CrossingsTuning(
    arm_reach=4.0, arm_skip=1, arm_nodes=4, arm_step=2.0, max_shift=8.0,
    l_angle=(math.radians(25.0), math.radians(155.0)),
    l_angle_floor=(math.radians(45.0), math.radians(135.0)),
    circle_radii=(2.5, 3.5, 5.0, 7.0), arm_gap=3.0, max_radius=8.0, t_white=0.02,
    relative=0.35, t_green=0.3, max_other=0.2, object_radius=2, edge_margin=1.5,
    min_path_share=0.7, max_misfit=math.radians(30.0), refine=True, refine_skip=1.0,
    refine_step=3.0, refine_reach=2.0, refine_min_points=3, arm_grow=12.0, arm_tolerance=3.0,
    line_pairs=True, pair_gap=1.5, merge_distance=2.0, min_arm_length=0.12, post_radius=2.0,
    max_cell_span=0.25, fine=True, fine_px=3.0, stems=True, stem_min_span=0.0,
    line_width=LINES.line_width, width_ratio=LINES.width_ratio)


@dataclass
class CrossingCandidate:
    kind: str  # "L", "T" or "X"
    key: int  # key node index
    pos: np.ndarray  # (2,) grid coordinates
    arm_points: np.ndarray  # (A, 2) grid coordinates, one point along each arm


def point_along(pos: np.ndarray, chain: list[int], reach: float) -> np.ndarray:
    """The point ``reach`` cells along a fine chain (starting at its first node), or the chain's
    last node when it is shorter."""
    return points_along(pos, [chain], reach)[0]


def points_along(pos: np.ndarray, chains: list[list[int]], reach: float) -> np.ndarray:
    """point_along of each chain (C, 2), in one compiled pass (``_points_along``)."""
    flat, start = flat_lists(chains)
    out = np.empty((len(chains), 2))
    _points_along(np.ascontiguousarray(pos, np.float64), flat, start, float(reach), out)
    return out


@njit(cache=True, nogil=True)
def _points_along(pos, flat, start, reach, out):
    """points_along, compiled: for chain c (nodes ``flat[start[c]:start[c + 1]]``) the arc
    length at each node summed in order (as np.cumsum), the first node at least ``reach``
    along (np.searchsorted's side "left") and the point between it and the node before."""
    for c in range(len(start) - 1):
        a, b = start[c], start[c + 1]
        s_prev, s, total = 0.0, 0.0, 0.0
        k = -1
        for i in range(a + 1, b):
            total = total + np.hypot(pos[flat[i], 0] - pos[flat[i - 1], 0],
                                     pos[flat[i], 1] - pos[flat[i - 1], 1])
            if k < 0:
                s_prev, s = s, total
                if s >= reach:
                    k = i
        last = flat[b - 1]
        if total <= reach:
            out[c, 0], out[c, 1] = pos[last, 0], pos[last, 1]
            continue
        p0, p1 = flat[k - 1], flat[k]
        seg = np.hypot(pos[p1, 0] - pos[p0, 0], pos[p1, 1] - pos[p0, 1])
        t = (reach - s_prev) / max(seg, 1e-9)
        out[c, 0] = pos[p0, 0] + t * (pos[p1, 0] - pos[p0, 0])
        out[c, 1] = pos[p0, 1] + t * (pos[p1, 1] - pos[p0, 1])


def crossing_candidates(ks: KeyStructure, graph: LineGraph, arm_reach: float,
                        l_angle_range: tuple[float, float], floor_of=None
                        ) -> list[CrossingCandidate]:
    """L (degree 2 with a corner angle in ``l_angle_range``, radians), T (degree 3) and X
    (degree 4) candidates of the key structure. The L's angle is measured in the image, or on
    the floor with ``floor_of`` (grid positions (N, 2) -> floor points, NaN above the
    horizon) where its points are on the floor."""
    deg = ks.degree().tolist()
    keys = [k for k, d in enumerate(deg) if d in (2, 3, 4)]
    if not keys:
        return []
    incidence = ks.incidence()
    chains = [incidence[k] for k in keys]
    along = points_along(graph.pos, [ch for cs in chains for ch in cs], arm_reach)
    first = [0, *itertools.accumulate(len(cs) for cs in chains)]
    # the L candidates' corner angles, all at once (compiled: _corner_angles), of their
    # centres and arm points (two each) in the grid and on the floor
    two = [n for n, k in enumerate(keys) if deg[k] == 2]
    angles = {}
    if two:
        corners = np.empty((len(two), 3, 2))
        arm = np.array([first[n] for n in two])
        corners[:, 0] = ks.pos[[keys[n] for n in two]]
        corners[:, 1] = along[arm]
        corners[:, 2] = along[arm + 1]
        use_floor = floor_of is not None
        on_floor = (floor_of(corners.reshape(-1, 2)).reshape(-1, 3, 2) if use_floor
                    else corners)
        ang = np.empty(len(two))
        _corner_angles(corners, np.ascontiguousarray(on_floor, np.float64), use_floor, ang)
        angles = dict(zip(two, ang.tolist()))
    out = []
    for n, k in enumerate(keys):
        centre = ks.pos[k]
        arms = along[first[n]:first[n + 1]].copy()
        if deg[k] == 2:
            if not (l_angle_range[0] <= angles[n] <= l_angle_range[1]):
                continue
            kind = "L"
        else:
            kind = "T" if deg[k] == 3 else "X"
        out.append(CrossingCandidate(kind, k, centre.copy(), arms))
    return out


@njit(cache=True, nogil=True)
def _angle_at(ax, ay, bx, by):
    """The angle (radians, [0, pi]) between the vectors (ax, ay) and (bx, by); 0 when one is
    zero."""
    na, nb = np.hypot(ax, ay), np.hypot(bx, by)
    if na == 0 or nb == 0:
        return 0.0
    c = _dot(ax, ay, bx, by) / (na * nb)
    c = c if c < 1.0 else 1.0  # as min(1.0, c), max(-1.0, c) (a NaN becomes 1)
    c = c if c > -1.0 else -1.0
    return math.acos(c)


@njit(cache=True, nogil=True)
def _corner_angles(corners, floor, use_floor, out):
    """The L candidates' corner angles: corner i's centre and arm points ``corners[i]`` (3, 2)
    in the grid, the angle between its arms there, or on the floor (``floor[i]`` (3, 2)) where
    all three points are on it (``use_floor``)."""
    for i in range(corners.shape[0]):
        c = corners[i]
        out[i] = _angle_at(c[1, 0] - c[0, 0], c[1, 1] - c[0, 1], c[2, 0] - c[0, 0],
                           c[2, 1] - c[0, 1])
        if use_floor:
            finite = True
            for j in range(3):
                finite = finite and np.isfinite(floor[i, j, 0]) and np.isfinite(floor[i, j, 1])
            if finite:
                f = floor[i]
                out[i] = _angle_at(f[1, 0] - f[0, 0], f[1, 1] - f[0, 1], f[2, 0] - f[0, 0],
                                   f[2, 1] - f[0, 1])


def sample_cells(image: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear samples of a per-cell image at grid points (N, 2) (x = column, y = row), 0
    outside."""
    p = np.asarray(pts, np.float32).reshape(-1, 1, 2)
    return cv2.remap(np.asarray(image, np.float32), p[..., 0], p[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=0).ravel()


def circle_transitions(white: np.ndarray, green: np.ndarray, centre: np.ndarray, radii,
                       t_white: float, t_green: float, samples: int = 48,
                       field: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Number of green -> white -> green passages on circles of ``radii`` around ``centre``
    (grid coordinates), one count per radius: a state machine over each circle's samples in
    order, where white (share >= t_white) and green (share >= t_green) change the state and
    anything else keeps it. A circle showing no green or no white counts 0. Also returns each
    circle's share of samples that are neither (an object standing there); with ``field``
    (1 inside the field boundary, 0 beyond it, per cell) only among the samples inside it:
    beyond the boundary the view is unknown, not an object on the field."""
    radii = np.atleast_1d(np.asarray(radii, float))
    t = np.linspace(0.0, 2 * math.pi, samples, endpoint=False)
    ring = np.stack([np.cos(t), np.sin(t)], axis=1)
    pts = (centre[None, None, :] + radii[:, None, None] * ring[None]).reshape(-1, 2)
    w = sample_cells(white, pts).reshape(len(radii), samples)
    g = sample_cells(green, pts).reshape(len(radii), samples)
    state = np.where(w >= t_white, 1, np.where(g >= t_green, 0, -1))
    if field is not None:
        on = sample_cells(field, pts).reshape(len(radii), samples) >= 0.5
        neither = (state < 0) & on
        n_on = on.sum(axis=1)
    # carry the last known state over unknown samples (cyclic): index of the last known one
    known = state >= 0
    twice = np.concatenate([known, known], axis=1)
    idx = np.where(twice, np.arange(2 * samples)[None, :], -1)
    last = np.maximum.accumulate(idx, axis=1)[:, samples:] % samples
    filled = np.take_along_axis(state, last, axis=1)
    entered = (filled == 1) & (np.roll(filled, 1, axis=1) == 0)
    counts = entered.sum(axis=1)
    if field is not None:
        other = np.where(n_on > 0, neither.sum(axis=1) / np.maximum(n_on, 1), 1.0)
    else:
        other = 1.0 - known.mean(axis=1)
    return np.where(known.any(axis=1), counts, 0), other


def white_path_share(white: np.ndarray, p: np.ndarray, q: np.ndarray, t_white: float,
                     step: float = 0.5) -> float:
    """Share of the samples on the straight path p -> q (grid coordinates) that are white."""
    return float(white_path_shares(white, p, np.asarray(q)[None], t_white, step)[0])


def white_path_shares(white: np.ndarray, p: np.ndarray, qs: np.ndarray, t_white: float,
                      step: float = 0.5) -> np.ndarray:
    """white_path_share from p to each of the points ``qs`` (A, 2), sampled together."""
    ns = [max(2, int(np.ceil(np.hypot(*(q - p)) / step)) + 1) for q in qs]
    pts = np.concatenate([p[None] * (1 - s) + q[None] * s for q, s in
                          zip(qs, (np.linspace(0.0, 1.0, n)[:, None] for n in ns))])
    on = sample_cells(white, pts) >= t_white
    return np.array([float(np.mean(part)) for part in np.split(on, np.cumsum(ns)[:-1])])


def floor_arms(kind: str, arms: np.ndarray) -> tuple[float, float]:
    """A candidate's orientation from its arm directions on the floor (radians, robot frame)
    and its angular misfit (radians) from the ideal shape: an L's right angle, a T's straight
    bar with the stem across it, an X's arms at multiples of 90 deg."""
    a = np.asarray(arms, float)
    if kind == "L":
        a = a.tolist()  # a few angles: Python floats (the same arithmetic, less overhead)
        gap = abs(math.remainder(a[0] - a[1], 2 * math.pi))
        misfit = abs(gap - math.pi / 2)
        return crossing_orientation("L", a), misfit
    if kind == "T":
        a = a.tolist()
        # the bar: the most nearly opposite pair of arms; the stem is the remaining arm
        pairs = [(0, 1, 2), (0, 2, 1), (1, 2, 0)]
        opp = [abs(abs(math.remainder(a[i] - a[j], 2 * math.pi)) - math.pi) for i, j, _ in pairs]
        i, j, s = pairs[min(range(3), key=opp.__getitem__)]  # the first smallest, as argmin
        across = [abs(abs(math.remainder(a[s] - a[k], 2 * math.pi)) - math.pi / 2) for k in (i, j)]
        misfit = max(min(opp), max(across))
        return math.remainder(a[s], 2 * math.pi), misfit
    # X: all four arms folded into [0, pi/2) agree; circular mean of 4 * angle
    z = np.exp(4j * a).mean()
    orient = float(np.mod(np.angle(z) / 4.0, math.pi / 2))
    fold = np.abs(np.angle(np.exp(4j * (a - orient)))) / 4.0
    return orient, float(fold.max())


def verify_crossing(centre: np.ndarray, arm_points: np.ndarray, white: np.ndarray,
                    green: np.ndarray, tuning: CrossingsTuning = CROSSINGS,
                    field: np.ndarray | None = None) -> float:
    """Image checks of section 4.1 at a crossing ``centre`` (grid coordinates): the circle's
    transition count equals the number of arms (at any of the radii tried), and a white path
    leads from the crossing along each arm (to ``arm_points``, the next node or the arm's
    reach). ``white`` is the white share per cell inside the field boundary; white means at
    least ``t_white`` and at least ``relative`` times the median white level at the arm points
    (far lines are thin and faint). Arms at a small image angle need a larger circle to be
    told apart: one on which neighbouring arms are ``arm_gap`` cells apart (up to
    ``max_radius``) is tried too. ``field``: the field region per cell (1 inside the
    boundary), see circle_transitions. Returns a score in [0, 1] (0 = rejected): the smallest
    white-path share.

    It runs compiled (``_verify``): circle_transitions and white_path_share with the cells
    sampled bilinearly as sample_cells does (to float32 rounding)."""
    use_field = field is not None
    t = tuning
    rule = (float(t.t_white), float(t.relative), float(t.t_green), float(t.arm_gap),
            float(t.max_radius), float(t.max_other), float(t.min_path_share))
    return float(_verify(np.ascontiguousarray(centre, np.float64),
                         np.ascontiguousarray(arm_points, np.float64).reshape(-1, 2),
                         np.asarray(white, np.float32), np.asarray(green, np.float32),
                         np.asarray(field, np.float32) if use_field
                         else np.zeros((1, 1), np.float32), use_field,
                         np.asarray(t.circle_radii, np.float64), rule))


CIRCLE_SAMPLES = 48  # samples on each circle of circle_transitions
_T = np.linspace(0.0, 2 * math.pi, CIRCLE_SAMPLES, endpoint=False)
_RING = np.ascontiguousarray(np.stack([np.cos(_T), np.sin(_T)], axis=1))


@njit(cache=True, nogil=True)
def _sample_cell(image, x64, y64):
    """sample_cells at one point: bilinear in float32, 0 outside the image."""
    h, w = image.shape
    one = np.float32(1.0)
    x, y = np.float32(x64), np.float32(y64)
    fx, fy = np.floor(x), np.floor(y)
    ix, iy = int(fx), int(fy)
    ax, ay = x - fx, y - fy
    out = np.float32(0.0)
    if 0 <= iy < h:
        if 0 <= ix < w:
            out += image[iy, ix] * ((one - ay) * (one - ax))
        if 0 <= ix + 1 < w:
            out += image[iy, ix + 1] * ((one - ay) * ax)
    if 0 <= iy + 1 < h:
        if 0 <= ix < w:
            out += image[iy + 1, ix] * (ay * (one - ax))
        if 0 <= ix + 1 < w:
            out += image[iy + 1, ix + 1] * (ay * ax)
    return out


@njit(cache=True, nogil=True)
def _circle(white, green, field, use_field, cx, cy, r, ring, t_white, t_green, state):
    """circle_transitions for one radius: (count, share of neither white nor green)."""
    n = ring.shape[0]
    n_on, neither, any_known = 0, 0, False
    for k in range(n):
        px, py = cx + r * ring[k, 0], cy + r * ring[k, 1]
        if _sample_cell(white, px, py) >= t_white:
            state[k] = 1
        elif _sample_cell(green, px, py) >= t_green:
            state[k] = 0
        else:
            state[k] = -1
        if state[k] >= 0:
            any_known = True
        if use_field and _sample_cell(field, px, py) >= 0.5:
            n_on += 1
            if state[k] < 0:
                neither += 1
    if use_field:
        other = neither / n_on if n_on > 0 else 1.0
    else:
        known = 0
        for k in range(n):
            known += state[k] >= 0
        other = 1.0 - known / n
    if not any_known:
        return 0, other
    # the last known state carried over unknown samples (cyclic)
    last = -1
    for k in range(n):
        if state[k] >= 0:
            last = state[k]
    count, prev = 0, last
    for k in range(n):
        cur = state[k] if state[k] >= 0 else prev
        if cur == 1 and prev == 0:
            count += 1
        prev = cur
    return count, other


@njit(cache=True, nogil=True)
def _path_share(white, px, py, qx, qy, t, step):
    """white_path_share from (px, py) to (qx, qy)."""
    n = max(2, int(np.ceil(math.hypot(qx - px, qy - py) / step)) + 1)
    d = 1.0 / (n - 1)
    on = 0
    for k in range(n):
        s = k * d if k < n - 1 else 1.0
        if _sample_cell(white, px * (1 - s) + qx * s, py * (1 - s) + qy * s) >= t:
            on += 1
    return on / n


@njit(cache=True, nogil=True)
def _verify(centre, arms, white, green, field, use_field, radii, rule):
    """verify_crossing, compiled (``rule``: t_white, relative, t_green, arm_gap, max_radius,
    max_other, min_path_share)."""
    t_white, relative, t_green, arm_gap, max_radius, max_other, min_path_share = rule
    ring = _RING
    n_arms = arms.shape[0]
    cx, cy = centre[0], centre[1]
    levels = np.empty(n_arms, np.float32)
    ang = np.empty(n_arms)
    for a in range(n_arms):
        levels[a] = _sample_cell(white, arms[a, 0], arms[a, 1])
        ang[a] = math.atan2(arms[a, 1] - cy, arms[a, 0] - cx)
    ref = np.median(levels) if n_arms else np.float32(np.nan)
    t = max(t_white, relative * ref)
    ang.sort()
    sep = np.inf
    for a in range(n_arms):
        gap = (ang[a + 1] if a + 1 < n_arms else ang[0] + 2 * math.pi) - ang[a]
        sep = min(sep, gap)
    state = np.empty(ring.shape[0], np.int64)
    found = False
    for k in range(len(radii) + 1):
        if k < len(radii):
            r = radii[k]
        elif sep > 0:
            r = min(max_radius, arm_gap / sep)
        else:
            break
        count, other = _circle(white, green, field, use_field, cx, cy, r, ring, t, t_green,
                               state)
        if count == n_arms and other <= max_other:
            found = True
            break
    if not found or n_arms == 0:
        return 0.0
    score = 1.0
    for a in range(n_arms):
        score = min(score, _path_share(white, cx, cy, arms[a, 0], arms[a, 1], t, 0.5))
    return score if score >= min_path_share else 0.0


@dataclass
class LineCrossing:
    """A crossing of two fitted field lines (ideal pixel coordinates): its type by where the
    lines meet (L: at an end of both, T: at an end of one and inside the other; two straight
    lines crossing inside both are no field crossing), the intersection and the unit
    directions of its arms."""

    kind: str
    point: np.ndarray  # (2,)
    arms: np.ndarray  # (A, 2) unit directions away from the point
    lines: tuple[int, int]  # the two lines' indices
    lengths: np.ndarray | None = None  # (A,) px of line along each arm from the point


def line_pair_crossings(ends: np.ndarray, widths: np.ndarray, floor_of, tol: float,
                        max_misfit: float, first_stem: int | None = None
                        ) -> list[LineCrossing]:
    """Crossings of pairs of fitted lines (``ends`` (N, 2, 2) in ideal pixels, ``widths``
    (N,) their white width across, px) that meet at about a right angle on the floor
    (``floor_of``: ideal pixels (M, 2) -> floor points; within ``max_misfit`` rad of 90 deg):
    each line either passes the intersection (by more than ``tol`` px: two arms) or ends on
    the other line (its nearer end within ``tol`` px plus the other line's width of it: one
    arm). Field lines cross at right angles; where a far corner's skeleton loses the junction
    at the grid's resolution, the lines fitted at full resolution still meet. Lines from
    ``first_stem`` on are stems (stem_lines): they are not paired with each other.

    The floor angles are numpy's arctan2; the pairs run compiled (``_pair_crossings``; the
    lines cut by _line_cut)."""
    n = len(ends)
    if n < 2:
        return []
    ends = np.ascontiguousarray(ends, np.float64)
    floor = floor_of(ends.reshape(-1, 2)).reshape(n, 2, 2)
    fdir = floor[:, 1] - floor[:, 0]
    fang = np.arctan2(fdir[:, 1], fdir[:, 0])
    cap = n * (n - 1) // 2
    kinds = np.empty(cap, np.int64)
    lines = np.empty((cap, 2), np.int64)
    points = np.empty((cap, 2))
    arms = np.empty((cap, 3, 2))
    lengths = np.empty((cap, 3))
    m = _pair_crossings(ends, np.asarray(widths, np.float64), fang, float(tol),
                        float(max_misfit), n if first_stem is None else int(first_stem),
                        kinds, lines, points, arms, lengths)
    out = [LineCrossing("LT"[kinds[k] - 2], points[k].copy(), arms[k, :kinds[k]].copy(),
                        (int(lines[k, 0]), int(lines[k, 1])), lengths[k, :kinds[k]].copy())
           for k in range(m)]
    return merge_line_crossings(out, tol, floor_of=floor_of)


@njit(cache=True, nogil=True)
def _remainder(a, b):
    """np.remainder of two floats (numpy's divmod: fmod, moved to the sign of b)."""
    mod = np.fmod(a, b)
    if b == 0:
        return mod
    if mod != 0:
        if (b < 0) != (mod < 0):
            mod += b
    else:
        mod = math.copysign(0.0, b)
    return mod


@njit(cache=True, nogil=True)
def _meeting_arms(t, length, ux, uy, end_gap, tol, arms, lengths, a):
    """_meeting compiled: line arms (ux, uy) at ``t`` along a line of ``length`` into
    arms[a:], their lengths into lengths[a:]; returns the new count, or -1 for none."""
    if tol < t < length - tol:
        arms[a, 0], arms[a, 1], lengths[a] = ux, uy, length - t
        arms[a + 1, 0], arms[a + 1, 1], lengths[a + 1] = -ux, -uy, t
        return a + 2
    if end_gap > tol:
        return -1
    if t <= 0.5 * length:
        arms[a, 0], arms[a, 1], lengths[a] = ux, uy, length - t
    else:
        arms[a, 0], arms[a, 1], lengths[a] = -ux, -uy, t
    return a + 1


@njit(cache=True, nogil=True)
def _pair_crossings(ends, widths, fang, tol, max_misfit, first_stem, kinds, lines, points,
                    arms, lengths):
    """line_pair_crossings after the floor angles ``fang`` (N,), compiled: the crossings of
    the line pairs i < j (row by row, as np.nonzero gives them) into the outputs (kind 2 L,
    3 T, the two lines, the point, the arms and their lengths); returns their number."""
    n = ends.shape[0]
    length = np.empty(n)
    u = np.empty((n, 2))
    for i in range(n):
        dx, dy = ends[i, 1, 0] - ends[i, 0, 0], ends[i, 1, 1] - ends[i, 0, 1]
        length[i] = np.hypot(dx, dy)
        den = length[i] if not length[i] < 1e-9 else 1e-9  # np.maximum (NaN stays)
        u[i, 0], u[i, 1] = dx / den, dy / den
    arm = np.empty((4, 2))
    arm_len = np.empty(4)
    m = 0
    half = math.pi / 2
    for i in range(n):
        for j in range(i + 1, n):
            if i >= first_stem and j >= first_stem:
                continue
            diff = _remainder(fang[i] - fang[j], math.pi)
            other = math.pi - diff
            near = diff if (diff <= other or np.isnan(diff)) else other  # np.minimum
            if not abs(near - half) <= max_misfit:  # NaN (off the floor) is no pair
                continue
            det, t_i, t_j = _line_cut(u[i, 0], u[i, 1], u[j, 0], u[j, 1],
                                      ends[j, 0, 0] - ends[i, 0, 0],
                                      ends[j, 0, 1] - ends[i, 0, 1])
            if not abs(det) >= 1e-3:
                continue
            xx, xy = ends[i, 0, 0] + t_i * u[i, 0], ends[i, 0, 1] + t_i * u[i, 1]
            # each line's end nearer the intersection and its distance from the other line
            k = 0 if t_i <= 0.5 * length[i] else 1
            g_i = abs(_dot(ends[i, k, 0] - ends[j, 0, 0], ends[i, k, 1] - ends[j, 0, 1],
                           -u[j, 1], u[j, 0]))
            k = 0 if t_j <= 0.5 * length[j] else 1
            g_j = abs(_dot(ends[j, k, 0] - ends[i, 0, 0], ends[j, k, 1] - ends[i, 0, 1],
                           -u[i, 1], u[i, 0]))
            c = _meeting_arms(t_i, length[i], u[i, 0], u[i, 1], g_i, tol + widths[j], arm,
                              arm_len, 0)
            if c < 0:
                continue
            c = _meeting_arms(t_j, length[j], u[j, 0], u[j, 1], g_j, tol + widths[i], arm,
                              arm_len, c)
            if c < 0 or c == 4:
                continue  # two straight lines crossing: fields have none (their X is the
                # centre circle on the halfway line), so it is no crossing of field lines
            kinds[m], lines[m, 0], lines[m, 1] = c, i, j
            points[m, 0], points[m, 1] = xx, xy
            for q in range(c):
                arms[m, q, 0], arms[m, q, 1], lengths[m, q] = arm[q, 0], arm[q, 1], arm_len[q]
            m += 1
    return m


def stem_lines(lines: np.ndarray, white_px: np.ndarray, camera, to_floor,
               cc: CrossingsTuning, cell: int) -> np.ndarray:
    """Short lines leaving the ends of fitted lines (``lines`` (N, 2, 2) ideal px) at a right
    angle on the floor, found on the full-resolution white mask where the grid has too few
    cells of them for a line of its own (a far goal area's side line between its front line
    and the goal line is 2 or 3 cells long): from each end, on both sides, the white line is
    followed along the floor's perpendicular (line_fit.grow_along from one ``line_width``
    past the end, profiles every px up to ``refine_step``), refitted on its white runs
    (line_fit.refine_segment) and kept when it is at least ``min_arm_length`` m long and
    within ``max_misfit`` of the right angle. Only at ends whose cell spans more than
    ``stem_min_span`` m of floor along the stem. Returns the stems (S, 2, 2) ideal px, for
    line_pair_crossings."""
    if len(lines) == 0:
        return np.zeros((0, 2, 2))
    lines = np.ascontiguousarray(lines, np.float64)
    floor = to_floor(lines.reshape(-1, 2)).reshape(-1, 2, 2)
    out = np.empty((4 * len(lines), 2, 2))
    rule = (float(cell), float(cc.stem_min_span), float(cc.line_width),
            float(cc.refine_step), float(cc.refine_reach * cell),
            float(cc.arm_grow * cell), float(cc.arm_tolerance),
            float(cc.min_arm_length), int(cc.refine_min_points),
            math.sin(cc.max_misfit))
    n = _stems(lines, floor, white_px, lens_parameters(camera), floor_bundle(to_floor), rule, out)
    return out[:n]


@njit(cache=True, nogil=True)
def _stems(lines, floor, white_px, lens, fl, rule, out):
    """stem_lines, compiled: the stems into ``out`` (4 N, 2, 2); returns their number.
    ``floor``: the lines' ends on the floor, ``fl``: Floor, ``rule``: (cell, min_span,
    line_width, refine_step, max_reach, grow, tolerance, min_length, min_points,
    sin_misfit) as stem_lines makes it."""
    (cell, min_span, line_width, refine_step, max_reach, grow, tolerance, min_length,
     min_points, sin_misfit) = rule
    n = 0
    res = np.empty(12)
    seg = np.empty((2, 2))
    back = np.empty((1, 2))
    for i in range(lines.shape[0]):
        ax, ay = floor[i, 1, 0] - floor[i, 0, 0], floor[i, 1, 1] - floor[i, 0, 1]
        la = math.hypot(ax, ay)
        if not np.isfinite(la) or la <= 0:
            continue
        ax, ay = ax / la, ay / la
        for k in range(2):
            ex, ey = lines[i, k, 0], lines[i, k, 1]
            bx, by = lines[i, 1 - k, 0] - ex, lines[i, 1 - k, 1] - ey
            nb = max(math.hypot(bx, by), 1e-9)
            back[0, 0], back[0, 1] = bx / nb, by / nb
            for sign in (1.0, -1.0):
                qx, qy = _ideal_point(fl, floor[i, k, 0] - sign * 0.05 * ay,
                                      floor[i, k, 1] + sign * 0.05 * ax)
                vx, vy = qx - ex, qy - ey
                nv = math.hypot(vx, vy)
                if not np.isfinite(nv) or nv <= 0:
                    continue
                vx, vy = vx / nv, vy / nv
                scale = 0.05 / nv  # m of floor per px along v
                if scale * cell <= min_span:
                    continue
                start, reach = _clear_start_kernel(ex, ey, vx, vy, back, scale, fl, line_width,
                                                   tolerance, max_reach)
                step = min(max(line_width / scale, 1.0), refine_step)
                sx, sy = ex + start * vx, ey + start * vy
                gx, gy = grow_kernel(white_px, lens, sx, sy, vx, vy, step, reach, grow, tolerance)
                t = (gx - ex) * vx + (gy - ey) * vy
                if t * scale < min_length or t <= start:
                    continue
                seg[0, 0], seg[0, 1], seg[1, 0], seg[1, 1] = sx, sy, gx, gy
                refine_kernel(seg, white_px, lens, step, reach, 0.0, min_points, refine_step, res)
                if res[0] == 0:
                    continue
                f0x, f0y = floor_at(fl.m, fl.height, fl.pos, True, res[1], res[2])
                f1x, f1y = floor_at(fl.m, fl.height, fl.pos, True, res[3], res[4])
                dx, dy = f1x - f0x, f1y - f0y
                ls = math.hypot(dx, dy)
                if not np.isfinite(ls) or ls < min_length or abs(dx * ax + dy * ay) / ls \
                        > sin_misfit:
                    continue
                out[n, 0, 0], out[n, 0, 1], out[n, 1, 0], out[n, 1, 1] = \
                    res[1], res[2], res[3], res[4]
                n += 1
    return n


def merge_line_crossings(crossings: list[LineCrossing], tol: float,
                         same_arm: float = math.radians(20.0), floor_of=None
                         ) -> list[LineCrossing]:
    """Crossings of line pairs closer than ``tol`` px are one crossing with the union of their
    arms (arms within ``same_arm`` rad of each other are one; on the floor with ``floor_of``,
    ideal pixels (M, 2) -> floor points, where the arms' first ``tol`` px are on it: far
    away the perspective flattens a right angle in the image): a T whose bar was fitted as
    two lines, one each side of the stem, gives two L's of the same point.

    The crossings are read in the order of their points (rounded so that the same point
    computed from a pair's two orders sorts alike), each gathering the later ones within
    ``tol`` of it, so the result does not depend on the order of the lines."""
    out = []
    if not crossings:
        return out
    cos_same = math.cos(same_arm)
    key = np.round(np.array([c.point for c in crossings], np.float64), 6)
    crossings = [crossings[i] for i in np.lexsort((key[:, 1], key[:, 0]))]
    pts = np.array([c.point for c in crossings], np.float64)
    near = (np.hypot(pts[None, :, 0] - pts[:, None, 0], pts[None, :, 1] - pts[:, None, 1])
            <= tol).tolist()
    used = [False] * len(crossings)
    for a, c in enumerate(crossings):
        if used[a]:
            continue
        group = [c]
        for b in range(a + 1, len(crossings)):
            if not used[b] and near[a][b]:
                group.append(crossings[b])
                used[b] = True
        if len(group) == 1:
            out.append(c)
            continue
        # the points' mean as np.mean over the rows computes it (summed row by row)
        point = np.array([sum(float(g.point[0]) for g in group),
                          sum(float(g.point[1]) for g in group)]) / len(group)
        all_arms = np.concatenate([g.arms for g in group])
        all_lengths = np.concatenate([g.lengths for g in group])
        cmp = all_arms
        if floor_of is not None:
            f = floor_of(np.concatenate([point[None], point[None] + tol * all_arms]))
            d = f[1:] - f[0]
            n = np.hypot(d[:, 0], d[:, 1])
            if np.isfinite(n).all() and np.all(n > 0):
                cmp = d / n[:, None]
        arms = np.empty(len(all_lengths), np.int64)
        lengths = np.empty(len(all_lengths))
        m = _distinct_arms(np.ascontiguousarray(cmp, np.float64),
                           np.ascontiguousarray(all_lengths, np.float64), cos_same, arms,
                           lengths)
        if m not in (2, 3):
            continue
        out.append(LineCrossing({2: "L", 3: "T"}[m], point, all_arms[arms[:m]],
                                group[0].lines, lengths[:m]))
    return out


@njit(cache=True, nogil=True)
def _distinct_arms(cmp, lengths, cos_same, arms, kept_lengths):
    """merge_line_crossings' arms of a group, in order: an arm whose direction ``cmp`` lies
    within acos(cos_same) of a kept arm's (the first such; _dot) gives that one the larger
    length (Python's max), else it is kept. The kept arms' indices go into ``arms``, their
    lengths into ``kept_lengths``; returns their number."""
    m = 0
    for k in range(cmp.shape[0]):
        same = -1
        for q in range(m):
            j = arms[q]
            if _dot(cmp[k, 0], cmp[k, 1], cmp[j, 0], cmp[j, 1]) >= cos_same:
                same = q
                break
        if same < 0:
            arms[m], kept_lengths[m] = k, lengths[k]
            m += 1
        elif lengths[k] > kept_lengths[same]:
            kept_lengths[same] = lengths[k]
    return m


# ---------------------------------------------------------------------------- the chain


class FrameGrid(NamedTuple):
    """One frame as the steps after the skeleton read it: its ``camera`` (at the frame's pose)
    and floor projection ``to_floor`` (perspective.FloorProjection), the grid's ``cell`` (px),
    the field boundary ``top`` (a row per column), the grid's white shares ``white`` and those
    inside the boundary ``inside`` (skeleton_grid), its ``green`` and ``other`` shares (all
    per cell, 0..1) and the full-resolution white mask ``white_px`` (uint8, None if not
    made). One value because the line and crossing steps take the same frame."""

    camera: object
    to_floor: object
    cell: int
    top: np.ndarray
    white: np.ndarray
    inside: np.ndarray
    green: np.ndarray
    other: np.ndarray
    white_px: np.ndarray | None = None


class Finds(NamedTuple):
    """What the steps before the crossings found that they consult: the fitted field lines
    ``lines_ideal`` (N, 2, 2) ideal px and their white widths ``line_widths`` (N,) px (None:
    no crossings of line pairs), and the goal posts' image feet ``posts_px``."""

    lines_ideal: np.ndarray | None = None
    line_widths: np.ndarray | None = None
    posts_px: object = ()


def find_crossings(ks, graph, ideal: np.ndarray, frame: FrameGrid, cc: CrossingsTuning,
                   trace: dict | None = None, floor_of=None, finds: Finds | None = None):
    """Section 4.1: L/T/X candidates of the key structure, each placed at the intersection of
    its arms' lines (fitted to the undistorted nodes, refined on the full-resolution white
    mask), and the crossings of pairs of fitted field lines (``finds.lines_ideal`` (N, 2, 2)
    ideal px, ``finds.line_widths`` (N,) px; ``crossings.line_pair_crossings``), all verified
    the same way (``_verify_crossing``: floor shape, range, boundary, objects, circle
    transitions and white paths; on the ``frame``'s shares inside the boundary). Of verified
    crossings closer than ``merge_distance`` cells the best scored one stays; none within
    ``post_radius`` cells of a goal post's foot (``finds.posts_px``). Returns rows [type,
    distance, bearing, orientation, confidence] and the crossings' image positions."""
    white, green, other, top = frame.inside, frame.green, frame.other, frame.top
    camera, to_floor, cell, white_px = frame.camera, frame.to_floor, frame.cell, frame.white_px
    lines_ideal, line_widths, posts_px = Finds() if finds is None else finds
    lo, hi = cc.l_angle if floor_of is None else cc.l_angle_floor
    cands = crossing_candidates(ks, graph, cc.arm_reach, (lo, hi), floor_of)
    other_mean = cv2.blur(other, (3, 3), borderType=cv2.BORDER_REPLICATE)
    rows_ = np.arange(white.shape[0], dtype=np.float64)[:, None]
    field_cells = (rows_ >= np.asarray(top, np.float64)[None, :]).astype(np.float32)
    verdicts, found = [], []
    deg = ks.degree()
    frame = VerifyFrame(white, green, other_mean, top, camera, to_floor, cc, cell, field_cells,
                        white_px)
    for cand in cands:
        verdict = _crossing(cand, ks, ideal, frame, deg)
        verdicts.append(verdict)
        if not isinstance(verdict, str):
            found.append(verdict)
    pairs, pair_verdicts = [], []
    if lines_ideal is not None and len(lines_ideal) > 1 and cc.line_pairs:
        lines_all, widths_all = lines_ideal, line_widths
        first_stem = None
        if white_px is not None and cc.stems:
            stems = stem_lines(lines_ideal, white_px, camera, to_floor, cc, cell)
            if len(stems):
                first_stem = len(lines_ideal)
                lines_all = np.concatenate([lines_ideal, stems])
                widths_all = np.concatenate([line_widths, np.full(len(stems), 0.0)])
        pairs = line_pair_crossings(lines_all, widths_all, to_floor, cc.pair_gap * cell,
                                    cc.max_misfit, first_stem)
        reach = cc.arm_reach * cell
        for lc in pairs:
            verdict = _verify_crossing(lc.kind, lc.point, lc.arms,
                                       np.minimum(reach, lc.lengths), frame, lc.lengths)
            pair_verdicts.append(verdict)
            if not isinstance(verdict, str):
                found.append(verdict)
    found.sort(key=lambda v: -v[0][4])
    rows, pxs = [], []
    # a goal post standing on a line makes a junction in the image, not a crossing
    near_post = cc.post_radius * cell
    found = [(row, px) for row, px in found
             if all(np.hypot(*(px - q)) > near_post for q in posts_px)]
    for row, px in found:
        if all(np.hypot(*(px - q)) > cc.merge_distance * cell for q in pxs):
            rows.append(row)
            pxs.append(px)
    if trace is not None:
        trace.update(candidates=cands, crossing_verdicts=verdicts, line_pairs=pairs,
                     line_pair_verdicts=pair_verdicts)
    return rows, pxs


def _crossing(cand, ks, ideal, frame, deg=None):
    """One key-structure candidate -> (row, image position), or the reason it was rejected
    (``frame``: the frame's VerifyFrame, ``deg``: the key structure's node degrees)."""
    cc, cell, sight = frame.cc, frame.cell, frame.sight
    white_px = sight.white_px if sight.use_white else None
    centre = ideal[ks.node[cand.key]]
    if not np.isfinite(centre).all():
        return "outside the lens model"
    chains = ks.arms(cand.key, 1 + cc.arm_skip + cc.arm_nodes, deg)
    if len(chains) != len(cand.arm_points):
        return "arm without nodes"
    placed = place_crossing(cand.kind, centre, chains, ideal, cc, cell,
                            white_px if cc.refine else None, frame.camera)
    if isinstance(placed, str):
        return placed
    x, dirs, lengths = placed
    reach = np.minimum(cc.arm_reach * cell, lengths)
    return _verify_crossing(cand.kind, x, dirs, reach, frame, lengths)


PLACE_REASONS = ("", "arm without nodes", "arms do not meet near the node")
KIND_INDEX = {"L": 0, "T": 1, "X": 2}


def place_crossing(kind: str, centre: np.ndarray, chains: list[list[int]], ideal: np.ndarray,
                   cc: CrossingsTuning, cell: int, white_px: np.ndarray | None, camera):
    """A key-structure candidate placed where its arms' lines meet: each arm's line fitted to
    its nodes (the chains' nodes from ``arm_skip`` + 1 on, undistorted ``ideal``), refined
    on the full-resolution white mask ``white_px`` unless None, and cut with the others.
    Returns (crossing (2,), the arms' unit directions (A, 2), the lines' lengths along them
    from it (A,), at least ``arm_step`` cells) in ideal px, or the reason it is rejected (an
    arm without nodes in the lens model, lines that do not meet within ``max_shift`` cells
    of the node).

    Per arm: the least-squares line of its nodes number ``arm_skip`` + 1 .. ``arm_skip`` +
    ``arm_nodes`` from the crossing (the nodes right next to a crossing bend towards it; the
    node itself joins an arm of one node), pointing away from it; refined over the nodes'
    extent from ``refine_skip`` cells off the crossing on (line_fit.refine_kernel; the
    coarse line where that fails). The lines meet as an L's two arms, a T's bar (its two most
    nearly opposite arms fitted together) with the stem, an X's two lines (opposite arms
    fitted together). It runs compiled (``_place``)."""
    n = len(chains)
    flat, start = flat_lists(chains)
    refine = white_px is not None
    out = np.empty((n + 1, 3))
    rule = (int(cc.arm_skip), int(cc.arm_nodes), float(cc.refine_skip * cell),
            float(cell), float(cc.refine_step), float(cc.refine_reach * cell),
            int(cc.refine_min_points), float(cc.max_shift * cell),
            float(cc.arm_step * cell))
    code = _place(KIND_INDEX[kind], np.ascontiguousarray(centre, np.float64), flat, start,
                  np.ascontiguousarray(ideal, np.float64), refine,
                  white_px if refine else np.zeros((1, 1), np.uint8),
                  lens_parameters(camera) if refine else np.zeros(9), rule, out)
    if code:
        return PLACE_REASONS[code]
    return out[0, :2].copy(), out[1:, :2].copy(), out[1:, 2].copy()


@njit(cache=True, nogil=True)
def _dot(ax, ay, bx, by):
    """The dot product of the 2-vectors (ax, ay) and (bx, by)."""
    return ax * bx + ay * by


@njit(cache=True, nogil=True)
def _fit_away(sel, ox, oy):
    """The least-squares line (cx, cy, ux, uy) of the points ``sel``
    (n, 2), its direction pointing away from (ox, oy)."""
    cx, cy, ux, uy, _, _, _ = _fit_points(sel)
    if _dot(cx - ox, cy - oy, ux, uy) < 0:
        ux, uy = -ux, -uy
    return cx, cy, ux, uy


@njit(cache=True, nogil=True)
def _meet(c1x, c1y, u1x, u1y, c2x, c2y, u2x, u2y):
    """Where the lines through c1 along u1 and through c2 along u2 meet: (ok, x, y), not ok
    when they are nearly parallel (|sin| < 1e-3, _line_cut)."""
    det, t, _ = _line_cut(u1x, u1y, u2x, u2y, c2x - c1x, c2y - c1y)
    if abs(det) < 1e-3:  # nearly parallel (|sin| < 1e-3)
        return False, np.nan, np.nan
    return True, c1x + t * u1x, c1y + t * u1y


@njit(cache=True, nogil=True)
def _line_cut(u1x, u1y, u2x, u2y, bx, by):
    """(det, t, s) of the lines p + t u1 and p + b + s u2 meeting: the 2 x 2 system
    [u1, -u2] (t, s) = b solved by Cramer's rule; det = u2 x u1 (the sine of the angle
    between unit directions); t and s NaN when det is 0."""
    det = u2x * u1y - u1x * u2y
    if det == 0:
        return det, np.nan, np.nan
    return det, (u2x * by - u2y * bx) / det, (u1x * by - u1y * bx) / det


@njit(cache=True, nogil=True)
def _place(kind, centre, flat, start, coords, refine, white_px, lens, rule, out):
    """place_crossing compiled: the arms' lines, refined, their meeting point and the arms'
    lengths of one candidate (``kind`` 0 L, 1 T, 2 X; chain c of its arms is ``flat[start[c]:
    start[c + 1]]``; ``rule``: (skip, count, t_skip, cell, step, reach, min_points,
    max_shift, arm_step) as place_crossing makes it). The crossing into out[0, :2], arm a's
    direction and length into out[1 + a]; returns 0, or the index of its reason in
    PLACE_REASONS."""
    skip, count, t_skip, cell, step, reach, min_points, max_shift, arm_step = rule
    n = len(start) - 1
    ox, oy = centre[0], centre[1]
    cs = np.empty((n, 2))
    us = np.empty((n, 2))
    sels = []
    for a in range(n):
        # the arm's finite nodes after the crossing's, from ``skip`` on
        m = 0
        pts = np.empty((max(start[a + 1] - start[a] - 1, 0), 2))
        for i in range(start[a] + 1, start[a + 1]):
            px, py = coords[flat[i], 0], coords[flat[i], 1]
            if np.isfinite(px) and np.isfinite(py):
                pts[m, 0], pts[m, 1] = px, py
                m += 1
        if m == 0:
            return 1
        lo, hi = (skip, min(skip + count, m)) if m >= skip + 2 else (0, min(count, m))
        if hi - lo < 2:
            sel = np.empty((hi - lo + 1, 2))
            sel[0, 0], sel[0, 1] = ox, oy
            sel[1:] = pts[lo:hi]
        else:
            sel = pts[lo:hi].copy()
        cx, cy, ux, uy = _fit_away(sel, ox, oy)
        if refine:
            # refined over the nodes' extent from t_skip px off the crossing on
            t0, t1 = np.inf, -np.inf
            for i in range(sel.shape[0]):
                t = _dot(sel[i, 0] - ox, sel[i, 1] - oy, ux, uy)
                t0, t1 = min(t0, t), max(t1, t)
            t0 = max(t0, t_skip)
            if not t1 - t0 < cell:
                ends = np.empty((2, 2))
                ends[0, 0], ends[0, 1] = ox + t0 * ux, oy + t0 * uy
                ends[1, 0], ends[1, 1] = ox + t1 * ux, oy + t1 * uy
                res = np.empty(12)
                centres, _ = refine_kernel(ends, white_px, lens, step, reach, 0.0, min_points,
                                           0.0, res)
                if res[0] != 0:
                    dx, dy = res[7], res[8]
                    if not _dot(dx, dy, ux, uy) >= 0:
                        dx, dy = -dx, -dy
                    cx, cy, ux, uy = res[5], res[6], dx, dy
                    sel = centres
        cs[a, 0], cs[a, 1], us[a, 0], us[a, 1] = cx, cy, ux, uy
        sels.append(sel)
    # the lines' intersection
    if kind == 0:
        ok, x, y = _meet(cs[0, 0], cs[0, 1], us[0, 0], us[0, 1], cs[1, 0], cs[1, 1],
                         us[1, 0], us[1, 1])
    elif kind == 1:
        # the bar: the pair of most nearly opposite arms (the first smallest cosine)
        bi, bj, bs, best = 0, 1, 2, np.inf
        for i, j, s in ((0, 1, 2), (0, 2, 1), (1, 2, 0)):
            cos = _dot(us[i, 0], us[i, 1], us[j, 0], us[j, 1])
            if cos < best:
                bi, bj, bs, best = i, j, s, cos
        bx, by, vx, vy = _fit_away(np.concatenate((sels[bi], sels[bj])), cs[bi, 0], cs[bi, 1])
        ok, x, y = _meet(bx, by, vx, vy, cs[bs, 0], cs[bs, 1], us[bs, 0], us[bs, 1])
    elif n != 4:
        ok, x, y = False, np.nan, np.nan
    else:
        # X: arm 0 with its most opposite arm (np.argmin: the first smallest), the others
        j, best = 1, np.inf
        for k in range(1, 4):
            cos = _dot(us[0, 0], us[0, 1], us[k, 0], us[k, 1])
            if cos < best or k == 1:
                j, best = k, cos
        r0, r1 = (2, 3) if j == 1 else ((1, 3) if j == 2 else (1, 2))
        ax, ay, vx, vy = _fit_away(np.concatenate((sels[0], sels[j])), cs[0, 0], cs[0, 1])
        bx, by, wx, wy = _fit_away(np.concatenate((sels[r0], sels[r1])), cs[r0, 0],
                                   cs[r0, 1])
        ok, x, y = _meet(ax, ay, vx, vy, bx, by, wx, wy)
    if not ok or np.hypot(x - ox, y - oy) > max_shift:
        return 2
    out[0, 0], out[0, 1] = x, y
    for a in range(n):
        sel = sels[a]
        far = -np.inf
        for i in range(sel.shape[0]):
            t = _dot(sel[i, 0] - x, sel[i, 1] - y, us[a, 0], us[a, 1])
            if not (t <= far or np.isnan(far)):  # np.max: a NaN wins
                far = t
        out[1 + a, 0], out[1 + a, 1] = us[a, 0], us[a, 1]
        out[1 + a, 2] = arm_step if arm_step > far else far
    return 0


def _verify_crossing(kind, x, dirs, reach, frame, lengths=None):
    """A crossing of ``kind`` at ideal point ``x`` with arms along ``dirs`` (A, 2) reaching
    ``reach`` (A,) px, its lines extending ``lengths`` (A,) px along them -> (row, image
    position), or the reason it is rejected. The cheap floor checks come before the image
    checks. ``frame``: the frame's VerifyFrame.

    The floor checks run compiled (``_floor_checks``), the image checks too
    (``_image_checks``); numpy's arctan2 gives the bearing and the arms' floor angles (the
    kernels' atan2 is not numpy's to the bit), floor_arms the shape's fit."""
    cc = frame.cc
    n = len(dirs)
    x = np.ascontiguousarray(x, np.float64)
    dirs = np.ascontiguousarray(dirs, np.float64)
    reach = np.array(reach, np.float64)
    has_lengths = lengths is not None
    lengths = np.array(lengths, np.float64) if has_lengths else np.zeros(n)
    angles_at = np.empty((n + 1, 2))  # the crossing on the floor, each arm's offset there
    scalars = np.empty(3)
    code = _floor_checks(x, dirs, reach, lengths, has_lengths, frame.sight, frame.floor,
                         frame.params, angles_at, scalars)
    if code:
        return FLOOR_REASONS[code]
    angles = np.arctan2(angles_at[:, 1], angles_at[:, 0])
    dist, bearing, span = scalars[0], angles[0], scalars[1]
    orient, misfit = floor_arms(kind, angles[1:])
    if misfit > cc.max_misfit:
        return f"floor angles misfit {math.degrees(misfit):.0f} deg"
    if scalars[2]:  # beyond the grid's resolution
        return _verify_fine(kind, x, dirs, frame, (dist, bearing, orient, misfit, span))
    out = np.empty(3)
    code = _image_checks(KIND_INDEX[kind], x, dirs, reach, frame.sight, frame.floor,
                         frame.params, frame.radii, out)
    if code == IMAGE_VERIFIED:
        row = [CROSSING_CODES[kind], dist, bearing, orient,
               out[0] * (1.0 - misfit / math.radians(90.0))]
        return row, out[1:3].copy()
    if code == IMAGE_AS_T:
        return _continued_as_t(x, dirs, reach, frame, lengths if has_lengths else None)
    if code == IMAGE_FINE:
        # the grid's circles may take in a neighbouring line (a far goal area's lines lie two
        # cells apart): the full-resolution check decides
        return _verify_fine(kind, x, dirs, frame,
                            (dist, bearing, orient, misfit, max(span, cc.max_cell_span)))
    return IMAGE_REASONS[code]


class Floor(NamedTuple):
    """A frame's floor projection as the kernels read it (perspective.FloorProjection): ``m``
    takes an ideal pixel (u, v, 1) to its ray, ``m_inv`` a floor point back to its
    homogeneous ideal pixel, ``height`` (m) the lens above the floor, ``pos`` (2,) the lens's
    position over the floor in the robot frame, ``shifted`` whether that is not (0, 0)."""

    m: np.ndarray
    m_inv: np.ndarray
    height: float
    pos: np.ndarray
    shifted: bool


def floor_bundle(to_floor) -> Floor:
    """The kernels' Floor of a perspective.FloorProjection."""
    pos = np.asarray(to_floor.position, np.float64)
    return Floor(to_floor.m, to_floor.m_inv, to_floor.height, pos, bool(pos.any()))


class Sight(NamedTuple):
    """What the verification kernels see of a frame: the grid's ``white``, ``green`` and
    ``other_mean`` shares (float32, cells), its field boundary ``top`` (float64, a row per
    column), the ``field`` cells (float32; (1, 1) when not given), the full-resolution white
    mask ``white_px`` (uint8; (1, 1) when not given, ``use_white`` False) and the ``lens``
    (line_fit.lens_parameters)."""

    white: np.ndarray
    green: np.ndarray
    other_mean: np.ndarray
    top: np.ndarray
    field: np.ndarray
    white_px: np.ndarray
    use_white: bool
    lens: np.ndarray


class VerifyFrame:
    """What the checks of _verify_crossing read of a frame, made once per frame: the frame's
    camera, floor projection ``to_floor``, crossings tuning ``cc`` (CROSSINGS) and grid
    ``cell`` (px); the grid's images, the white mask and the lens as the kernels take them
    (``sight``), the floor projection as they take it (``floor``), the tuning's numbers
    (``params``, indexed by the P_ names) and the circles' radii."""

    def __init__(self, white, green, other_mean, top, camera, to_floor, cc, cell,
                 field_cells=None, white_px=None):
        self.camera, self.to_floor, self.cc, self.cell = camera, to_floor, cc, cell
        use_field, use_white = field_cells is not None, white_px is not None
        self.sight = Sight(np.asarray(white, np.float32), np.asarray(green, np.float32),
                           np.asarray(other_mean, np.float32),
                           np.ascontiguousarray(top, np.float64),
                           np.asarray(field_cells, np.float32) if use_field else _NO_CELLS,
                           white_px if use_white else _NO_WHITE, use_white,
                           lens_parameters(camera))
        self.floor = floor_bundle(to_floor)
        self.radii = np.asarray(cc.circle_radii, np.float64)
        self.params = verify_params(camera, cc, cell, use_field)


_NO_CELLS = np.zeros((1, 1), np.float32)  # a Sight without the field cells
_NO_WHITE = np.zeros((1, 1), np.uint8)  # ... without the full-resolution white mask

def verify_params(camera, cc: CrossingsTuning, cell: int, use_field: bool = False
                  ) -> np.ndarray:
    """The numbers the verification kernels read (P_COUNT,), indexed by the P_ names."""
    w, h = camera.image_size
    p = np.empty(P_COUNT)
    p[P_CELL], p[P_WIDTH], p[P_HEIGHT] = cell, w, h
    p[P_FINE] = bool(cc.fine)
    p[P_USE_FIELD] = use_field
    p[P_WIDTH_LO], p[P_WIDTH_HI] = cc.width_ratio
    for k, name in _P_CONF:
        p[k] = getattr(cc, name)
    return p


# the numbers of VerifyFrame.params: the grid's cell (px), the image's size (px), whether the
# fine checks are on and the field region given, a painted line's width ratio, the tuning's
(P_CELL, P_WIDTH, P_HEIGHT, P_FINE, P_USE_FIELD, P_WIDTH_LO, P_WIDTH_HI, P_ARM_STEP,
 P_MIN_ARM_LENGTH, P_ARM_REACH, P_REFINE_STEP, P_REFINE_REACH, P_ARM_GROW, P_ARM_TOLERANCE,
 P_MAX_CELL_SPAN, P_EDGE_MARGIN, P_OBJECT_RADIUS, P_LINE_WIDTH, P_FINE_PX, P_T_GREEN,
 P_T_WHITE, P_RELATIVE, P_ARM_GAP, P_MAX_RADIUS, P_MAX_OTHER, P_MIN_PATH_SHARE,
 P_COUNT) = range(27)
_P_CONF = ((P_ARM_STEP, "arm_step"), (P_MIN_ARM_LENGTH, "min_arm_length"),
           (P_ARM_REACH, "arm_reach"), (P_REFINE_STEP, "refine_step"),
           (P_REFINE_REACH, "refine_reach"), (P_ARM_GROW, "arm_grow"),
           (P_ARM_TOLERANCE, "arm_tolerance"), (P_MAX_CELL_SPAN, "max_cell_span"),
           (P_EDGE_MARGIN, "edge_margin"), (P_OBJECT_RADIUS, "object_radius"),
           (P_LINE_WIDTH, "line_width"), (P_FINE_PX, "fine_px"), (P_T_GREEN, "t_green"),
           (P_T_WHITE, "t_white"), (P_RELATIVE, "relative"), (P_ARM_GAP, "arm_gap"),
           (P_MAX_RADIUS, "max_radius"), (P_MAX_OTHER, "max_other"),
           (P_MIN_PATH_SHARE, "min_path_share"))

FLOOR_REASONS = ("", "above the horizon", "arm too short", "too far")
IMAGE_VERIFIED, IMAGE_AS_T, IMAGE_FINE = 0, 1, 2
IMAGE_REASONS = ("", "", "", "outside the lens model", "at the field boundary",
                 "next to an object", "not verified in the image")


@njit(cache=True, nogil=True)
def floor_at(m, height, pos, shifted, x, y):
    """perspective.FloorProjection at one ideal pixel (x, y): its ray m (x, y, 1) cut with the
    floor ``height`` below the lens (NaN unless the ray points down), plus the lens's
    position ``pos`` over the floor if ``shifted`` (perspective._to_floor per pixel)."""
    rx = x * m[0, 0] + y * m[0, 1] + m[0, 2]
    ry = x * m[1, 0] + y * m[1, 1] + m[1, 2]
    down = x * m[2, 0] + y * m[2, 1] + m[2, 2]
    t = height / -down if down < -1e-9 else np.nan
    fx, fy = rx * t, ry * t
    if shifted:
        fx += pos[0]
        fy += pos[1]
    return fx, fy


@njit(cache=True, nogil=True)
def _to_edge(x0, x1, ux, uy, w, h, margin):
    """The distance (ideal px) from (x0, x1) along (ux, uy) to ``margin`` px inside the
    image's edge, at least 0 (in ideal pixels: the lens's distortion is small at the edges of
    the views this is used for)."""
    t = np.inf
    for d, lo, hi in ((ux, margin - x0, (w - 1 - margin) - x0),
                      (uy, margin - x1, (h - 1 - margin) - x1)):
        if d > 1e-12:
            t = min(t, hi / d)
        elif d < -1e-12:
            t = min(t, lo / d)
    return max(t, 0.0)


@njit(cache=True, nogil=True)
def _floor_checks(x, dirs, reach, lengths, has_lengths, sight, fl, p, angles_at, scalars):
    """_verify_crossing's floor checks, compiled: the crossing, a step along each arm, the
    cell below and the arms' ends on the floor; arms shorter than ``min_arm_length`` m grown
    along the white line on the full-resolution mask (white_arm_lengths; ``lengths`` and
    ``reach`` updated in place); the range. Returns 0 or the index of the reason in
    FLOOR_REASONS; ``angles_at`` (A + 1, 2) gets the crossing's floor point and each arm's
    offset from it (for arctan2), ``scalars`` the distance, the cell's span on the floor and
    whether that is beyond the grid's resolution (``sight``: Sight, ``fl``: Floor, ``p``:
    verify_params)."""
    use_white, white_px, lens = sight.use_white, sight.white_px, sight.lens
    m, height, pos, shifted = fl.m, fl.height, fl.pos, fl.shifted
    n = dirs.shape[0]
    cell = p[P_CELL]
    step = p[P_ARM_STEP] * cell
    x0, x1 = x[0], x[1]
    f0x, f0y = floor_at(m, height, pos, shifted, x0, x1)
    if not (np.isfinite(f0x) and np.isfinite(f0y)):
        return 1
    angles_at[0, 0], angles_at[0, 1] = f0x, f0y
    for k in range(n):
        fx, fy = floor_at(m, height, pos, shifted, x0 + step * dirs[k, 0],
                           x1 + step * dirs[k, 1])
        if not (np.isfinite(fx) and np.isfinite(fy)):
            return 1
        angles_at[1 + k, 0], angles_at[1 + k, 1] = fx - f0x, fy - f0y
    bx, by = floor_at(m, height, pos, shifted, x0 + 0.0, x1 + cell)
    span = np.hypot(bx - f0x, by - f0y)  # the cell below
    if not np.isfinite(span):
        span = np.inf
    if has_lengths:
        min_length = p[P_MIN_ARM_LENGTH]
        arm_m = np.empty(n)
        short = False
        for k in range(n):
            ex, ey = floor_at(m, height, pos, shifted, x0 + lengths[k] * dirs[k, 0],
                               x1 + lengths[k] * dirs[k, 1])
            arm_m[k] = np.hypot(ex - f0x, ey - f0y)  # NaN beyond the horizon: long enough
            short = short or arm_m[k] < min_length
        if short and use_white:
            # the fitted nodes or lines may end early (a far arm's few nodes, a line cut at a
            # junction): the arm is as long as the white line goes on along it in the image
            w, h = p[P_WIDTH], p[P_HEIGHT]
            far = p[P_ARM_REACH] * cell
            for k in range(n):
                ux, uy = dirs[k, 0], dirs[k, 1]
                if arm_m[k] < min_length:
                    gx, gy = grow_kernel(white_px, lens, x0 + lengths[k] * ux,
                                         x1 + lengths[k] * uy, ux, uy, p[P_REFINE_STEP],
                                         p[P_REFINE_REACH] * cell, p[P_ARM_GROW] * cell,
                                         p[P_ARM_TOLERANCE])
                    t = _dot(gx - x0, gy - x1, ux, uy)
                    if t > lengths[k]:
                        lengths[k] = t
                    if lengths[k] >= _to_edge(x0, x1, ux, uy, w, h, p[P_REFINE_STEP]):
                        lengths[k] = np.inf  # white up to the image's edge
                ex, ey = floor_at(m, height, pos, shifted, x0 + lengths[k] * ux,
                                   x1 + lengths[k] * uy)
                arm_m[k] = np.hypot(ex - f0x, ey - f0y)
                r = min(far, lengths[k]) if not np.isnan(lengths[k]) else lengths[k]
                if not reach[k] >= r and not np.isnan(reach[k]):  # np.maximum
                    reach[k] = r
        for k in range(n):
            if arm_m[k] < min_length:
                return 2
    scalars[0], scalars[1] = np.hypot(f0x, f0y), span
    # beyond the grid's resolution the full-resolution white mask decides (_verify_fine), as
    # far as its profiles (refine_step px apart) resolve the floor
    fine = span > p[P_MAX_CELL_SPAN]
    if fine and (not use_white or not p[P_FINE]
                 or span * p[P_REFINE_STEP] / cell > p[P_MAX_CELL_SPAN]):
        return 3
    scalars[2] = fine
    return 0


@njit(cache=True, nogil=True)
def _image_checks(kind, x, dirs, reach, sight, fl, p, radii, out):
    """_verify_crossing's image checks, compiled: each arm's reach clipped to the image
    (``reach`` updated in place), the crossing and the arms' ends in the image and on the
    grid, the field boundary and objects near it; an L (``kind`` 0) whose alternative is not
    in view (``_alternative_in_view``) or whose arms' line goes on through it (arm_state
    white) is to be looked at as a T (IMAGE_AS_T); then the circle and white paths
    (``_verify``). Returns IMAGE_VERIFIED with the score and the crossing's image position in
    ``out`` (3,), IMAGE_FINE where the grid does not verify it and the full-resolution check
    decides, or the index of the reason in IMAGE_REASONS (``sight``: Sight, ``fl``: Floor,
    ``p``: verify_params, ``radii``: the circles')."""
    white, green, other_mean, top, field = (sight.white, sight.green, sight.other_mean,
                                            sight.top, sight.field)
    use_white, lens = sight.use_white, sight.lens
    n = dirs.shape[0]
    cell = p[P_CELL]
    x0, x1 = x[0], x[1]
    w, h = p[P_WIDTH], p[P_HEIGHT]
    # an arm leaving the image is verified on its part in view
    grid = np.empty((n + 1, 2))
    for k in range(n + 1):
        if k == 0:
            qx, qy = x0, x1
        else:
            t = _to_edge(x0, x1, dirs[k - 1, 0], dirs[k - 1, 1], w, h, 0.5 * cell)
            if not reach[k - 1] <= t and not np.isnan(reach[k - 1]):  # np.minimum
                reach[k - 1] = t
            qx, qy = x0 + reach[k - 1] * dirs[k - 1, 0], x1 + reach[k - 1] * dirs[k - 1, 1]
        px, py = distort_point(lens, qx, qy)
        if not (np.isfinite(px) and np.isfinite(py)):
            return 3
        if k == 0:
            out[1], out[2] = px, py
        grid[k, 0], grid[k, 1] = (px + 0.5) / cell - 0.5, (py + 0.5) / cell - 0.5
    n_cols = top.shape[0]
    col = min(max(int(np.rint(grid[0, 0])), 0), n_cols - 1)
    near_top = -np.inf  # the boundary within two columns
    for c in range(max(col - 2, 0), min(col + 3, n_cols)):
        near_top = max(near_top, top[c])
    if grid[0, 1] - near_top < p[P_EDGE_MARGIN]:
        return 4  # a line meeting an object or the end of the view
    rows, cols = other_mean.shape
    row = min(max(int(np.rint(grid[0, 1])), 0), rows - 1)
    r = int(p[P_OBJECT_RADIUS])
    for i in range(max(row - r, 0), min(row + r + 1, rows)):
        for j in range(max(col - r, 0), min(col + r + 1, cols)):
            if other_mean[i, j] > 0.5:
                return 5  # a robot's or a person's white foot on a line
    # the arms that would make an L a T must be in view (a T's stem continued would make an
    # X, which fields hold only where the centre circle crosses the halfway line); a thin
    # line leaves a cell mostly green: where the full-resolution mask shows an arm's line
    # going on through the crossing, the L is no L
    if kind == 0:
        if not _alternative_in_view(x0, x1, dirs, sight, p):
            return IMAGE_AS_T
        if use_white:
            for k in range(n):
                if _arm_state(x0, x1, -dirs[k, 0], -dirs[k, 1], dirs, sight, fl, p) == 1:
                    return IMAGE_AS_T
    score = _verify(grid[0], grid[1:], white, green, field, p[P_USE_FIELD] != 0, radii,
                    (p[P_T_WHITE], p[P_RELATIVE], p[P_T_GREEN], p[P_ARM_GAP], p[P_MAX_RADIUS],
                     p[P_MAX_OTHER], p[P_MIN_PATH_SHARE]))
    if score <= 0:
        return IMAGE_FINE if use_white and p[P_FINE] else 6
    out[0] = score
    return IMAGE_VERIFIED


def _verify_fine(kind, x, dirs, frame, placed):
    """A crossing beyond the grid's resolution (one cell spans more than ``max_cell_span`` m
    of floor there; ``placed``: its distance, bearing, orientation and misfit on the floor
    and the cell's span there), verified on the full-resolution white mask: every arm's opposite
    direction is looked at (``arm_state``). An L needs both opposites green (one white makes
    it the T of that arm, neither known leaves it untold), a T its stem's opposite not white
    (an X). Its confidence is the grid's resolving power there (max_cell_span over the cell's
    span), times the shape's fit as on the grid. Returns (row, image position) or the reason
    it is rejected."""
    dist, bearing, orient, misfit, span = placed
    cc, cell, to_floor = frame.cc, frame.cell, frame.to_floor
    top, other_mean = frame.sight.top, frame.sight.other_mean
    px = distort_ideal(frame.sight.lens, x[None])[0]
    g = (px + 0.5) / cell - 0.5
    col = min(max(round(g[0]), 0), len(top) - 1)
    if not np.isfinite(g[1]) or g[1] < top[col]:
        return "at the field boundary"
    row = min(max(round(g[1]), 0), other_mean.shape[0] - 1)
    r = cc.object_radius
    if other_mean[max(row - r, 0): row + r + 1, max(col - r, 0): col + r + 1].max() > 0.5:
        return "next to an object"
    for u in dirs:
        st = arm_state(x, u, frame, dirs)
        if st != "white":
            return f"an arm {st}, not white"  # an arm without its white line
    # the arms without an opposite arm, by their directions on the floor (far away the
    # perspective folds a right angle in the image)
    f = to_floor(np.vstack([x[None], x[None] + cc.arm_step * cell * dirs]))
    fd = f[1:] - f[0]
    fd = fd / np.hypot(fd[:, 0], fd[:, 1])[:, None]
    if not np.isfinite(fd).all():
        return "above the horizon"
    cos_same = math.cos(cc.max_misfit)
    opposite = [k for k in range(len(dirs))
                if not any(fd[k, 0] * fd[j, 0] + fd[k, 1] * fd[j, 1] <= -cos_same
                           for j in range(len(dirs)))]
    if kind == "T":
        # the stem: the arm without an opposite arm
        if len(opposite) != 1:
            return "floor angles misfit"
        if arm_state(x, -dirs[opposite[0]], frame, dirs) == "white":
            return "white beyond the stem"  # white on through the bar: two lines crossing
    elif kind == "L":
        states = [arm_state(x, -dirs[k], frame, dirs) for k in opposite]
        white_k = [k for k, st in zip(opposite, states) if st == "white"]
        if len(white_k) == 1:
            k = white_k[0]
            arms = np.vstack([dirs, -dirs[k][None]])
            f = to_floor(np.vstack([x[None], x + cc.arm_step * cell * arms]))
            t_orient, t_misfit = floor_arms("T", np.arctan2(f[1:, 1] - f[0, 1],
                                                            f[1:, 0] - f[0, 0]))
            if t_misfit > cc.max_misfit:
                return f"floor angles misfit {math.degrees(t_misfit):.0f} deg"
            kind, orient, misfit = "T", t_orient, t_misfit
        elif white_k:
            return "not verified in the image"
        elif any(st != "green" for st in states):
            return "not green where a T's arm would be"
    else:
        return "too far"
    score = min(1.0, cc.max_cell_span / span) * (1.0 - misfit / math.radians(90.0))
    return [CROSSING_CODES[kind], dist, bearing, orient, score], px


def arm_state(x: np.ndarray, u: np.ndarray, frame: VerifyFrame,
              arms: np.ndarray | None = None) -> str:
    """What the image shows along the half-line from a crossing ``x`` (ideal px) along the
    unit ``u``, over ``min_arm_length`` m less a line width, from where it stands clear of
    the crossing's lines (one ``line_width`` m on the floor past the crossing line's edge,
    and far enough that the lines along ``arms`` (A, 2), as wide as painted lines there,
    no longer touch it in the image: far away a right angle on the floor is a narrow one in
    the image): "white" where the full-resolution white mask shows a line on it that long
    (line_fit.grow_along, profiles every px up to ``refine_step``; its runs centred on it and
    of a painted line's width, ``width_ratio``), or up to the image's edge; "green" where no
    white goes on, the line would be wide enough in the image to show (``fine_px`` / 2) and
    the cells along it are field (inside the boundary, no object, green at least
    ``t_green``); else "unknown" (out of view, hidden, not resolved, white of no line).
    ``frame``: the frame's VerifyFrame, made with the white mask."""
    a = np.zeros((0, 2)) if arms is None else np.ascontiguousarray(arms, np.float64)
    code = _arm_state(float(x[0]), float(x[1]), float(u[0]), float(u[1]), a, frame.sight,
                      frame.floor, frame.params)
    return ("unknown", "white", "green")[code]


@njit(cache=True, nogil=True)
def _arm_state(x0, x1, ux, uy, arms, sight, fl, p):
    """arm_state, compiled (``sight``: Sight, ``fl``: Floor, ``p``: verify_params): 0
    unknown, 1 white, 2 green."""
    white_px, green, other_mean, top, lens = (sight.white_px, sight.green, sight.other_mean,
                                              sight.top, sight.lens)
    w, h, cell = p[P_WIDTH], p[P_HEIGHT], p[P_CELL]
    line_width, tolerance = p[P_LINE_WIDTH], p[P_ARM_TOLERANCE]
    max_reach = p[P_REFINE_REACH] * cell
    fine_px, min_length, refine_step = p[P_FINE_PX], p[P_MIN_ARM_LENGTH], p[P_REFINE_STEP]
    ratio_lo, ratio_hi, t_green = p[P_WIDTH_LO], p[P_WIDTH_HI], p[P_T_GREEN]
    f0x, f0y = floor_at(fl.m, fl.height, fl.pos, True, x0, x1)
    f1x, f1y = floor_at(fl.m, fl.height, fl.pos, True, x0 + 4.0 * ux, x1 + 4.0 * uy)
    scale = math.hypot(f1x - f0x, f1y - f0y) / 4.0  # m of floor per px along u
    if not np.isfinite(scale) or scale <= 0:
        return 0
    start, reach = _clear_start_kernel(x0, x1, ux, uy, arms, scale, fl, line_width, tolerance,
                                       max_reach)
    need = start + max(fine_px, (min_length - line_width) / scale)
    step = min(max(line_width / scale, 1.0), refine_step)
    edge = _to_edge(x0, x1, ux, uy, w, h, step)  # to ``step`` px inside the image's edge
    sx, sy = x0 + start * ux, x1 + start * uy
    gx, gy = grow_kernel(white_px, lens, sx, sy, ux, uy, step, reach, need, tolerance)
    t = (gx - x0) * ux + (gy - x1) * uy
    nx, ny = -uy, ux
    if t >= need - 1e-6 or t >= edge - 1e-6:
        # white on: a painted line's, if its runs are centred on the arm and as wide as a
        # line of line_width m there (else something white that is no line: unknown)
        stop = min(t, max(need, start + 3 * step))
        seg = np.empty((2, 2))
        seg[0, 0], seg[0, 1] = sx, sy
        seg[1, 0], seg[1, 1] = x0 + stop * ux, x1 + stop * uy
        res = np.empty(12)
        _, widths = refine_kernel(seg, white_px, lens, step, reach, 0.0, 3, 0.0, res)
        if res[0] == 0:
            return 0
        for k in (1, 3):
            if abs((res[k] - x0) * nx + (res[k + 1] - x1) * ny) > 2 * tolerance:
                return 0
        mid = 0.5 * (start + stop)
        expected = _px_width(fl, x0 + mid * ux, x1 + mid * uy, ux, uy, line_width)
        ratio = np.median(widths) / max(expected, 1e-6)
        return 1 if ratio_lo <= ratio <= ratio_hi else 0
    if need > edge:
        return 0
    # a line thinner in the image than half the judged length (fine_px) may break up in the
    # white mask: no white there is no evidence of no line
    mid = 0.5 * (start + need)
    if not _px_width(fl, x0 + mid * ux, x1 + mid * uy, ux, uy, line_width) >= 0.5 * fine_px:
        return 0
    for k in range(3):
        tk = start + 0.5 * k * (need - start)
        px, py = distort_point(lens, x0 + tk * ux, x1 + tk * uy)
        gx_, gy_ = (px + 0.5) / cell - 0.5, (py + 0.5) / cell - 0.5
        col = min(max(int(round(gx_)), 0), top.shape[0] - 1)
        row = min(max(int(round(gy_)), 0), other_mean.shape[0] - 1)
        if gy_ < top[col] or other_mean[row, col] > 0.5:
            return 0
        if _sample_cell(green, gx_, gy_) < t_green:
            return 0
    return 2


@njit(cache=True, nogil=True)
def _ideal_point(fl, fx, fy):
    """perspective.FloorProjection.to_ideal at one floor point (``fl``: Floor)."""
    m_inv = fl.m_inv
    px, py, pz = fx - fl.pos[0], fy - fl.pos[1], -fl.height
    h0 = m_inv[0, 0] * px + m_inv[0, 1] * py + m_inv[0, 2] * pz
    h1 = m_inv[1, 0] * px + m_inv[1, 1] * py + m_inv[1, 2] * pz
    h2 = m_inv[2, 0] * px + m_inv[2, 1] * py + m_inv[2, 2] * pz
    if h2 <= 1e-9:
        return np.nan, np.nan
    return h0 / h2, h1 / h2


@njit(cache=True, nogil=True)
def _px_width(fl, px, py, ux, uy, line_width):
    """The width (ideal px, across (ux, uy)) of a line ``line_width`` m wide on the floor
    along the direction (ux, uy) takes at ideal pixel (px, py) (``fl``: Floor)."""
    f0x, f0y = floor_at(fl.m, fl.height, fl.pos, True, px, py)
    f1x, f1y = floor_at(fl.m, fl.height, fl.pos, True, px + ux, py + uy)
    ax, ay = f1x - f0x, f1y - f0y
    na = math.hypot(ax, ay)
    if not np.isfinite(na) or na <= 0:
        return np.nan
    nx, ny = -ay / na * (0.5 * line_width), ax / na * (0.5 * line_width)
    a0, a1 = _ideal_point(fl, f0x - nx, f0y - ny)
    b0, b1 = _ideal_point(fl, f0x + nx, f0y + ny)
    return abs((b0 - a0) * -uy + (b1 - a1) * ux)


@njit(cache=True, nogil=True)
def _clear_start_kernel(x0, x1, ux, uy, arms, scale, fl, line_width, tolerance, max_reach):
    """Where the half-line from (x0, x1) along (ux, uy) stands clear of the crossing's lines
    (arm_state's start, ideal px; ``scale``: m of floor per px along it) and the reach of
    its profiles (px)."""
    start = max(1.0, line_width / scale)
    w_u = _px_width(fl, x0, x1, ux, uy, line_width)
    if not np.isfinite(w_u):
        w_u = 1.0
    for k in range(arms.shape[0]):
        vx, vy = arms[k, 0], arms[k, 1]
        sin = abs(ux * vy - uy * vx)
        dot = ux * vx + uy * vy
        if 0.0 < dot < 0.999:  # ahead of the line, and not the line itself
            w_v = _px_width(fl, x0, x1, vx, vy, line_width)
            if np.isfinite(w_v):
                start = max(start, (0.5 * (w_u + w_v) + tolerance) / max(sin, 1e-3))
    reach = min(max(1.5 * w_u + 2 * tolerance, 2 * tolerance), max_reach)
    return start, reach


def _continued_as_t(x, dirs, reach, frame, lengths):
    """An L whose view opposite its arms is not carpet: where one arm's line goes on through
    the crossing (the fit of a T's bar ended at the stem, or the bar's far half was fitted as
    a line of its own that missed the pair), the crossing is that T. Each arm continued is
    verified as a T, by the same floor and image checks (the circle then counts three
    passages, and the continued arm needs its white path); the best verified one is returned,
    else the L's rejection."""
    best = "not green where a T's arm would be"
    for k in range(len(dirs)):
        arms = np.vstack([dirs, -dirs[k][None]])
        ext = np.append(reach, reach[k])
        lens = None if lengths is None else np.append(lengths, reach[k])
        v = _verify_crossing("T", x, arms, ext, frame, lens)
        if not isinstance(v, str) and (isinstance(best, str) or v[0][4] > best[0][4]):
            best = v
    return best


@njit(cache=True, nogil=True)
def _alternative_in_view(x0, x1, dirs, sight, p):
    """Whether the image shows carpet opposite an L's arms (where the third arm of a T would
    be), ``arm_reach`` cells from the crossing (x0, x1): inside the image and the field
    boundary (``edge_margin`` cells below ``sight.top``), no object there, and green (at least
    ``t_green``, sampled as OpenCV's remap does: ``_remap_sample``). A T seen with one half of
    its bar out of view or hidden looks like an L; so do a far X's arms, flattened by the
    perspective (``p``: verify_params)."""
    lens, top, other_mean, green = sight.lens, sight.top, sight.other_mean, sight.green
    w, h, cell = p[P_WIDTH], p[P_HEIGHT], p[P_CELL]
    reach, edge_margin, t_green = p[P_ARM_REACH] * cell, p[P_EDGE_MARGIN], p[P_T_GREEN]
    for k in range(dirs.shape[0]):
        px, py = distort_point(lens, x0 - reach * dirs[k, 0], x1 - reach * dirs[k, 1])
        if not (np.isfinite(px) and np.isfinite(py) and 0 <= px <= w - 1
                and 0 <= py <= h - 1):
            return False
        gx, gy = (px + 0.5) / cell - 0.5, (py + 0.5) / cell - 0.5
        col = min(max(int(np.rint(gx)), 0), top.shape[0] - 1)
        row = min(max(int(np.rint(gy)), 0), other_mean.shape[0] - 1)
        if gy - top[col] < edge_margin or other_mean[row, col] > 0.5:
            return False
        if _remap_sample(green, gx, gy) < t_green:
            return False
    return True


@njit(cache=True, nogil=True)
def _remap_sample(image, x, y):
    """sample_cells at one point (bilinear_at, pixels outside the image 0)."""
    return bilinear_at(image, x, y, 0.0)
