"""The SURF template paper's white-point table Dm(x, y, theta) and its matching error (eq. 1).

Dm(x, y, theta) is the set of polar white-line points (r_m, phi_m) a robot at (x, y) with
heading theta sees: where each ray from the robot, at robot angle phi, crosses a line's centre
line, every crossing up to ``max_range`` (not only the first few the radial scan lines of the
map keep). It is the radial table of Ribeiro et al. (2015) (tables.radial_table: ray-segment and
ray-circle intersections, crossings closer than the line width merged into one as a camera sees one
white run) at a finer angle step (``angle_step_deg``, default 1 deg against the map's 5) and with
room for every crossing. Headings are index rotations of it: the table built at heading
theta0 holds the points of heading theta0 + h x step in its angle bins shifted by h.

Eq. 1, the matching error of a query Dq = {(r_q, phi_q)} (white points the robot extracted, in
its polar frame) against Dm(x, y, theta):

    E(x, y, theta) = sum_i  min_{j: phi_m_j = phi_q_i} |r_q_i - r_m_j|,   or e_none where no
                                                                         phi_m_j = phi_q_i

"phi_q = phi_m" is read on the table's angle bins: a query point falls in the bin of its angle
rounded to the step. ``e_none`` (m) is the penalty of a query point whose bin holds no table
point; the paper gives no value, 1 m is ours (about the error of a point matched to the wrong
line of a 2 m line spacing half-way).

Computed on the fly for the region a query needs (``region_grid``: cells around a pose), not
stored in the map: at 1 deg with all crossings the whole table is two orders of magnitude the
map's radial table (docs/manual.md "The template method": its size for msl-2015), and the paper's
comparison only ever reads it around one pose.
"""

from __future__ import annotations

import math

import numpy as np

from ..common.errors import FieldlocError
from ..common.field import FieldModel
from ..common.map_file import Grid
from ..common.scanlines import NO_HIT_MM, ScanLines
from .tables import radial_table

E_NONE = 1.0  # m, eq. 1's penalty of a query point with no table point at its angle


def region_grid(x: float, y: float, half_size: float, step: float) -> Grid:
    """Cells of ``step`` m centred on (x, y), covering +-``half_size`` (the centre is a cell)."""
    if not (step > 0 and half_size >= 0):
        raise FieldlocError(f"region needs step > 0 and half_size >= 0, not {step}, {half_size}")
    n = int(math.floor(half_size / step + 1e-9))
    return Grid(origin=(x - n * step, y - n * step), resolution=float(step),
                shape=(2 * n + 1, 2 * n + 1))


def white_point_table(fm: FieldModel, grid: Grid, heading: float = 0.0, *,
                      angle_step_deg: float = 1.0, robot_radius: float = 0.25,
                      max_range: float = 4.0) -> np.ndarray:
    """Dm over ``grid``'s cells at ``heading``: (ny, nx, n_angles, K) float32 radii (m), inf
    where a bin holds fewer than K points; bin k is robot angle k x step. Every crossing is
    kept (K is the most any ray of the grid has)."""
    n = 360.0 / float(angle_step_deg)
    if not (abs(n - round(n)) < 1e-9 and round(n) >= 4):
        raise FieldlocError(f"angle_step_deg must divide 360 (and be <= 90), not {angle_step_deg}")
    # room for every crossing a ray can have: each segment once, each arc twice
    keep = max(len(fm.segments) + 2 * len(fm.arcs), 1)
    sl = ScanLines(n_angles=int(round(n)), max_crossings=keep, robot_radius=float(robot_radius),
                   max_range=float(max_range))
    mm = radial_table(fm, grid, sl, heading)  # (n_angles, keep, ny, nx) uint16 mm
    used = int(np.max(np.sum(mm != NO_HIT_MM, axis=1))) if mm.size else 0
    mm = mm[:, : max(used, 1)]
    r = np.where(mm == NO_HIT_MM, np.inf, mm.astype(np.float32) / np.float32(1000.0))
    return np.ascontiguousarray(np.transpose(r, (2, 3, 0, 1)))


def query_bins(points_robot: np.ndarray, n_angles: int) -> tuple[np.ndarray, np.ndarray]:
    """(r (Q,) m, angle bin (Q,)) of white points given in the robot frame (x, y)."""
    p = np.asarray(points_robot, float).reshape(-1, 2)
    p = p[np.all(np.isfinite(p), axis=1)]
    r = np.hypot(p[:, 0], p[:, 1])
    phi = np.arctan2(p[:, 1], p[:, 0])
    b = np.rint(phi / (2 * math.pi / n_angles)).astype(np.int64) % n_angles
    return r, b


def matching_error(table: np.ndarray, r_q: np.ndarray, bin_q: np.ndarray,
                   shifts=(0,), e_none: float = E_NONE) -> np.ndarray:
    """Eq. 1 for every cell of ``table`` (white_point_table) and every heading shift h (bins:
    heading = the table's heading + h x step): (len(shifts), ny, nx)."""
    if not e_none >= 0:
        raise FieldlocError(f"e_none must be >= 0 (m), not {e_none}")
    ny, nx, n, _k = table.shape
    r_q = np.asarray(r_q, np.float32)
    bin_q = np.asarray(bin_q, np.int64)
    out = np.zeros((len(shifts), ny, nx))
    for s, h in enumerate(shifts):
        rows = table[:, :, (bin_q + int(h)) % n, :]  # (ny, nx, Q, K)
        d = np.min(np.abs(rows - r_q[None, None, :, None]), axis=-1)  # inf: no point in bin
        out[s] = np.sum(np.where(np.isfinite(d), d, np.float32(e_none)), axis=-1)
    return out


def error_surface(fm: FieldModel, pose, points_robot: np.ndarray, *, half_size: float = 1.5,
                  step: float = 0.1, dtheta_deg: float = 30.0, angle_step_deg: float = 1.0,
                  e_none: float = E_NONE, robot_radius: float = 0.25,
                  max_range: float = 4.0) -> dict:
    """Figure 3 of the SURF template paper: eq. 1 of the white points ``points_robot`` (robot frame)
    against Dm around ``pose`` (x, y, theta): ``xy`` (ny, nx) over the cells (dx, dy) at the pose's
    heading, ``theta`` (H,) over heading offsets at the pose's position, ``xyt`` (H, ny, nx)
    over all three, with their axes ``dx``, ``dy`` (m) and ``dtheta`` (rad)."""
    x, y, th = (float(v) for v in pose)
    grid = region_grid(x, y, half_size, step)
    table = white_point_table(fm, grid, th, angle_step_deg=angle_step_deg,
                              robot_radius=robot_radius, max_range=max_range)
    n = table.shape[2]
    r, b = query_bins(points_robot, n)
    m = int(math.floor(float(dtheta_deg) / float(angle_step_deg) + 1e-9))
    shifts = np.arange(-m, m + 1)
    xyt = matching_error(table, r, b, shifts, e_none)
    c = grid.shape[0] // 2
    return {"xy": xyt[m], "theta": xyt[:, c, c], "xyt": xyt, "dx": grid.xs - x, "dy": grid.ys - y,
            "dtheta": shifts * math.radians(float(angle_step_deg)), "points": len(r),
            "table_bytes_per_cell": table.shape[2] * table.shape[3] * 2}
