"""Omni extraction: scan-line distances on drawn images of known geometry, run widths, lighting,
the features file (failures, resume), the CLI, and agreement with the map tables on rendered
frames."""

from __future__ import annotations

import math

import cv2
import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages import extract
from stages.common import colour
from stages.common.camera import OmniCamera, save_calib
from stages.common.errors import FieldlocError
from stages.common.features_file import FeaturesFile
from stages.common.scanlines import ScanLines, bin_points_to_scanlines
from stages.extract import omni

# a mirror like a MSL robot's: 0.25 m at ~50 px, 2 m at ~200 px, 4 m at ~225 px
CAMERA = OmniCamera(image_size=(480, 480), centre=(238.0, 243.0),
                    polynomial=np.array([0.0, 0.005, 0.0, 0.0, 0.0, 3.0 / 230.0 ** 5]),
                    valid_radius=(45.0, 232.0), forward_angle=math.pi / 2)
GREEN_BGR = (40.0, 140.0, 35.0)
WHITE_BGR = (225.0, 235.0, 230.0)
CONF = omni.confs["default"]


def draw(white_fn, camera=CAMERA, ss=3, gain=1.0, cast=(1.0, 1.0, 1.0), noise=0.0, seed=0,
         other_fn=None):
    """An omni image of a green floor with white where ``white_fn(points)`` (robot frame) is
    true, drawn with ``ss`` x ``ss`` supersampling; grey where ``other_fn`` is true."""
    w, h = camera.image_size
    vv, uu = np.mgrid[0:h * ss, 0:w * ss]
    p = camera.pixel_to_robot((uu + 0.5) / ss - 0.5, (vv + 0.5) / ss - 0.5)
    img = np.empty((h * ss, w * ss, 3), np.float32)
    img[:] = GREEN_BGR
    img[white_fn(p)] = WHITE_BGR
    if other_fn is not None:
        img[other_fn(p)] = (90.0, 90.0, 95.0)
    img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    img = img * gain * np.asarray(cast, np.float32)
    if noise:
        img += np.random.default_rng(seed).normal(0.0, noise, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def line_band(normal_angle, distance, width=0.1):
    """A straight white line whose centre line is {p : p . n = distance}, n at normal_angle."""
    n = np.array([math.cos(normal_angle), math.sin(normal_angle)])
    return lambda p: np.abs(p @ n - distance) <= width / 2


def first_spiral_crossing(direction, k, normal_angle, distance, min_angle_deg=0.0):
    """Ground radius where spiral (direction, k) first crosses the centre line, from the scan-line
    definition's polyline (linear interpolation between its samples); None when it crosses at
    less than ``min_angle_deg`` to the line (a graze: the white run is as long as the spiral
    stays on the line, so no extractor reports it reliably)."""
    pts = ScanLines(spiral_samples_per_turn=20000).spiral_points(direction, k)
    n = np.array([math.cos(normal_angle), math.sin(normal_angle)])
    s = pts @ n - distance
    i = np.flatnonzero(np.sign(s[1:]) != np.sign(s[:-1]))
    if len(i) == 0:
        # touching the white band without crossing its centre line is a graze too
        return None if np.min(np.abs(s)) <= 0.07 and min_angle_deg > 0 else math.nan
    i = i[0]
    t = s[i] / (s[i] - s[i + 1])
    p = pts[i] + t * (pts[i + 1] - pts[i])
    tangent = (pts[i + 1] - pts[i]) / np.linalg.norm(pts[i + 1] - pts[i])
    if math.degrees(math.asin(min(1.0, abs(float(tangent @ n))))) < min_angle_deg:
        return None
    return float(np.hypot(*p))


@pytest.mark.parametrize("distance", [0.6, 1.0, 1.7, 2.5])
def test_line_ahead_at_known_distance(distance):
    f = omni.extract_frame(draw(line_band(0.0, distance)), CAMERA, CONF)
    assert f["radial"].shape == (72, 4) and f["spiral"].shape == (2, 72)
    assert abs(f["radial"][0, 0] - distance) <= 0.02
    assert np.isnan(f["radial"][0, 1:]).all()
    # the rays within +-30 deg cross the line at distance / cos(bearing)
    for k in (-6, -3, 3, 6):
        expect = distance / math.cos(math.radians(5 * k))
        if expect <= 4.0:
            assert abs(f["radial"][k % 72, 0] - expect) <= 0.02 + 0.01 * expect
    # points lie on the white line (spirals that graze it report its edge), in the robot frame
    assert len(f["points"]) > 5
    assert np.all(np.abs(f["points"][:, 0] - distance) <= 0.06)
    assert np.median(np.abs(f["points"][:, 0] - distance)) <= 0.005 + 0.006 * distance
    # points_px are image positions of the same points
    back = CAMERA.pixel_to_robot(f["points_px"][:, 0], f["points_px"][:, 1])
    assert np.allclose(back, f["points"], atol=0.02 + 0.02 * distance)


def test_line_ahead_with_a_table_calibration():
    """The extractor walks a table-model camera (a team's mirror table) like a polynomial one:
    the mirror of CAMERA given as its radii every 0.25 m finds the same line within 1 cm."""
    d = 0.25 * np.arange(1, 17)
    table = OmniCamera(image_size=CAMERA.image_size, centre=CAMERA.centre, polynomial=None,
                       valid_radius=CAMERA.valid_radius, forward_angle=CAMERA.forward_angle,
                       radial_table=np.stack([CAMERA.radius_of_distance(d), d], axis=1))
    img = draw(line_band(0.0, 1.3))
    f = omni.extract_frame(img, table, CONF)
    g = omni.extract_frame(img, CAMERA, CONF)
    assert abs(f["radial"][0, 0] - 1.3) <= 0.02
    assert np.nanmax(np.abs(f["radial"] - g["radial"])) <= 0.01
    assert np.all(np.abs(f["points"][:, 0] - 1.3) <= 0.06)


def test_heading_conventions_radial_and_spiral():
    """Radial line k is at 5k deg counter-clockwise from forward; spirals as in ScanLines."""
    d = 0.8
    f = omni.extract_frame(draw(line_band(math.pi / 2, d)), CAMERA, CONF)  # line on the left
    assert abs(f["radial"][18, 0] - d) <= 0.02
    assert np.isnan(f["radial"][54, 0])  # nothing on the right
    assert np.all(np.abs(f["points"][:, 1] - d) <= 0.06)
    checked = 0
    for direction in (0, 1):
        for k in range(0, 72, omni.SPIRAL_START_STEP):
            expect = first_spiral_crossing(direction, k, math.pi / 2, d, min_angle_deg=20)
            got = f["spiral"][direction, k]
            if expect is None:
                continue
            if np.isnan(expect):
                assert np.isnan(got)
                continue
            assert abs(got - expect) <= 0.02, (direction, k)
            checked += 1
    assert checked >= 30
    # spiral start angles the robot does not walk (odd, 5 deg apart) stay empty
    assert np.isnan(f["spiral"][:, 1::2]).all()


def test_up_to_four_crossings_nearest_first():
    lines = [line_band(0.0, d) for d in (0.5, 0.9, 1.4, 2.0, 2.7)]
    f = omni.extract_frame(draw(lambda p: np.any([fn(p) for fn in lines], axis=0)), CAMERA,
                           CONF)
    assert np.allclose(f["radial"][0], [0.5, 0.9, 1.4, 2.0], atol=0.02)


def test_runs_narrower_than_the_minimum_are_ignored():
    """Narrower than RUNS.min_white_m (3 cm): ignored; a line twice as wide is found."""
    img = draw(line_band(0.0, 0.6, width=0.02))  # a 2 cm stripe: ~2-3 px here
    assert np.isnan(omni.extract_frame(img, CAMERA, CONF)["radial"][0, 0])
    img = draw(line_band(0.0, 0.6, width=0.04))
    assert abs(omni.extract_frame(img, CAMERA, CONF)["radial"][0, 0] - 0.6) <= 0.02


def test_white_without_green_on_both_sides_or_too_wide_is_ignored():
    # a white band ending in a grey area (no green after it): not a line crossing
    img = draw(line_band(0.0, 1.0), other_fn=lambda p: p[..., 0] > 1.05)
    assert np.isnan(omni.extract_frame(img, CAMERA, CONF)["radial"][0, 0])
    # a white patch 0.8 m deep: wider than any line
    img = draw(line_band(0.0, 1.0, width=0.8))
    assert np.isnan(omni.extract_frame(img, CAMERA, CONF)["radial"][0, 0])
    # grey edges (1 px ~ 1.5 cm here) between green and white: up to max_gap_px are allowed
    def grey_edges(width):
        return lambda p: (np.abs(p[..., 0] - 1.0) > 0.05) & (np.abs(p[..., 0] - 1.0) <= 0.05
                                                              + width)

    img = draw(line_band(0.0, 1.0), other_fn=grey_edges(0.03), ss=1)
    assert abs(omni.extract_frame(img, CAMERA, CONF)["radial"][0, 0] - 1.0) <= 0.02
    img = draw(line_band(0.0, 1.0), other_fn=grey_edges(0.09), ss=1)
    assert np.isnan(omni.extract_frame(img, CAMERA, CONF)["radial"][0, 0])


@pytest.mark.parametrize("gain,cast", [(0.45, (1.0, 1.0, 1.0)), (1.5, (1.0, 1.0, 1.0)),
                                       (1.0, (0.75, 1.0, 1.2)), (0.8, (1.25, 1.0, 0.8))])
def test_lighting_changes(gain, cast):
    """Dark, bright, warm and cold light: the field green is estimated per frame."""
    img = draw(line_band(0.0, 1.2), gain=gain, cast=cast, noise=3.0)
    f = omni.extract_frame(img, CAMERA, CONF)
    assert abs(f["radial"][0, 0] - 1.2) <= 0.02
    assert np.all(np.abs(f["points"][:, 0] - 1.2) <= 0.06)


def test_vignetting_keeps_far_lines():
    """Darker towards the rim (as real mirrors and the renderer do): local green luminance."""
    img = draw(lambda p: line_band(0.0, 0.8)(p) | line_band(0.0, 2.4)(p)).astype(np.float32)
    vv, uu = np.indices(img.shape[:2])
    r = np.hypot(uu - CAMERA.centre[0], vv - CAMERA.centre[1]) / 240.0
    img = (img * (1.0 - 0.55 * r ** 2)[..., None]).astype(np.uint8)
    f = omni.extract_frame(img, CAMERA, CONF)
    assert np.allclose(f["radial"][0, :2], [0.8, 2.4], atol=0.03)


def test_dataset_mask_hides_pixels():
    img = draw(line_band(0.0, 1.0))
    mask = np.ones((480, 480), bool)
    mask[:240, 200:280] = False  # a rod over the line ahead
    f = omni.extract_frame(img, CAMERA, CONF, mask=mask)
    assert np.isnan(f["radial"][0, 0])
    assert abs(f["radial"][9, 0] - 1.0 / math.cos(math.radians(45))) <= 0.03


def test_class_counts_per_cell():
    img = draw(line_band(0.0, 1.0))
    counts, fc = colour.classify_grid(img, colour.confs["default"])
    assert counts.shape == (60, 60, 3)
    assert np.all(counts.sum(axis=2) == 64)
    assert fc.found and counts[..., colour.WHITE].sum() > 0


def test_bin_points_to_scanlines():
    sl = ScanLines()
    d = 1.1
    ys = np.linspace(-3, 3, 601)
    pts = np.stack([np.full_like(ys, d), ys], axis=1)  # a line ahead, sampled every cm
    radial, spiral = bin_points_to_scanlines(pts, sl, tolerance=0.03)
    assert radial.shape == (72, 4) and spiral.shape == (2, 72)
    assert abs(radial[0, 0] - d) <= 0.01
    assert abs(radial[6, 0] - d / math.cos(math.radians(30))) <= 0.02
    assert np.isnan(radial[36, 0])
    for direction in (0, 1):
        for k in range(0, 72, 6):
            expect = first_spiral_crossing(direction, k, 0.0, d, min_angle_deg=20)
            if expect is not None and np.isfinite(expect):
                assert abs(spiral[direction, k] - expect) <= 0.04
    # points far from every scan line leave everything empty
    r2, s2 = bin_points_to_scanlines([[0.5 * math.cos(0.04), 0.5 * math.sin(0.04)]], sl,
                                          tolerance=0.005)
    assert np.isnan(r2).all()


# ---------------------------------------------------------------------------- the stage


def make_dataset(root, n=4, corrupt=None):
    (root / "images").mkdir(parents=True)
    save_calib(CAMERA, root / "calib.yaml")
    for i in range(n):
        img = draw(line_band(0.0, 0.7 + 0.2 * i), ss=1)
        cv2.imwrite(str(root / "images" / f"{i:03d}.png"), img)
    if corrupt is not None:
        (root / "images" / f"{corrupt}.png").write_bytes(b"not a png")
    return root


def test_main_writes_features_records_bad_frame_and_resumes(tmp_path, caplog):
    ds = make_dataset(tmp_path / "ds", n=3, corrupt="001x")
    out = tmp_path / "features.h5"
    assert extract.main(None, ds, out) == out
    with FeaturesFile(out) as ff:
        assert ff.names == ["000", "001", "002"]
        assert ff.camera_kind == "omni"
        assert len(ff.failures) == 1 and ff.failures[0].startswith("001x:")
        assert "scanlines" in ff.h5.attrs and "calib_hash" in ff.h5.attrs
        fr = ff.frame("001")
        assert abs(fr["radial"][0, 0] - 0.9) <= 0.02
        assert fr["points"].shape[1] == 2 and fr["points_px"].shape == fr["points"].shape
        assert ff.conf == extract.resolve_extract_conf("omni")
    # resume: a frame whose image changed is extracted again (trial U2, U2-5; its old
    # features were kept), and a frame the dataset no longer has is dropped, its failure too
    cv2.imwrite(str(ds / "images" / "000.png"), draw(line_band(0.0, 1.5), ss=1))
    (ds / "images" / "001x.png").unlink()
    extract.main(None, ds, out)
    with FeaturesFile(out) as ff:
        assert abs(ff.frame("000")["radial"][0, 0] - 1.5) <= 0.02
        assert ff.names == ["000", "001", "002"] and ff.failures == []
    # overwrite: everything again, failures forgotten
    extract.main(None, ds, out, overwrite=True)
    with FeaturesFile(out) as ff:
        assert abs(ff.frame("000")["radial"][0, 0] - 1.5) <= 0.02
        assert ff.failures == []
    # another conf cannot be mixed into the same file
    with pytest.raises(FieldlocError, match="another conf"):
        extract.main({"max_white_m": 0.5}, ds, out)


def test_failed_frame_is_retried_on_resume(tmp_path):
    ds = make_dataset(tmp_path / "ds", n=2)
    good = (ds / "images" / "001.png").read_bytes()
    (ds / "images" / "001.png").write_bytes(b"broken")
    out = extract.main(None, ds, tmp_path / "f.h5")
    with FeaturesFile(out) as ff:
        assert ff.names == ["000"] and len(ff.failures) == 1
    (ds / "images" / "001.png").write_bytes(good)
    extract.main(None, ds, out)
    with FeaturesFile(out) as ff:
        assert ff.names == ["000", "001"] and ff.failures == []


def test_interrupted_run_leaves_no_file_and_keeps_finished_frames(tmp_path, monkeypatch):
    """Ctrl-C on the second frame: no features file (not even a half one), the first frame
    kept in the resume folder, and the next run takes it over and leaves nothing behind."""
    ds = make_dataset(tmp_path / "ds", n=2)
    out = tmp_path / "f.h5"
    original = omni.extract_frame
    calls = []

    def interrupted_on_second(*a, **k):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return original(*a, **k)

    monkeypatch.setattr(omni, "extract_frame", interrupted_on_second)
    with pytest.raises(KeyboardInterrupt):
        extract.main(None, ds, out)
    assert not out.exists()
    assert [p.name for p in tmp_path.glob(".f.h5*")] == [".f.h5.parts"]
    # the frame finished before the interruption is committed (a chunk of one frame)
    assert sorted(p.name for p in (tmp_path / ".f.h5.parts").iterdir()) == ["000+1.npz",
                                                                            "run.json"]
    monkeypatch.setattr(omni, "extract_frame", original)
    calls.clear()
    extract.main(None, ds, out)
    assert list(tmp_path.glob(".f.h5*")) == []
    with FeaturesFile(out) as ff:
        assert ff.names == ["000", "001"]


def test_wrong_image_size_is_a_bad_frame(tmp_path):
    ds = make_dataset(tmp_path / "ds", n=1)
    cv2.imwrite(str(ds / "images" / "009.png"), np.zeros((100, 120, 3), np.uint8))
    out = extract.main(None, ds, tmp_path / "f.h5")
    with FeaturesFile(out) as ff:
        assert ff.names == ["000"]
        assert "calibration expects 480 x 480" in ff.failures[0]


def test_dataset_mask_file_is_used(tmp_path):
    ds = make_dataset(tmp_path / "ds", n=1)
    m = np.zeros((480, 480, 3), np.uint8)
    m[:240, 200:280] = (0, 0, 255)  # painted red: excluded (MINHO convention)
    cv2.imwrite(str(ds / "mask.png"), m)
    out = extract.main(None, ds, tmp_path / "f.h5")
    with FeaturesFile(out) as ff:
        assert np.isnan(ff.frame("000")["radial"][0, 0])
        assert ff.h5.attrs["mask_hash"]


def test_cli_extract_and_errors(tmp_path):
    ds = make_dataset(tmp_path / "ds", n=2)
    r = CliRunner().invoke(cli, ["extract", str(ds), "-o", str(tmp_path / "f.h5")])
    assert r.exit_code == 0, r.output
    assert "2 frames (omni camera)" in r.output
    r = CliRunner().invoke(cli, ["extract", str(ds), "-o", str(tmp_path / "g.h5"),
                                 "-c", "no_such_key=1"])
    assert r.exit_code == 1 and "unknown conf key 'no_such_key'" in r.output
    assert "Traceback" not in r.output
    r = CliRunner().invoke(cli, ["extract", str(tmp_path / "missing")])
    assert r.exit_code == 1 and "dataset folder not found" in r.output
    r = CliRunner().invoke(cli, ["extract", str(ds), "--preset", "nope"])
    assert r.exit_code == 1 and "unknown preset 'nope'" in r.output


def test_show_points_png(tmp_path):
    ds = make_dataset(tmp_path / "ds", n=1)
    out = tmp_path / "pts.png"
    r = CliRunner().invoke(cli, ["show", "points", str(ds), "--frame", "0", "--map", "msl-2015",
                                 "--pose", "-4.5", "0.0", "0", "-o", str(out)])
    assert r.exit_code == 0, r.output
    img = cv2.imread(str(out))
    assert img is not None and img.shape[1] > 800
    # the line ahead at 0.7 m from (-4.5, 0) heading 0 is x = -3.8: not a field line
    assert "0% within 15 cm" in r.output
    r = CliRunner().invoke(cli, ["show", "points", str(ds), "--frame", "0", "--map", "msl-2015",
                                 "--pose", "-0.7", "0.0", "0", "-o", str(out),
                                 "--overwrite"])  # show replaces only with it
    assert "100% within 15 cm" in r.output  # ... and from (-0.7, 0) it is the halfway line


def test_features_h5_holds_the_frames_as_columns_with_units(tmp_path):
    ds = make_dataset(tmp_path / "ds", n=2)
    out = extract.main(None, ds, tmp_path / "f.h5")
    with h5py.File(out, "r") as h:
        assert [n.decode() for n in h["index/name"][()]] == ["000", "001"]
        assert h["index/stamp"].shape == (2,)
        assert list(h["rows/radial"][()]) == [72, 72] and h["data/radial"].shape == (144, 4)
        assert h["data/radial"].attrs["units"] == "m"
        assert h["data/points_px"].attrs["units"] == "px"


# ---------------------------------------------------------------------------- rendered frames


def table_agreement(dataset_dir):
    """Extracted scan-line distances of every frame against the table builder's values at the
    frame's true pose (stages.build_map.tables on a one-cell grid at the exact pose and heading,
    so the 10 cm / 5 deg discretisation of a stored map does not blur the comparison). Radial:
    each extracted crossing against the nearest table crossing of the same line (as the
    localiser matches them); spiral: against the table's first crossing. Returns the errors."""
    from stages.build_map import tables
    from stages.common.dataset import open_dataset, read_image
    from stages.common.field import load_field
    from stages.common.map_file import Grid
    from stages.common.scanlines import NO_HIT_MM

    ds = open_dataset(dataset_dir)
    cam, truth = ds.camera(), ds.optional("truth")
    fm = load_field("msl-2015")
    sl = omni.scanlines_of(CONF)
    radial_err, spiral_err = [], []
    for i, path in enumerate(ds.images):
        f = omni.extract_frame(read_image(path), cam, CONF)
        x, y, th = truth["x"][i], truth["y"][i], truth["theta"][i]
        grid = Grid(origin=(x, y), resolution=0.1, shape=(1, 1))
        rt = tables.radial_table(fm, grid, sl, heading=th)[..., 0, 0].astype(float)
        st = tables.spiral_table(fm, grid, sl, heading=th)[..., 0, 0].astype(float)
        rt = np.where(rt == NO_HIT_MM, np.nan, rt / 1000.0)
        st = np.where(st == NO_HIT_MM, np.nan, st / 1000.0)
        for k, obs in enumerate(f["radial"]):
            table = rt[k][np.isfinite(rt[k])]
            for o in obs[np.isfinite(obs)]:
                radial_err.append(np.min(np.abs(table - o)) if len(table) else np.inf)
        seen = np.isfinite(f["spiral"])
        e = np.abs(f["spiral"][seen] - st[seen])
        spiral_err.extend(np.where(np.isfinite(e), e, np.inf))
    return np.array(radial_err), np.array(spiral_err)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    import copy

    from stages import simulate

    out = {}
    for preset in ("omni-clean", "omni-default"):
        conf = copy.deepcopy(simulate.confs[preset])
        conf.update(frames=4, seed=5)
        # the extractor is judged against the tables through the true camera: without the
        # calibration error omni-default writes (a team's mirror table, by design off)
        conf["calib_error"]["distance_error"] = 0.0
        out[preset] = simulate.main(conf, "msl-2015", tmp_path_factory.mktemp("sim") / preset)
    return out


def test_rendered_frames_agree_with_the_tables_at_the_true_pose(rendered):
    radial, spiral = table_agreement(rendered["omni-clean"])
    assert len(radial) >= 100 and len(spiral) >= 60
    assert np.mean(radial <= 0.05) >= 0.9
    assert np.median(radial) <= 0.02
    assert np.mean(spiral <= 0.05) >= 0.9
    # with clutter, people, robots, noise and changing light: still the large majority
    radial, spiral = table_agreement(rendered["omni-default"])
    assert len(radial) >= 60
    assert np.mean(radial <= 0.05) >= 0.65
    assert np.mean(spiral <= 0.05) >= 0.75


def test_extract_main_on_a_rendered_dataset(rendered, tmp_path):
    out = extract.main(None, rendered["omni-default"], tmp_path / "f.h5")
    with FeaturesFile(out) as ff:
        assert len(ff) == 4 and ff.failures == []
        assert np.allclose(ff.stamps, np.sort(ff.stamps))
        assert all(len(ff.frame(n)["points"]) >= 10 for n in ff.names)


def test_perspective_datasets_are_dispatched_with_head_angles(tmp_path, monkeypatch):
    """A perspective calib.yaml picks stages.extract.perspective; head.csv rows reach each
    frame as pitch/roll (nearest stamp within the tolerance, none otherwise)."""
    import yaml

    from stages.common.dataset import write_csv

    root = tmp_path / "persp"
    (root / "images").mkdir(parents=True)
    (root / "calib.yaml").write_text(yaml.safe_dump({
        "kind": "perspective", "image_size": [64, 48],
        "intrinsics": {"fx": 40.0, "fy": 40.0, "cx": 31.5, "cy": 23.5},
        "distortion": [0.0, 0.0, 0.0, 0.0, 0.0], "height": 0.5, "pitch": 0.4, "roll": 0.0}))
    for i in range(3):
        cv2.imwrite(str(root / "images" / f"{i:02d}.png"), np.full((48, 64, 3), 90, np.uint8))
    write_csv(root / "frames.csv", "frames", {"name": ["00.png", "01.png", "02.png"],
                                             "stamp": [0.0, 0.1, 0.2]})
    write_csv(root / "head.csv", "head", {"stamp": [0.0, 0.11, 0.5], "pitch": [0.3, 0.35, 0.9],
                                         "roll": [0.01, -0.02, 0.5]})
    perspective = extract.kind_module("perspective")
    seen = {}

    def record(image, camera, conf, pitch=None, roll=None, **info):
        seen[len(seen)] = (pitch, roll)
        return {"lines": np.zeros((0, 4)), "boundary": np.zeros((0, 2))}

    monkeypatch.setattr(perspective, "extract_frame", record)
    out = extract.main(None, root, tmp_path / "p.h5")
    assert seen == {0: (0.3, 0.01), 1: (0.35, -0.02), 2: (None, None)}
    with FeaturesFile(out) as ff:
        assert ff.camera_kind == "perspective" and ff.names == ["00", "01", "02"]
        assert "scanlines" not in ff.h5.attrs
