"""The omni mirror's distance calibration learnt from a whole recording.

A catadioptric camera's calib.yaml maps image radius r to floor distance f(r); a team's
mirror table read by hand puts a line at true distance D at an observed d = D + e(d), with e
smooth in d (minho-distance: 4-16 cm from 1 to 2 m). radial_correction.py learns e(d) online
from the frames a robot is confident of, as a robot must; an offline tool has the whole
recording and estimates it once from all of it: every frame whose pose is accepted with
confidence >= ``min_confidence`` contributes each of its scan-line crossings, the observed
distance d against the distance p its scan line predicts at the frame's pose in the map's
scan-line tables (the nearest table crossing, TableSearch.observation_predictions),
bilinearly interpolated between the four table cells around the pose so that the 10 cm grid
adds no error of its own (``predicted_distances``).

Model. e(d) is a piecewise-linear table over the observed distance: values at knots every
``knot_step`` m from the robot's radius to the scan lines' reach, linear between them and held
constant beyond the distances the crossings cover. A team's calibration error is a
fifth-order f(r) fitted to table marks read off with an error correlated over about 20 px of
image radius: near the robot, where a metre spans many pixels, e(d) can swing by 20 cm within
25 cm of distance, and farther out it is a bump or a wave over 1-2 m, which a low-order
polynomial in d (radial_correction's cubic) cannot follow and a knot table can. Its roughness
is penalised as a discrete smoothing spline (Eilers and Marx 1996): each knot's second
difference is a zero-mean observation of spread ``curvature_sigma``, each value one of spread
``prior_sigma`` (felt only where no crossing is).

What a crossing shows of e(d). On a radial scan line the residual d - p is e(d). A spiral
scan line reports the radius at which it meets a line; a floor point seen e too far along
its ray moves that meeting point along the spiral, mostly sideways, and its radius by only
e * g, g = -J_xy . u (``error_gain``; J_xy: the prediction's derivative by the robot's
position, u: the crossing's bearing in the field frame; for a radial line g = 1), which the
fit models; counted as radial, spiral crossings would pull e(d) towards zero.

Fit, jointly with the poses. The poses were fixed with the miscalibrated distances and carry
part of the error, which a fit holding them leaves in e(d) (docs/recording-calibration.md).
So e(d) and a correction of every frame's pose are estimated together: Gauss-Newton on the
crossings' residuals d - g e(d) - p(pose), linearised in the pose (J: the interpolation's
derivatives by x and y, a central difference by the heading), with a Gaussian prior holding
each pose near the track's (``pose_sigma_xy``, ``pose_sigma_theta_deg``); each frame's three
pose unknowns are eliminated by their Schur complement, so one step solves a knots-sized
system. Each step re-associates the crossings (with e(d) removed) and reweighs them
(iteratively reweighted least squares, Holland and Welsch 1977) with the Cauchy loss: weight
1 / (1 + (r / s)^2), s = max(``min_scale``, 1.4826 * the median absolute residual of the
gated crossings); crossings farther than ``max_residual`` from the model (another line,
clutter, a wrong association), on a grazing ray (|J_xy| > ``max_slope``), or whose four
table cells predict different crossings (``interpolation_span``) weigh nothing. A frame's
crossings of one white line share the pose's error, which the weights ignore: the figures
reported are fit residuals, not standard errors. Poses that are wrong by more than the gate
(a look-alike place held confidently) cannot be told from a calibration error and bend e(d):
the estimate is as good as the poses it is given.

``corrected_calibration`` writes the result into a calib.yaml mapping: the corrected mapping
f'(r) = f(r) - e(f(r)), so that a crossing extracted with it lies where the table expects it,
in the input's own model (the fifth-order polynomial when a refit follows f' within
``POLYNOMIAL_TOLERANCE``; else the monotone table of calib.yaml version 2), with a
``calibration`` record of how it was made (method ``recording``). ``write_corrected_calib``
writes it atomically and never over the recording's own calib.yaml.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..common.camera import OmniCamera, fit_polynomial
from ..common.errors import FieldlocError
from .calibration_record import (  # noqa: F401 (own_calibs: part of this module's interface)
    cauchy_scale,
    cauchy_weights,
    features_inputs,
    own_calibs,
    plain,
    record_header,
    track_arrays,
    usable_rows,
    write_calib_file,
)
from .lut_search import Observation, TableSearch

DEFAULTS = {
    "min_confidence": 0.95,  # frames whose pose is less sure are not used
    "knot_step": 0.125,  # m between the knots of the e(d) table
    "curvature_sigma": 0.01,  # m, spread of a knot's second difference (the roughness allowed)
    "prior_sigma": 0.3,  # m, ridge on each knot value (only felt where there are no crossings)
    "max_residual": 0.3,  # m, crossings farther from the current e(d) are not used
    "min_scale": 0.02,  # m, floor of the Cauchy scale
    "iterations": 20,  # Gauss-Newton / IRLS iterations at most
    "pose_sigma_xy": 0.25,  # m, spread of a frame's position about the track's
    "pose_sigma_theta_deg": 3.0,  # deg, spread of its heading about the track's
    "max_slope": 4.0,  # |d prediction / d position| above this: a grazing crossing, unused
    "interpolation_span": 0.15,  # m: four cells' predictions further apart: nearest cell
}
REPORT_DISTANCES = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0)  # m, e(d) in the record
POLYNOMIAL_TOLERANCE = 0.002  # m: largest departure of a refitted polynomial from f'(r)


@dataclass
class DistanceError:
    """e(d), the observed minus the true floor distance of a crossing (m), as a function of
    the observed distance d (m): a piecewise-linear table (module doc)."""

    knots: np.ndarray  # (k,) m
    values: np.ndarray  # (k,) m, e at the knots
    support: tuple[float, float]  # m: the observed distances the crossings covered
    frames: int = 0  # frames used
    crossings: int = 0  # crossings used (within max_residual in the last iteration)
    crossings_per_knot: np.ndarray = field(default=None)  # summed hat weights per knot
    residual_rms: float = math.nan  # m, rms of the used crossings about e(d)
    scale: float = math.nan  # m, the Cauchy scale of the last iteration
    fit: dict = field(default_factory=dict)  # iterations, how far the poses moved
    conf: dict = field(default_factory=dict)
    inputs: dict = field(default_factory=dict)  # the features file and what it was made from

    def __call__(self, d) -> np.ndarray:
        """e(d) (m) at observed distances d (m); constant beyond the distances seen."""
        d = np.clip(np.asarray(d, dtype=float), *self.support)
        return np.interp(d, self.knots, self.values)

    def correct(self, d) -> np.ndarray:
        """Observed distances with the error removed."""
        return np.asarray(d, dtype=float) - self(d)

    def summary(self, at=REPORT_DISTANCES) -> dict:
        return {
            "error_m": {f"{d:g}": round(float(self(d)), 4) for d in at},
            "frames": int(self.frames),
            "crossings": int(self.crossings),
            "residual_rms_m": round(float(self.residual_rms), 4),
            "support_m": [round(float(self.support[0]), 3), round(float(self.support[1]), 3)],
        }


# ---------------------------------------------------------------------------- inputs


_track_arrays = track_arrays


@dataclass
class _Frame:
    obs: Observation  # raw crossings (as the camera's calib.yaml gave them)
    pose: np.ndarray  # (3,) the track's pose
    fixed: np.ndarray  # (3,) the pose the current round uses


def _frames(search: TableSearch, features, arr: dict, min_confidence: float) -> list[_Frame]:
    sl = search.scanlines
    have = set(features.names)
    out = []
    for i in usable_rows(arr, min_confidence):
        name = arr["names"][i]
        if name not in have:
            continue
        fr = features.frame(name)
        obs = Observation.from_scanlines(fr.get("radial", np.zeros((0, 4))), fr.get("spiral"),
                                         search.params, sl.max_range, sl.spiral_end_radius,
                                         sl.robot_radius)
        if len(obs) == 0:
            continue
        pose = np.array([arr["x"][i], arr["y"][i], arr["theta"][i]])
        out.append(_Frame(obs=obs, pose=pose, fixed=pose.copy()))
    return out


# ---------------------------------------------------------------------------- predictions


def predicted_distances(search: TableSearch, obs: Observation, pose, span: float = 0.15,
                        heading_step: float = math.radians(1.0)
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per observation, the crossing distance (m) its scan line predicts at a continuous pose
    (x, y, theta), its derivatives by the pose, and whether both hold: the table predictions
    (TableSearch.observation_predictions, associated by ``obs``' distances) of the four cells
    around (x, y), bilinearly interpolated, whose derivatives by x and y are those of the
    interpolation, and by theta the central difference over +-``heading_step``. An
    observation whose four cells predict crossings more than ``span`` m apart (not one line's
    crossing) or "none" (no crossing) is not valid. Returns (p (n,), J (n, 3), valid (n,))."""
    x, y, theta = (float(v) for v in pose)
    res = search.grid.resolution
    x0, y0 = (float(v) for v in search.grid.origin)
    fy = (y - y0) / res
    fx = (x - x0) / res
    i0 = min(max(math.floor(fy), 0), search.ny - 2)
    j0 = min(max(math.floor(fx), 0), search.nx - 2)
    ty = min(max(fy - i0, 0.0), 1.0)
    tx = min(max(fx - j0, 0.0), 1.0)
    w = np.array([(1 - ty) * (1 - tx), (1 - ty) * tx, ty * (1 - tx), ty * tx])
    valid = np.ones(len(obs), dtype=bool)
    corners = {}
    for th in (theta, theta - heading_step, theta + heading_step):
        P = np.stack([search.observation_predictions(obs, (i0 + di, j0 + dj), th)
                      for di in (0, 1) for dj in (0, 1)])  # (4, n): 00, 01, 10, 11
        valid &= (np.ptp(P, axis=0) <= span) & np.all(np.abs(P) < 100.0, axis=0)
        corners[th] = P
    P = corners[theta]
    p = w @ P
    J = np.empty((len(obs), 3))
    J[:, 0] = ((1 - ty) * (P[1] - P[0]) + ty * (P[3] - P[2])) / res
    J[:, 1] = ((1 - tx) * (P[2] - P[0]) + tx * (P[3] - P[1])) / res
    J[:, 2] = (w @ corners[theta + heading_step] - w @ corners[theta - heading_step]) / (
        2 * heading_step)
    return p, J, valid


def error_gain(search: TableSearch, obs: Observation, pose, J: np.ndarray) -> np.ndarray:
    """Per observation, how much of the distance error e(d) its residual shows: 1 on a radial
    scan line; on a spiral, whose crossing moves along the spiral when the floor point moves
    along its ray, -J_xy . u (J_xy: the prediction's derivative by the robot's position,
    u: the unit vector of the crossing's bearing in the field frame): a floor point moved
    by e u is, for the crossing, the robot moved by -e u."""
    gain = np.ones(len(obs))
    spiral = np.asarray(obs.family) > 0
    if spiral.any():
        pts = obs.points(search.scanlines)[spiral]
        bearing = np.arctan2(pts[:, 1], pts[:, 0]) + float(pose[2])
        gain[spiral] = -(J[spiral, 0] * np.cos(bearing) + J[spiral, 1] * np.sin(bearing))
    return gain


# ---------------------------------------------------------------------------- the fit


def _hat_basis(d: np.ndarray, knots: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Linear interpolation weights of d between knots: (left index, weight left, weight right)."""
    d = np.clip(d, knots[0], knots[-1])
    step = knots[1] - knots[0]
    k = np.minimum(((d - knots[0]) / step).astype(np.int64), len(knots) - 2)
    t = (d - knots[k]) / step
    return k, 1.0 - t, t


def _dense_basis(d: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """(n, k) linear interpolation weights of d on the knots."""
    k, wl, wr = _hat_basis(d, knots)
    B = np.zeros((len(d), len(knots)))
    rows = np.arange(len(d))
    B[rows, k] = wl
    B[rows, k + 1] += wr
    return B


def _roughness(knots: np.ndarray, curvature_sigma: float, prior_sigma: float) -> np.ndarray:
    """The prior's information on the knot values (m^-2): second differences of spread
    ``curvature_sigma``, values of spread ``prior_sigma``."""
    n = len(knots)
    D = np.diff(np.eye(n), 2, axis=0)
    return D.T @ D / curvature_sigma**2 + np.eye(n) / prior_sigma**2


def _joint_fit(search: TableSearch, frames: list[_Frame], knots: np.ndarray, c: dict):
    """e(d) and the frames' poses by Gauss-Newton with IRLS weights (module doc). Sets each
    frame's ``fixed`` pose; returns (values, crossings used, residual rms, scale, iterations,
    summed hat weights per knot)."""
    K = len(knots)
    values = np.zeros(K)
    prior_v = _roughness(knots, float(c["curvature_sigma"]), float(c["prior_sigma"]))
    s_xy, s_th = float(c["pose_sigma_xy"]), math.radians(float(c["pose_sigma_theta_deg"]))
    prior_pose = np.diag([1 / s_xy**2, 1 / s_xy**2, 1 / s_th**2])
    max_res, span = float(c["max_residual"]), float(c["interpolation_span"])
    max_slope = float(c["max_slope"])
    scale = max_res
    for f in frames:
        f.fixed = f.pose.copy()
    iterations = 0
    lin = []
    for _ in range(int(c["iterations"])):
        iterations += 1
        lin = []
        for f in frames:
            raw = np.asarray(f.obs.distance, dtype=float)
            d = raw - np.interp(np.clip(raw, knots[0], knots[-1]), knots, values)
            obs = Observation(family=f.obs.family, angle_index=f.obs.angle_index, distance=d,
                              weight=f.obs.weight)
            p, J, ok = predicted_distances(search, obs, f.fixed, span)
            gain = error_gain(search, f.obs, f.fixed, J)
            ok &= (np.hypot(J[:, 0], J[:, 1]) <= max_slope) & (gain >= 0) & (gain <= 1.5)
            B = _dense_basis(raw[ok], knots) * gain[ok, None]
            y = raw[ok] - p[ok]
            lin.append((B, J[ok], y, y - B @ values))
        res = np.concatenate([r for *_, r in lin])
        inside = np.abs(res) <= max_res
        if inside.sum() < 50:
            raise FieldlocError(
                f"only {int(inside.sum())} crossings lie within {max_res:g} m of their"
                " predictions: the poses or the calibration are too far off")
        scale = cauchy_scale(res, inside, c["min_scale"])
        s2 = scale * scale
        A = prior_v * s2
        b = np.zeros(K)
        pose_terms = []
        for f, (B, J, y, r) in zip(frames, lin):
            w = cauchy_weights(r, scale, np.abs(r) <= max_res)
            BW = B.T * w
            JW = J.T * w
            A += BW @ B
            b += BW @ y
            dev = f.pose - f.fixed
            dev[2] = math.remainder(dev[2], 2 * math.pi)
            H = JW @ J + prior_pose * s2
            C = BW @ J
            g = JW @ y + prior_pose @ dev * s2
            Hinv = np.linalg.inv(H)
            A -= C @ Hinv @ C.T
            b -= C @ Hinv @ g
            pose_terms.append((Hinv, C, g))
        new = np.linalg.solve(A, b)
        step = 0.0
        for f, (Hinv, C, g) in zip(frames, pose_terms):
            delta = Hinv @ (g - C.T @ new)
            f.fixed = f.fixed + delta
            step = max(step, float(np.hypot(delta[0], delta[1])))
        change = float(np.max(np.abs(new - values)))
        values = new
        if change < 1e-4 and step < 1e-3:  # e(d) and every pose settled
            break
    counts = np.zeros(K)
    used = 0
    sq = 0.0
    for B, _J, _y, r in lin:
        keep = np.abs(r) <= max_res
        counts += B[keep].sum(axis=0)
        used += int(keep.sum())
        sq += float(np.sum(r[keep] ** 2))
    return values, used, math.sqrt(sq / max(used, 1)), scale, iterations, counts


def estimate_distance_error(search: TableSearch, features, track, radial_conf=None, *,
                            min_confidence: float = 0.95) -> DistanceError:
    """The mirror's distance error e(d) from every frame of a recording whose pose is accepted
    with confidence >= ``min_confidence`` (module doc). ``search``: the map's TableSearch;
    ``features``: the recording's FeaturesFile (omni: ``radial``, ``spiral``); ``track``: a
    PoseTrack or its arrays (names, x, y, theta, confidence, accepted); ``radial_conf``:
    overrides of DEFAULTS (None: the defaults). On a point-symmetric field the frames accepted
    up to the mirror count (``_track_arrays``). Raises FieldlocError when too few frames or
    crossings are usable."""
    c = dict(DEFAULTS, **(radial_conf or {}))
    c["min_confidence"] = float(min_confidence)
    unknown = set(c) - set(DEFAULTS)
    if unknown:
        raise FieldlocError(f"mirror calibration: unknown conf key '{sorted(unknown)[0]}'")
    if getattr(features, "camera_kind", "omni") != "omni":
        raise FieldlocError("a calibration from a recording needs an omni recording's features")
    arr = _track_arrays(track, search.field.is_point_symmetric())
    frames = _frames(search, features, arr, float(min_confidence))
    if len(frames) < 5:
        raise FieldlocError(
            f"only {len(frames)} frames hold a pose with confidence >= {min_confidence:g}:"
            " too few to calibrate from (at least 5)")
    sl = search.scanlines
    step = float(c["knot_step"])
    n_knots = max(3, int(math.ceil((sl.max_range - sl.robot_radius) / step)) + 1)
    knots = sl.robot_radius + step * np.arange(n_knots)
    values, used, rms, scale, iterations, counts = _joint_fit(search, frames, knots, c)
    moves = np.array([math.hypot(*(f.fixed[:2] - f.pose[:2])) for f in frames])
    seen = np.flatnonzero(counts >= 1.0)
    support = (float(knots[seen[0]]), float(knots[seen[-1]])) if len(seen) else (
        float(knots[0]), float(knots[-1]))
    return DistanceError(
        knots=knots, values=values, support=support, frames=len(frames), crossings=used,
        crossings_per_knot=counts, residual_rms=rms, scale=scale,
        fit={"iterations": iterations,
             "pose_shift_median_m": round(float(np.median(moves)), 4),
             "pose_shift_max_m": round(float(np.max(moves)), 4)},
        conf=c, inputs=_features_inputs(features))


_features_inputs = features_inputs


# ---------------------------------------------------------------------------- calib.yaml


def corrected_camera(camera: OmniCamera, error: DistanceError) -> tuple[OmniCamera, float]:
    """The camera with f'(r) = f(r) - e(f(r)), in the camera's own model: a polynomial
    refitted to f' when it follows f' within POLYNOMIAL_TOLERANCE over the valid radius (and
    increases), else the monotone table through f' sampled at every even pixel radius (and
    the valid radius' ends). Returns the camera and
    the largest departure (m) of its mapping from f' over the valid radius."""
    r0, r1 = camera.valid_radius
    rr = np.linspace(r0, r1, 512)
    f = camera.distance_of_radius(rr)
    target = f - error(f)
    if not np.all(np.diff(target) > 0):
        raise FieldlocError("the estimated distance error would make f(r) fall with the radius;"
                            " refusing to write a calibration from it")
    if not target[0] > 0:  # e(d) is constant below the distances seen: the inner rim's floor
        # would lie behind the mirror (held-out omni renders whose first round held a
        # look-alike: e = 0.5 m where f(r0) is 0.2 m, and a traceback from the camera's check)
        raise FieldlocError(
            f"the estimated distance error ({float(error(f[0])):.2f} m at {f[0]:.2f} m) would put"
            f" the floor at the inner radius at {target[0]:.2f} m; refusing to write a"
            " calibration from it")
    common = dict(image_size=camera.image_size, centre=camera.centre,
                  valid_radius=camera.valid_radius, forward_angle=camera.forward_angle,
                  mirrored=camera.mirrored)
    if camera.radial_model == "polynomial":
        coef, res = fit_polynomial(rr, target, degree=5)
        out = OmniCamera(polynomial=coef, **common)
        if (np.max(np.abs(res)) <= POLYNOMIAL_TOLERANCE
                and np.all(np.diff(out.distance_of_radius(rr)) > 0)):
            return out, float(np.max(np.abs(res)))
    inner = np.arange(math.floor(r0 / 2.0) + 1, math.ceil(r1 / 2.0)) * 2.0  # even px
    radius = np.round(np.r_[r0, inner[(inner > r0 + 0.5) & (inner < r1 - 0.5)], r1], 3)
    dist = camera.distance_of_radius(radius)
    dist = np.round(dist - error(dist), 5)
    try:
        out = OmniCamera(polynomial=None, radial_table=np.stack([radius, dist], axis=1),
                         **common)
    except ValueError as e:  # the camera's own check of the table, said as a refusal
        raise FieldlocError(f"the corrected distance table is no calibration ({e}); refusing to"
                            " write a calibration from it") from None
    return out, float(np.max(np.abs(out.distance_of_radius(rr) - target)))


def corrected_calibration(calib: dict, error: DistanceError, *, source: str,
                          sources: dict | None = None) -> dict:
    """calib.yaml's content (``calib``, an omni mapping) with its distance mapping corrected
    so that ``error`` is removed (``corrected_camera``), and a ``calibration`` record of how it
    was made, as stages.calibrate records its own: method ``recording``, ``source`` (the
    recording it came from: the poses file or the dataset), ``sources`` (the features file and
    the dataset and calib.yaml it was extracted from, with the calib's hash, as the features
    record them; updated with ``sources``), the estimator's conf, the frames and crossings
    used, e(d) at a few distances and as its table, the residual rms, the input's mapping it
    replaces (``replaced``). The calibration record the input held, if any, is kept under
    ``previous``."""
    if not isinstance(calib, dict) or calib.get("kind") != "omni":
        raise FieldlocError("a calibration from a recording corrects an omni calib.yaml only")
    camera = OmniCamera.from_dict(calib, "calib.yaml")
    new, departure = corrected_camera(camera, error)
    out = new.to_dict()
    record = {
        **record_header(source=source, inputs=error.inputs, sources=sources, conf=error.conf),
        "model": new.radial_model,
        "model_departure_m": round(departure, 5),
        **error.summary(),
        "error_table": {"distance_m": [round(float(v), 4) for v in error.knots],
                        "error_m": [round(float(v), 5) for v in error.values]},
        "fit": {k: plain(v) for k, v in error.fit.items()},
    }
    record["replaced"] = {k: calib[k] for k in ("version", "radial_model", "polynomial",
                                                "radial_table") if k in calib}
    if isinstance(calib.get("calibration"), dict):
        record["previous"] = calib["calibration"]
    out["calibration"] = record
    return out


def write_corrected_calib(path, calib_dict: dict, *, dataset_calib=None) -> Path:
    """Write ``calib_dict`` (``corrected_calibration``'s) as a calib.yaml at ``path``,
    atomically (calibration_record.write_calib_file). Refused (FieldlocError): ``path`` is the
    recording's own calib.yaml (``own_calibs``), or the mapping is not a valid omni
    calibration."""
    return write_calib_file(path, calib_dict, OmniCamera.from_dict, dataset_calib=dataset_calib)
