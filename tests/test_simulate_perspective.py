"""`fieldloc simulate perspective`: a KidSize humanoid's head camera on a rendered field."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages.common.camera import load_calib
from stages.common.dataset import open_dataset, read_csv
from stages.common.field import load_field
from stages.common.geometry import field_to_robot
from stages.common.perspective_camera import PerspectiveCamera
from stages.simulate import confs, main, trajectory, walk
from stages.simulate import scene as scene_mod
from stages.simulate.perspective_renderer import PerspectiveRenderer, perturbed_camera

FIELD = load_field("kidsize")


@pytest.fixture(scope="module")
def world():
    """A field without movers and with steady light, rendered with the default imaging
    (noise, Bayer mosaic, blur, vignetting, chromatic aberration)."""
    return scene_mod.build(FIELD, confs["perspective-clean"]["scene"], np.arange(4) / 10.0, 5)


@pytest.fixture(scope="module")
def renderer(world):
    return PerspectiveRenderer(confs["perspective-default"]["perspective"], world, seed=5)


def _line_points_and_normals(field, step=0.04):
    pts, nrm = [], []
    for (x0, y0), (x1, y1) in field.segments:
        length = math.hypot(x1 - x0, y1 - y0)
        t = np.linspace(0, 1, int(length / step) + 1)
        pts.append(np.stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)], 1))
        nrm.append(np.repeat([[-(y1 - y0) / length, (x1 - x0) / length]], len(t), 0))
    for cx, cy, r, a0, sweep in field.arcs:
        a = a0 + np.linspace(0, sweep, int(r * sweep / step) + 1)
        pts.append(np.stack([cx + r * np.cos(a), cy + r * np.sin(a)], 1))
        nrm.append(np.stack([np.cos(a), np.sin(a)], 1))
    return np.concatenate(pts), np.concatenate(nrm)


def _pixels(img, uv):
    ij = np.round(uv).astype(int)
    return img[ij[:, 1], ij[:, 0]].astype(float)  # BGR


def _visible(cam, layers, pose, pitch, roll, pts, near, far):
    rel = field_to_robot(pose, pts)
    dist = np.hypot(*rel.T)
    uv = cam.floor_to_pixel(rel, pitch, roll)
    ok = np.isfinite(uv).all(1) & (dist > near) & (dist < far)
    w, h = cam.image_size
    ok &= (uv[:, 0] > 8) & (uv[:, 0] < w - 9) & (uv[:, 1] > 8) & (uv[:, 1] < h - 9)
    ij = np.round(np.nan_to_num(uv)).astype(int)
    ok &= layers["floor"][np.clip(ij[:, 1], 0, h - 1), np.clip(ij[:, 0], 0, w - 1)]
    return uv[ok]


@pytest.mark.parametrize("pose,pitch,roll", [
    ((-1.0, 0.5, 0.3), 0.45, 0.02),
    ((-3.1, -0.8, 0.9), 0.52, -0.05),
    ((1.2, 2.0, -2.0), 0.40, 0.06),
])
def test_field_lines_are_white_and_the_carpet_beside_them_green(renderer, pose, pitch, roll):
    """Field-line points projected with the camera at the true pose and head angles land on
    white pixels; points 0.3 m beside the lines land on green ones."""
    img, layers = renderer.render_view(pose, pitch, roll, frame=1, return_layers=True)
    cam = renderer.camera
    pts, nrm = _line_points_and_normals(FIELD)
    on = _visible(cam, layers, pose, pitch, roll, pts, 0.3, 2.0)
    beside = np.concatenate([pts + 0.3 * nrm, pts - 0.3 * nrm])
    beside = beside[(FIELD.distance_to_lines(beside) > 0.25) & FIELD.is_on_field(beside, 0.5)]
    off = _visible(cam, layers, pose, pitch, roll, beside, 0.3, 4.0)
    assert len(on) > 30 and len(off) > 100
    b, g, r = _pixels(img, on).T
    white = (np.minimum(b, r) > 0.75 * g) & (g > 110)
    assert white.mean() > 0.9, white.mean()
    b, g, r = _pixels(img, off).T
    green = g > 1.4 * np.maximum(b, r)
    assert green.mean() > 0.95, green.mean()


def test_rendering_is_deterministic_for_a_seed(renderer, world):
    pose = (-1.5, 1.0, -0.4)
    a = renderer.render_view(pose, 0.45, 0.03, frame=2, angular_rate=(0.3, 0.2, 0.0))
    b = renderer.render_view(pose, 0.45, 0.03, frame=2, angular_rate=(0.3, 0.2, 0.0))
    again = PerspectiveRenderer(confs["perspective-default"]["perspective"], world, seed=5)
    c = again.render_view(pose, 0.45, 0.03, frame=2, angular_rate=(0.3, 0.2, 0.0))
    assert a.shape == (480, 752, 3) and a.dtype == np.uint8
    assert np.array_equal(a, b) and np.array_equal(a, c)  # exact integers: uint8 images
    # another frame has other sensor noise; another seed another camera noise bank
    d = renderer.render_view(pose, 0.45, 0.03, frame=3, angular_rate=(0.3, 0.2, 0.0))
    other = PerspectiveRenderer(confs["perspective-default"]["perspective"], world, seed=6)
    e = other.render_view(pose, 0.45, 0.03, frame=2, angular_rate=(0.3, 0.2, 0.0))
    assert not np.array_equal(a, d) and not np.array_equal(a, e)  # exact integers: uint8 images


def test_goal_posts_rise_above_the_field_boundary(renderer):
    """Looking at the opponent goal from the penalty mark: the posts are white vertical bars
    from the floor up past the horizon, into the clutter above the field."""
    pose = (4.5 - 1.5 - 1.2, 0.0, 0.0)
    img, layers = renderer.render_view(pose, 0.35, 0.0, frame=0, return_layers=True)
    cam = renderer.camera
    for px, py in FIELD.goal_posts[FIELD.goal_posts[:, 0] > 0]:
        rel = field_to_robot(pose, [[px, py]])
        foot = cam.floor_to_pixel(rel, 0.35, 0.0)[0]
        top = cam.project(np.array([[*rel[0], 1.0]]), 0.35, 0.0)[0]
        horizon = cam.horizon_row([foot[0]], 0.35, 0.0)[0]
        assert top[1] < horizon < foot[1]
        vs = np.linspace(top[1] + 3, foot[1] - 3, 12)
        uv = np.stack([np.interp(vs, [top[1], foot[1]], [top[0], foot[0]]), vs], 1)
        b, g, r = _pixels(img, uv).T
        assert (np.minimum(np.minimum(b, g), r) > 150).mean() > 0.8
        assert layers["objects"][np.round(uv[:, 1]).astype(int),
                                 np.round(uv[:, 0]).astype(int)].all()


def test_image_corners_are_darker_and_blurrier(renderer):
    """The wide-angle lens' corners are the unreliable part of the image (Schulz et al. 2011,
    §3)."""
    pose = (-1.0, 0.0, 0.0)
    img = renderer.render_view(pose, 0.6, 0.0, frame=0).astype(float)
    clean = renderer.scene_image(pose, 0.6, 0.0, 0)[0]
    grey = img.mean(2)
    centre = grey[200:280, 336:416]
    corner = grey[400:480, 0:80]
    ref = clean.mean(2)
    assert corner.mean() / ref[400:480, 0:80].mean() < 0.8 * centre.mean() / ref[200:280,
                                                                                   336:416].mean()
    assert renderer.vignette[0, 0] < 0.6 and renderer.vignette[240, 376] > 0.99


def test_bayer_demosaicing_leaves_colour_fringes_at_sharp_edges(renderer):
    """On the carpet (only green and white in the scene) the demosaiced image holds orange or
    cyan pixels next to the lines' sharp edges (the artefacts Schulz et al. (2011) filters)."""
    def fringes(im, carpet):
        b, g, r = (im[..., k].astype(float) for k in range(3))
        orange = (r > g + 20) & (r > b + 30)
        cyan = (b > r + 40) & (g > r + 40) & (b > 0.8 * g)
        return int(((orange | cyan) & carpet).sum())

    clean = PerspectiveRenderer(confs["perspective-clean"]["perspective"], renderer.scene, 5)
    mosaic = plain = 0
    for pose in ((-1.0, 0.5, 0.3), (-2.0, -0.5, 0.0)):  # two views: about 30 and 250
        img, layers = renderer.render_view(pose, 0.45, 0.0, frame=0, return_layers=True)
        carpet = cv2.erode(layers["floor"].astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
        mosaic += fringes(img, carpet)
        plain += fringes(clean.render_view(pose, 0.45, 0.0, frame=0), carpet)
    assert mosaic > 100
    assert plain < mosaic / 4


def test_walk_enters_at_the_touch_line_and_walks_at_humanoid_speed():
    conf = confs["perspective-default"]
    tconf = conf["trajectory"]
    assert tconf["start"] == "touchline"
    hx, hy = FIELD.length / 2, FIELD.width / 2
    for seed in range(4):
        start = walk.touchline_start(FIELD, tconf["margin"], np.random.default_rng(seed))
        assert -hx < start[0] < 0  # own half
        assert abs(abs(start[1]) - hy) <= 0.35  # at a touch line
        assert -math.copysign(1, start[1]) * math.sin(start[2]) > 0.99  # facing into the field
        path = trajectory.generate(FIELD, 600, conf["rate_hz"], {**tconf, "start": start},
                                   np.random.default_rng([seed, 1]))
        assert np.allclose(path.poses[0, :2], start[:2])
        v = path.speeds
        assert 0.15 < np.median(v) < 0.26 and v.max() < 0.27
        assert np.all(np.abs(path.poses[:, 0]) <= hx) and np.all(np.abs(path.poses[:, 1]) <= hy)
        turned = np.abs(np.diff(np.unwrap(path.poses[:, 2]))).sum()
        assert turned > math.pi  # it turns (within a minute), not only straight lines


def test_head_wobbles_with_the_walk_and_is_measured_with_noise():
    t = np.arange(300) / 10.0
    walking = np.stack([-2.0 + 0.2 * t, np.full_like(t, -2.7), np.zeros_like(t)], 1)
    standing = np.stack([np.full_like(t, -2.0), np.full_like(t, -2.7), np.zeros_like(t)], 1)
    cfg = {**walk.HEAD_DEFAULTS, "tilt": 0.0, "jitter": 0.0}
    w = walk.head_motion(t, walking, 0.45, 0.0, cfg, np.random.default_rng(0))
    s = walk.head_motion(t, standing, 0.45, 0.0, cfg, np.random.default_rng(0))
    assert 0.015 < w["roll"].std() < 0.05 and np.abs(w["roll"]).max() < 0.1
    assert np.abs(w["pitch"] - 0.45).max() < 0.05
    assert s["roll"].std() < 0.003  # no sway while standing still
    noise = walk.HEAD_DEFAULTS["measurement_noise"]
    err = w["measured_pitch"] - w["pitch"]
    assert 0.5 * noise < err.std() < 1.5 * noise


def test_perturbed_calibration_shifts_the_principal_point_and_scales_focal_lengths():
    cam = PerspectiveCamera()
    bad = perturbed_camera(cam, {"centre_shift": [3.0, -2.0], "scale": 1.05})
    assert (bad.cx, bad.cy) == (cam.cx + 3.0, cam.cy - 2.0)
    assert bad.fx == pytest.approx(cam.fx * 1.05) and bad.height == cam.height


def test_simulate_writes_a_perspective_dataset(tmp_path):
    conf = {**confs["perspective-default"], "frames": 3, "seed": 2}
    out = main(conf, "kidsize", tmp_path / "kid")
    ds = open_dataset(out)
    assert len(ds.images) == 3
    assert cv2.imread(str(ds.images[0])).shape == (480, 752, 3)
    cam = load_calib(ds.calib_path)
    assert isinstance(cam, PerspectiveCamera)
    assert cam.height == conf["perspective"]["height"]
    assert cam.pitch == conf["perspective"]["pitch"]
    head = read_csv(out / "head.csv", "head")
    truth_head = read_csv(out / "head_truth.csv", "head")
    assert np.allclose(head["stamp"], ds.stamps)
    assert np.abs(head["pitch"] - truth_head["pitch"]).max() < 0.05
    truth = read_csv(out / "truth.csv", "truth")
    assert truth["x"][0] < 0 and abs(abs(truth["y"][0]) - FIELD.width / 2) <= 0.35
    for kind in ("odometry", "imu", "frames"):
        assert len(read_csv(out / f"{kind}.csv", kind)["stamp" if kind != "frames"
                                                        else "name"]) == 3


def test_cli_simulate_perspective(tmp_path):
    runner = CliRunner()
    out = tmp_path / "kid"
    res = runner.invoke(cli, ["simulate", "perspective", "--field", "kidsize", "-o", str(out),
                              "--frames", "2", "--seed", "3", "--camera-height", "0.5",
                              "--pitch-deg", "30"])
    assert res.exit_code == 0, res.output
    cam = load_calib(out / "calib.yaml")
    assert cam.height == 0.5 and cam.pitch == pytest.approx(math.radians(30))
    # the other defaults are the stage's preset
    ref = confs["perspective-default"]["perspective"]
    assert cam.fx == ref["intrinsics"]["fx"] and list(cam.distortion) == ref["distortion"]
    res = runner.invoke(cli, ["simulate", "perspective", "--field", "nowhere", "-o",
                              str(tmp_path / "x"), "--frames", "1"])
    assert res.exit_code == 1 and "unknown field preset" in res.output


def test_nao_preset_renders_the_top_camera_on_an_spl_field(tmp_path):
    """`simulate perspective --preset perspective-nao`: 640 x 480 frames through HULKs' NAO
    intrinsics (no wide-angle lens), the camera about 0.45 m high; the hall's sun patches and
    shadows, white balls and the NAOs' white legs are in the world."""
    runner = CliRunner()
    out = tmp_path / "nao"
    res = runner.invoke(cli, ["-q", "simulate", "perspective", "--preset", "perspective-nao",
                              "--field", "spl", "-o", str(out), "--frames", "2", "--seed", "1"])
    assert res.exit_code == 0, res.output
    cam = load_calib(out / "calib.yaml")
    assert cam.image_size == (640, 480) and (cam.fx, cam.fy) == (608.0, 609.6)
    assert np.all(cam.distortion == 0) and abs(cam.height - 0.45) < 0.01
    assert cv2.imread(str(out / "images" / "000000.png")).shape == (480, 640, 3)
    conf = confs["perspective-nao"]
    field = load_field("spl")
    world = scene_mod.build(field, conf["scene"], np.arange(3) / 10.0, 1)
    # sun patches brighten and shadows darken the floor's light beyond the lamps' range
    base = scene_mod.build(field, {**conf["scene"], "sun_patches": 0, "shadows": 0},
                           np.arange(3) / 10.0, 1)
    ratio = world.albedo[..., 1].astype(float) / np.maximum(base.albedo[..., 1], 1)
    assert np.percentile(ratio, 99.5) > 1.5 and np.percentile(ratio, 0.5) < 0.8
    movers = [c for parts in world.movers_at(0) for c in parts]
    white = [c for c in movers if min(c.bgr) > 200]
    assert any(c.kind == "ball" for c in white)
    assert sum(c.kind == "body" and c.z0 > 0 and c.z1 < 0.4 for c in white) >= 2  # legs


def test_texture_sampling_is_bilinear_on_the_32nd_texel_grid():
    """fixed_remap samples where cv2.remap of OpenCV 4.x does (coordinates rounded to 1/32
    texel), under any OpenCV: uint8 textures within one grey level of the bilinear oracle
    (OpenCV's integer weights), float32 ones within float32 rounding; points outside the
    texture take the border value. The maps are OpenCV's own fixed-point pair (integers)."""
    import sys
    from pathlib import Path

    from stages.common.fixed_remap import fixed_maps, remap_linear

    sys.path.insert(0, str(Path(__file__).parent))
    from oracles.perspective_sampling import bilinear

    rng = np.random.default_rng(3)
    mx = rng.uniform(-3, 43, (40, 60)).astype(np.float32)
    my = rng.uniform(-3, 33, (40, 60)).astype(np.float32)
    xy, frac = fixed_maps(mx, my)
    ref_xy, ref_frac = cv2.convertMaps(mx, my, cv2.CV_16SC2)
    np.testing.assert_array_equal(xy, ref_xy)  # exact integers: int16 texels
    np.testing.assert_array_equal(frac, ref_frac)  # exact integers: uint16 indices
    qx, qy = np.rint(mx * 32.0) / 32.0, np.rint(my * 32.0) / 32.0
    tex8 = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
    got = remap_linear(tex8, mx, my, cv2.BORDER_CONSTANT, (7, 7, 7)).astype(float)
    want8 = np.stack([bilinear(tex8[..., c], qx, qy, 7.0) for c in range(3)], axis=-1)
    np.testing.assert_allclose(got, want8, rtol=0, atol=1.0)
    texf = rng.uniform(-1, 50, (30, 40, 4)).astype(np.float32)
    got = remap_linear(texf, mx, my, cv2.BORDER_CONSTANT, (50.0, 1.0, 0.0, 0.0))
    want = np.stack([bilinear(texf[..., c], qx, qy, b) for c, b in enumerate((50, 1, 0, 0))],
                    axis=-1)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
    # the exact coordinates would be another sampling: the 1/32 rounding is visible
    exact = np.stack([bilinear(tex8[..., c], mx, my, 7.0) for c in range(3)], axis=-1)
    assert np.abs(exact - want8).max() > 2.0
