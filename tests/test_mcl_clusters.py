"""The particle filter's heaviest cluster (stages.localize.mcl_clusters), compiled, against
its array-pass reference (tests/oracles/mcl_clusters.py) and its properties."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from oracles import mcl_clusters as oracle

from stages.localize.mcl_clusters import Clustering

BOUNDS = (-5.5, 5.5, -4.0, 4.0)  # a KidSize field and its surround, m
RADIUS, HEADING = 0.5, math.radians(30.0)
# the kernel and the reference sum the same weights in other orders (BLAS dots against a
# loop): their centres differ by rounding, far below a millimetre
TOL_M, TOL_RAD = 1e-9, 1e-9


def _belief(seed: int, clusters: int, n: int, zero_share: float):
    """A belief of ``clusters`` clusters of particles (spread 0.3 m, 0.2 rad) over the field,
    their weights random, ``zero_share`` of them 0."""
    rng = np.random.default_rng(seed)
    k = rng.integers(0, clusters, n)
    c = np.column_stack([rng.uniform(BOUNDS[0], BOUNDS[1], clusters),
                         rng.uniform(BOUNDS[2], BOUNDS[3], clusters),
                         rng.uniform(-math.pi, math.pi, clusters)])
    p = c[k] + rng.normal(0.0, [0.3, 0.3, 0.2], (n, 3))
    p[:, 2] = (p[:, 2] + math.pi) % (2 * math.pi) - math.pi
    w = rng.uniform(0.0, 1.0, n) * rng.uniform(0.2, 1.0, clusters)[k]
    w[rng.uniform(size=n) < zero_share] = 0.0
    return w / max(w.sum(), 1e-300), p


def _heaviest(w, p):
    th = p[:, 2]
    return Clustering(BOUNDS, RADIUS, HEADING).heaviest(w, p[:, 0], p[:, 1], th, np.cos(th),
                                                       np.sin(th))


def _close(a, b) -> bool:
    d = (a[2] - b[2] + math.pi) % (2 * math.pi) - math.pi
    return abs(a[0] - b[0]) <= TOL_M and abs(a[1] - b[1]) <= TOL_M and abs(d) <= TOL_RAD


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), clusters=st.integers(1, 6), n=st.integers(1, 600),
       zero_share=st.sampled_from([0.0, 0.5, 1.0]))
def test_heaviest_is_the_reference(seed, clusters, n, zero_share):
    """The compiled search finds the reference's centre, for beliefs of 1-6 clusters, with
    some or every weight 0 (then every particle counts alike)."""
    w, p = _belief(seed, clusters, n, zero_share)
    got = _heaviest(w, p)
    want = oracle.heaviest(BOUNDS, RADIUS, HEADING, w, p[:, 0], p[:, 1], p[:, 2])
    assert _close(got, want), (got, want)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 400))
def test_heaviest_ignores_the_particles_order(seed, n):
    """The particles' order changes nothing but rounding."""
    w, p = _belief(seed, 3, n, 0.0)
    order = np.random.default_rng(seed + 1).permutation(n)
    assert _close(_heaviest(w, p), _heaviest(w[order], p[order]))


def test_heaviest_finds_the_dominant_cluster():
    """Nine tenths of the weight in one tight cluster: the centre is that cluster's mean,
    wherever the rest lies (here across the field, with more particles)."""
    rng = np.random.default_rng(0)
    a = np.column_stack([rng.normal(2.0, 0.05, 100), rng.normal(-1.0, 0.05, 100),
                         rng.normal(3.0, 0.02, 100)])
    b = np.column_stack([rng.uniform(-4, 4, 500), rng.uniform(-3, 3, 500),
                         rng.uniform(-math.pi, math.pi, 500)])
    p = np.concatenate([a, b])
    w = np.concatenate([np.full(100, 0.9 / 100), np.full(500, 0.1 / 500)])
    c = _heaviest(w, p)
    assert math.hypot(c[0] - 2.0, c[1] + 1.0) < 0.03
    assert abs((c[2] - 3.0 + math.pi) % (2 * math.pi) - math.pi) < 0.02
