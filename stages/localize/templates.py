"""Method ``templates``: the SURF template paper's localisation by local features of the floor
matched against a template database (stages.common.templates, from build-templates), as ranked
hypotheses with a probability each.

Per frame the query is the frame's ground features (stages.common.ground_features, with the
conf the database was built with). Candidate templates:

- tracking: for every track (tracking.TrackBank), the ``TRACKED_TEMPLATES`` templates nearest
  to its odometry-propagated prior, within ``REACH_M`` m of it;
- lost (no track, a track whose prior outgrew the reach, the last frame not accepted, every
  ``GLOBAL_EVERY`` frames): a vote over the whole database. One descriptor index over all
  templates' features (template_matching.FeatureIndex: FLANN kd-trees per Laplacian sign, LSH
  for ORB), built once per database; every query feature's nearest neighbour that passes the
  ratio test votes for the template it belongs to; the ``GLOBAL_TEMPLATES`` templates with most
  votes are fitted.

A template is fitted by template_matching: its own index (built on first use), matches with
the ratio test and equal Laplacian sign, the pose of the SURF template paper's eq. 4 by
``pose_solver`` (``descent``: the paper's coordinate descent over (dtheta, dy, dx) from (0, 0, 0)
until no change; ``closed-form``: 2D Kabsch), pairs farther than median + ``OUTLIER_SIGMAS`` x
1.4826 MAD of the pair distances (never below ``MIN_OUTLIER_M``) removed and the pose estimated
again; the field pose is the template's pose composed with the fit. A fit needs ``MIN_PAIRS`` inlier
pairs.

The likelihood. The fit's evidence L (nats, template_matching.evidence: every pair a correct
match within ``PAIR_SIGMA_M`` or a wrong one anywhere on the ground image) tempered by
``TEMPERATURE`` is the frame's log-likelihood ratio against "no template explains the frame":
nll = -L / T. The null, what chance explains: the same fit on the same pairs with the query
points shuffled among them (``NULL_COPIES`` copies, the median evidence); a fix that does not
beat it is not fused, a frame where none does fails (``uninformative``). In a frame with a
global search, elsewhere (the mass of tracking.TrackBank's "other") explains what the null
explains, also when the vote found nothing but the tracks (then the search has looked
elsewhere and found nothing better: the mass a poor tracked frame gave elsewhere comes back to
the tracks); in a frame without one it keeps its share, as for lut.

The fix's covariance for the fusion: position sigma the inliers' rms pair distance (at least
``VISION_SIGMA_XY_M``; not divided by their number: one calibration error moves them together),
heading sigma that rms over the inliers' rms distance from their centroid (at least
``VISION_SIGMA_THETA_RAD``).

Belief, Kalman fusion with odometry, hypotheses and confidence are tracking.TrackBank's, as for
lut. The mirror image of a pose on a point-symmetric field is only a hypothesis where a template
near it matched too (the floor's texture, unlike the lines, is not symmetric).

Recorded per frame: the pose, ``error`` = rms inlier pair distance (m), confidence, mode (global:
the top track was born this frame; local), runtime (the method's: ground features, matching and
pose; not reading the image), hypotheses, flags (global-check, relocalised, mirror-ambiguous,
low-confidence; failures too-few-features, no-match, uninformative, unreadable-image).
``PoseTrack.meta``: the pose solver, descent rounds, ground-feature and matching times.

With ``smooth`` (docs/smoothing.md) the causal run is followed by smooth.smooth_track over
``TemplateScorer``'s candidates (the vote's fixes, the fits near given starts, the frame's
null), reusing the causal run's query features; the output is the smoothed track.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from ..common import ground_features as gf
from ..common.camera import camera_can
from ..common.conf import check_bounds
from ..common.dataset import read_image, read_mask
from ..common.errors import DatasetError, FieldlocError
from ..common.geometry import wrap_angle
from ..common.poses_file import PoseTrack
from . import bank_smoothing, tracking
from . import heading as heading_mod
from . import template_matching as tm
from .smooth import FrameCandidates
from .tracking import Candidate, TrackBank

log = logging.getLogger(__name__)

# read by localize.main: this method localises the dataset's images against a template
# database (templates=), not a features file
INPUT = "templates"
camera_kinds = ("omni",)  # localize.method_camera_kinds

confs = {
    # what a user chooses: the heading source, the pose solver (--pose-solver), the
    # recording's clock tolerance and the belief's keys (tracking.DEFAULTS); the matching's
    # tuned constants are named below (RATIO, MIN_PAIRS, TEMPERATURE, ...)
    "default": {
        **tracking.DEFAULTS,
        "heading": "imu",  # imu (imu.csv yaw, field-aligned) | track (the tracks' own)
        "pose_solver": "descent",  # descent (the SURF template paper) | closed-form (2D Kabsch)
        "stamp_tolerance": 0.02,  # s, imu row to frame matching (the recording's clocks)
    },
}
confs["closed-form"] = {**confs["default"], "pose_solver": "closed-form"}
confs["no-fusion"] = {**confs["default"], "fusion": {**confs["default"]["fusion"],
                                                      "enabled": False}}
confs["independent"] = {**confs["default"], "independent": True}

# the ranges the keys above must lie in (common.conf.check_bounds, checked when a run is checked,
# before any input is read): the bank's (tracking.BOUNDS) and a clock tolerance of at least 0
BOUNDS = {**tracking.BOUNDS, "stamp_tolerance": (0, None)}

# The matching's tuned constants (module doc). ratio, min_pairs and consensus_m were chosen on
# a capture session of the same venue by the same robot (docs/manual.md, bench inputs); the
# rest are the values the default preset held.
LOST_HEADINGS = 12  # headings tried when lost with no heading (track, no tracks)
CONSENSUS_M = 0.2  # m, pairs agreeing on one translation (template_matching)
# Lowe's ratio test, loose: the floor repeats itself (paint, carpet), a correct match's
# runner-up is often close, and the consensus removes what the test lets through
RATIO = 0.95
OUTLIER_SIGMAS = 3.0  # pair distances beyond median + this x robust sigma removed
MIN_OUTLIER_M = 0.05  # m, never removed below this
OUTLIER_PASSES = 3
MIN_PAIRS = 5  # inlier pairs of a fix
PAIR_SIGMA_M = 0.03  # m per axis, a correct pair's distance after the fit
INLIER_PRIOR = 0.3  # share of the pairs that are correct matches
TEMPERATURE = 3.0  # nats of evidence per nat of likelihood
REACH_M = 1.5  # m, templates considered around a track's prior
TRACKED_TEMPLATES = 3  # templates fitted per track
GLOBAL_TEMPLATES = 5  # templates fitted by the vote when lost
GLOBAL_EVERY = 10  # frames between global checks while tracking
NULL_COPIES = 3  # query-shuffled copies of a fix's pairs (median evidence)
VISION_SIGMA_XY_M = 0.02  # m, floor of a fix's position sigma
VISION_SIGMA_THETA_RAD = math.radians(0.5)  # rad, floor of a fix's heading sigma
FLANN_CHECKS = 32  # leaves FLANN visits per query


class FrameFailed(Exception):
    """A frame that cannot be localised; the message is the reason recorded in its flags."""


@dataclass
class TemplateFix:
    """A fix against one template: the field pose and what it rests on."""

    pose: np.ndarray  # (x, y, theta) on the field
    template: int
    fit: tm.Fit
    evidence: float  # nats
    pairs: int  # matched pairs before outlier removal
    rms: float  # m, inlier pair distances
    mode: str = "local"
    heading: float = 0.0  # the query's heading its points were turned by
    pairs_t: np.ndarray | None = None  # the matched points (for the null)
    pairs_q: np.ndarray | None = None


def check_conf(conf: dict) -> None:
    """The method's keys (FieldlocError)."""
    check_bounds(conf, BOUNDS)
    tracking.check_conf(conf)
    if conf["pose_solver"] not in tm.SOLVERS:
        raise FieldlocError(f"pose_solver must be one of {', '.join(tm.SOLVERS)}, not"
                            f" '{conf['pose_solver']}'")
    if conf["heading"] not in ("imu", "track"):
        raise FieldlocError(f"heading must be imu or track, not '{conf['heading']}'")


class TemplateMatcher:
    """The database with its indexes: one over all features (the vote, built at once) and one
    per template (built on first use)."""

    def __init__(self, db, conf: dict):
        self.db = db
        self.conf = conf
        self.metric = "hamming" if db.feature_kind == "orb" else "l2"
        self.owner = db.owner
        self.checks = FLANN_CHECKS
        self.index = tm.FeatureIndex(db.descriptors, db.laplacian, self.metric,
                                     checks=self.checks)
        self._template_index: dict[int, tm.FeatureIndex] = {}
        self.area = (2 * gf.unwarp.grid_of_conf(db.ground_conf["ground"]).extent) ** 2
        self.rounds = 0
        self.fits = 0

    def template_index(self, k: int) -> tm.FeatureIndex:
        idx = self._template_index.get(k)
        if idx is None:
            t = self.db.template(k)
            idx = tm.FeatureIndex(t.descriptors, t.laplacian, self.metric, checks=self.checks)
            self._template_index[k] = idx
        return idx

    def vote(self, query: gf.GroundFeatures, n: int) -> list[int]:
        """The ``n`` templates most query features' nearest neighbours (ratio test, same
        Laplacian sign) belong to, most votes first (templates without a vote left out)."""
        idx, dist = self.index.knn(query.descriptors, query.laplacian, 2)
        _q, rows, _d = tm.ratio_matches(idx, dist, RATIO)
        if not len(rows):
            return []
        votes = np.bincount(self.owner[rows], minlength=len(self.db))
        order = np.argsort(-votes, kind="stable")[:n]
        return [int(k) for k in order if votes[k] > 0]

    def fit(self, query: gf.GroundFeatures, k: int, heading: float) -> TemplateFix | None:
        """The fix of the query (described at ``heading``, rad) against template k, or None
        (too few pairs). Both point sets are turned to the field's axes (the template's by its
        pose, the query's by ``heading``), so the fit's rotation is the heading's error and
        the pairs' consensus (template_matching.consensus_fit) finds the correct ones; the
        field pose is the template's position plus the fit's translation, ``heading`` plus its
        rotation."""
        c = self.conf
        qi, ti, _d = tm.match(query, self.template_index(k), RATIO)
        if len(qi) < MIN_PAIRS:
            return None
        tp = self.db.poses[k]
        t = _turn(self.db.template(k).points[ti], float(tp[2]))
        q = _turn(query.points[qi], heading)
        f = tm.consensus_fit(t, q, radius=CONSENSUS_M, solver=c["pose_solver"],
                             outlier_sigmas=OUTLIER_SIGMAS,
                             min_outlier_m=MIN_OUTLIER_M,
                             outlier_passes=OUTLIER_PASSES,
                             min_pairs=MIN_PAIRS)
        if f is None:
            return None
        self.rounds += f.rounds
        self.fits += 1
        ev = tm.evidence(f.residuals, PAIR_SIGMA_M, self.area,
                         INLIER_PRIOR)
        rms = float(np.sqrt(np.mean(f.residuals[f.inliers] ** 2)))
        pose = np.array([tp[0] + f.pose[0], tp[1] + f.pose[1],
                         float(wrap_angle(heading + f.pose[2]))])
        return TemplateFix(pose=pose, template=k, fit=f, evidence=ev, pairs=len(qi), rms=rms,
                           heading=heading, pairs_t=t, pairs_q=q)

    def null_evidence(self, fix: TemplateFix, rng) -> float:
        """What chance explains (module doc): the median evidence of the fit on the fix's
        pairs with the query points shuffled."""
        out = []
        for _ in range(NULL_COPIES):
            q = fix.pairs_q[rng.permutation(len(fix.pairs_q))]
            f = tm.consensus_fit(fix.pairs_t, q, radius=CONSENSUS_M,
                                 solver="closed-form", outlier_sigmas=OUTLIER_SIGMAS,
                                 min_outlier_m=MIN_OUTLIER_M,
                                 outlier_passes=OUTLIER_PASSES, min_pairs=2)
            out.append(0.0 if f is None else tm.evidence(
                f.residuals, PAIR_SIGMA_M, self.area, INLIER_PRIOR))
        return float(np.median(out))

    def covariance(self, fix: TemplateFix) -> np.ndarray:
        """The fix's covariance (3, 3) for the fusion (module doc)."""
        q = fix.pairs_q[fix.fit.inliers]
        spread = float(np.sqrt(np.mean(np.sum((q - q.mean(0)) ** 2, axis=1)))) if len(q) else 0
        sxy = max(fix.rms, VISION_SIGMA_XY_M)
        sth = max(fix.rms / max(spread, 1e-3), VISION_SIGMA_THETA_RAD)
        return np.diag([sxy * sxy, sxy * sxy, min(sth, math.pi) ** 2])


def _turn(points: np.ndarray, angle: float) -> np.ndarray:
    """Points (N, 2) turned counter-clockwise by ``angle``."""
    c, s = math.cos(angle), math.sin(angle)
    p = np.asarray(points, float)
    return np.stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1]], axis=1)


class TemplateLocaliser:
    """The per-frame loop of method templates, the tracks kept between frames."""

    def __init__(self, conf: dict, matcher: TemplateMatcher, field, camera, mask, *,
                 seed: int = 0):
        self.conf = conf
        self.m = matcher
        self.camera, self.mask = camera, mask
        self.gconf = matcher.db.ground_conf
        self.field_axes = bool(matcher.db.field_axes)
        x0, x1, y0, y1 = field.world_bounds()
        reach = REACH_M
        self.bank = TrackBank(conf, area=(x1 - x0) * (y1 - y0), reach=reach,
                              reach_cells=max(int((2 * reach / 0.05) ** 2), 1),
                              symmetric=field.is_point_symmetric())
        self.T = TEMPERATURE
        self.rng = np.random.default_rng(seed)
        self.last_global = -10**9
        self.last_accepted = True
        self.feature_s = 0.0

    def failed(self, dt, odo, col=False):
        self.last_accepted = False
        self.bank.failed(dt, odo, col)

    def _query(self, image, heading: float, cache: dict) -> gf.GroundFeatures:
        """The frame's ground features, described at ``heading`` when the templates were in
        the field's axes (once per frame otherwise)."""
        key = round(float(heading), 6) if self.field_axes else None
        q = cache.get(key)
        if q is None:
            t0 = time.perf_counter()
            q = gf.ground_features(image, self.camera, self.gconf, self.mask,
                                   heading=heading if self.field_axes else None)
            self.feature_s += time.perf_counter() - t0
            cache[key] = q
        return q

    def _best(self, query, templates, heading) -> TemplateFix | None:
        best = None
        for k in templates:
            f = self.m.fit(query, k, heading)
            if f is not None and (best is None or f.evidence > best.evidence):
                best = f
        return best

    def frame(self, i: int, image, dt: float, odo, flags: list, yaw: float = math.nan,
              cache: dict | None = None):
        """Localise one frame (``yaw``: the IMU's, NaN if none): (hypotheses, top candidate,
        pose, covariance, accepted), or FrameFailed. ``cache``: the frame's query features
        by heading (``_query``), filled here (the smoother reuses them)."""
        conf, bank, m = self.conf, self.bank, self.m
        if conf["independent"]:
            bank.reset()
            dt, odo = 0.0, None
        cache = {} if cache is None else cache
        use_imu = conf["heading"] == "imu" and math.isfinite(yaw)
        other_prior = bank.other_prior()
        tracked: list[Candidate] = []
        lost = False
        fixes_seen: list[TemplateFix] = []
        for t in bank.tracks:
            prior_pose, prior_cov = bank.prior(t, dt, odo, False)
            lost |= bank.lost(prior_cov)
            heading = yaw if use_imu else float(prior_pose[2])
            query = self._query(image, heading, cache)
            d = np.hypot(m.db.poses[:, 0] - prior_pose[0], m.db.poses[:, 1] - prior_pose[1])
            near = [int(k) for k in np.argsort(d, kind="stable")[:TRACKED_TEMPLATES]
                    if d[k] <= REACH_M]
            fix = self._best(query, near, heading) if len(query) >= MIN_PAIRS else None
            if fix is None:  # nothing matched: the track explains the frame as chance does
                fix = TemplateFix(pose=np.asarray(prior_pose, float), template=-1, fit=None,
                                  evidence=0.0, pairs=0, rms=math.nan, heading=heading)
                R = np.eye(3)
                c = Candidate(fix=fix, R=R, track=t, mirror=t.mirror, nll=0.0,
                              beats_null=False,
                              log_prior=bank.tracked_log_prior(t, np.zeros(2), prior_cov, R))
            else:
                R = m.covariance(fix)
                dd = fix.pose[:2] - np.asarray(prior_pose[:2], float)
                c = Candidate(fix=fix, R=R, track=t, mirror=t.mirror, nll=-fix.evidence / self.T,
                              log_prior=bank.tracked_log_prior(t, dd, prior_cov, R))
                fixes_seen.append(fix)
            tracked.append(c)
        new: list[Candidate] = []
        searched = (not tracked or not self.last_accepted or lost
                    or i - self.last_global >= GLOBAL_EVERY)
        if searched:
            self.last_global = i
            if tracked:
                flags.append("global-check")
            if use_imu:
                headings = [yaw]
            elif tracked and self.last_accepted:
                headings = [float(bank.tracks[0].pose[2])]
            elif self.field_axes:  # no heading known: try them
                n = LOST_HEADINGS
                headings = [2 * math.pi * j / n - math.pi for j in range(n)]
            else:  # rotation-invariant features: the fit finds the heading
                headings = [0.0]
            lp = bank.global_log_prior(other_prior)
            fixes = []
            for h in headings:
                query = self._query(image, h, cache)
                if len(query) < MIN_PAIRS:
                    continue
                fixes += [f for f in (m.fit(query, k, h) for k in
                                      m.vote(query, GLOBAL_TEMPLATES))
                          if f is not None]
            fixes.sort(key=lambda f: -f.evidence)
            for f in fixes:
                f.mode = "global"
                if bank.near_track(f.pose) or bank.fold(new, f.pose, -f.evidence / self.T):
                    continue
                new.append(Candidate(fix=f, R=m.covariance(f), log_prior=lp,
                                     nll=-f.evidence / self.T))
            bank.finish_global(new, True)
            fixes_seen += fixes
        if not fixes_seen:
            n_feat = max((len(q) for q in cache.values()), default=0)
            raise FrameFailed("too-few-features" if n_feat < MIN_PAIRS else "no-match")
        null_ev = m.null_evidence(max(fixes_seen, key=lambda f: f.evidence), self.rng)
        for c in tracked:
            c.beats_null = c.beats_null and c.fix.evidence > null_ev
        if not any(c.fix.evidence > null_ev for c in tracked + new):
            raise FrameFailed("uninformative")
        # a global search that ran found what elsewhere explains: the null's share (module doc)
        other = bank.posterior(tracked, new, other_prior,
                               -null_ev / self.T if searched else None)
        top = bank.update(i, tracked + new, other, dt, odo, False)
        hyps = bank.hypotheses()
        pose, cov, _confidence, accepted = bank.conclude(hyps, top, bool(tracked), flags)
        self.last_accepted = accepted
        return hyps, top, pose, cov, accepted


# rad: a frame's query described at a heading this close to the one a start asks for is used
# for it, so that starts with nearly equal headings do not each describe the frame again
# (heading: track; upright descriptors change little over a degree, and the fit finds the
# rest: 1 deg is 3.5 cm at the 2 m the ground image reaches)
QUERY_HEADING_TOLERANCE = math.radians(1.0)


class TemplateScorer:
    """Method templates' candidates for the smoother (smooth.Scorer) after a causal run.

    - Global candidates of a frame: the vote's, the ``global_templates`` templates with most
      votes fitted (as when the causal run is lost), and the templates near the causal run's
      pose fitted, so that the smoother sees at least what the causal run fixed.
    - Candidates from given starts: as the tracks', the ``tracked_templates`` templates nearest
      the start within ``reach`` of it fitted, every fit a candidate. Where none lies within
      ``tracking.SAME_BASIN_M`` of the start, the start itself is one more candidate, the frame
      explained by chance (as a causal track whose templates did not match): nll the frame's
      null (-null / T, ``TemplateMatcher.null_evidence`` of its best fix), covariance the
      identity (it pulls the continuous pass no more than a causal track's miss pulls the
      fusion). A frame with no fix near the place its neighbours say then passes as
      uninformative instead of forcing the path through a wrong fit or a jump.

    A fit's nll is its evidence at the method's temperature (-L / T), its covariance
    ``TemplateMatcher.covariance``, its error the rms inlier pair distance. The query features
    are the causal run's (``queries``: per frame, by heading), described again only at a
    heading the causal run did not use; fits are computed once per frame, template and
    heading. The frames the causal run could not fix, and those where no template fits, have
    no candidates (``failed``). The floor's texture is not symmetric: a pose's mirror image is
    a candidate only where a template near it fits (``mirrored`` False)."""

    mirrored = False

    def __init__(self, loc: TemplateLocaliser, image_paths, yaw: np.ndarray, causal: PoseTrack,
                 queries: dict):
        self.loc = loc
        self.m = loc.m
        self.conf = loc.conf
        self.paths = list(image_paths)
        self.frames = len(self.paths)
        self.yaw = np.asarray(yaw, float)
        self.use_imu = self.conf["heading"] == "imu"
        self.causal_pose = np.column_stack([causal.x, causal.y, causal.theta]).astype(float)
        self.causal_flags = list(causal.flags)
        self.causal_failed = list(causal.failed)
        self.queries = queries
        self._image = (None, None)  # (frame, image): the last frame read again
        self._fits: dict = {}
        self._global: dict = {}
        self._null: dict = {}
        self.T = TEMPERATURE

    def _heading(self, i: int, start=None) -> float | None:
        """The heading frame i's query is described at: the IMU's, else the start's (None
        without a start)."""
        if self.use_imu and math.isfinite(self.yaw[i]):
            return float(self.yaw[i])
        return None if start is None else float(start[2])

    def _query(self, i: int, heading: float) -> tuple[gf.GroundFeatures, float]:
        """Frame i's query features and the heading they are described at: a description of
        the frame within ``QUERY_HEADING_TOLERANCE`` of ``heading`` if there is one (the
        causal run's or an earlier start's), else described at ``heading`` (the image read
        again)."""
        cache = self.queries.setdefault(i, {})
        if not self.loc.field_axes:
            key = None
        else:
            near = [k for k in cache if k is not None and abs(math.remainder(
                k - heading, 2 * math.pi)) <= QUERY_HEADING_TOLERANCE]
            key = (min(near, key=lambda k: abs(math.remainder(k - heading, 2 * math.pi)))
                   if near else round(float(heading), 6))
        if key not in cache:
            if self._image[0] != i:
                self._image = (i, read_image(self.paths[i]))
            self.loc._query(self._image[1], heading, cache)
        return cache[key], (heading if key is None else float(key))

    def _fit(self, i: int, k: int, heading: float) -> TemplateFix | None:
        query, h = self._query(i, heading)
        key = (i, k, h if self.loc.field_axes else None)
        if key not in self._fits:
            self._fits[key] = (self.m.fit(query, k, h)
                               if len(query) >= MIN_PAIRS else None)
        return self._fits[key]

    def _row(self, fix: TemplateFix):
        return fix.pose, -fix.evidence / self.T, self.m.covariance(fix), fix.rms

    def failed(self, i: int) -> str | None:
        if self.causal_failed[i]:
            return self.causal_flags[i].split(",")[-1] or "no-fix"
        return None if len(self.global_candidates(i)) else "no-match"

    def global_candidates(self, i: int) -> FrameCandidates:
        if i in self._global:
            return self._global[i]
        h = self._heading(i)
        if h is None and np.all(np.isfinite(self.causal_pose[i])):
            h = float(self.causal_pose[i, 2])  # the causal run's heading (no IMU)
        if h is not None:
            headings = [h]
        elif self.loc.field_axes:  # no heading known: try them (as the causal run when lost)
            n = LOST_HEADINGS
            headings = [2 * math.pi * j / n - math.pi for j in range(n)]
        else:  # rotation-invariant features: the fit finds the heading
            headings = [0.0]
        fixes = []
        for h in headings:
            query, _h = self._query(i, h)
            if len(query) < MIN_PAIRS:
                continue
            fixes += [self._fit(i, k, h) for k in self.m.vote(query, int(
                GLOBAL_TEMPLATES))]
        fixes = [f for f in fixes if f is not None]
        if np.all(np.isfinite(self.causal_pose[i])):
            fixes += self._near_fits(i, self.causal_pose[i])
        self._global[i] = FrameCandidates.from_rows([self._row(f) for f in fixes])
        if fixes:  # what chance explains, from the best fix's pairs (seeded by the frame)
            best = max(fixes, key=lambda f: f.evidence)
            self._null[i] = self.m.null_evidence(best, np.random.default_rng(i))
        return self._global[i]

    def _near_fits(self, i: int, start) -> list[TemplateFix]:
        """The fits of the ``tracked_templates`` templates nearest ``start``, within reach."""
        poses = self.m.db.poses
        h = self._heading(i, start)
        d = np.hypot(poses[:, 0] - start[0], poses[:, 1] - start[1])
        near = [int(k) for k in np.argsort(d, kind="stable")[:TRACKED_TEMPLATES]
                if d[k] <= REACH_M]
        return [f for f in (self._fit(i, k, h) for k in near) if f is not None]

    def local_candidates(self, i: int, starts: np.ndarray) -> FrameCandidates:
        rows, start = [], []
        null = self._null.get(i)
        for k, p in enumerate(np.asarray(starts, float).reshape(-1, 3)):
            fits = self._near_fits(i, p)
            rows += [self._row(f) for f in fits]
            if null is not None and not any(
                    math.hypot(f.pose[0] - p[0], f.pose[1] - p[1]) < tracking.SAME_BASIN_M
                    for f in fits):  # no fit near the start: it is kept, the frame explained
                rows.append((p, -null / self.T, np.eye(3), math.nan))  # by chance
            start += [k] * (len(rows) - len(start))
        return FrameCandidates.from_rows(rows, start=start)


def run(conf: dict, dataset, templates, map_file=None, progress=False) -> PoseTrack:
    """Localise every image of ``dataset`` against ``templates`` (a TemplateDatabase), with the
    dataset's odometry; ``map_file`` (optional) gives the field, else the database's record."""
    from tqdm import tqdm

    from ..common.field import load_field
    from .motion_model import accumulate_odometry

    check_conf(conf)
    db = templates
    if not len(db) or not len(db.points):
        raise FieldlocError(f"{db.path}: the template database holds no features")
    if map_file is not None:
        field = map_file.field
    elif db.field.get("name"):
        field = load_field(db.field["name"])
    else:
        raise FieldlocError(f"{db.path}: the templates do not name their field; give --map")
    gf.check_conf(db.ground_conf)  # the database's ground-image conf, checked
    camera = dataset.camera()
    if not camera_can(camera.kind, "ground_image"):
        raise FieldlocError(f"{dataset.root}: a '{camera.kind}' camera; method templates needs"
                            " omni frames")
    mask_path = dataset.root / "mask.png"
    mask = read_mask(mask_path, camera.image_size) if mask_path.is_file() else None
    t_index = time.perf_counter()
    matcher = TemplateMatcher(db, conf)
    index_s = time.perf_counter() - t_index
    loc = TemplateLocaliser(conf, matcher, field, camera, mask)
    names = list(dataset.names)
    stamps = np.asarray(dataset.stamps, float)
    odometry = dataset.optional("odometry")
    increments, has_odo = accumulate_odometry(odometry, stamps)
    loc.bank.has_odometry = bool(np.any(has_odo))
    imu = dataset.optional("imu")
    if conf["heading"] == "imu" and imu is None:
        raise FieldlocError(f"heading imu needs imu.csv in {dataset.root}; use -c heading=track")
    if imu is not None:
        yaw, collision = heading_mod.imu_per_frame(imu, stamps, float(conf["stamp_tolerance"]))
    else:
        yaw, collision = np.full(len(stamps), np.nan), np.zeros(len(stamps), bool)
    queries: dict = {}  # per frame its query features by heading, kept for the smoother
    track = PoseTrack()
    feature_s, match_s = [], []
    prev = None
    for i in tqdm(range(len(names)), desc="localize templates", unit="frame",
                  disable=not progress):
        name, stamp = names[i], float(stamps[i])
        dt = 0.0 if prev is None else max(stamp - prev, 0.0)
        prev = stamp
        odo = increments[i] if has_odo[i] else None
        flags: list[str] = []
        try:
            image = read_image(dataset.images[i])
        except DatasetError:
            loc.failed(dt, odo)
            track.add(name, stamp, None, mode="failed", flags="unreadable-image")
            continue
        t0 = time.perf_counter()
        f0 = loc.feature_s
        try:
            hyps, top, pose, cov, accepted = loc.frame(
                i, image, dt, odo, flags, float(yaw[i]),
                cache=queries.setdefault(i, {}) if conf["smooth"] else None)
        except DatasetError as e:  # an image not of the calibration's size, as extract's
            log.warning("frame %s skipped: %s", name, e)
            loc.failed(dt, odo)
            track.add(name, stamp, None, mode="failed", flags="unreadable-image")
            continue
        except FrameFailed as e:
            loc.failed(dt, odo)
            track.add(name, stamp, None, error=math.nan, confidence=0.0, mode="failed",
                      runtime=time.perf_counter() - t0, flags=",".join(flags + [str(e)]))
            continue
        finally:
            total = time.perf_counter() - t0
            feature_s.append(loc.feature_s - f0)
            match_s.append(total - feature_s[-1])
        track.add(name, stamp, pose, error=top.fix.rms, confidence=float(hyps[0, 3]),
                  mode=top.fix.mode, runtime=total, covariance=cov,
                  flags=",".join(flags), hypotheses=hyps, accepted=accepted)
    track.meta.update(
        pose_solver=conf["pose_solver"], templates=len(db), template_features=len(db.points),
        index_build_ms=1e3 * index_s,
        descent_rounds_per_fit=(matcher.rounds / matcher.fits if matcher.fits else 0.0),
        ground_features_ms=1e3 * float(np.median(feature_s)) if feature_s else math.nan,
        matching_ms=1e3 * float(np.median(match_s)) if match_s else math.nan)
    if not conf["smooth"]:
        return track
    scorer = TemplateScorer(loc, dataset.images, yaw, track, queries)
    x0, x1, y0, y1 = field.world_bounds()
    return bank_smoothing.smoothed(scorer, track, conf, increments=increments,
                                   has_odometry=has_odo, stamps=stamps, collision=collision,
                                   area=(x1 - x0) * (y1 - y0))
