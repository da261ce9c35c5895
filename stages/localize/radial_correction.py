"""Online correction of an omni camera's distance calibration from the tracked frames.

A catadioptric mirror's calibration (calib.yaml's f(r)) is rarely exact: a team's mirror table
read by hand, or a fit that bends between its pairs, puts a line at distance d at d + e(d),
with e smooth in d and growing with it (minho-distance: 4-16 cm at 1-2 m). Every crossing then
lies a little off its table entry, and a frame's fix is pulled by the mismatch.

While the robot is localised with confidence, each crossing's distance d (as observed) and the
distance its scan line predicts at the fused pose, p, measure e(d) = d - p. The error is
modelled as a polynomial in the distance from the robot's own radius r0,

    e(d) = sum_k a_k ((d - r0) / scale)^k,   k = 1 .. degree

(zero at r0, where the mirror's centre is best known), and the coefficients are estimated by
recursive least squares with exponential forgetting over the crossings of confident frames whose
residual lies within ``max_residual`` of the current e(d) (the rest are other lines or
clutter), each with a spread of ``noise``, from a zero-mean prior (``prior_sigma``: the error
at ``scale`` m it allows before data). Observations are corrected, d -> d - e(d), once
``min_points`` crossings are in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .tracking import near_pose

# what a user chooses: whether the correction runs (docs/recording-calibration.md: switched
# off with -c radial_correction.enabled=false)
DEFAULTS = {"enabled": True}

# The estimate's tuned constants (module doc; the defaults of RadialCorrection), chosen on
# renders with a team's mirror-table error (minho-distance, docs/recording-calibration.md)
DEGREE = 3
SCALE_M = 2.0  # m, the unit of the polynomial's variable
PRIOR_SIGMA_M = 0.1  # m, prior spread of each coefficient (the error at SCALE_M m)
FORGETTING = 0.998  # per frame used (the calibration drifts slowly, if at all)
MIN_POINTS = 300  # crossings in before the correction is applied
MAX_RESIDUAL_M = 0.25  # m, crossings farther from their prediction are not used
NOISE_M = 0.05  # m, spread of one crossing's residual about e(d)
MIN_CONFIDENCE = 0.99  # frames whose top hypothesis is less sure are not used
EVERY = 4  # frames between updates (consecutive frames see nearly the same crossings)


@dataclass
class RadialCorrection:
    """e(d) by recursive least squares (module doc)."""

    robot_radius: float
    degree: int = DEGREE
    scale: float = SCALE_M
    prior_sigma: float = PRIOR_SIGMA_M
    forgetting: float = FORGETTING
    min_points: int = MIN_POINTS
    max_residual: float = MAX_RESIDUAL_M
    noise: float = NOISE_M
    min_confidence: float = MIN_CONFIDENCE
    every: int = EVERY
    points: float = 0.0  # crossings used (decayed with the forgetting)
    frames: int = 0  # confident tracked frames seen (teaching_pose)
    coef: np.ndarray = field(default=None)  # a_1 .. a_degree (m)
    info: np.ndarray = field(default=None)  # information matrix of the coefficients
    vec: np.ndarray = field(default=None)  # information vector

    def __post_init__(self):
        n = int(self.degree)
        self.coef = np.zeros(n)
        self.info = np.eye(n) / self.prior_sigma**2
        self.vec = np.zeros(n)

    def teaching_pose(self, bank, top, hyps, collision: bool):
        """The pose at which a frame's observations may teach e(d), or None: the leading
        track's pose (tracking.TrackBank ``bank``) on a tracked frame (``top`` from a track)
        without a collision whose top hypothesis (``hyps`` row 0) holds ``min_confidence``,
        every ``every``-th such frame, and on a point-symmetric field only while the top
        hypothesis is that track's pose, not its mirror image (whose predictions are the
        same anyway)."""
        if (top.track is None or collision or not bank.tracks
                or hyps[0, 3] < self.min_confidence):
            return None
        self.frames += 1
        if self.frames % max(1, self.every):
            return None
        pose = bank.tracks[0].pose
        if bank.symmetric and not near_pose(hyps[0], pose, 0.3, 0.2):
            return None
        return pose

    @property
    def active(self) -> bool:
        return self.points >= self.min_points

    def _basis(self, d) -> np.ndarray:
        u = (np.asarray(d, float) - self.robot_radius) / self.scale
        return np.stack([u ** (k + 1) for k in range(len(self.coef))], axis=-1)

    def error(self, d) -> np.ndarray:
        """e(d) (m) of observed distances d (zero until active)."""
        d = np.asarray(d, float)
        if not self.active:
            return np.zeros_like(d)
        return self._basis(d) @ self.coef

    def correct(self, d) -> np.ndarray:
        """Observed distances with the estimated error removed."""
        return np.asarray(d, float) - self.error(d)

    def update(self, observed, predicted):
        """Add one frame's crossings: ``observed`` distances (as the camera gave them) and the
        distances their scan lines predict at the frame's pose."""
        d = np.asarray(observed, float)
        r = d - np.asarray(predicted, float)
        # gated about the current estimate (used before it is applied, too)
        keep = np.isfinite(r) & (np.abs(r - self._basis(d) @ self.coef) <= self.max_residual)
        if not keep.any():
            return
        A = self._basis(d[keep])
        prior = np.eye(len(self.coef)) / self.prior_sigma**2
        lam = self.forgetting
        # forget towards the prior, then add the frame
        self.info = lam * self.info + (1 - lam) * prior + A.T @ A / self.noise**2
        self.vec = lam * self.vec + A.T @ r[keep] / self.noise**2
        self.points = lam * self.points + int(keep.sum())
        self.coef = np.linalg.solve(self.info, self.vec)

    def summary(self, at=(1.0, 2.0, 3.0, 4.0)) -> dict:
        """The estimated error (m) at a few distances, and the crossings used."""
        return {"points": float(self.points), "active": bool(self.active),
                "error_m": {f"{d:g}": float(self._basis(d) @ self.coef) for d in at},
                "coefficients": [float(a) for a in self.coef],
                "scale_m": self.scale, "robot_radius_m": self.robot_radius}


def residual_sigma(correction: RadialCorrection) -> float:
    """Largest standard deviation of e(d) over 0..4 m implied by the coefficients' posterior
    (for reports)."""
    cov = np.linalg.inv(correction.info)
    d = np.linspace(correction.robot_radius, 4.0, 16)
    A = correction._basis(d)
    return float(math.sqrt(max(np.max(np.einsum("ij,jk,ik->i", A, cov, A)), 0.0)))


def fitted(robot_radius: float, crossings: list[tuple[np.ndarray, np.ndarray]],
           rounds: int = 3) -> RadialCorrection:
    """e(d) from a whole recording at once (the smoother's, smooth.py): ``crossings``, per frame
    at its smoothed pose the observed distances and the distances their scan lines predict
    there. Least squares over every crossing with the same prior and noise as the online
    estimate but no forgetting, gated about the previous round's estimate (the first round
    about zero: the gate ``max_residual`` admits the calibration's error and rejects other
    lines and clutter), ``rounds`` times."""
    rc = RadialCorrection(robot_radius=float(robot_radius), forgetting=1.0)
    d = np.concatenate([np.asarray(o, float) for o, _p in crossings]) if crossings else np.zeros(0)
    r = d - (np.concatenate([np.asarray(p, float) for _o, p in crossings]) if crossings
             else np.zeros(0))
    ok = np.isfinite(r)
    d, r = d[ok], r[ok]
    prior = np.eye(len(rc.coef)) / rc.prior_sigma**2
    A_all = rc._basis(d)
    for _ in range(max(1, int(rounds))):
        keep = np.abs(r - A_all @ rc.coef) <= rc.max_residual
        A = A_all[keep]
        rc.info = prior + A.T @ A / rc.noise**2
        rc.vec = A.T @ r[keep] / rc.noise**2
        rc.points = float(keep.sum())
        rc.coef = np.linalg.solve(rc.info, rc.vec)
    return rc


class PathCalibration:
    """The distance correction of a smoother's scorer (the omni methods'): ``calibration``,
    the RadialCorrection its frames are fixed with (setting it drops the frames it cached),
    and ``learn_calibration`` from a smoothed path (smooth.py). A scorer gives ``loc`` (its
    causal localiser: conf, collision flags), ``_cache`` and ``_crossings(i, pose)``: frame
    i's observed distances and the distances the map predicts for them at ``pose``."""

    radial = None
    robot_radius = 0.0

    @property
    def calibration(self):
        """The distance correction the frames are fixed with (a RadialCorrection or None)."""
        return self.radial

    @calibration.setter
    def calibration(self, rc) -> None:
        self.radial = rc
        self._cache.clear()

    def learn_calibration(self, path: dict, sure: dict):
        """The camera's distance error learnt from the frames of ``path`` (frame -> pose)
        whose ``sure`` (frame -> confidence) holds the radial correction's min_confidence and
        that flag no collision (``fitted``), or None when too few crossings are in."""
        if not self.loc.conf["radial_correction"]["enabled"]:
            return None
        crossings = [self._crossings(i, pose) for i, pose in path.items()
                     if sure.get(i, 0.0) >= MIN_CONFIDENCE and not self.loc.collision[i]]
        rc = fitted(self.robot_radius, crossings)
        return rc if rc.active else None
