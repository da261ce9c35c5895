"""Poses that explain one observation of a frame (sensor resetting, Lenser and Veloso 2000):
the particle filter's new particles placed by the frame's observations (mcl.py). A crossing or
goal post is put at a random field landmark of a kind it may be (the observation model's type
confusions; a crossing's orientation fixes the heading up to an X's quarter turns, a post leaves
it free on a circle around the post); a line on a random straight field line, either side of
it, its middle where the observed segment fits along the field segment. Ranges, bearings and
angles get the observation model's noise.
"""

from __future__ import annotations

import math

import numpy as np

from ..common.geometry import wrap_angle
from ..common.observations import Observations


class PosePlacer:
    """The field's landmarks and straight lines as the placement reads them (computed on first
    use), and the world's bounds (x0, x1, y0, y1) poses must lie in."""

    def __init__(self, model, bounds: tuple):
        self.model = model
        self.field = model.field
        self._bounds = bounds
        self._landmarks = None
        self._segments = None

    def poses(self, n: int, usable: Observations, rng) -> np.ndarray:
        """Up to ``n`` poses at which one of the frame's usable observations is explained by a
        random field feature of its kind: half by a crossing or goal post, half by a line (all
        by one kind when the frame has no other); poses off the world are dropped."""
        points = len(usable.crossings) + len(usable.posts)
        lines = len(usable.lines) if len(self.field.segments) else 0
        if n <= 0 or not (points or lines):
            return np.zeros((0, 3))
        n_lines = (n - n // 2 if points else n) if lines else 0
        p = np.concatenate([self._from_points(n - n_lines, usable, rng),
                            self._from_lines(n_lines, usable, rng)])
        x0, x1, y0, y1 = self._bounds
        ok = (p[:, 0] >= x0) & (p[:, 0] <= x1) & (p[:, 1] >= y0) & (p[:, 1] <= y1)
        return p[ok]

    def _from_points(self, n: int, obs: Observations, rng) -> np.ndarray:
        """Poses at which one observed crossing or goal post is explained by a random field
        landmark of a kind it may be (the model's type confusions)."""
        pos, orient, start, count = self._landmark_table()
        cr, po = obs.crossings, obs.posts
        kind = np.concatenate([cr[:, 0].astype(np.int64), np.full(len(po), 3)])
        d = np.concatenate([cr[:, 1], po[:, 0]])
        b = np.concatenate([cr[:, 2], po[:, 1]])
        o = np.concatenate([cr[:, 3], np.zeros(len(po))])
        ok = (kind >= 0) & (kind <= 3)
        ok[ok] &= count[kind[ok]] > 0
        if not ok.any() or n <= 0:
            return np.zeros((0, 3))
        kind, d, b, o = kind[ok], d[ok], b[ok], o[ok]
        u = rng.random((4, n))  # observation, landmark, quarter turn (X), post circle
        noise = rng.standard_normal((3, n))
        r = (u[0] * len(kind)).astype(np.int64)
        r_kind = kind[r]
        k = start[r_kind] + (u[1] * count[r_kind]).astype(np.int64)
        mc = self.model.tuning
        elevation = np.where(r_kind == 3, mc.post_elevation_sigma, mc.elevation_sigma)
        dd = d[r] + noise[0] * self.model.range_sigma(d[r], mc.sigma_range, elevation)
        bb = b[r] + noise[1] * mc.sigma_bearing
        post = r_kind == 3
        # a crossing fixes the heading by its orientation (X: up to quarter turns); a post
        # leaves it free, on a circle around the post
        turns = np.floor(u[2] * 4.0) * (r_kind == 2) * (math.pi / 2)
        th = orient[k] + turns - o[r] + noise[2] * 0.1
        psi = np.where(post, (2.0 * u[3] - 1.0) * math.pi, th + bb)
        th = np.where(post, psi - bb, th)
        return np.stack([pos[k, 0] - dd * np.cos(psi), pos[k, 1] - dd * np.sin(psi),
                         wrap_angle(th)], axis=1)

    def _from_lines(self, n: int, obs: Observations, rng) -> np.ndarray:
        """Poses at which one observed line lies on a random straight field line: the heading
        turns the observed perpendicular onto the field line's normal (either side of it), the
        distance puts the line at its offset, and the observed segment's middle lies at a
        random place along the field segment where the whole segment fits."""
        if n <= 0 or not len(obs.lines):
            return np.zeros((0, 3))
        nrm, off, tng, lo, hi = self._segment_table()
        ln = obs.lines
        r_obs = np.abs(ln[:, 0])
        a_obs = ln[:, 1] + np.where(ln[:, 0] < 0, math.pi, 0.0)
        if obs.line_ends is not None:
            mid = 0.5 * (obs.line_ends[:, 0:2] + obs.line_ends[:, 2:4])
        else:
            mid = r_obs[:, None] * np.stack([np.cos(a_obs), np.sin(a_obs)], axis=1)
        half = 0.5 * ln[:, 2]
        u = rng.random((3, n))
        noise = rng.standard_normal((2, n))
        i = (u[0] * len(ln)).astype(np.int64)
        j = (u[1] * len(off)).astype(np.int64)
        side = np.where(rng.random(n) < 0.5, 1.0, -1.0)
        mc = self.model.tuning
        th = (np.arctan2(side * nrm[j, 1], side * nrm[j, 0]) - a_obs[i]
              + noise[0] * mc.sigma_line_angle)
        c, s_ = np.cos(th), np.sin(th)
        mx, my = c * mid[i, 0] - s_ * mid[i, 1], s_ * mid[i, 0] + c * mid[i, 1]
        room = np.maximum(hi[j] - lo[j] - 2.0 * half[i], 0.0)
        t = lo[j] + 0.5 * (hi[j] - lo[j] - room) + u[2] * room  # where the middle lies
        normal = off[j] - side * (r_obs[i] + noise[1] * self.model.range_sigma(
            r_obs[i], mc.sigma_line))
        along = t - (mx * tng[j, 0] + my * tng[j, 1])
        return np.stack([normal * nrm[j, 0] + along * tng[j, 0],
                         normal * nrm[j, 1] + along * tng[j, 1], wrap_angle(th)], axis=1)

    def _landmark_table(self):
        """Field landmarks by observation kind (0 L, 1 T, 2 X, 3 goal post): positions (M, 2),
        orientations (M,), and where each kind starts."""
        if self._landmarks is None:
            fm = self.field
            types = np.asarray(fm.crossing_types)
            pos, orient, start, count = [], [], [], []
            n = 0
            for kind in ("L", "T", "X"):
                sel = np.flatnonzero(types == kind)
                pos.append(np.asarray(fm.crossings, float).reshape(-1, 2)[sel])
                orient.append(np.asarray(fm.crossing_orientation, float)[sel])
                start.append(n)
                count.append(len(sel))
                n += len(sel)
            posts = np.asarray(fm.goal_posts, float).reshape(-1, 2)
            pos.append(posts)
            orient.append(np.zeros(len(posts)))
            start.append(n)
            count.append(len(posts))
            self._landmarks = (np.concatenate(pos), np.concatenate(orient), np.array(start),
                               np.array(count))
        return self._landmarks

    def _segment_table(self):
        """The field's straight lines: unit normal (S, 2), offset (S,) with n . p = offset,
        unit direction (S, 2), first and last position along it (S,)."""
        if self._segments is None:
            seg = np.asarray(self.field.segments, float).reshape(-1, 2, 2)
            d = seg[:, 1] - seg[:, 0]
            t = d / np.maximum(np.linalg.norm(d, axis=1), 1e-12)[:, None]
            nrm = np.stack([-t[:, 1], t[:, 0]], axis=1)
            along = np.stack([np.einsum("ij,ij->i", t, seg[:, 0]),
                              np.einsum("ij,ij->i", t, seg[:, 1])], axis=1)
            self._segments = (nrm, np.einsum("ij,ij->i", nrm, seg[:, 0]), t,
                              along.min(axis=1), along.max(axis=1))
        return self._segments
