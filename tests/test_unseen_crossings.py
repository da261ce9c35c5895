"""The scan-line error the other way round (lut_matching.unseen_error): what it charges, and
that it tells a look-alike place from the truth where the paper's error does not."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stages.build_map import tables
from stages.common.map_file import Grid, MapFile
from stages.common.scanlines import NO_HIT_MM
from stages.localize import lut_tables
from stages.localize.lut_kernels import MAX_CROSSINGS
from stages.localize.lut_matching import (
    UNSEEN_REACH_MARGIN_M,
    UNSEEN_TOLERANCE_M,
    MatchingParams,
    Observation,
    unseen_error,
)

PARAMS = MatchingParams()
N = 72


def observation(radial: np.ndarray) -> Observation:
    """Radial crossings (N, MAX_CROSSINGS) m, NaN none, as observations (no spirals)."""
    return Observation.from_scanlines(radial, None, PARAMS, 10.0, 4.0, 0.0)


def table_rows(radial: np.ndarray) -> np.ndarray:
    """The same crossings as table rows (uint16 mm, NO_HIT_MM none)."""
    out = np.full(radial.shape, NO_HIT_MM, np.uint16)
    ok = np.isfinite(radial)
    out[ok] = np.rint(radial[ok] * 1000).astype(np.uint16)
    return out


crossings = st.lists(st.floats(0.3, 6.0), min_size=0, max_size=MAX_CROSSINGS)


def rows_from(lists) -> np.ndarray:
    """(N, MAX_CROSSINGS) sorted crossings at least 2 tolerances apart on each line."""
    r = np.full((N, MAX_CROSSINGS), np.nan)
    for k, values in enumerate(lists):
        kept: list[float] = []
        for v in sorted(values):
            if not kept or v - kept[-1] > 2 * UNSEEN_TOLERANCE_M + 0.01:
                kept.append(v)
        r[k, :len(kept)] = kept
    return r


@settings(max_examples=60, deadline=None)
@given(st.lists(crossings, min_size=N, max_size=N))
def test_every_crossing_seen_costs_nothing(lists):
    r = rows_from(lists)
    assert unseen_error(table_rows(r), observation(r), PARAMS) == pytest.approx(0.0, abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.lists(crossings, min_size=N, max_size=N), st.data())
def test_a_crossing_missed_before_a_seen_one_costs_its_weight(lists, data):
    """Dropping an observed crossing that lies nearer than the farthest one seen on its line
    (by more than the reach margin) adds w(t): the saturated error, as in E."""
    r = rows_from(lists)
    lines = [k for k in range(N) if np.sum(np.isfinite(r[k])) >= 2
             and r[k, 0] < np.nanmax(r[k]) - UNSEEN_REACH_MARGIN_M]
    if not lines:
        return
    k = data.draw(st.sampled_from(lines))
    seen = r.copy()
    t = seen[k, 0]
    seen[k, 0] = np.nan
    before = unseen_error(table_rows(r), observation(r), PARAMS)
    after = unseen_error(table_rows(r), observation(seen), PARAMS)
    assert after - before == pytest.approx(float(PARAMS.weight(t)), rel=1e-3)


@settings(max_examples=60, deadline=None)
@given(st.lists(crossings, min_size=N, max_size=N))
def test_lines_that_saw_nothing_cost_nothing(lists):
    """A line without an observation tells nothing (blocked, or only far floor)."""
    r = rows_from(lists)
    observed = np.full_like(r, np.nan)
    assert unseen_error(table_rows(r), observation(observed), PARAMS) == pytest.approx(
        0.0, abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.lists(crossings, min_size=N, max_size=N), st.floats(-0.2, 0.2))
def test_crossings_within_the_tolerance_count_as_seen(lists, shift):
    """Observed crossings a few centimetres off the table's (a calibration, a cell away)
    are the same line: nothing is unseen."""
    r = rows_from(lists)
    assert unseen_error(table_rows(r), observation(r + shift), PARAMS) == pytest.approx(
        0.0, abs=1e-12)


@pytest.fixture(scope="module")
def map_file(msl2015_map):
    return MapFile(msl2015_map)


@pytest.fixture(scope="module")
def radial_table(map_file):
    return lut_tables.radial_table(map_file)


@settings(max_examples=25, deadline=None)
@given(st.floats(-8.5, 8.5), st.floats(-5.5, 5.5), st.integers(0, N - 1))
def test_rows_are_what_a_robot_at_the_pose_sees(map_file, radial_table, x, y, m):
    """RadialTable.rows at a cell centre and a table heading: the builder's ray casting from
    that position at that heading, the robot's own line k in row k: the same crossings on
    every line, to 2 mm (the table's millimetres), but for any within 5 mm of the scan lines'
    ends, which either build may keep or drop."""
    rt = radial_table
    sl = rt.scanlines
    i, j = rt.grid.cell_of(x, y)
    cx, cy = rt.grid.centre_of(i, j)
    theta = m * sl.angle_step
    one = Grid(origin=(float(cx), float(cy)), resolution=0.1, shape=(1, 1))
    want = tables.radial_table(map_file.field, one, sl, heading=theta)[:, :, 0, 0]
    got = rt.rows((cx, cy, theta))

    def inside(row):
        d = row[row != NO_HIT_MM] / 1000.0
        return d[(d > sl.robot_radius + 0.005) & (d < sl.max_range - 0.005)]

    for k in range(N):
        a, b = inside(got[k]), inside(want[k])
        assert len(a) == len(b), (k, a, b)
        np.testing.assert_allclose(a, b, atol=0.002)


def test_the_penalty_area_look_alike_is_told_from_the_truth(map_file, radial_table):
    """A robot in front of its own penalty area (a rendered recording's start) sees the
    penalty area's front line and side lines; 6.75 m on, on the halfway line, the same
    crossings fit nearly as well under E (a rendered recording's smoother chose it), but the
    centre circle lies where the scan lines saw floor and no line: the unseen crossings
    there cost more than a full-weight observation and a half, at the truth none."""
    rt = radial_table
    fm = map_file.field
    truth = (-5.2, 1.2, 1.136)
    one = Grid(origin=truth[:2], resolution=0.1, shape=(1, 1))
    seen = tables.radial_table(fm, one, rt.scanlines, heading=truth[2])[:, :, 0, 0]
    r = np.where(seen == NO_HIT_MM, np.nan, seen / 1000.0)
    obs = observation(r)
    look_alike = (truth[0] + 6.75, truth[1], truth[2])
    at_truth = rt.unseen_error(obs, truth, PARAMS)
    there = rt.unseen_error(obs, look_alike, PARAMS)
    assert at_truth < 0.5
    assert there > at_truth + 1.5, (at_truth, there)
    assert math.isfinite(there)
