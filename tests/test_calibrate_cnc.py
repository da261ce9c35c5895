"""`fieldloc calibrate omni --from-cnc`: the Carpe Noctem carpet rings (CarpetCalibrator.conf
distances, radii measured in the picture or given by hand)."""

from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages import calibrate
from stages.calibrate import cnc
from stages.common.camera import load_calib

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
CNC = REALDATA / "cnc-calibration"

DIST = np.array([1.0, 1.5, 2.0, 3.0, 4.0])
CENTRE = (148.3, 151.7)


def _mirror_radius(d):
    """Image radius (px) of a floor distance (m) for a made-up convex mirror."""
    return 140.0 * d / (d + 0.9)


def _ring_picture(seed=0, size=300):
    """Rings of 10 cm tape at DIST on grey carpet, three dark spokes, noise, a bright rim."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:size, 0:size].astype(float)
    rho = np.hypot(u - CENTRE[0], v - CENTRE[1])
    d = 0.9 * rho / np.maximum(140.0 - rho, 1e-6)
    img = np.full((size, size), 120.0)
    for di in DIST:
        img[np.abs(d - di) < 0.05] = 240.0
    img[rho >= 133] = 60.0  # the mirror's dark rim
    img[rho >= 137] = 230.0  # glare beyond it
    ang = np.degrees(np.arctan2(-(v - CENTRE[1]), u - CENTRE[0])) % 360
    for a in (30, 150, 270):
        img[(np.abs(((ang - a) + 180) % 360 - 180) < 2.0) & (rho > 20)] = 30.0
    img = cv2.GaussianBlur(img, (0, 0), 0.8) + rng.normal(0, 2.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def _conf_file(tmp_path, mm):
    lines = "".join(f"\tdist{i} = {v}\n" for i, v in enumerate(mm))
    p = tmp_path / "CarpetCalibrator.conf"
    p.write_text(f"[Dist]\n{lines}[!Dist]\n")
    return p


def test_rings_and_centre_found_in_a_picture():
    rings = cnc.detect_rings(_ring_picture())
    assert abs(rings.centre[0] - CENTRE[0]) < 0.3 and abs(rings.centre[1] - CENTRE[1]) < 0.3
    # the tape's middle in floor metres maps to the middle of its image (within 0.3 px here)
    np.testing.assert_allclose(rings.radius_px, _mirror_radius(DIST), atol=0.3)
    assert np.all(rings.sectors >= 6)


def test_from_cnc_pairs_detected_rings_and_explicit_choice(tmp_path):
    img = tmp_path / "CarpetCalibImage.png"
    cv2.imwrite(str(img), _ring_picture())
    conf_file = _conf_file(tmp_path, [0, *(DIST * 1000).astype(int)])
    out = calibrate.from_cnc(None, conf_file, tmp_path / "calib.yaml", rings="detected")
    cam = load_calib(out)
    assert cam.image_size == (300, 300)
    # the calibration maps each ring's true radius to its distance within 1 cm
    np.testing.assert_allclose(cam.distance_of_radius(_mirror_radius(DIST)), DIST, atol=0.01)
    rec = calibrate.report(out)
    assert rec["pairing"] == "detected rings in order" and len(rec["detected_rings"]["rings"]) == 5
    # explicit radii, one ring not seen: four pairs
    r = _mirror_radius(DIST)
    out2 = calibrate.from_cnc(None, conf_file, tmp_path / "c2.yaml",
                              rings=",".join([f"{r[0]:.2f}", "-", *(f"{v:.2f}" for v in r[2:])]))
    assert [p["distance_m"] for p in calibrate.report(out2)["pairs"]] == [1.0, 2.0, 3.0, 4.0]


def test_from_cnc_errors(tmp_path):
    cv2.imwrite(str(tmp_path / "CarpetCalibImage.png"), _ring_picture())
    conf_file = _conf_file(tmp_path, [0, 1000, 1500, 2000, 3000, 4000, 5000])  # one too many
    runner = CliRunner()
    base = ["calibrate", "omni", "--from-cnc", str(conf_file), "-o", str(tmp_path / "c.yaml")]
    res = runner.invoke(cli, base)
    assert res.exit_code == 1 and "needs --rings" in res.output and "shows 5 rings" in res.output
    res = runner.invoke(cli, [*base, "--rings", "detected"])
    assert res.exit_code == 1 and "6 ring distances but 5 rings" in res.output
    res = runner.invoke(cli, [*base, "--rings", "80,70,-,90,95,100"])
    assert res.exit_code == 1 and "must increase" in res.output
    res = runner.invoke(cli, [*base, "--rings", "60,70"])
    assert res.exit_code == 1 and "2 entries for 6 distances" in res.output
    (tmp_path / "bad.conf").write_text("[Dist]\ndist0 = zero\n[!Dist]\n")
    res = runner.invoke(cli, ["calibrate", "omni", "--from-cnc", str(tmp_path / "bad.conf"),
                              "-o", str(tmp_path / "c.yaml"), "--rings", "detected"])
    assert res.exit_code == 1 and "not a number" in res.output
    assert not (tmp_path / "c.yaml").exists()


@pytest.mark.realdata
def test_team_picture_rings_and_both_readings(tmp_path):
    if not CNC.exists():
        pytest.skip("../shared/realdata/cnc-calibration absent")
    rings = cnc.detect_rings(cv2.imread(str(CNC / cnc.IMAGE_NAME)))
    d = cnc.read_distances(CNC / cnc.CONF_NAME)
    assert list(d) == [1, 1.5, 2, 2.5, 3, 4, 5, 6, 7]
    # nine rings, seen in every sector, about (231, 231) (the team's lookup table is zero at
    # (230, 230))
    assert len(rings.radius_px) == 9 and np.all(rings.sectors == 8)
    assert abs(rings.centre[0] - 231) < 1 and abs(rings.centre[1] - 231) < 1
    np.testing.assert_allclose(rings.radius_px, [103.7, 130.0, 146.8, 158.1, 166.2, 177.2,
                                                 184.4, 189.0, 192.2], atol=0.5)
    # paired in order, the radius grows ever slower with distance, as a convex mirror's does
    assert np.all(np.diff(cnc.slopes(rings.radius_px, d)) < 0)
    # the team's later per-pixel table agrees on the rings to 3 m (within 1.1 %), is 3-7 % off
    # at 4 and 5 m, and reads the outermost ring as 6 m, not 7 m: the pairing is a choice
    lookup = np.loadtxt(CNC / "DistanceLookup.txt")
    a = np.radians(np.arange(0, 360, 5))
    at = [np.nanmedian(lookup[np.round(rings.centre[1] - r * np.sin(a)).astype(int),
                             np.round(rings.centre[0] + r * np.cos(a)).astype(int)]) / 1000
          for r in rings.radius_px]
    rel = np.abs(np.array(at) - d) / d
    assert np.all(rel[:5] < 0.012) and np.all(rel[5:7] < 0.08)
    assert abs(at[-1] - 6.0) < 0.15 < abs(at[-1] - 7.0)
