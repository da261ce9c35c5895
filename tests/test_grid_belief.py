"""lut's whole-field belief (``belief: grid``, stages.localize.grid_belief): the filter's
properties, and a rendered run through the command a user runs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from fieldloc_cli.main import cli
from stages.localize.grid_belief import GridBelief, reachable_prior

XS = np.arange(-3.0, 3.0 + 1e-9, 0.1)
YS = np.arange(-2.0, 2.0 + 1e-9, 0.1)


def _belief(kidnap=0.0):
    return GridBelief(XS, YS, np.zeros((len(YS), len(XS))), kidnap)


def _peaked(b, x, y, sigma=0.15):
    b.p = np.exp(-((b.X - x) ** 2 + (b.Y - y) ** 2) / (2 * sigma ** 2))
    b.p /= b.p.sum()


def _mean(b):
    return float(np.sum(b.p * b.X)), float(np.sum(b.p * b.Y))


@settings(max_examples=40, deadline=None)
@given(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(0.0, 0.2))
def test_predict_moves_the_belief_by_the_step_and_keeps_its_mass(dx, dy, sigma):
    b = _belief()
    _peaked(b, 0.3, -0.2)
    m0 = _mean(b)
    b.predict((dx, dy), sigma)
    assert math.isclose(b.p.sum(), 1.0, rel_tol=1e-9)
    m1 = _mean(b)
    # a peak far from the grid's edges moves by the step (bilinear shift: within 1 mm)
    assert abs(m1[0] - m0[0] - dx) < 1e-3 and abs(m1[1] - m0[1] - dy) < 1e-3


def test_predict_spreads_by_the_noise_and_keeps_the_kidnap_floor():
    b = _belief(kidnap=1e-4)
    _peaked(b, 0.0, 0.0, sigma=0.1)
    var0 = float(np.sum(b.p * b.X ** 2))
    b.predict((0.0, 0.0), 0.2)
    var1 = float(np.sum(b.p * b.X ** 2))
    # a Gaussian blur adds its variance (the kidnap's uniform share adds its own)
    uniform = float(np.mean(b.X ** 2))
    expect = (1 - 1e-4) * (var0 + 0.2 ** 2) + 1e-4 * uniform
    assert math.isclose(var1, expect, rel_tol=0.03)
    assert b.p.min() >= 1e-4 / b.p.size * (1 - 1e-9)


@settings(deadline=None)
@given(st.floats(-50, 50), st.floats(0.5, 20))
def test_update_ignores_a_constant_added_to_the_error(c, temperature):
    rng = np.random.default_rng(0)
    e = rng.uniform(0, 10, (len(YS), len(XS)))
    a, b = _belief(), _belief()
    a.update(e, temperature)
    b.update(e + c, temperature)
    np.testing.assert_allclose(a.p, b.p, rtol=1e-9, atol=1e-300)
    flat = _belief()
    flat.update(np.full_like(e, c), temperature)
    np.testing.assert_allclose(flat.p, _belief().p, rtol=1e-12)


def test_modes_are_separated_and_ranked():
    b = _belief()
    _peaked(b, -1.5, 0.5, 0.1)
    p1 = b.p.copy()
    _peaked(b, 1.5, -0.5, 0.1)
    b.p = 0.7 * p1 + 0.3 * b.p
    modes = b.modes(4, 1.0, 0.4)
    assert math.hypot(modes[0][0] + 1.5, modes[0][1] - 0.5) < 0.06
    assert math.hypot(modes[1][0] - 1.5, modes[1][1] + 0.5) < 0.06
    assert modes[0][2] == pytest.approx(0.7, abs=0.01) and modes[1][2] == pytest.approx(
        0.3, abs=0.01)
    assert all(math.hypot(a[0] - c[0], a[1] - c[1]) >= 1.0
               for k, a in enumerate(modes) for c in modes[:k])


def test_reachable_prior_keeps_robots_out_of_the_goals():
    from stages.common.field import load_field

    fm = load_field("msl-2015")
    xs = np.arange(-10.0, 10.0 + 1e-9, 0.1)
    ys = np.arange(-7.0, 7.0 + 1e-9, 0.1)
    lp = reachable_prior(fm, xs, ys, 1e-3)
    X, Y = np.meshgrid(xs, ys)
    in_goal = (np.abs(X) > fm.length / 2 + 0.3) & (np.abs(Y) < 0.9)
    np.testing.assert_allclose(lp[in_goal], math.log(1e-3), rtol=1e-12)
    np.testing.assert_allclose(lp[np.abs(X) < fm.length / 2], 0.0, atol=1e-12)
    out = lp < 0.5 * math.log(1e-3)
    assert (out == out[::-1, ::-1]).all()  # the field's 180 deg symmetry


def test_grid_belief_through_the_cli(omni_default_rendered, msl2015_map, tmp_path):
    from stages.common.poses_file import read_poses

    ds, feats = omni_default_rendered
    out = tmp_path / "grid.h5"
    res = CliRunner().invoke(cli, ["localize", str(ds), "--map", str(msl2015_map),
                                   "--features", str(feats), "--preset", "grid",
                                   "-o", str(out)])
    assert res.exit_code == 0, res.output
    c, attrs = read_poses(out)
    assert attrs["conf"]["belief"] == "grid"
    truth = np.loadtxt(ds / "truth.csv", delimiter=",", skiprows=1)
    ok = ~c["failed"]
    err = np.hypot(c["x"] - truth[:, 1], c["y"] - truth[:, 2])
    assert (c["mode"][ok] == "grid").all()
    assert ((c["confidence"] >= 0) & (c["confidence"] <= 1 + 1e-6)).all()
    # the 40 busy frames of seed 3 (the lut tracks: every frame within 40 cm, as here)
    assert np.mean(ok & (err <= 0.4)) >= 0.9, np.round(err, 2)
    assert not np.any(c["accepted"] & (err > 1.0))
    h = c["hypotheses"]
    assert np.allclose(h[ok, 0, 3], c["confidence"][ok], atol=1e-6)


@pytest.mark.parametrize("args, message", [
    (["--heading", "histogram"], "field-aligned heading"),
    (["--independent"], "does not localise frames independently"),
    (["-c", "belief=cells"], "belief must be auto, tracks or grid"),
])
def test_grid_belief_refuses_what_it_cannot_do(omni_default_rendered, msl2015_map, tmp_path,
                                               args, message):
    ds, feats = omni_default_rendered
    res = CliRunner().invoke(cli, ["localize", str(ds), "--map", str(msl2015_map),
                                   "--features", str(feats), "--preset", "grid",
                                   "-o", str(tmp_path / "x.h5"), *args])
    assert res.exit_code != 0
    assert message in res.output and "Traceback" not in res.output
    assert not (tmp_path / "x.h5").exists()
