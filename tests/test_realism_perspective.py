"""Rendered NAO frames (``simulate perspective --preset perspective-nao``) held against the real
NAO frames of ../shared/realdata/hulks-goalbox-labels (GUIDE section 7), on measurable points,
as test_realism_omni.py does for the omni camera.

Colour space: YUV as OpenCV's COLOR_BGR2YUV (BT.601, U and V centred on 128), the one the
extractor classifies in. Field green and line white are picked by the same loose,
classifier-independent rule in real and rendered frames (test_realism_omni.green_and_white).

Line width: along lines on the floor (the labelled lines of the real frames, projected with
each frame's camera matrix; the field model's lines at the true pose of the rendered ones),
the full width at half maximum of the luminance across the line in the image, over the width a
painted line of the field's line width has there (so that the line's orientation and range
drop out), in bins of range.

False white: the share of the white pixels below the horizon whose floor point lies on the
field (inside its lines plus 0.3 m) but farther than 0.15 m from every line: balls, robots'
legs, goal posts, reflections. The real frames' field pose comes from their labels
(test_extract_hulks.field_pose_from_labels).

Skipped when ../shared/realdata is absent.
"""

from __future__ import annotations

import copy
import functools
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from stages import simulate
from stages.common.field import load_field
from stages.common.geometry import field_to_robot, robot_to_field
from stages.simulate import scene
from stages.simulate.perspective_renderer import PerspectiveRenderer

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
HULKS = REALDATA / "hulks-goalbox-labels" / "measurements"
pytestmark = [
    pytest.mark.realdata,
    pytest.mark.skipif(not HULKS.is_dir(), reason="needs ../shared/realdata"),
]
RANGE_BINS = (0.5, 1.0, 1.5, 2.5, 4.0)


@dataclass
class Frame:
    image: np.ndarray  # BGR
    camera: object  # PerspectiveCamera at the frame's pose
    lines: np.ndarray  # (K, 2, 2) floor segments in the robot frame whose width is measured
    pose: np.ndarray | None  # robot pose on the field (x, y, theta)
    hidden: np.ndarray | None = None  # bool (h, w): pixels on things standing on the floor


def green_and_white(img):
    """YUV image and masks of field green and line white by a loose rule (as
    test_realism_omni)."""
    yuv = cv2.cvtColor(img, cv2.COLOR_BGR2YUV)
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    y, u, v = (yuv[..., i].astype(float) for i in range(3))
    green = (hsv[..., 0] > 35) & (hsv[..., 0] < 85) & (hsv[..., 1] > 80) & (hsv[..., 2] > 40)
    near_green = cv2.boxFilter(green.astype(np.float32), -1, (21, 21)) > 0.3
    local = cv2.medianBlur(yuv[..., 0], 21).astype(float)
    white = near_green & (y > local + 35) & (np.abs(u - 128) < 25) & (np.abs(v - 128) < 25)
    return yuv.astype(float), green, white


def colour_spread(images):
    greens, whites, medians = [], [], []
    for img in images:
        yuv, g, w = green_and_white(img)
        greens.append(yuv[g])
        whites.append(yuv[w])
        medians.append(np.median(yuv[g][:, 0]))
    return np.concatenate(greens), np.concatenate(whites), np.asarray(medians)


def line_widths(img, cam, segments, line_width: float = 0.05, hidden=None, step: float = 0.1,
                search: float = 6.0) -> np.ndarray:
    """(N, 2) [range (m), FWHM over a painted line's width] at points every ``step`` m along
    floor ``segments`` (K, 2, 2) that are in view (and not ``hidden``): the luminance profile
    across the line's image direction, its maximum within ``search`` px of the projected
    point, half maximum over the profile's outer quarters."""
    y = cv2.cvtColor(img, cv2.COLOR_BGR2YUV)[..., 0].astype(np.float32)
    h, w = y.shape
    t = np.arange(-30.0, 30.5, 0.5)
    out = []
    for seg in np.asarray(segments, float).reshape(-1, 2, 2):
        d = seg[1] - seg[0]
        length = float(np.hypot(*d))
        if length < 0.2:
            continue
        u = d / length
        n = np.array([-u[1], u[0]])
        s = np.arange(0.1, length - 0.1 + 1e-9, step)[:, None]
        p = seg[0] + s * u
        px = cam.floor_to_pixel(p)
        ahead = cam.floor_to_pixel(p + 0.05 * u)
        side = cam.floor_to_pixel(np.concatenate([p - 0.5 * line_width * n,
                                                  p + 0.5 * line_width * n]))
        side = side.reshape(2, -1, 2)
        for k in range(len(p)):
            if not (np.all(np.isfinite(px[k])) and np.all(np.isfinite(ahead[k]))
                    and np.all(np.isfinite(side[:, k]))):
                continue
            q = px[k]
            if not (35 <= q[0] < w - 35 and 35 <= q[1] < h - 35):
                continue
            if hidden is not None and hidden[int(q[1]), int(q[0])]:
                continue
            a = ahead[k] - q
            a /= max(np.hypot(*a), 1e-9)
            nrm = np.array([-a[1], a[0]], np.float32)
            expected = abs(float((side[1, k] - side[0, k]) @ nrm))
            if expected < 1.5:
                continue  # thinner than a pixel and a half: no width to measure
            pts = (q[None] + t[:, None] * nrm[None]).astype(np.float32)
            prof = cv2.remap(y, pts[None, :, 0], pts[None, :, 1], cv2.INTER_LINEAR)[0]
            mid = len(t) // 2
            win = int(search / 0.5)
            i = mid - win + int(np.argmax(prof[mid - win: mid + win + 1]))
            quarter = len(t) // 4
            base = float(np.median(np.concatenate([prof[:quarter], prof[-quarter:]])))
            peak = float(prof[i])
            if peak - base < 30:
                continue
            half = base + 0.5 * (peak - base)
            lo, hi = i, i
            while lo > 0 and prof[lo] > half:
                lo -= 1
            while hi < len(prof) - 1 and prof[hi] > half:
                hi += 1
            if lo == 0 or hi == len(prof) - 1:
                continue  # not a line: white to the profile's end
            out.append((float(np.hypot(*p[k])), (t[hi] - t[lo]) / expected))
    return np.array(out, float).reshape(-1, 2)


def width_table(samples) -> list[tuple[float, int]]:
    """Median width ratio and count per range bin of RANGE_BINS."""
    s = np.concatenate([a for a in samples if len(a)]) if samples else np.zeros((0, 2))
    out = []
    for lo, hi in zip(RANGE_BINS[:-1], RANGE_BINS[1:]):
        m = (s[:, 0] >= lo) & (s[:, 0] < hi)
        out.append((float(np.median(s[m, 1])) if m.sum() else float("nan"), int(m.sum())))
    return out


def false_white(img, cam, pose, field) -> float:
    """Share of the white pixels (loose rule) below the horizon whose floor point lies on the
    field but farther than 0.15 m from every line (module doc)."""
    _, _, white = green_and_white(img)
    vs, us = np.nonzero(white)
    if len(us) < 50:
        return float("nan")
    floor = cam.pixel_to_floor(np.stack([us, vs], axis=1).astype(float))
    ok = np.all(np.isfinite(floor), axis=1)
    pts = robot_to_field(pose, floor[ok])
    on = (np.abs(pts[:, 0]) <= field.length / 2 + 0.3) & (np.abs(pts[:, 1]) <= field.width / 2
                                                          + 0.3)
    if on.sum() < 50:
        return float("nan")
    d = field.distance_to_lines(pts[on])
    return float(np.mean(d > field.line_width / 2 + 0.15))


# ---------------------------------------------------------------------------- the frames


@functools.lru_cache(maxsize=1)
def hulks_frames() -> list[Frame]:
    """The real frames with their camera, labelled floor lines and labelled field pose."""
    import test_extract_hulks as labels

    from stages.calibrate import hulks

    spl = load_field("spl")
    out = []
    for js in sorted(HULKS.glob("*.json")):
        cam = hulks.read_frame(js).camera
        lab = labels.read_labels(js)
        floor = {k: cam.pixel_to_floor(v) for k, v in lab.items()}
        if not all(np.all(np.isfinite(v)) for v in floor.values()):
            continue
        pose = labels.field_pose_from_labels(floor, spl)
        img = cv2.imread(str(js.with_suffix(".jpg")))
        out.append(Frame(img, cam, np.stack(list(floor.values())), pose))
    return out


def nao_views(n: int, seed: int, field) -> list[tuple[np.ndarray, float, float]]:
    """Poses and head angles like the HULKs captures: a NAO 1-4 m in front of a goal area,
    looking at it (pitch 0-25 deg, roll within 3 deg)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        gx = field.length / 2
        x = gx - rng.uniform(1.0, 4.0)
        y = rng.uniform(-2.0, 2.0)
        target = np.array([gx - 0.3, rng.uniform(-1.5, 1.5)])
        theta = math.atan2(target[1] - y, target[0] - x)
        out.append((np.array([x, y, theta]), math.radians(rng.uniform(0.0, 25.0)),
                    math.radians(rng.uniform(-3.0, 3.0))))
    return out


@functools.lru_cache(maxsize=1)
def nao_frames(n: int = 12, seed: int = 3) -> list[Frame]:
    """Rendered frames of the ``perspective-nao`` preset at ``nao_views``."""
    field = load_field("spl")
    conf = copy.deepcopy(simulate.confs["perspective-nao"])
    # frames some seconds apart: the hall's light changes between them as between captures
    world = scene.build(field, conf["scene"], np.arange(n) * 2.3, seed)
    renderer = PerspectiveRenderer(conf["perspective"], world, seed)
    out = []
    for k, (pose, pitch, roll) in enumerate(nao_views(n, seed, field)):
        img, layers = renderer.render_view(pose, pitch, roll, frame=k, return_layers=True)
        cam = renderer.camera.with_pose(pitch=pitch, roll=roll)
        segs = field_to_robot(pose, field.segments.reshape(-1, 2)).reshape(-1, 2, 2)
        out.append(Frame(img, cam, segs, pose, layers["objects"]))
    return out


# ---------------------------------------------------------------------------- tests


def test_colour_spread_covers_the_real_nao_frames():
    rg, rw, rmed = colour_spread([f.image for f in hulks_frames()])
    sg, sw, smed = colour_spread([f.image for f in nao_frames()])
    tol = 4.0
    for name, r, s in (("green", rg, sg), ("white", rw, sw)):
        lo_r, hi_r = np.percentile(r, [5, 95], axis=0)
        lo_s, hi_s = np.percentile(s, [2, 98], axis=0)
        for k, ch in enumerate("YUV"):
            assert lo_s[k] <= lo_r[k] + tol, f"{name} {ch}: rendered low {lo_s[k]:.0f} > real" \
                f" {lo_r[k]:.0f}"
            assert hi_s[k] >= hi_r[k] - tol, f"{name} {ch}: rendered high {hi_s[k]:.0f} < real" \
                f" {hi_r[k]:.0f}"
    # dark and bright frames: the per-frame field luminance spans most of the real range
    assert smed.min() <= np.percentile(rmed, 10) and smed.max() >= np.percentile(rmed, 90)
    # and the rendered green is not absurdly wider than the real
    assert np.percentile(sg[:, 0], 98) - np.percentile(sg[:, 0], 2) < 2.0 * (
        np.percentile(rg[:, 0], 98) - np.percentile(rg[:, 0], 2))


def test_line_width_against_range_matches_the_real_nao_frames():
    real = width_table([line_widths(f.image, f.camera, f.lines) for f in hulks_frames()])
    sim = width_table([line_widths(f.image, f.camera, f.lines, hidden=f.hidden)
                       for f in nao_frames()])
    compared = 0
    for (r, nr), (s, ns) in zip(real, sim):
        if nr < 30 or ns < 30:
            continue
        assert abs(s - r) <= 0.35 * r, (real, sim)
        compared += 1
    assert compared >= 3, (real, sim)


def test_false_white_is_of_the_real_order():
    spl = load_field("spl")
    real = np.nanmedian([false_white(f.image, f.camera, f.pose, spl) for f in hulks_frames()])
    sim = np.nanmedian([false_white(f.image, f.camera, f.pose, spl) for f in nao_frames()])
    assert 0.5 * real <= sim <= 2.0 * real, (real, sim)
