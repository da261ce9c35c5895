"""Discrete decisions compared where their margin is clear.

A kernel and its oracle take the same decision (a pixel is green, a crossing is kept) from
floating-point quantities; where the two sides of the test lie within rounding of each other,
another CPU's rounding (FMA or not, another SIMD path) may take the other branch. So a
decision is held exactly only where its relative margin exceeds ``NEAR``; disagreements are
allowed only below it, and their share is bounded.
"""

from __future__ import annotations

import numpy as np

# relative margin below which float32 rounding may flip a decision: a few float32 operations
# round by ~1e-7 each, so 1e-5 leaves two orders to spare
NEAR = 1e-5


def le_margin(lhs, rhs):
    """(lhs <= rhs, the relative distance of the pair from the tie) in float64."""
    lhs, rhs = np.asarray(lhs), np.asarray(rhs)
    gap = np.abs(lhs.astype(np.float64) - rhs.astype(np.float64))
    return lhs <= rhs, gap / np.maximum(np.abs(lhs) + np.abs(rhs), 1.0)


def assert_decisions_agree(got, want, margin, *, max_share: float = 1e-4, what: str = ""):
    """``got`` equals ``want`` wherever ``margin`` > NEAR; where it does not, the decisions
    may differ, on at most ``max_share`` of them."""
    got, want = np.asarray(got), np.asarray(want)
    differ = got != want
    clear = differ & (np.asarray(margin) > NEAR)
    assert not clear.any(), (what, int(clear.sum()), "decisions differ with a clear margin")
    assert differ.mean() <= max_share, (what, float(differ.mean()))
