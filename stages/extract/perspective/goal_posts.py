"""Goal posts: white vertical bars rising above the field boundary (Schulz et al. 2011 treat poles
as point landmarks; a post's foot point on the floor is one).

On the subsampled white image, per column (vectorised over columns):

- ``bar_runs``: the run of white cells going up from the field boundary (the part of the bar
  that rises above it) and the run going down from the boundary into the field (the part in
  front of the field, down to the post's foot);
- ``standing_bars``: columns whose upward run rises at least ``min_rise`` cells above their
  surroundings', grouped into bars of adjacent columns no wider than ``max_width`` cells (a
  white wall or banner is wider) that stand out (``_stands_out``: not white beside them);
- ``post_feet``: per bar, the foot point in full-resolution pixels: the white-weighted mean
  column and the bottom of the downward run with a subpixel fraction from the share of white
  in the lowest cell.

``is_post_bar`` tells a post's lower part, which the line structure makes a segment, from a
field line seen along its length.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...common.jit import njit
from ...common.numeric import median, sum32


class PostsTuning(NamedTuple):
    """The numbers of the goal post steps (``goal_posts``, ``is_post_bar`` and the extractor's
    checks on the floor), tuned on the rendered KidSize and NAO frames and the HULKs and
    Falcons frames (docs/manual.md "Perspective extraction on real frames"). The posts'
    diameter and range are the user's (the extractor's conf, posts.post_diameter and
    posts.max_distance)."""

    t_white: float  # white share of a cell of a post
    min_rise: int  # cells of white above the boundary
    max_rise: int  # cells
    max_below: int  # cells
    max_width: int  # cells (goal_posts' default; the extractor uses min_distance)
    min_distance: float  # m: posts nearer than this (wider in the image) are not sought
    full_height: int  # cells of bar at which the confidence is 1
    # m of white bar at least, unless it runs out of the image (a post rises to its crossbar,
    # 0.8 m in the SPL, 1.2 m in the Humanoid league; a robot's white arm beside its torso,
    # projected from its lower end as if that stood on the floor, measures about 0.5 m: on
    # rendered NAO walks of the tuning range, 95 % of the true posts measured 0.70 m or more,
    # half of the bars that were no post 0.52 m or less)
    min_height: float
    width_ratio: tuple[float, float]  # measured / expected width in the image
    # a white segment inside the boundary is a post's bar, not a line, when it runs straight
    # away from the robot on the floor (perpendicular distance below bar_radial m), starts at
    # least bar_min_distance m away, reaches the boundary (within bar_touch cells) and keeps
    # bar_width_ratio of a post's width (see is_post_bar)
    bar_radial: float
    bar_min_distance: float
    bar_touch: float
    bar_width_ratio: float
    bar_confidence: float


POSTS = PostsTuning(t_white=0.2, min_rise=3, max_rise=30, max_below=30, max_width=4,
                    min_distance=0.7, full_height=12, min_height=0.6, width_ratio=(0.4, 2.5),
                    bar_radial=0.15, bar_min_distance=0.8, bar_touch=3.5, bar_width_ratio=0.6,
                    bar_confidence=0.5)


def bar_runs(white: np.ndarray, top: np.ndarray, t_white: float, max_up: int, max_down: int
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per column: (run of white cells upward from the boundary, run downward from it, row of
    the first field cell). A cell is white when its share is at least ``t_white``."""
    h, w = white.shape
    up, down, start = (np.empty(w, np.int64) for _ in range(3))
    white = np.ascontiguousarray(white)
    _white_runs(white, white.dtype.type(t_white), np.asarray(top, np.float64), int(max_up),
                int(max_down), up, down, start)
    return up, down, start


@njit(cache=True, nogil=True)
def _white_runs(white, t_white, top, max_up, max_down, up, down, start):
    """Per column, its first field row ``start`` (ceil(top) within 0..h; a NaN top as numpy
    casts it, to 0) and the white cells (share >= t_white) in a row upward from the row
    above it (at most ``max_up``) and downward from it (at most ``max_down``)."""
    h = white.shape[0]
    for c in range(white.shape[1]):
        start[c] = 0 if np.isnan(top[c]) else min(max(int(np.ceil(top[c])), 0), h)
    is_white = white >= t_white
    for c in range(white.shape[1]):
        n = 0
        while n < max_up and 0 <= start[c] - 1 - n < h and is_white[start[c] - 1 - n, c]:
            n += 1
        up[c] = n
        n = 0
        while n < max_down and 0 <= start[c] + n < h and is_white[start[c] + n, c]:
            n += 1
        down[c] = n


def standing_bars(excess: np.ndarray, base: np.ndarray, start: np.ndarray, white: np.ndarray,
                  t_white: float, min_rise: int, max_width: int, near: int
                  ) -> tuple[list[np.ndarray], list[int]]:
    """The bars: groups of adjacent columns whose white run rises at least ``min_rise`` cells
    above their surroundings' (``excess``), at most ``max_width`` columns wide, that stand out
    (``_stands_out`` in the ``near`` rows above the group's surroundings' white, ``base``, from
    its highest boundary row ``start``), with that lift of each (its largest base). Found by
    one compiled pass (``_standing_bars``)."""
    white = np.ascontiguousarray(white)
    bars = np.empty((len(excess), 3), np.int64)
    m = _standing_bars(np.ascontiguousarray(excess, np.int64),
                       np.ascontiguousarray(base, np.int64),
                       np.ascontiguousarray(start, np.int64), white, white.dtype.type(t_white),
                       int(min_rise), int(max_width), int(near), bars)
    rows = bars[:m].tolist()
    return [np.arange(a, b) for a, b, _ in rows], [lift for _, _, lift in rows]


@njit(cache=True, nogil=True)
def _standing_bars(excess, base, start, white, t_white, min_rise, max_width, near, bars):
    """standing_bars' pass: the maximal runs of columns with excess >= min_rise, at most
    max_width wide, each with its largest base (the lift) and lowest start, kept where they
    stand out (_stands_out, margin 2): (first column, end column, lift) into ``bars``;
    returns their number."""
    n = len(excess)
    m = 0
    c = 0
    while c < n:
        if excess[c] < min_rise:
            c += 1
            continue
        a = c
        while c < n and excess[c] >= min_rise:
            c += 1
        if c - a > max_width:
            continue
        lift, low = base[a], start[a]
        for k in range(a + 1, c):
            lift, low = max(lift, base[k]), min(low, start[k])
        if _stands_out(white, a, c - 1, low - lift, near, t_white, 2):
            bars[m, 0], bars[m, 1], bars[m, 2] = a, c, lift
            m += 1
    return m


@njit(cache=True, nogil=True)
def _stands_out(white, first, last, start, rise, t_white, margin):
    """A bar (the columns first..last) stands out when, in the ``rise`` rows just above the
    boundary row ``start``, the cells ``margin`` columns left and right of it are not white
    (>= t_white) in most rows: the share of white rows beside it (as np.mean of the column's
    white test over the rows start - rise .. start - 1 within the image) is at most 1/3 on
    both sides (a white wall or banner is white beside it too; the image border counts as
    not white)."""
    h, w = white.shape
    r0, r1 = max(start - rise, 0), max(start, 0)
    if r1 <= r0:
        return False
    for c in (first - margin, last + margin):
        if 0 <= c < w:
            count = 0
            for r in range(r0, min(r1, h)):
                if white[r, c] >= t_white:
                    count += 1
            if not count / (r1 - r0) <= 1 / 3:
                return False
    return True


def bar_width(white: np.ndarray, group: np.ndarray, start: int, rise: int, cell: int) -> float:
    """Measured width of a bar in pixels: the median over the ``rise`` rows just above the
    boundary of the white share summed across its columns and one column each side, times the
    cell size."""
    h, w = white.shape
    r0, r1 = max(start - rise, 0), max(start, 0)
    if r1 <= r0:
        return 0.0
    sums = white[r0:r1, max(group[0] - 1, 0):min(group[-1] + 2, w)].sum(axis=1)
    # np.median's value (the compiled median) times the cell, in float32 as numpy has it
    return float(np.float32(median(sums)) * np.float32(cell))


def post_feet(white: np.ndarray, groups: list[np.ndarray], up_run: np.ndarray,
              down_run: np.ndarray, start: np.ndarray, t_white: float, cell: int
              ) -> tuple[np.ndarray, np.ndarray]:
    """Foot points (P, 2) in full-resolution pixels (u, v) and the bars' heights in cells (P,)
    (white run above (``up_run``) plus below the boundary)."""
    feet, heights = [], []
    for g in groups:
        wts = np.array([white[max(start[c] - 1, 0), c] for c in g]) + 1e-6
        u = float(np.sum(((g + 0.5) * cell - 0.5) * wts) / wts.sum())
        main = g[int(np.argmax(up_run[g] + down_run[g]))]
        bottom = start[main] + down_run[main]  # first non-white row below the bar
        frac = 0.0
        if bottom < white.shape[0]:
            ref = max(float(white[max(start[main] - 1, 0), main]), t_white)
            frac = min(1.0, float(white[bottom, main]) / ref)
        v = (bottom + frac) * cell - 0.5
        feet.append((u, v))
        heights.append(float(up_run[main] + down_run[main]))
    return np.array(feet, float).reshape(-1, 2), np.array(heights, float)


def rise_above_surroundings(up_run: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """(excess, base): the upward white run of each column minus the run its surroundings
    share (the grey opening of the run over ``window`` columns, borders replicated, as
    cv2.morphologyEx opens it: compiled, ``_opening``). A band of white that rises above the
    boundary everywhere (a hall floor or wall that is white too, a barrier board) is the
    base; a post narrower than ``window`` rises above it."""
    run = np.asarray(up_run, np.int64)
    base = _opening(np.ascontiguousarray(run), max(int(window), 1))
    return run - base, base


@njit(cache=True, nogil=True)
def _opening(run, window):
    """Grey opening of a row of integers: the minimum over ``window`` columns (anchored at
    window // 2, the row's ends replicated), then the maximum over the same."""
    return _window_extreme(_window_extreme(run, window, False), window, True)


@njit(cache=True, nogil=True)
def _window_extreme(row, window, largest):
    """The minimum (``largest``: maximum) of a row of integers over ``window`` columns
    anchored at window // 2, the row's ends replicated."""
    n = len(row)
    a = window // 2
    out = np.empty(n, np.int64)
    for x in range(n):
        m = row[min(max(x - a, 0), n - 1)]
        for j in range(1, window):
            v = row[min(max(x + j - a, 0), n - 1)]
            m = max(m, v) if largest else min(m, v)
        out[x] = m
    return out


def goal_posts(white: np.ndarray, top: np.ndarray, tuning: PostsTuning, cell: int,
               max_width: int | None = None):
    """The whole step: (foot points (P, 2) px, bar heights (P,) cells, measured bar widths (P,)
    px, column groups, whether each bar runs out of sight upwards (its white run reaches the
    image's top row or ``max_rise``: its height is a lower bound)). Bars are columns whose
    white run rises at least ``min_rise`` cells above their surroundings'
    (``rise_above_surroundings`` over ``max_width`` + 2 columns; ``max_width`` cells, default
    the tuning's), told apart there (``_stands_out``) and measured there (``bar_width``). The
    caller removes the bars from the white image before the line structure is built, so a
    post's lower part is not taken for a line."""
    t = tuning
    max_width = int(t.max_width if max_width is None else max_width)
    up, down, start = bar_runs(white, top, t.t_white, t.max_rise, t.max_below)
    excess, base = rise_above_surroundings(up, max_width + 2)
    near = t.min_rise  # rows above the surroundings' white where a post is told apart
    groups, lift = standing_bars(excess, base, start, white, t.t_white, t.min_rise,
                                 max_width, near)
    # heights: the part of the bar rising above the surroundings' white, plus below the boundary
    feet, heights = post_feet(white, groups, excess, down, start, t.t_white, cell)
    widths = np.array([bar_width(white, g, int(start[g].min()) - lf, near, cell)
                       for g, lf in zip(groups, lift)], float)
    cut = np.array([bool(np.any((up[g] >= t.max_rise) | (start[g] - up[g] <= 0)))
                    for g in groups], bool)
    return feet, heights, widths, groups, cut


def runs_away(dist: float, near: float, pc: PostsTuning) -> bool:
    """Whether a white segment's floor projection (perpendicular distance ``dist`` from the
    robot, nearest end ``near``, m) could be a vertical bar standing on the floor: it runs
    straight away from the robot (a vertical line lies in a vertical plane through the camera,
    which meets the floor in a line through the robot: ``dist`` below ``bar_radial``) and
    starts at least ``bar_min_distance`` away (a field line seen along its length would reach
    the robot's feet)."""
    return not (dist > pc.bar_radial or near < pc.bar_min_distance)


def is_leg_bar(dist: float, near: float, foot_row: float, bottom: float, cell: int,
               pc: PostsTuning) -> bool:
    """A white segment that is a vertical bar standing on the floor but short of the field
    boundary (a robot's or a person's leg; ``is_post_bar`` takes the bars that reach it): it
    ``runs_away`` and its near end's image row ``foot_row`` lies inside the image, at least
    ``bar_touch`` cells above its lower edge ``bottom`` (px). A field line the robot stands on,
    seen along its length, runs out of the image's lower edge; one that starts ahead of the
    robot on the line through its feet is rare and is lost."""
    return runs_away(dist, near, pc) and bool(foot_row < bottom - pc.bar_touch * cell)


def is_post_bar(dist: float, near: float, ends_px: np.ndarray, top: np.ndarray, white: np.ndarray,
                fx: float, cell: int, pc: PostsTuning, diameter: float) -> bool:
    """A white segment that is a vertical bar on the floor rather than a field line: it
    ``runs_away`` from the robot, its upper end reaches the field boundary (within
    ``bar_touch`` cells), and it keeps a post's width up to there: a field line seen along its
    length looks the same but thins out with distance, a post (all of it as far away as its
    foot) does not. The width is the white share summed across the bar (times the cell size)
    over its upper half, against a post's ``diameter`` (m) at the foot's distance (at least
    ``bar_width_ratio`` of it; compiled: ``_bar_share``)."""
    if not runs_away(dist, near, pc):
        return False
    k = int(np.argmin(ends_px[:, 1]))
    up, foot = ends_px[k], ends_px[1 - k]
    col = int(np.clip((up[0] + 0.5) // cell, 0, len(top) - 1))
    if (up[1] + 0.5) / cell - top[col] > pc.bar_touch:
        return False
    width = float(_bar_share(np.ascontiguousarray(white, np.float32), float(foot[0]),
                             float(foot[1]), float(up[0]), float(up[1]), int(cell),
                             _BAR_STEPS)) * cell
    return width >= pc.bar_width_ratio * fx * diameter / near


# where is_post_bar measures the bar: shares of the way from its foot to its upper end
_BAR_STEPS = np.linspace(0.5, 0.9, 5)
_BAR_STEPS.setflags(write=False)


@njit(cache=True, nogil=True)
def _bar_share(white, fx, fy, ux, uy, cell, steps):
    """is_post_bar's white across a bar (float32 shares): at each point ``steps`` of the way
    from its foot (fx, fy) to its upper end (ux, uy) (image px), in the grid cell there
    (rounded half to even, clipped to the grid), the shares of that cell and two cells each
    side (clipped) summed (sum32); their median."""
    h, w = white.shape
    sums = np.empty(len(steps), np.float32)
    across = np.empty(5, np.float32)
    for i in range(len(steps)):
        t = steps[i]
        gx = ((fx * (1 - t) + ux * t) + 0.5) / cell - 0.5
        gy = ((fy * (1 - t) + uy * t) + 0.5) / cell - 0.5
        r = min(max(int(np.rint(gy)), 0), h - 1)
        c = int(np.rint(gx))
        for k in range(5):
            across[k] = white[r, min(max(c + k - 2, 0), w - 1)]
        sums[i] = sum32(across)
    return median(sums)
