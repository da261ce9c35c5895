"""The SURF template paper's comparison: the white-point table Dm with eq. 1
(stages.build_map.white_points), the template pairs' eq. 4 surface and the query errors
(stages.localize.error_surface), the local minima (stages.common.surfaces) and `fieldloc show
error-surface`."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from click.testing import CliRunner

from fieldloc_cli.main import cli
from stages import build_templates, simulate
from stages.build_map import white_points as wp
from stages.common.errors import FieldlocError
from stages.common.field import load_field
from stages.common.surfaces import count_minima, local_minima
from stages.localize import error_surface as tes
from stages.localize import template_matching as tm


def test_a_cell_sees_the_halfway_line_at_its_distance_in_the_bin_of_its_direction():
    fm = load_field("msl-2015")  # halfway line x = 0; (1, 4.5) is outside the centre circle
    g = wp.region_grid(1.0, 4.5, 0.2, 0.1)
    c = g.shape[0] // 2
    assert np.allclose([g.xs[c], g.ys[c]], [1.0, 4.5])
    t = wp.white_point_table(fm, g, 0.0)
    assert t.shape[:3] == (5, 5, 360)
    assert t[c, c, 180, 0] == pytest.approx(1.0)  # straight back (-x): 1 m to x = 0
    assert t[c + 1, c - 1, 180, 0] == pytest.approx(0.9)  # the cell 10 cm nearer
    # heading 90 deg: the line is now at robot angle 90 deg (left)
    t90 = wp.white_point_table(fm, g, math.pi / 2)
    assert t90[c, c, 90, 0] == pytest.approx(1.0)
    # eq. 1: a point at its table radius costs nothing, 0.3 m off costs 0.3, none costs e_none
    e = wp.matching_error(t, np.array([1.0, 1.3, 2.0]), np.array([180, 180, 0]), (0,), 0.7)
    assert e[0, c, c] == pytest.approx(0.0 + 0.3 + 0.7)
    assert np.isfinite(t).sum() > 0 and not np.isfinite(t[c, c, 0]).any()  # +x: nothing in 4 m
    with pytest.raises(FieldlocError, match="angle_step_deg"):
        wp.white_point_table(fm, g, 0.0, angle_step_deg=7.0)


def test_the_white_point_surface_is_lowest_at_the_true_pose_of_its_own_points():
    fm = load_field("msl-2015")
    pose = (3.0, 2.0, math.radians(20))
    cell = wp.region_grid(pose[0], pose[1], 0.0, 0.1)
    t = wp.white_point_table(fm, cell, pose[2])[0, 0]  # (360, K): what the robot sees
    k, j = np.nonzero(np.isfinite(t))
    phi = np.radians(k.astype(float))
    pts = np.stack([t[k, j] * np.cos(phi), t[k, j] * np.sin(phi)], axis=1)
    s = wp.error_surface(fm, pose, pts, half_size=0.5, step=0.1, dtheta_deg=10)
    c = s["xy"].shape[0] // 2
    assert s["xy"][c, c] == pytest.approx(0.0, abs=1e-3)
    assert np.all(np.delete(s["xy"].ravel(), c * s["xy"].shape[1] + c) > 0.5)
    assert s["theta"][len(s["theta"]) // 2] == pytest.approx(0.0, abs=1e-3)
    assert tuple(local_minima(s["xy"])[0]) == (c, c)  # the lowest minimum is the truth
    assert s["xyt"].shape == (21, 11, 11) and np.allclose(s["xyt"][10], s["xy"])
    assert tuple(local_minima(s["xyt"])[0]) == (10, c, c)


def test_local_minima_are_strict_interior_minima_below_the_level():
    s = np.array([[5, 5, 5, 5, 5],
                  [5, 1, 5, 3, 5],
                  [5, 5, 5, 5, 5],
                  [5, 2, 2, 5, 5],  # a flat pair is not strict
                  [0, 5, 5, 5, 5]], float)  # a border minimum does not count
    assert local_minima(s).tolist() == [[1, 1], [1, 3]]
    assert count_minima(s, level=2.0) == 1
    assert count_minima(np.array([3.0, 1.0, 2.0, 0.5, 4.0])) == 2
    cube = np.ones((3, 4, 3))
    cube[1, 2, 1] = 0.0
    assert local_minima(cube).tolist() == [[1, 2, 1]]
    with pytest.raises(FieldlocError):
        local_minima(np.zeros((3, 3, 3, 3)))


def test_the_template_pairs_surface_has_one_minimum_at_the_true_displacement():
    rng = np.random.default_rng(4)
    q = rng.uniform(-3, 3, (40, 2))
    true = (0.4, -0.3, math.radians(6))
    t = tm.transform(true, q) + rng.normal(0, 0.01, q.shape)
    s = tes.template_surface(t, q, true, half_size=1.0, step=0.1, dtheta_deg=20)
    c = s["xy"].shape[0] // 2
    assert count_minima(s["xy"]) == 1 and tuple(local_minima(s["xy"])[0]) == (c, c)
    assert count_minima(s["theta"]) == 1 and int(np.argmin(s["theta"])) == len(s["theta"]) // 2
    assert count_minima(s["xyt"]) == 1
    # the surface is eq. 4 (template_matching.matching_error) of the displaced query
    h, i, j = 3, 2, 15
    pose = (true[0] + s["dx"][j], true[1] + s["dy"][i], true[2] + s["dtheta"][h])
    assert s["xyt"][h, i, j] == pytest.approx(tm.matching_error(pose, t, q))


def _grid(seed, tmp, name, **grid):
    conf = copy.deepcopy(simulate.confs["omni-default"])
    conf.update(seed=seed, calib_seed=2, world_seed=2)
    conf["scene"]["texture_resolution"] = 0.02
    conf["trajectory"].update(kind="grid", grid_centre=[1.0, 1.0], **grid)
    return simulate.main(conf, "spl", tmp / name)


@pytest.fixture(scope="module")
def template_and_queries(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("surface")
    capture = _grid(5, tmp, "capture", grid_spacing=1.0, grid_half_size=0.0)
    db = build_templates.main(None, capture, tmp / "t.h5")
    queries = _grid(6, tmp, "queries", grid_spacing=0.3, grid_half_size=0.3)
    return db, queries, tmp


def test_show_error_surface_draws_and_counts_on_a_rendered_template(template_and_queries):
    db, queries, tmp = template_and_queries
    out = tmp / "s.png"
    r = CliRunner().invoke(cli, ["show", "error-surface", str(db), str(queries), "-o", str(out),
                                 "--half-size", "0.6", "--dtheta-deg", "10"])
    assert r.exit_code == 0, r.output
    assert out.stat().st_size > 10_000
    lines = r.stdout.strip().splitlines()
    assert lines[0].startswith("template 0 at (1.00, 1.00) m")
    assert lines[2].startswith("(b) template pairs (eq. 4), local minima (below the median):"
                               " 1 (1) over (dx, dy, dtheta), 1 (1) over (dx, dy), 1 (1)")
    near = [ln for ln in lines if ln.startswith("(c) 0.0-0.5 m")][0]
    assert "9 queries, 0 failed" in near
    median_cm = float(near.split("median ")[1].split(" cm")[0])
    assert median_cm < 10  # queries within 0.45 m of the template: a few cm


def test_show_error_surface_bad_input_is_one_line(template_and_queries, tmp_path):
    db, queries, _tmp = template_and_queries
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5" * 20)
    for argv in (["show", "error-surface", str(bad), str(queries), "-o", str(tmp_path / "x.png")],
                 ["show", "error-surface", str(db), str(tmp_path / "none"), "-o",
                  str(tmp_path / "x.png")],
                 ["show", "error-surface", str(db), str(queries), "--template", "5", "-o",
                  str(tmp_path / "x.png")],
                 ["show", "error-surface", str(db), str(queries), "--step", "0", "-o",
                  str(tmp_path / "x.png")]):
        r = CliRunner().invoke(cli, argv)
        assert r.exit_code == 1, r.output
        assert len(r.output.strip().splitlines()) == 1 and "Traceback" not in r.output
    assert not (tmp_path / "x.png").exists()
