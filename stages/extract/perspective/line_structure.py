"""The line structure graph (Schulz et al. 2011, sections 3.2, 3.3 and the key structure of 4.1).

All of it works on the subsampled white image (one cell per 8 x 8 pixels, values are the
share of white pixels in the cell), in grid coordinates (x = column, y = row, float for
subpixel positions):

- ``white_inside_boundary``: only the white cells inside the field boundary;
- ``low_pass``: a binomial low-pass so each line cross-section has one maximum;
- ``ranking_skeleton``: the ranking operator, c(x, y) = number of 8-neighbours with an equal
  or higher grey level; a non-zero pixel with c < 3 is on the skeleton (c = 0 peaks,
  c = 1, 2 ridges);
- ``place_nodes``: nodes first at peaks, then on ridge pixels at least two pixels apart;
- ``connect_nodes``: connections where the 3 x 3 regions of two nodes overlap or touch on the
  skeleton (``remove_triangles``, ``limit_degree``: no triangles, no degree above 4);
- ``stretch_lines``: end nodes moved to the last pixel of the skeleton;
- ``split_isolated_nodes``: degree-0 nodes split into two connected nodes to fill gaps;
- ``fill_gaps``: candidate connections scored by continuity, closure and simplicity (short,
  similar grey level along the gap as at the nodes), never above degree 4;
- ``key_structure``: the lines smoothed, nodes at low curvature removed, short lines ending in
  junctions eliminated (and small rings), close connected junctions merged; key nodes stay on
  the skeleton.
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np
from numba import njit

# the sum of a float64 array, a plain loop (numeric.sum64)
from ...common.numeric import sum64 as block_sum


class SkeletonTuning(NamedTuple):
    """The numbers of the skeleton and the fine graph (sections 3.2-3.3: ``skeleton_grid``,
    ``line_structure_graph``), in grid cells; tuned on the rendered KidSize and NAO frames and
    the HULKs NAO frames."""

    boundary_margin: int  # cells below the boundary left out
    min_white: float  # low-passed white share below which a cell is background
    max_gap: float  # cells, gap filling
    gap_max_angle: float  # rad between a line's direction and the gap
    gap_min_grey_ratio: float  # grey along the gap relative to the nodes'
    close_gap: float  # cells: two line ends this close join whatever their direction


SKELETON = SkeletonTuning(boundary_margin=1, min_white=0.04, max_gap=6.0,
                          gap_max_angle=math.radians(30.0), gap_min_grey_ratio=0.25,
                          close_gap=4.0)


class KeyTuning(NamedTuple):
    """The numbers of the key structure (section 4.1: ``key_structure``), in grid cells and
    radians; tuned on the rendered KidSize and NAO frames and the HULKs NAO frames."""

    min_spur_length: float  # cells: shorter lines ending in a junction are removed
    smooth_iterations: int
    corner_reach: float  # cells: arm length for the turning angle
    corner_min_turn: float  # rad: lower turning is low curvature
    # the same on the floor (used where the nodes project to the floor): an L turns by 90 deg
    # there, the centre circle by about 40 deg over 3 cells at 2 m
    corner_min_turn_floor: float
    corner_min_turn_image: float  # ... where the image turns this
    floor_angles: bool  # corners and L angles measured on the floor
    merge_distance: float  # cells: connected junctions closer than this merge
    max_ring: float  # cells: shorter rings hanging at a node are removed


KEY = KeyTuning(min_spur_length=2.5, smooth_iterations=2, corner_reach=3.0,
                corner_min_turn=math.radians(25.0), corner_min_turn_floor=math.radians(45.0),
                corner_min_turn_image=math.radians(10.0), floor_angles=True, merge_distance=3.0,
                max_ring=10.0)

# ---------------------------------------------------------------------------- 3.2 skeleton


def white_inside_boundary(white: np.ndarray, top: np.ndarray, margin: int = 1) -> np.ndarray:
    """White share per cell (H, W) float32, zero above the field boundary (``top`` = first
    field row per column) and in the ``margin`` rows just below it."""
    h, _ = white.shape
    rows = np.arange(h, dtype=np.float64)[:, None]
    inside = rows >= np.ceil(np.asarray(top, np.float64))[None, :] + margin
    return np.where(inside, white.astype(np.float32), np.float32(0.0))


def low_pass(image: np.ndarray) -> np.ndarray:
    """3 x 3 binomial low-pass, so that each line cross-section has a single maximum."""
    k = np.array([0.25, 0.5, 0.25], np.float32)
    return cv2.sepFilter2D(image.astype(np.float32), -1, k, k, borderType=cv2.BORDER_CONSTANT)


def ranking_keys(image: np.ndarray) -> np.ndarray:
    """Grey levels as exactly comparable keys (float64 holding integers): the level quantised
    to 1/65536, ties broken by the pixel's raster index, so that a line two cells wide with
    equal values still has one maximum per cross-section."""
    h, w = image.shape
    q = np.round(image.astype(np.float64) * 65536.0)
    return q * (h * w) + np.arange(h * w, dtype=np.float64).reshape(h, w)


def ranking_count(image: np.ndarray, key: np.ndarray | None = None) -> np.ndarray:
    """c(x, y): the number of 8-neighbours with an equal or higher grey level (int8), ties
    broken as in ranking_keys (``key``: the image's ranking_keys, if already computed)."""
    key = ranking_keys(image) if key is None else key
    c = np.empty(key.shape, np.int8)
    _rank_counts(np.ascontiguousarray(key, np.float64), c)
    return c


@njit(cache=True, nogil=True)
def _rank_counts(key, c):
    """ranking_count compiled: per pixel, the 8-neighbours whose key is >= its own (outside
    the image a key of -1)."""
    h, w = key.shape
    for r in range(h):
        for x in range(w):
            k = key[r, x]
            n = 0
            for dy in range(-1, 2):
                for dx in range(-1, 2):
                    if dy == 0 and dx == 0:
                        continue
                    rr, xx = r + dy, x + dx
                    other = key[rr, xx] if 0 <= rr < h and 0 <= xx < w else -1.0
                    if other >= k:
                        n += 1
            c[r, x] = n


def ranking_skeleton(image: np.ndarray, min_value: float, key: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """The ranking-operator skeleton: pixels above ``min_value`` (grey level zero is background)
    with c(x, y) < 3 (``key``: the image's ranking_keys, if already computed). Returns
    (skeleton mask, c)."""
    c = ranking_count(image, key)
    return (image > min_value) & (c < 3), c


def skeleton_grid(white: np.ndarray, top: np.ndarray, margin: int, min_value: float,
                  exact_shares: bool) -> tuple[np.ndarray, np.ndarray, tuple]:
    """white_inside_boundary, low_pass, ranking_keys and ranking_skeleton of a white-share
    image in one compiled pass (``_skeleton_grid``) where ``exact_shares``: its values are
    multiples of a power of two no finer than 2^-6 (counts over a power-of-two cell area),
    so that the low-pass's quarter and half weights sum them exactly in float32 in any order
    and the grid is cv2.sepFilter2D's to the bit; else by those functions. Returns (inside,
    low-passed, (ranking keys, skeleton, ranking count))."""
    if not exact_shares:
        inside = white_inside_boundary(white, top, margin)
        lp = low_pass(inside)
        key = ranking_keys(lp)
        skeleton, c = ranking_skeleton(lp, min_value, key)
        return inside, lp, (key, skeleton, c)
    h, w = white.shape
    inside = np.empty((h, w), np.float32)
    lp = np.empty((h, w), np.float32)
    key = np.empty((h, w))
    skeleton = np.empty((h, w), np.bool_)
    c = np.empty((h, w), np.int8)
    _skeleton_grid(np.ascontiguousarray(white, np.float32), np.asarray(top, np.float64),
                   float(margin), np.float32(min_value), inside, lp, key, skeleton, c)
    return inside, lp, (key, skeleton, c)


@njit(cache=True, nogil=True)
def _skeleton_grid(white, top, margin, min_value, inside, lp, key, skeleton, c):
    """skeleton_grid's compiled pass (see there): inside the boundary (rows from ceil(top) +
    margin), the 3 x 3 binomial low-pass (zero beyond the grid), its ranking keys, the
    ranking count (_rank_counts) and the skeleton (low-passed above min_value, count < 3)."""
    h, w = white.shape
    for y in range(h):
        for x in range(w):
            inside[y, x] = white[y, x] if y >= np.ceil(top[x]) + margin else np.float32(0.0)
    quarter, half = np.float32(0.25), np.float32(0.5)
    rows = np.empty((h, w), np.float32)
    for y in range(h):
        for x in range(w):
            left = inside[y, x - 1] if x > 0 else np.float32(0.0)
            right = inside[y, x + 1] if x < w - 1 else np.float32(0.0)
            rows[y, x] = quarter * left + half * inside[y, x] + quarter * right
    for y in range(h):
        for x in range(w):
            up = rows[y - 1, x] if y > 0 else np.float32(0.0)
            down = rows[y + 1, x] if y < h - 1 else np.float32(0.0)
            lp[y, x] = quarter * up + half * rows[y, x] + quarter * down
            key[y, x] = np.rint(np.float64(lp[y, x]) * 65536.0) * (h * w) + (y * w + x)
    _rank_counts(key, c)
    for y in range(h):
        for x in range(w):
            skeleton[y, x] = lp[y, x] > min_value and c[y, x] < 3


# ---------------------------------------------------------------------------- 3.3 nodes


@dataclass
class LineGraph:
    """Nodes on the skeleton and their connections. ``pix`` is the skeleton pixel (x, y) a node
    sits on, ``pos`` its subpixel position, ``value`` the low-passed grey level there."""

    pix: np.ndarray  # (N, 2) int
    pos: np.ndarray  # (N, 2) float
    value: np.ndarray  # (N,) float
    # changed in place only where the flat lists are dropped (connect, disconnect, add_node)
    adj: list[set] = field(default_factory=list)
    # the connections as the kernels read them (neighbour_lists), while they hold
    lists: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False,
                                                         compare=False)

    def __len__(self):
        return len(self.pix)

    def degree(self) -> np.ndarray:
        return np.array([len(a) for a in self.adj], dtype=int)

    def edges(self) -> np.ndarray:
        e = [(i, j) for i, a in enumerate(self.adj) for j in a if i < j]
        return np.array(e, dtype=int).reshape(-1, 2)

    def neighbour_lists(self) -> tuple[np.ndarray, np.ndarray]:
        """The connections as flat arrays for the kernels (``(start, nbr)``: node i's
        neighbours are ``nbr[start[i]:start[i + 1]]``, in no particular order; ``flat_lists``
        of the sets), made once while the connections stay as they are (the kernels only read
        them)."""
        if self.lists is None:
            nbr, start = flat_lists(self.adj)
            self.lists = start, nbr
        return self.lists

    def connect(self, i: int, j: int):
        if i != j:
            self.adj[i].add(j)
            self.adj[j].add(i)
            self.lists = None

    def disconnect(self, i: int, j: int):
        self.adj[i].discard(j)
        self.adj[j].discard(i)
        self.lists = None

    def add_node(self, pix, pos, value) -> int:
        self.pix = np.vstack([self.pix, np.asarray(pix, int)[None]])
        self.pos = np.vstack([self.pos, np.asarray(pos, float)[None]])
        self.value = np.append(self.value, value)
        self.adj.append(set())
        self.lists = None
        return len(self.pix) - 1

    def copy(self) -> LineGraph:
        return LineGraph(self.pix.copy(), self.pos.copy(), self.value.copy(),
                         [set(a) for a in self.adj], self.lists)


def place_nodes(image: np.ndarray, skeleton: np.ndarray, c: np.ndarray,
                key: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Nodes first at peaks (c = 0), then at ridge pixels (c = 1, 2) at least two pixels apart
    (no two nodes 8-neighbours). Done in parallel rounds: in each round every available
    skeleton pixel whose priority (peaks first, then grey level) is the highest in its 3 x 3
    neighbourhood becomes a node and blocks its neighbours. The result is maximal, so every
    skeleton pixel touches a node.

    Returns node pixels (N, 2) int (x, y), ordered by priority, and the node regions: an int32
    image with node index + 1 on every skeleton pixel (a node's pixel and the skeleton pixels
    of its 3 x 3 region assigned to it, 4-neighbours first), 0 elsewhere. ``key``: the
    image's ranking_keys, if already computed."""
    key = ranking_keys(image) if key is None else key
    # the parallel rounds pick the same pixels as one greedy pass in priority order (every
    # priority differs: a pixel that is the highest available one in its neighbourhood is
    # taken in both, and so, round after round, is every pixel the greedy pass takes)
    skeleton = np.ascontiguousarray(skeleton, np.bool_)
    ys, xs = _nodes_by_priority(np.ascontiguousarray(key, np.float64),
                                np.ascontiguousarray(c, np.int8), skeleton)
    regions = _node_regions(skeleton, ys, xs)
    pix = np.empty((len(xs), 2), int)
    pix[:, 0], pix[:, 1] = xs, ys
    return pix, regions


@njit(cache=True, nogil=True)
def _nodes_by_priority(key, c, skeleton):
    """place_nodes' greedy pass, compiled: the skeleton pixels (row-major, as np.nonzero)
    sorted by falling priority (the ranking key, peaks (c = 0) first: 2^45 added), stably,
    and taken while none of their 8-neighbours is (_greedy_nodes). Returns the nodes' rows
    and columns in that order."""
    h, w = skeleton.shape
    n = 0
    for y in range(h):
        for x in range(w):
            if skeleton[y, x]:
                n += 1
    sy = np.empty(n, np.int64)
    sx = np.empty(n, np.int64)
    neg = np.empty(n)
    k = 0
    for y in range(h):
        for x in range(w):
            if skeleton[y, x]:
                sy[k], sx[k] = y, x
                neg[k] = -(key[y, x] + (2.0 ** 45 if c[y, x] == 0 else 0.0))
                k += 1
    order = np.argsort(neg, kind="mergesort")
    oy, ox = sy[order], sx[order]
    taken = _greedy_nodes(oy, ox, h, w)
    return oy[taken].copy(), ox[taken].copy()


@njit(cache=True, nogil=True)
def _node_regions(skeleton, ys, xs):
    """place_nodes' region image: node k + 1 at its pixel (ys[k], xs[k]); every other
    skeleton pixel takes the largest node label among its 4-neighbours, else among its
    8-neighbours (a grey dilation of the labels, first with the cross, then the square)."""
    h, w = skeleton.shape
    labels = np.zeros((h, w), np.int32)
    for k in range(len(ys)):
        labels[ys[k], xs[k]] = k + 1
    out = labels.copy()
    for r in range(h):
        for c in range(w):
            if not skeleton[r, c] or labels[r, c] != 0:
                continue
            m = 0
            for dr, dc in ((-1, 0), (0, -1), (0, 1), (1, 0)):
                if 0 <= r + dr < h and 0 <= c + dc < w:
                    m = max(m, labels[r + dr, c + dc])
            if m == 0:
                for dr in range(-1, 2):
                    for dc in range(-1, 2):
                        if 0 <= r + dr < h and 0 <= c + dc < w:
                            m = max(m, labels[r + dr, c + dc])
            out[r, c] = m
    return out


@njit(cache=True, nogil=True)
def _greedy_nodes(ys, xs, h, w):
    """Pixels (in the order given) taken while none of their 8-neighbours is taken."""
    blocked = np.zeros((h + 2, w + 2), np.bool_)
    taken = np.zeros(len(ys), np.bool_)
    for k in range(len(ys)):
        y, x = ys[k] + 1, xs[k] + 1
        if blocked[y, x]:
            continue
        taken[k] = True
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                blocked[y + dy, x + dx] = True
    return taken


def subpixel_positions(image: np.ndarray, pix: np.ndarray) -> np.ndarray:
    """Grey-level weighted centroid of each node's 3 x 3 window (x, y) (compiled:
    ``_centroids``)."""
    if len(pix) == 0:
        return np.zeros((0, 2))
    return _centroids(np.ascontiguousarray(image), np.ascontiguousarray(pix, np.int64))


@njit(cache=True, nogil=True)
def _centroids(image, pix):
    """subpixel_positions compiled: per node pixel, its 3 x 3 window's grey levels (0 outside
    the image) as weights, the weighted mean offset (sums: block_sum)."""
    h, w = image.shape
    out = np.empty((pix.shape[0], 2))
    wts = np.empty(9)
    ax = np.empty(9)
    ay = np.empty(9)
    for i in range(pix.shape[0]):
        k = 0
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                y, x = pix[i, 1] + dy, pix[i, 0] + dx
                v = np.float64(image[y, x]) if 0 <= y < h and 0 <= x < w else 0.0
                wts[k] = v
                ax[k] = v * dx
                ay[k] = v * dy
                k += 1
        wsum = block_sum(wts)
        if wsum <= 0:
            wsum = 1.0
        out[i, 0] = np.float64(pix[i, 0]) + block_sum(ax) / wsum
        out[i, 1] = np.float64(pix[i, 1]) + block_sum(ay) / wsum
    return out


def connect_nodes(regions: np.ndarray, n: int) -> list[set]:
    """Connections where the 3 x 3 regions of two nodes overlap or touch on the skeleton: two
    nodes are connected when skeleton pixels of their regions are 8-neighbours. Each node's
    set is filled in ascending order of its neighbours (``_region_links``), the order in
    which adding the connections one by one, by (lower, higher) node, fills it."""
    return _adjacency(*node_links(regions, n))


def node_links(regions: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """connect_nodes' connections as the flat lists of LineGraph.neighbour_lists (each
    node's neighbours ascending; compiled: ``_region_links``)."""
    return _region_links(np.ascontiguousarray(regions, np.int32), int(n))


def _adjacency(start: np.ndarray, nbr: np.ndarray) -> list[set]:
    """Flat neighbour lists as LineGraph's sets, each filled in the lists' order."""
    b, nb = start.tolist(), nbr.tolist()
    return [set(nb[b[k]:b[k + 1]]) for k in range(len(b) - 1)]


@njit(cache=True, nogil=True)
def _region_links(regions, n):
    """connect_nodes compiled: the pairs of different node labels (``regions`` = node + 1)
    on 8-neighbouring pixels, as each node's neighbours in ascending order (``nbrs[start[i]:
    start[i + 1]]``)."""
    h, w = regions.shape
    linked = np.zeros((n, n), np.bool_)
    for r in range(h):
        for c in range(w):
            a = regions[r, c]
            if a <= 0:
                continue
            for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
                rr, cc = r + dr, c + dc
                if rr < h and 0 <= cc < w:
                    b = regions[rr, cc]
                    if b > 0 and b != a:
                        linked[a - 1, b - 1] = True
                        linked[b - 1, a - 1] = True
    start = np.zeros(n + 1, np.int64)
    for i in range(n):
        start[i + 1] = start[i] + linked[i].sum()
    nbrs = np.empty(start[n], np.int64)
    k = 0
    for i in range(n):
        for j in range(n):
            if linked[i, j]:
                nbrs[k] = j
                k += 1
    return start, nbrs


def remove_triangles(graph: LineGraph):
    """Drop the longest side of each triangle of connections (in place). The triangles are
    found by a compiled walk (``_triangle_cuts``: nodes in order, each one's higher neighbours
    and their common higher neighbours as the sets held them then); the sides it cuts are
    then taken out of the sets in the same order."""
    n = len(graph)
    if n < 3:
        return
    start, nbr = graph.neighbour_lists()
    kept = np.empty_like(start), np.empty_like(nbr)
    cuts = _triangle_cuts(start, nbr, np.ascontiguousarray(graph.pos, np.float64), *kept)
    for a, b in cuts.tolist():
        graph.disconnect(a, b)
    graph.lists = kept[0], kept[1][:kept[0][-1]]


@njit(cache=True, nogil=True)
def _triangle_cuts(start, nbr, pos, kept_start, kept_nbr):
    """remove_triangles' walk: for i in order (of degree >= 2 then), for each neighbour j > i
    (sorted, as connected when i's turn came), for each common neighbour k > j (sorted, as
    connected when j's turn came), the longest side of (i, j), (j, k), (i, k) (np.hypot,
    the first of equal ones) is cut. Returns the cuts (a, b) in order; the connections left
    go into ``kept_start``, ``kept_nbr`` (LineGraph.neighbour_lists' form)."""
    n = len(start) - 1
    linked = np.zeros((n, n), np.bool_)
    deg = np.zeros(n, np.int64)
    for i in range(n):
        for q in range(start[i], start[i + 1]):
            linked[i, nbr[q]] = True
        deg[i] = start[i + 1] - start[i]
    cuts = np.empty((len(nbr) + 1, 2), np.int64)
    m = 0
    js = np.empty(n, np.int64)
    ks = np.empty(n, np.int64)
    lens = np.empty(3)
    for i in range(n):
        if deg[i] < 2:
            continue
        nj = 0
        for j in range(i + 1, n):  # ascending: sorted(adj[i]), those above i
            if linked[i, j]:
                js[nj] = j
                nj += 1
        for a in range(nj):
            j = js[a]
            nk = 0
            for k in range(j + 1, n):
                if linked[i, k] and linked[j, k]:
                    ks[nk] = k
                    nk += 1
            for b in range(nk):
                k = ks[b]
                lens[0] = np.hypot(pos[i, 0] - pos[j, 0], pos[i, 1] - pos[j, 1])
                lens[1] = np.hypot(pos[j, 0] - pos[k, 0], pos[j, 1] - pos[k, 1])
                lens[2] = np.hypot(pos[i, 0] - pos[k, 0], pos[i, 1] - pos[k, 1])
                w = 0
                for t in range(1, 3):
                    if lens[t] > lens[w]:
                        w = t
                p, q = (i, j) if w == 0 else ((j, k) if w == 1 else (i, k))
                if linked[p, q]:
                    linked[p, q] = False
                    linked[q, p] = False
                    deg[p] -= 1
                    deg[q] -= 1
                if m == len(cuts):
                    more = np.empty((2 * m, 2), np.int64)
                    more[:m] = cuts
                    cuts = more
                cuts[m, 0], cuts[m, 1] = p, q
                m += 1
    k = 0
    for i in range(n):
        kept_start[i] = k
        for j in range(n):
            if linked[i, j]:
                kept_nbr[k] = j
                k += 1
    kept_start[n] = k
    return cuts[:m].copy()


def limit_degree(graph: LineGraph, max_degree: int = 4):
    """No crossing of degree above ``max_degree``: a node with more connections loses its
    longest ones (in place)."""
    start, _ = graph.neighbour_lists()
    for i in np.nonzero(start[1:] - start[:-1] > max_degree)[0].tolist():  # (degrees only fall)
        while len(graph.adj[i]) > max_degree:
            far = max(graph.adj[i], key=lambda j: np.hypot(*(graph.pos[i] - graph.pos[j])))
            graph.disconnect(i, far)


def stretch_lines(graph: LineGraph, regions: np.ndarray):
    """Move each end node (degree 1) to the last pixel of the skeleton: the pixel of its
    region farthest from its neighbour (the first in row-major order of equally far ones; in
    place)."""
    start, nbr = graph.neighbour_lists()
    ends = np.nonzero(start[1:] - start[:-1] == 1)[0]
    if len(ends) == 0:
        return
    other = np.full(len(graph), -1, np.int64)
    other[ends] = nbr[start[ends]]
    _farthest_region_pixels(np.ascontiguousarray(regions, np.int32), other,
                            np.ascontiguousarray(graph.pos, np.float64), graph.pix)


@njit(cache=True, nogil=True)
def _farthest_region_pixels(regions, other, pos, pix):
    """stretch_lines compiled: for each node i with ``other[i]`` >= 0 (its neighbour), the
    pixel of its region (``regions`` = node index + 1) farthest from the neighbour's position
    into ``pix[i]``."""
    n = len(other)
    best = np.full(n, -1.0)
    bx = np.zeros(n, np.int64)
    by = np.zeros(n, np.int64)
    for r in range(regions.shape[0]):
        for c in range(regions.shape[1]):
            i = regions[r, c] - 1
            if i < 0 or other[i] < 0:
                continue
            d = math.hypot(c - pos[other[i], 0], r - pos[other[i], 1])
            if d > best[i]:
                best[i], bx[i], by[i] = d, c, r
    for i in range(n):
        if best[i] >= 0:
            pix[i, 0], pix[i, 1] = bx[i], by[i]


def split_isolated_nodes(graph: LineGraph, regions: np.ndarray, image: np.ndarray):
    """Split each degree-0 node whose region holds at least two skeleton pixels into two
    connected nodes at the region's two farthest pixels, so that short isolated pieces can
    bridge gaps (in place; the graph's flat lists are extended by them, ``_linked_lists``)."""
    start, nbr = graph.neighbour_lists()
    lonely = np.nonzero(start[1:] - start[:-1] == 0)[0]
    if len(lonely) == 0:
        return
    # each region's pixels in row-major order, as a mask per region would pick them, and per
    # lonely node the region's two farthest pixels (compiled: _region_pixels, _farthest_pairs)
    xs, ys, region_start = _region_pixels(np.ascontiguousarray(regions, np.int32),
                                          max(len(graph), int(regions.max(initial=0))))
    far = _farthest_pairs(xs, ys, region_start, lonely.astype(np.int64))
    split = far[:, 0] >= 0
    if not split.any():
        return
    ids, ends = lonely[split], far[split]
    graph.pix[ids] = ends[:, 0:2]
    new = ends[:, 2:4].astype(graph.pix.dtype)
    first = len(graph)
    graph.pix = np.concatenate([graph.pix, new])
    graph.pos = np.concatenate([graph.pos, new.astype(float)])
    graph.value = np.append(graph.value, image[new[:, 1], new[:, 0]])
    graph.adj.extend(set() for _ in range(len(new)))
    for k, i in enumerate(ids.tolist()):
        graph.connect(i, first + k)
    pairs = np.empty((len(new), 2), np.int64)
    pairs[:, 0], pairs[:, 1] = ids, np.arange(first, first + len(new))
    lists = np.empty(len(graph) + 1, np.int64), np.empty(len(nbr) + 2 * len(new), np.int64)
    _linked_lists(start, nbr, pairs, *lists)
    graph.lists = lists


@njit(cache=True, nogil=True)
def _region_pixels(regions, n):
    """The pixels (x, y) of each node's region (``regions`` = node + 1), node by node, each
    region's in row-major order: node i's are ``[start[i]:start[i + 1]]`` (a counting sort
    of the labelled pixels)."""
    h, w = regions.shape
    start = np.zeros(n + 1, np.int64)
    for r in range(h):
        for c in range(w):
            if regions[r, c] > 0:
                start[regions[r, c]] += 1
    for i in range(n):
        start[i + 1] += start[i]
    fill = start[:n].copy()
    xs = np.empty(start[n], np.int64)
    ys = np.empty(start[n], np.int64)
    for r in range(h):
        for c in range(w):
            lab = regions[r, c] - 1
            if lab >= 0:
                xs[fill[lab]], ys[fill[lab]] = c, r
                fill[lab] += 1
    return xs, ys, start


@njit(cache=True, nogil=True)
def _farthest_pairs(xs, ys, start, lonely):
    """For each lonely node i, the pixels (xa, ya, xb, yb) of its region (``xs``, ``ys``
    [start[i]:start[i + 1]], row-major) farthest apart (the first such pair in row-major order
    of the distance matrix, as np.argmax takes it), or -1 where the region holds one pixel."""
    out = np.full((len(lonely), 4), -1, np.int64)
    for k in range(len(lonely)):
        i = lonely[k]
        s, e = start[i], start[i + 1]
        if e - s < 2:
            continue
        best, ba, bb = -1.0, s, s
        for a in range(s, e):
            for b in range(s, e):
                d = math.hypot(float(xs[a] - xs[b]), float(ys[a] - ys[b]))
                if d > best:
                    best, ba, bb = d, a, b
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = xs[ba], ys[ba], xs[bb], ys[bb]
    return out


def fill_gaps(graph: LineGraph, image: np.ndarray, max_gap: float, min_cos: float,
              min_grey_ratio: float, close_gap: float, max_degree: int = 4, samples: int = 8):
    """Candidate connections from end and isolated nodes to nodes within ``max_gap`` cells,
    evaluated by continuity (the gap continues the line's direction within acos(min_cos); a
    gap of at most ``close_gap`` cells between two line ends closes without it, as at a
    corner whose tip the skeleton misses), closure (short gaps first) and simplicity (the
    grey level along the gap is at least ``min_grey_ratio`` of the nodes'; no node above degree
    ``max_degree``; no connection to a node already three steps away). Accepted greedily by
    score (in place; the graph's flat lists are extended by them, ``_linked_lists``)."""
    if len(graph) < 2:
        return
    start, nbr = graph.neighbour_lists()
    deg = start[1:] - start[:-1]
    loose = np.nonzero(deg <= 1)[0]
    if len(loose) == 0:
        return
    pos = np.ascontiguousarray(graph.pos, np.float64)
    # the candidates (continuity, closure) by one compiled pass over the loose nodes
    score, ci, cj = _gap_candidates(pos, start, nbr, deg, loose, float(max_gap), float(min_cos),
                                    float(close_gap))
    if len(score) == 0:
        return
    # simplicity: grey level along all candidate gaps, sampled in one compiled pass as
    # cv2.remap samples (_gap_grey)
    grey = np.empty(len(score), np.float32)
    _gap_grey(pos, ci, cj, _gap_steps(samples)[0, :, 0], np.asarray(image, np.float32), grey)
    # the grey ratios, the scores' order and the greedy choice, compiled (_gap_choice)
    value = np.ascontiguousarray(graph.value)
    accepted = np.empty((len(score), 2), np.int64)
    n = _gap_choice(score, ci, cj, np.ascontiguousarray(grey), value, value.dtype.type(1e-9),
                    float(min_grey_ratio), start, nbr, int(max_degree), accepted)
    for i, j in accepted[:n].tolist():
        graph.connect(i, j)
    if n:
        lists = np.empty_like(start), np.empty(len(nbr) + 2 * n, np.int64)
        _linked_lists(start, nbr, accepted[:n], *lists)
        graph.lists = lists


@njit(cache=True, nogil=True)
def _linked_lists(start, nbr, pairs, new_start, new_nbr):
    """Flat neighbour lists (LineGraph.neighbour_lists' form) with the connections ``pairs``
    (i, j) added both ways, into ``new_start``, ``new_nbr`` (each node's old neighbours,
    then its new ones; nodes beyond the old lists, up to len(new_start) - 1, had none)."""
    n_old = len(start) - 1
    n = len(new_start) - 1
    extra = np.zeros(n, np.int64)
    for p in range(pairs.shape[0]):
        extra[pairs[p, 0]] += 1
        extra[pairs[p, 1]] += 1
    new_start[0] = 0
    for i in range(n):
        old = start[i + 1] - start[i] if i < n_old else 0
        new_start[i + 1] = new_start[i] + old + extra[i]
    fill = np.empty(n, np.int64)
    for i in range(n):
        k = new_start[i]
        if i < n_old:
            for q in range(start[i], start[i + 1]):
                new_nbr[k] = nbr[q]
                k += 1
        fill[i] = k
    for p in range(pairs.shape[0]):
        i, j = pairs[p, 0], pairs[p, 1]
        new_nbr[fill[i]] = j
        fill[i] += 1
        new_nbr[fill[j]] = i
        fill[j] += 1


@njit(cache=True, nogil=True)
def _gap_choice(score, ci, cj, grey, value, eps, min_ratio, start, nbr, max_degree, accepted):
    """fill_gaps' choice, compiled: per candidate (score, i, j) its grey ratio (the gap's
    least grey over the mean of the nodes' values, in their float type, as numpy had it),
    those of at least ``min_ratio`` ordered by score plus ratio (falling, stably, as Python's
    sort), and accepted in turn unless already connected, i has two connections or j
    ``max_degree``. The accepted connections (i, j) go into ``accepted`` in order; returns
    their number."""
    m = len(score)
    total = np.empty(m)
    keep = np.empty(m, np.int64)
    k = 0
    for q in range(m):
        ref = value.dtype.type(0.5) * (value[ci[q]] + value[cj[q]])
        r = grey[q] / max(ref, eps) if ref > 0 else grey.dtype.type(0.0)
        if np.float64(r) >= min_ratio:
            total[k] = score[q] + np.float64(r)
            keep[k] = q
            k += 1
    order = np.argsort(-total[:k], kind="mergesort")
    deg = np.empty(len(start) - 1, np.int64)
    for i in range(len(start) - 1):
        deg[i] = start[i + 1] - start[i]
    n = 0
    for o in order:
        q = keep[o]
        i, j = ci[q], cj[q]
        linked = False
        for p in range(start[i], start[i + 1]):
            if nbr[p] == j:
                linked = True
        for a in range(n):
            if (accepted[a, 0] == i and accepted[a, 1] == j) or (accepted[a, 0] == j
                                                                 and accepted[a, 1] == i):
                linked = True
        if linked or deg[i] >= 2 or deg[j] >= max_degree:
            continue
        accepted[n, 0], accepted[n, 1] = i, j
        n += 1
        deg[i] += 1
        deg[j] += 1
    return n


@njit(cache=True, nogil=True)
def _gap_grey(pos, ci, cj, t, image, out):
    """fill_gaps' grey level along each candidate gap ci[k] -> cj[k] (grid positions ``pos``):
    the least of the image at the points (1 - t) p + t q, each sampled bilinearly, 0
    outside the image (bilinear_at)."""
    for k in range(ci.shape[0]):
        a, b = ci[k], cj[k]
        low = np.inf
        for s in range(t.shape[0]):
            x = pos[a, 0] * (1 - t[s]) + pos[b, 0] * t[s]
            y = pos[a, 1] * (1 - t[s]) + pos[b, 1] * t[s]
            v = bilinear_at(image, x, y, 0.0)
            if v < low or s == 0:
                low = v
        out[k] = low


@njit(cache=True, nogil=True)
def bilinear_at(image, x, y, border):
    """A 2-D ``image`` at the point (x = column, y = row), interpolated bilinearly in float64
    (along the row, then across), pixels outside the image ``border``: what cv2.remap with
    INTER_LINEAR and BORDER_CONSTANT computes, in plain arithmetic at full precision (OpenCV
    rounds the offsets to 1/32 px in 4.x, not in 5.x)."""
    h, w = image.shape
    fx, fy = math.floor(x), math.floor(y)
    ix, iy = int(fx), int(fy)
    ax, ay = x - fx, y - fy
    in0, in1 = 0 <= iy < h, 0 <= iy + 1 < h
    left, right = 0 <= ix < w, 0 <= ix + 1 < w
    p00 = np.float64(image[iy, ix]) if in0 and left else border
    p01 = np.float64(image[iy, ix + 1]) if in0 and right else border
    p10 = np.float64(image[iy + 1, ix]) if in1 and left else border
    p11 = np.float64(image[iy + 1, ix + 1]) if in1 and right else border
    r0 = p00 + (p01 - p00) * ax
    r1 = p10 + (p11 - p10) * ax
    return r0 + (r1 - r0) * ay


@functools.lru_cache(maxsize=4)
def _gap_steps(samples: int) -> np.ndarray:
    """np.linspace(0, 1, samples) shaped (1, samples, 1), made once (read-only)."""
    t = np.linspace(0.0, 1.0, samples)[None, :, None]
    t.setflags(write=False)
    return t


@njit(cache=True, nogil=True)
def _outward(pos, start, nbr, i):
    """The unit direction (dx, dy) in which the line ends at end node i (from a node up to
    three steps back along its line towards i); (nan, nan) for a node without a single
    neighbour."""
    if start[i + 1] - start[i] != 1:
        return np.nan, np.nan
    prev, cur = i, nbr[start[i]]
    for _ in range(2):  # reach 3: up to two more steps back along the line
        count, nxt = 0, -1
        for k in range(start[cur], start[cur + 1]):
            if nbr[k] != prev:
                count += 1
                nxt = nbr[k]
        if count != 1:
            break
        prev, cur = cur, nxt
    dx = pos[i, 0] - pos[cur, 0]
    dy = pos[i, 1] - pos[cur, 1]
    n = math.hypot(dx, dy)
    if n > 0:
        return dx / n, dy / n
    return np.nan, np.nan


@njit(cache=True, nogil=True)
def _gap_candidates(pos, start, nbr, deg, loose, max_gap, min_cos, close_gap):
    """fill_gaps' candidate connections (score, i, j), in its order: loose node by loose node,
    the nodes within ``max_gap`` by index (math.hypot, numpy's np.hypot to the bit), those
    not within three steps of i, continuing the lines' outward directions (or closing a short
    gap between two line ends)."""
    n = pos.shape[0]
    d_row = np.empty(n)
    ox = np.full(n, np.nan)
    oy = np.full(n, np.nan)
    for a in range(len(loose)):
        ox[loose[a]], oy[loose[a]] = _outward(pos, start, nbr, loose[a])
    cap = 16
    score = np.empty(cap)
    ci = np.empty(cap, np.int64)
    cj = np.empty(cap, np.int64)
    m = 0
    steps = np.zeros(n, np.bool_)
    frontier = np.empty(n, np.int64)
    nxt = np.empty(n, np.int64)
    seen = np.empty(n, np.int64)
    for a in range(len(loose)):
        i = loose[a]
        any_near = False
        for j in range(n):
            d_row[j] = math.hypot(pos[i, 0] - pos[j, 0], pos[i, 1] - pos[j, 1])
            if d_row[j] <= max_gap and d_row[j] > 0:
                any_near = True
        if not any_near:
            continue
        # the nodes within three steps of i
        steps[i] = True
        seen[0] = i
        n_seen = 1
        frontier[0] = i
        nf = 1
        for _ in range(3):
            nn = 0
            for f in range(nf):
                c = frontier[f]
                for k in range(start[c], start[c + 1]):
                    q = nbr[k]
                    if not steps[q]:
                        steps[q] = True
                        seen[n_seen] = q
                        n_seen += 1
                        nxt[nn] = q
                        nn += 1
            frontier[:nn] = nxt[:nn]
            nf = nn
        has_i = not np.isnan(ox[i])
        xi, yi = pos[i, 0], pos[i, 1]
        for j in range(n):
            dj = d_row[j]
            if not (dj <= max_gap and dj > 0) or steps[j]:
                continue
            gx, gy = (pos[j, 0] - xi) / dj, (pos[j, 1] - yi) / dj
            has_j = deg[j] <= 1 and not np.isnan(ox[j])
            closing = dj <= close_gap and deg[j] == 1 and deg[i] == 1
            s = 0.0
            if has_i:
                c_i = ox[i] * gx + oy[i] * gy
                if c_i < min_cos and not closing:
                    continue
                s += c_i
            if has_j:
                c_j = -ox[j] * gx + -oy[j] * gy
                if c_j < min_cos and not closing:
                    continue
                s += c_j
            if not has_i and not has_j and deg[j] > 0:
                continue  # an isolated node joins only where a line's direction leads
            if m == cap:
                cap *= 2
                score2 = np.empty(cap)
                ci2 = np.empty(cap, np.int64)
                cj2 = np.empty(cap, np.int64)
                score2[:m], ci2[:m], cj2[:m] = score[:m], ci[:m], cj[:m]
                score, ci, cj = score2, ci2, cj2
            score[m] = s - dj / max_gap
            ci[m] = i
            cj[m] = j
            m += 1
        for k in range(n_seen):
            steps[seen[k]] = False
    return score[:m].copy(), ci[:m].copy(), cj[:m].copy()


def line_structure_graph(white_lp: np.ndarray, tuning: SkeletonTuning = SKELETON, ranked=None
                         ) -> tuple[LineGraph, np.ndarray, np.ndarray]:
    """Section 3.2-3.3 on the low-passed white image: skeleton, nodes, connections, stretching,
    splitting of isolated nodes and gap filling. ``ranked``: the image's (ranking keys,
    skeleton, ranking count), if already computed (skeleton_grid). Returns (graph, skeleton,
    regions)."""
    if ranked is None:
        key = ranking_keys(white_lp)
        skeleton, c = ranking_skeleton(white_lp, tuning.min_white, key)
    else:
        key, skeleton, c = ranked
    pix, regions = place_nodes(white_lp, skeleton, c, key)
    links = node_links(regions, len(pix))
    graph = LineGraph(pix, pix.astype(np.float64), white_lp[pix[:, 1], pix[:, 0]]
                      if len(pix) else np.zeros(0), _adjacency(*links), links)
    if len(pix) == 0:
        return graph, skeleton, regions
    graph.pos = subpixel_positions(white_lp, graph.pix)
    remove_triangles(graph)
    limit_degree(graph, 4)
    stretch_lines(graph, regions)
    split_isolated_nodes(graph, regions, white_lp)
    graph.pos = subpixel_positions(white_lp, graph.pix)
    fill_gaps(graph, white_lp, tuning.max_gap, math.cos(tuning.gap_max_angle),
              tuning.gap_min_grey_ratio, tuning.close_gap)
    return graph, skeleton, regions


# ---------------------------------------------------------------------------- 4.1 key structure


@dataclass
class KeyStructure:
    """The key node structure: key nodes (fine node index, position) and key edges, each the
    chain of fine nodes it replaces (from its first to its second key node)."""

    node: list[int]
    pos: np.ndarray  # (K, 2) grid coordinates
    edges: list[tuple[int, int, list[int]]]

    def degree(self) -> np.ndarray:
        ends = [k for a, b, _ in self.edges for k in (a, b)]
        return np.bincount(np.array(ends, np.int64), minlength=len(self.node))

    def incident(self, k: int) -> list[list[int]]:
        """The fine chains leaving key node k, each starting at k."""
        out = []
        for a, b, chain in self.edges:
            if a == k:
                out.append(chain)
            if b == k:
                out.append(chain[::-1])
        return out

    def incidence(self) -> list[list[list[int]]]:
        """``incident`` of every key node, by one pass over the edges."""
        out: list[list[list[int]]] = [[] for _ in self.node]
        for a, b, chain in self.edges:
            out[a].append(chain)
            out[b].append(chain[::-1])
        return out

    def arms(self, k: int, min_nodes: int, deg: np.ndarray | None = None) -> list[list[int]]:
        """The fine chains leaving key node k, each continued through degree-2 key nodes (a
        bend right next to a junction) until it holds ``min_nodes`` nodes or ends (``deg``:
        the degrees, if already computed)."""
        deg = self.degree() if deg is None else deg
        out = []
        for e, (a, b, chain) in enumerate(self.edges):
            if a != k and b != k:
                continue  # (most edges: no reversed copy of their chain made)
            for start, end, ch in ((a, b, chain), (b, a, chain[::-1])):
                if start != k:
                    continue
                arm, at, via = list(ch), end, e
                while len(arm) < min_nodes and deg[at] == 2 and at != k:
                    nxt = [(i, p, q, c) for i, (p, q, c) in enumerate(self.edges)
                           if i != via and at in (p, q)]
                    if not nxt:
                        break
                    i, p, q, c = nxt[0]
                    arm += (c if p == at else c[::-1])[1:]
                    at, via = (q if p == at else p), i
                out.append(arm)
                if a == b:
                    break
        return out


def _chain_length(pos: np.ndarray, chain: list[int]) -> float:
    """The length of a fine chain (cells; compiled: ``_path_length``)."""
    return _path_length(pos, np.array(chain, np.int64)) if len(chain) > 1 else 0.0


@njit(cache=True, nogil=True)
def _path_length(pos, path):
    """The length of the path through the nodes ``path`` (at least two): its steps' np.hypot
    lengths summed (block_sum)."""
    steps = np.empty(len(path) - 1)
    for k in range(len(path) - 1):
        steps[k] = math.hypot(pos[path[k + 1], 0] - pos[path[k], 0],
                              pos[path[k + 1], 1] - pos[path[k], 1])
    return block_sum(steps)


def remove_short_lines(graph: LineGraph, min_length: float) -> LineGraph:
    """Eliminate short lines ending in junctions: a path from an end node to a node of degree
    >= 3 shorter than ``min_length`` cells is removed (returns a new graph). The end nodes
    are walked in order, each on the graph as the earlier removals left it (compiled:
    ``_short_spurs``); the removed connections are then taken out of the copy's sets in the
    same order; the copy keeps the connections left as its flat lists."""
    g = graph.copy()
    if len(g) == 0:
        return g
    start, nbr = graph.neighbour_lists()
    kept_start = np.empty_like(start)
    kept_nbr = np.empty_like(nbr)
    cut = _short_spurs(start, nbr, np.ascontiguousarray(g.pos, np.float64), float(min_length),
                       kept_start, kept_nbr)
    for a, b in cut.tolist():
        g.disconnect(a, b)
    g.lists = (kept_start, kept_nbr[:kept_start[-1]])
    return g


@njit(cache=True, nogil=True)
def _short_spurs(start, nbr, pos, min_length, kept_start, kept_nbr):
    """remove_short_lines' walks: from each end node (degree 1 at the start, in index order)
    along nodes of degree 2 to the first node of another degree; where that is a junction
    (degree >= 3) and the path is shorter than ``min_length`` (_path_length), the path's
    connections are removed (here and from the degrees the later walks see). Returns the
    removed connections (a, b) in order; the connections left go into ``kept_start``,
    ``kept_nbr`` as flat lists of the same form."""
    n = len(start) - 1
    alive = np.ones(len(nbr), np.bool_)
    deg = np.empty(n, np.int64)
    for i in range(n):
        deg[i] = start[i + 1] - start[i]
    ends = np.nonzero(deg == 1)[0]
    path = np.empty(n + 1, np.int64)
    cut = np.empty((len(nbr), 2), np.int64)
    m = 0
    for e in ends:
        path[0] = e
        np_ = 1
        prev, cur = -1, e
        while True:
            if deg[cur] != (1 if cur == e else 2):
                break
            nxt = -1
            for k in range(start[cur], start[cur + 1]):
                if alive[k] and nbr[k] != prev:
                    nxt = nbr[k]
                    break
            if nxt < 0:
                break
            prev, cur = cur, nxt
            path[np_] = cur
            np_ += 1
            if np_ > n:  # a ring of degree-2 nodes back to the end: the walk went round
                break
        if deg[cur] < 3:
            continue
        length = _path_length(pos, path[:np_]) if np_ > 1 else 0.0
        if length >= min_length:
            continue
        for k in range(np_ - 1):
            a, b = path[k], path[k + 1]
            for q in range(start[a], start[a + 1]):
                if alive[q] and nbr[q] == b:
                    alive[q] = False
                    deg[a] -= 1
            for q in range(start[b], start[b + 1]):
                if alive[q] and nbr[q] == a:
                    alive[q] = False
                    deg[b] -= 1
            cut[m, 0], cut[m, 1] = a, b
            m += 1
    k = 0
    for i in range(n):
        kept_start[i] = k
        for q in range(start[i], start[i + 1]):
            if alive[q]:
                kept_nbr[k] = nbr[q]
                k += 1
    kept_start[n] = k
    return cut[:m].copy()


def flat_lists(lists) -> tuple[np.ndarray, np.ndarray]:
    """Index lists (or arrays) as one int64 array and their starts (L + 1,)."""
    start = np.zeros(len(lists) + 1, np.int64)
    np.add.accumulate(np.fromiter(map(len, lists), np.int64, len(lists)), out=start[1:])
    if lists and isinstance(lists[0], np.ndarray):  # (joined whole, not item by item)
        return np.concatenate(lists, dtype=np.int64), start
    flat = np.fromiter(itertools.chain.from_iterable(lists), np.int64, int(start[-1]))
    return flat, start


def trace_chains(graph: LineGraph) -> list[list[int]]:
    """Chains of degree-2 nodes between nodes of another degree (each chain includes its two
    end nodes); closed loops of degree-2 nodes start and end at their first node. Walked by
    a compiled pass (``_trace``) over the neighbour lists."""
    n = len(graph.adj)
    if n == 0:
        return []
    start, nbr = graph.neighbour_lists()
    flat = np.empty(3 * (len(nbr) + n) + 4, np.int64)
    bounds = np.empty(len(nbr) + n + 2, np.int64)
    m = _trace(start, nbr, flat, bounds)
    nodes, b = flat[:bounds[m]].tolist(), bounds[:m + 1].tolist()
    return [nodes[b[k]:b[k + 1]] for k in range(m)]


@njit(cache=True, nogil=True)
def _follow(start, nbr, used, flat, k, s, t):
    """One chain of _trace into ``flat`` from ``k``: s, t, then the degree-2 nodes not yet
    used that follow t (each marked used); returns the next free index."""
    flat[k], flat[k + 1] = s, t
    k += 2
    prev, cur = s, t
    while start[cur + 1] - start[cur] == 2 and not used[cur]:
        used[cur] = True
        a = nbr[start[cur]]
        nxt = nbr[start[cur] + 1] if a == prev else a
        prev, cur = cur, nxt
        flat[k] = cur
        k += 1
    return k


@njit(cache=True, nogil=True)
def _trace(start, nbr, flat, bounds):
    """trace_chains' walk: nodes of degree other than 2 (and not 0) in order, each one's
    neighbours in ascending order: a walk along the degree-2 nodes not yet used, or a direct
    chain to another such node (once per pair); then the loops of unused degree-2 nodes,
    each from its first node through its lower neighbour. Chain k's nodes into
    ``flat[bounds[k]:bounds[k + 1]]``; returns the number of chains."""
    n = len(start) - 1
    used = np.zeros(n, np.bool_)
    direct = np.zeros((n, n), np.bool_)
    m, k = 0, 0
    for s in range(n):
        d = start[s + 1] - start[s]
        if d == 2 or d == 0:
            continue
        nb = np.sort(nbr[start[s]:start[s + 1]])
        for t in nb:
            if start[t + 1] - start[t] == 2:
                if used[t]:
                    continue
                bounds[m] = k
                k = _follow(start, nbr, used, flat, k, s, t)
                m += 1
            else:
                lo, hi = min(s, t), max(s, t)
                if direct[lo, hi]:
                    continue
                direct[lo, hi] = True
                bounds[m] = k
                flat[k], flat[k + 1] = s, t
                k += 2
                m += 1
    for s in range(n):  # loops of degree-2 nodes only
        if start[s + 1] - start[s] == 2 and not used[s]:
            used[s] = True
            t = min(nbr[start[s]], nbr[start[s] + 1])
            bounds[m] = k
            k = _follow(start, nbr, used, flat, k, s, t)
            if flat[k - 1] != s:
                flat[k] = s
                k += 1
            m += 1
    bounds[m] = k
    return m


def smooth_lines(graph: LineGraph, iterations: int = 2) -> np.ndarray:
    """Node positions smoothed along the lines: each degree-2 node moves to the mean of itself
    and its two neighbours; other nodes stay (returns new positions)."""
    pos = np.array(graph.pos, np.float64)  # a copy
    if len(pos) == 0:
        return pos
    start, nbr = graph.neighbour_lists()
    _smooth_chains(pos, start, nbr, int(iterations))
    return pos


@njit(cache=True, nogil=True)
def _smooth_chains(pos, start, nbr, iterations):
    """smooth_lines in place, compiled: each round every degree-2 node's new position is
    (its own + its lower neighbour's + its higher neighbour's) / 3 from the round's old
    positions, as the numpy expression computed it."""
    n = len(start) - 1
    idx = np.empty(n, np.int64)
    lo = np.empty(n, np.int64)
    hi = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        if start[i + 1] - start[i] == 2:
            a, b = nbr[start[i]], nbr[start[i] + 1]
            idx[m], lo[m], hi[m] = i, min(a, b), max(a, b)
            m += 1
    new = np.empty((m, 2))
    for _ in range(iterations):
        for k in range(m):
            for d in range(2):
                new[k, d] = (pos[idx[k], d] + pos[lo[k], d] + pos[hi[k], d]) / 3.0
        for k in range(m):
            pos[idx[k], 0], pos[idx[k], 1] = new[k, 0], new[k, 1]


def turning_angles(chains: list[list[int]], pos: np.ndarray, reach: float,
                   floor: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
    """Turning angle (rad) at every node of every chain, measured with arms reaching ``reach``
    along the chain on both sides (0 at a chain's ends), all chains at once, in the image and,
    with ``floor`` (the nodes' floor positions, (N, 2), NaN where unknown), on the floor too:
    there the arms are those nodes' floor points where known (a far L corner looks nearly
    straight in a perspective image). The chains' arcs and arms are found once for both.
    Returns the image angles, the floor angles (None without ``floor``), the arc length of
    each node along its chain and the chain's first index, all over the chains' concatenated
    nodes."""
    if not chains:
        return np.zeros(0), (None if floor is None else np.zeros(0)), np.zeros(0), \
            np.zeros(0, int)
    idx, first = flat_lists(chains)
    lens = first[1:] - first[:-1]
    n = len(idx)
    cos_img = np.empty(n)
    cos_floor = np.empty(n)
    arc = np.empty(n)
    start = np.empty(n, np.int64)
    ends = np.empty(n, np.bool_)
    use_floor = floor is not None
    _turn_cosines(np.ascontiguousarray(pos, np.float64), idx, lens, float(reach),
                  np.ascontiguousarray(floor, np.float64) if use_floor else np.zeros((1, 2)),
                  use_floor, cos_img, cos_floor, arc, start, ends)
    turn = np.arccos(cos_img)  # numpy's arccos (its SIMD one, as before)
    turn[ends] = 0.0
    floor_turn = None
    if use_floor:
        floor_turn = np.arccos(cos_floor)
        floor_turn[ends] = 0.0
    return turn, floor_turn, arc, start


@njit(cache=True, nogil=True, inline="always")
def _arm_cosine(ax, ay, bx, by):
    """The clipped cosine of the angle between the arms a (back) and b (forward), as numpy
    had it ((a . b) / (|a| |b|), np.hypot lengths; 1 where an arm is empty)."""
    na, nb = np.hypot(ax, ay), np.hypot(bx, by)
    if not (na > 0 and nb > 0):
        return 1.0
    c = (ax * bx + ay * by) / (na * nb)
    if c < -1.0:
        return -1.0
    if c > 1.0:
        return 1.0
    return c


@njit(cache=True, nogil=True)
def _search(key, v, right):
    """np.searchsorted(key, v, side "right" if ``right`` else "left")."""
    lo, hi = 0, len(key)
    while lo < hi:
        mid = (lo + hi) >> 1
        if key[mid] < v or (right and key[mid] == v):
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, nogil=True)
def _turn_cosines(pos, idx, lens, reach, floor, use_floor, cos_img, cos_floor, arc, start,
                  ends):
    """turning_angles before the arccos, compiled, as its numpy expressions computed it: the
    arcs (np.hypot steps, one cumulative sum over all chains, less each chain's first), the
    arms' far ends by a sorted search of the chains laid end to end (the same keys), and the
    arms' clipped cosines in the image and (``use_floor``) on the floor where both floor
    arms are known; ``ends`` marks each chain's first and last node."""
    n = len(idx)
    cum = np.empty(n)  # the steps' cumulative sum over all chains (a chain's first step 0)
    total = 0.0
    k = 0
    for c in range(len(lens)):
        for j in range(lens[c]):
            if j > 0:
                i0, i1 = idx[k - 1], idx[k]
                total = total + np.hypot(pos[i1, 0] - pos[i0, 0], pos[i1, 1] - pos[i0, 1])
            else:
                total = total + 0.0
            cum[k] = total
            start[k] = k - j
            k += 1
    top = 0.0
    for k in range(n):
        arc[k] = cum[k] - cum[start[k]]
        top = max(top, arc[k])
    span = top + 4 * reach + 1.0
    key = np.empty(n)
    k = 0
    for c in range(len(lens)):
        for _ in range(lens[c]):
            key[k] = arc[k] + c * span
            k += 1
    k = 0
    for c in range(len(lens)):
        first, last = k, k + lens[c] - 1
        for j in range(lens[c]):
            back = min(max(_search(key, key[k] - reach, True) - 1, first), last)
            fwd = min(max(_search(key, key[k] + reach, False), first), last)
            ends[k] = j == 0 or j == lens[c] - 1
            p, q, r = idx[back], idx[k], idx[fwd]
            ax, ay = pos[q, 0] - pos[p, 0], pos[q, 1] - pos[p, 1]
            bx, by = pos[r, 0] - pos[q, 0], pos[r, 1] - pos[q, 1]
            cos_img[k] = _arm_cosine(ax, ay, bx, by)
            if use_floor:
                fax, fay = floor[q, 0] - floor[p, 0], floor[q, 1] - floor[p, 1]
                fbx, fby = floor[r, 0] - floor[q, 0], floor[r, 1] - floor[q, 1]
                if (np.isfinite(fax) and np.isfinite(fay) and np.isfinite(fbx)
                        and np.isfinite(fby)):
                    ax, ay, bx, by = fax, fay, fbx, fby
                cos_floor[k] = _arm_cosine(ax, ay, bx, by)
            k += 1


def corner_nodes(turn: np.ndarray, arc: np.ndarray, reach: float, min_turn: float) -> list[int]:
    """Indices (in one chain, from its turning angles and arc lengths) of the nodes kept at high
    curvature: local maxima of the turning angle above ``min_turn``, at least ``reach`` apart and
    from the chain's ends; all other interior nodes are removed."""
    if len(turn) < 3 or turn.max() < min_turn:
        return []
    kept: list[int] = []
    for i in np.argsort(-turn, kind="stable"):
        if turn[i] < min_turn:
            break
        if all(abs(arc[i] - arc[k]) >= reach for k in kept) and arc[i] >= reach * 0.5 \
                and arc[-1] - arc[i] >= reach * 0.5:
            kept.append(int(i))
    return sorted(kept)


@njit(cache=True, nogil=True)
def _corner_cuts(turn, arc, offsets, reach, min_turn, cuts, cut_start, by_python):
    """corner_nodes of every chain (``offsets``: its first index in turn and arc), compiled:
    the same stable order by falling turn and the same tests; chain c's cuts, ascending,
    into ``cuts[cut_start[c]:cut_start[c + 1]]``. A chain with a NaN turn is left to
    corner_nodes (``by_python``)."""
    m = 0
    kept = np.empty(len(turn), np.int64)
    for c in range(len(offsets) - 1):
        cut_start[c] = m
        i0, i1 = offsets[c], offsets[c + 1]
        n = i1 - i0
        t, a = turn[i0:i1], arc[i0:i1]
        top = -np.inf
        for i in range(n):
            if np.isnan(t[i]):
                by_python[c] = True
            top = max(top, t[i])
        if by_python[c] or n < 3 or top < min_turn:
            continue
        neg = np.empty(n)
        for i in range(n):
            neg[i] = -t[i]
        nk = 0
        for i in np.argsort(neg, kind="mergesort"):
            if t[i] < min_turn:
                break
            ok = a[i] >= reach * 0.5 and a[n - 1] - a[i] >= reach * 0.5
            for q in range(nk):
                if not abs(a[i] - a[kept[q]]) >= reach:
                    ok = False
            if ok:
                kept[nk] = i
                nk += 1
        chosen = np.sort(kept[:nk])
        for q in range(nk):
            cuts[m] = chosen[q]
            m += 1
    cut_start[len(offsets) - 1] = m


def key_structure(graph: LineGraph, tuning: KeyTuning = KEY, floor_of=None) -> KeyStructure:
    """Section 4.1: from the fine graph to the key node structure. ``floor_of``: a function
    of grid positions (N, 2) -> floor points (N, 2) (NaN above the horizon); with it the
    corners are found by their turning angle on the floor (``corner_min_turn_floor``) among
    the nodes turning at least ``corner_min_turn_image`` in the image."""
    t = tuning
    pruned = remove_short_lines(graph, t.min_spur_length)
    smooth = smooth_lines(pruned, t.smooth_iterations)
    chains = trace_chains(pruned)
    key_of: dict[int, int] = {}  # the key nodes' indices by fine node, in order of finding
    edges = []
    min_turn, reach = t.corner_min_turn, t.corner_reach
    on_floor = floor_of is not None and len(smooth)
    turn, floor_turn, arc, start = turning_angles(
        chains, smooth, reach, floor_of(smooth) if on_floor else None)
    if on_floor:
        # on the floor, where the image turns at least a little: far from the camera a pixel
        # of noise is a large floor angle
        turn = np.where(turn >= t.corner_min_turn_image, floor_turn, 0.0)
        min_turn = t.corner_min_turn_floor
    # the corners of all chains at once (corner_nodes, compiled: _corner_cuts)
    offsets = np.zeros(len(chains) + 1, np.int64)
    np.add.accumulate(np.fromiter(map(len, chains), np.int64, len(chains)), out=offsets[1:])
    cuts = np.empty(len(turn), np.int64)
    cut_start = np.empty(len(chains) + 1, np.int64)
    by_python = np.zeros(len(chains), np.bool_)
    _corner_cuts(np.ascontiguousarray(turn, np.float64), np.ascontiguousarray(arc, np.float64),
                 offsets, float(reach), float(min_turn), cuts, cut_start, by_python)
    cut_list, cut_at = cuts.tolist(), cut_start.tolist()
    for c, (chain, python) in enumerate(zip(chains, by_python.tolist())):
        if python:
            i0, i1 = offsets[c], offsets[c + 1]
            cut = corner_nodes(turn[i0:i1], arc[i0:i1], reach, min_turn)
        else:
            cut = cut_list[cut_at[c]:cut_at[c + 1]]
        bounds = [0] + cut + [len(chain) - 1]
        for a, b in zip(bounds[:-1], bounds[1:]):
            ka = key_of.setdefault(chain[a], len(key_of))
            edges.append((ka, key_of.setdefault(chain[b], len(key_of)), chain[a:b + 1]))
    nodes = list(key_of)
    # small rings hanging at a node (a hole in a wide crossing blob) are no lines
    edges = [e for e in edges if not (e[0] == e[1]
                                       and _chain_length(pruned.pos, e[2]) < t.max_ring)]
    ks = KeyStructure(nodes, pruned.pos[nodes] if nodes else np.zeros((0, 2)), edges)
    return merge_close_junctions(ks, pruned, t.merge_distance)


def merge_close_junctions(ks: KeyStructure, graph: LineGraph, max_length: float
                          ) -> KeyStructure:
    """Merge junctions (degree >= 3) connected by a key edge shorter than ``max_length`` cells
    into one crossing, placed at the fine node of the two (on the skeleton) nearest to their
    mean position."""
    while True:
        deg = ks.degree().tolist()
        best = None
        for e, (a, b, chain) in enumerate(ks.edges):
            if a != b and deg[a] >= 3 and deg[b] >= 3:
                ln = _chain_length(graph.pos, chain)
                if ln < max_length and (best is None or ln < best[0]):
                    best = (ln, e)
        if best is None:
            return ks
        a, b, chain = ks.edges[best[1]]
        mid = 0.5 * (ks.pos[a] + ks.pos[b])
        near = min(chain, key=lambda i: np.hypot(*(graph.pos[i] - mid)))
        ks.node[a] = near
        ks.pos[a] = graph.pos[near]
        edges = []
        for e, (p, q, ch) in enumerate(ks.edges):
            if e == best[1]:
                continue
            if p == b:
                p, ch = a, chain + ch[1:] if ch and ch[0] == chain[-1] else ch
            if q == b:
                q, ch = a, ch + chain[::-1][1:] if ch and ch[-1] == chain[-1] else ch
            edges.append((p, q, ch))
        # drop node b (keep indices dense)
        keep = [k for k in range(len(ks.node)) if k != b]
        remap = {k: n for n, k in enumerate(keep)}
        ks = KeyStructure([ks.node[k] for k in keep], ks.pos[keep],
                          [(remap[p], remap[q], ch) for p, q, ch in edges])
