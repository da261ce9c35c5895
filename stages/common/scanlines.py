"""The scan lines of Ribeiro et al. (2015), defined once for the table builder and the
image extractor.

In the robot frame (x forward, y left), from the robot's own radius outwards:
- 72 radial scan lines, ray k at angle 5k deg counter-clockwise from +x, up to ``max_range``;
  each reports the distances of up to 4 white-line crossings, nearest first.
- Archimedean spiral scan lines r(phi) = r0 + (r_end - r0) phi / (2 pi), phi in [0, 2 pi], that
  start at the robot radius r0 and reach ``spiral_end_radius`` after one full turn; start angles
  every 5 deg (72), turning counter-clockwise (direction 0) or clockwise (direction 1); each
  reports the radius of its first white-line crossing. A robot uses every other start angle
  (36 each way, 10 deg apart, as in the paper); all 72 are kept so that any heading that is a
  multiple of 5 deg is an index rotation.

Heading as index rotation: what a robot with heading m * 5 deg sees on its radial line k is
what a robot with heading 0 at the same place sees on radial line (k + m) mod 72; the same holds
for the spiral start angles. ``rotate_to_heading`` applies it to a table row set.

Line points of a team's own detector (robot frame) become scan-line crossings through
``bin_points_to_scanlines``, the layout extract writes and localize reads.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from .errors import FieldlocError

NO_HIT_MM = 65535  # uint16 marker for "no crossing" in the tables
# m: the farthest a scan line (radial or spiral) may reach, for build-map and extract alike.
# A camera on a robot resolves field lines a few metres away; 50 m is past the diagonal of
# the largest league field (MSL, 22 x 14 m: 26 m) plus its border, so no real range is
# refused, while 1e308 m would overflow the tables' cell arithmetic
MAX_RANGE_M = 50.0
# the most scan lines and crossings per line a stored map or features file may give: build-map
# and extract write ScanLines' 72 lines 5 deg apart with 4 crossings each; a reader takes up
# to a line a degree and 16 crossings (a 4 m line crosses at most 5 of a field's lines), which
# bounds the tables and columns it reads from those numbers
MAX_SCAN_ANGLES = 360
MAX_SCAN_CROSSINGS = 16


@dataclass(frozen=True)
class ScanLines:
    n_angles: int = 72  # radial lines and spiral start angles (5 deg apart)
    max_crossings: int = 4  # per radial line
    robot_radius: float = 0.25  # m, where every search starts (the robot's own body)
    max_range: float = 4.0  # m, radial search limit
    spiral_end_radius: float = 2.0  # m, spiral radius after one full turn
    spiral_samples_per_turn: int = 1440  # polyline resolution used to walk a spiral

    def check(self, where: str = "") -> ScanLines:
        """Itself, if its lines can be walked (FieldlocError otherwise): each starts at the
        robot radius and ends beyond it, and no spiral reaches past the radial lines' range.
        build-map and extract hold their confs to it, so a map and features agree."""
        r0, r1, r_max = self.robot_radius, self.spiral_end_radius, self.max_range
        if not 0 <= r0 < r1 <= r_max:
            raise FieldlocError(f"{where}need 0 <= robot_radius < spiral_end_radius <= max_range,"
                                f" got {r0:g}, {r1:g}, {r_max:g}")
        return self

    @property
    def angle_step(self) -> float:
        return 2 * math.pi / self.n_angles

    @property
    def radial_angles(self) -> np.ndarray:
        """Angle (rad) of each radial scan line in the robot frame."""
        return np.arange(self.n_angles) * self.angle_step

    def spiral_phi(self) -> np.ndarray:
        """Turning parameter phi (rad) of the polyline samples, 0..2 pi inclusive."""
        return np.linspace(0.0, 2 * math.pi, self.spiral_samples_per_turn + 1)

    def spiral_radius(self, phi) -> np.ndarray:
        r0, r1 = self.robot_radius, self.spiral_end_radius
        return r0 + (r1 - r0) * np.asarray(phi) / (2 * math.pi)

    def spiral_points(self, direction: int, start_index: int, heading: float = 0.0) -> np.ndarray:
        """Polyline (M, 2) of one spiral, from its start outwards, in the robot frame (or in a
        frame rotated by ``heading``). direction 0 turns counter-clockwise, 1 clockwise."""
        phi = self.spiral_phi()
        r = self.spiral_radius(phi)
        sign = 1.0 if direction == 0 else -1.0
        ang = heading + start_index * self.angle_step + sign * phi
        return np.stack([r * np.cos(ang), r * np.sin(ang)], axis=1)

    def radial_points(self, index: int, step: float) -> np.ndarray:
        """Samples (M, 2) along radial line ``index`` every ``step`` metres."""
        t = np.arange(self.robot_radius, self.max_range + 1e-9, step)
        a = index * self.angle_step
        return np.stack([t * math.cos(a), t * math.sin(a)], axis=1)

    def heading_index(self, theta: float) -> int:
        """The scan-line index shift for a heading (rounded to the angle step)."""
        return int(round(theta / self.angle_step)) % self.n_angles

    def as_dict(self) -> dict:
        return asdict(self)


def rotate_to_heading(rows: np.ndarray, shift: int, axis: int) -> np.ndarray:
    """Scan-line values seen at heading ``shift`` * step from values at heading 0: entry k of
    the result is entry (k + shift) mod n of ``rows`` along ``axis``."""
    return np.roll(rows, -shift, axis=axis)


def bin_points_to_scanlines(points_robot, scanlines: ScanLines | None = None,
                            tolerance: float = 0.05, merge: float = 0.15):
    """Line points from a team's own detector (robot frame, metres, (N, 2)) -> the tables'
    layout: ``radial`` (72, 4) nearest first NaN padded, ``spiral`` (2, 72) NaN if none.

    A point counts as a crossing of a scan line when its perpendicular distance to that line is
    at most ``tolerance`` (m) and it lies between the robot radius and the line's end (max_range
    for radial lines, spiral_end_radius for spirals). Radial crossings are the point's
    projection on the ray; points of one radial line closer than ``merge`` (m) to the previous
    one are taken as the same white line and averaged. A spiral's crossing is the ground radius
    of its nearest qualifying point. Points from detectors that sample lines sparsely leave
    most scan lines empty, which the table matching ignores (Ribeiro et al. 2015: scan lines without
    a crossing are skipped)."""
    sl = scanlines or ScanLines()
    p = np.asarray(points_robot, dtype=float).reshape(-1, 2)
    p = p[np.isfinite(p).all(axis=1)]
    n = sl.n_angles
    radial = np.full((n, sl.max_crossings), np.nan, np.float32)
    spiral = np.full((2, n), np.nan, np.float32)
    if len(p) == 0:
        return radial, spiral
    rho = np.hypot(p[:, 0], p[:, 1])
    beta = np.arctan2(p[:, 1], p[:, 0])
    # radial: every ray within tolerance (near the robot several rays can qualify)
    rel = (beta[:, None] - sl.radial_angles[None, :] + np.pi) % (2 * np.pi) - np.pi  # (N, n)
    perp = rho[:, None] * np.abs(np.sin(rel))
    along = rho[:, None] * np.cos(rel)
    hit = (perp <= tolerance) & (along >= sl.robot_radius) & (along <= sl.max_range)
    pi_, li = np.nonzero(hit)
    if len(li):
        d = along[pi_, li]
        order = np.lexsort((d, li))
        li, d = li[order], d[order]
        # merge crossings of one line closer than `merge` into clusters (mean distance)
        new = np.ones(len(li), bool)
        new[1:] = (li[1:] != li[:-1]) | (np.diff(d) > merge)
        grp = np.cumsum(new) - 1
        cnt = np.bincount(grp)
        dm = np.bincount(grp, d) / cnt
        gl = li[new]
        first = np.searchsorted(gl, gl, side="left")
        rank = np.arange(len(gl)) - first
        keep = rank < sl.max_crossings
        radial[gl[keep], rank[keep]] = dm[keep]
    # spirals: at radius rho the spiral (direction, k) is at angle a_k +- phi(rho)
    r0, r1 = sl.robot_radius, sl.spiral_end_radius
    inside = (rho >= r0) & (rho <= r1)
    phi = 2 * np.pi * (rho - r0) / (r1 - r0)
    cos_psi = 1.0 / np.sqrt(1.0 + ((r1 - r0) / (2 * np.pi * np.maximum(rho, 1e-6))) ** 2)
    for direction, sign in ((0, 1.0), (1, -1.0)):  # the two spiral directions
        rel = (beta[:, None] - sign * phi[:, None] - sl.radial_angles[None, :] + np.pi) % (
            2 * np.pi) - np.pi
        perp = rho[:, None] * np.abs(rel) * cos_psi[:, None]
        ok = (perp <= tolerance) & inside[:, None]
        r_hit = np.where(ok, rho[:, None], np.inf).min(axis=0)
        spiral[direction] = np.where(np.isfinite(r_hit), r_hit, np.nan)
    return radial, spiral
