"""The SURF template paper's template side of its comparison (section III): the matching-error
surface of one template against a query displaced from it (figure 4), and the estimated pose's error
against the query's distance from its template (figure 5), with method templates' own matching and
fit (templates.TemplateMatcher: ratio test, equal Laplacian sign, consensus, the ``pose_solver``).

Figure 4. The pairs of one query matched to the template (both turned to the field's axes, as
the method turns them) are held, and eq. 4, E = sum_i ||t_i - A(dx, dy, dtheta) q_i||^2 over
the fit's inlier pairs, is evaluated for the query displaced by (dx, dy, dtheta) from its true
pose relative to the template. With the pairs held, E is a quadratic in (dx, dy) and a shifted
cosine in dtheta: one minimum by construction, wherever the pairs are right; what the surface
measures is where that minimum lies (at the true pose when the matches are right) and how
steep it is.

Figure 5. Every frame of a query dataset (with truth) is fitted against one template at the
heading the method would describe it at (the IMU's, imu.csv), as localize does per template;
the position error is the distance of the estimated position from the true one, the heading
error the wrapped difference of the headings, and a query with no fit (too few pairs) is a
failure.
"""

from __future__ import annotations

import math

import numpy as np

from ..common import ground_features as gf
from ..common.dataset import read_image, read_mask
from ..common.errors import FieldlocError
from ..common.geometry import wrap_angle
from . import heading as heading_mod
from . import template_matching as tm
from .templates import MIN_PAIRS, TemplateMatcher, confs


def template_surface(pairs_t: np.ndarray, pairs_q: np.ndarray, pose0, *, half_size: float = 1.5,
                     step: float = 0.1, dtheta_deg: float = 30.0,
                     dtheta_step_deg: float = 1.0) -> dict:
    """Eq. 4 of the pairs (t, q) at ``pose0`` (the query's true pose relative to the template,
    field axes) plus displacements: ``xy`` (ny, nx) over (dx, dy), ``theta`` (H,) over dtheta,
    ``xyt`` (H, ny, nx) over all three, with the axes ``dx``, ``dy`` (m), ``dtheta`` (rad)."""
    n = int(math.floor(half_size / step + 1e-9))
    d = np.arange(-n, n + 1) * float(step)
    m = int(math.floor(dtheta_deg / dtheta_step_deg + 1e-9))
    dth = np.radians(np.arange(-m, m + 1) * float(dtheta_step_deg))
    x0, y0, t0 = (float(v) for v in pose0)
    t = np.asarray(pairs_t, float)
    xyt = np.empty((len(dth), len(d), len(d)))
    for h, a in enumerate(dth):
        # eq. 4 at (x0 + dx, y0 + dy, t0 + a): the residuals u - (dx, dy), u = t - A(x0, y0) q
        u = t - tm.transform((x0, y0, t0 + a), pairs_q)
        rx = u[:, 0][None, :] - d[:, None]  # (nx, M)
        ry = u[:, 1][None, :] - d[:, None]  # (ny, M)
        xyt[h] = (ry * ry).sum(1)[:, None] + (rx * rx).sum(1)[None, :]
    return {"xy": xyt[m], "theta": xyt[:, n, n], "xyt": xyt, "dx": d, "dy": d.copy(), "dtheta": dth,
            "pairs": len(pairs_t)}


def query_headings(dataset, tolerance: float = 0.02) -> np.ndarray:
    """The IMU's heading (rad) at every frame of ``dataset`` (NaN where none)."""
    imu = dataset.optional("imu")
    if imu is None:
        raise FieldlocError(f"{dataset.root}: the queries need imu.csv (the heading the method"
                            " describes them at)")
    yaw, _c = heading_mod.imu_per_frame(imu, np.asarray(dataset.stamps, float), tolerance)
    return np.asarray(yaw, float)


def fit_queries(db, k: int, dataset, truth: np.ndarray, conf: dict | None = None,
                frames=None) -> dict:
    """Every frame (or ``frames``, indices) of ``dataset`` fitted against template ``k`` of
    ``db`` (module doc): per frame ``distance`` (m, true position from the template's),
    ``position_error`` (m), ``heading_error`` (rad, signed), ``dheading`` (rad, the query's
    true heading less the template's), NaN errors where the fit failed; and the fix of each
    frame (None where it failed) in ``fixes``."""
    conf = confs["default"] if conf is None else conf
    matcher = TemplateMatcher(db, conf)
    camera = dataset.camera()
    mp = dataset.root / "mask.png"
    mask = read_mask(mp, camera.image_size) if mp.is_file() else None
    yaw = query_headings(dataset)
    rows = range(len(dataset.names)) if frames is None else frames
    tp = db.poses[k]
    out = {key: [] for key in ("distance", "position_error", "heading_error", "dheading",
                               "fixes", "frames")}
    for i in rows:
        pose = truth[i]
        h = float(yaw[i]) if math.isfinite(yaw[i]) else float(pose[2])
        q = gf.ground_features(read_image(dataset.images[i]), camera, db.ground_conf, mask,
                               heading=h if db.field_axes else None)
        fix = matcher.fit(q, k, h) if len(q) >= MIN_PAIRS else None
        out["frames"].append(int(i))
        out["distance"].append(float(np.hypot(pose[0] - tp[0], pose[1] - tp[1])))
        out["dheading"].append(float(wrap_angle(pose[2] - tp[2])))
        out["fixes"].append(fix)
        if fix is None:
            out["position_error"].append(math.nan)
            out["heading_error"].append(math.nan)
        else:
            out["position_error"].append(float(np.hypot(*(fix.pose[:2] - pose[:2]))))
            out["heading_error"].append(float(wrap_angle(fix.pose[2] - pose[2])))
    return {key: (v if key == "fixes" else np.asarray(v)) for key, v in out.items()}


def distance_summary(distance: np.ndarray, position_error: np.ndarray,
                     heading_error: np.ndarray, limits=(0.5, 1.0, 1.5, 2.0)) -> list[dict]:
    """Per ring of distance from the template (up to each limit, from the previous one): the
    queries, failures, median and largest position error (m), largest |heading error| (rad)."""
    out, lo = [], -1.0
    for hi in limits:
        sel = (distance > lo) & (distance <= hi + 1e-9)
        e, h = position_error[sel], heading_error[sel]
        ok = np.isfinite(e)
        out.append({"from": max(lo, 0.0), "to": hi, "queries": int(sel.sum()),
                    "failed": int((~ok).sum()),
                    "median_m": float(np.median(e[ok])) if ok.any() else math.nan,
                    "max_m": float(np.max(e[ok])) if ok.any() else math.nan,
                    "max_heading": float(np.max(np.abs(h[ok]))) if ok.any() else math.nan})
        lo = hi
    return out
