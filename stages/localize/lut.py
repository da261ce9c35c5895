"""Method ``lut``: localisation in the scan-line tables of Ribeiro et al. (2015), as ranked
hypotheses with a probability each.

The matching is the paper's (lut_matching.py): per observed crossing distance the error to the
table entry of its scan line, weighted by rho(e) = 1 - c^2 / (c^2 + e^2), nearer points weighing
more; E(pose) is the sum, in units of full-weight observations. This module turns E into a
belief through the tempered likelihood, combined with the motion's prior:

    p(frame | pose)  ~  exp(-E(pose) / T)

(``TEMPERATURE`` T: neighbouring scan lines see the same white line, so one full-weight
observation is worth less than one nat; T is fitted for calibrated probabilities).

Two beliefs carry it (``belief``; docs/lut-belief.md): ``grid`` (``--preset grid``), a
probability per table cell at the frame's field-aligned heading, moved by the odometry and
multiplied by every cell's likelihood (Markov localisation, Fox, Burgard and Thrun 1999;
grid_belief.py): nothing is born or pruned, so a place the first frames misjudged is never lost;
``tracks`` (default), at most ``tracking.MAX_TRACKS`` weighted Gaussian tracks, each a pose in
the paper's decentralised Kalman filter (kalman.py), kept by tracking.TrackBank (shared by every
pose-fixing method), to which this module gives the fixes, their tempered likelihoods and the
null.

A track, per frame: its prior is the last fused pose moved by the odometry (the last fused
motion on IMU collision frames); its heading ``imu`` (field-aligned yaw, heading.py),
``histogram`` (the paper's line-point histograms within +-40 deg of the prediction) or
``truth``, else refined by the search; the paper's local search in a ``WINDOW_M`` x
``WINDOW_M`` m square, ranked by E / T + Mahalanobis^2 / 2 (a minimum far from where the
odometry puts the robot needs that much more evidence) and refined (sub-cell, line points),
gives the fix (TableSearch.tracked_fix); the weight is multiplied by exp(-E / T), the
odometry's agreement exp(-m^2 / 2) (m the Kalman innovation, floored by ``tracking.MIN_GATE_M``
/ ``tracking.GATE_SIGMAS``) and 1 - ``tracking.KIDNAP_PROBABILITY``; the fix is fused when it
beats the null.

Global searches propose tracks on the first frame, when no track is left, every
``GLOBAL_EVERY`` frames (a wrong track cannot persist unchallenged), and after a frame not
confident up to the mirror (TrackBank.confident). Each separated minimum
(``GLOBAL_CANDIDATES``, ``tracking.AMBIGUITY_DISTANCE_M`` apart) that is not a track or its
mirror is a candidate of prior mass ``tracking.KIDNAP_PROBABILITY`` / N, N the number of
``tracking.AMBIGUITY_DISTANCE_M`` squares in the world (a uniform prior over where the robot
could have been put); weights are normalised, tracks below
``tracking.PRUNE_PROBABILITY`` dropped, tracks that meet merged. Without a known heading the
unknown-heading search (72 headings) proposes poses and headings. In ``independent`` runs
(``global_evidence: auto``; ``points``: every frame without a track) candidates and the null's
copies are weighed by the line points' distance to the nearest line (PointFit): the scan-line
error measures a miss along the ray, far for a point beside a line its ray meets at a grazing
angle, and on real images chose poses explaining fewer points (docs/manual.md). Tracked runs
keep the scan-line error for first and lost frames: with the points, a rendered run with a
look-alike place (omni-hard) locked onto it for good.

The null: the same observations at random bearings (scan lines shuffled,
``Observation.random_bearings``), searched the same way, show what chance alone explains
(E_null, the median of ``NULL_COPIES``; a tracked frame's first bounded from below,
TableSearch.tracked_score_bound). A frame with no hypothesis beating it (``uninformative``) or
fewer than ``MIN_OBSERVATIONS`` crossings fails: the tracks only predict. In a global frame the
null is one more hypothesis ("none of these"): a pose barely beating chance gets little.

Symmetry: on a point-symmetric field a track carries its mirror image's share of its weight
(``mirror``: about 1/2 when the unknown-heading search finds both, never changed by the lines;
0 with a field-aligned IMU heading); ``start_half`` (own: x < 0, opponent, any) multiplies the
other half's share at the first fix by ``start_half_error``. Each frame lists its top's mirror.

Per frame: the hypotheses (at most ``hypotheses``) with probabilities; the pose is the top one,
its probability the ``confidence``, *accepted* at >= ``min_confidence`` (``independent: true``:
every frame global, with no track, prior or odometry). Recorded: pose, ``error`` = e_norm = E /
total weight of the fix, confidence, ``mode`` (global; global-heading: the top track born this
frame; local; failed), runtime, fused covariance, hypotheses, flags: collision; heading-vision,
heading-unsure (the heading from the search; not pinned down); window-edge; global-check (a
global search beside the tracks); relocalised (the top a track born by a global search while an
older one existed); mirror-ambiguous (mirror >= half the top); start-half (first fix mirrored
onto start_half); low-confidence; too-few-observations, uninformative, no-imu-row,
no-truth-heading.

Vision covariance: the quadratic fit of the error surface at the fix gives its Hessian H (of
e_norm, m^-2); the position covariance is ``VISION_SIGMA_XY_M``^2 (1/c^2) H^-1, H's eigenvalues
clipped from below at 0.2 % of 1/c^2 (a fix seeing only parallel lines is uncertain along
them), scaled by (1 + inlier_rho / 0.05), capped at 1 m. The heading variance is the heading
source's, or from the error's curvature over the heading when the search refined it.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..common.conf import check_bounds
from ..common.errors import FieldlocError, real_path
from ..common.field import FieldModel
from ..common.geometry import wrap_angle
from ..common.map_file import MapFile
from ..common.poses_file import PoseTrack
from . import bank_smoothing, grid_belief, tracking
from . import heading as heading_mod
from .lut_search import (
    EVIDENCE,
    MatchingParams,
    Observation,
    SearchResult,
    Support,
    TableSearch,
    frame_observations,
    random_bearing_points,
)
from .point_fit import PointFit
from .radial_correction import DEFAULTS as RADIAL_DEFAULTS
from .radial_correction import PathCalibration, RadialCorrection
from .smooth import LOCAL_REACH_M, FrameCandidates
from .tracking import Candidate, FrameFailed, Track, TrackBank, eig2

log = logging.getLogger(__name__)

camera_kinds = ("omni",)  # the features it reads
confs = {
    # what a user chooses: the belief's keys (tracking.DEFAULTS; min_confidence 0.8, chosen on
    # the tuning sets' confidently wrong frames, which are more on held-out sets:
    # docs/manual.md, docs/results.md), the heading source and what is known of the start;
    # the search's tuned constants are named below (WINDOW_M, TEMPERATURE, SEARCH, ...)
    "default": {
        **tracking.DEFAULTS,
        "heading": "imu",  # imu | histogram | truth
        "imu_alignment": "field",  # field: imu yaw is field-aligned (+ small bias) | vision
        "start_half": "any",  # own (x < 0) | opponent (x > 0) | any: where the first fix is
        "start_half_error": 1e-3,  # probability that start_half is wrong
        "stamp_tolerance": 0.02,  # s, imu/truth row to frame matching (the recording's clocks)
        "global_evidence": "auto",  # points | scanlines | auto: what weighs the candidates
        # of a global search on a frame with no track (and its null): the line points'
        # distance to the nearest line (PointFit) after refining each candidate in its basin,
        # or the paper's scan-line error (along each ray: prefers poses where lines are crossed
        # at the right range to poses where the points lie on lines; docs/manual.md, real images);
        # auto: points for independent frames, scan lines for a tracked run (whose tracks
        # are weighed by the scan-line error: its first fix too, docs/manual.md)
        # online estimate of the calibration's distance error (radial_correction.py)
        "radial_correction": dict(RADIAL_DEFAULTS),
        # with smooth: learn the camera's calibration from the smoothed poses, extract the
        # frames again with it and smooth again (stages.pipelines.images_to_poses, two rounds)
        "recalibrate": True,
        # tracks: the Gaussian tracks of tracking.TrackBank (module doc); grid: a probability
        # per table cell over the whole field (grid_belief.py; needs a field-aligned heading);
        # auto: grid where the heading is field-aligned and the run tracked, else tracks.
        # tracks by default: on held-out renders the grid accepted fewer right frames
        # (docs/lut-belief.md)
        "belief": "tracks",
    },
}
confs["no-fusion"] = {**confs["default"], "fusion": {**confs["default"]["fusion"],
                                                       "enabled": False}}
confs["independent"] = {**confs["default"], "independent": True}
confs["grid"] = {**confs["default"], "belief": "grid"}
confs["tracks"] = {**confs["default"], "belief": "tracks"}


# The search's tuned constants (module doc; the values the default preset held, chosen on the
# rendered tuning sets and calibrated there: docs/results.md, docs/manual.md). The heading
# sources' are heading.py's, the belief's tracking.py's.
WINDOW_M = 2.0  # m, side of the local search square (Ribeiro et al. 2015: 4 m^2)
MIN_OBSERVATIONS = 8  # fewer crossings: the frame fails
TEMPERATURE = 0.5  # evidence (full-weight observations) per nat (calibrated)
# consecutive frames whose views are one measurement: a tracked frame's evidence counts
# 1 / TRACK_CORRELATION (calibrated)
TRACK_CORRELATION = 4.0
# rad, a vision heading less sure than this is not used (collision frames, histogram without
# straight lines)
VISION_HEADING_MAX_SIGMA_RAD = math.radians(2.4)
GLOBAL_REACH_M = 0.5  # m, how far the points' refinement moves a global candidate
GLOBAL_CANDIDATES = 16  # separated minima of a global search proposed as tracks
UNKNOWN_HEADING_CANDIDATES = 24  # (heading, cell) candidates refined
GLOBAL_EVERY = 5  # frames between global searches while tracking
NULL_COPIES = 2  # random-bearing copies of the observations (median), global
TRACKED_NULL_COPIES = 1  # ... tracked frames (their window is small)
# m, an observation within this of its predicted crossing is an inlier of the fix (c / 2:
# rho = 0.2); reported, and shapes the covariance
INLIER_ERROR_M = 0.125
VISION_SIGMA_XY_M = 0.01  # m, smallest position sigma of a well-constrained fix
# its sigma per m of its inliers' rms error (vision_covariance; fused poses consistent with
# their covariance, NEES, docs/manual.md)
VISION_RMS_FACTOR = 2.5
# the table search's matching (lut_matching.py)
SEARCH = MatchingParams(
    c=0.25,  # m, scale of 1 - c^2 / (c^2 + e^2)
    range_scale=2.0,  # m, weight 1 / (1 + (d / range_scale)^2): nearer weigh more
    distance_bin=0.05,  # m, observed-distance quantisation of the error lookup
    use_spiral=True,
    coarse_step=3,  # cells, subsampling of the unknown-heading pass
    pair_tolerance=0.6,  # m, same white line on neighbouring scan lines
)


_SEARCH_CACHE: dict = {}


def table_search(map_file: MapFile, params: MatchingParams) -> TableSearch:
    """The TableSearch of a map (built once per map file and parameters; the last one is
    kept, building it takes seconds and hundreds of MB on a full field)."""
    return _cached(map_file, params)[0]


def point_fit(map_file: MapFile, params: MatchingParams) -> PointFit:
    """The PointFit of a map's field (built once with its TableSearch)."""
    return _cached(map_file, params)[1]


def _cached(map_file: MapFile, params: MatchingParams):
    p = real_path(map_file.path)
    key = (str(p), p.stat().st_mtime_ns, params)
    if key not in _SEARCH_CACHE:
        _SEARCH_CACHE.clear()
        t = time.perf_counter()
        search = TableSearch(map_file, params)
        _SEARCH_CACHE[key] = (search, PointFit(map_file.field, c=params.c, map_path=p))
        log.info("table search for %s ready in %.1f s (tables and lookup %.0f MB, %s)", p.name,
                 time.perf_counter() - t, search.lookup_nbytes / 1e6, search.lookup_source)
    return _SEARCH_CACHE[key]


def vision_covariance(result: SearchResult, support: Support, heading_sigma: float) -> np.ndarray:
    """Covariance (3, 3) of a fix for the fusion (see the module doc)."""
    c = SEARCH.c
    ref = 1.0 / (c * c)
    h = result.hessian
    cov = np.zeros((3, 3))
    # the fix is as good as its inliers fit: their rms error times VISION_RMS_FACTOR (not
    # divided by their number: a biased mirror calibration moves them together, and the fit
    # absorbs part of the bias), at least VISION_SIGMA_XY_M
    rms = support.inlier_rms if math.isfinite(support.inlier_rms) else c
    s = ref * max(VISION_RMS_FACTOR * rms, VISION_SIGMA_XY_M) ** 2
    hxx, hxy, hyy = float(h[0, 0]), float(0.5 * (h[0, 1] + h[1, 0])), float(h[1, 1])
    if math.isfinite(hxx) and math.isfinite(hxy) and math.isfinite(hyy):
        # the Hessian's eigenvalues clipped from below, inverted, scaled
        (l1, l2), (ux, uy) = eig2(hxx, hxy, hyy)
        v1 = min(s / max(l1, 0.002 * ref), 1.0)  # capped at 1 m^2
        v2 = min(s / max(l2, 0.002 * ref), 1.0)
        cov[0, 0] = v1 * ux * ux + v2 * uy * uy
        cov[1, 1] = v1 * uy * uy + v2 * ux * ux
        cov[0, 1] = cov[1, 0] = (v1 - v2) * ux * uy
    else:
        cov[0, 0] = cov[1, 1] = 1.0
    cov[2, 2] = heading_sigma**2
    return cov


# the ranges lut's numeric keys must lie in to run at all (common.conf.check_bounds): the
# belief's (its count of hypotheses and its acceptance threshold), a clock tolerance of at
# least 0
BOUNDS = {**tracking.BOUNDS, "stamp_tolerance": (0, None)}


def check_conf(conf: dict) -> None:
    """The method's keys checked without a dataset (FieldlocError): at run time, and where a
    batch SPEC names the method, before anything runs."""
    check_bounds(conf, BOUNDS)
    heading_mod.check_keys(conf)
    tracking.check_conf(conf)
    if conf["global_evidence"] not in ("auto", "points", "scanlines"):
        raise FieldlocError("global_evidence must be auto, points or scanlines, not"
                            f" {conf['global_evidence']!r}")
    if conf["belief"] not in ("auto", "tracks", "grid"):
        raise FieldlocError(f"belief must be auto, tracks or grid, not"
                            f" {str(conf['belief'])[:40]!r}")
    if conf["belief"] == "grid":
        if conf["independent"]:
            raise FieldlocError("belief grid carries the belief from frame to frame; it does"
                                " not localise frames independently")
        grid_belief.check_conf(conf)


@dataclass(kw_only=True)
class LutCandidate(Candidate):
    """A Candidate of the table search: its fix (SearchResult) with the fix's support, its
    error term (``evidence``, full-weight observations; ``nll`` = evidence / T), ``fit`` (nats:
    nll plus the prior's Mahalanobis^2 / 2 when tracked), ``window_fit`` (tracked: the same
    from the window's quantised error term, which the null is compared with) and ``prior``
    (tracked: prior pose, inverse covariance used to search, prior covariance)."""

    support: Support
    evidence: float = 0.0
    fit: float = 0.0
    window_fit: float = math.inf
    prior: tuple | None = None


@dataclass(frozen=True)
class LutFrame:
    """One frame as its searches read it, made at the frame's start and passed to every method
    that reads it, so that no search reads another frame's: the observations (``obs``), their
    points (robot frame: what the fixes' points fit moves a fix to, ``points``), the features
    file's points (``frame_points``: every white run its scan lines crossed, or a team's
    detector's; None when the file has none) and the temperature of the frame's evidence
    (``T``: a frame alone, or one more frame of a tracked sequence)."""

    obs: Observation
    points: np.ndarray
    frame_points: np.ndarray | None
    T: float

    @cached_property
    def line_points(self) -> np.ndarray:
        """The frame's line points (what the line share of a pose counts), which weigh a
        global candidate whose evidence is the points (LutLocaliser._by_points): the features
        file's finite ones, the observations' own where the file has none. Made when first
        asked for (a tracked frame never asks)."""
        fp = self.frame_points
        fp = None if fp is None else np.asarray(fp, np.float64).reshape(-1, 2)
        return (self.points if fp is None or not len(fp)
                else fp[np.isfinite(fp).all(axis=1)])


class LutLocaliser:
    """The per-frame loop of method lut (see the module doc) and what it keeps between
    frames: the tracks, the IMU's alignment, the radial correction, when the last global
    search ran, the null copies' shuffles. What one frame's searches read is a LutFrame,
    passed to them."""

    def __init__(self, conf: dict, search: TableSearch, fit: PointFit, *, yaw, collision,
                 truth_heading, seed: int = 0):
        self.conf = conf
        self.search = search
        self.fit = fit
        self.yaw, self.collision, self.truth_heading = yaw, collision, truth_heading
        self.alignment = heading_mod.ImuAlignment(
            variance=(heading_mod.IMU_SIGMA_RAD ** 2 + math.radians(2.0) ** 2),
            known=conf["imu_alignment"] == "field")
        self.heading_sigma = heading_mod.SOURCE_SIGMA_RAD[conf["heading"]]
        self.half = 0.5 * WINDOW_M
        # a points' fit moves a fix within the search's own resolution: one table cell, half
        # a table heading step (_fit_points)
        self._fit_reach = (search.grid.resolution, 0.5 * search.step)
        self.T_frame = TEMPERATURE
        self.T_track = self.T_frame * TRACK_CORRELATION
        ny, nx = search.grid.shape
        self.symmetric = search.field.is_point_symmetric()
        # the belief: over the world the tables cover; a tracked fix is searched in the window
        self.bank = TrackBank(conf, area=nx * ny * search.grid.resolution ** 2,
                              reach=self.half,
                              reach_cells=(2 * round(self.half / search.grid.resolution) + 1) ** 2,
                              symmetric=self.symmetric)
        self._offset_updates = 0
        self.fixed_once = False  # start_half applies to the first fix only
        self.last_global = -10**9
        self.last_confident = True  # the last frame's belief, up to the mirror (TrackBank)
        self.field_heading = heading_mod.field_aligned(conf)  # rules the mirror out
        self.rng = np.random.default_rng(seed)
        # the null copies' shuffles of the scan lines, drawn from rng when first needed and
        # used in turn across frames (_null_perm)
        self._perms: np.ndarray | None = None
        self._next_perm = 0
        rc = conf["radial_correction"]
        self.radial = (RadialCorrection(robot_radius=float(search.scanlines.robot_radius))
                       if rc["enabled"] and not conf["independent"] else None)

    # ------------------------------------------------------------------ book-keeping
    def failed(self, dt: float, odo, collision: bool):
        """A failed frame: the tracks only predict (TrackBank.failed)."""
        self.last_confident = False
        self.bank.failed(dt, odo, collision)

    # ------------------------------------------------------------------ one frame
    def frame(self, i: int, fr: dict, dt: float, odo, flags: list):
        """Localise frame i: returns (hypotheses (k, 4), the top candidate, pose, covariance,
        accepted) or raises FrameFailed."""
        conf, search = self.conf, self.search
        col = bool(self.collision[i])
        bank = self.bank
        if conf["independent"]:
            bank.reset()
            dt, odo = 0.0, None
        obs, raw_distance = frame_observations(fr, search, self.radial, EVIDENCE)
        if len(obs) < MIN_OBSERVATIONS:
            raise FrameFailed("too-few-observations")
        # evidence of a frame alone, or of one more frame of a tracked sequence
        f = self.frame_input(fr, obs, self.T_track if bank.tracks else self.T_frame)
        base_heading = self._frame_heading(i, col)  # None: from each track / unknown
        other_prior = bank.other_prior()  # the mass of "elsewhere"
        tracked: list[LutCandidate] = []
        lost = False
        for t in bank.tracks:
            prior = bank.prior(t, dt, odo, col)
            lost |= bank.lost(prior[1])
            tracked.append(self._track_candidate(t, prior, f, base_heading, col, flags))
        new: list[LutCandidate] = []
        searched = None  # the global search's (headings, heading given?)
        if (not tracked or not self.last_confident or lost
                or i - self.last_global >= GLOBAL_EVERY):
            heading = base_heading
            if heading is None and tracked and self.last_confident:
                # a confident track's heading (histogram, or IMU before its alignment);
                # after a frame not confident (up to the mirror) the heading is searched too
                heading = float(max(tracked, key=lambda c: c.log_prior - c.fit).fix.theta)
            new, searched = self._global_candidates(f, heading, flags,
                                                    bank.global_log_prior(other_prior),
                                                    field_heading=base_heading is not None
                                                    and self.field_heading)
            self.last_global = i
            if tracked:
                flags.append("global-check")
        # the null: what chance explains, searched the same way
        if tracked:
            null_fit = self._tracked_null(f, tracked)
            if min(c.window_fit for c in tracked) >= null_fit:
                raise FrameFailed("uninformative")
            for c in tracked:  # a fix is fused into its track only where it beats the null
                c.beats_null = c.window_fit < null_fit
        if new or not tracked:  # a global search ran this frame
            null_evidence = self._global_null(f, *searched)
            if not tracked and (not new or min(c.evidence for c in new) / f.T
                                >= null_evidence):
                raise FrameFailed("uninformative")
        # elsewhere, where a global search found nothing better, explains what chance
        # explains (the null counts as one basin of the world's); else its share is kept
        other = bank.posterior(tracked, new, other_prior, null_evidence if new else None)
        top = bank.update(i, tracked + new, other, dt, odo, col)
        hyps = bank.hypotheses()
        self._track_imu_offset(i, obs, top, col)
        self._learn_radial(obs, raw_distance, top, hyps, col)
        if top.fix.at_window_edge:
            flags.append("window-edge")
        pose, cov, _confidence, accepted = bank.conclude(hyps, top, bool(tracked), flags)
        self.fixed_once = True
        self.last_confident = bank.confident()
        return hyps, top, pose, cov, accepted

    def frame_input(self, fr: dict, obs: Observation, T: float) -> LutFrame:
        """What the searches of the frame ``fr`` (features frame) with observations ``obs``
        read, its evidence at temperature ``T``."""
        return LutFrame(obs=obs, points=obs.points(self.search.scanlines),
                        frame_points=fr.get("points"), T=T)

    # ------------------------------------------------------------------ heading
    def _frame_heading(self, i: int, col: bool):
        """The heading of every hypothesis this frame when the source gives one (imu, truth),
        None when each track has its own (histogram) or it is unknown."""
        source = self.conf["heading"]
        if source == "truth":
            if not np.isfinite(self.truth_heading[i]):
                raise FrameFailed("no-truth-heading")
            return float(self.truth_heading[i])
        if source == "imu":
            if not np.isfinite(self.yaw[i]):
                raise FrameFailed("no-imu-row")
            self.alignment.predict()
            if not self.alignment.known:
                return None
            return self.alignment.heading(float(self.yaw[i]))
        return None

    def _track_heading(self, prior_pose, f: LutFrame, base_heading, col, flags):
        """(heading, refine by vision?) of a track this frame."""
        conf = self.conf
        if base_heading is not None:
            if col and conf["heading"] == "imu":
                flags.append("heading-vision")  # the IMU yaw jolts on collisions
                return base_heading, True
            return base_heading, False
        if conf["heading"] == "imu":  # alignment unknown yet: the track's own heading
            return float(prior_pose[2]), True
        pts = f.points if f.frame_points is None else f.frame_points
        th, sharp = heading_mod.histogram_heading(
            pts, float(prior_pose[2]), window=heading_mod.HISTOGRAM_WINDOW_RAD,
            step=heading_mod.HISTOGRAM_STEP_RAD, bin=heading_mod.HISTOGRAM_BIN_M,
            max_distance=self.search.scanlines.max_range, score=heading_mod.HISTOGRAM_SCORE)
        jump = abs(float(wrap_angle(th - prior_pose[2]))) if np.isfinite(th) else np.inf
        if sharp >= heading_mod.HISTOGRAM_MIN_SHARPNESS and jump <= heading_mod.HISTOGRAM_GATE_RAD:
            return th, False
        flags.append("heading-vision")  # no straight lines seen (e.g. only the centre circle)
        return float(prior_pose[2]), True

    # ------------------------------------------------------------------ tracks
    def _track_candidate(self, t: Track, prior, f: LutFrame, base_heading, col, flags):
        """The fix of a track this frame (step 3 of the module doc) as a Candidate, and a
        second Candidate for a clearly better minimum elsewhere in the window."""
        search, obs, T = self.search, f.obs, f.T
        prior_pose, prior_cov = prior
        theta, by_vision = self._track_heading(prior_pose, f, base_heading, col, flags)
        bank = self.bank
        info = bank.innovation_information(prior_cov)
        # the window's error term in evidence units: scaled by the frame's evidence share
        scale = obs.total_weight / max(obs.lookup_total_weight, 1e-12)
        # a heading refined by vision below is fitted by the points after it; else in the call
        fit = None if by_vision else (self.fit, f.points, *self._fit_reach)
        fix, sup, window_fit, table_xy = search.tracked_fix(
            obs, theta, prior_pose[:2], info, T / scale, T, INLIER_ERROR_M,
            half_width=self.half, prior_cap=bank.prior_cap, fit=fit)
        heading_sigma = self.heading_sigma
        if by_vision:
            rh, curv = search.refine_heading(obs, fix.cell, fix.theta)
            sigma = _curvature_sigma(curv, obs)
            if rh.error <= fix.error and sigma <= VISION_HEADING_MAX_SIGMA_RAD:
                rh.mode, rh.at_window_edge = fix.mode, fix.at_window_edge
                fix = rh
                sup = search.support(obs, fix, INLIER_ERROR_M)
                heading_sigma = sigma
            else:  # keep the predicted or jolted heading, trusted little
                heading_sigma = heading_mod.UNSURE_HEADING_SIGMA_RAD
                flags.append("heading-unsure")
            table_xy = (fix.x, fix.y)
        d = np.array([table_xy[0] - prior_pose[0], table_xy[1] - prior_pose[1]])
        evidence = fix.error
        nll = evidence / T
        fit = nll + bank.prior_term(d, info)
        R = vision_covariance(fix, sup, heading_sigma)
        if by_vision:
            self._fit_points(fix, f)
        if heading_sigma > self.heading_sigma:  # a heading this unsure moves the fix too:
            # by the heading error times the observations' mean range
            spread = heading_sigma * float(np.average(obs.distance, weights=obs.weight))
            R[:2, :2] += np.eye(2) * spread * spread
        return LutCandidate(fix=fix, support=sup, R=R, track=t, mirror=t.mirror,
                            evidence=evidence, nll=nll, fit=fit, window_fit=window_fit,
                            prior=(prior_pose, info, prior_cov),
                            log_prior=bank.tracked_log_prior(t, d, prior_cov, R))

    def _fit_points(self, fix: SearchResult, f: LutFrame, *,
                    heading_fixed: bool = True) -> float:
        """Move a fix to where its observations' line points fit the field's lines best
        (PointFit, the distance to the nearest line: more precise than the scan-line table's
        10 cm cells and 5 deg headings, less specific: along a line it is flat, so it refines
        a fix within one table cell and half a heading step and does not rank fixes); its
        heading too unless ``heading_fixed``. Returns the scan-line evidence of the fix (its
        error term before the move)."""
        max_shift, max_turn = self._fit_reach
        pose, _cost, _normal = self.fit.refine(
            f.points, f.obs.weight, fix.pose, fixed_heading=heading_fixed,
            max_shift=max_shift, max_turn=max_turn)
        fix.x, fix.y, fix.theta = float(pose[0]), float(pose[1]), float(pose[2])
        return fix.error

    def _point_evidence(self, fix: SearchResult, obs: Observation, points, *,
                        heading_fixed: bool = True) -> float:
        """Move a global candidate to the minimum of its line points' cost (PointFit) in its
        basin (``GLOBAL_REACH_M``; its heading too unless ``heading_fixed``) and return that
        cost as evidence, in the units of the scan-line error (the same observations and
        rho), but measured across the lines, not along the rays. As in method fit (Lauer et
        al.), every point weighs alike in the fit and the mean cost is scaled by the frame's
        total evidence weight (range weights and the structures' caps, Observation.
        with_evidence). Weighed by those per point, a long line seen by many scan lines
        would count less than a small clutter structure of a few points, and far points
        little: on the real minho-lab images that chose poses explaining fewer points
        (docs/results.md)."""
        reach = GLOBAL_REACH_M
        pose, cost, _normal = self.fit.refine(
            points, np.ones(len(points)), fix.pose, fixed_heading=heading_fixed,
            max_shift=reach, max_turn=self.search.step)
        fix.x, fix.y, fix.theta = float(pose[0]), float(pose[1]), float(pose[2])
        return cost * obs.total_weight / max(float(len(points)), 1e-12)

    def _by_points(self) -> bool:
        """Whether this frame's global candidates are weighed by their points: the conf
        says so (``auto``: for independent frames) and no track competes (a track's fix is
        weighed by the scan-line error)."""
        ev = self.conf["global_evidence"]
        if ev == "auto":
            ev = "points" if self.conf["independent"] else "scanlines"
        return ev == "points" and not self.bank.tracks

    # ------------------------------------------------------------------ global search
    def _global_candidates(self, f: LutFrame, heading, flags, log_prior: float, *,
                           field_heading: bool = False) -> tuple[list[LutCandidate], tuple]:
        """New-track candidates from a global search (known heading) or the unknown-heading
        search, those near an existing track (or its mirror) left out, and what the frame's
        null searches the same way: (the headings searched, None for all; the heading given,
        not refined?). ``field_heading``: the heading is field-aligned (rules the mirror
        out); otherwise a candidate's mirror image explains the frame as well
        (TrackBank.finish_global)."""
        conf, search, obs, T = self.conf, self.search, f.obs, f.T
        headings = [heading] if heading is not None else self._histogram_headings(f)
        fixes = self._search_fixes(obs, headings, UNKNOWN_HEADING_CANDIDATES)
        if headings is not None:
            for r in fixes:
                r.mode = "global" if heading is not None else "global-heading"
        sigma = heading_mod.HISTOGRAM_SIGMA_RAD if heading is None else self.heading_sigma
        out: list[LutCandidate] = []
        fixed = heading is not None
        if self._by_points():
            scored = [(self._point_evidence(r, obs, f.line_points, heading_fixed=fixed), r)
                      for r in fixes]
        else:
            scored = [(self._fit_points(r, f, heading_fixed=fixed), r) for r in fixes]
        scored.sort(key=lambda e: e[0])
        for e, r in scored:
            # the same basin as a track (or its mirror), or as a better candidate
            if self.bank.near_track(r.pose) or self.bank.fold(out, r.pose, e / T):
                continue
            sup = search.support(obs, r, INLIER_ERROR_M)
            out.append(LutCandidate(fix=r, support=sup, log_prior=log_prior, evidence=e,
                                    nll=e / T, fit=e / T,
                                    R=vision_covariance(r, sup, sigma)))
        self.bank.finish_global(out, field_heading)
        if not self.fixed_once and conf["start_half"] != "any":
            for c in out:
                self._on_start_half(f, c, flags)
        return out, (headings, fixed)

    def _search_fixes(self, obs, headings, unknown_candidates: int) -> list[SearchResult]:
        """The fixes of a global search: at each of ``headings`` its best pose and its
        separated runners-up, or with no heading (None) the unknown-heading search's best and
        its ``unknown_candidates`` runners-up, each runner-up refined in full resolution."""
        search = self.search
        if headings is None:
            r = search.unknown_heading_search(obs, candidates=unknown_candidates)
            return [r] + [self._refined(obs, c) for c in r.candidates]
        fixes = []
        for th in headings:
            g = search.global_search(obs, th, candidates=GLOBAL_CANDIDATES,
                                     separation=tracking.AMBIGUITY_DISTANCE_M)
            fixes += [g] + [self._refined(obs, c) for c in g.candidates]
        return fixes

    def _histogram_headings(self, f: LutFrame):
        """With no heading known: the four headings (90 deg apart) at which the line points'
        histograms peak (Ribeiro et al. 2015, V-B over a full quarter turn), or None when the points
        show no straight lines (the unknown-heading search then tries all 72 table headings)."""
        conf = self.conf
        if conf["heading"] != "histogram":
            return None
        th, sharp = heading_mod.histogram_heading(
            f.line_points if self._by_points() else f.obs.points(self.search.scanlines),
            0.0, window=math.pi / 4,
            step=heading_mod.HISTOGRAM_STEP_RAD, bin=heading_mod.HISTOGRAM_BIN_M,
            max_distance=self.search.scanlines.max_range, score=heading_mod.HISTOGRAM_SCORE)
        if not np.isfinite(th) or sharp < heading_mod.HISTOGRAM_MIN_SHARPNESS:
            return None
        return [float(wrap_angle(th + k * math.pi / 2)) for k in range(4)]

    def _refined(self, obs, c) -> SearchResult:
        """A runner-up (x, y, theta, e_norm) of a search refined in full resolution."""
        r = self.search.refine(obs, self.search.grid.cell_of(c[0], c[1]), c[2])
        r.mode = "global-heading"
        return r

    def _on_start_half(self, f: LutFrame, c: LutCandidate, flags):
        """The start_half prior on a first-fix candidate (TrackBank.start_half); a candidate
        moved to its mirror image is refitted there."""
        conf, obs = self.conf, f.obs

        def mirrored(c, pose):
            mx, my, mth = pose
            m = self.search.refine(obs, self.search.grid.cell_of(mx, my), mth)
            m.mode = c.fix.mode
            c.fix = m
            c.support = self.search.support(obs, m, INLIER_ERROR_M)
            c.evidence = (self._point_evidence(m, obs, f.line_points, heading_fixed=False)
                          if self._by_points()
                          else self._fit_points(m, f, heading_fixed=False))
            c.fit = c.nll = c.evidence / f.T

        if self.bank.start_half(c, conf["start_half"], float(conf["start_half_error"]),
                                mirrored):
            flags.append("start-half")

    # ------------------------------------------------------------------ the null
    def _tracked_null(self, f: LutFrame, tracked: list[LutCandidate]) -> float:
        """The null of a tracked frame: the median over ``TRACKED_NULL_COPIES``
        random-bearing copies of the observations of the best posterior score of the
        strongest track's window (its quantised error term, as Candidate.window_fit;
        module doc). The null only decides which fixes beat it; when a lower bound of every
        copy's score (TableSearch.tracked_score_bound, a few times cheaper) lies above every
        fix's window_fit, every fix beats it and that bound is returned (each comparison
        with a window_fit comes out as with the exact scores)."""
        search = self.search
        top = max(tracked, key=lambda c: c.log_prior - c.fit)
        pose, info, _cov = top.prior
        worst = max(c.window_fit for c in tracked)
        args = []
        for _ in range(TRACKED_NULL_COPIES):
            nobs = self._null_copy(f.obs)
            scale = nobs.total_weight / max(nobs.lookup_total_weight, 1e-12)
            args.append((nobs, top.fix.theta, pose[:2], info, f.T / scale))
        kw = {"half_width": self.half, "prior_cap": self.bank.prior_cap}
        bounds = [search.tracked_score_bound(*a, **kw) for a in args]
        if min(bounds) > worst:
            return min(bounds)
        return _median([search.tracked_score(*a, **kw) for a in args])

    def _null_perm(self) -> np.ndarray:
        """The next shuffle of the scan lines (3, n_angles) for a null copy (the permutations
        are drawn once from the seeded generator and used in turn)."""
        n = self.search.n_angles
        if self._perms is None:
            self._perms = np.stack([np.stack([self.rng.permutation(n) for _ in range(3)])
                                    for _ in range(64)])
        perm = self._perms[self._next_perm % len(self._perms)]
        self._next_perm += 1
        return perm

    def _null_copy(self, obs) -> Observation:
        """The next random-bearing copy of the observations (_null_perm)."""
        return obs.random_bearings(self._null_perm())

    def _global_null(self, f: LutFrame, headings, heading_fixed: bool) -> float:
        """The null of a global search: evidence / T of the median over ``null_copies``
        random-bearing copies searched globally (at the ``headings`` the search used, or over
        all headings; weighed by their points, with the heading refined unless
        ``heading_fixed``, as the frame's candidates were: _global_candidates)."""
        search, obs, T = self.search, f.obs, f.T
        by_points = self._by_points()
        unknown = max(2, UNKNOWN_HEADING_CANDIDATES // 4)
        out = []
        for _ in range(NULL_COPIES):
            perm = self._null_perm()
            nobs = obs.random_bearings(perm)
            if by_points:  # searched and weighed as the frame's candidates are
                pts = (nobs.points(search.scanlines) if f.line_points is f.points
                       else random_bearing_points(f.line_points, perm[0],
                                                  search.scanlines.angle_step))
                out.append(min(self._point_evidence(r, nobs, pts, heading_fixed=heading_fixed)
                               for r in self._search_fixes(nobs, headings, unknown)) / T)
            elif headings is None:
                r = search.unknown_heading_search(nobs, candidates=unknown)
                out.append(r.error / T)
            else:
                out.append(min(search.global_search(nobs, th, candidates=1).error
                               for th in headings) / T)
        return _median(out)

    # ------------------------------------------------------------------ learning
    def _learn_radial(self, obs, raw_distance, top: LutCandidate, hyps, col):
        """The crossings of a confident tracked frame against their predictions at the fused
        pose, into the radial correction (radial_correction.py)."""
        pose = None if self.radial is None else self.radial.teaching_pose(
            self.bank, top, hyps, col)
        if pose is None:
            return
        pred = self.search.observation_predictions(
            obs, self.search.cell_of(float(pose[0]), float(pose[1])), float(pose[2]))
        self.radial.update(raw_distance, pred)

    def _track_imu_offset(self, i, obs, top: LutCandidate, col):
        """IMU alignment: initialised on the first fix of the unknown-heading search
        (``imu_alignment: vision``), then updated from the vision heading every
        ``imu_offset_every`` frames (every frame on the first ``imu_offset_every`` updates),
        on tracked frames clean enough (half the observations inliers: clutter can tilt the
        vision heading)."""
        conf = self.conf
        if conf["heading"] != "imu" or not np.isfinite(self.yaw[i]):
            return
        if not self.alignment.known:
            var = max(math.radians(1.5) ** 2, heading_mod.IMU_SIGMA_RAD ** 2)
            tracks = self.bank.tracks
            theta = tracks[0].pose[2] if tracks else top.fix.theta
            self.alignment.initialise(float(theta), float(self.yaw[i]), var)
            return
        every = heading_mod.IMU_OFFSET_EVERY
        if every <= 0 or col or top.track is None or top.support.inlier_share < 0.5:
            return
        self._offset_updates += 1
        if i % every and self._offset_updates > every:  # every frame while it settles
            return
        r = top.fix
        rh, curv = self.search.refine_heading(obs, r.cell, r.theta)
        if curv > 0 and rh.error <= r.error * 1.5:
            self.alignment.update(rh.theta, float(self.yaw[i]), _curvature_sigma(curv, obs) ** 2)


class LutScorer(PathCalibration):
    """Method lut's candidates for the smoother (smooth.Scorer) after a causal run, with what
    that run learnt of the whole recording (the IMU's alignment, the radial correction). A
    frame's candidates are fixed as the tracks' are (the local search at the frame's heading,
    moved by the line points' fit), the global ones by the global search; their nll is the
    line points' evidence with the map crossings the radial lines should have seen and did
    not (lut_matching.unseen_error: a look-alike place predicts lines the image does not
    show) at the tracked temperature (consecutive frames' views are one measurement: the
    module doc), their covariance ``vision_covariance``."""

    def __init__(self, loc: LutLocaliser, features, sensors):
        self.loc = loc
        self.features = features
        self.names = list(features.names)
        self.frames = len(self.names)
        self.sensors = sensors
        self.mirrored = loc.symmetric and not (loc.field_heading
                                              and loc.conf["heading"] != "histogram")
        self._cache: dict = {}
        # the distance correction: the causal run's, until one learnt from the smoothed path
        # explains the path better (smooth.py)
        self.radial = loc.radial
        self.robot_radius = loc.search.scanlines.robot_radius

    def _crossings(self, i: int, pose):
        """Frame i's crossings as observed and as the tables predict them at ``pose``."""
        loc = self.loc
        fr, _obs = self._frame(i)
        raw, _d = frame_observations(fr, loc.search, None, EVIDENCE)
        cell = loc.search.cell_of(float(pose[0]), float(pose[1]))
        return raw.distance, loc.search.observation_predictions(raw, cell, float(pose[2]))

    def _frame(self, i: int):
        """(features frame, observations) of frame i, read once."""
        if i not in self._cache:
            try:
                fr = self.features.frame(self.names[i])
            except (KeyError, OSError):
                self._cache[i] = (None, None)
                return self._cache[i]
            obs, _raw = frame_observations(fr, self.loc.search, self.radial,
                                           EVIDENCE)
            self._cache[i] = (fr, obs)
        return self._cache[i]

    def _heading(self, i: int):
        """The frame's heading where its source gives one (the IMU's as aligned at the end
        of the run), else None."""
        loc = self.loc
        source = loc.conf["heading"]
        if source == "truth":
            return float(loc.truth_heading[i]) if np.isfinite(loc.truth_heading[i]) else None
        if source == "imu" and loc.alignment.known and np.isfinite(loc.yaw[i]):
            return loc.alignment.heading(float(loc.yaw[i]))
        return None

    def failed(self, i: int) -> str | None:
        fr, obs = self._frame(i)
        if fr is None:
            return "unreadable-features"
        if len(obs) < MIN_OBSERVATIONS:
            return "too-few-observations"
        return None

    def _input(self, i: int) -> LutFrame:
        """Frame i as the localiser's searches read it (its evidence at the tracked
        temperature, as the candidates' nll)."""
        fr, obs = self._frame(i)
        return self.loc.frame_input(fr, obs, self.loc.T_track)

    def _candidate(self, f: LutFrame, fix, heading_sigma: float, *, heading_fixed: bool):
        """(pose, nll, covariance, e_norm) of a fix: its nll the line points' error and the
        map crossings its radial lines should have seen and did not (lut_matching.
        unseen_error), both at the tracked temperature."""
        loc = self.loc
        e = loc._fit_points(fix, f, heading_fixed=heading_fixed)
        tables = loc.search.tables
        e += tables.radial.unseen_error(f.obs, fix.pose, tables.params)
        sup = loc.search.support(f.obs, fix, INLIER_ERROR_M)
        return fix.pose, e / loc.T_track, vision_covariance(fix, sup, heading_sigma), \
            fix.error_norm

    def global_candidates(self, i: int) -> FrameCandidates:
        loc = self.loc
        f = self._input(i)
        obs = f.obs
        heading = self._heading(i)
        headings = [heading] if heading is not None else loc._histogram_headings(f)
        fixes = loc._search_fixes(obs, headings, UNKNOWN_HEADING_CANDIDATES)
        sigma = loc.heading_sigma if heading is not None else heading_mod.HISTOGRAM_SIGMA_RAD
        rows = [self._candidate(f, r, sigma, heading_fixed=headings is not None)
                for r in fixes]
        if self.mirrored:  # the mirror image explains the frame as well: fixed there too
            mirrors = [FieldModel.mirror_pose(r.pose) for r in fixes]
            rows += [self._candidate(f, loc.search.refine(
                obs, loc.search.grid.cell_of(*m[:2]), m[2]), sigma,
                heading_fixed=headings is not None) for m in mirrors]
        return FrameCandidates.from_rows(rows)

    def local_candidates(self, i: int, starts: np.ndarray) -> FrameCandidates:
        loc = self.loc
        f = self._input(i)
        obs = f.obs
        heading = self._heading(i)
        col = bool(loc.collision[i])
        rows = []
        for p in starts:
            flags: list = []
            theta, by_vision = loc._track_heading(p, f, heading, col, flags)
            fix = loc.search.local_search(obs, theta, p[:2], half_width=LOCAL_REACH_M)
            sigma = loc.heading_sigma
            if by_vision:
                rh, curv = loc.search.refine_heading(obs, fix.cell, fix.theta)
                if rh.error <= fix.error:
                    fix = rh
                sigma = max(_curvature_sigma(curv, obs), loc.heading_sigma)
            rows.append(self._candidate(f, fix, sigma, heading_fixed=not by_vision))
        return FrameCandidates.from_rows(rows, start=range(len(rows)))


# s: how long a frame's evidence counts as correlated with its neighbours' in the smoother
# (smooth.evidence_temperature: each frame's nll divided by this over the frame interval; T = 2
# at 10 frames/s). Measured on the tuning renders (omni seeds 20-39), the log-likelihood ratio
# between the true place and the best other one stays correlated over 5.5 frames; the value is
# below that because the transitions are not divided, and from T = 3 on they led lut's first
# round to a look-alike (omni-hard seed 21). Chosen on tuning seeds 20-59; the figures and
# the fit and mcl tries are in docs/smoothing.md, "Correlated frames"
SMOOTH_CORRELATION_S = 0.2


def _smoothed(loc: LutLocaliser, features, sensors, causal: PoseTrack, conf: dict
              ) -> PoseTrack:
    """The causal run's track smoothed with the whole recording (smooth.py)."""
    scorer = LutScorer(loc, features, sensors)
    ny, nx = loc.search.grid.shape
    track = bank_smoothing.smoothed(scorer, causal, conf, increments=sensors.increments,
                                    has_odometry=sensors.has_odometry, stamps=features.stamps,
                                    collision=sensors.collision,
                                    area=nx * ny * loc.search.grid.resolution ** 2,
                                    correlation_s=SMOOTH_CORRELATION_S)
    if scorer.radial is not None:
        track.meta["radial_correction"] = scorer.radial.summary()
    return track


def run(conf: dict, dataset, features, map_file: MapFile, progress=False) -> PoseTrack:
    """Localise every frame of ``features`` (names, stamps, frame(name) with ``radial``,
    ``spiral`` and ``points``) in ``map_file``'s tables, with the odometry, IMU and truth of
    ``dataset`` (stages.common.dataset.Dataset or None). ``progress``: tqdm on the frames."""
    check_conf(conf)
    heading_mod.check_conf(conf, dataset)
    if not map_file.has_table("radial") or not map_file.has_table("spiral"):
        raise FieldlocError(f"{map_file.path}: no scan-line tables for method lut")
    search = table_search(map_file, SEARCH)
    sensors = tracking.frame_sensors(conf, dataset, features.stamps)
    if grid_belief.uses_grid(conf):
        grid = grid_belief.GridLocaliser(conf, search, yaw=sensors.yaw,
                                         collision=sensors.collision,
                                         truth_heading=sensors.truth_heading,
                                         min_observations=MIN_OBSERVATIONS)
        grid.has_odometry = bool(np.any(sensors.has_odometry))
        track = tracking.localise_frames(grid, features, sensors, desc="localize lut (grid)",
                                         progress=progress)
        if not conf["smooth"]:
            return track
        # the smoother's fixes are the tracks' (LutScorer), with what the grid learnt
        loc = LutLocaliser(conf, search, point_fit(map_file, search.params), yaw=sensors.yaw,
                           collision=sensors.collision, truth_heading=sensors.truth_heading)
        loc.radial = grid.radial
        return _smoothed(loc, features, sensors, track, conf)
    loc = LutLocaliser(conf, search, point_fit(map_file, search.params), yaw=sensors.yaw,
                       collision=sensors.collision, truth_heading=sensors.truth_heading)
    loc.bank.has_odometry = bool(np.any(sensors.has_odometry))
    track = tracking.localise_frames(loc, features, sensors, desc="localize lut",
                                     progress=progress)
    return _smoothed(loc, features, sensors, track, conf) if conf["smooth"] else track


def _curvature_sigma(curvature: float, obs: Observation) -> float:
    """Heading standard deviation of a vision heading from the curvature of the error term
    over the heading (a least-squares reading of e_norm * total weight as a log-likelihood with
    the paper's c as the error scale), at least 0.5 deg and at most 10 deg."""
    if curvature <= 0:
        return math.radians(10.0)
    sigma = math.sqrt(1.0 / (curvature * max(obs.total_weight, 1.0)))
    return float(np.clip(sigma, math.radians(0.5), math.radians(10.0)))


def _median(values) -> float:
    v = sorted(values)
    n = len(v)
    return float(v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2]))
