"""Oracle of an omni camera's distance error, as stages.localize.mirror_calibration defines it:
e(d) = d - D, the observed floor distance d (the written calib.yaml's f_w at the image radius
where the floor point appears) minus the point's true distance D (the rendering camera's f at
that radius), as a function of d:

    e(d) = d - f_true(f_w^-1(d)).

f_w^-1 by bisection on the written polynomial or table (both increase over the valid radius),
independent of OmniCamera.radius_of_distance's sampled inverse.
"""

from __future__ import annotations

import numpy as np


def radius_of(distance_of_radius, d: float, r0: float, r1: float) -> float:
    """The radius in [r0, r1] (px) at which an increasing f reaches d, by bisection."""
    lo, hi = float(r0), float(r1)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if float(distance_of_radius(mid)) < d:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def distance_error(true_camera, written_camera, d) -> np.ndarray:
    """e(d) (m) at observed distances d (m) of a camera written as ``written_camera`` whose
    images were made by ``true_camera`` (both stages.common.camera.OmniCamera)."""
    r0, r1 = written_camera.valid_radius
    out = []
    for v in np.atleast_1d(np.asarray(d, dtype=float)):
        r = radius_of(written_camera.distance_of_radius, v, r0, r1)
        out.append(v - float(true_camera.distance_of_radius(r)))
    return np.asarray(out)
