"""Kalman filters of Ribeiro et al. (2015), IV-C: the vision and odometry nodes and their
decentralised fusion in information form (equations 6-9)."""

from __future__ import annotations

import math

import numpy as np

from stages.common.geometry import compose, wrap_angle
from stages.localize.kalman import DecentralisedFusion, Gaussian, LocalFilter, fuse


def test_one_node_fusion_equals_its_kalman_filter():
    prior = Gaussian(np.array([1.0, 2.0, 0.5]), np.diag([0.04, 0.09, 0.01]))
    node = LocalFilter("vision")
    node.predict(prior)
    post = node.correct(np.array([1.1, 1.9, 0.52]), np.diag([0.01, 0.01, 0.0004]))
    fused = fuse(prior, [node])
    np.testing.assert_allclose(fused.mean, post.mean, atol=1e-12)
    np.testing.assert_allclose(fused.cov, post.cov, atol=1e-12)


def test_two_nodes_add_their_information():
    prior = Gaussian(np.zeros(3), np.eye(3))
    a, b = LocalFilter("vision"), LocalFilter("odometry")
    for n in (a, b):
        n.predict(prior)
    a.correct(np.array([1.0, 0.0, 0.0]), np.eye(3) * 0.1)
    b.correct(np.array([0.0, 1.0, 0.0]), np.eye(3) * 0.1)
    fused = fuse(prior, [a, b])
    # information: 1 (prior) + 10 + 10 per axis
    np.testing.assert_allclose(fused.cov, np.eye(3) / 21.0, atol=1e-12)
    np.testing.assert_allclose(fused.mean, [10 / 21.0, 10 / 21.0, 0.0], atol=1e-12)
    assert np.trace(fused.cov) < min(np.trace(a.posterior.cov), np.trace(b.posterior.cov))


def test_heading_fused_across_pi():
    prior = Gaussian(np.array([0.0, 0.0, math.radians(179.0)]), np.eye(3) * 0.01)
    node = LocalFilter("vision")
    node.predict(prior)
    node.correct(np.array([0.0, 0.0, math.radians(-179.0)]), np.eye(3) * 0.01)
    fused = fuse(prior, [node])
    assert abs(abs(fused.mean[2]) - math.pi) < math.radians(0.1)


def drive(n=80, seed=4):
    """True poses of a robot curving at 1 m/s, 10 Hz, and its true increments."""
    rng = np.random.default_rng(seed)
    poses = [np.array([0.0, 0.0, 0.0])]
    inc = []
    for _ in range(n - 1):
        u = np.array([0.1, 0.0, rng.uniform(-0.05, 0.05)])
        inc.append(u)
        poses.append(compose(poses[-1], u))
    return np.array(poses), np.array(inc)


def test_fusion_reduces_the_vision_noise():
    rng = np.random.default_rng(5)
    poses, inc = drive()
    sigma = 0.05
    R = np.diag([sigma**2, sigma**2, 0.01**2])
    f = DecentralisedFusion()
    raw, fused, var = [], [], []
    for i, p in enumerate(poses):
        z = p + np.array([*rng.normal(0.0, sigma, 2), rng.normal(0.0, 0.01)])
        odo = None if i == 0 else inc[i - 1] * (1 + rng.normal(0.0, 0.02))
        est = f.step(0.1, odo, False, (z, R))
        raw.append(np.hypot(*(z[:2] - p[:2])))
        fused.append(np.hypot(*(est.mean[:2] - p[:2])))
        var.append(np.trace(est.cov[:2, :2]))
    raw, fused = np.array(raw[10:]), np.array(fused[10:])
    assert np.sqrt(np.mean(fused**2)) < 0.6 * np.sqrt(np.mean(raw**2))
    assert np.mean(var[10:]) < np.trace(R[:2, :2])


def test_odometry_is_not_fused_on_collision_frames():
    poses, inc = drive(20)
    R = np.diag([0.05**2, 0.05**2, 0.01**2])
    a, b = DecentralisedFusion(), DecentralisedFusion()
    for i, p in enumerate(poses[:10]):
        odo = None if i == 0 else inc[i - 1]
        a.step(0.1, odo, False, (p, R))
        b.step(0.1, odo, False, (p, R))
    wrong = np.array([1.5, -0.8, 0.6])  # wheels spinning against another robot
    ea = a.step(0.1, wrong, True, (poses[10], R))
    eb = b.step(0.1, None, False, (poses[10], R))
    np.testing.assert_allclose(ea.mean, eb.mean, atol=1e-12)
    np.testing.assert_allclose(ea.cov, eb.cov, atol=1e-12)
    assert np.hypot(*(ea.mean[:2] - poses[10][:2])) < 0.05
    # the same increment fused without the collision flag drags the estimate away
    c = DecentralisedFusion()
    for i, p in enumerate(poses[:10]):
        c.step(0.1, None if i == 0 else inc[i - 1], False, (p, R))
    ec = c.step(0.1, wrong, False, (poses[10], R))
    assert np.hypot(*(ec.mean[:2] - poses[10][:2])) > np.hypot(*(ea.mean[:2] - poses[10][:2]))


def test_prediction_only_frames_grow_the_covariance():
    poses, inc = drive(10)
    R = np.diag([0.05**2, 0.05**2, 0.01**2])
    f = DecentralisedFusion()
    for i, p in enumerate(poses[:5]):
        f.step(0.1, None if i == 0 else inc[i - 1], False, (p, R))
    before = np.trace(f.state.cov)
    est = f.step(0.1, inc[4], False, None)  # vision failed: odometry and model only
    assert np.trace(est.cov) > before
    assert abs(float(wrap_angle(est.mean[2] - poses[5][2]))) < 0.05


def _reference_step(f: DecentralisedFusion, dt, odometry, collision, vision):
    """DecentralisedFusion.step from the numpy nodes (equations 6-9 as written in
    LocalFilter, fuse and the model/odometry noise methods)."""
    from stages.common.geometry import between

    prior = f.model_prediction(dt)
    v, o = LocalFilter("vision"), LocalFilter("odometry")
    v.predict(prior)
    o.predict(prior)
    if odometry is not None and not collision:
        o.posterior = f.odometry_posterior(np.asarray(odometry, float), dt)
    if vision is not None:
        v.correct(*vision)
    fused = fuse(prior, [v, o])
    return fused, between(f.state.mean, fused.mean)


def test_compiled_frame_equals_the_numpy_nodes():
    rng = np.random.default_rng(11)
    for trial in range(40):
        f = DecentralisedFusion()
        f.reset(np.array([rng.uniform(-5, 5), rng.uniform(-3, 3), rng.uniform(-3, 3)]),
                np.diag(rng.uniform(0.001, 0.05, 3)))
        f.last_motion = rng.normal(0, [0.05, 0.02, 0.05])
        f.motion_known = bool(trial % 3)
        odo = None if trial % 5 == 0 else f.last_motion + rng.normal(0, 0.01, 3)
        col = trial % 7 == 0
        vision = None if trial % 4 == 0 else (
            compose(f.state.mean, f.last_motion) + rng.normal(0, [0.05, 0.05, 0.02]),
            np.diag(rng.uniform(0.0005, 0.02, 3)))
        ref, motion = _reference_step(f, 0.1, odo, col, vision)
        pose, cov = f.predicted(0.1, odo, col)
        if odo is not None and not col:
            np.testing.assert_allclose(pose, f.odometry_prior(odo), atol=1e-12)
            np.testing.assert_allclose(cov, f.odometry_posterior(np.asarray(odo), 0.1).cov,
                                       atol=1e-12)
        else:
            np.testing.assert_allclose(cov, f.model_prediction(0.1).cov, atol=1e-12)
        got = f.step(0.1, odo, col, vision)
        np.testing.assert_allclose(got.mean, ref.mean, atol=1e-9)
        np.testing.assert_allclose(got.cov, ref.cov, atol=1e-9)
        np.testing.assert_allclose(f.last_motion, motion, atol=1e-9)
