"""Crossing association tables (Schulz et al. 2011, section 5.1): stages.common.crossing_tables."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from stages.common.crossing_tables import (
    L_ORIENTATIONS,
    crossing_association_tables,
    l_orientation_bin,
)
from stages.common.field import load_field
from stages.common.map_file import Grid


def _brute_force(fm, x, y, kind, orientation_bin=None):
    """Index of the closest crossing of ``kind`` (and L orientation set) by a plain search."""
    best, best_d = -1, math.inf
    for k, (p, t, o) in enumerate(zip(fm.crossings, fm.crossing_types,
                                      fm.crossing_orientation)):
        if t != kind:
            continue
        if orientation_bin is not None:
            d_ang = [abs(math.remainder(o - c, 2 * math.pi)) for c in L_ORIENTATIONS]
            if int(np.argmin(d_ang)) != orientation_bin:
                continue
        d = math.hypot(p[0] - x, p[1] - y)
        if d < best_d - 1e-12:
            best, best_d = k, d
    return best, best_d


@pytest.mark.parametrize("field", ["kidsize", "msl-2015"])
def test_tables_match_brute_force_nearest(field):
    fm = load_field(field)
    grid = Grid.around(fm, fm.border, 0.1)
    tabs = crossing_association_tables(fm, grid)
    lut_l, attrs_l = tabs["crossing_lut_L"]
    lut_t, _ = tabs["crossing_lut_T"]
    ny, nx = grid.shape
    assert lut_l.shape == (4, ny, nx) and lut_l.dtype == np.int16
    assert lut_t.shape == (ny, nx) and lut_t.dtype == np.int16
    assert np.allclose(attrs_l["orientations"], np.radians([45, 135, 225, 315]))
    rng = np.random.default_rng(5)
    cells = np.stack([rng.integers(0, ny, 300), rng.integers(0, nx, 300)], axis=1)
    for i, j in cells:
        x, y = grid.centre_of(i, j)
        for b in range(4):
            want, want_d = _brute_force(fm, x, y, "L", b)
            got = int(lut_l[b, i, j])
            # ties (equidistant crossings) may resolve either way; the distance must agree
            got_d = math.hypot(*(fm.crossings[got] - (x, y)))
            assert fm.crossing_types[got] == "L"
            assert int(l_orientation_bin(fm.crossing_orientation[got])) == b
            assert got_d == pytest.approx(want_d, abs=1e-9), (x, y, b, got, want)
        want, want_d = _brute_force(fm, x, y, "T")
        got = int(lut_t[i, j])
        assert fm.crossing_types[got] == "T"
        assert math.hypot(*(fm.crossings[got] - (x, y))) == pytest.approx(want_d, abs=1e-9)


def test_every_l_set_and_every_t_is_used_on_kidsize():
    """Each of the four L sets holds the field's L crossings of that orientation, and every
    crossing is the answer for the cells around it."""
    fm = load_field("kidsize")
    grid = Grid.around(fm, fm.border, 0.1)
    tabs = crossing_association_tables(fm, grid)
    lut_l, lut_t = tabs["crossing_lut_L"][0], tabs["crossing_lut_T"][0]
    for k, (p, t, o) in enumerate(zip(fm.crossings, fm.crossing_types,
                                      fm.crossing_orientation)):
        i, j = grid.cell_of(p[0], p[1])
        if t == "L":
            assert lut_l[int(l_orientation_bin(o)), i, j] == k
        elif t == "T":
            assert lut_t[i, j] == k
    # kidsize: 12 L crossings, three per orientation set; 10 T crossings
    for b in range(4):
        assert len(np.unique(lut_l[b])) == 3
    assert len(np.unique(lut_t)) == 10


def test_no_crossing_of_a_kind_is_minus_one():
    fm = load_field("kidsize")
    types = np.array(["X" if t == "T" else t for t in fm.crossing_types])
    # keep only the L crossings of the 45 deg set
    keep_l = (types == "L") & (l_orientation_bin(fm.crossing_orientation) == 0)
    types = np.where((types == "L") & ~keep_l, "X", types)
    fm2 = dataclasses.replace(fm, crossing_types=types)
    grid = Grid.around(fm2, fm2.border, 0.25)
    tabs = crossing_association_tables(fm2, grid)
    lut_l, lut_t = tabs["crossing_lut_L"][0], tabs["crossing_lut_T"][0]
    assert np.all(lut_t == -1)
    assert np.all(lut_l[1:] == -1)
    assert np.all(lut_l[0] >= 0)


def test_orientation_bins():
    deg = np.array([0.0, 10, 45, 89.9, 90.1, 135, 180, 225, 269, 271, 315, 359, -45, 405])
    assert list(l_orientation_bin(np.radians(deg))) == [0, 0, 0, 0, 1, 1, 2, 2, 2, 3, 3, 3,
                                                          3, 0]
