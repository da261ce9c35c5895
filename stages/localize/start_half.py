"""The start half (``start_half``, ``start_half_error``: the half of the field a robot
started in, as a team knows it at kick-off) carried to later frames by the odometry
(``StartHalf``): mcl's uniform start picks with it which of a pose and its mirror image each
pose it adds stands for (mcl_start, mcl_resampling.mirror_guard), and localize's warning that
the frames overruled the given half (symmetry.start_half_warning) judges a track's first
accepted poses by where they put the robot's first pose, not by where they lie: a robot may
have walked across the halfway line before its first accepted frame."""

from __future__ import annotations

import math

import numpy as np
from scipy.special import log_ndtr

from ..common.geometry import compose, wrap_angle
from .motion_model import motion_sigmas

# nats: where the belief supports neither a new pose nor its mirror image (a far kidnap), the
# start half's log odds between the two decide when they are at least this (20 : 1); weaker
# odds (a long walk's odometry) leave the choice to the last estimate's side
HALF_DECIDES = 3.0


class StartHalf:
    """The start half (``start_half``, ``start_half_error``) carried to later frames by the
    odometry: a pose now is on the start's side of the field when the odometry since the
    first frame, undone from it, puts the robot's first pose on the half given.

    On a point-symmetric field a pose and its mirror image explain every frame alike, so
    what a uniform start knows of the side is the half the robot started in. The particles
    drawn at the start carry it; the poses the filter adds later (sensor resets, augmented
    MCL, the rivals, the first frame's places) do not, unless each is taken as whichever of
    itself and its mirror image this prior favours. Undoing the odometry D from a pose P
    gives the first pose S = P (+) D^-1, and from P's mirror image the mirror image of S, so
    the prior of P against its mirror is that of x_S against -x_S. The odometry's error
    (motion_model's noise, summed as a random walk, with the heading's error as a lever on
    the distance covered) makes x_S uncertain: the prior of the half is the chance that the
    first pose lay there, Phi(-x_S / sigma) for the own half, mixed with ``start_half_error``.
    """

    def __init__(self, half: str, error: float):
        self.sign = -1.0 if half == "own" else 1.0
        self.error = float(error)
        self.moved = np.zeros(3)  # the odometry since the first frame, composed
        self.var_xy = 0.0  # m^2: the variance of the composed translation, per axis
        self.var_th = 0.0  # rad^2: of the composed heading
        self.travelled = 0.0  # m: the path's length

    def move(self, odometry, dt: float, **noise_flags) -> None:
        """Compose one frame's odometry increment (motion_model's arguments)."""
        s_t, s_r = motion_sigmas(odometry, dt, **noise_flags)
        self.moved = compose(self.moved, np.asarray(odometry, dtype=float))
        self.var_xy += s_t * s_t
        self.var_th += s_r * s_r
        self.travelled += math.hypot(float(odometry[0]), float(odometry[1]))

    def reach(self) -> float:
        """m: how far past the centre line a pose may now lie on the start's side: the path
        covered and three of the first pose's sigmas."""
        return self.travelled + 3.0 * self._sigma()

    def _sigma(self) -> float:
        lever = float(np.hypot(self.moved[0], self.moved[1]))
        return math.sqrt(self.var_xy + self.var_th * lever * lever) + 1e-9

    def first_x(self, poses: np.ndarray) -> np.ndarray:
        """x of the first pose each of ``poses`` (M, 3) implies: the odometry since the first
        frame undone from it."""
        dx, dy, dth = self.moved
        th0 = poses[:, 2] - dth  # the first pose's heading
        return poses[:, 0] - (np.cos(th0) * dx - np.sin(th0) * dy)

    def log_odds(self, poses: np.ndarray) -> np.ndarray:
        """log prior(pose) - log prior(its mirror image) for poses (M, 3)."""
        z = self.sign * self.first_x(poses) / self._sigma()
        e = self.error
        # log((1 - e) Phi(z) + e Phi(-z)) for the pose, the same with -z for its mirror
        if e <= 0.0:
            return log_ndtr(z) - log_ndtr(-z)
        right, wrong = math.log1p(-e) if e < 1.0 else -math.inf, math.log(e)
        return (np.logaddexp(right + log_ndtr(z), wrong + log_ndtr(-z))
                - np.logaddexp(right + log_ndtr(-z), wrong + log_ndtr(z)))

    def sided(self, poses: np.ndarray) -> np.ndarray:
        """``poses`` (M, 3), each replaced by its mirror image where the start half's odds
        favour that by HALF_DECIDES or more."""
        if not len(poses):
            return poses
        flip = self.log_odds(poses) <= -HALF_DECIDES
        out = poses.copy()
        out[flip, 0:2] *= -1.0
        out[flip, 2] = wrap_angle(out[flip, 2] + math.pi)
        return out
