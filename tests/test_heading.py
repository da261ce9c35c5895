"""Heading for the table search: line-point histograms (Ribeiro et al. 2015, V-B), IMU alignment,
and the per-frame lookup of imu.csv / truth.csv rows."""

from __future__ import annotations

import math

import numpy as np

from stages.common.field import load_field
from stages.common.geometry import field_to_robot, wrap_angle
from stages.localize.heading import (
    HISTOGRAM_MIN_SHARPNESS,
    ImuAlignment,
    histogram_heading,
    imu_per_frame,
    nearest_rows,
    truth_heading,
)

MIN_SHARPNESS = HISTOGRAM_MIN_SHARPNESS  # lut's and fit's (1.7)


def line_points(fm, pose, rng, *, spacing=0.05, noise=0.02, clutter=0.15, max_range=4.0):
    """Line points (robot frame) a robot at ``pose`` sees: samples along every centre line
    within range, with noise, a share of random clutter points and random gaps."""
    pts = []
    for a, b in fm.segments:
        n = max(2, int(np.hypot(*(b - a)) / spacing))
        t = np.linspace(0.0, 1.0, n)[:, None]
        pts.append(a + t * (b - a))
    for cx, cy, r, a0, sweep in fm.arcs:
        n = max(2, int(r * sweep / spacing))
        ang = a0 + np.linspace(0.0, sweep, n)
        pts.append(np.stack([cx + r * np.cos(ang), cy + r * np.sin(ang)], axis=1))
    p = field_to_robot(pose, np.concatenate(pts))
    d = np.hypot(p[:, 0], p[:, 1])
    p = p[(d >= 0.25) & (d <= max_range) & (rng.random(len(p)) > 0.3)]
    p = p + rng.normal(0.0, noise, p.shape)
    k = int(clutter * len(p))
    ang, rad = rng.uniform(-math.pi, math.pi, k), rng.uniform(0.25, max_range, k)
    return np.concatenate([p, np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=1)])


def test_histogram_heading_tracks_a_turning_robot():
    """Over a drive with turns of up to 6 deg per frame the histogram heading stays within
    3 deg; where it cannot judge (no straight line in view) its sharpness says so and the
    tracker keeps the predicted heading (odometry's turn)."""
    fm = load_field("msl-2015")
    rng = np.random.default_rng(1)
    n = 60
    turn = np.radians(rng.uniform(-6.0, 6.0, n))
    theta = np.cumsum(turn) + 0.4
    x = np.linspace(-7.0, 7.0, n)
    y = 2.5 * np.sin(np.linspace(0, 3, n))
    estimate = theta[0] + math.radians(2.0)
    errors, judged = [], 0
    for i in range(1, n):
        predicted = estimate + turn[i]
        pts = line_points(fm, (x[i], y[i], theta[i]), rng)
        h, sharp = histogram_heading(pts, predicted)
        if np.isfinite(h) and sharp >= MIN_SHARPNESS:
            estimate = h
            judged += 1
        else:
            estimate = predicted
        errors.append(abs(math.degrees(float(wrap_angle(estimate - theta[i])))))
    assert max(errors) <= 3.0, np.round(errors, 2)
    assert judged >= 0.8 * (n - 1)
    assert np.median(errors) < 1.0


def test_histogram_heading_recovers_an_offset_within_the_window():
    fm = load_field("msl-2015")
    rng = np.random.default_rng(2)
    for offset in (-35.0, -20.0, 15.0, 38.0):
        pose = (-6.0, 1.0, 0.7)
        pts = line_points(fm, pose, rng, clutter=0.0)
        h, sharp = histogram_heading(pts, pose[2] + math.radians(offset))
        assert sharp >= MIN_SHARPNESS
        assert abs(math.degrees(float(wrap_angle(h - pose[2])))) < 1.5


def test_histogram_heading_needs_points():
    h, sharp = histogram_heading(np.zeros((3, 2)) + 1.0, 0.0)
    assert math.isnan(h) and sharp == 0.0


def test_imu_alignment_tracks_the_bias_and_rejects_outliers():
    rng = np.random.default_rng(3)
    true_offset = 0.3
    al = ImuAlignment(offset=0.0, variance=math.radians(20.0) ** 2)
    for i in range(200):
        yaw = rng.uniform(-math.pi, math.pi)
        field_heading = yaw + true_offset
        vision = field_heading + rng.normal(0.0, math.radians(1.0))
        if i % 25 == 24:
            vision += math.pi / 2  # a wrong vision heading
        al.predict()
        al.update(float(vision), float(yaw), math.radians(1.0) ** 2)
    assert abs(al.offset - true_offset) < math.radians(0.5)
    assert abs(al.heading(1.0) - float(wrap_angle(1.0 + al.offset))) < 1e-12


def test_rows_by_stamp_within_tolerance():
    src = np.array([0.0, 0.1, 0.2, 0.5])
    idx = nearest_rows(src, np.array([0.01, 0.14, 0.35, 0.51, 2.0]), 0.05)
    assert idx.tolist() == [0, 1, -1, 3, -1]
    imu = {"stamp": src, "yaw": np.array([0.1, 0.2, 0.3, 0.4]),
           "collision": np.array([0.0, 1.0, 0.0, 0.0])}
    yaw, col = imu_per_frame(imu, np.array([0.1, 0.3]), 0.02)
    assert yaw[0] == 0.2 and col[0] and np.isnan(yaw[1]) and not col[1]
    truth = {"stamp": src, "theta": np.array([1.0, 2.0, 3.0, 4.0])}
    assert truth_heading(truth, np.array([0.19]), 0.02).tolist() == [3.0]
