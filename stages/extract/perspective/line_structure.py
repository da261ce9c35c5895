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

This module is the Python API of these steps; their compiled kernels live in
``line_structure_kernels``.
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np

from .line_structure_kernels import (
    _centroids,
    _corner_cuts,
    _farthest_pairs,
    _farthest_region_pixels,
    _gap_candidates,
    _gap_choice,
    _gap_grey,
    _linked_lists,
    _node_regions,
    _nodes_by_priority,
    _path_length,
    _rank_counts,
    _region_links,
    _region_pixels,
    _short_spurs,
    _skeleton_grid,
    _smooth_chains,
    _trace,
    _triangle_cuts,
    _turn_cosines,
)


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


def subpixel_positions(image: np.ndarray, pix: np.ndarray) -> np.ndarray:
    """Grey-level weighted centroid of each node's 3 x 3 window (x, y) (compiled:
    ``_centroids``)."""
    if len(pix) == 0:
        return np.zeros((0, 2))
    return _centroids(np.ascontiguousarray(image), np.ascontiguousarray(pix, np.int64))


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


@functools.lru_cache(maxsize=4)
def _gap_steps(samples: int) -> np.ndarray:
    """np.linspace(0, 1, samples) shaped (1, samples, 1), made once (read-only)."""
    t = np.linspace(0.0, 1.0, samples)[None, :, None]
    t.setflags(write=False)
    return t


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


def smooth_lines(graph: LineGraph, iterations: int = 2) -> np.ndarray:
    """Node positions smoothed along the lines: each degree-2 node moves to the mean of itself
    and its two neighbours; other nodes stay (returns new positions)."""
    pos = np.array(graph.pos, np.float64)  # a copy
    if len(pos) == 0:
        return pos
    start, nbr = graph.neighbour_lists()
    _smooth_chains(pos, start, nbr, int(iterations))
    return pos


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
