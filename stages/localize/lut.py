"""Method ``lut``: localisation in the scan-line tables of seed 002, frame by frame.

The matching is the seed's (lut_search.py): per observed crossing distance the error to the
table entry of its scan line, weighted by rho(e) = 1 - c^2 / (c^2 + e^2), nearer points weighing
more. This module decides whether a fix is accepted, whether the frame fails, and when the
robot is lost. None of these decisions thresholds the mean error e_norm: in a frame whose line
points are mostly clutter (a white cable on the carpet, sticks, feet, reflections) e_norm is
high at the true pose although the field lines in view fix the pose well, and a wrong pose can
score a *lower* e_norm by fitting the clutter to some other line. The decisions rest on

- support: the inliers of a fix (lut_search.Support), the observations within
  ``inlier_error`` (c / 2) of their predicted crossing, their number and share;
- distinctness (global fixes, made without a prior): no rival minimum farther than
  ``ambiguity_distance`` may fit nearly as well, and no other pose may explain a large part of
  what the fix leaves unexplained;
- agreement with the odometry (tracking): the fix must lie in the Kalman innovation gate
  around the prior.

Per frame:

1. observations: the frame's radial (72, 4) and spiral (2, 72) crossing distances; fewer than
   ``min_observations`` -> the frame fails (too-few-observations), the track is kept;
2. heading (``heading``): ``imu`` (imu.csv yaw aligned to the field, see heading.py),
   ``histogram`` (line-point histograms within +-40 deg of the last heading moved by the
   odometry's turn; accepted when sharp and within ``histogram_gate`` of that prediction),
   or ``truth`` (truth.csv, for ablations). With no heading yet (histogram on the first frame
   or after more than ``max_predicted_frames`` failures, imu with ``imu_alignment: vision``
   before the first fix) the unknown-heading global search (all 72 headings) finds pose and
   heading, accepted like a global fix with ``unknown_heading_ratio`` for ``distinct_ratio``,
   no dominance test, and its mirror pose not counted as a rival (see ``start_half``);
3. global search (lost: the first frame, more than ``max_predicted_frames`` failed frames in a
   row, or a prior so uncertain that ``gate_sigmas`` of its sigma exceed half the window).
   The fix needs ``min_global_inliers`` inliers and an inlier share of
   ``min_global_inlier_share`` (too-few-inliers), and it must be distinct (ambiguous): every
   rival minimum of the search (the ``global_candidates`` best, ``ambiguity_distance`` apart)
   has an e_norm at least ``distinct_ratio`` times the fix's and ``distinct_margin`` more in
   the error term (units of full-weight observations), or the fix dominates it: it explains
   ``dominance_unique`` observations the rival does not and ``dominance_ratio`` times as many
   as the rival explains that it does not (a rival along the only line in view explains a
   subset of what the fix explains); and a global search over the fix's outliers finds no
   pose explaining ``second_explanation`` times the fix's inlier count (at least
   ``min_global_inliers``) of them. The last test catches clutter near the robot, which
   weighs more than the far field lines: a pose fitting a cable to some line can win the
   frame, the true pose, ranked on all observations, is then not among the runners-up, but
   it explains the lines that pose leaves out;
4. tracking: the prior is the previous pose moved by the odometry (on IMU collision frames by
   the last fused motion), its covariance the fusion's prediction. The seed's local search in
   a ``window`` x ``window`` m square around it gives the fix when its innovation (Mahalanobis
   distance from the prior under the prior's covariance, the fix's covariance and a floor of
   (``min_gate`` / ``gate_sigmas``)^2 against overconfidence) is at most ``gate_sigmas``: a fix
   seeing one line passes anywhere along it, a fix within ``min_gate`` always passes.
   Otherwise (the odometry says the robot cannot have jumped to that minimum) the fix is the
   basin the prior lies in, found by descent from the prior's cell (flag outside-gate); when
   that fails the gate too, no-fit-near-prior. The fix needs ``min_inliers`` inliers and an
   inlier share of ``min_inlier_share`` (too-few-inliers). A rejected tracking fix makes a
   global search run on the same frame: its fix is taken when it passes the global tests (a
   clear frame after a wrong track), else the frame fails (flag global-<reason>) and the prior
   moves on with the odometry. A window minimum outside the gate that passes the global
   support tests and is distinctly better than the tracked fix contests the track; after
   ``lost_frames`` contested frames in a row a global fix that passes the global tests
   replaces it (flag relocalised);
5. fusion (``fusion.enabled``): the vision fix and the odometry in the decentralised Kalman
   filter (kalman.py); odometry is not fused on IMU collision frames. The fused pose is the
   frame's pose; after a global fix that failed the gate around the track the filter restarts
   at the fix.

``start_half`` (own | opponent | any): the half of the field the robot is on at its first fix,
which resolves the 180 deg mirror ambiguity of a symmetric field for the unknown-heading search
(histogram heading, or IMU with ``imu_alignment: vision``): own = x < 0 (the field's +x points
at the opponent goal), opponent = x > 0. A first fix on the other half whose mirror pose fits
as well is replaced by the mirror pose (flag start-half; flag start-half-contradicted and the
fix kept if the mirror pose fits clearly worse, on a field that is not symmetric). With
``any`` a fix whose mirror fits as well is flagged mirror-ambiguous and kept; later
re-localisations with unknown heading pick the candidate nearest the old track's heading.
Near the centre line the half is decided by the sign of x all the same.

Recorded per frame: pose, ``error`` = the normalised error term e_norm in [0, 1) of the fix
(reported, not used to decide), ``confidence`` = inlier share * min(1, inliers /
``full_inliers``), ``mode`` (global, global-heading, local; ``failed`` with a reason), runtime,
fused covariance, and flags: collision (IMU flag); heading-vision (the heading source could not
be used, IMU yaw on a collision frame or a histogram without straight lines, so the search
refined the heading itself); heading-unsure (that vision heading was not pinned down either, the
predicted heading was kept with ``unsure_heading_sigma``); window-edge (the window's minimum
lay on its edge); outside-gate; relocalised; mirror-ambiguous; start-half; failure reasons
too-few-observations, too-few-inliers, no-fit-near-prior, ambiguous, no-imu-row,
no-truth-heading.

Vision covariance for the fusion: the quadratic fit of the error surface at the fix gives its
Hessian H (of e_norm, m^-2); a well-constrained fix seen without clutter has H ~ I / c^2 (every
observation's error grows with the displacement along its scan line). The position covariance
is ``vision_sigma_xy``^2 * (1/c^2) * H^-1, with H's eigenvalues clipped from below at 0.2 % of
1/c^2 (a fix seeing only parallel lines is uncertain along them), scaled by (1 + inlier_rho /
0.05) (how tightly the inliers fit) and capped at 1 m. Clutter flattens H by the outliers' share
of the weight (they lie on rho's flat tail), so a cluttered fix is trusted less in proportion.
The heading variance is that of the heading source (``imu_sigma``, ``histogram_sigma``,
``truth_sigma``) or, for a heading refined by the search, from the curvature of the error term
over the heading.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from ..common.errors import FieldlocError
from ..common.geometry import compose, wrap_angle
from ..common.map_file import MapFile
from ..common.poses_file import PoseTrack
from . import heading as heading_mod
from .kalman import DecentralisedFusion, FusionParams
from .lut_search import MatchingParams, Observation, SearchResult, Support, TableSearch

log = logging.getLogger(__name__)

confs = {
    "default": {
        "heading": "imu",  # imu | histogram | truth
        "imu_alignment": "field",  # field: imu yaw is field-aligned (+ small bias) | vision
        "start_half": "any",  # own (x < 0) | opponent (x > 0) | any: the half of the first
        # fix, resolves the mirror ambiguity of the unknown-heading search (module doc)
        "imu_sigma": 0.01,  # rad, IMU heading noise for the fusion
        "imu_offset_every": 5,  # frames between vision updates of the IMU offset (0: never)
        "histogram_window": math.radians(40.0),  # rad, +- around the last heading
        "histogram_step": math.radians(0.5),  # rad
        "histogram_bin": 0.05,  # m
        "histogram_sigma": 0.02,  # rad, histogram heading noise for the fusion
        "histogram_score": "peak",  # peak (seed 002) | energy (sum of squared bin counts)
        "histogram_min_sharpness": 1.7,  # best score / mean score; below: heading by vision
        "histogram_gate": 0.15,  # rad, largest accepted deviation from the predicted heading
        "max_predicted_frames": 30,  # failed frames in a row over which the track is kept
        # (sooner lost when the prior's gate outgrows the window)
        "truth_sigma": 0.001,  # rad
        "vision_heading_max_sigma": math.radians(2.4),  # rad, a vision heading less sure than
        # this is not used (collision frames, histogram without straight lines)
        "unsure_heading_sigma": 0.1,  # rad, heading noise for the fusion on such frames
        "stamp_tolerance": 0.02,  # s, imu/truth row to frame matching
        "window": 2.0,  # m, side of the local search square (seed 002: 4 m^2)
        "global_candidates": 8,  # separated minima of a global search compared as rivals
        "unknown_heading_candidates": 8,  # (heading, cell) candidates refined
        "min_observations": 8,  # fewer crossings: the frame fails
        "inlier_error": 0.125,  # m, an observation within this of its predicted crossing is
        # an inlier of the fix (c / 2: rho = 0.2)
        "min_inliers": 10,  # tracking: fewer inliers at the fix and the frame fails
        "min_inlier_share": 0.1,  # tracking: smaller share of inliers and the frame fails
        "min_global_inliers": 15,  # a global fix (no prior) needs this many inliers ...
        "min_global_inlier_share": 0.5,  # ... and this share of the observations
        "ambiguity_distance": 1.0,  # m, minima farther apart than this are rivals
        "distinct_ratio": 1.5,  # a global fix's rivals must have this many times its error
        "distinct_margin": 1.5,  # ... and this much more in error-term units (full-weight
        # observations); a mirror pose that is not distinct is mirror-ambiguous. Or:
        "dominance_unique": 6,  # the fix explains at least this many observations the rival
        "dominance_ratio": 4.0,  # does not, and this many times as many as the rival explains
        # that the fix does not
        "second_explanation": 0.4,  # a global fix fails as ambiguous when one pose explains
        # this share of its inliers' count (at least min_global_inliers) among its outliers
        "unknown_heading_ratio": 2.0,  # distinct_ratio of an unknown-heading fix (72 times the
        # poses to choose from; no dominance: its rivals are too few to hold the true pose)
        "gate_sigmas": 3.0,  # tracking: largest innovation (Mahalanobis distance of the fix
        # from the prior under both covariances)
        "min_gate": 0.3,  # m, a fix this near the prior always passes the gate; smallest reach
        # of the descent from the prior
        "lost_frames": 3,  # contested tracked fixes in a row before a global search
        "full_inliers": 40,  # inliers for full confidence
        "vision_sigma_xy": 0.02,  # m, noise of a well-constrained fix (tuned on rendered sets)
        "search": {
            "c": 0.25,  # m, scale of 1 - c^2 / (c^2 + e^2)
            "range_scale": 2.0,  # m, weight 1 / (1 + (d / range_scale)^2): nearer weigh more
            "distance_bin": 0.05,  # m, observed-distance quantisation of the error lookup
            "use_spiral": True,
            "coarse_step": 3,  # cells, subsampling of the unknown-heading pass
            "pair_tolerance": 0.6,  # m, same white line on neighbouring scan lines
        },
        "fusion": {
            "enabled": True,
            **{k: getattr(FusionParams, k) for k in FusionParams.__dataclass_fields__},
        },
    },
}
confs["no-fusion"] = {**confs["default"], "fusion": {**confs["default"]["fusion"],
                                                       "enabled": False}}

HEADING_SOURCES = ("imu", "histogram", "truth")
START_HALVES = ("own", "opponent", "any")

_SEARCH_CACHE: dict = {}


def table_search(map_file: MapFile, params: MatchingParams) -> TableSearch:
    """The TableSearch of a map (built once per map file and parameters; the last one is
    kept, building it takes seconds and hundreds of MB on a full field)."""
    p = map_file.path.resolve()
    key = (str(p), p.stat().st_mtime_ns, params)
    if key not in _SEARCH_CACHE:
        _SEARCH_CACHE.clear()
        t = time.perf_counter()
        _SEARCH_CACHE[key] = TableSearch(map_file, params)
        log.info("table search for %s built in %.1f s (error lookup %.0f MB)", p.name,
                 time.perf_counter() - t, _SEARCH_CACHE[key].error_lookup.nbytes / 1e6)
    return _SEARCH_CACHE[key]


def vision_covariance(result: SearchResult, support: Support, conf: dict,
                      heading_sigma: float) -> np.ndarray:
    """Covariance (3, 3) of a fix for the fusion (see the module doc)."""
    c = float(conf["search"]["c"])
    ref = 1.0 / (c * c)
    H = np.asarray(result.hessian, float)
    cov = np.zeros((3, 3))
    if np.all(np.isfinite(H)):
        vals, vecs = np.linalg.eigh(0.5 * (H + H.T))
        vals = np.maximum(vals, 0.002 * ref)
        cxy = (vecs / vals) @ vecs.T * ref * conf["vision_sigma_xy"] ** 2
    else:
        cxy = np.eye(2) * 1.0
    cxy *= 1.0 + support.inlier_rho / 0.05
    vals, vecs = np.linalg.eigh(cxy)
    cov[:2, :2] = (vecs * np.minimum(vals, 1.0)) @ vecs.T
    cov[2, 2] = heading_sigma**2
    return cov


def fix_confidence(support: Support, conf: dict) -> float:
    """Inlier share * min(1, inliers / full_inliers), in [0, 1]."""
    return float(support.inlier_share * min(1.0, support.inliers / conf["full_inliers"]))


def _check_conf(conf: dict, dataset):
    if conf["heading"] not in HEADING_SOURCES:
        raise FieldlocError(
            f"unknown heading source '{conf['heading']}' (use {', '.join(HEADING_SOURCES)})")
    if conf["imu_alignment"] not in ("field", "vision"):
        raise FieldlocError("imu_alignment must be 'field' or 'vision'")
    if conf["start_half"] not in START_HALVES:
        raise FieldlocError(
            f"start_half must be one of {', '.join(START_HALVES)}, not '{conf['start_half']}'")
    need = {"imu": "imu", "truth": "truth"}.get(conf["heading"])
    if need and (dataset is None or dataset.optional(need) is None):
        where = dataset.root if dataset is not None else "the dataset"
        raise FieldlocError(
            f"--heading {conf['heading']} needs {need}.csv in {where}; use --heading histogram")


class FrameFailed(Exception):
    """A frame that cannot be localised; the message is the reason recorded in its flags."""


class LutLocaliser:
    """The per-frame loop of method lut (see the module doc), state kept between frames."""

    def __init__(self, conf: dict, search: TableSearch, *, yaw, collision, truth_heading):
        self.conf = conf
        self.search = search
        self.yaw, self.collision, self.truth_heading = yaw, collision, truth_heading
        self.alignment = heading_mod.ImuAlignment(
            variance=(conf["imu_sigma"] ** 2 + math.radians(2.0) ** 2),
            known=conf["imu_alignment"] == "field")
        self.heading_sigma = {"imu": conf["imu_sigma"], "histogram": conf["histogram_sigma"],
                              "truth": conf["truth_sigma"]}[conf["heading"]]
        self.fusion = DecentralisedFusion(FusionParams.from_conf(conf["fusion"]))
        self.use_fusion = bool(conf["fusion"]["enabled"])
        self.half = 0.5 * float(conf["window"])
        self.lost = True
        self.fixed_once = False  # whether any frame was localised (start_half applies before)
        self.failures_in_row = 0
        self.contested_in_row = 0  # tracked fixes in a row with a clearly better rival
        self.last_pose = None  # last recorded pose (fused or vision)

    def failed(self, dt: float, odo, collision: bool, reason: str):
        """Book-keeping for a failed frame: the fusion only predicts, the track moves on with
        the odometry for up to ``max_predicted_frames`` failed frames in a row (or until the
        prior outgrows the window, see _search), then the robot is lost (global search
        only)."""
        self.failures_in_row += 1
        self.contested_in_row = 0
        if self.failures_in_row > self.conf["max_predicted_frames"]:
            self.lost = True
        if self.use_fusion:
            self.fusion.step(dt, odo, collision, None)

    def frame(self, i: int, fr: dict, dt: float, odo, flags: list):
        """Localise frame i; returns (result, support, pose, covariance) or raises
        FrameFailed."""
        conf, search = self.conf, self.search
        sl = search.scanlines
        col = bool(self.collision[i])
        obs = Observation.from_scanlines(fr.get("radial", np.zeros((0, 4))), fr.get("spiral"),
                                         search.params, sl.max_range, sl.spiral_end_radius,
                                         sl.robot_radius)
        if len(obs) < conf["min_observations"]:
            raise FrameFailed("too-few-observations")
        prior_pose, prior_cov = self._prior(dt, odo, col)
        theta, vision_heading = self._heading(i, fr, obs, prior_pose, col, flags)
        r, sup = self._search(i, obs, theta, prior_pose, prior_cov, flags)
        heading_sigma = self.heading_sigma
        if vision_heading:
            # the search's own heading, when the error term pins it down (seeing only the
            # centre circle it does not: turning about the circle's centre changes nothing)
            rh, curv = search.refine_heading(obs, r.cell, r.theta)
            sigma = _curvature_sigma(curv, obs)
            if rh.error <= r.error and sigma <= conf["vision_heading_max_sigma"]:
                rh.mode, rh.at_window_edge = r.mode, r.at_window_edge
                r = rh
                sup = search.support(obs, r, conf["inlier_error"])
                heading_sigma = sigma
            else:  # keep the predicted (histogram) or jolted (IMU) heading, trusted little
                heading_sigma = conf["unsure_heading_sigma"]
                flags.append("heading-unsure")
        if r.mode == "global-heading":
            heading_sigma = conf["histogram_sigma"]
        self._track_imu_offset(i, obs, r, sup, col)

        R = vision_covariance(r, sup, conf, heading_sigma)
        pose, cov = r.pose, R
        if self.use_fusion:
            f = self.fusion
            if r.mode != "local" and f.state is not None:
                if self._innovation(r, R, prior_pose, prior_cov) > self.conf["gate_sigmas"]:
                    f.state = None  # the track was wrong: restart at the fix
            est = f.step(dt, odo, col, (r.pose, R))
            pose, cov = est.mean, est.cov
        self.lost = False
        self.fixed_once = True
        self.failures_in_row = 0
        self.last_pose = np.asarray(pose, float)
        return r, sup, pose, cov

    # ------------------------------------------------------------------ prior and heading
    def _prior(self, dt: float, odo, col: bool):
        """(prior pose or None, its position covariance (2, 2) or None): the previous pose
        moved by the odometry (by the last fused motion on collision frames or without
        odometry), the covariance from the fusion's prediction (without fusion: ``min_gate``
        / ``gate_sigmas`` growing with the failed frames in a row)."""
        f = self.fusion
        if self.use_fusion and f.state is not None:
            if odo is not None and not col:
                pose = f.odometry_prior(odo)
                cov = f.odometry_posterior(np.asarray(odo, float), dt).cov
            else:
                pred = f.model_prediction(dt)
                pose, cov = compose(f.state.mean, f.last_motion), pred.cov
            return pose, np.asarray(cov, float)[:2, :2]
        if self.last_pose is None:
            return None, None
        pose = compose(self.last_pose, odo) if odo is not None and not col else self.last_pose
        s = self.conf["min_gate"] / self.conf["gate_sigmas"] * math.sqrt(1 + self.failures_in_row)
        return np.asarray(pose, float).copy(), np.eye(2) * s * s

    def _gate_radius(self, prior_cov) -> float:
        """Half-width (m) of the search square around the prior when the window's minimum
        fails the gate: ``gate_sigmas`` times the prior's largest position sigma, at least
        ``min_gate``, at most half the window."""
        return float(min(max(self.conf["min_gate"],
                             self.conf["gate_sigmas"] * self._prior_sigma(prior_cov)), self.half))

    @staticmethod
    def _prior_sigma(prior_cov) -> float:
        """Largest position standard deviation (m) of the prior."""
        return math.sqrt(max(float(np.linalg.eigvalsh(prior_cov)[-1]), 0.0))

    def _innovation(self, fix: SearchResult, R: np.ndarray, prior_pose, prior_cov) -> float:
        """Mahalanobis distance of a fix's position from the prior under the sum of the prior's
        and the fix's covariances (the Kalman innovation): a fix along the only line in view is
        uncertain along it and passes wherever the search put it on the line; a minimum in
        another basin does not."""
        d = np.array([fix.x - prior_pose[0], fix.y - prior_pose[1]])
        floor = self.conf["min_gate"] / self.conf["gate_sigmas"]  # against overconfidence:
        # a fix within min_gate of the prior always passes (clutter can bias a fix by 10 cm)
        S = (np.asarray(prior_cov, float) + np.asarray(R, float)[:2, :2]
             + np.eye(2) * floor * floor)
        return float(math.sqrt(max(d @ np.linalg.solve(S, d), 0.0)))

    def _heading(self, i, fr, obs, prior_pose, col, flags):
        """(heading or None if unknown, whether the search should refine it by vision)."""
        conf = self.conf
        source = conf["heading"]
        if source == "truth":
            if not np.isfinite(self.truth_heading[i]):
                raise FrameFailed("no-truth-heading")
            return float(self.truth_heading[i]), False
        if source == "imu":
            if not np.isfinite(self.yaw[i]):
                raise FrameFailed("no-imu-row")
            self.alignment.predict()
            if not self.alignment.known:
                return None, False
            if col:  # the IMU yaw jolts on collisions: the search refines it
                flags.append("heading-vision")
            return self.alignment.heading(float(self.yaw[i])), col
        # histogram
        if prior_pose is None or self.failures_in_row > conf["max_predicted_frames"]:
            return None, False
        pts = fr.get("points")
        if pts is None:
            pts = obs.points(self.search.scanlines)
        th, sharp = heading_mod.histogram_heading(
            pts, float(prior_pose[2]), window=conf["histogram_window"],
            step=conf["histogram_step"], bin=conf["histogram_bin"],
            max_distance=self.search.scanlines.max_range, score=conf["histogram_score"])
        jump = abs(float(wrap_angle(th - prior_pose[2]))) if np.isfinite(th) else np.inf
        if sharp >= conf["histogram_min_sharpness"] and jump <= conf["histogram_gate"]:
            return th, False
        flags.append("heading-vision")  # no straight lines seen (e.g. only the centre circle)
        return float(prior_pose[2]), True

    # ------------------------------------------------------------------ searches
    def _search(self, i, obs, theta, prior_pose, prior_cov, flags):
        """(fix, its support) or FrameFailed."""
        if theta is None:
            return self._unknown_heading(i, obs, prior_pose, flags)
        if prior_pose is not None and self._prior_sigma(prior_cov) * self.conf[
                "gate_sigmas"] > self.half:
            self.lost = True  # the window no longer covers where the robot may be
        if self.lost or prior_pose is None:
            g, sup, why = self._global(obs, theta)
            if why:
                raise FrameFailed(why)
            return g, sup
        return self._track(obs, theta, prior_pose, prior_cov, flags)

    def _global(self, obs, theta):
        """Global search with a known heading: (fix, support, None) when it passes the global
        tests, else (fix, support, failure reason)."""
        conf = self.conf
        g = self.search.global_search(obs, theta, candidates=conf["global_candidates"],
                                      separation=conf["ambiguity_distance"])
        sup = self.search.support(obs, g, conf["inlier_error"])
        why = self._global_support_failure(sup)
        if why is None:
            rivals = [c for c in g.candidates
                      if math.hypot(c[0] - g.x, c[1] - g.y) > conf["ambiguity_distance"]]
            if not self._distinct(g, rivals, obs) or self._second_explanation(obs, g, sup):
                why = "ambiguous"
        return g, sup, why

    def _second_explanation(self, obs, fix: SearchResult, sup: Support) -> bool:
        """Whether the observations the fix leaves unexplained hold another consistent view:
        a global search (at the fix's heading) over the fix's outliers finds a pose with at
        least ``second_explanation`` times the fix's inliers among them (and at least
        ``min_global_inliers``). Clutter near the robot (a cable) weighs more than the far
        field lines, so a pose fitting the clutter to some line can win a frame; the field
        lines it leaves out then fit the true pose, which the global search's runners-up,
        ranked on all observations, need not hold."""
        conf, search = self.conf, self.search
        need = max(conf["min_global_inliers"], conf["second_explanation"] * sup.inliers)
        _e, inl = search.inliers(obs, fix.x, fix.y, fix.theta, conf["inlier_error"])
        rest = obs.subset(~inl)
        if len(rest) < need:
            return False
        g = search.global_search(rest, fix.theta, candidates=1)
        return search.support(rest, g, conf["inlier_error"]).inliers >= need

    def _global_support_failure(self, sup: Support):
        conf = self.conf
        if (sup.inliers < conf["min_global_inliers"]
                or sup.inlier_share < conf["min_global_inlier_share"]):
            return "too-few-inliers"
        return None

    def _distinct(self, fix: SearchResult, rivals, obs, *, ratio=None, dominance=True) -> bool:
        """Whether the fix stands out from every rival (x, y, theta, error_norm): the rival's
        e_norm at least ``distinct_ratio`` (or ``ratio``) times the fix's (computed alike) and
        above it by ``distinct_margin`` in the error term, or (with ``dominance``) the fix
        dominates the rival: it explains
        ``dominance_unique`` observations the rival does not, and ``dominance_ratio`` times as
        many as the rival explains that it does not (a rival along the only line in view
        explains a subset of what the fix explains; the true pose as a rival of a fix made of
        clutter explains lines the fix does not)."""
        conf, search = self.conf, self.search
        ref = fix.candidate_error_norm if np.isfinite(fix.candidate_error_norm) \
            else fix.error_norm
        fix_inliers = None
        for x, y, th, e in rivals:
            if self._beats(ref, e, obs, ratio):
                continue
            if not dominance:
                return False
            if fix_inliers is None:
                fix_inliers = search.inliers(obs, fix.x, fix.y, fix.theta,
                                             conf["inlier_error"])[1]
            rival_inliers = search.inliers(obs, x, y, th, conf["inlier_error"])[1]
            own = int(np.sum(fix_inliers & ~rival_inliers))
            theirs = int(np.sum(rival_inliers & ~fix_inliers))
            if own < conf["dominance_unique"] or own < conf["dominance_ratio"] * theirs:
                return False
        return True

    def _beats(self, e_fix: float, e_rival: float, obs, ratio=None) -> bool:
        """Whether e_norm ``e_fix`` is distinctly lower than ``e_rival`` (see _distinct)."""
        conf = self.conf
        ratio = conf["distinct_ratio"] if ratio is None else ratio
        return (e_rival >= ratio * e_fix
                and (e_rival - e_fix) * obs.total_weight >= conf["distinct_margin"])

    def _gated(self, obs, fix, prior_pose, prior_cov):
        """(support, innovation) of a tracked fix."""
        sup = self.search.support(obs, fix, self.conf["inlier_error"])
        R = vision_covariance(fix, sup, self.conf, self.heading_sigma)
        return sup, self._innovation(fix, R, prior_pose, prior_cov)

    def _track(self, obs, theta, prior_pose, prior_cov, flags):
        """Local search around the prior, gated by the odometry (module doc, step 4)."""
        conf, search = self.conf, self.search
        gate = conf["gate_sigmas"]
        w = search.local_search(obs, theta, prior_pose[:2], half_width=self.half)
        if w.at_window_edge:
            flags.append("window-edge")
        why = None
        fix = w
        sup, d = self._gated(obs, w, prior_pose, prior_cov)
        if d > gate:  # the window's minimum is where the robot cannot be: the basin the prior
            # lies in (descent from the prior's cell, at most the gate radius far)
            flags.append("outside-gate")
            steps = math.ceil(self._gate_radius(prior_cov) / search.grid.resolution)
            fix = search.refine(obs, search.grid.cell_of(prior_pose[0], prior_pose[1]), theta,
                                max_moves=steps)
            sup, d = self._gated(obs, fix, prior_pose, prior_cov)
            if d > gate:
                why = "no-fit-near-prior"
        if why is None and (sup.inliers < conf["min_inliers"]
                            or sup.inlier_share < conf["min_inlier_share"]):
            why = "too-few-inliers"
        if why is not None:
            # a clear frame after a wrong track: a global fix that passes the global tests
            g, gsup, gwhy = self._global(obs, theta)
            if gwhy is None:
                self.contested_in_row = 0
                return g, gsup
            flags.append(f"global-{gwhy}")
            raise FrameFailed(why)
        fix.mode = "local"
        # a clearly better minimum outside the gate, good enough for a global fix, contests
        # the track; after lost_frames such frames a passing global search replaces it
        contested = False
        if fix is not w:
            wsup = search.support(obs, w, conf["inlier_error"])
            contested = (self._global_support_failure(wsup) is None
                         and self._beats(w.error_norm, fix.error_norm, obs))
        self.contested_in_row = self.contested_in_row + 1 if contested else 0
        if self.contested_in_row >= conf["lost_frames"]:
            self.contested_in_row = 0
            g, gsup, gwhy = self._global(obs, theta)
            if gwhy is None and math.hypot(g.x - fix.x, g.y - fix.y) > conf["ambiguity_distance"]:
                flags.append("relocalised")
                return g, gsup
        return fix, sup

    def _unknown_heading(self, i, obs, prior_pose, flags):
        """Unknown-heading global search: accepted like a global fix, its rivals all
        candidates but the same pose and the mirror pose; the mirror ambiguity resolved by
        ``start_half`` on the first fix, by the old track's heading later."""
        conf, search = self.conf, self.search
        r = search.unknown_heading_search(obs, candidates=conf["unknown_heading_candidates"])
        sup = search.support(obs, r, conf["inlier_error"])
        why = self._global_support_failure(sup)
        if why:
            raise FrameFailed(why)
        rivals = [c for c in r.candidates if not (_near_pose(c, r.pose)
                                                  or _near_pose(c, _mirror(r.pose)))]
        ratio = conf["unknown_heading_ratio"]
        if (not self._distinct(r, rivals, obs, ratio=ratio, dominance=False)
                or self._second_explanation(obs, r, sup)):
            raise FrameFailed("ambiguous")
        mirrors = [c for c in r.candidates if _near_pose(c, _mirror(r.pose))
                   and not self._beats(r.error_norm, c[3], obs, ratio)]
        if conf["start_half"] != "any" and not self.fixed_once:
            r = self._on_start_half(obs, r, flags)
            sup = search.support(obs, r, conf["inlier_error"])
        elif mirrors:
            if prior_pose is not None:  # an old track, however stale, picks the half
                e_fix = r.error_norm
                r = _nearest_heading_candidate(
                    search, obs, r, float(prior_pose[2]),
                    lambda e: not self._beats(e_fix, e, obs, ratio))
                sup = search.support(obs, r, conf["inlier_error"])
            else:
                flags.append("mirror-ambiguous")
        if conf["heading"] == "imu":
            var = max(math.radians(1.5) ** 2, conf["imu_sigma"] ** 2)
            self.alignment.initialise(r.theta, float(self.yaw[i]), var)
        return r, sup

    def _on_start_half(self, obs, r: SearchResult, flags) -> SearchResult:
        """The fix or its mirror pose, whichever lies on ``start_half``, when the mirror fits
        as well (within ``distinct_margin``)."""
        want_negative = self.conf["start_half"] == "own"
        if (r.x < 0) == want_negative:
            return r
        mx, my, mth = _mirror(r.pose)
        m = self.search.refine(obs, self.search.grid.cell_of(mx, my), mth)
        if self._beats(r.error_norm, m.error_norm, obs, self.conf["unknown_heading_ratio"]):
            flags.append("start-half-contradicted")  # an asymmetric field: the fix stands
            return r
        m.mode = r.mode
        m.candidates = r.candidates
        m.candidate_error_norm = m.error_norm
        flags.append("start-half")
        return m

    def _track_imu_offset(self, i, obs, r, sup, col):
        """Update the IMU offset from the vision heading every ``imu_offset_every`` frames (every
        frame while the offset is uncertain, above 0.5 deg), on tracked frames clean enough for
        a global fix (clutter can tilt the vision heading)."""
        every = int(self.conf["imu_offset_every"])
        if self.conf["heading"] != "imu" or every <= 0 or col or r.mode != "local":
            return
        if sup.inlier_share < self.conf["min_global_inlier_share"]:
            return
        if i % every and self.alignment.variance < math.radians(0.5) ** 2:
            return
        rh, curv = self.search.refine_heading(obs, r.cell, r.theta)
        if curv > 0 and rh.error <= r.error * 1.5:
            self.alignment.update(rh.theta, float(self.yaw[i]), _curvature_sigma(curv, obs) ** 2)


def run(conf: dict, dataset, features, map_file: MapFile, progress=False) -> PoseTrack:
    """Localise every frame of ``features`` (names, stamps, frame(name) with ``radial``,
    ``spiral`` and ``points``) in ``map_file``'s tables, with the odometry, IMU and truth of
    ``dataset`` (stages.common.dataset.Dataset or None). ``progress``: tqdm on the frames."""
    from tqdm import tqdm

    from .motion_model import accumulate_odometry

    _check_conf(conf, dataset)
    if not map_file.has_table("radial") or not map_file.has_table("spiral"):
        raise FieldlocError(f"{map_file.path}: no scan-line tables for method lut")
    search = table_search(map_file, MatchingParams.from_conf(conf["search"]))
    names = list(features.names)
    stamps = np.asarray(features.stamps, dtype=float)
    n = len(names)
    tol = float(conf["stamp_tolerance"])
    odometry = dataset.optional("odometry") if dataset is not None else None
    increments, has_odo = accumulate_odometry(odometry, stamps)
    imu = dataset.optional("imu") if dataset is not None else None
    if imu is not None:
        yaw, collision = heading_mod.imu_per_frame(imu, stamps, tol)
    else:
        yaw, collision = np.full(n, np.nan), np.zeros(n, dtype=bool)
    truth_th = (heading_mod.truth_heading(dataset.optional("truth"), stamps, tol)
                if conf["heading"] == "truth" else None)
    loc = LutLocaliser(conf, search, yaw=yaw, collision=collision, truth_heading=truth_th)

    track = PoseTrack()
    prev_stamp = None
    for i in tqdm(range(n), desc="localize lut", unit="frame", disable=not progress):
        name, stamp = names[i], float(stamps[i])
        dt = 0.0 if prev_stamp is None else max(stamp - prev_stamp, 0.0)
        prev_stamp = stamp
        odo = increments[i] if has_odo[i] else None
        flags = ["collision"] if collision[i] else []
        try:
            fr = features.frame(name)
        except (KeyError, OSError) as e:
            fr, reason = None, f"unreadable-features ({e})"
        t0 = time.perf_counter()  # the method's time, without reading the features
        try:
            if fr is None:
                raise FrameFailed(reason)
            r, sup, pose, cov = loc.frame(i, fr, dt, odo, flags)
        except FrameFailed as e:
            loc.failed(dt, odo, bool(collision[i]), str(e))
            log.debug("frame %s failed: %s", name, e)
            track.add(name, stamp, None, error=math.nan, confidence=0.0, mode="failed",
                      runtime=time.perf_counter() - t0, flags=",".join(flags + [str(e)]))
            continue
        track.add(name, stamp, pose, error=r.error_norm, confidence=fix_confidence(sup, conf),
                  mode=r.mode, runtime=time.perf_counter() - t0, covariance=cov,
                  flags=",".join(flags))
    return track


def _curvature_sigma(curvature: float, obs: Observation) -> float:
    """Heading standard deviation of a vision heading from the curvature of the error term
    over the heading (a least-squares reading of e_norm * total weight as a log-likelihood with
    the seed's c as the error scale), at least 0.5 deg and at most 10 deg."""
    if curvature <= 0:
        return math.radians(10.0)
    sigma = math.sqrt(1.0 / (curvature * max(obs.total_weight, 1.0)))
    return float(np.clip(sigma, math.radians(0.5), math.radians(10.0)))


def _mirror(pose) -> tuple[float, float, float]:
    """The pose seeing the same lines under the field's 180 deg symmetry."""
    return -float(pose[0]), -float(pose[1]), float(wrap_angle(float(pose[2]) + math.pi))


def _near_pose(candidate, pose, distance: float = 0.5, angle: float = 0.2) -> bool:
    """Whether a candidate (x, y, theta, ...) lies within ``distance`` m and ``angle`` rad of
    a pose."""
    return (math.hypot(candidate[0] - pose[0], candidate[1] - pose[1]) < distance
            and abs(float(wrap_angle(candidate[2] - pose[2]))) < angle)


def _nearest_heading_candidate(search: TableSearch, obs: Observation, result, heading: float,
                               fits_as_well):
    """Among the fix and its runners-up whose e_norm ``fits_as_well``, the one whose heading
    is nearest ``heading``, refined."""
    options = [(result.x, result.y, result.theta, result.error_norm)] + [
        c for c in result.candidates if fits_as_well(c[3])]
    x, y, th, _e = min(options, key=lambda c: abs(float(wrap_angle(c[2] - heading))))
    if (x, y, th) == (result.x, result.y, result.theta):
        return result
    r = search.refine(obs, search.grid.cell_of(x, y), th)
    r.mode = result.mode
    r.candidates = result.candidates
    r.candidate_error_norm = r.error_norm
    return r
