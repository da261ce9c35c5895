"""Map tables against independent brute-force computations, and the build-map CLI."""

import math

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from scipy.ndimage import distance_transform_edt

from fieldloc_cli.main import cli
from stages import build_map
from stages.build_map import tables
from stages.common.field import load_field
from stages.common.map_file import Grid, MapFile
from stages.common.scanlines import NO_HIT_MM, ScanLines


def _crossings_by_march(fm, points, spacing, merge):
    """For a batch of sampled curves (B, T, 2): the fractional sample indices where each crosses
    a centre line, found without the table code: local minima of the distance to the lines,
    refined by 400 sub-samples between the neighbouring samples and kept when the refined
    distance is below 0.05 mm (a crossing, not a graze). Crossings closer than ``merge`` (curve
    length) are one white run, reported by its middle. None for a curve that runs along a line
    (no crossing is defined there)."""
    d = fm.distance_to_lines(points)
    along = (np.cumsum(d < 1e-6, axis=1)[:, 4:] - np.cumsum(d < 1e-6, axis=1)[:, :-4]) >= 4
    mid = d[:, 1:-1]
    b, k = np.nonzero((mid <= d[:, :-2]) & (mid < d[:, 2:]) & (mid < spacing))
    k = k + 1
    u = np.linspace(-1.0, 1.0, 401)[None, :, None]
    p0, p1, p2 = points[b, k - 1][:, None], points[b, k][:, None], points[b, k + 1][:, None]
    sub = np.where(u < 0, p1 + u * (p1 - p0), p1 + u * (p2 - p1))
    ds = fm.distance_to_lines(sub)
    keep = ds.min(axis=1) < 5e-5
    pos = k + u[0, np.argmin(ds, axis=1), 0]
    out = []
    for row in range(points.shape[0]):
        if along[row].any():
            out.append(None)
            continue
        merged = []
        for x in sorted(pos[(b == row) & keep]):
            if merged and (x - merged[-1][1]) * spacing <= merge:
                merged[-1][1] = x
            else:
                merged.append([x, x])
        out.append([0.5 * (g[0] + g[1]) for g in merged])
    return out


def _same_hits(got, expect, lo, hi, tol=0.005):
    """Compare hit lists, leaving out hits within ``tol`` of the search limits (a crossing
    exactly at a limit belongs to either side)."""
    keep = [e for e in expect if lo + tol < e < hi - tol]
    have = [g for g in got if lo + tol < g < hi - tol]
    return len(keep) == len(have) and np.allclose(keep, have, atol=tol)


@pytest.fixture(scope="module")
def msl2015_tables():
    fm = load_field("msl-2015")
    conf = build_map.confs["default"]
    grid, sl, tabs = build_map.build_tables(fm, conf)
    return fm, grid, sl, tabs


def test_grid_covers_world(msl2015_tables):
    fm, grid, sl, tabs = msl2015_tables
    assert grid.shape == (141, 201)  # 20 x 14 m at 10 cm, inclusive
    assert np.allclose(grid.origin, (-10.0, -7.0))
    assert tabs["radial"][0].shape == (72, 4, 141, 201)
    assert tabs["spiral"][0].shape == (2, 72, 141, 201)
    assert tabs["radial"][0].dtype == np.uint16


def test_radial_and_spiral_equal_brute_force_march(msl2015_tables):
    fm, grid, sl, tabs = msl2015_tables
    radial, spiral = tabs["radial"][0], tabs["spiral"][0]
    rng = np.random.default_rng(7)
    cells = np.stack([rng.integers(0, grid.shape[0], 200), rng.integers(0, grid.shape[1], 200)], 1)
    step = 0.005
    t = np.arange(sl.robot_radius - 2 * step, sl.max_range + 3 * step, step)
    phi = np.linspace(0, 2 * math.pi, 1501)
    r_sp = sl.spiral_radius(phi)
    bad = []
    for i, j in cells:
        ox, oy = grid.centre_of(i, j)
        ang = sl.radial_angles
        pts = np.stack([ox + np.cos(ang)[:, None] * t, oy + np.sin(ang)[:, None] * t], -1)
        for k, hits in enumerate(_crossings_by_march(fm, pts, step, fm.line_width)):
            if hits is None:  # the ray runs along a line
                continue
            expect = [t[0] + h * step for h in hits]
            expect = [e for e in expect if sl.robot_radius <= e <= sl.max_range]
            got = [v / 1000 for v in radial[k, :, i, j] if v != NO_HIT_MM]
            if len(got) == sl.max_crossings:  # the table keeps the first four only
                expect = expect[: sl.max_crossings]
            if not _same_hits(got, expect, sl.robot_radius, sl.max_range):
                bad.append(("radial", i, j, k, got, expect))
        # a sample of 24 spirals per cell (12 each way)
        picks = [(direction, k) for direction in (0, 1)
                 for k in rng.choice(sl.n_angles, 12, replace=False)]
        curves = []
        for direction, k in picks:
            a = k * sl.angle_step + (1 if direction == 0 else -1) * phi
            curves.append(np.stack([ox + r_sp * np.cos(a), oy + r_sp * np.sin(a)], -1))
        curves = np.asarray(curves)
        seg = np.hypot(*np.diff(curves[0], axis=0).T).max()
        for (direction, k), hits in zip(picks, _crossings_by_march(fm, curves, seg, 0.0)):
            if hits is None:
                continue
            expect = [float(np.interp(h, np.arange(len(phi)), r_sp)) for h in hits]
            v = spiral[direction, k, i, j]
            got = [] if v == NO_HIT_MM else [v / 1000]
            lo, hi = sl.robot_radius + 0.005, sl.spiral_end_radius - 0.005
            if any(not lo < h < hi for h in got + expect[:1]):
                continue  # first crossing at a search limit: either answer is right
            if not _same_hits(got, expect[:1], sl.robot_radius, sl.spiral_end_radius):
                bad.append(("spiral", i, j, direction, k, got, expect))
    for b in bad:
        print(b)
    assert not bad, bad[:5]


def test_index_rotation_equals_table_at_heading():
    fm = load_field("kidsize")
    grid = Grid.around(fm, 0.5, 0.25)
    sl = ScanLines()
    base_r = tables.radial_table(fm, grid, sl)
    base_s = tables.spiral_table(fm, grid, sl)
    for m in (1, 7, 40):
        heading = m * sl.angle_step
        rot_r = np.roll(base_r, -m, axis=0)
        rot_s = np.roll(base_s, -m, axis=1)
        at_r = tables.radial_table(fm, grid, sl, heading=heading)
        at_s = tables.spiral_table(fm, grid, sl, heading=heading)
        assert np.abs(rot_r.astype(int) - at_r.astype(int)).max() <= 1
        # spirals: identical up to rounding, except where a crossing is a tangential touch
        diff = np.abs(rot_s.astype(int) - at_s.astype(int))
        assert (diff <= 1).mean() > 0.999


def test_distance_table_matches_edt_on_fine_raster(msl2015_tables):
    fm, grid, sl, tabs = msl2015_tables
    dist = tabs["distance"][0]
    # 1/160 m: the msl-2015 lines (sixteenths of a metre from the letters' outer-side
    # convention) and the 10 cm cells both fall on whole pixels
    res = 1 / 160
    x0, y0 = grid.origin
    w = int(round((grid.xs[-1] - x0) / res)) + 1
    h = int(round((grid.ys[-1] - y0) / res)) + 1
    raster = np.full((h, w), 255, np.uint8)

    def px(x, y):
        return (int(round((x - x0) / res)), int(round((y - y0) / res)))

    for (ax, ay), (bx, by) in fm.segments:
        cv2.line(raster, px(ax, ay), px(bx, by), 0, 1)
    for cx, cy, r, a0, sweep in fm.arcs:
        cv2.ellipse(raster, px(cx, cy), (int(round(r / res)),) * 2, 0,
                    math.degrees(a0), math.degrees(a0 + sweep), 0, 1)
    edt = distance_transform_edt(raster > 0) * res
    at_cells = edt[::16, ::16]
    assert at_cells.shape == dist.shape
    assert np.abs(at_cells - dist).max() <= 0.01


def test_distance_gradient_points_away_from_lines(msl2015_tables):
    fm, grid, sl, tabs = msl2015_tables
    g = tabs["distance_gradient"][0]
    i, j = grid.cell_of(1.0, 0.0)  # between the halfway line (x = 0) and the circle (x = 2)
    # equidistant: one of them wins, the gradient is a unit vector along x
    assert np.isclose(abs(g[0, i, j]), 1.0) and np.isclose(g[1, i, j], 0.0)
    i, j = grid.cell_of(0.0, 4.0)
    assert np.allclose(g[:, i, j], [0.0, 0.0])  # on the halfway line


def test_map_file_round_trip(msl2015_map):
    with MapFile(msl2015_map) as m:
        assert m.field.name == "msl-2015"
        assert m.grid.shape == (141, 201)
        r = m.table("radial")
        i, j = m.grid.cell_of(0.0, 0.0)
        # ray along +x from the centre spot meets the circle's middle: letter H is 4 m over
        # the line's outer sides, so the radius is 2 - 0.125 / 2 = 1.9375 m (mm, rounded)
        assert abs(int(r[0, 0, i, j]) - 1937.5) <= 0.5
        assert m.table_attrs("radial")["units"] == "mm"


def test_cli_build_map_inspect_and_errors(tmp_path):
    runner = CliRunner()
    out = tmp_path / "spl.map.h5"
    res = runner.invoke(cli, ["build-map", "spl", "-o", str(out), "--resolution", "0.2"])
    assert res.exit_code == 0, res.output
    assert "crossings L 12 T 10 X 2" in res.output
    res = runner.invoke(cli, ["inspect", str(out)])
    assert res.exit_code == 0
    assert "/tables/radial  (72, 4, 41, 57) uint16 [mm]" in res.output
    assert "@schema = fieldloc.map" in res.output
    res = runner.invoke(cli, ["build-map", "spl", "-o", str(out)])
    assert res.exit_code == 1 and "exists" in res.output
    res = runner.invoke(cli, ["build-map", "nope", "-o", str(tmp_path / "x.h5")])
    assert res.exit_code == 1
    assert res.output.strip().splitlines() == [
        "fieldloc: error: unknown field preset 'nope' (presets: adultsize, kidsize, msl,"
        " msl-2015, spl; or give a path to a field YAML)"
    ]
    res = runner.invoke(cli, ["build-map", "spl", "-o", str(tmp_path / "no" / "x.h5")])
    assert res.exit_code == 1 and "does not exist" in res.output
    assert "Traceback" not in res.output
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5")
    res = runner.invoke(cli, ["inspect", str(bad)])
    assert res.exit_code == 1 and "not an HDF5 file" in res.output


def test_interrupted_build_keeps_previous_map(tmp_path, monkeypatch):
    out = tmp_path / "k.map.h5"
    build_map.main({**build_map.confs["default"], "resolution": 0.5}, "kidsize", out)
    before = out.read_bytes()

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(tables, "distance_table", boom)
    with pytest.raises(KeyboardInterrupt):
        build_map.main({**build_map.confs["default"], "resolution": 0.5}, "kidsize", out,
                       overwrite=True)
    assert out.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["k.map.h5"]
