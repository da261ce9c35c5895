"""Method ``lut``: localisation in the scan-line tables of seed 002, frame by frame.

Per frame:

1. observations: the frame's radial (72, 4) and spiral (2, 72) crossing distances;
   fewer than ``min_observations`` -> the frame fails;
2. heading (``heading``): ``imu`` (imu.csv yaw aligned to the field, see heading.py),
   ``histogram`` (line-point histograms within +-40 deg of the last heading moved by the
   odometry's turn; accepted when sharp and within ``histogram_gate`` of that prediction),
   or ``truth`` (truth.csv, for ablations). With no heading yet (histogram on the first frame
   or after more than ``max_predicted_frames`` failures, imu with ``imu_alignment: vision``
   before the first fix) the unknown-heading global search (all 72 headings) finds pose and
   heading; such a fix must stand out from its runners-up other than the mirror pose
   (``unknown_heading_distinct``) or the frame fails as ambiguous;
3. search: on the first frame and whenever lost, global search over all cells; otherwise
   the prior is the previous pose moved by the odometry (on IMU collision frames by the last
   fused motion instead), and a local search in a ``window`` x ``window`` m square around it.
   A local fix is doubtful when its normalised error exceeds ``lost_error`` or its minimum
   lies on the window's edge; after ``lost_frames`` doubtful fixes in a row a global search
   runs and replaces the local fix if better (if the local error is acceptable, only if below
   ``relocalise_ratio`` times it: a flat error surface along the only line in view also puts
   the minimum on the edge, and one ambiguous frame must not make the track jump);
4. a fix whose normalised error exceeds ``fail_error`` is a failure: the frame is recorded as
   failed (no pose) and the next frame searches globally (a frame with too few crossings
   fails without losing the track: the prior moves on with the odometry for up to
   ``max_predicted_frames`` frames); a global search needs
   ``min_global_observations`` crossings (fewer fit too many places of a symmetric field)
   and its fix an error below ``global_max_error`` (cluttered frames fit anywhere a little):
   when lost, a frame with fewer fails; when tracking, the local fix is kept;
5. fusion (``fusion.enabled``): the vision fix and the odometry in the decentralised Kalman
   filter (kalman.py); odometry is not fused on IMU collision frames. The fused pose is the
   frame's pose; after a global search that jumped away from the track the filter restarts at
   the fix.

Recorded per frame: pose, ``error`` = the normalised error term e_norm in [0, 1) of the fix
(lut_search), ``confidence`` = (1 - e_norm / fail_error) * min(1, observations /
full_observations), ``mode`` (global, global-heading, local; ``failed`` with a reason), runtime,
fused covariance, and flags: collision (IMU flag); heading-vision (the heading source could not
be used, IMU yaw on a collision frame or a histogram without straight lines, so the search
refined the heading itself); heading-unsure (that vision heading was not pinned down either, the
predicted heading was kept with ``unsure_heading_sigma``); window-edge; mirror-ambiguous (an
unknown-heading fix whose mirror pose fits as well: on a symmetric field no image can tell the
halves apart, the first fix picks one); failure reasons too-few-observations,
too-few-observations-to-relocalise, error-too-high, ambiguous, no-imu-row, no-truth-heading.

Vision covariance for the fusion: the quadratic fit of the error surface at the fix gives its
Hessian H (of e_norm, m^-2); a well-constrained fix has H ~ I / c^2 (every observation's error
grows with the displacement along its scan line). The position covariance is
``vision_sigma_xy``^2 * (1/c^2) * H^-1, with H's eigenvalues clipped from below at 0.2 % of 1/c^2
(a fix seeing only parallel lines is uncertain along them), scaled by (1 + e_norm / 0.1) and
capped at 1 m. The heading variance is that of the heading source (``imu_sigma``,
``histogram_sigma``, ``truth_sigma``) or, for a heading refined by the search, from the
curvature of the error term over the heading.
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
from .lut_search import MatchingParams, Observation, TableSearch

log = logging.getLogger(__name__)

confs = {
    "default": {
        "heading": "imu",  # imu | histogram | truth
        "imu_alignment": "field",  # field: imu yaw is field-aligned (+ small bias) | vision
        "imu_sigma": 0.01,  # rad, IMU heading noise for the fusion
        "imu_offset_every": 5,  # frames between vision updates of the IMU offset (0: never)
        "histogram_window": math.radians(40.0),  # rad, +- around the last heading
        "histogram_step": math.radians(0.5),  # rad
        "histogram_bin": 0.05,  # m
        "histogram_sigma": 0.02,  # rad, histogram heading noise for the fusion
        "histogram_score": "peak",  # peak (seed 002) | energy (sum of squared bin counts)
        "histogram_min_sharpness": 1.7,  # best score / mean score; below: heading by vision
        "histogram_gate": 0.15,  # rad, largest accepted deviation from the predicted heading
        "max_predicted_frames": 10,  # failed frames in a row over which the heading is kept
        "truth_sigma": 0.001,  # rad
        "vision_heading_max_sigma": math.radians(2.4),  # rad, a vision heading less sure than
        # this is not used (collision frames, histogram without straight lines)
        "unsure_heading_sigma": 0.1,  # rad, heading noise for the fusion on such frames
        "stamp_tolerance": 0.02,  # s, imu/truth row to frame matching
        "window": 2.0,  # m, side of the local search square (seed 002: 4 m^2)
        "global_candidates": 3,  # separated minima refined in a global search
        "unknown_heading_candidates": 8,  # (heading, cell) candidates refined
        "unknown_heading_distinct": 1.3,  # runners-up (but the mirror) must have this many
        # times the error of an unknown-heading fix, or the frame is ambiguous and fails
        "min_observations": 8,  # fewer crossings: the frame fails
        "full_observations": 40,  # crossings for full confidence
        "min_global_observations": 40,  # fewer: too ambiguous for a global fix (frame fails
        # when lost, the track is kept when tracking)
        "lost_error": 0.3,  # e_norm above which a local fix triggers a global search
        "fail_error": 0.5,  # e_norm above which the frame fails
        "global_max_error": 0.2,  # e_norm above which a global fix is not trusted (a jump
        # needs a clear fit; tracking tolerates up to fail_error, the prior constrains it)
        "lost_frames": 3,  # doubtful local fixes in a row before a global search
        "relocalise_ratio": 0.6,  # a global fix replaces an acceptable local one (e_norm below
        # lost_error, minimum on the window edge) only when its e_norm is below this fraction
        "mirror_margin": 0.1,  # relative error difference under which a mirror is ambiguous
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


def vision_covariance(result, conf: dict, heading_sigma: float) -> np.ndarray:
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
    cxy *= 1.0 + result.error_norm / 0.1
    vals, vecs = np.linalg.eigh(cxy)
    cov[:2, :2] = (vecs * np.minimum(vals, 1.0)) @ vecs.T
    cov[2, 2] = heading_sigma**2
    return cov


def _check_conf(conf: dict, dataset):
    if conf["heading"] not in HEADING_SOURCES:
        raise FieldlocError(
            f"unknown heading source '{conf['heading']}' (use {', '.join(HEADING_SOURCES)})")
    if conf["imu_alignment"] not in ("field", "vision"):
        raise FieldlocError("imu_alignment must be 'field' or 'vision'")
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
        self.failures_in_row = 0
        self.doubtful_in_row = 0  # local fixes in a row on the window edge or above lost_error
        self.last_pose = None  # last recorded pose (fused or vision)

    def failed(self, dt: float, odo, collision: bool, reason: str):
        """Book-keeping for a failed frame: the fusion only predicts. A frame that did not fit
        (error too high) means lost; one that saw too little keeps the track (moved by the
        odometry) for up to ``max_predicted_frames`` frames."""
        self.failures_in_row += 1
        if reason == "error-too-high" or self.failures_in_row > self.conf["max_predicted_frames"]:
            self.lost = True
        if self.use_fusion:
            self.fusion.step(dt, odo, collision, None)

    def frame(self, i: int, fr: dict, dt: float, odo, flags: list):
        """Localise frame i; returns (result, pose, covariance) or raises FrameFailed."""
        conf, search = self.conf, self.search
        sl = search.scanlines
        col = bool(self.collision[i])
        obs = Observation.from_scanlines(fr.get("radial", np.zeros((0, 4))), fr.get("spiral"),
                                         search.params, sl.max_range, sl.spiral_end_radius,
                                         sl.robot_radius)
        if len(obs) < conf["min_observations"]:
            raise FrameFailed("too-few-observations")
        prior_pose = _prior(self.fusion if self.use_fusion else None, self.last_pose, odo, col)
        theta, vision_heading = self._heading(i, fr, obs, prior_pose, col, flags)
        r = self._search(i, obs, theta, prior_pose, flags)
        if r is None or r.error_norm > conf["fail_error"]:
            raise FrameFailed("error-too-high")
        heading_sigma = self.heading_sigma
        if vision_heading:
            # the search's own heading, when the error term pins it down (seeing only the
            # centre circle it does not: turning about the circle's centre changes nothing)
            rh, curv = search.refine_heading(obs, r.cell, r.theta)
            sigma = _curvature_sigma(curv, obs)
            if rh.error <= r.error and sigma <= conf["vision_heading_max_sigma"]:
                rh.mode, rh.at_window_edge = r.mode, r.at_window_edge
                r = rh
                heading_sigma = sigma
            else:  # keep the predicted (histogram) or jolted (IMU) heading, trusted little
                heading_sigma = conf["unsure_heading_sigma"]
                flags.append("heading-unsure")
        if r.mode == "global-heading":
            heading_sigma = conf["histogram_sigma"]
        self._track_imu_offset(i, obs, r, col)

        R = vision_covariance(r, conf, heading_sigma)
        pose, cov = r.pose, R
        if self.use_fusion:
            f = self.fusion
            if r.mode != "local" and f.state is not None:
                if np.hypot(*(f.state.mean[:2] - r.pose[:2])) > 3 * self.half:
                    f.state = None  # the track was wrong: restart at the fix
            est = f.step(dt, odo, col, (r.pose, R))
            pose, cov = est.mean, est.cov
        self.lost = False
        self.failures_in_row = 0
        self.last_pose = np.asarray(pose, float)
        return r, pose, cov, len(obs)

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

    def _search(self, i, obs, theta, prior_pose, flags):
        conf, search = self.conf, self.search
        if theta is None:
            if len(obs) < conf["min_global_observations"]:
                raise FrameFailed("too-few-observations-to-relocalise")
            r = search.unknown_heading_search(obs, candidates=conf["unknown_heading_candidates"])
            if r.error_norm > conf["global_max_error"]:
                raise FrameFailed("error-too-high")
            if not _distinct(r, conf["mirror_margin"], conf["unknown_heading_distinct"]):
                raise FrameFailed("ambiguous")
            if _mirror_ambiguous(r, conf["mirror_margin"]):
                if prior_pose is not None:  # an old track, however stale, picks the half
                    r = _nearest_heading_candidate(search, obs, r, float(prior_pose[2]),
                                                   conf["mirror_margin"])
                else:
                    flags.append("mirror-ambiguous")
            if conf["heading"] == "imu":
                var = max(math.radians(1.5) ** 2, conf["imu_sigma"] ** 2)
                self.alignment.initialise(r.theta, float(self.yaw[i]), var)
            return r
        if self.lost or prior_pose is None:
            if len(obs) < conf["min_global_observations"]:
                raise FrameFailed("too-few-observations-to-relocalise")
            g = search.global_search(obs, theta, candidates=conf["global_candidates"])
            if g.error_norm > conf["global_max_error"]:
                raise FrameFailed("error-too-high")
            return g
        r = search.local_search(obs, theta, prior_pose[:2], half_width=self.half)
        doubtful = r.at_window_edge or r.error_norm > conf["lost_error"]
        self.doubtful_in_row = self.doubtful_in_row + 1 if doubtful else 0
        if (self.doubtful_in_row >= conf["lost_frames"]
                and len(obs) >= conf["min_global_observations"]):
            # lost? a global fix replaces the local one only when better (clearly better when
            # the local error is acceptable: a flat error surface along the only line in view
            # also puts the local minimum on the window's edge)
            g = search.global_search(obs, theta, candidates=conf["global_candidates"])
            ratio = 1.0 if r.error_norm > conf["lost_error"] else conf["relocalise_ratio"]
            if g.error_norm < ratio * r.error_norm and g.error_norm <= conf["global_max_error"]:
                r = g
                self.doubtful_in_row = 0
        if r.mode == "local" and r.at_window_edge:
            flags.append("window-edge")
        return r

    def _track_imu_offset(self, i, obs, r, col):
        """Update the IMU offset from the vision heading every ``imu_offset_every`` frames (every
        frame while the offset is uncertain, above 0.5 deg)."""
        every = int(self.conf["imu_offset_every"])
        if self.conf["heading"] != "imu" or every <= 0 or col or r.mode != "local":
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
            r, pose, cov, n_obs = loc.frame(i, fr, dt, odo, flags)
        except FrameFailed as e:
            loc.failed(dt, odo, bool(collision[i]), str(e))
            log.debug("frame %s failed: %s", name, e)
            track.add(name, stamp, None, error=math.nan, confidence=0.0, mode="failed",
                      runtime=time.perf_counter() - t0, flags=",".join(flags + [str(e)]))
            continue
        confidence = (max(0.0, 1.0 - r.error_norm / conf["fail_error"])
                      * min(1.0, n_obs / conf["full_observations"]))
        track.add(name, stamp, pose, error=r.error_norm, confidence=confidence, mode=r.mode,
                  runtime=time.perf_counter() - t0, covariance=cov, flags=",".join(flags))
    return track


def _curvature_sigma(curvature: float, obs: Observation) -> float:
    """Heading standard deviation of a vision heading from the curvature of the error term
    over the heading (a least-squares reading of e_norm * total weight as a log-likelihood with
    the seed's c as the error scale), at least 0.5 deg and at most 10 deg."""
    if curvature <= 0:
        return math.radians(10.0)
    sigma = math.sqrt(1.0 / (curvature * max(obs.total_weight, 1.0)))
    return float(np.clip(sigma, math.radians(0.5), math.radians(10.0)))


def _prior(fusion, last_pose, odo, collision):
    """The previous pose moved by the odometry (by the last fused motion on collision frames
    or without odometry)."""
    if fusion is not None and fusion.state is not None:
        if odo is not None and not collision:
            return fusion.odometry_prior(odo)
        return compose(fusion.state.mean, fusion.last_motion)
    if last_pose is None:
        return None
    return compose(last_pose, odo) if odo is not None and not collision else last_pose.copy()


def _nearest_heading_candidate(search: TableSearch, obs: Observation, result, heading: float,
                               margin: float):
    """Among the fix and its runners-up that fit within ``margin`` (relative) of the best, the
    one whose heading is nearest ``heading``, refined."""
    limit = result.error_norm * (1 + margin) + 1e-3
    options = [(result.x, result.y, result.theta, result.error_norm)] + [
        c for c in result.candidates if c[3] <= limit]
    x, y, th, _e = min(options, key=lambda c: abs(float(wrap_angle(c[2] - heading))))
    if (x, y, th) == (result.x, result.y, result.theta):
        return result
    r = search.refine(obs, search.grid.cell_of(x, y), th)
    r.mode = result.mode
    return r


def _distinct(result, mirror_margin: float, ratio: float) -> bool:
    """Whether an unknown-heading fix stands out: every runner-up that is not (close to) its
    mirror pose has an error at least ``ratio`` times the fix's plus 0.02 (seeing only the
    centre circle, any rotation about its centre fits; seeing one corner, poses 90 deg apart
    fit alike)."""
    mx, my = -result.x, -result.y
    mth = float(wrap_angle(result.theta + math.pi))
    for x, y, th, e in result.candidates:
        mirror = math.hypot(x - mx, y - my) < 0.5 and abs(float(wrap_angle(th - mth))) < 0.2
        same = math.hypot(x - result.x, y - result.y) < 0.5 and abs(
            float(wrap_angle(th - result.theta))) < 0.2
        if not (mirror or same) and e < ratio * result.error_norm + 0.02:
            return False
    return True


def _mirror_ambiguous(result, margin: float) -> bool:
    """Whether a runner-up of an unknown-heading search is (close to) the mirror pose of the
    fix and fits almost as well."""
    if result is None:
        return False
    mx, my, mth = -result.x, -result.y, float(wrap_angle(result.theta + math.pi))
    for x, y, th, e in result.candidates:
        if (math.hypot(x - mx, y - my) < 0.5 and abs(float(wrap_angle(th - mth))) < 0.2
                and e <= result.error_norm * (1 + margin) + 1e-3):
            return True
    return False
