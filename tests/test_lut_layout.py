"""The memory layout of the table search's arrays (lut_search.py module doc): the error lookup
and its min-pooled copy hold each row's cells in 8 x 8 blocks, the radial table in metres a
cell's crossings side by side. Each is checked against the map's own millimetre tables,
computed here without the search's code, and every window sum against a plain numpy sum."""

from __future__ import annotations

import numpy as np
import pytest

from stages import build_map
from stages.common.map_file import MapFile
from stages.common.scanlines import NO_HIT_MM
from stages.localize.lut_kernels import (
    TILE,
    evidence_weights,
    flatten_scanlines,
    structure_sizes,
    tiled_sum,
)
from stages.localize.lut_search import MatchingParams, Observation, TableSearch


@pytest.fixture(scope="module")
def search(tmp_path_factory):
    path = build_map.main({"resolution": 0.2}, "kidsize",
                          tmp_path_factory.mktemp("layout") / "kid.map.h5")
    with MapFile(path) as mf:
        yield TableSearch(mf, MatchingParams(), cache=False)


def _rows_of_cells(tiled: np.ndarray, ny: int, nx: int) -> np.ndarray:
    """The tiled rows (rows, blocks * TILE^2) back as rows of cells (rows, ny, nx)."""
    rows = tiled.shape[0]
    nty, ntx = -(-ny // TILE), -(-nx // TILE)
    blocks = tiled.reshape(rows, nty, ntx, TILE, TILE).transpose(0, 1, 3, 2, 4)
    return blocks.reshape(rows, nty * TILE, ntx * TILE)[:, :ny, :nx]


def test_the_grid_is_not_a_whole_number_of_blocks(search):
    # so that the padding and the partial blocks at the edges are exercised below
    assert search.ny % TILE and search.nx % TILE


def test_the_tiled_lookup_holds_each_cells_quantised_error(search):
    s, p = search, search.params
    cells = _rows_of_cells(s.error_lookup, s.ny, s.nx).reshape(s.lookup_rows_total, -1)
    mm = s.radial_mm.astype(np.float64) * 1e-3  # (line, crossing, cell)
    none = s.radial_mm == NO_HIT_MM
    rng = np.random.default_rng(0)
    for k, b in zip(rng.integers(0, s.n_angles, 20), rng.integers(0, s.nb_radial, 20)):
        d = b * p.distance_bin
        e = np.where(none[k], 1e3, np.abs(mm[k] - d)).min(axis=0)
        want = np.rint(s.q_levels * p.weight(d) * e**2 / (p.c**2 + e**2))
        got = cells[k * s.nb_radial + b].astype(np.float64)
        assert np.abs(got - want).max() <= 1  # float32 arithmetic in the build


def test_the_radial_table_in_metres_holds_a_cells_crossings_side_by_side(search):
    s = search
    want = np.where(s.radial_mm == NO_HIT_MM, 1e3, s.radial_mm * 1e-3).transpose(0, 2, 1)
    assert s.radial_m.shape == (s.n_angles, s.ncell, 4)
    assert np.allclose(s.radial_m, want, rtol=0, atol=1e-6)


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


@pytest.mark.parametrize("coarse", [False, True])
def test_a_window_sum_is_the_sum_of_the_observations_rows(search, coarse):
    s = search
    lookup = s.coarse_lookup if coarse else s.error_lookup
    ny, nx = s.coarse_shape if coarse else (s.ny, s.nx)
    ntx = s.coarse_ntx if coarse else s.ntx
    cells = _rows_of_cells(lookup, ny, nx)
    rng = np.random.default_rng(2)
    n = 60
    obs = Observation(family=rng.integers(0, 3, n), angle_index=rng.integers(0, s.n_angles, n),
                      distance=rng.uniform(0.3, 2.0, n), weight=np.ones(n))
    m = 11
    rows = s.lookup_rows(obs, m)
    full = cells[rows].astype(np.int64).sum(axis=0)
    windows = [(0, ny, 0, nx), (1, 2, 3, 4), (ny - 3, ny, nx - 9, nx)]
    for _ in range(10):
        i0, j0 = rng.integers(0, ny - 1), rng.integers(0, nx - 1)
        windows.append((i0, rng.integers(i0 + 1, ny + 1), j0, rng.integers(j0 + 1, nx + 1)))
    for i0, i1, j0, j1 in windows:
        out = np.empty((i1 - i0, j1 - j0), np.uint16)
        tiled_sum(lookup, *s._row_arrays(obs, m), int(i0), int(i1), int(j0), int(j1), ntx, out)
        assert np.array_equal(out, full[i0:i1, j0:j1])  # exact integers: uint16 sums


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
