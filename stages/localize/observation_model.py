"""Observation model of the particle filter (seed 000, section 5): how likely one frame's lines,
crossings and goal posts are at many poses at once.

Observations are egocentric, in the robot frame on the floor (x forward, y left), as
``extract`` writes them for a perspective camera: lines, optional line ends, crossings and goal
posts (stages.common.observations lists the columns).

Point model (eq. 3), for crossings and goal posts, with expected egocentric distance and
bearing (d_e, phi_e) of the associated landmark::

    cost = (d_e - d_o)^2 / (2 (sigma_d + lambda_d d_o)^2) + (phi_e - phi_o)^2 / (2 sigma_phi^2)

The range uncertainty grows with the distance (the camera's unknown pitch and roll). The
squared bearing error is computed as 2 (1 - cos(phi_e - phi_o)) (equal near zero, no atan2).
L, T and X crossings also carry an orientation term (1 - cos of the orientation error, X
modulo 90 deg) with ``sigma_crossing_orientation``; 0 drops it, as in the seed.

Line model (eqs. 4-5), with the dropped perpendiculars l_e (expected) and l_o (observed) as
vectors in the robot frame, d_o the distance to the closest observed point of the line::

    cost = d(l_e, l_o)^2 / (2 (sigma_l + lambda_l d_o)^2) + (psi_e - psi_o)^2 / (2 sigma_psi^2)
    d(l_e, l_o) = |l_e - l_o|  if <l_e, l_o> > -tol^2  else infinity   (oriented distance)

psi is the line's direction (modulo pi; sin^2 of the difference stands for its square). A line
behind the robot has its perpendicular pointing the other way and is rejected by eq. 5. The
tolerance ``oriented_tolerance`` (0 is the seed's rule) keeps a line the robot stands on (both
perpendiculars ~0) from being rejected by noise. Lines shorter than ``min_line_length`` or
farther than ``max_line_distance`` are ignored (the seed ignores short, far lines). Two
additions to the seed, both in the same cost units: the observed segment must lie within the
model segment's extent (the part sticking out beyond its ends, less ``extent_margin``, is a
distance error with sigma ``sigma_extent`` + lambda_l d_o; without line_ends it is skipped),
and the centre circle and arcs are candidate lines too (the tangent at the arc point nearest
the observed segment's middle; a straight observation of half length h departs h^2 / 2r from
the arc, charged like the extent).

Association: L crossings through the map's orientation tables (stages.common.crossing_tables)
at the field cell where the particle places the observation and the set of the observation's
global orientation; T crossings through the T table; X crossings, goal posts and lines per
particle, by the smallest cost ("arg min before exp"). For lines, each (line, particle) pair is
compared with the field lines of the direction it is most nearly parallel to (the others cost
at least sin^2(45 deg) / (2 sigma_psi^2) ~ 39, exp(-39) ~ 1e-17).

Combination (section 5.3): each observation's likelihood is
``a_uni + (1 - a_uni) exp(-cost)`` with ``a_uni = a_base + (1 - a_base) (1 - confidence)``
(``uniform_floor`` = a_base; ``post_uniform_floor`` for goal posts, most of whose detections
are other robots' or people's legs), the uniform density taken relative to the peak of the
normal model; the frame's likelihood is the product over observations (a sum of logarithms).

Speed: ``log_likelihood`` runs the numba kernel of stages.localize.mcl_kernels (one pass per
observation over the poses, the alternatives of a crossing's type evaluated in registers, and
only where the observed type costs more than the confusion's penalty). The numpy code below
(``reference_log_likelihood``) is its reference: every array keeps the poses on its last
axis, the per-segment line work runs in float32 with the segments on the first axis. Both cap
costs at 60 (exp < 1e-26).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stages.common.crossing_tables import crossing_association_tables
from stages.common.field import FieldModel
from stages.common.map_file import Grid
from stages.common.observations import Observations

from . import mcl_kernels as K

PARTS = ("lines", "crossings", "posts")
DEFAULT_CAMERA_HEIGHT = 0.5  # m, when neither the conf nor a calibration gives one

DEFAULTS = {
    "camera_height": None,  # m, the camera above the floor; None: the dataset's calib.yaml
    # (mcl.run), 0.5 without one
    "sigma_range": 0.03,  # m, range sigma of eq. 3 at distance 0
    "elevation_sigma": 0.01,  # rad, sigma of a floor point's angle below the horizon (the
    # camera's pitch and the pixel's error): the range sigma grows as (h^2 + d^2) / h
    "post_elevation_sigma": 0.03,  # rad, the same for a goal post's foot (less sharp)
    "sigma_bearing": 0.06,  # rad, sigma_phi of eq. 3
    "sigma_crossing_orientation": 0.3,  # rad, L/T/X orientation term; 0 = off (the seed)
    "crossing_type_confusion": 0.2,  # probability that a crossing shows fewer arms than it
    # has (an L of a T or X, a T of an X: an arm unseen); 0 = types as observed (the seed)
    "sigma_line": 0.03,  # m, sigma_l of eq. 4 at distance 0 (grows as the range sigma)
    "sigma_line_angle": 0.08,  # rad, sigma_psi of eq. 4
    "oriented_tolerance": 0.15,  # m, eq. 5 accepts <l_e, l_o> > -tol^2
    "line_extent": True,  # charge the part of a segment beyond the model segment's ends
    "sigma_extent": 0.15,  # m, at distance 0 (grows as the range sigma of the farther end)
    "extent_margin": 0.1,  # m of overhang that is free
    "arc_lines": True,  # the centre circle (and arcs) as candidate lines, by their tangent
    "min_line_length": 0.3,  # m, shorter lines are ignored (seed: short and far lines)
    "max_line_distance": 6.0,  # m, lines whose closest point is farther are ignored
    "uniform_floor": 0.1,  # a_base of section 5.3, in ]0, 1[
    "post_uniform_floor": 0.6,  # a_base for goal posts: most detected posts are no goal
    # post (robots' and people's legs; measured on rendered NAO walks: 61-88 % of them lie at
    # no post at the true pose, 19 % on the KidSize walk); None = uniform_floor
    "use_lines": True,
    "use_crossings": True,
    "use_posts": True,
}


def _log_mixture(cost, a_uni):
    """log(a_uni + (1 - a_uni) exp(-cost)), cost (K, N), a_uni (K, 1). Costs are capped where
    exp(-cost) no longer matters (and would underflow, which is slow)."""
    np.minimum(cost, _COST_CAP, out=cost)
    np.negative(cost, out=cost)
    np.exp(cost, out=cost)
    cost *= 1.0 - a_uni
    cost += a_uni
    return np.log(cost, out=cost)


_COST_CAP = 60.0  # exp(-60) ~ 1e-26, far below any uniform floor
_NO_LINES = np.zeros((0, 4))
_NO_CROSSINGS = np.zeros((0, 5))
_NO_POSTS = np.zeros((0, 3))
_NO_DISTANCES = np.zeros((0, 1))
_BIG = np.float32(1e6)  # cost of an excluded association
# rows of the line model's (quantity, pair) matrix: particle position, the observed
# perpendicular as a field-frame unit vector, its length, eq. 4's weight, its foot; with
# line ends also the observed segment's middle and the extent term's constants
_PX, _PY, _UX, _UY, _R, _WD, _FX, _FY, _MX, _MY, _HM, _RATIO = range(12)
_N_ROWS = 12


def _project(vx, vy, sel, direction) -> np.ndarray:
    """(vx, vy)[sel] . direction, without the multiplications an axis direction needs."""
    dx, dy = float(direction[0]), float(direction[1])
    if dy == 0.0:
        return vx[sel] * dx
    if dx == 0.0:
        return vy[sel] * dy
    return vx[sel] * dx + vy[sel] * dy


def line_closest_distance(obs: Observations) -> np.ndarray:
    """Distance from the robot to the closest observed point of each line."""
    r = np.abs(obs.lines[:, 0])
    if obs.line_ends is None:
        return r
    p0, p1 = obs.line_ends[:, 0:2], obs.line_ends[:, 2:4]
    d = p1 - p0
    dx, dy = d[:, 0], d[:, 1]
    den = np.maximum(dx * dx + dy * dy, 1e-12)
    s = np.minimum(np.maximum(-(p0[:, 0] * dx + p0[:, 1] * dy) / den, 0.0), 1.0)
    return np.hypot(p0[:, 0] + s * dx, p0[:, 1] + s * dy)


@dataclass
class ReferenceRows:
    """The numpy reference's per-observation constants (column vectors (K, 1) that broadcast
    against the particles on the last axis)."""

    obs: Observations
    lines: dict
    table_rows: dict  # L and T crossings, associated through the tables
    candidate_rows: dict  # X crossings and goal posts, associated per particle


@dataclass
class PreparedObservations:
    """The observations a model uses, with the per-observation constants of its equations
    (computed once per frame, reused for every pose): the kernel's rows
    (stages.localize.mcl_kernels: ``lines`` (L, 12), ``points`` (K, 12) and the sum ``part``
    (K,) each point adds to), and the numpy reference's on demand."""

    obs: Observations
    lines: np.ndarray
    points: np.ndarray
    part: np.ndarray
    reference: ReferenceRows | None = None

    def __len__(self) -> int:
        return len(self.obs)


class ObservationModel:
    """Likelihood of a frame's observations at N poses, vectorised over the poses.

    ``lut_l`` (4, ny, nx) and ``lut_t`` (ny, nx) are the crossing association tables on
    ``grid`` (stages.common.crossing_tables); ``from_field`` builds them when no map is at
    hand, ``from_map`` reads them from a map.
    """

    def __init__(self, field_model: FieldModel, grid: Grid, lut_l: np.ndarray,
                 lut_t: np.ndarray, conf: dict | None = None):
        self.field = field_model
        self.grid = grid
        self.conf = dict(DEFAULTS, **(conf or {}))
        unknown = set(self.conf) - set(DEFAULTS)
        if unknown:
            raise KeyError(f"unknown observation-model keys: {sorted(unknown)}")
        ny, nx = grid.shape
        if lut_l.shape != (4, ny, nx) or lut_t.shape != (ny, nx):
            raise ValueError("crossing tables do not match the grid")
        self._cells = ny * nx
        # one table: the four L orientation sets, then T
        self.lut = np.concatenate([np.asarray(lut_l).ravel(), np.asarray(lut_t).ravel()])
        self.lut = self.lut.astype(np.int64)

        fm = field_model
        self.cross_pos = np.asarray(fm.crossings, float).reshape(-1, 2)
        self.cross_orient = np.asarray(fm.crossing_orientation, float)
        self.cross_x = np.ascontiguousarray(self.cross_pos[:, 0])
        self.cross_y = np.ascontiguousarray(self.cross_pos[:, 1])
        self.cross_c, self.cross_s = np.cos(self.cross_orient), np.sin(self.cross_orient)
        self.x_idx = np.flatnonzero(np.asarray(fm.crossing_types) == "X")
        self.posts = np.asarray(fm.goal_posts, float).reshape(-1, 2)
        # lines: the straight segments, grouped by direction (parallel lines share a normal)
        seg = np.asarray(fm.segments, float).reshape(-1, 2, 2)
        d = seg[:, 1] - seg[:, 0]
        length = np.linalg.norm(d, axis=1)
        t = d / length[:, None]
        flip = (t[:, 1] < -1e-9) | ((np.abs(t[:, 1]) <= 1e-9) & (t[:, 0] < 0))
        t[flip] *= -1  # canonical direction, angle in [0, pi)
        n = np.stack([-t[:, 1], t[:, 0]], axis=1)
        offset = np.einsum("ij,ij->i", n, seg[:, 0])  # n . p = offset on the line
        along = np.stack([np.einsum("ij,ij->i", t, seg[:, 0]),
                          np.einsum("ij,ij->i", t, seg[:, 1])], axis=1)
        angle = np.round(np.arctan2(t[:, 1], t[:, 0]), 6)
        # (normal, direction, offsets, first and last position along the direction) per
        # direction, the segments on the first axis
        self.line_groups = []
        seg64 = []  # the same in float64, the kernel's
        for a in np.unique(angle):
            k = angle == a
            seg64.append(np.stack([offset[k], along[k].min(axis=1), along[k].max(axis=1)],
                                  axis=1))
            self.line_groups.append((
                n[k][0], t[k][0],
                offset[k].astype(np.float32)[:, None],
                along[k].min(axis=1).astype(np.float32)[:, None],
                along[k].max(axis=1).astype(np.float32)[:, None],
            ))
        self.group_normals = np.array([g[0] for g in self.line_groups]).reshape(-1, 2)
        self.arcs = np.asarray(fm.arcs, float).reshape(-1, 5)
        self._kernel_constants(seg64)

    def _kernel_constants(self, seg64):
        """The field and conf as the kernel's arrays (mcl_kernels)."""
        c = self.conf
        g = self.grid
        self._t_table = bool(self.lut[4 * self._cells:].max() >= 0)
        self._k_grid = np.array([g.origin[0], g.origin[1], 1.0 / g.resolution, g.shape[1],
                                 g.shape[0]], float)
        self._k_cross = np.ascontiguousarray(np.stack(
            [self.cross_x, self.cross_y, self.cross_c, self.cross_s], axis=1).reshape(-1, 4))
        so = float(c["sigma_crossing_orientation"])
        w_x = 1.0 / (16.0 * so * so) if so > 0 else 0.0
        self._k_w_o = 1.0 / (so * so) if so > 0 else 0.0
        x = self.x_idx
        four = 4.0 * self.cross_orient[x]
        n_x, n_p = len(x), len(self.posts)
        cand = np.zeros((2 * n_x + n_p, 6))
        for block, sign in ((slice(0, n_x), -1.0), (slice(n_x, 2 * n_x), 1.0)):
            cand[block] = np.stack([self.cross_x[x], self.cross_y[x], np.cos(four),
                                    np.sin(four), np.full(n_x, w_x), np.full(n_x, sign)],
                                   axis=1).reshape(-1, 6)
        cand[2 * n_x:, 0:2] = self.posts
        self._k_cand = cand
        # candidate ranges: the X crossings as an L's (sign -1: its bisector lies halfway
        # between two arms), as a T's or X's (sign 1), the goal posts
        self._cand_ranges = ((0, n_x), (n_x, 2 * n_x), (2 * n_x, 2 * n_x + n_p))
        groups = self.line_groups
        self._k_normals = np.array([gr[0] for gr in groups], float).reshape(-1, 2)
        self._k_tangents = np.array([gr[1] for gr in groups], float).reshape(-1, 2)
        self._k_seg = np.concatenate(seg64).reshape(-1, 3) if seg64 else np.zeros((0, 3))
        self._k_group_start = np.cumsum([0] + [len(gr[2]) for gr in groups]).astype(np.int64)
        self._k_arcs = (np.ascontiguousarray(self.arcs) if c["arc_lines"]
                        else np.zeros((0, 5)))

    def with_conf(self, conf: dict | None) -> ObservationModel:
        """The same field and tables with another conf."""
        ny, nx = self.grid.shape
        lut_l = self.lut[:4 * self._cells].reshape(4, ny, nx)
        return ObservationModel(self.field, self.grid, lut_l,
                                self.lut[4 * self._cells:].reshape(ny, nx), conf)

    @classmethod
    def from_field(cls, field_model: FieldModel, conf: dict | None = None,
                   resolution: float = 0.1) -> ObservationModel:
        """A model with crossing tables computed on the fly (no map file needed)."""
        grid = Grid.around(field_model, field_model.border, resolution)
        tabs = crossing_association_tables(field_model, grid)
        return cls(field_model, grid, tabs["crossing_lut_L"][0], tabs["crossing_lut_T"][0],
                   conf)

    @classmethod
    def from_map(cls, map_file, conf: dict | None = None) -> ObservationModel:
        """A model on a map (stages.common.map_file.MapFile) and its crossing tables."""
        lut_l, lut_t = map_file.crossing_tables()
        return cls(map_file.field, map_file.grid, lut_l, lut_t, conf)

    # ------------------------------------------------------------------ observations in use
    def usable(self, obs: Observations) -> Observations:
        """The observations the model uses: finite, enabled kinds, lines long and near enough,
        crossings of a known type."""
        return self._usable(obs)[0]

    def _usable(self, obs: Observations):
        """``usable`` and the closest distance (L, 1) of each line kept."""
        c = self.conf
        lines, ends = obs.lines, obs.line_ends
        d_o = _NO_DISTANCES
        if not c["use_lines"] or not len(lines):
            lines, ends = _NO_LINES, None
        else:
            ok = np.isfinite(lines).all(axis=1)
            if ends is not None:
                ok &= np.isfinite(ends).all(axis=1)
            d_all = line_closest_distance(Observations(lines, ends, _NO_CROSSINGS, _NO_POSTS))
            ok &= (lines[:, 2] >= c["min_line_length"]) & (d_all <= c["max_line_distance"])
            if not ok.all():
                lines, ends, d_all = lines[ok], None if ends is None else ends[ok], d_all[ok]
            d_o = d_all[:, None]
        cr = obs.crossings
        if not c["use_crossings"] or not len(cr):
            crossings = _NO_CROSSINGS
        else:
            ok = np.isfinite(cr).all(axis=1) & ((cr[:, 0] == 0) | (cr[:, 0] == 1)
                                                 | (cr[:, 0] == 2))
            crossings = cr if ok.all() else cr[ok]
        posts = obs.posts
        if not c["use_posts"] or not len(posts):
            posts = _NO_POSTS
        else:
            ok = np.isfinite(posts).all(axis=1)
            posts = posts if ok.all() else posts[ok]
        return Observations(lines, ends, crossings, posts), d_o

    def range_sigma(self, d, base: float, elevation: float | np.ndarray | None = None):
        """Range sigma (m) of a floor point at distance ``d``: ``base`` in quadrature with the
        error that an elevation-angle sigma (``elevation_sigma``) makes there, d(range) /
        d(angle) = (h^2 + d^2) / h for a camera at height h."""
        c = self.conf
        h = DEFAULT_CAMERA_HEIGHT if c["camera_height"] is None else float(c["camera_height"])
        e = c["elevation_sigma"] if elevation is None else elevation
        grow = e * (h * h + np.asarray(d, float) ** 2) / h
        return np.sqrt(base * base + grow * grow)

    def _floor(self, confidence, base=None):
        """a_uni (K, 1) of section 5.3 for observations of the given confidence."""
        base = float(self.conf["uniform_floor"] if base is None else base)
        conf01 = np.minimum(np.maximum(confidence, 0.0), 1.0)
        return (base + (1.0 - base) * (1.0 - conf01))[:, None]

    def prepare(self, obs: Observations, *, usable: bool = False) -> PreparedObservations:
        """The usable observations with the kernel's per-observation rows. ``usable``: ``obs``
        is already the model's usable set (a PreparedObservations' ``obs``)."""
        if usable:
            d_o = line_closest_distance(obs)[:, None] if len(obs.lines) else _NO_DISTANCES
        else:
            obs, d_o = self._usable(obs)
        return PreparedObservations(obs, self._line_rows(obs, d_o), *self._point_rows_kernel(obs))

    def _line_rows(self, obs: Observations, d_o) -> np.ndarray:
        """The kernel's rows of the usable lines (mcl_kernels.L_*)."""
        raw = obs.lines
        rows = np.zeros((len(raw), K.N_LINE_COLS))
        if not len(raw):
            return rows
        c = self.conf
        a = raw[:, 1] + np.where(raw[:, 0] < 0, math.pi, 0.0)
        w_d = 1.0 / (2.0 * self.range_sigma(d_o[:, 0], c["sigma_line"]) ** 2)
        rows[:, K.L_R] = np.abs(raw[:, 0])
        rows[:, K.L_CA], rows[:, K.L_SA] = np.cos(a), np.sin(a)
        rows[:, K.L_WD] = w_d
        rows[:, K.L_FLOOR] = self._floor(raw[:, 3])[:, 0]
        if c["line_extent"] and obs.line_ends is not None:
            ends = obs.line_ends
            half = 0.5 * np.hypot(ends[:, 2] - ends[:, 0], ends[:, 3] - ends[:, 1])
            far = np.maximum(np.hypot(ends[:, 0], ends[:, 1]), np.hypot(ends[:, 2], ends[:, 3]))
            w_e = 1.0 / (2.0 * self.range_sigma(far, c["sigma_extent"]) ** 2)
            rows[:, K.L_MX] = 0.5 * (ends[:, 0] + ends[:, 2])
            rows[:, K.L_MY] = 0.5 * (ends[:, 1] + ends[:, 3])
            rows[:, K.L_HM] = half - c["extent_margin"]
            rows[:, K.L_RATIO] = w_e / w_d
            rows[:, K.L_H2] = half * half / 2.0
            rows[:, K.L_WE] = w_e
            rows[:, K.L_EXT] = 1.0
        return rows

    def _point_rows_kernel(self, obs: Observations):
        """The kernel's rows (mcl_kernels.P_*) of the usable crossings and posts, and the sum
        each adds to (1 crossings, 2 posts). X crossings on a field without X, and posts on a
        field without posts, are left out (nothing to associate them with)."""
        c = self.conf
        cr, po = obs.crossings, obs.posts
        if not len(self.x_idx):
            cr = cr[cr[:, 0] != 2]
        if not len(self.posts):
            po = po[:0]
        k_c, k_p = len(cr), len(po)
        rows = np.zeros((k_c + k_p, K.N_POINT_COLS))
        part = np.concatenate([np.ones(k_c, np.int64), np.full(k_p, 2, np.int64)])
        if not len(rows):
            return rows, part
        kind = cr[:, 0]
        d = np.concatenate([cr[:, 1], po[:, 0]])
        b = np.concatenate([cr[:, 2], po[:, 1]])
        o = np.concatenate([cr[:, 3], np.zeros(k_p)])
        elevation = np.concatenate([np.full(k_c, c["elevation_sigma"]),
                                    np.full(k_p, c["post_elevation_sigma"])])
        rows[:, K.P_D] = d
        rows[:, K.P_CB], rows[:, K.P_SB] = np.cos(b), np.sin(b)
        rows[:, K.P_CO], rows[:, K.P_SO] = np.cos(o), np.sin(o)
        rows[:, K.P_WD] = 1.0 / (2.0 * self.range_sigma(d, c["sigma_range"], elevation) ** 2)
        rows[:k_c, K.P_FLOOR] = self._floor(cr[:, 4])[:, 0]
        post_base = c.get("post_uniform_floor")
        rows[k_c:, K.P_FLOOR] = self._floor(po[:, 2], post_base)[:, 0]
        is_l, is_t, is_x = kind == 0, kind == 1, kind == 2
        rows[:, K.P_TABLE] = -1.0
        rows[:k_c, K.P_TABLE][is_l] = K.TABLE_L
        rows[:k_c, K.P_TABLE][is_t] = 4 * self._cells
        rows[:, K.P_AS_T] = -1.0
        x_l, x_t, posts = self._cand_ranges
        p_conf = float(c["crossing_type_confusion"])
        if p_conf > 0:
            rows[:k_c, K.P_PEN] = -math.log(min(p_conf, 1.0))
            if self._t_table:  # an L of a T
                rows[:k_c, K.P_AS_T][is_l] = 4 * self._cells
            rows[:k_c, K.P_C0:K.P_C1 + 1][is_l] = x_l  # an L or T of an X
            rows[:k_c, K.P_C0:K.P_C1 + 1][is_t] = x_t
        rows[:k_c, K.P_C0:K.P_C1 + 1][is_x] = x_t
        rows[k_c:, K.P_C0:K.P_C1 + 1] = posts
        return rows, part

    def _reference_rows(self, prep: PreparedObservations) -> ReferenceRows:
        """The numpy reference's constants of ``prep``'s observations (computed once)."""
        if prep.reference is None:
            obs = prep.obs
            d_o = line_closest_distance(obs)[:, None] if len(obs.lines) else _NO_DISTANCES
            prep.reference = self._prepare_reference(obs, d_o)
        return prep.reference

    def _prepare_reference(self, obs: Observations, d_o) -> ReferenceRows:
        """The usable observations ``obs`` with the numpy reference's constants."""
        c = self.conf
        # lines
        lines = {}
        if len(obs.lines):
            raw = obs.lines
            a = (raw[:, 1] + np.where(raw[:, 0] < 0, math.pi, 0.0))[:, None]
            w_d = 1.0 / (2.0 * self.range_sigma(d_o, c["sigma_line"]) ** 2)
            r = np.abs(raw[:, 0])[:, None]
            ca, sa = np.cos(a), np.sin(a)
            f32 = np.float32
            lines = dict(r=r, ca=ca, sa=sa, w_d=w_d, floor=self._floor(raw[:, 3]), extent=None,
                         r32=r.astype(f32), ca32=ca.astype(f32), sa32=sa.astype(f32),
                         wd32=w_d.astype(f32))
            lines["floor32"] = lines["floor"].astype(f32)
            if c["line_extent"] and obs.line_ends is not None:
                ends = obs.line_ends
                half = 0.5 * np.hypot(ends[:, 2] - ends[:, 0], ends[:, 3] - ends[:, 1])[:, None]
                far = np.maximum(np.hypot(ends[:, 0], ends[:, 1]),
                                 np.hypot(ends[:, 2], ends[:, 3]))[:, None]
                w_e = 1.0 / (2.0 * self.range_sigma(far, c["sigma_extent"]) ** 2)
                mid = 0.5 * (ends[:, 0:2] + ends[:, 2:4])
                hm, ratio, h2 = half - c["extent_margin"], w_e / w_d, half * half / 2.0
                lines["extent"] = dict(
                    mid=mid, half=half, hm=hm, ratio=ratio, w_e=w_e, h2=h2,
                    mx32=mid[:, 0:1].astype(f32), my32=mid[:, 1:2].astype(f32),
                    hm32=hm.astype(f32), ratio32=ratio.astype(f32), h2_32=h2.astype(f32),
                    we32=w_e.astype(f32))
        # points: L/T through the tables, X and posts per particle
        cr = obs.crossings
        table_rows, cand_rows = {}, {}
        lt = cr[cr[:, 0] < 2] if len(cr) else cr
        if len(lt):
            table_rows = self._point_rows(lt[:, 1], lt[:, 2], lt[:, 4], lt[:, 3])
            is_l = (lt[:, 0] == 0)[:, None]
            table_rows["is_l"] = is_l
            table_rows["t_offset"] = np.where(lt[:, 0] == 1, 4 * self._cells, 0)[:, None]
            p_conf = float(c["crossing_type_confusion"])
            if p_conf > 0:
                # the penalty of explaining a crossing by a feature with more arms
                table_rows["confusion_cost"] = -math.log(min(p_conf, 1.0))
                if len(self.x_idx):  # L and T as an X, orientation modulo 90 deg (an L's
                    # bisector lies halfway between two arms)
                    table_rows["as_x"] = self._x_candidates(
                        len(lt), np.where(is_l[:, 0], -1.0, 1.0))
        xs = cr[cr[:, 0] == 2] if len(cr) else cr
        if not len(self.x_idx):
            xs = xs[:0]
        ps = obs.posts if len(self.posts) else obs.posts[:0]
        if len(xs) or len(ps):
            k_x, k_p = len(xs), len(ps)
            m = max(len(self.x_idx) if k_x else 0, len(self.posts) if k_p else 0)
            cx = np.zeros((m, k_x + k_p, 1))
            cy = np.zeros((m, k_x + k_p, 1))
            if k_x:  # pad by repeating the first candidate
                sel = np.resize(self.x_idx, m)
                cx[:, :k_x, 0] = self.cross_x[sel][:, None]
                cy[:, :k_x, 0] = self.cross_y[sel][:, None]
            if k_p:
                sel = np.resize(np.arange(len(self.posts)), m)
                cx[:, k_x:, 0] = self.posts[sel, 0][:, None]
                cy[:, k_x:, 0] = self.posts[sel, 1][:, None]
            cand_rows = self._point_rows(
                np.concatenate([xs[:, 1], ps[:, 0]]), np.concatenate([xs[:, 2], ps[:, 1]]),
                np.concatenate([xs[:, 4], ps[:, 2]]),
                np.concatenate([xs[:, 3], np.zeros(k_p)]),
                np.concatenate([np.full(k_x, c["elevation_sigma"]),
                                np.full(k_p, c["post_elevation_sigma"])]))
            cand_rows.update(cx=cx, cy=cy, n_x=k_x)
            if k_p and c.get("post_uniform_floor") is not None:
                cand_rows["floor"][k_x:] = self._floor(ps[:, 2], c["post_uniform_floor"])
            if k_x and c["sigma_crossing_orientation"] > 0:
                four = 4.0 * self.cross_orient[np.resize(self.x_idx, m)]
                cand_rows["c4"] = np.cos(four)[:, None, None]
                cand_rows["s4"] = np.sin(four)[:, None, None]
                w_o = np.zeros((k_x + k_p, 1))
                w_o[:k_x] = 1.0 / (16.0 * c["sigma_crossing_orientation"] ** 2)
                cand_rows["w_o"] = w_o
        return ReferenceRows(obs, lines, table_rows, cand_rows)

    def _x_candidates(self, k: int, sign: np.ndarray) -> dict:
        """The field's X crossings as candidates (M, 1, 1) for ``k`` observations, with their
        orientation term modulo 90 deg: ``sign`` (K,) 1 where the observed orientation lies
        along an arm, -1 where it lies halfway between two."""
        c = self.conf
        out = {"cx": np.repeat(self.cross_x[self.x_idx][:, None, None], k, axis=1),
               "cy": np.repeat(self.cross_y[self.x_idx][:, None, None], k, axis=1)}
        if c["sigma_crossing_orientation"] > 0:
            four = 4.0 * self.cross_orient[self.x_idx]
            out["c4"] = np.cos(four)[:, None, None]
            out["s4"] = np.sin(four)[:, None, None]
            out["w_o"] = np.full((k, 1), 1.0 / (16.0 * c["sigma_crossing_orientation"] ** 2))
            out["sign"] = np.asarray(sign, float)[:, None]
        return out

    def _point_rows(self, d_o, b_o, confidence, orient, elevation=None):
        c = self.conf
        d_o = np.asarray(d_o, float)[:, None]
        if elevation is not None:
            elevation = np.asarray(elevation, float)[:, None]
        b_o = np.asarray(b_o, float)[:, None]
        o_o = np.asarray(orient, float)[:, None]
        return dict(d=d_o, cb=np.cos(b_o), sb=np.sin(b_o), co=np.cos(o_o), so=np.sin(o_o),
                    w_d=1.0 / (2.0 * self.range_sigma(d_o, c["sigma_range"], elevation) ** 2),
                    floor=self._floor(np.asarray(confidence, float)))

    # ------------------------------------------------------------------ likelihood
    # Arrays keep the particles on the last (contiguous) axis: numpy's inner loops then run
    # over the particles, not over a handful of observations or candidates.
    def log_likelihood(self, x, y, theta, obs, *, parts: bool = False,
                       prepared: bool = False):
        """Log-likelihood (N,) of ``obs`` (Observations or PreparedObservations) at poses
        (x, y, theta), each (N,), by the kernel (stages.localize.mcl_kernels). With ``parts``,
        a dict with the summed log-likelihood of "lines", "crossings" and "posts" instead.
        (``prepared`` is accepted for callers that passed usable observations; preparation
        is idempotent.)"""
        prep = obs if isinstance(obs, PreparedObservations) else self.prepare(obs)
        x = np.ascontiguousarray(x, dtype=float).ravel()
        y = np.ascontiguousarray(y, dtype=float).ravel()
        th = np.ascontiguousarray(theta, dtype=float).ravel()
        cth, sth = np.cos(th), np.sin(th)
        out = np.zeros((3, len(x)))
        c = self.conf
        if len(prep.lines):
            K.line_log_likelihood(out, x, y, cth, sth, prep.lines, self._k_normals,
                                  self._k_tangents, self._k_seg, self._k_group_start,
                                  self._k_arcs, float(c["oriented_tolerance"]) ** 2,
                                  1.0 / (2.0 * float(c["sigma_line_angle"]) ** 2),
                                  float(c["extent_margin"]))
        if len(prep.points):
            K.point_log_likelihood(out, x, y, cth, sth, prep.points, prep.part, self._k_cand,
                                   self.lut, self._k_cross, self._k_grid,
                                   1.0 / float(c["sigma_bearing"]) ** 2, self._k_w_o)
        if parts:
            return dict(zip(PARTS, out))
        return out.sum(axis=0)

    def reference_log_likelihood(self, x, y, theta, obs, *, parts: bool = False):
        """``log_likelihood`` by the numpy reference (the equations as array passes; the
        kernel is held against it)."""
        prep = obs if isinstance(obs, PreparedObservations) else self.prepare(obs)
        ref = self._reference_rows(prep)
        x = np.ascontiguousarray(x, dtype=float).ravel()
        y = np.ascontiguousarray(y, dtype=float).ravel()
        th = np.ascontiguousarray(theta, dtype=float).ravel()
        cth, sth = np.cos(th), np.sin(th)
        out = {}
        if ref.lines:
            out["lines"] = self.line_log_likelihood(x, y, cth, sth, ref).sum(axis=0,
                                                                             dtype=float)
        if ref.table_rows:
            out["crossings"] = self.table_log_likelihood(x, y, cth, sth, ref).sum(axis=0)
        if ref.candidate_rows:
            ll = self.candidate_log_likelihood(x, y, cth, sth, ref)
            n_x = ref.candidate_rows["n_x"]
            if n_x:
                out["crossings"] = out.get("crossings", 0.0) + ll[:n_x].sum(axis=0)
            if n_x < len(ll):
                out["posts"] = ll[n_x:].sum(axis=0)
        if parts:
            return {k: np.broadcast_to(out.get(k, 0.0), x.shape).copy() for k in PARTS}
        total = np.zeros(x.shape)
        for v in out.values():
            total += v
        return total

    # ---- points (eq. 3)
    @staticmethod
    def _point_cost(vx, vy, ux, uy, rows, w_b):
        """Eq. 3: vx, vy landmark minus particle position (field frame), ux, uy the observed
        bearing as a field-frame unit vector, broadcastable to (..., K, N). The bearing error
        enters as 2 (1 - cos), its square near zero (no atan2)."""
        d_e = vx * vx
        d_e += vy * vy
        np.sqrt(d_e, out=d_e)
        cos_b = ux * vx
        cos_b += uy * vy
        cos_b /= np.maximum(d_e, 1e-9)
        d_e -= rows["d"]
        d_e *= d_e
        d_e *= rows["w_d"]
        np.subtract(1.0, cos_b, out=cos_b)
        cos_b *= w_b
        d_e += cos_b
        return d_e

    def table_log_likelihood(self, x, y, cth, sth, prep: ReferenceRows):
        """Log-likelihood (K, N) of the L and T crossings, associated through the tables at
        the cell where each particle places the observation (and, for L, the set of the
        observation's global orientation); with ``crossing_type_confusion`` also by the T
        table (an L) and the X crossings (an L or T), whichever costs least with the
        confusion's penalty."""
        rows = prep.table_rows
        # the observed bearing (u) and orientation (g) as field-frame unit vectors, (K, N)
        ux = rows["cb"] * cth - rows["sb"] * sth
        uy = rows["cb"] * sth + rows["sb"] * cth
        gx = rows["co"] * cth - rows["so"] * sth
        gy = rows["co"] * sth + rows["so"] * cth
        cell = self._cell(x, y, ux, uy, rows["d"])
        # L: the quadrant of the global orientation picks the set (45, 135, 225, 315 deg)
        below = gy < 0
        quad = below * 2 + (below != (gx < 0))
        quad *= self._cells
        quad += cell
        cost = self._table_cost(np.where(rows["is_l"], quad, cell + rows["t_offset"]), x, y,
                                ux, uy, gx, gy, rows, False)
        if "confusion_cost" in rows:
            pen = rows["confusion_cost"]
            is_l = rows["is_l"][:, 0]
            if is_l.any() and self.lut[4 * self._cells:].max() >= 0:  # an L of a T
                sel = np.flatnonzero(is_l)
                sub = {k: rows[k][sel] for k in ("d", "w_d")}
                as_t = self._table_cost(cell[sel] + 4 * self._cells, x, y, ux[sel], uy[sel],
                                        gx[sel], gy[sel], sub, True)
                as_t += pen
                np.minimum(cost[sel], as_t, out=as_t)
                cost[sel] = as_t
            if "as_x" in rows:
                as_x = self._candidate_cost(x, ux, uy, gx, gy, y, rows, rows["as_x"])
                as_x += pen
                np.minimum(cost, as_x, out=cost)
        return _log_mixture(cost, rows["floor"])

    def _cell(self, x, y, ux, uy, d) -> np.ndarray:
        """The index (K, N) of the grid cell where each pose places each point observation
        (distance ``d`` (K, 1) along the field-frame bearing ux, uy)."""
        g = self.grid
        inv_res = 1.0 / g.resolution
        fx = x + d * ux
        fy = y + d * uy
        j = ((fx - g.origin[0]) * inv_res + 0.5).astype(np.int64)
        i = ((fy - g.origin[1]) * inv_res + 0.5).astype(np.int64)
        np.minimum(np.maximum(j, 0, out=j), g.shape[1] - 1, out=j)
        np.minimum(np.maximum(i, 0, out=i), g.shape[0] - 1, out=i)
        i *= g.shape[1]
        i += j
        return i

    def _table_cost(self, i, x, y, ux, uy, gx, gy, rows, l_at_t: bool) -> np.ndarray:
        """Eq. 3 and the orientation term (K, N) of point observations associated with the
        crossings the tables hold at the indices ``i``; ``l_at_t``: L observations at T
        crossings, whose bisector lies 45 deg from the stem."""
        c = self.conf
        idx = self.lut[i]  # (K, N), -1 = none
        missing = idx < 0
        idx[missing] = 0
        cost = self._point_cost(self.cross_x[idx] - x, self.cross_y[idx] - y, ux, uy, rows,
                                1.0 / c["sigma_bearing"] ** 2)
        so = c["sigma_crossing_orientation"]
        if so > 0:
            ci, si = self.cross_c[idx], self.cross_s[idx]
            cos_o = ci * gx
            cos_o += si * gy
            if l_at_t:  # cos of the angle to the nearer of stem +- 45 deg
                sin_o = ci * gy
                sin_o -= si * gx
                np.abs(sin_o, out=sin_o)
                cos_o += sin_o
                cos_o *= math.sqrt(0.5)
            np.subtract(1.0, cos_o, out=cos_o)
            cos_o *= 1.0 / so ** 2
            cost += cos_o
        cost[missing] = _COST_CAP
        return cost

    def _candidate_cost(self, x, ux, uy, gx, gy, y, rows, cand) -> np.ndarray:
        """Eq. 3 (K, N) with the candidate of least cost (candidates ``cand`` on the first
        axis: cx, cy and the X orientation term modulo 90 deg, c4, s4, w_o, sign)."""
        cost = self._point_cost(cand["cx"] - x, cand["cy"] - y, ux, uy, rows,
                                1.0 / self.conf["sigma_bearing"] ** 2)  # (M, K, N)
        if "c4" in cand:  # X orientation modulo 90 deg: cos(4 (o_c - theta - o_o))
            c2, s2 = gx * gx - gy * gy, 2.0 * gx * gy  # the angle doubled, twice
            c4, s4 = c2 * c2 - s2 * s2, 2.0 * c2 * s2
            cos4 = cand["c4"] * c4 + cand["s4"] * s4
            if "sign" in cand:
                cos4 *= cand["sign"]
            np.subtract(1.0, cos4, out=cos4)
            cos4 *= cand["w_o"]
            cost += cos4
        return cost.min(axis=0)

    def candidate_log_likelihood(self, x, y, cth, sth, prep: ReferenceRows):
        """Log-likelihood (K, N) of X crossings (first rows) and goal posts: each particle
        associates each with the candidate of least cost (candidates on the first axis)."""
        rows = prep.candidate_rows
        ux = rows["cb"] * cth - rows["sb"] * sth  # (K, N)
        uy = rows["cb"] * sth + rows["sb"] * cth
        gx = gy = None
        if "c4" in rows:
            gx = rows["co"] * cth - rows["so"] * sth
            gy = rows["co"] * sth + rows["so"] * cth
        return _log_mixture(self._candidate_cost(x, ux, uy, gx, gy, y, rows, rows),
                            rows["floor"])

    # ---- lines (eqs. 4-5)
    def line_log_likelihood(self, x, y, cth, sth, prep: ReferenceRows):
        """Log-likelihood (L, N) of each line observation at each pose.

        Pairs (observed line, particle) are flattened; each pair is compared with the lines of
        the field direction it is most nearly parallel to (any other direction costs at least
        sin^2(45 deg) / (2 sigma_psi^2) ~ 39, whose exp is negligible) and with the arcs'
        tangents. The pairs' quantities are the rows of one float32 matrix whose columns are
        ordered so that the pairs of each direction form a contiguous block: observations whose
        pairs all choose one direction (the usual case while tracking) are ordered as whole
        rows, otherwise the pairs are sorted once. The segments of a direction lie on the first
        axis of its block's costs."""
        ln = prep.lines
        n_l, n_p = len(ln["r"]), x.shape[0]
        f32 = np.float32
        ext = ln["extent"]
        xf, yf = x.astype(f32), y.astype(f32)
        cf, sf = cth.astype(f32), sth.astype(f32)
        # the observed perpendicular's unit vector in the field frame, (L, N)
        ux = ln["ca32"] * cf
        ux -= ln["sa32"] * sf
        uy = ln["ca32"] * sf
        uy += ln["sa32"] * cf
        # the field direction of each pair
        gn = self.group_normals
        n_g = len(gn)
        if n_g == 2:
            a = _project(ux, uy, slice(None), gn[1])
            b = _project(ux, uy, slice(None), gn[0])
            np.abs(a, out=a)
            np.abs(b, out=b)
            gid = np.greater(a, b).view(np.int8)
        elif n_g > 2:
            gid = np.argmax(np.abs(gn[:, 0, None, None] * ux + gn[:, 1, None, None] * uy),
                            axis=0).astype(np.int8)
        else:
            gid = np.zeros((n_l, n_p), np.int8)
        lo, hi = gid.min(axis=1), gid.max(axis=1)
        row_group = np.where(lo == hi, lo, n_g)  # n_g: mixed
        order = np.argsort(row_group, kind="stable")
        if np.any(order[1:] < order[:-1]):
            ux, uy, gid, row_group = ux[order], uy[order], gid[order], row_group[order]
        else:
            order = None

        def per_line(v):  # a per-line constant (L, 1) in the order of the rows
            return v if order is None else v[order]

        rows = _N_ROWS if ext is not None else _MX
        pr = np.empty((rows, n_l, n_p), f32)
        pr[_PX] = xf
        pr[_PY] = yf
        pr[_UX] = ux
        pr[_UY] = uy
        pr[_R] = per_line(ln["r32"])
        pr[_WD] = per_line(ln["wd32"])
        np.multiply(pr[_R], ux, out=pr[_FX])  # the perpendicular's foot in the field frame
        pr[_FX] += xf
        np.multiply(pr[_R], uy, out=pr[_FY])
        pr[_FY] += yf
        if ext is not None:  # the observed segment's middle in the field frame
            mx, my, tmp = pr[_MX], pr[_MY], pr[_HM]
            mid_x, mid_y = per_line(ext["mx32"]), per_line(ext["my32"])
            np.multiply(mid_x, cf, out=mx)
            np.multiply(mid_y, sf, out=tmp)
            mx -= tmp
            mx += xf
            np.multiply(mid_x, sf, out=my)
            np.multiply(mid_y, cf, out=tmp)
            my += tmp
            my += yf
            pr[_HM] = per_line(ext["hm32"])
            pr[_RATIO] = per_line(ext["ratio32"])
        pr = pr.reshape(rows, n_l * n_p)
        best = np.empty(n_l * n_p, f32)
        starts = np.searchsorted(row_group, np.arange(n_g + 2))
        first_mixed = starts[n_g]
        mixed = gid[first_mixed:].ravel()
        for g in range(n_g):
            if starts[g + 1] > starts[g]:  # observations all of this direction: a block
                block = slice(starts[g] * n_p, starts[g + 1] * n_p)
                best[block] = self._line_group_cost(pr, block, g, ext is not None)
            if len(mixed):  # the pairs of this direction among the others
                sel = first_mixed * n_p + np.flatnonzero(mixed == g)
                if len(sel):
                    best[sel] = self._line_group_cost(pr, sel, g, ext is not None)
        c = self.conf
        if c["arc_lines"] and len(self.arcs):
            line_of_pair = None
            if ext is not None:  # the observation of each column, for the arc's extent term
                line_of_pair = np.arange(n_l).repeat(n_p)
                line_of_pair = line_of_pair if order is None else order[line_of_pair]
            for arc in self.arcs:
                self._arc_line_cost(best, pr, arc, ext, line_of_pair)
        best = best.reshape(n_l, n_p)
        if order is not None:
            out = np.empty((n_l, n_p), f32)
            out[order] = best
            best = out
        return _log_mixture(best, ln["floor32"])

    def _line_group_cost(self, pr: np.ndarray, sel, g: int, extent: bool) -> np.ndarray:
        """Cost of the pairs ``sel`` (a slice or indices of the columns of ``pr``) against the
        field lines of direction ``g``: the least over those lines of eq. 4 with eq. 5 and the
        extent term. (With an axis-parallel direction only one of x and y is read.)"""
        c = self.conf
        nrm, tng, off, lo, hi = self.line_groups[g]
        cos_d = _project(pr[_UX], pr[_UY], sel, nrm)
        r_s = pr[_R, sel]
        rc = r_s * cos_d  # the observed perpendicular projected on the group normal
        pn = _project(pr[_PX], pr[_PY], sel, nrm)
        # |l_e - l_o|^2 = (e - r cos)^2 + r^2 sin^2 with e = off - pn: e - rc = off - q
        cost = off - _project(pr[_FX], pr[_FY], sel, nrm)
        cost *= cost  # (S_g, M)
        # eq. 5: <l_e, l_o> = (off - pn) rc must exceed -tol^2: off rc > pn rc - tol^2
        pn *= rc
        pn -= np.float32(c["oriented_tolerance"] ** 2)
        bad = np.multiply.outer(off[:, 0], rc) <= pn
        if extent:
            # the overhang of the observed middle +- (half length - margin) beyond [lo, hi]
            t = _project(pr[_MX], pr[_MY], sel, tng)
            hm = pr[_HM, sel]
            over = (t + hm) - hi
            under = lo - (t - hm)
            np.maximum(over, under, out=over)
            np.maximum(over, 0.0, out=over)
            over *= over
            over *= pr[_RATIO, sel]
            cost += over
        np.copyto(cost, _BIG, where=bad)
        wd = pr[_WD, sel]
        w_a = np.float32(1.0 / (2.0 * c["sigma_line_angle"] ** 2))
        out = cost.min(axis=0)
        out *= wd
        cos_d *= cos_d
        np.subtract(1.0, cos_d, out=cos_d)
        r_s = r_s * r_s
        r_s *= wd
        r_s += w_a
        cos_d *= r_s
        out += cos_d
        return out

    def _arc_line_cost(self, best, pr, arc, ext, line_of_pair):
        """Lower ``best`` (M,) where the tangent of an arc, at the arc point nearest to the
        observed segment (its midpoint, else the perpendicular's foot), explains a (line,
        particle) pair (columns of ``pr``; ``line_of_pair``: the observation of each, for
        the extent term of ``ext``) better. Only pairs whose segment lies within 1 m of
        the arc count."""
        c = self.conf
        tol2 = c["oriented_tolerance"] ** 2
        w_a = 1.0 / (2.0 * c["sigma_line_angle"] ** 2)
        cx, cy, rad, a0, sweep = arc
        qx, qy = (pr[_MX], pr[_MY]) if ext is not None else (pr[_FX], pr[_FY])
        vx, vy = qx - np.float32(cx), qy - np.float32(cy)
        dist = vx * vx
        dist += vy * vy
        np.sqrt(dist, out=dist)
        sel = np.flatnonzero(np.abs(dist - np.float32(rad)) < 1.0)
        if not len(sel):
            return
        vx, vy, dist = vx[sel], vy[sel], dist[sel]
        if sweep < 2 * math.pi - 1e-9:  # clamp the nearest point to the arc's ends
            phi = np.arctan2(vy, vx)
            rel = np.mod(phi - a0, 2 * math.pi)
            rel = np.where(rel > sweep, np.where(rel - sweep < 2 * math.pi - rel, sweep, 0.0),
                           rel)
            nx_, ny_ = np.cos(a0 + rel), np.sin(a0 + rel)
        else:
            dist = np.maximum(dist, 1e-9)
            nx_, ny_ = vx / dist, vy / dist
        ps = pr[:, sel]
        r_s, w_s = ps[_R], ps[_WD]
        e = (rad + cx * nx_ + cy * ny_) - (ps[_PX] * nx_ + ps[_PY] * ny_)
        cos_d = ps[_UX] * nx_ + ps[_UY] * ny_
        rc = r_s * cos_d
        cost = (e - rc) ** 2 * w_s + (1.0 - cos_d * cos_d) * (r_s * r_s * w_s + w_a)
        cost[e * rc <= -tol2] = _BIG
        if ext is not None:  # a straight segment of half length h departs h^2 / 2r from the arc
            dev = np.maximum(ext["h2"][:, 0] / rad - c["extent_margin"], 0.0)
            cost += (dev * dev * ext["w_e"][:, 0])[line_of_pair[sel]]
        best[sel] = np.minimum(best[sel], cost)
