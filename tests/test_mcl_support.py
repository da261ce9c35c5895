"""The belief's density at new poses (stages.localize.mcl_resampling.log_support), which
decides the side of the field a sensor reset's pose is put on (mirror_guard)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from stages.localize.mcl_clusters import Clustering
from stages.localize.mcl_resampling import Belief, log_support, mirror_guard


def _reference(particles, weights, poses, radius, heading, held=256):
    """The density as array passes over every (pose, support particle) pair."""
    cum = np.cumsum(weights)
    k = min(held, len(weights))
    idx = np.minimum(np.searchsorted(cum, (np.arange(k) + 0.5) / k * cum[-1]), len(weights) - 1)
    q = particles[idx]
    e = ((poses[:, None, 0] - q[None, :, 0]) ** 2 + (poses[:, None, 1] - q[None, :, 1]) ** 2)
    e = e / (2 * radius ** 2) + (1 - np.cos(poses[:, None, 2] - q[None, :, 2])) / heading ** 2
    top = (-e).max(axis=1)
    return top + np.log(np.exp(-e - top[:, None]).sum(axis=1)) - math.log(len(q))


def _belief(rng, n):
    centre = rng.uniform([-4, -3, -math.pi], [4, 3, math.pi])
    p = centre + rng.normal(0, 1, (n, 3)) * rng.uniform([0.05, 0.05, 0.02], [1.5, 1.5, 1.0])
    w = rng.random(n) ** 3
    return p, w / w.sum()


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 1500), m=st.integers(1, 60))
def test_the_density_is_the_kernels_sum(seed, n, m):
    """The compiled density equals the sum over every pair (to 1e-9 in log), however far the
    poses lie from the belief (terms e^-40 below the nearest are left out)."""
    rng = np.random.default_rng(seed)
    p, w = _belief(rng, n)
    poses = rng.uniform([-6, -4.5, -math.pi], [6, 4.5, math.pi], (m, 3))
    poses[: m // 2] = p[rng.integers(0, n, m // 2)] + rng.normal(0, 0.1, (m // 2, 3))
    clusters = Clustering((-6, 6, -4.5, 4.5), 0.5, math.radians(30))
    got = log_support(Belief(p, w), poses, clusters)
    ref = _reference(p, w, poses, 0.5, math.radians(30))
    assert np.allclose(got, ref, rtol=1e-12, atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_a_new_pose_goes_to_the_beliefs_side(seed):
    """A belief on one side of a point-symmetric field: a new pose near it, or near its
    mirror, is put near it (the side the track chose)."""
    rng = np.random.default_rng(seed)
    centre = np.array([rng.uniform(1.5, 4), rng.uniform(-3, 3), rng.uniform(-math.pi, math.pi)])
    p = centre + rng.normal(0, [0.2, 0.2, 0.1], (500, 3))
    w = np.full(500, 1 / 500)
    near = centre + rng.normal(0, [0.2, 0.2, 0.1], (20, 3))
    mirrored = near.copy()
    mirrored[:, :2] *= -1
    mirrored[:, 2] += math.pi
    clusters = Clustering((-6, 6, -4.5, 4.5), 0.5, math.radians(30))
    for poses in (near, mirrored):
        out = mirror_guard(poses, Belief(p, w), clusters, centre)
        assert np.all(out[:, 0] > 0)
