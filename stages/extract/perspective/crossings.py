"""Line crossing detection on the key node structure (Schulz et al. 2011, section 4.1): the
Python side of the crossings step - its tuning (``CROSSINGS``), candidates, verification,
placement and merging, and the frame's chain ``find_crossings``. The compiled kernels these
call live in ``crossing_kernels``; this module prepares their arrays and turns their codes
into crossings and reasons.

A degree-2 key node whose two edges meet at a corner angle is an L-crossing candidate, a
degree-3 node a T and a degree-4 node an X (``crossing_candidates``). The crossing is placed
where the lines fitted to its arms meet (``place_crossing``; an L's skeleton cuts its
corner). A candidate is verified in the subsampled colour images by two checks
(``_verify_crossing``'s image checks, compiled in ``crossing_kernels._verify``):

- on a circle centred at the crossing a state machine counts the green -> white -> green
  passages (one per arm leaving the crossing); the count must equal the candidate's number
  of arms, on a circle mostly of green and white (a robot's or a person's white feet on a
  line make false corners);
- from the crossing along each arm (to the next node, at most a few cells) the straight path
  must be white.

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

from stages.common.features_file import CROSSING_CODES
from stages.common.field import crossing_orientation

from .crossing_kernels import (
    IMAGE_AS_T,
    IMAGE_FINE,
    IMAGE_VERIFIED,
    P_ARM_GAP,
    P_ARM_GROW,
    P_ARM_REACH,
    P_ARM_STEP,
    P_ARM_TOLERANCE,
    P_CELL,
    P_COUNT,
    P_EDGE_MARGIN,
    P_FINE,
    P_FINE_PX,
    P_HEIGHT,
    P_LINE_WIDTH,
    P_MAX_CELL_SPAN,
    P_MAX_OTHER,
    P_MAX_RADIUS,
    P_MIN_ARM_LENGTH,
    P_MIN_PATH_SHARE,
    P_OBJECT_RADIUS,
    P_REFINE_REACH,
    P_REFINE_STEP,
    P_RELATIVE,
    P_T_GREEN,
    P_T_WHITE,
    P_USE_FIELD,
    P_WIDTH,
    P_WIDTH_HI,
    P_WIDTH_LO,
    _arm_state,
    _corner_angles,
    _distinct_arms,
    _floor_checks,
    _image_checks,
    _pair_crossings,
    _place,
    _points_along,
    _stems,
)
from .line_fit import LINES, distort_ideal, lens_parameters
from .line_structure import KeyStructure, LineGraph, flat_lists


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
    # line on the full-resolution mask (crossing_kernels._floor_checks): by at most arm_grow cells,
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


def points_along(pos: np.ndarray, chains: list[list[int]], reach: float) -> np.ndarray:
    """The point ``reach`` cells along each fine chain (starting at its first node), or the
    chain's last node when it is shorter (C, 2), in one compiled pass (``_points_along``)."""
    flat, start = flat_lists(chains)
    out = np.empty((len(chains), 2))
    _points_along(np.ascontiguousarray(pos, np.float64), flat, start, float(reach), out)
    return out


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
    extent from ``refine_skip`` cells off the crossing on (line_fit_kernels.refine_kernel; the
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
IMAGE_REASONS = ("", "", "", "outside the lens model", "at the field boundary",
                 "next to an object", "not verified in the image")


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
