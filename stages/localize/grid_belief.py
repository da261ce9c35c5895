"""Method lut's whole-field belief: Markov localisation on the tables' grid (Fox, Burgard and
Thrun 1999, "Markov localization for mobile robots in dynamic environments", JAIR 11), for runs
with a field-aligned heading (``belief: grid``).

The belief is a probability per cell of the scan-line tables' grid (10 cm over the field and
its border), at the frame's IMU heading. Per frame:

1. predict: the belief moves by the odometry's step, turned into the field frame by the
   previous heading (bilinear shift), blurred by the odometry's noise (the fusion's
   ``odometry_xy`` per metre travelled plus ``odometry_min_xy``; the fusion's model noise
   where the motion is unknown: a collision frame, no odometry), and mixed with the uniform
   belief at ``KIDNAP_PROBABILITY`` (tracking.py; the rate at which the robot is put elsewhere);
2. update: multiplied by the frame's tempered likelihood exp(-E(cell) / T) at the table
   heading nearest the IMU's, E the paper's matching error over every cell (the error
   lookup's surface, each observation at its evidence weight: TableSearch.surface), and
   normalised. A frame with fewer than lut's ``MIN_OBSERVATIONS`` crossings (the camera blocked,
   the robot lifted) skips the update: its answer is the prediction (mode ``predicted``);
3. conclude: the hypotheses are the belief's most probable cells, ``AMBIGUITY_DISTANCE_M``
   apart (the global search's places), each with the belief's mass within that distance of
   it: the probability of that place. The top one's cell is refined to sub-cell by the
   seed's refinement (TableSearch.refine), and its place's mass is the confidence. The
   position covariance is the belief's own second moment about the pose over the place.

Every place keeps its probability from frame to frame: nothing is born or pruned, so a place
the first frames misjudged is not lost, and the belief moves to it as soon as the evidence the
odometry links over frames says so (the tracks of tracking.TrackBank must first find such a
place with a global search and give it the prior of a kidnap). A prior over where a robot can
stand (``UNREACHABLE_PROBABILITY`` inside and behind the goals) enters once, at the start, and
in every kidnap's uniform mass.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..common.errors import FieldlocError
from .heading import IMU_SIGMA_RAD
from .radial_correction import RadialCorrection
from .tracking import AMBIGUITY_DISTANCE_M, FUSION, KIDNAP_PROBABILITY, FrameFailed

# evidence (full-weight observations of the surface) per nat: consecutive views overlap and one
# white line crosses many scan lines, so one observation is worth much less than a nat; fitted
# on rendered tuning seeds (docs/lut-belief.md), as lut's TEMPERATURE
TEMPERATURE = 4.0
# prior of a cell a robot cannot stand on (inside or behind a goal), relative to the field
UNREACHABLE_PROBABILITY = 1e-3
# a goal's mouth widened by the robot's radius: a robot centre closer to the goal line than
# this inside the posts' span is inside the goal (msl robots are about 0.5 m across)
GOAL_SLACK_M = 0.25


@dataclass
class GridFix:
    """The top hypothesis's fix as localise_frames records it."""

    x: float
    y: float
    theta: float
    error_norm: float
    mode: str = "grid"



@dataclass
class GridTop:
    """The frame's top hypothesis, as localise_frames reads it (``fix``)."""

    fix: GridFix


def uses_grid(conf: dict) -> bool:
    """Whether a lut conf's belief is the grid: ``belief`` grid, or auto with a
    field-aligned heading (IMU aligned with the field, or the truth) on a tracked run."""
    if conf["belief"] == "auto":
        return not conf["independent"] and (
            conf["heading"] == "truth"
            or (conf["heading"] == "imu" and conf["imu_alignment"] == "field"))
    return conf["belief"] == "grid"


def check_conf(conf: dict) -> None:
    """What the grid needs of a lut conf: a field-aligned heading (FieldlocError)."""
    if not (conf["heading"] == "truth"
            or (conf["heading"] == "imu" and conf["imu_alignment"] == "field")):
        raise FieldlocError("belief grid needs a field-aligned heading (heading imu with"
                            " imu_alignment field, or truth); the histogram's heading and a"
                            " vision-aligned IMU are for the tracks (belief tracks)")


def reachable_prior(field, xs: np.ndarray, ys: np.ndarray, unreachable: float) -> np.ndarray:
    """Log prior per cell (ny, nx) of cell centres ``xs`` (nx,) and ``ys`` (ny,): 0 where a
    robot can stand, log(``unreachable``) inside and behind the goals (beyond a goal line less
    GOAL_SLACK_M, between the posts' y plus that slack)."""
    X, Y = np.meshgrid(xs, ys)
    posts = np.asarray(field.goal_posts, float)
    half_len = field.length / 2
    mouth = (np.abs(posts[:, 1]).max() if len(posts) else 0.0) + GOAL_SLACK_M
    inside = (np.abs(X) > half_len + GOAL_SLACK_M) & (np.abs(Y) < mouth)
    return np.where(inside, math.log(max(unreachable, 1e-300)), 0.0)


def _move_taps(shift: float, sigma: float) -> np.ndarray:
    """Weights of scipy.ndimage.convolve1d (odd length, centred) that move a 1-D belief by
    ``shift`` cells and blur it by a Gaussian of ``sigma`` cells: the bilinear split of the
    shift between its two neighbouring whole cells, convolved with the sampled Gaussian (its
    taps normalised; a sigma below a hundredth of a cell is no blur)."""
    base = math.floor(shift)
    frac = shift - base
    r = int(math.ceil(3.0 * sigma)) if sigma > 1e-2 else 0
    t = np.arange(-r, r + 1, dtype=float)
    g = np.exp(-0.5 * (t / sigma) ** 2) if r else np.ones(1)
    g /= g.sum()
    k = np.convolve(g, np.array([1.0 - frac, frac]))  # moves by base - r .. base + r + 1
    lo = base - r
    m = max(abs(lo), abs(lo + len(k) - 1))
    w = np.zeros(2 * m + 1)
    w[m + lo:m + lo + len(k)] = k  # w[m + o] moves mass by o cells
    return w


class GridBelief:
    """The belief over the grid's cells (module doc), probabilities in a (ny, nx) array."""

    def __init__(self, xs: np.ndarray, ys: np.ndarray, log_prior: np.ndarray, kidnap: float):
        self.xs, self.ys = np.asarray(xs, float), np.asarray(ys, float)
        self.res = float(self.xs[1] - self.xs[0])
        prior = np.exp(log_prior - log_prior.max())
        self.prior = prior / prior.sum()
        self.kidnap = float(kidnap)
        self.p = self.prior.copy()
        self.X, self.Y = np.meshgrid(self.xs, self.ys)

    def predict(self, step_xy, sigma: float) -> None:
        """Move the belief by ``step_xy`` (m, field frame), blur it by ``sigma`` (m) and mix in
        the prior at the kidnap probability. The move (bilinear) and the blur (Gaussian) are
        one separable filter: two 1-D passes of a few taps each; mass moved off the grid is
        lost before the belief is normalised."""
        from scipy import ndimage

        p = self.p
        for axis, shift in ((1, float(step_xy[0]) / self.res), (0, float(step_xy[1]) / self.res)):
            p = ndimage.convolve1d(p, _move_taps(shift, float(sigma) / self.res), axis=axis,
                                   mode="constant", cval=0.0)
        total = p.sum()
        p = p / total if total > 0 else self.prior.copy()
        self.p = (1.0 - self.kidnap) * p + self.kidnap * self.prior

    def update(self, error: np.ndarray, temperature: float) -> None:
        """Multiply by exp(-error / temperature) per cell and normalise."""
        e = np.asarray(error, float)
        like = np.exp(-(e - e.min()) / float(temperature))
        p = self.p * like
        total = p.sum()
        self.p = p / total if total > 0 else self.prior.copy()

    def _window(self, x: float, y: float, radius: float) -> tuple[int, int, int, int]:
        """Cell bounds [i0, i1) x [j0, j1) of the square around (x, y) holding the disc of
        ``radius``."""
        r = int(math.ceil(radius / self.res)) + 1
        j = int(round((x - self.xs[0]) / self.res))
        i = int(round((y - self.ys[0]) / self.res))
        ny, nx = self.p.shape
        return max(i - r, 0), min(i + r + 1, ny), max(j - r, 0), min(j + r + 1, nx)

    def mass_near(self, x: float, y: float, radius: float) -> float:
        """The belief's mass within ``radius`` of (x, y)."""
        i0, i1, j0, j1 = self._window(x, y, radius)
        X, Y = self.X[i0:i1, j0:j1], self.Y[i0:i1, j0:j1]
        near = np.hypot(X - x, Y - y) <= radius
        return float(self.p[i0:i1, j0:j1][near].sum())

    def covariance_near(self, x: float, y: float, radius: float) -> np.ndarray:
        """(2, 2) second moment of the belief about (x, y) within ``radius``, with a floor of
        a uniform cell's."""
        i0, i1, j0, j1 = self._window(x, y, radius)
        X, Y = self.X[i0:i1, j0:j1] - x, self.Y[i0:i1, j0:j1] - y
        w = np.where(np.hypot(X, Y) <= radius, self.p[i0:i1, j0:j1], 0.0)
        s = w.sum()
        floor = self.res ** 2 / 12.0
        if s <= 0:
            return np.eye(2) * radius ** 2
        c = np.array([[np.sum(w * X * X), np.sum(w * X * Y)],
                      [np.sum(w * X * Y), np.sum(w * Y * Y)]]) / s
        return c + np.eye(2) * floor

    def modes(self, count: int, separation: float, radius: float) -> list[tuple]:
        """Up to ``count`` separated maxima (x, y, mass within ``radius``), the most probable
        cell first, each next one the most probable cell at least ``separation`` from those
        before it."""
        p = self.p.copy()
        out: list[tuple] = []
        for _ in range(count):
            k = int(np.argmax(p))
            i, j = divmod(k, p.shape[1])
            if p[i, j] <= 0:
                break
            x, y = float(self.xs[j]), float(self.ys[i])
            out.append((x, y, self.mass_near(x, y, radius)))
            i0, i1, j0, j1 = self._window(x, y, separation)
            near = np.hypot(self.X[i0:i1, j0:j1] - x, self.Y[i0:i1, j0:j1] - y) < separation
            p[i0:i1, j0:j1][near] = 0.0
        return out


class GridLocaliser:
    """The per-frame loop of ``belief: grid`` (module doc), as tracking.localise_frames runs
    it."""

    def __init__(self, conf: dict, search, *, yaw, collision, truth_heading, min_observations):
        check_conf(conf)
        self.conf, self.search = conf, search
        self.min_observations = min_observations  # fewer crossings: the update is skipped
        self.fusion = FUSION
        self.yaw, self.collision, self.truth_heading = yaw, collision, truth_heading
        ny, nx = search.grid.shape
        res = float(search.grid.resolution)
        xs = float(search.grid.origin[0]) + res * np.arange(nx)
        ys = float(search.grid.origin[1]) + res * np.arange(ny)
        self.belief = GridBelief(xs, ys, reachable_prior(
            search.field, xs, ys, UNREACHABLE_PROBABILITY),
            KIDNAP_PROBABILITY)
        self.prev_heading = None
        self.has_odometry = True
        rc = conf["radial_correction"]  # the calibration's distance error, learnt online
        self.radial = (RadialCorrection(robot_radius=float(search.scanlines.robot_radius))
                       if rc["enabled"] else None)

    def _heading(self, i: int) -> float:
        src = self.truth_heading if self.conf["heading"] == "truth" else self.yaw
        th = float(src[i]) if src is not None else math.nan
        if not math.isfinite(th):
            raise FrameFailed("no-truth-heading" if self.conf["heading"] == "truth"
                              else "no-imu-row")
        return th

    def _predict(self, dt: float, odo, col: bool) -> None:
        f = self.fusion
        if odo is None or self.prev_heading is None:
            # the motion is unknown: a random walk of the fusion's model noise (of up to its
            # max_speed where the dataset measures no motion at all)
            speed = f.model_xy if self.has_odometry else f.max_speed
            self.belief.predict((0.0, 0.0), math.hypot(speed * dt, f.model_min_xy))
            return
        c, s = math.cos(self.prev_heading), math.sin(self.prev_heading)
        dx, dy = float(odo[0]), float(odo[1])
        step = (c * dx - s * dy, s * dx + c * dy)
        sigma = f.odometry_xy * math.hypot(dx, dy) + f.odometry_min_xy
        if col:  # a collision: the wheels slip, the motion is the model's guess as well
            sigma = math.hypot(sigma, f.model_xy * dt)
        self.belief.predict(step, sigma)

    def _learn_radial(self, obs, raw_distance, fix: GridFix, confidence: float) -> None:
        """The crossings of a frame whose pose holds the radial correction's
        ``min_confidence`` against their predictions there, every ``every``-th such frame,
        into the correction (radial_correction.py)."""
        rc = self.radial
        if rc is None or confidence < rc.min_confidence:
            return
        rc.frames += 1
        if rc.frames % max(1, rc.every):
            return
        cell = self.search.cell_of(fix.x, fix.y)
        rc.update(raw_distance, self.search.observation_predictions(obs, cell, fix.theta))

    def failed(self, dt: float, odo, collision: bool) -> None:
        """A frame with no usable observations: the belief only predicts."""
        self._predict(dt, odo, collision)

    def frame(self, i: int, fr: dict, dt: float, odo, flags: list):
        from .lut_search import EVIDENCE, frame_observations

        conf, search = self.conf, self.search
        col = bool(self.collision[i])
        self._predict(dt, odo, col)
        theta = self._heading(i)
        self.prev_heading = theta
        obs, raw_distance = frame_observations(fr, search, self.radial, EVIDENCE)
        seen = len(obs) >= self.min_observations
        if seen:
            self.belief.update(search.surface(obs, theta), TEMPERATURE)
        else:  # nothing to weigh: the belief's prediction is the frame's answer
            flags.append("too-few-observations")
        # a place: the cells within the global search's ambiguity distance of a pose (two
        # places are at least that far apart); the confidence is the mass of the pose's place
        reach = AMBIGUITY_DISTANCE_M
        modes = self.belief.modes(int(conf["hypotheses"]), reach, reach)
        x, y, _ = modes[0]
        fix = GridFix(x, y, theta, math.nan, "grid" if seen else "predicted")
        if seen:  # sub-cell, by the paper's refinement in the mode's basin
            r = search.refine(obs, search.grid.cell_of(x, y), theta)
            if math.hypot(r.x - x, r.y - y) <= reach:
                fix.x, fix.y = r.x, r.y
            fix.error_norm = r.error_norm
        confidence = min(self.belief.mass_near(fix.x, fix.y, reach), 1.0)
        hyps = np.array([[fix.x, fix.y, theta, confidence]]
                        + [[mx, my, theta, m] for mx, my, m in modes[1:]], float)
        cov = np.zeros((3, 3))
        cov[:2, :2] = self.belief.covariance_near(fix.x, fix.y, reach)
        cov[2, 2] = IMU_SIGMA_RAD ** 2
        if seen and not col:
            self._learn_radial(obs, raw_distance, fix, confidence)
        accepted = confidence >= conf["min_confidence"]
        if not accepted:
            flags.append("low-confidence")
        return hyps, GridTop(fix), np.array([fix.x, fix.y, theta]), cov, accepted
