"""The perspective camera's mount (pitch and roll offsets) and height learnt from a recording.

A humanoid's head camera is projected to the floor with the head angles the robot measures
(head.csv) and the calib.yaml's height; the camera sits in the head a degree or two off its
drawing (``pitch_offset``, ``roll_offset`` of stages.common.perspective_camera), and the
height is measured to a few centimetres. Two degrees of pitch move a line seen 3 m away by
about half a metre. The robot cannot see that error frame by frame, an offline tool with the
whole recording can: every frame whose pose is accepted with confidence >= ``min_confidence``
contributes its lines, and one mount fits them all.

Observations. The extractor keeps every line's end points in the image (``line_ends_px`` of
the features file). A line is straight between its ends in ideal (undistorted) coordinates, so
``samples`` points are taken along it there, one every ``sample_step`` m of its floor length
(at least 2, at most ``max_samples``), and projected to the floor at a candidate mount: the
frame's head pitch and roll plus the calibration's offsets plus (dpitch, droll), the height
plus dheight (``_Projector``). Samples beyond ``max_range`` m of the camera (a pixel spans
decimetres there) are not used. Placed in the field by the frame's pose, each sample's
residual is its signed distance to the field line it is associated with: the nearest centre
line (segment within ``end_margin`` of its ends, or arc) whose direction agrees with the
observed line's within ``direction_tolerance_deg`` (a sample near a crossing belongs to the
line it was seen on, not to the crossing one).

Fit, jointly with the poses and the head angles. The poses were found with the miscalibrated
mount and carry part of its error; a fit holding them leaves that part in the estimate. So the
three mount parameters are estimated together with five unknowns per frame, as
mirror_calibration.py does for the omni mirror: a correction of the frame's pose (x, y, theta)
and of its measured head pitch and roll (head.csv holds what the joint encoders and the IMU
say, with an error of their own per frame; projected with it, far lines scatter unevenly, a
pitch measured too low pushing them out of range or over the horizon and one measured too high
not, which held fixed biases the mount by a few tenths of a degree). Gauss-Newton on the
samples' residuals (point-to-line, Besl and McKay 1992; Chen and Medioni 1992), linearised in
the pose analytically and in the mount and head angles by forward differences, with Gaussian
priors: each pose near the track's (``pose_sigma_xy``, ``pose_sigma_theta_deg``, loose: the
track's error from the miscalibration reaches decimetres), each frame's head angles near
head.csv's (``head_sigma_deg``), consecutive frames' pose corrections differing as a random
walk in time (``drift_xy``, ``drift_theta_deg`` per sqrt(s): the track's error drifts slowly
along the recording, while the error a wrong mount puts into a frame changes with what the
frame sees; without this tie each frame's pose absorbs most of it), and a weak one on the
mount (``mount_sigma``). One step solves the sparse normal equations (block tridiagonal in
the frames, bordered by the mount). Every step re-associates the samples and reweighs them
(iteratively reweighted least squares, Holland and Welsch 1977) with the Cauchy loss, weight
1 / (1 + (r / s)^2), s = max(``min_scale``, 1.4826 * the median absolute residual of the
gated samples); samples farther than ``max_residual`` (later min(max_residual, ``gate_scales``
* s)) from their line weigh nothing.

Starts. Two degrees of pitch put far samples half a metre off, at the spacing of parallel
lines, and a track that fitted the wrong mount is a local minimum with it: the fit runs
``screen_iterations`` steps from every start of a lattice over dpitch and droll
(+-``start_pitch_deg``, +-``start_roll_deg`` in ``start_step_deg`` steps), and the solution
of the lowest robust cost (``_cost``: every sample's Cauchy loss at ``min_scale``, capped at
``max_residual``) runs on to convergence.

Standard errors. A frame's samples share its pose's and head angles' errors and the samples
of one line share its detection's, so the residuals are not independent: the standard errors
are the sandwich (cluster-robust) covariance with frames as clusters (Liang and Zeger 1986),
N^-1 (sum_f g_f g_f^T) N^-1 restricted to the mount, N the normal matrix, g_f frame f's
gradient (its samples' and its own priors').

Reproduced, or not written. The standard errors say how well the samples pin the mount if the
track is right; they cannot say whether it is. A track that held a look-alike place for a
stretch fits a mount that absorbs the error, at standard errors of a few hundredths of a
degree. So the usable frames' first and second halves (in time) are fitted again, each on its
own from every start, and the mount is refused unless they agree within ``REPRODUCIBLE``
(``_halves_agreement``; a camera knocked during the recording fails it too). The check costs
two more fits.

``corrected_calibration`` writes the result into a calib.yaml mapping (pitch_offset,
roll_offset and height replaced; every other key as the input's) with a ``calibration`` record
(calibration_record.py); ``write_corrected_calib`` writes it atomically and never over the
recording's own calib.yaml.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..common.errors import FieldlocError
from ..common.head_angles import head_at
from ..common.perspective_camera import MAX_MOUNT_OFFSET, PerspectiveCamera, head_rotation
from .calibration_record import (
    cauchy_scale,
    cauchy_weights,
    features_inputs,
    plain,
    record_header,
    track_arrays,
    usable_rows,
    write_calib_file,
)

log = logging.getLogger(__name__)

DEFAULTS = {
    "min_confidence": 0.9,  # frames whose pose is less sure are not used
    "min_frames": 10,  # fewer usable frames: refused
    "sample_step": 0.2,  # m of floor length between a line's samples
    "max_samples": 12,  # samples per line at most
    "max_range": 6.0,  # m: samples farther from the camera are not used
    "direction_tolerance_deg": 25.0,  # an observed line and its field line agree this well
    "end_margin": 0.2,  # m: a sample this far beyond a field line's end still belongs to it
    "max_residual": 0.5,  # m: samples farther from their line weigh nothing
    "gate_scales": 5.0,  # later, the gate: this many Cauchy scales (up to max_residual)
    "min_scale": 0.02,  # m, floor of the Cauchy scale
    "iterations": 200,  # Gauss-Newton / IRLS iterations at most
    "pose_sigma_xy": 1.0,  # m, spread of a frame's position about the track's
    "pose_sigma_theta_deg": 10.0,  # deg, spread of its heading about the track's
    "head_sigma_deg": 0.5,  # deg, spread of a frame's head.csv pitch and roll about the truth
    "drift_xy": 0.05,  # m per sqrt(s): consecutive pose corrections differ as a random walk
    "drift_theta_deg": 1.0,  # deg per sqrt(s): ... and in heading
    "mount_sigma": 0.2,  # rad and m: the weak prior on the mount's correction
    "start_pitch_deg": 4.0,  # the fit starts from dpitch within +- this (deg) ...
    "start_roll_deg": 2.0,  # ... and droll within +- this (deg) ...
    "start_step_deg": 2.0,  # ... in these steps
    "screen_iterations": 25,  # each start runs this many steps; the best then converges
}
# forward-difference steps of the mount's Jacobian: rad for the angles, m for the height
_STEP = np.array([1e-4, 1e-4, 1e-4])
# a fitted height below this share of the calibration's is not a camera's (a diverged fit)
MIN_HEIGHT_SHARE = 0.5
# the shortest time between frames the random walk of the pose corrections assumes (s)
MIN_STEP_S = 1e-3
# a mount is written only when the two halves of the recording, fitted each on its own, agree
# within these (rad, m: _halves_agreement). A mount 1 deg or 3 cm off puts lines 3 m away
# 5-7 cm off, more than the miscalibration it corrects leaves after a good fit. On the
# tuning walks (seeds 200-223, docs/recording-calibration.md) good fits' halves differed by
# up to 0.64 deg and 2.8 cm (NAO; KidSize 0.2 deg, 0.4 cm), a fit to a track wrong in part
# by 15.8 deg and 140 cm
REPRODUCIBLE = (math.radians(1.0), 0.03)


@dataclass
class MountEstimate:
    """The mount's correction learnt from a recording: dpitch, droll (rad) to add to the
    calibration's pitch_offset and roll_offset, dheight (m) to add to its height; with the
    values that result and their standard errors (module doc)."""

    correction: np.ndarray  # (3,) dpitch, droll (rad), dheight (m)
    standard_error: np.ndarray  # (3,) rad, rad, m
    pitch_offset: float  # rad, the calibration's plus dpitch
    roll_offset: float  # rad
    height: float  # m
    frames: int = 0
    lines: int = 0
    samples: int = 0  # used (gated in) in the last iteration
    residual_rms: float = math.nan  # m, of the used samples
    scale: float = math.nan  # m, the Cauchy scale of the last iteration
    fit: dict = field(default_factory=dict)
    conf: dict = field(default_factory=dict)
    inputs: dict = field(default_factory=dict)

    def summary(self) -> dict:
        se = self.standard_error
        return {
            "pitch_offset_rad": round(float(self.pitch_offset), 5),
            "roll_offset_rad": round(float(self.roll_offset), 5),
            "height_m": round(float(self.height), 4),
            "standard_error": {"pitch_offset_rad": round(float(se[0]), 5),
                               "roll_offset_rad": round(float(se[1]), 5),
                               "height_m": round(float(se[2]), 4)},
            "correction": {"pitch_offset_rad": round(float(self.correction[0]), 5),
                           "roll_offset_rad": round(float(self.correction[1]), 5),
                           "height_m": round(float(self.correction[2]), 4)},
            "frames": int(self.frames),
            "lines": int(self.lines),
            "samples": int(self.samples),
            "residual_rms_m": round(float(self.residual_rms), 4),
        }


# ---------------------------------------------------------------------------- observations


@dataclass
class _Samples:
    """Every usable frame's line samples, flattened: ideal normalised image coordinates
    ``xy`` (n, 2), their frame index ``frame`` (n,) and line index ``line`` (n,); per frame its
    head pose (pitch, roll, yaw, height, x, y) and the track's pose."""

    xy: np.ndarray
    frame: np.ndarray
    line: np.ndarray
    head: np.ndarray  # (F, 6) pitch, roll, yaw, height, x, y of the camera (offsets not added)
    poses: np.ndarray  # (F, 3) the track's poses
    names: list
    stamps: np.ndarray  # (F,) s


def _samples(camera: PerspectiveCamera, features, head, arr: dict, c: dict) -> _Samples:
    """The line samples of the usable frames (module doc). ``head``: head_angles.head_table of
    the dataset (None: the nominal angles)."""
    have = set(features.names)
    stamp_of = dict(zip(features.names, (float(s) for s in features.stamps)))
    xy, frame, line, heads, poses, names, stamps = [], [], [], [], [], [], []
    n_lines = 0
    for i in usable_rows(arr, float(c["min_confidence"])):
        name = arr["names"][i]
        if name not in have:
            continue
        fr = features.frame(name)
        ends_px = np.asarray(fr.get("line_ends_px", np.zeros((0, 4))), float).reshape(-1, 4)
        ends_m = np.asarray(fr.get("line_ends", np.zeros((0, 4))), float).reshape(-1, 4)
        if len(ends_px) == 0 or len(ends_m) != len(ends_px):
            continue
        hp = head_at(head, stamp_of[name])
        ideal = camera.undistort_normalized(camera._to_normalized(ends_px.reshape(-1, 2)))
        ideal = ideal.reshape(-1, 2, 2)
        length = np.hypot(ends_m[:, 2] - ends_m[:, 0], ends_m[:, 3] - ends_m[:, 1])
        f = len(poses)
        kept = 0
        for k in range(len(ends_px)):
            if not (np.all(np.isfinite(ideal[k])) and math.isfinite(length[k])):
                continue
            n = int(min(max(math.ceil(length[k] / float(c["sample_step"])) + 1, 2),
                        int(c["max_samples"])))
            t = np.linspace(0.0, 1.0, n)[:, None]
            xy.append(ideal[k, 0] * (1 - t) + ideal[k, 1] * t)
            frame.append(np.full(n, f))
            line.append(np.full(n, n_lines))
            n_lines += 1
            kept += 1
        if not kept:
            continue
        heads.append([hp.get("pitch", camera.pitch), hp.get("roll", camera.roll),
                      hp.get("yaw", camera.yaw), hp.get("height", camera.height),
                      hp.get("x", camera.position[0]), hp.get("y", camera.position[1])])
        poses.append([arr["x"][i], arr["y"][i], arr["theta"][i]])
        names.append(name)
        stamps.append(stamp_of[name])
    if not poses:
        return _Samples(np.zeros((0, 2)), np.zeros(0, int), np.zeros(0, int), np.zeros((0, 6)),
                        np.zeros((0, 3)), [], np.zeros(0))
    return _Samples(np.concatenate(xy), np.concatenate(frame), np.concatenate(line),
                    np.asarray(heads, float), np.asarray(poses, float), names,
                    np.asarray(stamps, float))


class _Projector:
    """Floor points (robot frame) of the samples at a mount correction (dpitch, droll,
    dheight), as the calibration's camera with its offsets and height so corrected projects
    them (PerspectiveCamera.pixel_to_floor on ideal coordinates); ``head`` (F, 2): each
    frame's own correction of its head.csv pitch and roll (None: none)."""

    def __init__(self, camera: PerspectiveCamera, s: _Samples):
        self.camera = camera
        self.s = s
        self.rays = np.concatenate([s.xy, np.ones((len(s.xy), 1))], axis=1)

    def __call__(self, m, head=None) -> np.ndarray:
        s, cam = self.s, self.camera
        dp, dr, dh = (float(v) for v in m)
        head = np.zeros((len(s.head), 2)) if head is None else head
        R = np.stack([head_rotation(h[2], h[0] + cam.pitch_offset + dp + e[0],
                                    h[1] + cam.roll_offset + dr + e[1])
                      for h, e in zip(s.head, head)])
        ray = np.einsum("nij,nj->ni", R[s.frame], self.rays)
        down = ray[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(down < -1e-6, (s.head[s.frame, 3] + dh) / -down, np.nan)
        return ray[:, :2] * t[:, None] + s.head[s.frame, 4:6]


def _place(floor: np.ndarray, poses: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """Robot-frame floor points into the field frame by their frames' poses."""
    p = poses[frame]
    c, sn = np.cos(p[:, 2]), np.sin(p[:, 2])
    return np.stack([p[:, 0] + c * floor[:, 0] - sn * floor[:, 1],
                     p[:, 1] + sn * floor[:, 0] + c * floor[:, 1]], axis=1)


def _line_directions(P: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Unit direction (n, 2) of each sample's observed line in the field frame (its first to
    its last sample)."""
    n_lines = int(line.max()) + 1 if len(line) else 0
    first = np.full(n_lines, -1)
    last = np.zeros(n_lines, int)
    idx = np.arange(len(line))
    first[line[::-1]] = idx[::-1]
    last[line] = idx
    d = P[last[line]] - P[first[line]]
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return np.divide(d, n, out=np.zeros_like(d), where=n > 0)


def associate(field, P: np.ndarray, u: np.ndarray, c: dict
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each field point P (n, 2) of an observed line of direction u (n, 2): its signed
    distance r (n,) to the nearest field centre line of agreeing direction (module doc), that
    line's unit normal n (n, 2) with r = n . (P - a point of the line) to first order, and
    whether there is one (n,)."""
    cos_tol = math.cos(math.radians(float(c["direction_tolerance_deg"])))
    margin = float(c["end_margin"])
    best = np.full(len(P), np.inf)
    r = np.zeros(len(P))
    normal = np.zeros((len(P), 2))
    for (x0, y0), (x1, y1) in field.segments:
        d = np.array([x1 - x0, y1 - y0])
        L = float(np.hypot(*d))
        d = d / L
        nrm = np.array([-d[1], d[0]])
        rel = P - (x0, y0)
        along = rel @ d
        dist = rel @ nrm
        ok = (along >= -margin) & (along <= L + margin) & (np.abs(u @ d) >= cos_tol)
        take = ok & (np.abs(dist) < best)
        best = np.where(take, np.abs(dist), best)
        r = np.where(take, dist, r)
        normal[take] = nrm
    for cx, cy, rad, a0, sweep in field.arcs:
        v = P - (cx, cy)
        rho = np.hypot(v[:, 0], v[:, 1])
        phi = np.arctan2(v[:, 1], v[:, 0])
        tangent = np.stack([-np.sin(phi), np.cos(phi)], axis=1)
        inside = np.ones(len(P), bool) if sweep >= 2 * math.pi - 1e-9 else (
            np.mod(phi - a0 + margin / rad, 2 * math.pi) <= sweep + 2 * margin / rad)
        ok = inside & (np.abs(np.sum(u * tangent, axis=1)) >= cos_tol) & (rho > 1e-9)
        dist = rho - rad
        take = ok & (np.abs(dist) < best)
        best = np.where(take, np.abs(dist), best)
        r = np.where(take, dist, r)
        with np.errstate(divide="ignore", invalid="ignore"):
            normal[take] = v[take] / rho[take, None]
    return r, normal, np.isfinite(best)


# ---------------------------------------------------------------------------- the fit


def _cost(field, project, s: _Samples, m, poses, head, c: dict) -> float:
    """The robust cost of a solution, comparable between starts: the Cauchy loss at scale
    ``min_scale`` of every sample's distance to its line, capped at ``max_residual`` (also
    for samples beyond ``max_range``, above the horizon or with no line of their
    direction)."""
    floor = project(m, head)
    reach = np.hypot(*(floor - s.head[s.frame, 4:6]).T)
    P = _place(floor, poses, s.frame)
    ok = (reach <= float(c["max_range"])) & np.all(np.isfinite(P), axis=1)
    Pz = np.where(ok[:, None], P, 0.0)
    r, _n, has = associate(field, Pz, _line_directions(Pz, s.line), c)
    cap = float(c["max_residual"])
    r = np.where(ok & has, np.minimum(np.abs(r), cap), cap)
    return float(np.sum(np.log1p((r / float(c["min_scale"])) ** 2)))


def _plausible(camera: PerspectiveCamera, m) -> bool:
    """Whether the mount corrected by m is one a camera can have: offsets within
    MAX_MOUNT_OFFSET, the height more than MIN_HEIGHT_SHARE of the calibration's."""
    return (max(abs(camera.pitch_offset + m[0]), abs(camera.roll_offset + m[1]))
            <= MAX_MOUNT_OFFSET and camera.height + m[2] > MIN_HEIGHT_SHARE * camera.height)


def _starts(c: dict) -> list[np.ndarray]:
    """The mount corrections the fit starts from (module doc): a lattice over dpitch and
    droll, dheight 0."""
    def lattice(half_deg, step_deg):
        n = int(round(float(half_deg) / float(step_deg))) if float(step_deg) > 0 else 0
        return np.radians(float(step_deg) * np.arange(-n, n + 1))

    return [np.array([dp, dr, 0.0])
            for dp in lattice(c["start_pitch_deg"], c["start_step_deg"])
            for dr in lattice(c["start_roll_deg"], c["start_step_deg"])]


def _prior_matrix(s: _Samples, c: dict):
    """The priors (module doc) as a sparse information matrix over [mount (3), frame 0 (5),
    frame 1 (5), ...]: the mount's correction about 0, each frame's pose correction about the
    track's, its head angles' correction about head.csv's, and consecutive pose corrections'
    differences as a random walk in time."""
    from scipy import sparse

    F = len(s.poses)
    s_xy, s_th = float(c["pose_sigma_xy"]), math.radians(float(c["pose_sigma_theta_deg"]))
    s_head = math.radians(float(c["head_sigma_deg"]))
    own = np.array([1 / s_xy**2, 1 / s_xy**2, 1 / s_th**2, 1 / s_head**2, 1 / s_head**2])
    rows, cols, vals = [], [], []

    def add(i, j, v):
        rows.append(i)
        cols.append(j)
        vals.append(v)

    for k in range(3):
        add(k, k, 1.0 / float(c["mount_sigma"]) ** 2)
    for f in range(F):
        for k in range(5):
            add(3 + 5 * f + k, 3 + 5 * f + k, own[k])
    walk = np.array([float(c["drift_xy"]) ** 2, float(c["drift_xy"]) ** 2,
                     math.radians(float(c["drift_theta_deg"])) ** 2])
    dt = np.maximum(np.diff(s.stamps), MIN_STEP_S)
    for f in range(F - 1):
        w = 1.0 / (walk * dt[f])
        for k in range(3):
            i, j = 3 + 5 * f + k, 3 + 5 * (f + 1) + k
            add(i, i, w[k])
            add(j, j, w[k])
            add(i, j, -w[k])
            add(j, i, -w[k])
    n = 3 + 5 * F
    return sparse.csc_matrix((vals, (rows, cols)), shape=(n, n))


def _walk_diagonal(prior, F: int) -> np.ndarray:
    """(F, 5) the random walk's share of the prior's diagonal per frame unknown (the part of
    the prior that ties a frame to its neighbours, not to its own measurements)."""
    out = np.zeros((F, 5))
    if F > 1:
        for k in range(3):
            i = 3 + 5 * np.arange(F - 1) + k
            w = -np.asarray(prior[i, i + 5]).ravel()
            out[:-1, k] += w
            out[1:, k] += w
    return out


def _joint_fit(field, project: _Projector, s: _Samples, c: dict, start, iterations: int,
               poses=None, head=None):
    """The mount's correction, the frames' poses and their head angles' corrections by
    Gauss-Newton with IRLS weights from the mount correction ``start`` and ``poses`` (None:
    the track's) and ``head`` (None: head.csv's), at most ``iterations`` steps (module doc).
    Returns (m, poses, head corrections, standard errors, samples used, rms, scale,
    iterations done)."""
    from scipy import sparse
    from scipy.sparse.linalg import splu

    F = len(s.poses)
    m = np.array(start, float)
    budget = int(iterations)
    poses = s.poses.copy() if poses is None else np.array(poses, float)
    head = np.zeros((F, 2)) if head is None else np.array(head, float)
    prior = _prior_matrix(s, c)
    max_res, max_range = float(c["max_residual"]), float(c["max_range"])
    gate = max_res
    iterations = 0
    frame = s.frame
    n = 3 + 5 * F
    # where each sample's Jacobian entries go in the unknowns: the mount, its frame's block
    cols = np.concatenate([np.tile(np.arange(3), (len(frame), 1)),
                           3 + 5 * frame[:, None] + np.arange(5)], axis=1)  # (N, 8)
    for _ in range(budget):
        iterations += 1
        floor = project(m, head)
        reach = np.hypot(*(floor - s.head[frame, 4:6]).T)
        P = _place(floor, poses, frame)
        good = (reach <= max_range) & np.all(np.isfinite(P), axis=1)
        Pz = np.where(good[:, None], P, 0.0)
        r, nrm, has = associate(field, Pz, _line_directions(Pz, s.line), c)
        good &= has
        inside = good & (np.abs(r) <= gate)
        if inside.sum() < 30:
            raise FieldlocError(
                f"only {int(inside.sum())} line samples lie within {gate:g} m of a field line:"
                " the poses or the calibration are too far off")
        scale = cauchy_scale(r, inside, c["min_scale"])
        s2 = scale * scale
        w = cauchy_weights(r, scale, inside)
        # Jacobians: by the mount (forward differences of the projection; by a frame's head
        # angles the same as by the mount's), by the pose
        B = np.zeros((len(r), 3))
        for k in range(3):
            dm = np.array(m, float)
            dm[k] += _STEP[k]
            Pk = _place(project(dm, head), poses, frame)
            B[inside, k] = np.sum(nrm * (Pk - P), axis=1)[inside] / _STEP[k]
        inside &= np.all(np.isfinite(B), axis=1)  # a step put the sample over the horizon
        B[~inside] = 0.0
        w[~inside] = 0.0
        rot = P - poses[frame, :2]
        J = np.stack([nrm[:, 0], nrm[:, 1], nrm[:, 1] * rot[:, 0] - nrm[:, 0] * rot[:, 1],
                      B[:, 0], B[:, 1]], 1)
        J[~inside] = 0.0
        rw = np.where(inside, r, 0.0)
        row = np.concatenate([B, J], axis=1)  # (N, 8): d r / d unknowns at ``cols``
        idx = np.flatnonzero(inside)
        ri, ci = cols[idx][:, :, None], cols[idx][:, None, :]
        vals = (row[idx][:, :, None] * row[idx][:, None, :]) * w[idx, None, None]
        N = sparse.csc_matrix((vals.ravel(), (np.broadcast_to(ri, vals.shape).ravel(),
                                              np.broadcast_to(ci, vals.shape).ravel())),
                              shape=(n, n))
        dev = np.concatenate([poses - s.poses, head], axis=1)
        dev[:, 2] = np.remainder(dev[:, 2] + math.pi, 2 * math.pi) - math.pi
        state = np.r_[m, dev.ravel()]
        N = N + prior * s2
        grad = np.zeros(n)
        np.add.at(grad, cols[idx], row[idx] * (w[idx] * rw[idx])[:, None])
        rhs = -grad - prior @ state * s2
        try:
            solver = splu(sparse.csc_matrix(N))
            delta = solver.solve(rhs)
        except RuntimeError as e:  # no unknown can be singular under the priors but by NaN
            raise FieldlocError(f"the mount fit's normal equations are singular ({e})"
                                ) from None
        if not np.all(np.isfinite(delta)):
            raise FieldlocError("the mount fit diverged (a step is not finite)")
        m = m + delta[:3]
        d = delta[3:].reshape(F, 5)
        poses += d[:, :3]
        head += d[:, 3:]
        step = float(np.max(np.hypot(d[:, 0], d[:, 1])))
        gate = min(max_res, float(c["gate_scales"]) * scale)
        log.debug("mount fit %d: m %s, scale %.4f, samples %d, pose step %.4f", iterations,
                  np.round(m, 5), scale, int(inside.sum()), step)
        if np.max(np.abs(delta[:3])) < 1e-5 and step < 1e-3:
            break
    # the frame-clustered sandwich: each frame's gradient (its samples' and its own priors':
    # the head angles it was measured with are its data too), through the normal equations
    G = np.zeros((n, F))
    frame_of = frame[idx]
    contrib = row[idx] * (w[idx] * rw[idx])[:, None]
    for k in range(8):
        np.add.at(G, (cols[idx][:, k], frame_of), contrib[:, k])
    own = prior.diagonal()[3:].reshape(F, 5) - _walk_diagonal(prior, F)
    for k in range(5):
        G[3 + 5 * np.arange(F) + k, np.arange(F)] += own[:, k] * dev[:, k] * s2
    X = solver.solve(G)[:3]
    cov = X @ X.T
    used = int(inside.sum())
    rms = math.sqrt(float(np.sum(r[inside] ** 2)) / max(used, 1))
    return (m, poses, head, np.sqrt(np.maximum(np.diag(cov), 0.0)), used, rms, scale,
            iterations)


def _fit(field, camera: PerspectiveCamera, s: _Samples, c: dict):
    """The joint fit (``_joint_fit``'s results) from the start of the lowest robust cost
    after ``screen_iterations`` steps from each of ``_starts`` (module doc)."""
    project = _Projector(camera, s)
    screened = []
    for start in _starts(c):
        try:
            m, poses, head_fix, *_rest = _joint_fit(field, project, s, c, start,
                                                    int(c["screen_iterations"]))
        except FieldlocError:  # a start too far off for any line to be associated
            continue
        if not _plausible(camera, m):
            continue
        screened.append((_cost(field, project, s, m, poses, head_fix, c), m, poses, head_fix))
    if not screened:
        raise FieldlocError("no start of the mount fit associates enough line samples: the"
                            " poses or the calibration are too far off")
    _cost_best, m, poses, head_fix = min(screened, key=lambda t: t[0])
    return _joint_fit(field, project, s, c, m, int(c["iterations"]), poses, head_fix)


def _subset(s: _Samples, frames: np.ndarray) -> _Samples:
    """The samples of the usable frames ``frames`` (indices, in order), renumbered."""
    keep = np.isin(s.frame, frames)
    new_frame = np.full(len(s.poses), -1)
    new_frame[frames] = np.arange(len(frames))
    _u, line = np.unique(s.line[keep], return_inverse=True)
    return _Samples(s.xy[keep], new_frame[s.frame[keep]], line.reshape(-1), s.head[frames],
                    s.poses[frames], [s.names[i] for i in frames], s.stamps[frames])


def _halves_agreement(field, camera: PerspectiveCamera, s: _Samples, c: dict) -> dict:
    """The mount fitted on the first and on the second half of the usable frames (in time),
    each on its own from every start: a recording whose track is right where it is used
    gives both halves the mount of the whole; one whose track is wrong in part (a look-alike
    place held for a stretch) fits a mount that absorbs the error, which the other half does
    not share; so does a camera knocked during the recording. Raises FieldlocError when they
    differ by more than REPRODUCIBLE, when a half cannot be fitted, or when a half has fewer
    than ``min_frames`` frames. Returns both halves' corrections and their largest differences
    (deg, deg, m)."""
    F = len(s.poses)
    n_min = int(c["min_frames"])
    if F < 2 * n_min:
        raise FieldlocError(
            f"only {F} frames hold lines and a pose with confidence >="
            f" {float(c['min_confidence']):g}: too few to check the mount on both halves of"
            f" the recording (at least {2 * n_min})")
    fits = []
    for frames in (np.arange(F // 2), np.arange(F // 2, F)):
        try:
            fits.append(_fit(field, camera, _subset(s, frames), c)[0])
        except FieldlocError as e:
            raise FieldlocError(f"the mount could not be fitted on one half of the recording"
                                f" alone ({e})") from None
    diff = np.abs(fits[0] - fits[1])
    shown = (f"pitch {math.degrees(diff[0]):.2f} deg, roll {math.degrees(diff[1]):.2f} deg,"
             f" height {100 * diff[2]:.1f} cm")
    if not (diff[0] <= REPRODUCIBLE[0] and diff[1] <= REPRODUCIBLE[0]
            and diff[2] <= REPRODUCIBLE[1]):
        raise FieldlocError(
            f"the two halves of the recording give mounts {shown} apart: the track is likely"
            " wrong in part (a calibration fitted to it would be too); not written")
    return {"halves": [[round(float(v), 5) for v in f] for f in fits],
            "halves_difference": [round(math.degrees(float(diff[0])), 4),
                                  round(math.degrees(float(diff[1])), 4),
                                  round(float(diff[2]), 4)]}


def estimate_mount(field, camera: PerspectiveCamera, features, track, head=None,
                   conf: dict | None = None) -> MountEstimate:
    """The mount's correction (module doc) from every frame of a recording whose pose is
    accepted with confidence >= ``min_confidence``. ``field``: the FieldModel; ``camera``: the
    PerspectiveCamera of the calib.yaml the features were extracted with; ``features``: the
    recording's FeaturesFile (perspective: ``line_ends_px``, ``line_ends``); ``track``: a
    PoseTrack or its arrays; ``head``: head_angles.head_table of the dataset (None: nominal
    angles); ``conf``: overrides of DEFAULTS. Raises FieldlocError when too few frames or
    samples are usable."""
    c = dict(DEFAULTS, **(conf or {}))
    unknown = set(c) - set(DEFAULTS)
    if unknown:
        raise FieldlocError(f"mount calibration: unknown conf key '{sorted(unknown)[0]}'")
    if getattr(features, "camera_kind", "perspective") != "perspective":
        raise FieldlocError("a mount calibration from a recording needs a perspective"
                            " recording's features")
    if head is not None and "height" in head[1]:
        raise FieldlocError("head.csv records the camera height of every frame, which the"
                            " calib.yaml's height does not set: the height cannot be learnt"
                            " into calib.yaml")
    arr = track_arrays(track, field.is_point_symmetric())
    s = _samples(camera, features, head, arr, c)
    n_min = int(c["min_frames"])
    if len(s.poses) < n_min:
        raise FieldlocError(
            f"only {len(s.poses)} frames hold lines and a pose with confidence >="
            f" {float(c['min_confidence']):g}: too few to calibrate the mount from (at least"
            f" {n_min})")
    m, poses, head_fix, se, used, rms, scale, iterations = _fit(field, camera, s, c)
    moves = np.hypot(*(poses[:, :2] - s.poses[:, :2]).T)
    pitch_offset = camera.pitch_offset + float(m[0])
    roll_offset = camera.roll_offset + float(m[1])
    height = camera.height + float(m[2])
    if not _plausible(camera, m):
        raise FieldlocError(
            f"the estimated mount (pitch_offset {pitch_offset:+.3f}, roll_offset"
            f" {roll_offset:+.3f} rad, height {height:.3f} m) is beyond a camera's mount:"
            " refusing to write a calibration from it")
    halves = _halves_agreement(field, camera, s, c)
    return MountEstimate(
        correction=m, standard_error=se, pitch_offset=pitch_offset, roll_offset=roll_offset,
        height=height, frames=len(s.poses), lines=int(len(np.unique(s.line))),
        samples=used, residual_rms=rms, scale=scale,
        fit={"iterations": iterations,
             "pose_shift_median_m": round(float(np.median(moves)), 4),
             "pose_shift_max_m": round(float(np.max(moves)), 4),
             "head_correction_rms_deg": [round(math.degrees(float(v)), 4) for v in
                                         np.sqrt(np.mean(head_fix**2, axis=0))],
             **halves},
        conf=c, inputs=features_inputs(features))


# ---------------------------------------------------------------------------- calib.yaml


def corrected_calibration(calib: dict, estimate: MountEstimate, *, source: str,
                          sources: dict | None = None) -> dict:
    """calib.yaml's content (``calib``, a perspective mapping) with pitch_offset, roll_offset
    and height replaced by ``estimate``'s and every other key kept, and a ``calibration``
    record of how it was made (calibration_record.record_header: method ``recording``, the
    source and sources, the conf) with the estimates, their standard errors, the frames,
    lines and samples used, the residual rms, and the values it replaces (``replaced``). The
    calibration record the input held, if any, is kept under ``previous``."""
    if not isinstance(calib, dict) or calib.get("kind") != "perspective":
        raise FieldlocError("a mount calibration from a recording corrects a perspective"
                            " calib.yaml only")
    PerspectiveCamera.from_dict(calib, "calib.yaml")
    out = {k: v for k, v in calib.items() if k != "calibration"}
    out["height"] = round(float(estimate.height), 5)
    out["pitch_offset"] = round(float(estimate.pitch_offset), 6)
    out["roll_offset"] = round(float(estimate.roll_offset), 6)
    record = {
        **record_header(source=source, inputs=estimate.inputs, sources=sources,
                        conf=estimate.conf),
        "model": "mount",
        **estimate.summary(),
        "fit": {k: plain(v) for k, v in estimate.fit.items()},
        "replaced": {k: round(float(calib.get(k, 0.0)), 6)
                     for k in ("height", "pitch_offset", "roll_offset")},
    }
    if isinstance(calib.get("calibration"), dict):
        record["previous"] = calib["calibration"]
    out["calibration"] = record
    return out


def write_corrected_calib(path, calib_dict: dict, *, dataset_calib=None) -> Path:
    """Write ``calib_dict`` (``corrected_calibration``'s) as a calib.yaml at ``path``,
    atomically; never over the recording's own calib.yaml (calibration_record)."""
    return write_calib_file(path, calib_dict, PerspectiveCamera.from_dict,
                            dataset_calib=dataset_calib)
