"""Perspective feature extraction (Schulz et al. 2011, sections 3-4): each step on small generated
data with known answers, then the whole chain on drawn scenes and on frames of the perspective
renderer compared with the field model at the true pose."""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
import pytest

from stages.common.features_file import FRAME_DATASETS
from stages.common.field import distance_to_lines, load_field
from stages.common.geometry import robot_to_field
from stages.common.perspective_camera import PerspectiveCamera
from stages.extract import perspective
from stages.extract.perspective import line_fit
from stages.extract.perspective.field_boundary import (
    field_height_histogram,
    local_convex_filling,
    local_convexity,
)
from stages.extract.perspective.line_fit import (
    LineFit,
    RefinedLine,
    fit_line,
    floor_line_parameters,
    merge_segments,
    split_component,
)
from stages.extract.perspective.line_structure import low_pass, place_nodes, ranking_skeleton
from stages.simulate import scene
from stages.simulate.perspective_renderer import PerspectiveRenderer

CONF = perspective.confs["default"]
GREEN, WHITE, WALL, DARK = (40, 140, 50), (235, 235, 235), (110, 105, 100), (30, 30, 35)
# an ideal lens keeps the drawn scenes cheap; the rendered frames below use the wide-angle one
CAM = PerspectiveCamera(distortion=np.zeros(5))


# ---------------------------------------------------------------------------- drawn scenes


@functools.lru_cache(maxsize=1)
def _floor_of_pixels() -> np.ndarray:
    return _floor_of(CAM)


def _floor_of(cam) -> np.ndarray:
    w, h = cam.image_size
    vv, uu = np.mgrid[0:h, 0:w]
    uv = np.stack([uu, vv], -1).reshape(-1, 2).astype(float)
    return cam.pixel_to_floor(uv).reshape(h, w, 2)


def draw_scene(segments, *, line_width=0.06, carpet_x=5.0, seed=0, cam=None) -> np.ndarray:
    """BGR frame of a green carpet reaching ``carpet_x`` m ahead of the robot with white lines
    (robot-frame segments (S, 2, 2)), a grey wall beyond, and a little noise, as ``cam`` (the
    drawn scenes' camera ``CAM`` by default) sees it."""
    fl = _floor_of_pixels() if cam is None else _floor_of(cam)
    h, w = fl.shape[:2]
    img = np.empty((h, w, 3), np.float32)
    img[:] = WALL
    carpet = np.isfinite(fl[..., 0]) & (fl[..., 0] <= carpet_x) & (np.abs(fl[..., 1]) <= 4.0)
    img[carpet] = GREEN
    seg = np.asarray(segments, float).reshape(-1, 2, 2)
    d = np.full((h, w), np.inf)
    d[carpet] = distance_to_lines(fl[carpet], seg, np.zeros((0, 5)))
    img[d <= line_width / 2] = WHITE
    img += np.random.default_rng(seed).normal(0.0, 4.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def _robot_xy(row) -> np.ndarray:
    return row[1] * np.array([math.cos(row[2]), math.sin(row[2])])


def _used_lines(res):
    return [(ln, e) for ln, e in zip(res["lines"], res["line_ends"]) if ln[3] > 0]


DRAWN = {
    # kind: (segments, crossing position, orientation (robot frame), period of the orientation)
    "L": ([[[1.3, 0.3], [2.3, 0.3]], [[1.3, 0.3], [1.3, -0.7]]], (1.3, 0.3), -math.pi / 4,
          2 * math.pi),
    "T": ([[[1.5, -1.0], [1.5, 1.0]], [[1.5, 0.0], [0.6, 0.0]]], (1.5, 0.0), math.pi,
          2 * math.pi),
    "X": ([[[0.9, 0.0], [2.1, 0.0]], [[1.5, -0.6], [1.5, 0.6]]], (1.5, 0.0), 0.0, math.pi / 2),
}


@pytest.mark.parametrize("kind", ["L", "T", "X"])
def test_drawn_crossing_is_found_as_its_type(kind):
    segments, where, orientation, period = DRAWN[kind]
    res = perspective.extract_frame(draw_scene(segments), CAM, CONF)
    c = res["crossings"]
    assert len(c) == 1, c
    assert "LTX"[int(c[0, 0])] == kind
    assert np.hypot(*(_robot_xy(c[0]) - where)) < 0.08
    assert abs(math.remainder(c[0, 3] - orientation, period)) < math.radians(8)
    assert 0 < c[0, 4] <= 1
    # the image position is where the crossing projects
    assert np.hypot(*(res["crossings_px"][0] - CAM.floor_to_pixel(np.array([where]))[0])) < 10


def test_straight_line_split_by_a_gap_is_one_line():
    segments = [[[0.7, -0.5], [1.5, -0.5]], [[1.8, -0.5], [3.0, -0.5]]]
    res = perspective.extract_frame(draw_scene(segments), CAM, CONF)
    used = _used_lines(res)
    assert len(used) == 1, res["lines"]
    (dist, angle, length, _), ends = used[0]
    assert abs(dist - 0.5) < 0.04
    assert abs(math.remainder(angle + math.pi / 2, 2 * math.pi)) < 0.05
    assert length > 1.8  # both pieces: 0.7 .. 3.0 m minus what the far end loses
    assert np.all(np.abs(ends[[1, 3]] + 0.5) < 0.06)
    assert len(res["crossings"]) == 0


def test_boundary_stops_at_a_robot_on_the_field_edge():
    edge_x = 2.5
    img = draw_scene([], carpet_x=edge_x)
    v_edge = float(CAM.floor_to_pixel(np.array([[edge_x, 0.0]]))[0, 1])
    # a dark robot standing on the edge: its feet a little in front of it, its body above
    cv2.rectangle(img, (330, int(v_edge) - 120), (420, int(v_edge) + 12), DARK, -1)
    res = perspective.extract_frame(img, CAM, CONF)
    b = res["boundary"]
    robot = (b[:, 0] > 345) & (b[:, 0] < 405)
    away = (b[:, 0] < 250) | (b[:, 0] > 500)
    # the boundary does not climb the robot's body ...
    assert np.all(b[robot, 1] >= v_edge - 4), b[robot, 1]
    # ... and follows the carpet's edge elsewhere (within about one grid cell)
    assert np.all(np.abs(b[away, 1] - v_edge) <= 10), b[away, 1] - v_edge


def _bar(img, foot, z0, z1, radius, colour, cam=CAM):
    """Draw a vertical cylinder of ``radius`` m standing at floor point ``foot`` (robot frame)
    from height ``z0`` to ``z1`` m into ``img`` as ``cam`` sees it (its outline as a
    quadrilateral); returns the image points of its axis at z0 and z1."""
    base = cam.project(np.array([[foot[0], foot[1], z0]]), inside=False)[0]
    top = cam.project(np.array([[foot[0], foot[1], z1]]), inside=False)[0]
    half = cam.fx * radius / np.hypot(*foot)
    poly = np.array([[base[0] - half, base[1]], [base[0] + half, base[1]],
                     [top[0] + half, top[1]], [top[0] - half, top[1]]])
    cv2.fillConvexPoly(img, np.round(poly).astype(np.int32), colour)
    return base, top


def test_goal_post_rising_above_the_boundary_is_a_point_landmark():
    foot = np.array([2.0, 0.4])
    img = draw_scene([], carpet_x=3.0)
    _bar(img, foot, 0.0, 1.2, 0.05, WHITE)
    res = perspective.extract_frame(img, CAM, CONF)
    assert len(res["posts"]) == 1, res["posts"]
    d, bearing, confidence = res["posts"][0]
    assert abs(d - np.hypot(*foot)) < 0.15
    assert abs(bearing - math.atan2(foot[1], foot[0])) < 0.03
    assert confidence > 0
    assert len(_used_lines(res)) == 0  # the post's lower part is not a field line


def test_goal_post_in_front_of_its_net_is_a_post_not_a_line():
    """Behind a goal post the net shows carpet, so the field boundary climbs to the crossbar:
    the post does not rise above the boundary, yet its bar is a post, not a field line."""
    foot = np.array([2.0, 0.4])
    img = draw_scene([], carpet_x=3.0)
    base = CAM.project(np.array([[foot[0], foot[1], 0.0]]), inside=False)[0]
    top = CAM.project(np.array([[foot[0], foot[1], 0.6]]), inside=False)[0]
    u0 = int(base[0])
    cv2.rectangle(img, (u0 - 90, int(top[1])), (u0 + 30, int(base[1])), GREEN, -1)  # the net
    _bar(img, foot, 0.0, 0.6, 0.05, WHITE)
    res = perspective.extract_frame(img, CAM, CONF)
    b = res["boundary"]
    assert b[np.argmin(np.abs(b[:, 0] - u0)), 1] < base[1] - 40  # the boundary climbed
    assert len(_used_lines(res)) == 0
    assert len(res["posts"]) == 1, res["posts"]
    d, bearing, _ = res["posts"][0]
    assert abs(d - np.hypot(*foot)) < 0.2
    assert abs(bearing - math.atan2(foot[1], foot[0])) < 0.03


@pytest.mark.parametrize("foot", [(1.2, 0.2), (1.0, -0.3), (1.5, 0.4), (1.3, -0.5), (1.1, 0.45)])
def test_a_robots_white_leg_is_no_field_line(foot):
    """A NAO's white leg stands on the floor below its grey body, short of the field
    boundary: its floor projection runs straight away from the robot like a field line seen
    along its length, but starts inside the image, which such a line could only do if the
    robot stood on its extension. It is no used line; a field line across the view and one
    the robot stands on (running out of the image's lower edge) stay used."""
    field_lines = [[[1.0, 1.2], [1.0, -1.2]], [[0.0, -0.05], [3.5, -0.05]]]
    img = draw_scene(field_lines, carpet_x=4.0)
    foot = np.array(foot)
    _bar(img, foot, 0.0, 0.27, 0.022, WHITE)  # a leg of the renderer's NAO (scene.nao_robot)
    _bar(img, foot, 0.27, 0.45, 0.05, (90, 90, 95))  # its grey hip and body above it
    res = perspective.extract_frame(img, CAM, CONF)
    used = _used_lines(res)
    ends = [e.reshape(2, 2) for _, e in used]
    # no used line lies on the leg's floor projection (the ray from the robot through its foot)
    ray = foot / np.hypot(*foot)
    on_leg = [e for e in ends if np.all(np.abs(e @ np.array([-ray[1], ray[0]])) < 0.1)
              and np.min(e @ ray) > 0.8 * np.hypot(*foot)]
    assert not on_leg, on_leg
    # both field lines are found and used
    for (a, b) in np.asarray(field_lines):
        d = [np.max(distance_to_lines(e, np.array([[a, b]]), np.zeros((0, 5)))) for e in ends]
        assert min(d) < 0.1, (a, b, ends)


# a NAO's top camera as the renderer's perspective-nao preset has it (HULKs' intrinsics)
NAO_CAM = PerspectiveCamera(image_size=(640, 480), fx=608.0, fy=609.6, cx=319.5, cy=239.5,
                            distortion=np.zeros(5), height=0.45, pitch=0.19)


def _nao(img, cam, centre, grey=(120, 122, 126), jersey=(200, 60, 200)):
    """Draw the renderer's NAO (scene.nao_robot: 0.57 m high, radius 0.1 m) standing at floor
    point ``centre`` (robot frame), facing the camera: its legs, its torso and jersey, and its
    white arms beside the torso; returns the image points (bottom, top) of its arms' axes."""
    centre = np.asarray(centre, float)
    side = np.array([-centre[1], centre[0]]) / np.hypot(*centre)
    for s in (-1.0, 1.0):
        _bar(img, centre + s * 0.045 * side, 0.017, 0.274, 0.022, WHITE, cam)
    _bar(img, centre, 0.274, 0.479, 0.08, grey, cam)
    _bar(img, centre, 0.342, 0.445, 0.082, jersey, cam)
    return [_bar(img, centre + s * 0.105 * side, 0.285, 0.456, 0.012, WHITE, cam)
            for s in (-1.0, 1.0)]


@pytest.mark.parametrize("centre", [(1.3, 0.3), (1.6, -0.2), (2.0, 0.5)])
def test_a_robots_white_arm_is_no_goal_post(centre):
    """A NAO's white arm hangs beside its torso and crosses the field boundary like a post;
    taken for one, its lower end (0.29 m above the floor) puts its foot far beyond the robot,
    where the bar's few pixels measure under half a metre: no goal post shows so little of
    itself unless it runs out of the image. A real goal post beside it is still found."""
    img = draw_scene([], carpet_x=6.0, cam=NAO_CAM)
    arms = _nao(img, NAO_CAM, centre)
    post = np.array([3.0, -1.2 if centre[1] > 0 else 1.2])
    _bar(img, post, 0.0, 0.8, 0.05, WHITE, NAO_CAM)
    res = perspective.extract_frame(img, NAO_CAM, CONF)
    px = res["posts_px"]
    for bottom, _ in arms:
        assert not any(abs(p[0] - bottom[0]) < 12 for p in px), (px, bottom)
    assert len(res["posts"]) == 1, res["posts"]
    assert abs(res["posts"][0][0] - np.hypot(*post)) < 0.3


@pytest.mark.parametrize("distance", [0.9, 1.2, 1.6])
def test_a_near_post_cut_by_the_images_top_edge_is_found(distance):
    """A camera looking down shows a near post's lower part only, less than a post's
    smallest visible height; where its bar runs out of the image its height is unknown, not
    small, and it is a post."""
    cam = NAO_CAM.with_pose(pitch=0.45)
    foot = np.array([distance, 0.25])
    img = draw_scene([], carpet_x=distance + 0.8, cam=cam)
    _, top = _bar(img, foot, 0.0, 0.8, 0.05, WHITE, cam)
    assert top[1] < 0  # the post's top is out of sight
    res = perspective.extract_frame(img, cam, CONF)
    d, bearing = np.hypot(*foot), math.atan2(foot[1], foot[0])
    found = [p for p in res["posts"] if p[2] == 1.0]  # found rising above the boundary
    assert len(found) == 1, res["posts"]
    assert abs(found[0][0] - d) < 0.1 and abs(found[0][1] - bearing) < 0.05, (found, d, bearing)


@pytest.mark.parametrize("carpet_x", [2.2, 2.6])
def test_the_carpets_edge_against_a_bright_floor_is_not_a_used_line(carpet_x, monkeypatch):
    """The carpet ends ``carpet_x`` m ahead at a light grey hall floor: its edge is white
    against green as a line is, but no carpet lies beyond it and the field boundary is at it
    (field_edge), so only the painted line at 1.5 m is used; without the check the edge is
    used as a line too."""
    fl = _floor_of_pixels()
    img = draw_scene([[[1.5, -2.0], [1.5, 2.0]]], carpet_x=carpet_x).astype(np.float32)
    floor = np.isfinite(fl[..., 0]) & ((fl[..., 0] > carpet_x) | (np.abs(fl[..., 1]) > 4.0))
    img[floor] = (200, 200, 205)
    img = np.clip(img + np.random.default_rng(1).normal(0.0, 4.0, img.shape), 0, 255)
    img = img.astype(np.uint8)
    used = [ln[0] for ln, _ in _used_lines(perspective.extract_frame(img, CAM, CONF))]
    assert len(used) == 1 and abs(used[0] - 1.5) < 0.05, used
    # no edge check (the extractor reads its tuned constants, line_fit.LINES, on each call)
    monkeypatch.setattr(perspective, "LINES", perspective.LINES._replace(min_green_beyond=0.0))
    used = [ln[0] for ln, _ in _used_lines(perspective.extract_frame(img, CAM, CONF))]
    assert any(abs(d - carpet_x) < 0.2 for d in used), used


def test_field_edge_looks_across_the_line_away_from_the_robot():
    """A grid green only nearer than 2 m (lens without distortion, no pitch) and the boundary
    2 m away in every column: a segment at 1.5 m has green 0.15 m beyond it and the
    boundary 0.5 m on, one at 1.95 m neither, and one behind the camera is out of view."""
    cam = CAM
    to_floor = perspective.FloorProjection(cam)
    cell = int(CONF["cell"])
    w, h = cam.image_size
    vv, uu = np.mgrid[0:h // cell, 0:w // cell]
    px = np.stack([(uu + 0.5) * cell - 0.5, (vv + 0.5) * cell - 0.5], -1).reshape(-1, 2)
    fl = cam.pixel_to_floor(px).reshape(h // cell, w // cell, 2)
    green = (np.isfinite(fl[..., 0]) & (fl[..., 0] < 2.0)).astype(np.float32)
    segs = np.array([[[1.5, -0.3], [1.5, 0.3]], [[1.95, 0.3], [1.95, -0.3]],
                     [[-1.0, -0.3], [-1.0, 0.3]]])
    boundary_range = np.full(w // cell, 2.0)
    share, gap = perspective.field_edge(segs, to_floor, line_fit.lens_parameters(cam), green,
                                        boundary_range, cell, 0.15)
    assert share[0] == 1.0 and share[1] == 0.0 and np.isnan(share[2]), share
    # the gap is the boundary's range less the segment point's, along each column's ray
    assert 0.45 < gap[0] < 0.5 and 0.0 < gap[1] < 0.05 and np.isnan(gap[2]), gap


def test_a_line_in_a_sun_patch_with_field_beyond_stays_used(monkeypatch):
    """Carpet washed out to grey beyond a line (a sun patch from 1.55 to 2.5 m) fails the
    green test there, but the field goes on past the patch: the line is no field edge."""
    fl = _floor_of_pixels()
    img = draw_scene([[[1.5, -2.0], [1.5, 2.0]]], carpet_x=4.0).astype(np.float32)
    patch = np.isfinite(fl[..., 0]) & (fl[..., 0] > 1.55) & (fl[..., 0] < 2.5)
    img[patch] = (110, 125, 110)  # grey-green: neither field green nor white
    img = np.clip(img + np.random.default_rng(1).normal(0.0, 4.0, img.shape), 0, 255)
    img = img.astype(np.uint8)
    res = perspective.extract_frame(img, CAM, CONF)
    assert any(abs(ln[0] - 1.5) < 0.05 for ln, _ in _used_lines(res)), res["lines"]
    # by the green beyond it alone it would be the field's edge
    monkeypatch.setattr(perspective, "LINES", perspective.LINES._replace(edge_gap_m=math.inf))
    assert not _used_lines(perspective.extract_frame(img, CAM, CONF))


def test_result_has_the_schema_datasets_and_overlay_draws_them():
    segments, *_ = DRAWN["T"]
    img = draw_scene(segments)
    res = perspective.extract_frame(img, CAM, CONF, pitch=CAM.pitch, roll=0.0)
    assert set(res) <= set(FRAME_DATASETS)
    shapes = {"boundary": 2, "line_ends": 4, "line_ends_px": 4, "lines": 4, "crossings": 5,
              "crossings_px": 2, "posts": 3, "posts_px": 2}
    for key, cols in shapes.items():
        assert res[key].ndim == 2 and res[key].shape[1] == cols, key
    assert len(res["boundary"]) == CAM.image_size[0] // CONF["cell"]
    out = perspective.debug_overlay(img, res)
    assert out.shape == img.shape and not np.array_equal(out, img)  # exact integers: uint8 images
    # the crossing is marked in yellow at its image position
    u, v = np.round(res["crossings_px"][0]).astype(int)
    patch = out[v - 8:v + 9, u - 8:u + 9].reshape(-1, 3)
    assert np.any(np.all(patch == (0, 230, 255), axis=1))


def test_head_angles_change_the_floor_projection():
    segments, where, *_ = DRAWN["L"]
    img = draw_scene(segments)
    near = perspective.extract_frame(img, CAM, CONF, pitch=CAM.pitch + 0.05)["crossings"]
    assert len(near) == 1
    # looking further down than the frame was taken: the crossing seems nearer
    assert near[0, 1] < np.hypot(*where) - 0.1


# ---------------------------------------------------------------------------- single steps


def test_height_histogram_stops_after_more_than_four_empty_cells():
    field = np.zeros((20, 3), bool)
    field[10:, 0] = True  # field up to row 10
    field[10:, 1] = True
    field[3:6, 1] = True  # 4 empty rows (6..9) then field again: the scan goes on
    field[12:, 2] = True
    field[2:7, 2] = True  # 5 empty rows (7..11): the scan stops
    assert field_height_histogram(field).tolist() == [10.0, 17.0, 8.0]


def test_local_convex_filling_fills_a_narrow_gap_but_not_a_wide_dent():
    narrow = np.array([20, 20, 20, 12, 20, 20, 20], float)
    assert local_convexity(narrow)[3] < 0
    assert local_convex_filling(narrow)[3] == 20
    wide = np.array([20] * 5 + [8] * 8 + [20] * 5, float)
    filled = local_convex_filling(wide)
    assert np.all(filled[7:11] == 8)  # the dent's inside stays: a robot is not field


def test_ranking_skeleton_keeps_one_ridge_of_a_two_cell_wide_line():
    img = np.zeros((12, 30), np.float32)
    img[5:7, 3:27] = 0.5  # a horizontal line two cells wide with equal values
    lp = low_pass(img)
    skeleton, c = ranking_skeleton(lp, 0.02)
    cols = skeleton[:, 6:24]
    assert np.all(cols.sum(axis=0) == 1)  # one skeleton pixel per cross-section
    pix, regions = place_nodes(lp, skeleton, c)
    gaps = np.abs(pix[:, None, :] - pix[None, :, :]).max(axis=2) + np.eye(len(pix), dtype=int) * 9
    assert gaps.min() >= 2  # nodes at least two pixels apart
    assert np.all(regions[skeleton] > 0)  # every skeleton pixel belongs to a node


def test_split_and_merge():
    t = np.linspace(0, 10, 11)
    corner = np.concatenate([np.stack([t, 0 * t], 1), np.stack([10 + 0 * t[1:], t[1:]], 1)])
    parts = split_component(corner, np.arange(len(corner)), 1.0)
    assert len(parts) == 2 and parts[0][-1] == parts[1][0] == 10  # split at the corner
    line = np.stack([np.linspace(0, 30, 16), 0.1 * np.sin(np.arange(16))], 1)
    merged = merge_segments(line, [np.arange(0, 6), np.arange(9, 16)], math.radians(4), 1.0,
                            1.0)
    assert len(merged) == 1 and len(merged[0]) == 13
    fit = fit_line(line)
    assert abs(fit.direction[1]) < 0.01 and fit.rms < 0.1
    dist, angle, length = floor_line_parameters(np.array([1.0, -2.0]), np.array([1.0, 2.0]))
    assert (dist, angle, length) == pytest.approx((1.0, 0.0, 4.0))


# ---------------------------------------------------------------------------- rendered frames


def test_rendered_frames_match_the_field_model_at_the_true_pose():
    """Frames of the perspective renderer (wide-angle lens, clutter, noise) near a goal area:
    lines and crossings projected to the floor and moved to the field with the true pose lie
    on the field model. Tolerances: used lines' worst point within 0.08 m (median) and 0.25 m
    (for 75 % of them); crossings within 0.3 m of a model crossing of the same type (80 %),
    median orientation error 10 deg."""
    fm = load_field("kidsize")
    n = 10
    world = scene.build(fm, None, np.arange(n) / 30.0, 7)
    renderer = PerspectiveRenderer(None, world, seed=7)
    cam = renderer.camera
    rng = np.random.default_rng(11)
    line_err, cross = [], []
    for k in range(n):
        pose = np.array([rng.uniform(1.0, 3.0), rng.uniform(-2, 2), rng.uniform(-0.8, 0.8)])
        pitch, roll = cam.pitch + rng.normal(0, 0.02), rng.normal(0, 0.02)
        img = renderer.render_view(pose, pitch, roll, frame=k)
        res = perspective.extract_frame(img, cam, CONF, pitch=pitch, roll=roll)
        for _, e in _used_lines(res):
            s = np.linspace(0, 1, 5)[:, None]
            pts = robot_to_field(pose, e[:2] * (1 - s) + e[2:] * s)
            line_err.append(fm.distance_to_lines(pts).max())
        for c in res["crossings"]:
            kind = "LTX"[int(c[0])]
            p = robot_to_field(pose, _robot_xy(c)[None])[0]
            same = fm.crossing_types == kind
            d = np.hypot(*(fm.crossings[same] - p).T)
            j = int(np.argmin(d))
            period = math.pi / 2 if kind == "X" else 2 * math.pi
            dori = abs(math.remainder(c[3] + pose[2] - fm.crossing_orientation[same][j], period))
            cross.append((d[j], dori))
    line_err = np.array(line_err)
    assert len(line_err) >= 3 * n
    assert np.median(line_err) < 0.08
    assert np.mean(line_err < 0.25) >= 0.75
    cross = np.array(cross)
    assert len(cross) >= 4
    good = cross[:, 0] < 0.3
    assert good.mean() >= 0.8
    assert np.median(cross[good, 1]) < math.radians(10)


def test_debug_images_are_written_per_frame(tmp_path):
    """`fieldloc extract --debug-images DIR`: one overlay per extracted frame, like fig. 1."""
    from click.testing import CliRunner

    from fieldloc_cli.main import cli
    from stages import simulate

    conf = dict(simulate.confs["perspective-default"], frames=2, seed=1)
    data = simulate.main(conf, "kidsize", tmp_path / "kid")
    res = CliRunner().invoke(cli, ["extract", str(data), "--debug-images",
                                   str(tmp_path / "dbg")])
    assert res.exit_code == 0, res.output
    pngs = sorted(p.name for p in (tmp_path / "dbg").glob("*.png"))
    assert pngs == ["000000.png", "000001.png"]
    assert (tmp_path / "dbg" / "debug-images.yaml").is_file()  # the folder is extract's
    img = cv2.imread(str(tmp_path / "dbg" / pngs[0]))
    raw = cv2.imread(str(data / "images" / pngs[0]))
    assert img.shape == raw.shape and np.any(img != raw)  # something was drawn


# ---------------------------------------------------------------------------- speed-up reference
# The line refinement before it became a compiled kernel (line_fit.refine_segment), kept here as
# the reference: numpy on whole profiles, the lens's distortion by PerspectiveCamera. The
# colour classes' reference is colour.classify_grid (numpy, as the omni extractor uses it).


def _ref_bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples (float64) of ``image`` at pixel positions (x, y) (pixel centres at
    integers), pixels outside the image counting 0."""
    h, w = image.shape
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx, fy = x - x0, y - y0
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    out = np.zeros(np.shape(x))
    for dy, wy in ((0, 1.0 - fy), (1, fy)):
        for dx, wx in ((0, 1.0 - fx), (1, fx)):
            xi, yi = x0 + dx, y0 + dy
            ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
            v = np.where(ok, image[np.clip(yi, 0, h - 1), np.clip(xi, 0, w - 1)], 0.0)
            out += v * (wx * wy)
    return out


def _ref_white_profiles(white: np.ndarray, to_image, origin: np.ndarray, direction: np.ndarray,
                   along: np.ndarray, across: np.ndarray) -> np.ndarray:
    """White share (S, T) sampled bilinearly from the full-resolution mask ``white`` at ideal
    points origin + along[s] * direction + across[t] * normal; ``to_image`` maps ideal pixels
    (N, 2) to image pixels (the lens's distortion)."""
    normal = np.array([-direction[1], direction[0]])
    pts = (origin[None, None, :] + along[:, None, None] * direction[None, None, :]
           + across[None, :, None] * normal[None, None, :])
    img = to_image(pts.reshape(-1, 2)).reshape(len(along), len(across), 2)
    return _ref_bilinear(white, img[..., 0], img[..., 1])


def _ref_run_centres(profiles: np.ndarray, across: np.ndarray, level: float = 0.5
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per profile (row of ``profiles``, sampled at offsets ``across``, 1 px apart): the centre
    (white-weighted mean offset) and width (summed white share, px) of the white run (samples
    >= ``level``) nearest the profile's middle, and whether there is one that does not touch
    the profile's ends (a run reaching both ends is a white area, not a line)."""
    s, t = profiles.shape
    on = profiles >= level
    mid = t // 2
    idx = np.arange(t)
    # runs: label consecutive on-samples; pick the run whose nearest sample is closest to mid
    start = on & ~np.concatenate([np.zeros((s, 1), bool), on[:, :-1]], axis=1)
    label = np.cumsum(start, axis=1) * on
    dist = np.where(on, np.abs(idx - mid)[None, :], t + 1)
    best = np.argmin(dist, axis=1)
    ok = on[np.arange(s), best]
    chosen = label == label[np.arange(s), best][:, None]
    chosen &= on & ok[:, None]
    touches = chosen[:, 0] | chosen[:, -1]
    w = np.where(chosen, profiles, 0.0)
    mass = w.sum(axis=1)
    centre = np.where(mass > 0, (w * across[None, :]).sum(axis=1) / np.maximum(mass, 1e-9), 0.0)
    return centre, mass * float(across[1] - across[0]), ok & ~touches


def _ref_robust_fit(points: np.ndarray, min_residual: float = 1.5, max_gap: int = 12,
               iterations: int = 3) -> tuple[LineFit, np.ndarray]:
    """A line through ordered points (n, 2) (white-run centres along a segment) that may bend
    onto a neighbouring line at either end: fitted first to the middle half, then to the
    points within max(``min_residual``, 3 robust sigmas) of the fit that are connected to the
    middle (inliers with at most ``max_gap`` outliers between them), again until that set
    stops changing. Returns the fit and the inlier mask."""
    n = len(points)
    keep = np.zeros(n, bool)
    keep[n // 4: n - n // 4] = True
    if keep.sum() < 2:
        keep[:] = True
    fit = fit_line(points[keep])
    mid = n // 2
    for _ in range(iterations):
        r = (points - fit.centroid) @ fit.normal
        core = r[keep]
        sigma = 1.4826 * float(np.median(np.abs(core - np.median(core))))
        ok = np.abs(r) <= max(min_residual, 3.0 * sigma)
        # the run of inliers around the middle, bridging at most max_gap outliers
        edges = np.diff(np.concatenate([[0], (~ok).astype(np.int8), [0]]))
        starts, stops = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
        wide = stops - starts > max_gap
        lo = int(max((b for a, b in zip(starts[wide], stops[wide]) if b <= mid), default=0))
        hi = int(min((a for a in starts[wide] if a > mid), default=n))
        new = ok.copy()
        new[:lo] = False
        new[hi:] = False
        if new.sum() < 2:
            break
        if np.array_equal(new, keep):  # exact decisions: inlier masks
            break
        keep = new
        fit = fit_line(points[keep])
    return fit, keep


def _ref_refine_segment(ends: np.ndarray, white: np.ndarray, to_image, step: float,
                   reach: float, extend: float, min_points: int, grow: float = 0.0
                   ) -> RefinedLine | None:
    """The coarse segment ``ends`` (2, 2, ideal px) refined on the full-resolution white mask:
    perpendicular profiles every ``step`` px from ``extend`` px before its first end to
    ``extend`` px beyond its second, each ``reach`` px to either side; the centres of their
    white runs fitted robustly (``robust_fit``); the refined segment spans the extreme inliers,
    then grows along the fit at each end for up to ``grow`` px while the profiles there still
    cross a white run on the line (``grow_end``: the grid's skeleton stops short of corners).
    None when fewer than ``min_points`` profiles cross a white run."""
    d = ends[1] - ends[0]
    length = float(np.hypot(*d))
    if length < 1e-6:
        return None
    u = d / length
    along = np.arange(-extend, length + extend + 1e-9, step)
    across = np.arange(-reach, reach + 0.5, 1.0)
    prof = _ref_white_profiles(white, to_image, ends[0], u, along, across)
    centre, width, ok = _ref_run_centres(prof, across)
    if ok.sum() < min_points:
        return None
    n = np.array([-u[1], u[0]])
    pts = ends[0][None] + along[ok, None] * u[None] + centre[ok, None] * n[None]
    fit, keep = _ref_robust_fit(pts)
    if keep.sum() < min_points:
        return None
    pts, width = pts[keep], width[ok][keep]
    t = (pts - fit.centroid) @ fit.direction
    lo, hi = fit.centroid + t.min() * fit.direction, fit.centroid + t.max() * fit.direction
    if (hi - lo) @ u < 0:
        lo, hi = hi, lo
    if grow > 0:
        r = (pts - fit.centroid) @ fit.normal
        tol = max(1.5, 3.0 * 1.4826 * float(np.median(np.abs(r - np.median(r)))))
        d = (hi - lo) / max(float(np.hypot(*(hi - lo))), 1e-9)
        lo = _ref_grow_end(lo, -d, white, to_image, step, reach, grow, tol)
        hi = _ref_grow_end(hi, d, white, to_image, step, reach, grow, tol)
    return RefinedLine(np.stack([lo, hi]), fit, pts, width)


def _ref_grow_end(end: np.ndarray, direction: np.ndarray, white: np.ndarray, to_image, step: float,
             reach: float, grow: float, tol: float, misses: int = 2) -> np.ndarray:
    """``end`` moved along ``direction`` (unit, ideal px) in ``step`` px steps, up to ``grow``
    px, to the last profile whose white run lies within ``tol`` px of the line before
    ``misses`` consecutive profiles without (a corner's other line makes a white area across
    the profile: no run, so the line stops there)."""
    along = np.arange(step, grow + 1e-9, step)
    if len(along) == 0:
        return end
    across = np.arange(-reach, reach + 0.5, 1.0)
    prof = _ref_white_profiles(white, to_image, end, direction, along, across)
    centre, _, ok = _ref_run_centres(prof, across)
    ok &= np.abs(centre) <= tol
    last = -1
    miss = 0
    for k in range(len(along)):
        if ok[k]:
            last, miss = k, 0
        else:
            miss += 1
            if miss >= misses:
                break
    return end if last < 0 else end + along[last] * direction


def _reference_refine(ends, white, lens, step, reach, extend, min_points, grow=0.0):
    fx, fy, cx, cy, *dist = lens
    cam = PerspectiveCamera(fx=fx, fy=fy, cx=cx, cy=cy, distortion=np.array(dist))
    return _ref_refine_segment(ends, white, cam.distort_points, step, reach, extend,
                               min_points, grow)


@pytest.mark.parametrize("preset,field", [("perspective-default", "kidsize"),
                                          ("perspective-nao", "spl")])
def test_compiled_kernels_give_the_reference_features(preset, field, monkeypatch):
    """The speed-up (compiled colour classes, compiled line refinement) keeps the features:
    rendered frames of both cameras extracted by the product path and by the reference
    implementations give the same rows (to 1e-6)."""
    from stages import simulate
    from stages.common import colour

    fm = load_field(field)
    conf = dict(simulate.confs[preset])
    world = scene.build(fm, conf["scene"], np.arange(3) / 10.0, 4)
    renderer = PerspectiveRenderer(conf["perspective"], world, seed=4)
    cam = renderer.camera
    rng = np.random.default_rng(8)
    frames = []
    for k in range(3):
        pose = np.array([fm.length / 2 - rng.uniform(1.0, 3.5), rng.uniform(-2, 2),
                         rng.uniform(-0.5, 0.5)])
        pitch, roll = cam.pitch + rng.normal(0, 0.03), rng.normal(0, 0.02)
        frames.append((renderer.render_view(pose, pitch, roll, frame=k), pitch, roll))
    ext = perspective.confs["default"]
    fast = [perspective.extract_frame(img, cam, ext, pitch=p, roll=r) for img, p, r in frames]
    monkeypatch.setattr(perspective, "refine_segments",  # lines
                        lambda ends, *a, **k: [_reference_refine(e, *a, **k) for e in ends])
    # (the crossings' placement, crossings.place_crossing, is checked against where drawn
    # lines meet in test_perspective_kernels)
    monkeypatch.setattr(line_fit, "refine_segment", _reference_refine)
    monkeypatch.setattr(colour, "classify_cells", lambda *a, **k: None)
    slow = [perspective.extract_frame(img, cam, ext, pitch=p, roll=r) for img, p, r in frames]
    found = 0
    for a, b in zip(fast, slow):
        for key in a:
            assert a[key].shape == b[key].shape, key
            np.testing.assert_allclose(a[key], b[key], atol=1e-6, err_msg=key)
        found += len(a["lines"])
    assert found >= 6  # the frames hold lines to compare


def test_the_view_is_the_floor_below_the_boundary_within_its_range():
    """The view polygon (the unseen term's "where a line should have been found") holds the
    floor points whose pixels lie in the image below the field boundary and within
    VIEW_RANGE, and no others, except within a few cm of its edge (its samples are 16 px
    apart and the lens bends the image's edges): a drawn scene with the carpet's far edge
    2.5 m ahead (the boundary), at two head pitches."""
    from matplotlib.path import Path as Polygon

    for pitch in (CAM.pitch, CAM.pitch + 0.15):
        cam = CAM.with_pose(pitch=pitch)
        img = draw_scene(np.zeros((0, 2, 2)), carpet_x=2.5, cam=cam)
        res = perspective.extract_frame(img, cam, CONF, pitch=pitch, roll=0.0)
        view = res["view"].astype(float)
        assert view.shape[0] >= 3 and np.isfinite(view).all()
        assert np.hypot(*view.T).max() <= perspective.VIEW_RANGE + 1e-3
        rng = np.random.default_rng(0)
        pts = np.column_stack([rng.uniform(0.0, 4.0, 4000), rng.uniform(-3.0, 3.0, 4000)])
        uv = cam.floor_to_pixel(pts, pitch, 0.0)
        w, h = cam.image_size
        in_image = np.isfinite(uv).all(axis=1)
        in_image[in_image] &= ((uv[in_image] >= 0) & (uv[in_image] <= [w - 1, h - 1])).all(1)
        # on the carpet (the boundary lies at its far edge), with a margin for the boundary's
        # cells (8 px)
        expected = in_image & (pts[:, 0] < 2.4)
        outside = in_image & (pts[:, 0] > 2.7) | ~in_image
        inside = Polygon(view).contains_points(pts)
        edge = np.array([Polygon(view).contains_point(p, radius=0.1)
                         != Polygon(view).contains_point(p, radius=-0.1) for p in pts])
        assert np.all(inside[expected & ~edge])
        assert not np.any(inside[outside & ~edge])
        assert expected.sum() > 500


def test_a_frame_without_floor_in_range_has_an_empty_view():
    """Looking at the sky (the horizon below the image), no floor is in range."""
    img = np.full((CAM.image_size[1], CAM.image_size[0], 3), WALL, np.uint8)
    res = perspective.extract_frame(img, CAM, CONF, pitch=-0.6, roll=0.0)
    assert res["view"].shape == (0, 2)
