"""fieldloc calibrate omni: fit f(r) from measured pairs, residuals, rejections, CLI."""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages import calibrate
from stages.calibrate import CalibrationError
from stages.common.camera import load_calib
from stages.simulate.omni_renderer import DEFAULT_POLYNOMIAL

CONF = calibrate.confs["default"]
KW = {"centre": (243.0, 237.0), "image_size": (480, 480), "valid_radius": (40.0, 228.0)}


def write_points(path, r, d, header="radius_px,distance_m"):
    lines = [header] + [f"{float(a)!r},{float(b)!r}" for a, b in zip(r, d)]
    path.write_text("\n".join(lines) + "\n")
    return path


def true_distance(r):
    return np.polynomial.polynomial.polyval(np.asarray(r, float), DEFAULT_POLYNOMIAL)


def test_recovers_a_known_polynomial_exactly(tmp_path):
    r = np.linspace(42, 226, 15)
    pts = write_points(tmp_path / "p.csv", r, true_distance(r))
    out = calibrate.main(CONF, pts, tmp_path / "calib.yaml", forward_angle=1.0, mirrored=True,
                         **KW)
    cam = load_calib(out)
    assert cam.kind == "omni"
    assert np.allclose(cam.polynomial, DEFAULT_POLYNOMIAL, rtol=1e-5, atol=1e-9)
    dense = np.linspace(40, 228, 300)
    assert np.abs(cam.distance_of_radius(dense) - true_distance(dense)).max() < 1e-6
    assert cam.centre == KW["centre"] and cam.valid_radius == KW["valid_radius"]
    assert cam.forward_angle == 1.0 and cam.mirrored is True
    rep = calibrate.residual_report(cam, pts)
    assert rep.rms < 1e-8 and rep.max_abs < 1e-8


def test_noisy_pairs_give_small_residuals(tmp_path):
    rng = np.random.default_rng(0)
    r = np.repeat(np.linspace(42, 200, 20), 2)
    d = true_distance(r) * (1 + rng.normal(0, 0.01, len(r)))
    fit = calibrate.fit(CONF, r, d, **{**KW, "valid_radius": (40.0, 200.0)})
    assert 0.002 < fit.rms < 0.05
    assert fit.max_abs >= fit.rms
    assert np.abs(fit.camera.radius_of_distance(1.0) - 117.1) < 2.0


@pytest.mark.parametrize(
    "r, d, vr, message",
    [
        (np.linspace(50, 200, 7), None, (40, 228), "7 pairs, but a degree-5 fit needs at least 8"),
        (np.repeat([60.0, 100, 140], 4), None, (40, 228), "only 3 distinct radii among 12"),
        # a mirror whose floor distance falls again: not a mapping
        (np.linspace(50, 220, 12), "bump", (40, 228), "not increasing between 40 and 228"),
    ],
)
def test_rejections(tmp_path, r, d, vr, message):
    if d is None:
        d = true_distance(r)
    elif d == "bump":
        d = 1.0 + 0.5 * np.sin(np.asarray(r) / 25.0)
    pts = write_points(tmp_path / "p.csv", r, d)
    with pytest.raises(CalibrationError, match=message):
        calibrate.main(CONF, pts, tmp_path / "c.yaml", **{**KW, "valid_radius": vr})
    assert not (tmp_path / "c.yaml").exists()


def test_rejects_bad_files(tmp_path):
    r = np.linspace(50, 200, 10)
    with pytest.raises(CalibrationError, match="expected columns 'radius_px,distance_m'"):
        calibrate.read_points(write_points(tmp_path / "a.csv", r, true_distance(r), "r,d"))
    (tmp_path / "b.csv").write_text("radius_px,distance_m\n50,0.3\n60,abc\n")
    with pytest.raises(CalibrationError, match="line 3"):
        calibrate.read_points(tmp_path / "b.csv")
    (tmp_path / "c.csv").write_text("radius_px,distance_m\n50,-0.3\n")
    with pytest.raises(CalibrationError, match="finite and >= 0"):
        calibrate.read_points(tmp_path / "c.csv")
    with pytest.raises(CalibrationError, match="not found"):
        calibrate.read_points(tmp_path / "missing.csv")
    pts = write_points(tmp_path / "ok.csv", r, true_distance(r))
    with pytest.raises(CalibrationError, match="outside the 480 x 480 image"):
        calibrate.fit(CONF, r, true_distance(r), **{**KW, "centre": (500.0, 10.0)})
    out = tmp_path / "exists.yaml"
    out.write_text("x")
    with pytest.raises(CalibrationError, match="--overwrite"):
        calibrate.main(CONF, pts, out, **KW)


def test_cli_round_trip(tmp_path):
    r = np.linspace(42, 226, 12)
    pts = write_points(tmp_path / "p.csv", r, true_distance(r))
    out = tmp_path / "calib.yaml"
    runner = CliRunner()
    args = ["calibrate", "omni", str(pts), "-o", str(out), "--centre", "243", "237",
            "--image-size", "480", "480", "--valid-radius", "40", "228",
            "--forward-angle-deg", "30"]
    res = runner.invoke(cli, args)
    assert res.exit_code == 0, res.output
    assert "12 pairs, residual RMS 0.00 cm, max 0.00 cm" in res.output
    cam = load_calib(out)
    assert math.isclose(cam.forward_angle, math.radians(30))
    assert np.allclose(cam.polynomial, DEFAULT_POLYNOMIAL, rtol=1e-5, atol=1e-9)
    res = runner.invoke(cli, ["-v"] + args + ["--overwrite"])
    assert res.exit_code == 0, res.output
    rows = [ln for ln in res.output.splitlines() if ln.count(",") == 3]
    assert rows[0] == "radius_px,distance_m,fitted_m,residual_m" and len(rows) == 13
    few = write_points(tmp_path / "few.csv", r[:5], true_distance(r[:5]))
    res = runner.invoke(cli, ["calibrate", "omni", str(few), "-o", str(tmp_path / "x.yaml"),
                              "--centre", "243", "237", "--image-size", "480", "480",
                              "--valid-radius", "40", "228"])
    assert res.exit_code == 1
    errors = [ln for ln in res.output.splitlines() if ln.startswith("fieldloc: error:")]
    assert len(errors) == 1 and "at least 8" in errors[0] and "Traceback" not in res.output
