"""The observation model's unseen term (stages.localize.observation_model's module doc;
Hoffmann, Spranger, Göhring and Jüngel 2005): the field line a pose should have shown in the
frame's view and the pieces of it the frame's lines cover."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from oracles import unseen_lines as oracle

from stages.common.field import load_field
from stages.common.observations import Observations
from stages.localize import mcl_kernels as K
from stages.localize import observation_model as om
from stages.localize.observation_model import TUNING, ObservationModel

# a camera's view: a sector 60 deg wide from 0.5 m to 5 m ahead (m, robot frame)
_A = np.linspace(-math.radians(30), math.radians(30), 13)
SECTOR = np.r_[np.c_[0.5 * np.cos(_A), 0.5 * np.sin(_A)],
               np.c_[5.0 * np.cos(_A[::-1]), 5.0 * np.sin(_A[::-1])]]


@pytest.fixture(scope="module", params=["spl", "kidsize"])
def model(request):
    return ObservationModel.from_field(load_field(request.param))


def _frame(view=SECTOR, ends=np.zeros((0, 4))):
    """A frame of lines given by their ends (m), with the view ``view``."""
    ends = np.asarray(ends, float).reshape(-1, 4)
    d = ends[:, 2:] - ends[:, :2]
    length = np.hypot(d[:, 0], d[:, 1])
    n = np.c_[-d[:, 1], d[:, 0]] / np.maximum(length, 1e-9)[:, None]
    r = np.einsum("ij,ij->i", n, ends[:, :2])
    lines = np.c_[r, np.arctan2(n[:, 1], n[:, 0]), length, np.ones(len(ends))]
    return Observations(lines, ends, np.zeros((0, 5)), np.zeros((0, 3)), view)


def _unseen(model, poses, obs):
    p = np.asarray(poses, float).reshape(-1, 3)
    return model.log_likelihood(p[:, 0], p[:, 1], p[:, 2], obs, parts=True)["unseen"]


@settings(max_examples=40, deadline=None)
@given(x=st.floats(-5.5, 5.5), y=st.floats(-4.0, 4.0), theta=st.floats(-math.pi, math.pi),
       seed=st.integers(0, 2**31 - 1))
def test_the_length_in_view_is_the_pieces_in_view(model, x, y, theta, seed):
    """The compiled count (each line cut with the circle and the view's hull, its pieces
    stepped) equals the reference's piece by piece, for a random view mask in a random
    sector (to 1e-9 m), but for pieces whose
    middle lies within 1e-7 m of a cell's side or the circle (the poses of a whole number of
    cells put the halfway line's pieces there), which either may count."""
    rng = np.random.default_rng(seed)
    r = TUNING.unseen_range
    cells = int(math.ceil(2 * r / om.UNSEEN_CELL))
    mask = rng.random((cells, cells)) < rng.uniform(0.2, 0.9)
    # inside a sector of random direction and width, as a camera's view (the kernel cuts
    # the lines with the set cells' hull)
    centre = (np.arange(cells) + 0.5) * om.UNSEEN_CELL - r
    u, v = np.meshgrid(centre, centre)
    off = np.angle(np.exp(1j * (np.arctan2(v, u) - rng.uniform(-math.pi, math.pi))))
    mask &= np.abs(off) <= rng.uniform(0.1, math.pi)
    mask = mask.astype(np.uint8)
    fast = K.line_in_view((x, y, math.cos(theta), math.sin(theta)), model._samples,
                          om.view_area(mask, r, om.UNSEEN_CELL))
    args = ((x, y, theta), model._samples.points, mask, r, om.UNSEEN_CELL)
    ref = oracle.line_in_view(*args)
    assert abs(fast - ref) <= oracle.line_in_view(*args, edge=1e-7) + 1e-9


def test_the_pieces_are_the_fields_lines(model):
    """The pieces cover the field's lines and arcs: their lengths add up to the lines' (to
    1e-9 m), no piece is longer than the spacing and each middle lies on a line."""
    fm = model.field
    segments = np.asarray(fm.segments, float).reshape(-1, 2, 2)
    total = np.hypot(*(segments[:, 1] - segments[:, 0]).T).sum()
    total += sum(abs(sweep) * rad for _, _, rad, _, sweep in np.asarray(fm.arcs).reshape(-1, 5))
    pts = model._samples.points
    assert pts[:, 2].sum() == pytest.approx(total, abs=1e-9)
    assert pts[:, 2].max() <= om.UNSEEN_SPACING + 1e-12
    assert fm.distance_to_lines(pts[:, :2]).max() < 0.01


def test_no_view_no_term(model):
    """Without a view (features of an older extract, synthetic observations) the term is 0;
    so it is without line ends, whose length in view cannot be told."""
    poses = [[0.5, 0.5, 0.3], [-2.0, 1.0, 2.0]]
    ends = [[1.0, -0.5, 1.0, 0.5]]
    assert np.all(_unseen(model, poses, _frame(view=None, ends=ends)) == 0)  # exact
    obs = _frame(ends=ends)
    assert np.all(_unseen(model, poses, dataclasses.replace(obs, line_ends=None)) == 0)  # exact


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_more_unseen_line_costs_more_and_at_most_the_floor(model, seed):
    """A frame that holds no line: a pose whose view holds more of the field's line scores
    lower (a piece missed is evidence), never below log(floor), and 0 where none is in view."""
    rng = np.random.default_rng(seed)
    poses = np.column_stack([rng.uniform(-5, 5, 60), rng.uniform(-3.5, 3.5, 60),
                             rng.uniform(-math.pi, math.pi, 60)])
    term = _unseen(model, poses, _frame())
    assert np.all(term <= 0) and np.all(term >= math.log(TUNING.unseen_floor) - 1e-12)
    prep = model.prepare(_frame())
    v = prep.view
    # the length in view at each pose's bin centre (where the kernel evaluates the term)
    bx, bt = v.bin_xy, v.bin_heading
    centres = np.column_stack([(np.floor(poses[:, 0] / bx) + 0.5) * bx,
                               (np.floor(poses[:, 1] / bx) + 0.5) * bx,
                               (np.floor((poses[:, 2] + math.pi) / bt) + 0.5) * bt - math.pi])
    a = v.area
    length = np.array([oracle.line_in_view(c, model._samples.points, a.mask, a.r,
                                           1.0 / a.inv_cell) for c in centres])
    assert np.all(term[length == 0] == 0)  # exact
    order = np.argsort(length, kind="stable")
    assert np.all(np.diff(term[order]) <= 1e-12)


@settings(max_examples=30, deadline=None)
@given(x=st.floats(-4.5, 4.5), y=st.floats(-3.0, 3.0), theta=st.floats(-math.pi, math.pi))
def test_a_pose_and_its_mirror_score_alike(model, x, y, theta):
    """On a point-symmetric field a pose and its mirror (x, y, theta) -> (-x, -y, theta + pi)
    show the same line in the same view: their terms are equal (to 1e-9; the bins are
    symmetric about the field's centre, but for a pose on a bin's edge)."""
    bins = (x / om.UNSEEN_BIN_XY, y / om.UNSEEN_BIN_XY, (theta + math.pi) / om.UNSEEN_BIN_HEADING)
    assume(all(abs(b - round(b)) > 1e-6 for b in bins))
    obs = _frame(ends=[[1.0, -0.4, 1.2, 0.6]])
    a, b = _unseen(model, [[x, y, theta], [-x, -y, theta + math.pi]], obs)
    assert a == pytest.approx(b, abs=1e-9)



@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), shape=st.sampled_from(["noise", "sector", "one", "row"]))
def test_the_view_area_holds_every_set_cell(seed, shape):
    """The half-planes the kernel cuts lines with hold every corner of every set cell (the
    hull of the cells' middles, grown), for any mask: noise, a sector, one cell, one row."""
    rng = np.random.default_rng(seed)
    r, cell = 2.0, om.UNSEEN_CELL
    n = int(math.ceil(2 * r / cell))
    mask = np.zeros((n, n), np.uint8)
    if shape == "noise":
        mask[:] = rng.random((n, n)) < rng.uniform(0.001, 0.5)
    elif shape == "sector":
        c = (np.arange(n) + 0.5) * cell - r
        u, v = np.meshgrid(c, c)
        off = np.angle(np.exp(1j * (np.arctan2(v, u) - rng.uniform(-math.pi, math.pi))))
        mask[:] = (np.abs(off) < rng.uniform(0.05, 1.0)) & (np.hypot(u, v) < r)
    elif shape == "one":
        mask[rng.integers(n), rng.integers(n)] = 1
    else:
        row = rng.integers(n)
        mask[row, rng.integers(n // 2):rng.integers(n // 2, n) + 1] = 1
    planes = om.view_area(mask, r, cell).planes
    iy, ix = np.nonzero(mask)
    corners = np.concatenate([np.column_stack([ix + a, iy + b]) for a in (0, 1) for b in (0, 1)])
    corners = corners * cell - r
    assert np.all(corners @ planes[:, :2].T <= planes[:, 2] + 1e-9)


@given(seen=st.floats(0.0, 30.0), q=st.floats(0.05, 0.95))
def test_the_binomial_peak_is_the_grids_largest(seen, q):
    """The bisection finds the largest log C(n, seen) + (n - seen) log(1 - q) over the grid
    n = seen + 0.05 k, k < 800 (to 1e-9; the grid's every value computed by scipy)."""
    from scipy.special import gammaln
    n = seen + 0.05 * np.arange(800)
    grid = gammaln(n + 1) - gammaln(n - seen + 1) + (n - seen) * math.log1p(-q)
    assert K.binomial_peak(seen, math.log1p(-q), 0.05, 800) == pytest.approx(grid.max(),
                                                                               abs=1e-9)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_a_frames_lines_in_view_are_their_pieces_in_view(seed):
    """A frame's seen length (its segments cut into pieces of at most a cell and stepped,
    with the hull's cut) equals the reference's piece by piece (to 1e-9 m), but for pieces
    within 1e-7 m of a cell's side or the circle."""
    rng = np.random.default_rng(seed)
    r, cell = TUNING.unseen_range, om.UNSEEN_CELL
    n = int(math.ceil(2 * r / cell))
    c = (np.arange(n) + 0.5) * cell - r
    u, v = np.meshgrid(c, c)
    mask = ((np.abs(np.arctan2(v, u)) < rng.uniform(0.2, 1.5))
            & (rng.random((n, n)) < rng.uniform(0.3, 1.0))).astype(np.uint8)
    ends = rng.uniform(-2.5, 2.5, (int(rng.integers(1, 6)), 4))
    fast = K.segments_in_view(ends, cell, om.view_area(mask, r, cell))
    pts = om.line_samples(ends.reshape(-1, 2, 2), (), cell).points
    args = ((0.0, 0.0, 0.0), pts, mask, r, cell)
    assert abs(fast - oracle.line_in_view(*args)) <= oracle.line_in_view(*args, edge=1e-7) + 1e-9
