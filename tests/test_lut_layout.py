"""The table search's lookup (lut_tables.py module doc) against plain numpy references written
here: the error lookup enumerated over every cell (its entries held to the rounded error term
within half a level), its min-pooled copy, the surfaces summed from them, the greedy of
separated minima and the window's best cell. The search computes the lookup's entries only
where the min-pooled lookup leaves a cell in play (branch and bound): every surface, pick and
best cell must equal the enumeration's exactly (integer sums and decisions)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stages import build_map
from stages.common.map_file import MapFile
from stages.common.scanlines import NO_HIT_MM
from stages.localize.lut_global import full_surface
from stages.localize.lut_kernels import (
    MAX_CROSSINGS,
    TILE,
    evidence_weights,
    flatten_scanlines,
    structure_sizes,
    tiled_sum,
)
from stages.localize.lut_search import MatchingParams, Observation, TableSearch
from stages.localize.lut_tables import COARSE_BIN_POOL
from stages.localize.lut_tracked import window_best


@pytest.fixture(scope="module")
def kid_map(tmp_path_factory):
    return build_map.main({"resolution": 0.2}, "kidsize",
                          tmp_path_factory.mktemp("layout") / "kid.map.h5")


# coarse_step 2 (MatchingParams' default) and 3 (lut's): the kidsize grid at 0.2 m leaves a
# last fine column that no coarse cell covers with one of them (checked below)
@pytest.fixture(scope="module", params=[2, 3])
def search(kid_map, request):
    with MapFile(kid_map) as mf:
        yield TableSearch(mf, MatchingParams(coarse_step=request.param), cache=False)


@pytest.fixture(scope="module")
def reference(search):
    return reference_lookup(search), reference_pooled(search)


def reference_lookup(s) -> np.ndarray:
    """The whole error lookup (rows, ny, nx) uint8, enumerated: per scan line, distance bin and
    cell the least of the quantised errors (``Quantised.values``) of the cell's crossings. The
    values themselves are held to rint(q_levels w(d) rho(e)) with a tolerance below
    (test_the_quantised_errors_are_the_rounded_error_term); the searches, which compute entries
    only where the min-pooled bound leaves a cell in play, must give what this enumeration
    gives: integer sums and decisions, exactly."""
    q = s.quantised
    values = q.values.reshape(-1, q.width)
    rows = [values[:s.nb_radial][:, s.radial_table[k]].min(axis=2) for k in range(s.n_angles)]
    rows += [values[s.nb_radial:][:, s.spiral_table[line]] for line in range(2 * s.n_angles)]
    return np.concatenate(rows).reshape(-1, s.ny, s.nx)


def error_term(s) -> np.ndarray:
    """q_levels w(d) rho(e) (rows, ny, nx) in float64: the real value every entry rounds, e the
    distance from the bin's d to the nearest crossing of the line at the cell."""
    p = s.params
    t_r = np.where(s.radial_mm == NO_HIT_MM, 1e3, s.radial_mm * 1e-3)  # (line, crossing, cell)
    t_s = np.where(s.spiral_mm == NO_HIT_MM, 1e3, s.spiral_mm * 1e-3)
    out = []
    for nb, tables in ((s.nb_radial, t_r), (s.nb_spiral, t_s[:, None, :])):
        d = np.arange(nb) * p.distance_bin
        for t in tables:
            e = np.abs(t[:, None, :] - d[None, :, None]).min(axis=0)  # (bin, cell)
            out.append(s.q_levels * p.weight(d)[:, None] * p.rho(e))
    return np.concatenate(out).reshape(-1, s.ny, s.nx)


def reference_pooled(s) -> np.ndarray:
    """The min-pooled lookup (rows, cy, cx): coarse cell (a, b) of a row the least entry of
    the fine cells within coarse_step // 2 of fine cell (a, b) * coarse_step, over the
    COARSE_BIN_POOL distance bins of the row (a scan line's bins in groups from its first)."""
    step, (cy, cx) = s.params.coarse_step, s.coarse_shape
    ref, half = reference_lookup(s), step // 2
    out = np.empty((len(ref), cy, cx), np.uint8)
    for a in range(cy):
        for b in range(cx):
            i, j = a * step, b * step
            out[:, a, b] = ref[:, max(i - half, 0):i + half + 1,
                               max(j - half, 0):j + half + 1].min(axis=(1, 2))
    row_of = pooled_row_of(s)
    pooled = np.full((row_of[-1] + 1, cy, cx), 255, np.uint8)
    for r, g in enumerate(row_of):
        pooled[g] = np.minimum(pooled[g], out[r])
    return pooled


def pooled_row_of(s) -> np.ndarray:
    """The min-pooled lookup's row of every row of the error lookup: each scan line's
    distance bins in groups of COARSE_BIN_POOL from its first."""
    out, base = [], 0
    for nb in [s.nb_radial] * s.n_angles + [s.nb_spiral] * (2 * s.n_angles):
        out.append(base + np.arange(nb) // COARSE_BIN_POOL)
        base += -(-nb // COARSE_BIN_POOL)
    return np.concatenate(out)


def _rows_of_cells(tiled: np.ndarray, ny: int, nx: int) -> np.ndarray:
    """The tiled rows (rows, blocks * TILE^2) back as rows of cells (rows, ny, nx)."""
    rows = tiled.shape[0]
    nty, ntx = -(-ny // TILE), -(-nx // TILE)
    blocks = tiled.reshape(rows, nty, ntx, TILE, TILE).transpose(0, 1, 3, 2, 4)
    return blocks.reshape(rows, nty * TILE, ntx * TILE)[:, :ny, :nx]


def observations(s, rng, *, from_table: bool) -> Observation:
    """A frame's observations: the table's own crossings at a random cell and heading with 3
    cm noise, a fifth dropped and a few false hits (a sharp minimum), or distances at random
    (a flat surface)."""
    if from_table:
        c, m = int(rng.integers(s.ncell)), int(rng.integers(s.n_angles))
        lines = (np.arange(s.n_angles) + m) % s.n_angles
        mm = s.radial_mm[lines, :, c].astype(float)
        d = np.where(mm == NO_HIT_MM, np.nan, mm * 1e-3 + rng.normal(0, 0.03, mm.shape))
        d[rng.random(d.shape) < 0.2] = np.nan
        d[rng.integers(0, s.n_angles, 3), 3] = rng.uniform(0.5, 3.0, 3)
        spiral = s.spiral_mm[np.concatenate([lines, s.n_angles + lines]), c].astype(float)
        sp = np.where(spiral == NO_HIT_MM, np.nan, spiral * 1e-3).reshape(2, -1)
    else:
        d = np.where(rng.random((s.n_angles, MAX_CROSSINGS)) < 0.3,
                     rng.uniform(0.3, 4.0, (s.n_angles, MAX_CROSSINGS)), np.nan)
        sp = np.where(rng.random((2, s.n_angles)) < 0.3, rng.uniform(0.3, 3.0, (2, s.n_angles)),
                      np.nan)
    sl = s.scanlines
    return Observation.from_scanlines(d, sp, s.params, sl.max_range, sl.spiral_end_radius,
                                      sl.robot_radius)


def reference_surface(s, ref, obs, m) -> np.ndarray:
    """The quantised error surface (ny, nx): the sum of the observations' reference rows."""
    return ref[s.lookup_rows(obs, m)].astype(np.int64).sum(axis=0)


def reference_greedy(surface: np.ndarray, k: int, r: int) -> list[int]:
    """Up to k flat cells: the lowest (then lowest index) not within r cells (in x and y) of
    one taken before."""
    order = np.lexsort((np.arange(surface.size), surface.ravel()))
    picks: list[int] = []
    nx = surface.shape[1]
    for c in order:
        if all(abs(c // nx - p // nx) > r or abs(c % nx - p % nx) > r for p in picks):
            picks.append(int(c))
            if len(picks) == k:
                break
    return picks


def test_the_grid_is_not_a_whole_number_of_blocks(search):
    # so that the padding and the partial blocks at the edges are exercised below
    assert search.ny % TILE and search.nx % TILE


def test_some_fine_cells_lie_past_the_last_coarse_cell(search):
    # (the min-pooled lookup bounds them by 0): exercised by the searches below
    step, (cy, cx) = search.params.coarse_step, search.coarse_shape
    past = cy * step - step // 2 < search.ny or cx * step - step // 2 < search.nx
    assert past == (search.params.coarse_step == 3)


def test_the_quantised_errors_are_the_rounded_error_term(search, reference):
    """Every entry of the error lookup, the least quantised error of a cell's crossings
    (Quantised: the value is monotone in the error), is the error term q_levels w(d) rho(e)
    rounded to the nearest level: within half a level, and 1e-3 of a level for the float32
    arithmetic of the values' table."""
    ref, _pooled = reference
    assert np.abs(ref.astype(np.float64) - error_term(search)).max() <= 0.5 + 1e-3


def test_the_tables_are_the_maps_with_a_cells_crossings_side_by_side(search):
    s = search
    # exact integers: uint8 / uint16 values and their integer sums
    assert np.array_equal(s.radial_table, s.radial_mm.transpose(0, 2, 1))
    # exact integers: uint8 / uint16 values and their integer sums
    assert np.array_equal(s.spiral_table, s.spiral_mm)


def test_the_min_pooled_lookup_bounds_every_cell_it_covers(search, reference):
    s, (ref, pooled) = search, reference
    cy, cx = s.coarse_shape
    coarse = _rows_of_cells(s.coarse_lookup, cy, cx)
    # exact integers: uint8 / uint16 values and their integer sums
    assert np.array_equal(coarse, pooled)
    step, half = s.params.coarse_step, s.params.coarse_step // 2
    a = (np.arange(s.ny) + half) // step
    b = (np.arange(s.nx) + half) // step
    ok_i, ok_j = a < cy, b < cx
    bound = coarse[pooled_row_of(s)][:, a[ok_i]][:, :, b[ok_j]]
    assert np.all(bound <= ref[:, ok_i][:, :, ok_j])


def test_exact_errors_read_the_nearest_crossing_of_each_cell(search):
    s = search
    rng = np.random.default_rng(1)
    n = 40
    obs = Observation(family=np.zeros(n, np.int64), angle_index=rng.integers(0, s.n_angles, n),
                      distance=rng.uniform(0.3, 3.5, n), weight=np.ones(n))
    cells = rng.integers(0, s.ncell, 12)
    m = 7
    got = s.exact_error(obs, cells, m)
    t = np.where(s.radial_mm == NO_HIT_MM, 1e3, s.radial_mm * 1e-3)  # (line, crossing, cell)
    lines = (obs.angle_index + m) % s.n_angles
    e = np.abs(t[lines][:, :, cells] - obs.distance[:, None, None]).min(axis=1)  # (obs, cell)
    c2 = s.params.c ** 2
    assert np.allclose(got, (e**2 / (c2 + e**2)).sum(axis=0), rtol=1e-5)


def test_window_sums_are_the_sums_of_the_observations_rows(search, reference):
    s, (ref, pooled) = search, reference
    rng = np.random.default_rng(2)
    for case in range(6):
        obs = observations(s, rng, from_table=case % 2 == 0)
        m = int(rng.integers(s.n_angles))
        full = reference_surface(s, ref, obs, m)
        # exact integers: sums of uint8 quantised errors
        assert np.array_equal(full_surface(s.tables, obs, m), full.ravel())
        windows = [(1, 2, 3, 4), (s.ny - 3, s.ny, s.nx - 9, s.nx)]
        for _ in range(5):
            i0, j0 = rng.integers(0, s.ny - 1), rng.integers(0, s.nx - 1)
            windows.append((i0, rng.integers(i0 + 1, s.ny + 1), j0,
                            rng.integers(j0 + 1, s.nx + 1)))
        for i0, i1, j0, j1 in windows:
            got = s.local_surface(obs, m, int(i0), int(i1), int(j0), int(j1))
            # exact integers: uint8 / uint16 values and their integer sums
            assert np.array_equal(got, full[i0:i1, j0:j1])
        # the min-pooled lookup's sums (tiled_sum) are its rows' sums too
        cy, cx = s.coarse_shape
        out = np.empty((cy, cx), np.uint16)
        tiled_sum(s.min_pooled, s.tables.observed(obs), m, (0, cy, 0, cx), out)
        rows = s.lookup_rows(obs, m, coarse=True)
        # exact integers: uint8 / uint16 values and their integer sums
        assert np.array_equal(out, pooled[rows].astype(np.int64).sum(axis=0))


def test_the_weighted_surface_is_the_weighted_sum_of_the_rows(search, reference):
    s, (ref, _pooled) = search, reference
    rng = np.random.default_rng(4)
    obs = observations(s, rng, from_table=True)
    ev = obs.with_evidence(s.scanlines, 2.0, 0.2, 0.1)
    theta = 0.3
    m = s.scanlines.heading_index(theta)
    scale = (ev.weight / ev.lookup_weight).astype(np.float32)
    want = np.zeros((s.ny, s.nx), np.float32)
    for f, row in zip(scale, s.lookup_rows(ev, m)):  # in order, float32 as the kernel adds
        want += f * ref[row]
    # the same float32 operations in the same order: equal but for a fused multiply-add
    np.testing.assert_allclose(s.surface(ev, theta), want.astype(np.float64) / s.q_levels,
                               rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("from_table", [True, False])
def test_branch_and_bound_picks_the_greedys_cells_on_the_whole_surface(search, reference,
                                                                       from_table):
    """separated_minima computes the surface only where the min-pooled bound leaves a cell
    in play; its picks equal the greedy's on the whole reference surface, for few and many
    minima, close and far apart (with many, the greedy runs out of cells)."""
    s, (ref, _pooled) = search, reference
    rng = np.random.default_rng(5 + from_table)
    for _ in range(8):
        obs = observations(s, rng, from_table=from_table)
        m = int(rng.integers(s.n_angles))
        full = reference_surface(s, ref, obs, m)
        for k, r in ((1, 1), (3, 3), (16, 5), (60, 8)):
            got = s.separated_minima(obs, m, k, r)
            assert got.tolist() == reference_greedy(full, k, r), (k, r)


def test_the_windows_best_cell_is_the_least_posterior_score(search, reference):
    """tracked_window (branch and bound) returns the cell of least quantised surface / T +
    capped Mahalanobis term over the window, the first of equal ones, and its score: the
    tracked window's and, without a prior, the local search's; windows at the grid's edges
    included."""
    s, (ref, _pooled) = search, reference
    rng = np.random.default_rng(7)
    res, (x0, y0) = s.grid.resolution, s.grid.origin
    for case in range(24):
        obs = observations(s, rng, from_table=case % 3 != 0)
        theta = float(rng.uniform(-math.pi, math.pi))
        m = s.scanlines.heading_index(theta)
        full = reference_surface(s, ref, obs, m)
        corner = case % 4 == 0
        prior = ((x0 + (s.nx - 1) * res, y0 + (s.ny - 1) * res) if corner else
                 (rng.uniform(x0, x0 + s.nx * res), rng.uniform(y0, y0 + s.ny * res)))
        a = rng.uniform(0.5, 30.0)
        info = np.array([[a, 0.3 * a], [0.3 * a, 2.0 * a]])
        T, cap = rng.uniform(0.3, 3.0), 9.0
        i0, i1, j0, j1 = s.local_window(prior[0], prior[1], 1.0)
        ii, jj = np.mgrid[i0:i1, j0:j1]
        dx, dy = x0 + jj * res - prior[0], y0 + ii * res - prior[1]
        q2 = 0.5 * (info[0, 0] * dx * dx + 2.0 * info[0, 1] * dx * dy + info[1, 1] * dy * dy)
        score = full[i0:i1, j0:j1] * (1.0 / (s.q_levels * T)) + np.minimum(q2, cap)
        got = s.tracked_score(obs, theta, prior, info, T, half_width=1.0, prior_cap=cap)
        assert got == pytest.approx(score.min(), rel=1e-12, abs=1e-12)
        best, _ = window_best(s.tables, obs, theta, prior, info, T, 1.0, cap)
        assert best == (i0 + np.argmin(score) // (j1 - j0)) * s.nx + j0 + np.argmin(score) % (
            j1 - j0)
        local = s.local_search(obs, theta, prior, half_width=1.0, refine=False)
        bi, bj = np.unravel_index(np.argmin(full[i0:i1, j0:j1]), (i1 - i0, j1 - j0))
        assert local.cell == (i0 + bi, j0 + bj)
        assert local.error * s.q_levels == pytest.approx(full[i0 + bi, j0 + bj], abs=1e-9)


def test_structure_sizes_are_the_sizes_of_the_chained_groups():
    rng = np.random.default_rng(3)
    pts = np.concatenate([rng.uniform(-3, 3, (60, 2)),
                          np.stack([np.linspace(0.5, 3, 40), np.full(40, 1.0)], axis=1)])
    dist = np.hypot(pts[:, 0], pts[:, 1])
    link, per_m = 0.2, 0.1
    got = structure_sizes(np.ascontiguousarray(pts), dist, link, per_m)
    reach = link + per_m * np.maximum(dist[:, None], dist[None, :])
    near = np.hypot(*(pts[:, None, :] - pts[None, :, :]).transpose(2, 0, 1)) < reach
    group = np.arange(len(pts))
    for _ in range(len(pts)):  # the smallest index each point is chained to
        group = np.minimum(group, np.where(near, group[None, :], len(pts)).min(axis=1))
    want = np.bincount(group, minlength=len(pts))[group]
    assert np.array_equal(got, want)  # exact integers: group sizes
    assert got.max() >= 40  # the line is one structure


def test_evidence_weights_cap_each_structure_at_per_structure_observations():
    rng = np.random.default_rng(5)
    pts = np.concatenate([rng.uniform(-3, 3, (30, 2)),
                          np.stack([np.linspace(0.5, 3, 20), np.full(20, 1.0)], axis=1)])
    dist = np.hypot(pts[:, 0], pts[:, 1])
    base = MatchingParams().weight(dist)
    size = structure_sizes(np.ascontiguousarray(pts), dist, 0.2, 0.1)
    got = evidence_weights(np.ascontiguousarray(pts), dist, base, 0.2, 0.1, 3.0)
    # the numpy expression it replaced, element-wise: a division and a product, each rounded
    # once (2 ulp leaves room for a fused multiply-add)
    np.testing.assert_array_max_ulp(got, base * np.minimum(1.0, 3.0 / size), maxulp=2)
    line = size >= 20
    assert np.isclose(got[line].sum(), 3.0 * base[line].mean(), rtol=0.2)


def test_flattened_weights_are_the_matching_weights():
    rng = np.random.default_rng(6)
    radial = rng.uniform(0, 9, (72, 4))
    radial[rng.random((72, 4)) < 0.4] = np.nan
    spiral = rng.uniform(0, 6, (2, 72))
    p = MatchingParams(range_scale=3.3)
    _f, _a, d, w = flatten_scanlines(radial, spiral, True, 0.2, 8.0, 5.0, p.range_scale)
    assert len(d) > 0
    # element-wise the same few operations: within 4 ulp (a fused multiply-add or two)
    np.testing.assert_array_max_ulp(w, p.weight(d), maxulp=4)
