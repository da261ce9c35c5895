"""fieldloc simulate omni: dataset contract, determinism, trajectory, sensors, and that the
rendered lines sit where the written calibration says."""

from __future__ import annotations

import copy
import math

import cv2
import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages import simulate
from stages.common.camera import load_calib
from stages.common.conf import resolve_conf
from stages.common.dataset import open_dataset, read_csv
from stages.common.errors import FieldlocError
from stages.common.field import load_field
from stages.common.geometry import compose, field_to_robot, wrap_angle
from stages.simulate import sensors, trajectory
from stages.simulate.omni_renderer import DEFAULT_POLYNOMIAL, TEAM_MIRROR_POLYNOMIAL


def small_conf(preset="omni-default", frames=4, seed=3, **changes):
    conf = copy.deepcopy(simulate.confs[preset])
    conf["frames"] = frames
    conf["seed"] = seed
    conf["scene"]["texture_resolution"] = 0.02  # coarser world texture: faster tests
    for k, v in changes.items():
        conf[k] = v
    return conf


@pytest.fixture(scope="module")
def spl():
    return load_field("spl")


@pytest.fixture(scope="module")
def msl():
    return load_field("msl-2015")


# ---------------------------------------------------------------------------- dataset


def test_dataset_folder_is_complete_and_deterministic(tmp_path, spl):
    a = simulate.main(small_conf(), spl, tmp_path / "a")
    b = simulate.main(small_conf(), spl, tmp_path / "b")
    c = simulate.main(small_conf(seed=4), spl, tmp_path / "c")
    ds = open_dataset(a)
    assert ds.names == [f"{i:06d}" for i in range(4)]
    assert np.allclose(ds.stamps, np.arange(4) / simulate.confs["omni-default"]["rate_hz"])
    cam = ds.camera()
    assert cam.kind == "omni" and cam.image_size == (480, 480)
    for kind in ("odometry", "imu", "truth"):
        assert len(ds.optional(kind)["stamp"]) == 4
    img = cv2.imread(str(ds.images[0]))
    assert img.shape == (480, 480, 3)
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    for rel in files:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    assert (a / "images/000000.png").read_bytes() != (c / "images/000000.png").read_bytes()
    assert (a / "truth.csv").read_bytes() != (c / "truth.csv").read_bytes()
    # nothing left beside the dataset folders
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "b", "c"]


def test_refuses_non_empty_folder_unless_overwrite(tmp_path, spl):
    out = tmp_path / "data"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(FieldlocError, match="not empty"):
        simulate.main(small_conf(frames=1), spl, out)
    assert (out / "keep.txt").exists()
    # --overwrite replaces only a dataset simulate made, never a user's folder
    with pytest.raises(FieldlocError, match="not a dataset made by fieldloc simulate"):
        simulate.main(small_conf(frames=1), spl, out, overwrite=True)
    assert (out / "keep.txt").read_text() == "mine"
    (out / "keep.txt").unlink()
    simulate.main(small_conf(frames=1), spl, out)
    (out / "features.h5").write_text("derived")  # what the pipeline adds to a dataset
    # ... is never deleted by replacing the dataset: the user moves it out first
    with pytest.raises(FieldlocError, match="features.h5, which simulate did not write"):
        simulate.main(small_conf(frames=1), spl, out, overwrite=True)
    assert (out / "features.h5").read_text() == "derived"
    (out / "features.h5").unlink()
    simulate.main(small_conf(frames=1), spl, out, overwrite=True)
    assert (out / "images/000000.png").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data"]
    empty = tmp_path / "empty"
    empty.mkdir()
    simulate.main(small_conf(frames=1), spl, empty)  # an empty folder is fine


def test_calib_error_perturbs_only_what_is_written(tmp_path, spl):
    conf = small_conf(frames=1)
    conf["calib_error"] = {"centre_shift": [3.0, -2.0], "scale": 1.05, "distance_error": 0.0}
    out = simulate.main(conf, spl, tmp_path / "d")
    written = load_calib(out / "calib.yaml")
    true = yaml.safe_load((out / "simulation.yaml").read_text())["true_camera"]
    assert written.centre == pytest.approx((true["centre"][0] + 3.0, true["centre"][1] - 2.0))
    assert np.allclose(written.polynomial, np.asarray(true["polynomial"]) * 1.05)


def test_team_calibration_is_off_by_its_distance_error():
    """omni-default writes what a team's mirror table gives: f(r) fitted to radii read off with
    a smooth random error, placing the floor `distance_error` off (rms over the table's floor),
    increasing, drawn from the seed; omni-clean writes the true camera."""
    from stages.simulate.omni_renderer import camera_from_conf, perturbed_camera

    cam = camera_from_conf(simulate.confs["omni-default"]["omni"])
    ce = simulate.confs["omni-default"]["calib_error"]
    assert ce["distance_error"] > 0
    a, b, c = (perturbed_camera(cam, ce, rng=np.random.default_rng(s)) for s in (1, 1, 2))
    assert np.array_equal(a.polynomial, b.polynomial)  # exact same-run: one seed twice
    assert not np.allclose(a.polynomial, c.polynomial)
    d = np.linspace(float(cam.distance_of_radius(cam.valid_radius[0])), ce["table_range"], 300)
    for w in (a, c):
        err = w.distance_of_radius(cam.radius_of_distance(d)) - d
        assert np.sqrt(np.mean(err**2)) == pytest.approx(ce["distance_error"], rel=0.05)
        assert np.abs(err).max() < 4 * ce["distance_error"]
        rr = np.linspace(*w.valid_radius, 500)
        assert np.all(np.diff(w.distance_of_radius(rr)) > 0)
        # the written floor ends at the table's last mark, as a team's calibration does
        assert w.distance_of_radius(w.valid_radius[1]) == pytest.approx(ce["table_range"],
                                                                        abs=0.1)
        assert w.centre == cam.centre and w.forward_angle == cam.forward_angle
    clean = perturbed_camera(cam, simulate.confs["omni-clean"]["calib_error"],
                             rng=np.random.default_rng(1))
    assert np.array_equal(clean.polynomial, cam.polynomial)  # exact same-run: a copy
    assert clean.valid_radius == cam.valid_radius
    with pytest.raises(FieldlocError, match="distance_error"):
        perturbed_camera(cam, {**ce, "distance_error": 0.7}, rng=np.random.default_rng(1))


def test_omni_default_dataset_states_a_team_calibration(tmp_path, spl):
    out = simulate.main(small_conf(frames=1), spl, tmp_path / "d")
    written = load_calib(out / "calib.yaml")
    true = yaml.safe_load((out / "simulation.yaml").read_text())["true_camera"]
    assert not np.allclose(written.polynomial, true["polynomial"])
    assert written.valid_radius[1] < true["valid_radius"][1]
    other = simulate.main(small_conf(frames=1, seed=4), spl, tmp_path / "e")
    assert not np.allclose(load_calib(other / "calib.yaml").polynomial, written.polynomial)


# ---------------------------------------------------------------------------- trajectory


@pytest.mark.parametrize("kind", trajectory.PATH_KINDS)
@pytest.mark.parametrize("heading", ["free", "along"])
def test_trajectory_stays_on_field_with_speeds_in_range(msl, kind, heading):
    conf = {**trajectory.DEFAULTS, "kind": kind, "heading": heading}
    fastest = 0.0
    for seed in range(6):
        t = trajectory.generate(msl, 400, 10.0, conf, np.random.default_rng(seed))
        margin = conf["margin"]
        assert np.all(np.abs(t.poses[:, 0]) <= msl.length / 2 - margin + 1e-9)
        assert np.all(np.abs(t.poses[:, 1]) <= msl.width / 2 - margin + 1e-9)
        v = t.speeds
        assert v.min() >= conf["speed_min"] - 1e-9 and v.max() <= conf["speed_max"] + 1e-9
        fastest = max(fastest, v.max())
        turn = np.abs(np.diff(np.unwrap(t.poses[:, 2]))) * 10.0
        assert turn.max() <= 3.0 + 1e-6  # smooth: bounded turn rate
        assert np.ptp(np.unwrap(t.poses[:, 2])) > 1.0  # and it does turn
        # smooth: speed changes at most accel_max per second between frames
        assert np.abs(np.diff(v)).max() * 10.0 <= conf["accel_max"] * 1.6 + 0.3
    assert fastest > 1.5  # it does speed up


def test_trajectory_for_a_walking_humanoid(spl):
    conf = {"speed_min": 0.05, "speed_max": 0.3, "heading": "along", "lateral_accel_max": 0.3,
            "accel_max": 0.3, "margin": 0.2, "start": [-1.0, 0.5, 0.3]}
    t = trajectory.generate(spl, 300, 10.0, conf, np.random.default_rng(0))
    assert np.allclose(t.poses[0], [-1.0, 0.5, 0.3])
    assert t.speeds.min() >= 0.05 - 1e-9 and t.speeds.max() <= 0.3 + 1e-9
    assert np.all(np.abs(t.poses[:, 0]) <= spl.length / 2 - 0.2 + 1e-9)


def test_trajectory_rejects_bad_conf(spl):
    with pytest.raises(FieldlocError, match="unknown trajectory"):
        trajectory.generate(spl, 10, 10.0, {"kind": "zigzag"}, np.random.default_rng(0))
    with pytest.raises(FieldlocError, match="not on the field"):
        trajectory.generate(spl, 10, 10.0, {"start": [20.0, 0.0, 0.0]},
                            np.random.default_rng(0))


# ---------------------------------------------------------------------------- sensors


def _integrate(start, motions):
    pose = np.asarray(start, dtype=float)
    out = [pose]
    for m in motions[1:]:
        pose = compose(pose, m)
        out.append(pose)
    return np.asarray(out)


def test_noise_free_odometry_integrates_to_truth(msl):
    t = trajectory.generate(msl, 200, 10.0, {}, np.random.default_rng(1))
    zero = {k: 0.0 for k in sensors.ODOMETRY_DEFAULTS}
    odo = sensors.odometry(t.poses, zero, np.random.default_rng(2))
    path = _integrate(t.poses[0], odo)
    assert np.abs(path[:, :2] - t.poses[:, :2]).max() < 1e-9
    assert np.abs(wrap_angle(path[:, 2] - t.poses[:, 2])).max() < 1e-9


def test_odometry_errors_match_the_noise_model(msl):
    t = trajectory.generate(msl, 600, 10.0, {}, np.random.default_rng(1))
    conf = dict(sensors.ODOMETRY_DEFAULTS)
    errs, finals = [], []
    for seed in range(8):
        odo = sensors.odometry(t.poses, conf, np.random.default_rng(seed))
        true = sensors.true_motion(t.poses)
        errs.append(odo[1:] - true[1:])
        # over 5 s windows, integrated odometry stays within the error model's reach of truth
        for s in range(0, 550, 50):
            seg = _integrate(t.poses[s], odo[s: s + 51])
            moved = np.hypot(*np.diff(t.poses[s: s + 51, :2], axis=0).T).sum()
            finals.append(np.hypot(*(seg[-1, :2] - t.poses[s + 50, :2])) / max(moved, 0.5))
    e = np.concatenate(errs)
    dist = np.hypot(*sensors.true_motion(t.poses)[1:, :2].T)
    # per-frame translation error ~ slip * distance + noise (and the run's scale error)
    expect = np.sqrt((conf["slip_sigma"] ** 2 + conf["scale_sigma"] ** 2) * np.mean(dist**2)
                     + conf["noise_xy"] ** 2)
    assert 0.5 * expect < e[:, 0].std() < 2.0 * expect
    assert np.abs(e[:, 2]).mean() > 0  # not exact
    assert np.median(finals) < 0.08 and np.max(finals) < 0.4  # drift per metre moved


def test_collisions_disturb_odometry_and_set_the_flag(msl):
    t = trajectory.generate(msl, 800, 10.0, {}, np.random.default_rng(1))
    conf = {**sensors.IMU_DEFAULTS, "collision_rate_hz": 0.5}
    flags = sensors.collision_flags(800, 10.0, conf, np.random.default_rng(3))
    assert 10 < flags.sum() < 400 and not flags[0]
    odo = sensors.odometry(t.poses, sensors.ODOMETRY_DEFAULTS, np.random.default_rng(4), flags)
    err = np.hypot(*(odo - sensors.true_motion(t.poses))[:, :2].T)
    assert np.median(err[flags]) > 3 * np.median(err[~flags])
    yaw = sensors.imu_yaw(t.poses, t.stamps, sensors.IMU_DEFAULTS, np.random.default_rng(5))
    yerr = wrap_angle(yaw - t.poses[:, 2])
    assert np.degrees(np.abs(yerr)).max() < 3.0  # usable as the heading (issue goal: 2 deg)
    assert np.abs(yerr).max() > 0
    contacts = np.zeros(800, bool)
    contacts[100:103] = True
    none = {**sensors.IMU_DEFAULTS, "collision_rate_hz": 0.0}
    assert np.array_equal(
        sensors.collision_flags(800, 10.0, none, np.random.default_rng(3), contacts), contacts
    )  # exact decisions: collision flags


def test_dataset_csvs_agree_with_truth(tmp_path, spl):
    conf = small_conf(frames=15)
    out = simulate.main(conf, spl, tmp_path / "d")
    truth = read_csv(out / "truth.csv", "truth")
    odo = read_csv(out / "odometry.csv", "odometry")
    imu = read_csv(out / "imu.csv", "imu")
    poses = np.stack([truth["x"], truth["y"], truth["theta"]], axis=1)
    true = sensors.true_motion(poses)
    ok = imu["collision"] == 0
    moved = np.hypot(true[:, 0], true[:, 1])
    dev = np.hypot(odo["dx"] - true[:, 0], odo["dy"] - true[:, 1])
    assert np.all(dev[ok] <= 0.25 * moved[ok] + 0.01)
    assert np.degrees(np.abs(wrap_angle(imu["yaw"] - truth["theta"]))).max() < 5
    assert set(np.unique(imu["collision"])) <= {0.0, 1.0}


# ---------------------------------------------------------------------------- images


def _line_samples(field, pose, cam, rng, n=400):
    """Points on field lines seen by the camera (0.45..2.5 m), and points 0.5 m from every
    line, as pixels."""
    lines = []
    for (x0, y0), (x1, y1) in field.segments:
        t = rng.random(n)
        p = np.stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)], axis=1)
        lines.append(p)
    p = np.concatenate(lines)
    q = p + rng.normal(0, 1, p.shape)
    q = q[np.abs(field.distance_to_lines(q) - 0.5) < 0.05]
    out = []
    for k, pts in enumerate((p, q)):
        rel = field_to_robot(pose, pts)
        d = np.hypot(rel[:, 0], rel[:, 1])
        keep = (d > 0.45) & (d < 2.5)
        if k == 0:  # lines at least 3 px wide (far lines are thinner: a pixel spans more)
            r = cam.radius_of_distance(d)
            slope = np.polynomial.polynomial.polyval(r, np.polynomial.polynomial.polyder(
                cam.polynomial))
            keep &= field.line_width / np.maximum(slope, d / r) >= 3.0
        uv = cam.robot_to_pixel(rel[keep])
        out.append(np.round(uv[np.isfinite(uv).all(axis=1)]).astype(int))
    return out


def _is_white(bgr):
    b, g, r = (bgr[..., i].astype(int) for i in range(3))
    return (np.minimum(np.minimum(b, g), r) > 150) & (np.maximum(np.maximum(b, g), r)
                                                      - np.minimum(np.minimum(b, g), r) < 60)


def _is_green(bgr):
    b, g, r = (bgr[..., i].astype(int) for i in range(3))
    return (g > r + 30) & (g > b + 30)


@pytest.mark.parametrize("pose", [(-0.8, 2.3, 0.2), (-2.0, -1.5, 2.5)])
def test_lines_appear_where_the_calibration_says(tmp_path, spl, pose):
    conf = small_conf("omni-clean", frames=1)
    conf["trajectory"]["start"] = list(pose)
    conf["omni"]["struts_deg"] = []
    out = simulate.main(conf, spl, tmp_path / "d")
    cam = load_calib(out / "calib.yaml")
    img = cv2.imread(str(out / "images/000000.png"))
    truth = read_csv(out / "truth.csv", "truth")
    p = (truth["x"][0], truth["y"][0], truth["theta"][0])
    on, off = _line_samples(spl, p, cam, np.random.default_rng(0))
    assert len(on) > 30 and len(off) > 30
    assert _is_white(img[on[:, 1], on[:, 0]]).mean() > 0.97
    assert _is_green(img[off[:, 1], off[:, 0]]).mean() > 0.97


def test_written_miscalibration_misplaces_lines(tmp_path, spl):
    conf = small_conf("omni-clean", frames=1)
    conf["trajectory"]["start"] = [-0.8, 2.3, 0.2]
    conf["omni"]["struts_deg"] = []
    conf["calib_error"] = {"centre_shift": [0.0, 0.0], "scale": 1.15}
    out = simulate.main(conf, spl, tmp_path / "d")
    cam = load_calib(out / "calib.yaml")
    img = cv2.imread(str(out / "images/000000.png"))
    on, _ = _line_samples(spl, tuple(conf["trajectory"]["start"]), cam,
                          np.random.default_rng(0))
    assert _is_white(img[on[:, 1], on[:, 0]]).mean() < 0.6


def test_default_conf_lines_are_mostly_visible(tmp_path, spl):
    conf = small_conf(frames=6, seed=11)
    out = simulate.main(conf, spl, tmp_path / "d")
    cam = load_calib(out / "calib.yaml")
    truth = read_csv(out / "truth.csv", "truth")
    white, green = [], []
    for i, path in enumerate(open_dataset(out).images):
        img = cv2.imread(str(path))
        yuv = cv2.cvtColor(img, cv2.COLOR_BGR2YUV).astype(int)
        p = (truth["x"][i], truth["y"][i], truth["theta"][i])
        on, off = _line_samples(spl, p, cam, np.random.default_rng(i))
        if len(on) == 0 or len(off) == 0:
            continue
        y_on, y_off = yuv[on[:, 1], on[:, 0], 0], yuv[off[:, 1], off[:, 0], 0]
        ref = np.median(y_off)
        white.append(np.mean(y_on > ref + 40))
        green.append(np.mean(_is_green(img[off[:, 1], off[:, 0]])))
    assert len(white) >= 3
    # lines are bright against the local green, except where robots, people, struts or worn
    # paint hide them; off-line points are green except for clutter and occluders
    assert 0.6 < np.mean(white) < 0.995
    assert 0.7 < np.mean(green) < 0.995


def test_default_mirror_geometry():
    # omni-clean: the designed mirror; omni-default and omni-hard: one with the resolution of
    # the seed team's (checked against its mirror.cfg in test_realism_omni.py)
    for preset, poly, dist, radius in (
            ("omni-clean", DEFAULT_POLYNOMIAL, [0.3, 1.0, 3.0, 5.8], [43, 118, 180, 200]),
            ("omni-default", TEAM_MIRROR_POLYNOMIAL, [0.3, 1.0, 2.0, 3.0, 4.0, 6.4],
             [40, 94, 123, 145, 164, 192]),
            ("omni-hard", TEAM_MIRROR_POLYNOMIAL, [1.0], [94])):
        cam = simulate.omni_renderer.camera_from_conf(simulate.confs[preset]["omni"])
        assert np.allclose(cam.polynomial, poly), preset
        assert np.allclose(cam.radius_of_distance(dist), radius, atol=4), preset
        assert cam.max_distance >= 4.0  # the tables' range
        assert cam.centre != (240.0, 240.0)
        rr = np.linspace(*cam.valid_radius, 500)
        assert np.all(np.diff(cam.distance_of_radius(rr)) > 0)


# ---------------------------------------------------------------------------- CLI


def test_cli_round_trip_and_defaults(tmp_path):
    runner = CliRunner()
    out = tmp_path / "cli"
    res = runner.invoke(cli, ["-q", "simulate", "omni", "--field", "spl", "-o", str(out),
                              "--frames", "2", "--calib-error", "1", "2", "1.1",
                              "-c", "scene.texture_resolution=0.02"])
    assert res.exit_code == 0, res.output
    info = yaml.safe_load((out / "simulation.yaml").read_text())
    expected = resolve_conf(simulate.confs, "omni-default",
                            {"scene": {"texture_resolution": 0.02}})
    expected["frames"] = 2
    expected["calib_error"].update(centre_shift=[1.0, 2.0], scale=1.1, distance_error=0.0)
    assert info["conf"] == yaml.safe_load(yaml.safe_dump(simulate._plain(expected)))
    assert info["seed"] == simulate.confs["omni-default"]["seed"]
    assert len(list((out / "images").iterdir())) == 2
    again = runner.invoke(cli, ["simulate", "omni", "--field", "spl", "-o", str(out),
                                "--frames", "1"])
    assert again.exit_code == 1
    assert "not empty" in again.output and "Traceback" not in again.output
    bad = runner.invoke(cli, ["simulate", "omni", "--field", "nowhere-cup", "-o",
                              str(tmp_path / "x")])
    assert bad.exit_code == 1 and "unknown field preset" in bad.output
    bad = runner.invoke(cli, ["simulate", "omni", "--field", "spl", "-o", str(tmp_path / "y"),
                              "-c", "scene.nonsense=1"])
    assert bad.exit_code == 1 and "unknown conf key" in bad.output


def test_presets_share_keys():
    common = set(simulate.confs["omni-default"]) - {"omni"}
    for name, conf in simulate.confs.items():
        # every preset: the shared keys plus its own camera kind's renderer section
        assert set(conf) == common | {conf["camera"]}, name
        assert conf["camera"] in simulate.RENDERERS
        for key in ("trajectory", "odometry", "imu", "scene"):
            assert set(conf[key]) == set(simulate.confs["omni-default"][key]), (name, key)
    assert math.isclose(simulate.confs["default"]["rate_hz"], 10.0)


def test_presets_name_every_renderer_key():
    """Each omni preset spells out the renderer's keys, so `-c omni.imaging.X=...` works on
    every preset."""
    from stages.simulate.omni_renderer import OMNI_DEFAULTS

    for name, conf in simulate.confs.items():
        if conf["camera"] != "omni":
            continue
        assert set(conf["omni"]) == set(OMNI_DEFAULTS), name
        assert set(conf["omni"]["imaging"]) == set(OMNI_DEFAULTS["imaging"]), name


def test_turning_smears_the_world_but_not_the_robot(spl):
    from stages.simulate import scene
    from stages.simulate.omni_renderer import OmniRenderer

    conf = copy.deepcopy(simulate.confs["omni-clean"])
    conf["scene"]["texture_resolution"] = 0.02
    stamps = np.arange(3) / 10.0
    world = scene.build(spl, conf["scene"], stamps, 0)
    omni = copy.deepcopy(conf["omni"])
    omni["imaging"]["exposure_time"] = 0.05
    still = OmniRenderer(omni, world, 0)
    turning = OmniRenderer(omni, world, 0)
    poses = np.array([[-0.8, 2.3, 0.0], [-0.8, 2.3, 0.3], [-0.8, 2.3, 0.6]])  # 3 rad/s
    turning.prepare(trajectory.Trajectory(stamps=stamps, poses=poses))
    a = still.render(poses[1], 1).astype(float)
    b = turning.render(poses[1], 1).astype(float)
    cam = still.camera
    uu, vv = np.meshgrid(np.arange(480), np.arange(480))
    rad = np.hypot(uu - cam.centre[0], vv - cam.centre[1])
    floor = (rad > 60) & (rad < 200)
    sharp = np.abs(np.diff(a, axis=1)).mean(axis=2)[floor[:, 1:]].mean()
    smeared = np.abs(np.diff(b, axis=1)).mean(axis=2)[floor[:, 1:]].mean()
    assert smeared < 0.8 * sharp  # edges across the turn are softer
    body = rad < 30
    assert np.abs(a[body] - b[body]).max() <= 1  # the robot's own body turns with the camera


def test_imaging_steps_shared_by_the_renderers():
    """stages.simulate.imaging: noise sigma = shot * sqrt(level) + read; chroma subsampling
    keeps the luma; the JPEG round trip with quality 0 is no round trip."""
    import cv2

    from stages.common.errors import FieldlocError
    from stages.simulate import imaging

    rng = np.random.default_rng(0)
    levels = np.full((200, 200, 3), 100.0, np.float32)
    noise = rng.standard_normal((200, 200, 3)).astype(np.float32)
    imaging.add_sensor_noise(levels, noise, 0.35, 2.0)
    assert abs(float(np.std(levels)) - (0.35 * 10.0 + 2.0)) < 0.1
    img = rng.integers(90, 160, (40, 64, 3), dtype=np.uint8)  # colours no channel clips
    luma = cv2.cvtColor(img, cv2.COLOR_BGR2YUV)[..., 0].astype(int)
    for method in imaging.CHROMA_METHODS:
        out = imaging.chroma_subsample(img, 4, method)
        assert np.abs(cv2.cvtColor(out, cv2.COLOR_BGR2YUV)[..., 0].astype(int) - luma).max() <= 3
    assert imaging.chroma_subsample(img, 1, "box") is img
    with pytest.raises(FieldlocError, match="chroma"):
        imaging.chroma_subsample(img, 2, "nope")
    assert imaging.jpeg_round_trip(img, 0) is img
    assert imaging.jpeg_round_trip(img, 90).shape == img.shape
