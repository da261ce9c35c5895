"""The continuous pass of the smoother (smooth.py): a path of fixes refined as a pose graph.

A factor graph over one Pose2 per frame (Dellaert and Kaess 2017, "Factor graphs for robot
perception"), solved with GTSAM's Levenberg-Marquardt and its marginals:

- between consecutive frames a BetweenFactorPose2: the odometry increment with its covariance
  (motion_model.Motion: slip proportional to the motion; a random walk where none was recorded);
- per frame with a fix a PriorFactorPose2 at the fix with its covariance, under a Huber
  M-estimator (``HUBER_K`` standard deviations): a fix the odometry contradicts by many sigmas
  pulls with a constant force instead of a quadratic one, so one bad fix bends the path little.

GTSAM is the smoothing library of the robotics community (iSAM2, the marginals through the
Bayes tree); a chain of a thousand poses is solved in a few tens of milliseconds. Covariances in
GTSAM are in the pose's own (body) frame; the fixes' are given in the field frame and rotated in,
the marginals rotated back.
"""

from __future__ import annotations

import math

import numpy as np

from .motion_model import Motion

# Huber's threshold in standard deviations of a fix (the usual 95 % efficiency constant under
# Gaussian noise: Huber 1964)
HUBER_K = 1.345


def _rotation(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _sym(cov: np.ndarray) -> np.ndarray:
    cov = 0.5 * (cov + cov.T)
    return cov + np.eye(3) * 1e-9


def refine_path(fixes: np.ndarray, fix_cov: np.ndarray, motion: Motion
                ) -> tuple[np.ndarray, np.ndarray]:
    """Poses (N, 3) and covariances (N, 3, 3, field frame) of every frame from the fixes (N, 3;
    NaN rows: no fix) with their covariances (field frame) and the odometry. Frames before the
    first fix or after the last are reached by the odometry from it; a run with no fix at all
    gives NaN."""
    import gtsam

    n = len(fixes)
    has = np.all(np.isfinite(fixes), axis=1)
    out = np.full((n, 3), np.nan)
    out_cov = np.full((n, 3, 3), np.nan)
    if not has.any():
        return out, out_cov
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    first = int(np.argmax(has))
    guess = _initial_path(fixes, has, motion, first)
    robust = gtsam.noiseModel.mEstimator.Huber.Create(HUBER_K)
    for i in range(n):
        initial.insert(i, gtsam.Pose2(*guess[i]))
        if i > 0:
            q = motion.cov[i]
            graph.add(gtsam.BetweenFactorPose2(
                i - 1, i, gtsam.Pose2(*motion.increments[i]),
                gtsam.noiseModel.Gaussian.Covariance(_sym(q))))
        if has[i]:
            r = _rotation(fixes[i, 2])
            body = r.T @ np.asarray(fix_cov[i], float) @ r
            noise = gtsam.noiseModel.Robust.Create(
                robust, gtsam.noiseModel.Gaussian.Covariance(_sym(body)))
            graph.add(gtsam.PriorFactorPose2(i, gtsam.Pose2(*fixes[i]), noise))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
    marginals = gtsam.Marginals(graph, result)
    for i in range(n):
        p = result.atPose2(i)
        out[i] = (p.x(), p.y(), p.theta())
        r = _rotation(p.theta())
        out_cov[i] = r @ marginals.marginalCovariance(i) @ r.T
    return out, out_cov


def _initial_path(fixes: np.ndarray, has: np.ndarray, motion: Motion, first: int) -> np.ndarray:
    """Each frame's starting pose: its fix, or the last fixed pose (the first fix, for frames
    before it) moved by the odometry."""
    from ..common.geometry import compose, inverse

    n = len(fixes)
    guess = np.zeros((n, 3))
    guess[first] = fixes[first]
    for i in range(first - 1, -1, -1):  # backwards from the first fix
        guess[i] = compose(guess[i + 1], inverse(motion.increments[i + 1]))
    for i in range(first + 1, n):
        guess[i] = fixes[i] if has[i] else compose(guess[i - 1], motion.increments[i])
    return guess
