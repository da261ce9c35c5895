"""Observation model of the particle filter (Schulz et al. 2011, section 5): how likely one frame's
lines, crossings and goal posts are at many poses at once.

Observations are egocentric, in the robot frame on the floor (x forward, y left), as
``extract`` writes them for a perspective camera: lines, optional line ends, crossings and goal
posts (stages.common.observations lists the columns).

Point model (eq. 3), for crossings and goal posts, with expected egocentric distance and
bearing (d_e, phi_e) of the associated landmark::

    cost = (d_e - d_o)^2 / (2 (sigma_d + lambda_d d_o)^2) + (phi_e - phi_o)^2 / (2 sigma_phi^2)

The range uncertainty grows with the distance (the camera's unknown pitch and roll). The
squared bearing error is computed as 2 (1 - cos(phi_e - phi_o)) (equal near zero, no atan2).
L, T and X crossings also carry an orientation term (1 - cos of the orientation error, X
modulo 90 deg) with ``sigma_crossing_orientation``; 0 drops it, as in the paper.

Line model (eqs. 4-5), with the dropped perpendiculars l_e (expected) and l_o (observed) as
vectors in the robot frame, d_o the distance to the closest observed point of the line::

    cost = d(l_e, l_o)^2 / (2 (sigma_l + lambda_l d_o)^2) + (psi_e - psi_o)^2 / (2 sigma_psi^2)
    d(l_e, l_o) = |l_e - l_o|  if <l_e, l_o> > -tol^2  else infinity   (oriented distance)

psi is the line's direction (modulo pi; sin^2 of the difference stands for its square). A line
behind the robot has its perpendicular pointing the other way and is rejected by eq. 5. The
tolerance ``oriented_tolerance`` (0 is the paper's rule) keeps a line the robot stands on (both
perpendiculars ~0) from being rejected by noise. Lines shorter than ``min_line_length`` or
farther than ``max_line_distance`` are ignored (the paper ignores short, far lines). Two
additions to the paper, both in the same cost units: the observed segment must lie within the
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

Unseen lines (negative information: Hoffmann, Spranger, Göhring and Jüngel 2005): a pose
that should have shown more field line near the robot than the frame holds is less likely.
On rendered NAO walks the look-alike places the filter held (1.65 m along the touch line, the
penalty area turned about its front line) would show 1-2 m of line near the robot that the
frames do not hold. Where the features give the frame's view (the floor the image sees below
the field boundary, ``extract``'s ``view``), shrunk by ``unseen_margin`` (a line at its edge is
often cut short), the field's lines inside it within ``unseen_range`` of a pose make n =
length / ``unseen_piece`` pieces, and the frame's usable lines cover ``seen`` pieces of it.
Each piece is found with probability q (``unseen_detection``): log P(seen | n) = log C(n, seen)
+ seen log q + (n - seen) log(1 - q), with n = max(n, seen) (a false line adds pieces no pose
can explain). The frame's term is log(floor + (1 - floor) P / P_peak), P_peak the largest
P(seen | n) over n (``unseen_floor``, the same construction as an observation's uniform floor):
the pieces missed together in one frame (a robot in front of the camera, a blurred frame) are
not independent, and without the floor a frame that missed the line at the robot's feet
ruled the truth out. A pose showing no more line than was seen costs nothing.

The names in double backquotes above are fields of ``TUNING`` (an ``ObservationTuning``);
which kinds of observation are used and the camera's height are the user's choice
(``DEFAULTS``, mcl's ``observation`` conf group).

Speed: ``log_likelihood`` runs the numba kernel of stages.localize.mcl_kernels (one pass per
observation over the poses, the alternatives of a crossing's type evaluated in registers, and
only where the observed type costs more than the confusion's penalty). Costs are capped at 60
(exp < 1e-26). tests/oracles/observation_model.py writes the equations out as array passes;
tests/test_mcl.py holds the kernel against it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

from stages.common import crossing_tables
from stages.common.conf import SCALAR
from stages.common.crossing_tables import crossing_association_tables
from stages.common.field import FieldModel
from stages.common.map_file import Grid
from stages.common.observations import Observations
from stages.common.perspective_camera import MAX_HEIGHT_M, MIN_HEIGHT_M

from . import mcl_kernels as K

PARTS = ("lines", "crossings", "posts", "unseen")
DEFAULT_CAMERA_HEIGHT = 0.5  # m, when neither the conf nor a calibration gives one

# what a user chooses (mcl's ``observation`` conf group): the camera's height and which kinds
# of observation to use (the no-lines preset is the paper's ablation: crossings and posts only)
DEFAULTS = {
    "camera_height": None,  # m, the camera above the floor; None: the dataset's calib.yaml
    # (mcl.run), 0.5 without one
    "use_lines": True,
    "use_crossings": True,
    "use_posts": True,
}
# the ranges of its numeric keys (common.conf.check_bounds, held by the confs that hold the
# group, under their name for it): a camera height as a calib.yaml may give it
# (perspective_camera), one number (its preset is None, so any YAML value is taken)
BOUNDS = {"camera_height": (MIN_HEIGHT_M, MAX_HEIGHT_M, SCALAR)}


class ObservationTuning(NamedTuple):
    """The observation model's sigmas, floors and switches of its equations (module doc)."""

    sigma_range: float
    elevation_sigma: float
    post_elevation_sigma: float
    sigma_bearing: float
    sigma_crossing_orientation: float
    crossing_type_confusion: float
    sigma_line: float
    sigma_line_angle: float
    oriented_tolerance: float
    line_extent: bool
    sigma_extent: float
    extent_margin: float
    arc_lines: bool
    min_line_length: float
    max_line_distance: float
    uniform_floor: float
    post_uniform_floor: float | None
    unseen_range: float
    unseen_piece: float
    unseen_margin: float
    unseen_detection: float
    unseen_floor: float


# the model's constants: the paper's equations with the values the filter was tuned with on
# rendered KidSize and NAO walks (the posts' floor: docs/results.md, "mcl", "Goal posts' own
# uniform floor")
TUNING = ObservationTuning(
    sigma_range=0.03,  # m, range sigma of eq. 3 at distance 0
    elevation_sigma=0.01,  # rad, sigma of a floor point's angle below the horizon (the
    # camera's pitch and the pixel's error): the range sigma grows as (h^2 + d^2) / h
    post_elevation_sigma=0.03,  # rad, the same for a goal post's foot (less sharp)
    sigma_bearing=0.06,  # rad, sigma_phi of eq. 3
    sigma_crossing_orientation=0.3,  # rad, L/T/X orientation term; 0 = off (the paper)
    crossing_type_confusion=0.2,  # probability that a crossing shows fewer arms than it
    # has (an L of a T or X, a T of an X: an arm unseen); 0 = types as observed (the paper)
    sigma_line=0.03,  # m, sigma_l of eq. 4 at distance 0 (grows as the range sigma)
    sigma_line_angle=0.08,  # rad, sigma_psi of eq. 4
    oriented_tolerance=0.15,  # m, eq. 5 accepts <l_e, l_o> > -tol^2
    line_extent=True,  # charge the part of a segment beyond the model segment's ends
    sigma_extent=0.15,  # m, at distance 0 (grows as the range sigma of the farther end)
    extent_margin=0.1,  # m of overhang that is free
    arc_lines=True,  # the centre circle (and arcs) as candidate lines, by their tangent
    min_line_length=0.3,  # m, shorter lines are ignored (Schulz et al.: short, far lines)
    max_line_distance=6.0,  # m, lines whose closest point is farther are ignored
    uniform_floor=0.1,  # a_base of section 5.3, in ]0, 1[
    post_uniform_floor=0.6,  # a_base for goal posts: most detected posts are no goal
    # post (robots' and people's legs: on rendered NAO walks most detections lie at no post
    # at the true pose; docs/results.md); None = uniform_floor
    unseen_range=2.0,  # m: the unseen term counts the lines this near (0: no term); farther
    # ones are missed too often to tell (on rendered NAO walks 460-489 at the true poses, a
    # 0.5 m piece 1.5-2.5 m away was found 80 % of the time, 2.5-3.5 m away 70 %, with a
    # frame-to-frame spread that made the evidence far weaker)
    unseen_piece=0.5,  # m of line that is one piece
    unseen_margin=0.2,  # m: the view is shrunk by this much (a line at the image's edge or
    # just below the field boundary is often cut short or missed)
    unseen_detection=0.76,  # q: the probability that a piece in view is found (maximum
    # likelihood at the true poses of rendered NAO walks 460-489; a beta-distributed q fitted
    # there came out this binomial: no spread from frame to frame)
    unseen_floor=0.7,  # a frame's term is log(floor + (1 - floor) P / P_peak): a frame's
    # misses cost a pose at most log(0.7) = -0.36 nats (NAO tuning walks 460-519: floors
    # 0.5-0.8 did alike, 0.1 and 0.3 left more frames confidently wrong; docs/results.md)
)
UNSEEN_CELL = 0.05  # m, the view mask's cells
UNSEEN_SPACING = 0.1  # m between the field lines' samples (a fifth of a piece)
# the term is evaluated once per bin of poses (mcl_kernels.unseen_log_likelihood): a tracked
# belief's 1000 particles (10 cm and 3 deg apart) share about 130 bins; at 2 m, 3 deg moves a
# line 10 cm, a fifth of a piece
UNSEEN_BIN_XY = 0.1  # m
UNSEEN_BIN_HEADING = math.radians(3.0)
# the binomial's peak is sought over n = seen + k 0.05, k < 800 (40 pieces more than seen)
_PEAK_STEP, _PEAK_COUNT = 0.05, 800


_NO_LINES = np.zeros((0, 4))
_NO_CROSSINGS = np.zeros((0, 5))
_NO_POSTS = np.zeros((0, 3))
_NO_DISTANCES = np.zeros((0, 1))
_NO_ENDS = np.zeros((0, 4))


def line_samples(segments, arcs, spacing: float) -> K.LineSamples:
    """Lines (``segments`` (S, 2, 2)) and arcs (``arcs`` (A, 5): cx, cy, r, a0, sweep) cut
    into equal pieces at most ``spacing`` long, as the unseen term's kernel reads them
    (mcl_kernels.LineSamples): each piece's middle and length, and per line or arc its
    bounding box, its pieces and (a straight line) its start and unit direction."""
    points, groups = [], []

    def add(pts, piece, box, line):
        groups.append([*box, sum(len(q) for q in points), len(pts), *line, piece])
        points.append(np.column_stack([pts, np.full(len(pts), piece)]))

    for a, b in np.asarray(segments, float).reshape(-1, 2, 2):
        length = float(np.hypot(*(b - a)))
        n = max(1, int(math.ceil(length / spacing)))
        t = (np.arange(n) + 0.5)[:, None] / n
        d = (b - a) / max(length, 1e-12)
        add(a + t * (b - a), length / n, [*np.minimum(a, b), *np.maximum(a, b)],
            [1.0, a[0], a[1], d[0], d[1]])
    for cx, cy, rad, a0, sweep in np.asarray(arcs, float).reshape(-1, 5):
        n = max(1, int(math.ceil(abs(sweep) * rad / spacing)))
        ang = a0 + sweep * (np.arange(n) + 0.5) / n
        add(np.column_stack([cx + rad * np.cos(ang), cy + rad * np.sin(ang)]),
            abs(sweep) * rad / n, [cx - rad, cy - rad, cx + rad, cy + rad],
            [0.0, 0.0, 0.0, 0.0, 0.0])
    return K.LineSamples(
        np.concatenate(points) if points else np.zeros((0, 3)),
        np.array(groups, float).reshape(-1, K.N_SAMPLE_GROUP_COLS))


# a point of a set cell lies within sqrt(2) / 2 of a cell of the cell's centre: the hull of
# the centres, grown by this many cells, holds every set cell
_HULL_GROWTH = 0.75
# the hull's planes the kernel cuts with: its longest edges (a camera's view: its two sides,
# the near edge and the far one; the kernel on the bench's belief 0.35 ms, with all ten
# edges 0.40 ms)
_VIEW_PLANES = 4


def view_area(mask: np.ndarray, r: float, cell: float) -> K.ViewArea:
    """The ViewArea of a view ``mask`` (cells of ``cell`` m over [-r, r]^2 about the robot,
    row y, column x): the mask and the half-planes of the ``_VIEW_PLANES`` longest edges of
    its set cells' convex hull, grown by ``_HULL_GROWTH`` cells (mcl_kernels.view_planes)."""
    return K.ViewArea(mask, float(r), 1.0 / cell,
                      K.view_planes(mask, float(r), float(cell), _HULL_GROWTH * cell,
                                    _VIEW_PLANES))


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
class PreparedObservations:
    """The observations a model uses, with the per-observation constants of its equations
    (computed once per frame, reused for every pose): the kernel's rows
    (stages.localize.mcl_kernels: ``lines`` (L, 12), ``points`` (K, 12) and the sum ``part``
    (K,) each point adds to)."""

    obs: Observations
    lines: np.ndarray
    points: np.ndarray
    part: np.ndarray
    view: K.View | None = None  # the unseen term's view (None: no term)

    def __len__(self) -> int:
        return len(self.obs)


class ObservationModel:
    """Likelihood of a frame's observations at N poses, vectorised over the poses.

    ``lut_l`` (4, ny, nx) and ``lut_t`` (ny, nx) are the crossing association tables on
    ``grid`` (stages.common.crossing_tables); ``from_field`` builds them when no map is at
    hand, ``from_map`` reads them from a map. ``conf``: what the user chose (``DEFAULTS``'
    keys); ``tuning``: the equations' sigmas and floors (``TUNING``).
    """

    def __init__(self, field_model: FieldModel, grid: Grid, lut_l: np.ndarray,
                 lut_t: np.ndarray, conf: dict | None = None,
                 tuning: ObservationTuning = TUNING):
        self.field = field_model
        self.grid = grid
        self.conf = dict(DEFAULTS, **(conf or {}))
        self.tuning = tuning
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
        # per direction: its normal and direction, and its segments' rows (offset, first and
        # last position along the direction)
        groups = []
        for a in np.unique(angle):
            k = angle == a
            groups.append((n[k][0], t[k][0], np.stack(
                [offset[k], along[k].min(axis=1), along[k].max(axis=1)], axis=1)))
        self.arcs = np.asarray(fm.arcs, float).reshape(-1, 5)
        # the unseen term's field lines
        self._samples = line_samples(fm.segments, fm.arcs, UNSEEN_SPACING)
        self._kernel_constants(groups)

    def _kernel_constants(self, groups):
        """The field and conf as the kernel's arrays (mcl_kernels)."""
        t = self.tuning
        g = self.grid
        self._t_table = bool(self.lut[4 * self._cells:].max() >= 0)
        self._k_grid = np.array([g.origin[0], g.origin[1], 1.0 / g.resolution, g.shape[1],
                                 g.shape[0]], float)
        self._k_cross = np.ascontiguousarray(np.stack(
            [self.cross_x, self.cross_y, self.cross_c, self.cross_s], axis=1).reshape(-1, 4))
        so = float(t.sigma_crossing_orientation)
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
        self._k_lines = K.FieldLines(
            np.array([gr[0] for gr in groups], float).reshape(-1, 2),
            np.array([gr[1] for gr in groups], float).reshape(-1, 2),
            (np.concatenate([gr[2] for gr in groups]).reshape(-1, 3) if groups
             else np.zeros((0, 3))),
            np.cumsum([0] + [len(gr[2]) for gr in groups]).astype(np.int64),
            np.ascontiguousarray(self.arcs) if t.arc_lines else np.zeros((0, 5)))

    def with_conf(self, conf: dict | None,
                  tuning: ObservationTuning | None = None) -> ObservationModel:
        """The same field and tables with another conf (and tuning: by default this one's)."""
        ny, nx = self.grid.shape
        lut_l = self.lut[:4 * self._cells].reshape(4, ny, nx)
        return ObservationModel(self.field, self.grid, lut_l,
                                self.lut[4 * self._cells:].reshape(ny, nx), conf,
                                self.tuning if tuning is None else tuning)

    @classmethod
    def from_field(cls, field_model: FieldModel, conf: dict | None = None,
                   resolution: float = 0.1, tuning: ObservationTuning = TUNING
                   ) -> ObservationModel:
        """A model with crossing tables computed on the fly (no map file needed)."""
        grid = Grid.around(field_model, field_model.border, resolution)
        tabs = crossing_association_tables(field_model, grid)
        return cls(field_model, grid, tabs["crossing_lut_L"][0], tabs["crossing_lut_T"][0],
                   conf, tuning)

    @classmethod
    def from_map(cls, map_file, conf: dict | None = None) -> ObservationModel:
        """A model on a map (stages.common.map_file.MapFile) and its crossing tables."""
        lut_l, lut_t = crossing_tables.of_map(map_file)
        return cls(map_file.field, map_file.grid, lut_l, lut_t, conf)

    # ------------------------------------------------------------------ observations in use
    def usable(self, obs: Observations) -> Observations:
        """The observations the model uses: finite, enabled kinds, lines long and near enough,
        crossings of a known type."""
        return self._usable(obs)[0]

    def _usable(self, obs: Observations):
        """``usable`` and the closest distance (L, 1) of each line kept."""
        c, t = self.conf, self.tuning
        lines, ends = obs.lines, obs.line_ends
        d_o = _NO_DISTANCES
        if not c["use_lines"] or not len(lines):
            lines, ends = _NO_LINES, None
        else:
            ok = np.isfinite(lines).all(axis=1)
            if ends is not None:
                ok &= np.isfinite(ends).all(axis=1)
            d_all = line_closest_distance(Observations(lines, ends, _NO_CROSSINGS, _NO_POSTS))
            ok &= (lines[:, 2] >= t.min_line_length) & (d_all <= t.max_line_distance)
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
        return Observations(lines, ends, crossings, posts, obs.view), d_o

    def range_sigma(self, d, base: float, elevation: float | np.ndarray | None = None):
        """Range sigma (m) of a floor point at distance ``d``: ``base`` in quadrature with the
        error that an elevation-angle sigma (``elevation_sigma``) makes there, d(range) /
        d(angle) = (h^2 + d^2) / h for a camera at height h."""
        c, t = self.conf, self.tuning
        h = DEFAULT_CAMERA_HEIGHT if c["camera_height"] is None else float(c["camera_height"])
        e = t.elevation_sigma if elevation is None else elevation
        grow = e * (h * h + np.asarray(d, float) ** 2) / h
        return np.sqrt(base * base + grow * grow)

    def _floor(self, confidence, base=None):
        """a_uni (K, 1) of section 5.3 for observations of the given confidence."""
        base = float(self.tuning.uniform_floor if base is None else base)
        conf01 = np.minimum(np.maximum(confidence, 0.0), 1.0)
        return (base + (1.0 - base) * (1.0 - conf01))[:, None]

    def prepare(self, obs: Observations, *, usable: bool = False) -> PreparedObservations:
        """The usable observations with the kernel's per-observation rows. ``usable``: ``obs``
        is already the model's usable set (a PreparedObservations' ``obs``)."""
        if usable:
            d_o = line_closest_distance(obs)[:, None] if len(obs.lines) else _NO_DISTANCES
        else:
            obs, d_o = self._usable(obs)
        return PreparedObservations(obs, self._line_rows(obs, d_o), *self._point_rows_kernel(obs),
                                    self._view(obs))

    def _view(self, obs: Observations) -> K.View | None:
        """The unseen term's View of the frame (None without a view, line ends or the term)."""
        t = self.tuning
        r = float(t.unseen_range)
        view = obs.view
        if (r <= 0 or t.unseen_floor >= 1.0 or view is None or len(view) < 3
                or not self.conf["use_lines"] or (len(obs.lines) and obs.line_ends is None)
                or not len(self._samples.points)):
            return None
        view = np.asarray(view, float)
        if not np.isfinite(view).all():
            return None
        cells = int(math.ceil(2.0 * r / UNSEEN_CELL))
        mask = np.zeros((cells, cells), np.uint8)
        shift = 4  # fillPoly's fixed point: 1/16 of a cell; its pixel centres lie at whole
        # coordinates, the kernel's cell i spans [i, i + 1)
        poly = np.round(((view + r) / UNSEEN_CELL - 0.5) * (1 << shift)).astype(np.int32)
        cv2.fillPoly(mask, [poly], 1, lineType=cv2.LINE_8, shift=shift)
        k = int(round(t.unseen_margin / UNSEEN_CELL))
        if k > 0:
            mask = cv2.erode(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE,
                                                             (2 * k + 1, 2 * k + 1)))
        area = view_area(mask, r, UNSEEN_CELL)
        seen = 0.0
        if len(obs.lines):  # the lines' length inside the (shrunk) view within r
            ends = np.ascontiguousarray(obs.line_ends, float).reshape(-1, 4)
            seen = K.segments_in_view(ends, UNSEEN_CELL, area) / t.unseen_piece
        log_miss = math.log1p(-float(t.unseen_detection))
        # the binomial's peak over the pieces a pose may show (n >= seen), for the floor
        peak = K.binomial_peak(seen, log_miss, _PEAK_STEP, _PEAK_COUNT)
        return K.View(area, seen, 1.0 / t.unseen_piece, log_miss, peak,
                      float(t.unseen_floor), UNSEEN_BIN_XY, UNSEEN_BIN_HEADING)

    def _camera_height(self) -> float:
        """The camera's height (m) the range sigmas grow with."""
        h = self.conf["camera_height"]
        return DEFAULT_CAMERA_HEIGHT if h is None else float(h)

    def _line_rows(self, obs: Observations, d_o) -> np.ndarray:
        """The kernel's rows of the usable lines (mcl_kernels.L_* by mcl_kernels.line_rows)."""
        t = self.tuning
        ends = obs.line_ends if t.line_extent and obs.line_ends is not None else _NO_ENDS
        return K.line_rows(np.ascontiguousarray(obs.lines, float),
                           np.ascontiguousarray(d_o[:, 0], float),
                           np.ascontiguousarray(ends, float),
                           (self._camera_height(), float(t.elevation_sigma),
                            float(t.sigma_line), float(t.sigma_extent),
                            float(t.extent_margin), float(t.uniform_floor),
                            1.0 if t.line_extent else 0.0))

    def _point_rows_kernel(self, obs: Observations):
        """The kernel's rows (mcl_kernels.P_*) of the usable crossings and posts, and the sum
        each adds to (1 crossings, 2 posts), by mcl_kernels.point_rows. X crossings on a field
        without X, and posts on a field without posts, are left out (nothing to associate
        them with)."""
        t = self.tuning
        cr, po = obs.crossings, obs.posts
        if not len(self.x_idx) and len(cr):
            cr = cr[cr[:, 0] != 2]
        if not len(self.posts):
            po = po[:0]
        post_floor = t.uniform_floor if t.post_uniform_floor is None else t.post_uniform_floor
        (xl0, xl1), (xt0, xt1), (p0, p1) = self._cand_ranges
        return K.point_rows(
            np.ascontiguousarray(cr, float).reshape(-1, 5),
            np.ascontiguousarray(po, float).reshape(-1, 3),
            (float(4 * self._cells), 1.0 if self._t_table else 0.0, float(xl0), float(xl1),
             float(xt0), float(xt1), float(p0), float(p1)),
            (self._camera_height(), float(t.elevation_sigma), float(t.post_elevation_sigma),
             float(t.sigma_range), float(t.uniform_floor), float(post_floor),
             float(t.crossing_type_confusion)))

    # ------------------------------------------------------------------ likelihood
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
        out = np.zeros((len(PARTS), len(x)))
        t = self.tuning
        poses = K.Poses(x, y, cth, sth, th)
        if len(prep.lines):
            K.line_log_likelihood(out, poses, prep.lines, self._k_lines,
                                  (float(t.oriented_tolerance) ** 2,
                                   1.0 / (2.0 * float(t.sigma_line_angle) ** 2),
                                   float(t.extent_margin)))
        if len(prep.points):
            K.point_log_likelihood(out, poses, prep.points, prep.part,
                                   K.FieldPoints(self._k_cand, self.lut, self._k_cross,
                                                 self._k_grid),
                                   (1.0 / float(t.sigma_bearing) ** 2, self._k_w_o))
        if prep.view is not None and len(prep):
            K.unseen_log_likelihood(out, poses, self._samples, prep.view)
        if parts:
            return dict(zip(PARTS, out))
        return out.sum(axis=0)
