"""The particle filter's odds that the robot is elsewhere (mcl.py): the kidnap share and the
rival hypotheses kept over frames.

Kidnap share. While tracking, sensor resetting (Lenser and Veloso 2000) places the posterior
share of "the robot is not where the belief says": its prior, the larger of
``KIDNAP_PROBABILITY`` and augmented MCL's share of random particles (Thrun, Burgard and Fox
2005; mcl_resampling.LikelihoodAverages), spread over the world's hypothesis regions (a
cluster's radius and heading window), against the belief's predictive likelihood sum(w_i L_i)
of the frame; the place it would be is the best of the frame's placed poses, or the best
rival. A tracked robot places (almost) nothing, a kidnapped one most.

Rivals (``RIVALS``, a uniform start's: one frame rarely beats the kidnap prior, and a start
settled metres off along a touch line would stay there): the placed pool's best poses, moved
by the odometry without noise, each summing its log-likelihood ratio against the belief's
predictive likelihood (its evidence) and against the belief's heaviest particle (its odds),
forgetting over ``RIVAL_MEMORY`` frames: a sequential test of "elsewhere". The best stands for
"elsewhere" once its evidence beats the frame's best placed pose. A new rival's sums start
from the frames before it (``Rivals.retro_odds``, up to ``RIVAL_LOOKBACK`` memories back), not
from its first ratio. Rivals in the belief's best cluster or its mirror, or ``RIVAL_FLOOR``
below the belief, are dropped. Rivals outside the belief's clusters are hypotheses too, at the
odds their sums give (``Rivals.with_rivals``): a particle set alone cannot hold two places that
explain a still robot's frames alike, and would overstate the one it kept.
"""

from __future__ import annotations

import collections
import math
from types import MappingProxyType

import numpy as np

from ..common.geometry import compose, inverse
from . import motion_model

KIDNAP_PROBABILITY = 1e-3  # per frame, that the robot is not where the belief says: while
# tracking, the landmarks place the posterior share of "elsewhere" (module doc); the
# smoother has its own (mcl_smoothing.SMOOTH_KIDNAP_PROBABILITY)
# while tracking, the pool's best poses kept over frames as rivals of the belief, each
# accumulating its evidence against it (a sequential test of "elsewhere"), by the initial
# belief: a uniform start's first frames settle on one of several places that explain
# them alike, and the rivals find the right one later; from the placement (or a given
# pose) the prior has chosen, and rivals there take rendered NAO walks off the truth
# where people's legs and other robots pass for posts
RIVALS = MappingProxyType({"placement": 0, "uniform": 8, "pose": 0})
RIVAL_FLOOR = 10.0  # nats: a rival whose evidence falls this far below the belief's is
# dropped
RIVAL_MEMORY = 20.0  # frames: a rival's evidence forgets with this time constant, so that
# one as good as the belief (a random walk) seldom drifts past the kidnap prior
# a new rival's odds are summed over the frames of this many of the rivals' memory
# (``RIVAL_MEMORY``) back: a frame that far back weighs exp(-3) ~ 5 % of this one
RIVAL_LOOKBACK = 3.0


def regions(bounds: tuple, radius: float, heading: float) -> float:
    """How many hypothesis regions (a cluster's ``radius``, m, and ``heading`` window, rad)
    the world ``bounds`` (x0, x1, y0, y1) holds: a uniform belief's density in the units of
    mcl_resampling.log_support is about 1 / this."""
    x0, x1, y0, y1 = bounds
    return max((x1 - x0) * (y1 - y0) / (math.pi * radius ** 2)
               * math.pi / max(heading, 1e-6), 1.0)


class Rivals:
    """The rival poses of a belief kept over frames (``poses`` (R, 3)), each with its
    ``evidence`` (its log-likelihood ratio against the belief's predictive likelihood, summed
    since it was found) and its ``odds`` (the same against the belief's heaviest particle,
    the frame that found it included); the frames a new rival's sums start from (``recent``:
    per frame with observations while tracking, its prepared observations, the belief's
    heaviest particle's log-likelihood, the belief's predictive log-likelihood and the
    odometry since the frame before) and the odometry since the last of them
    (``since_recent``). ``model``: the observation model; ``clusters``: the belief's
    clustering (mcl_clusters.Clustering); ``bounds``: the world."""

    def __init__(self, model, clusters, bounds: tuple):
        self.model = model
        self.clusters = clusters
        self.regions = regions(bounds, clusters.radius, clusters.heading)
        self.limit = 0  # rivals kept, by the initial belief (RIVALS)
        self.clear()

    def start(self, mode: str):
        """No rivals, and as many kept as the initial belief ``mode`` asks (``RIVALS``)."""
        self.clear()
        self.limit = int(RIVALS.get(mode, 0))

    def clear(self):
        self.poses = np.zeros((0, 3))
        self.evidence = np.zeros(0)
        self.odds = np.zeros(0)
        memory = max(float(RIVAL_MEMORY), 1.0)
        self.recent = collections.deque(maxlen=int(math.ceil(RIVAL_LOOKBACK * memory)))
        self.since_recent = np.zeros(3)

    def move(self, odometry):
        """The rivals moved by the odometry, without noise (each is one pose: a random walk
        would carry it off the place whose evidence it sums)."""
        if len(self.poses):
            self.poses = motion_model.moved(self.poses, *(float(v) for v in odometry))
        if self.limit > 0:
            self.since_recent = compose(self.since_recent, np.asarray(odometry, float))

    def remember(self, prep, ll_belief: float, log_tracked: float):
        """A tracked frame with observations ``prep``, for the sums of rivals found later."""
        if self.limit > 0:
            self.recent.append((prep, ll_belief, log_tracked, self.since_recent))
            self.since_recent = np.zeros(3)

    def kidnap_share(self, inject_share: float, log_tracked: float,
                     ll_pool: np.ndarray) -> tuple[float, np.ndarray | None]:
        """The posterior share of "the robot is elsewhere": its prior (the larger of
        ``KIDNAP_PROBABILITY`` and augmented MCL's share ``inject_share``) spread over the
        world's hypothesis regions, against the predicted belief's likelihood sum(w_i L_i)
        (``log_tracked``, its log). The place it would be is the best of this frame's placed
        poses (log-likelihoods ``ll_pool``) or the best rival (its evidence), as far as either
        explains more. Returns the share and the rival to place around where one does (else
        None)."""
        elsewhere = max(float(KIDNAP_PROBABILITY), inject_share, 1e-300)
        log_prior = math.log(elsewhere / self.regions)
        ratio = float(ll_pool.max()) - log_tracked
        placed = None
        if len(self.evidence):
            best = int(np.argmax(self.evidence))
            if self.evidence[best] > ratio:
                ratio = float(self.evidence[best])
                placed = self.poses[best].copy()
        return 1.0 / (1.0 + math.exp(min(-(log_prior + ratio), 700.0))), placed

    def update(self, pool, ll_pool, ll_rivals, log_tracked: float,
               ll_belief: float | None = None, last_pose=None):
        """The sequential test of "elsewhere" while tracking: each rival's evidence grows by
        its log-likelihood ratio (``ll_rivals``) against the belief's predictive likelihood in
        this frame (``log_tracked``), so a place that explains every frame a little better
        than the belief wins over a few frames (one frame's ratio must beat the kidnap prior on
        its own). The pool's best poses (``pool``, log-likelihoods ``ll_pool``) join as new
        rivals, or move a rival they lie within a cluster of to the better of the two poses;
        rivals inside the cluster of the last estimate's pose ``last_pose`` (or its mirror),
        or below the belief by ``RIVAL_FLOOR``, are dropped; the ``RIVALS`` strongest are
        kept. ``ll_belief``: the belief's heaviest particle's log-likelihood (the odds'
        reference; ``log_tracked`` without it)."""
        k_max = self.limit
        if k_max <= 0:
            return
        poses = self.poses.copy()
        keep_share = 1.0 - 1.0 / max(float(RIVAL_MEMORY), 1.0)
        evidence = self.evidence * keep_share + (ll_rivals - log_tracked)
        # the odds compare poses with poses: each rival with the belief's heaviest particle
        # (against the belief's predictive likelihood, a spread belief would lose to any
        # rival as good as its best pose)
        ll_b = log_tracked if ll_belief is None else ll_belief
        odds = self.odds * keep_share + (ll_rivals - ll_b)
        if len(pool):
            top = (np.argpartition(-ll_pool, k_max - 1)[:k_max] if len(pool) > k_max
                   else np.arange(len(pool)))
            q, ll_q = pool[top], ll_pool[top]
            new = np.ones(len(q), bool)
            if len(poses):  # a candidate within a cluster of a rival moves it
                near = (((q[:, None, 0] - poses[None, :, 0]) ** 2
                         + (q[:, None, 1] - poses[None, :, 1]) ** 2
                         <= float(self.clusters.radius) ** 2)
                        & (np.cos(q[:, None, 2] - poses[None, :, 2])
                           >= math.cos(float(self.clusters.heading))))
                new = ~near.any(axis=1)
                held = np.array(ll_rivals, float)
                for j in np.flatnonzero(~new):
                    i = int(np.argmax(near[j]))
                    if ll_q[j] > held[i]:
                        poses[i], held[i] = q[j], ll_q[j]
            # a new rival's sums start with the frames before this one (retro_odds); this
            # frame chose it (the best of the pool) and counts in the single frame's test,
            # so its evidence leaves this frame out
            e_q, o_q = self.retro_odds(q[new], keep_share)
            poses = np.concatenate([poses, q[new]])
            evidence = np.concatenate([evidence, e_q])
            odds = np.concatenate([odds, o_q + (ll_q[new] - ll_b)])
        keep = evidence > -float(RIVAL_FLOOR)
        if last_pose is not None and len(poses):
            x, y, th = poses[:, 0], poses[:, 1], poses[:, 2]
            cos_t, sin_t = np.cos(th), np.sin(th)
            for centre in (last_pose, self.model.field.mirror_pose(last_pose)):
                keep &= ~self.clusters.members(centre, x, y, cos_t, sin_t)
        poses, evidence, odds = poses[keep], evidence[keep], odds[keep]
        order = np.argsort(-evidence, kind="stable")[:k_max]
        self.poses, self.evidence = poses[order], evidence[order]
        self.odds = odds[order]

    def retro_odds(self, q: np.ndarray, keep_share: float) -> tuple[np.ndarray, np.ndarray]:
        """The sums new rivals ``q`` (R, 3) would hold had each been followed through the
        frames the belief has weighed while tracking (``recent``), before this one: each
        rival moved back there by the odometry, its log-likelihood there against the
        belief's predictive likelihood then (the evidence) and against the belief's heaviest
        particle then (the odds), forgetting as the rivals' sums do. A place found now is
        scored on what the frames before said of it, not on this frame alone: one frame that
        happens to fit it is not the many frames a rival must win, and a place that fitted
        every frame so far has won them already."""
        evidence, odds = np.zeros(len(q)), np.zeros(len(q))
        if not len(q) or not self.recent:
            return evidence, odds
        p = np.asarray(q, float)
        inc, weight = self.since_recent, 1.0
        for prep, ll_ref, log_tracked, inc_before in reversed(self.recent):
            p = motion_model.moved(p, *inverse(inc))
            weight *= keep_share
            ll = self.model.log_likelihood(p[:, 0], p[:, 1], p[:, 2], prep)
            evidence += weight * (ll - float(log_tracked))
            odds += weight * (ll - float(ll_ref))
            inc = inc_before
        return evidence, odds

    def with_rivals(self, rows: list, *, symmetric: bool, paired: bool) -> tuple[list, float]:
        """The belief's hypotheses ``rows`` (x, y, theta, share; heaviest first) beside the
        rivals, and the share of the belief in the whole. Each rival not inside a listed
        cluster (or its mirror image on a ``symmetric`` field) holds, against the belief, the
        odds its summed log-likelihood ratio against the belief's heaviest particle gives (a
        place and the belief have the same prior after a uniform start): the belief's rows are
        scaled by 1 / (1 + sum of the odds), a rival's row holds its odds over the same sum
        (half of it, and half its mirror image, while particles stand for mirrored pairs,
        ``paired``). The belief's best cluster stays first (it is the frame's pose), and its
        mirror image second on a point-symmetric field, as the belief lists them. A particle
        set cannot hold two places that explain a still robot's frames alike: which keeps the
        mass is the luck of the first frames (the poses placed by the observations land at
        one of them first), while the rivals find the other."""
        if not len(self.poses) or not rows:
            return rows, 1.0
        field, members = self.model.field, self.clusters.members

        def near(a, b) -> bool:  # b a member of a's cluster (the clusters' own rule)
            return bool(members(a, b[0], b[1], math.cos(b[2]), math.sin(b[2])))

        held = [np.asarray(r[:3], float) for r in rows]
        found = []
        for i in np.argsort(-self.odds, kind="stable"):
            pose = self.poses[i]
            images = (pose, field.mirror_pose(pose)) if symmetric else (pose,)
            if any(near(h, q) for h in held for q in images):
                continue
            found.append((pose, math.exp(min(float(self.odds[i]), 50.0))))
            held.append(pose)
        if not found:
            return rows, 1.0
        total = 1.0 + sum(o for _, o in found)
        out = [(*r[:3], r[3] / total) for r in rows]
        for pose, o in found:
            if paired:
                half = 0.5 * o / total
                out += [(*pose, half), (*field.mirror_pose(pose), half)]
            else:
                out.append((*pose, o / total))
        pinned = 2 if symmetric and len(rows) > 1 else 1  # the pose and its mirror
        return out[:pinned] + sorted(out[pinned:], key=lambda r: -r[3]), 1.0 / total
