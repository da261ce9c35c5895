"""The numba kernels of the line structure graph (``line_structure``): the inner loops of the
ranking skeleton, the nodes' placement and regions, their links, the triangle, spur and gap
passes over the graph's adjacency lists, the chains' tracing and smoothing, their turning
angles and the key structure's corner cuts, and ``bilinear_at``, the one-point bilinear sample
that the crossings' kernels use too. They take plain arrays (a graph as its adjacency lists:
``start``, ``nbr``) and write into output arrays; ``line_structure`` holds the Python API that
builds their inputs and reads their results. Kept apart so that the API reads without the
kernels' loops in the way; nothing here imports ``line_structure``.
"""

from __future__ import annotations

import math

import numpy as np

from ...common.jit import njit

# the sum of a float64 array, a plain loop (numeric.sum64)
from ...common.numeric import sum64 as block_sum


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


@njit(cache=True, nogil=True)
def _path_length(pos, path):
    """The length of the path through the nodes ``path`` (at least two): its steps' np.hypot
    lengths summed (block_sum)."""
    steps = np.empty(len(path) - 1)
    for k in range(len(path) - 1):
        steps[k] = math.hypot(pos[path[k + 1], 0] - pos[path[k], 0],
                              pos[path[k + 1], 1] - pos[path[k], 1])
    return block_sum(steps)


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
