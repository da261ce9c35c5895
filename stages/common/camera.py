"""Camera models read from a dataset's calib.yaml.

Omnidirectional (catadioptric) camera, seed 004 eq. 2: the ground distance of a pixel is a
fifth-order polynomial f(r) of its radius r (pixels) from the image centre; its bearing is its
image angle relative to the robot's forward direction in the image.

calib.yaml for kind omni::

    kind: omni
    image_size: [480, 480]          # width, height (px)
    centre: [240.0, 240.0]          # image centre (u, v) in px
    polynomial: [a0, a1, ..., a5]   # f(r) = sum a_i r^i, metres, r in px
    valid_radius: [40.0, 230.0]     # px: robot-body mask radius .. outer limit of the floor
    forward_angle: 1.5707963        # rad: image angle of the robot's +x axis, counter-clockwise
                                    # from the image's +u axis with v pointing up
    mirrored: false                 # true if the image shows the floor mirrored
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from .errors import DatasetError


@dataclass
class OmniCamera:
    image_size: tuple[int, int]
    centre: tuple[float, float]
    polynomial: np.ndarray  # (6,) a0..a5, r in px -> metres
    valid_radius: tuple[float, float]
    forward_angle: float = math.pi / 2
    mirrored: bool = False
    _inverse: tuple | None = field(default=None, repr=False, compare=False)

    kind = "omni"

    # ------------------------------------------------------------------ radial mapping
    def distance_of_radius(self, r) -> np.ndarray:
        """Ground distance (m) of pixel radius r (px): the polynomial f(r)."""
        return np.polynomial.polynomial.polyval(np.asarray(r, dtype=float), self.polynomial)

    def _inverse_table(self):
        if self._inverse is None:
            r = np.linspace(self.valid_radius[0], self.valid_radius[1], 4096)
            d = self.distance_of_radius(r)
            # keep the monotonic part from the body mask outwards (f may dip inside the mask)
            inc = np.concatenate([[True], np.diff(d) > 0])
            stop = np.argmin(inc) if not inc.all() else len(inc)
            self._inverse = (d[:stop], r[:stop])
        return self._inverse

    def radius_of_distance(self, d) -> np.ndarray:
        """Pixel radius at which ground distance d (m) appears; NaN outside the valid floor."""
        dd, rr = self._inverse_table()
        d = np.asarray(d, dtype=float)
        out = np.interp(d, dd, rr, left=np.nan, right=np.nan)
        return np.where((out >= self.valid_radius[0]) & (out <= self.valid_radius[1]), out, np.nan)

    @property
    def max_distance(self) -> float:
        return float(self._inverse_table()[0][-1])

    # ------------------------------------------------------------------ pixels <-> robot frame
    def _sign(self) -> float:
        return -1.0 if self.mirrored else 1.0

    def pixel_to_robot(self, u, v) -> np.ndarray:
        """Pixels (u, v) -> points (..., 2) on the floor in the robot frame (metres)."""
        du = np.asarray(u, dtype=float) - self.centre[0]
        dv = np.asarray(v, dtype=float) - self.centre[1]
        r = np.hypot(du, dv)
        alpha = np.arctan2(-dv, du)
        bearing = self._sign() * (alpha - self.forward_angle)
        d = self.distance_of_radius(r)
        return np.stack([d * np.cos(bearing), d * np.sin(bearing)], axis=-1)

    def robot_to_pixel(self, points) -> np.ndarray:
        """Floor points (..., 2) in the robot frame -> pixels (..., 2) (u, v); NaN if unseen."""
        p = np.asarray(points, dtype=float)
        d = np.hypot(p[..., 0], p[..., 1])
        bearing = np.arctan2(p[..., 1], p[..., 0])
        alpha = self._sign() * bearing + self.forward_angle
        r = self.radius_of_distance(d)
        return np.stack(
            [self.centre[0] + r * np.cos(alpha), self.centre[1] - r * np.sin(alpha)], axis=-1
        )

    def bearing_to_image_angle(self, bearing) -> np.ndarray:
        return self._sign() * np.asarray(bearing, dtype=float) + self.forward_angle

    # ------------------------------------------------------------------ io
    def to_dict(self) -> dict:
        return {
            "kind": "omni",
            "image_size": [int(self.image_size[0]), int(self.image_size[1])],
            "centre": [float(self.centre[0]), float(self.centre[1])],
            "polynomial": [float(a) for a in self.polynomial],
            "valid_radius": [float(self.valid_radius[0]), float(self.valid_radius[1])],
            "forward_angle": float(self.forward_angle),
            "mirrored": bool(self.mirrored),
        }

    @classmethod
    def from_dict(cls, d: dict, where: str = "calib") -> OmniCamera:
        try:
            poly = np.asarray(d["polynomial"], dtype=float)
            cam = cls(
                image_size=(int(d["image_size"][0]), int(d["image_size"][1])),
                centre=(float(d["centre"][0]), float(d["centre"][1])),
                polynomial=poly,
                valid_radius=(float(d["valid_radius"][0]), float(d["valid_radius"][1])),
                forward_angle=float(d.get("forward_angle", math.pi / 2)),
                mirrored=bool(d.get("mirrored", False)),
            )
        except KeyError as e:
            raise DatasetError(f"{where}: omni calibration misses key {e}") from None
        except (TypeError, ValueError, IndexError) as e:
            raise DatasetError(f"{where}: omni calibration has a malformed value ({e})") from None
        if poly.ndim != 1 or not 2 <= len(poly) <= 6:
            raise DatasetError(f"{where}: 'polynomial' needs 2..6 coefficients a0..a5")
        return cam


def load_calib(path: str | Path):
    """Read a calib.yaml and return the camera model of its kind."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"calibration not found: {path}")
    try:
        d = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise DatasetError(f"{path}: not valid YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(d, dict) or "kind" not in d:
        raise DatasetError(f"{path}: calibration needs a 'kind' (omni or perspective)")
    if d["kind"] == "omni":
        return OmniCamera.from_dict(d, str(path))
    if d["kind"] == "perspective":
        from .perspective_camera import PerspectiveCamera  # issue 4

        return PerspectiveCamera.from_dict(d, str(path))
    raise DatasetError(f"{path}: unknown camera kind '{d['kind']}' (omni or perspective)")


def save_calib(camera, path: str | Path) -> Path:
    from .artifacts import atomic_path

    path = Path(path)
    with atomic_path(path, suffix=".yaml") as tmp:
        tmp.write_text(yaml.safe_dump(camera.to_dict(), sort_keys=False))
    return path


def fit_polynomial(radius_px, distance_m, degree: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares fit of f(r) = sum a_i r^i (seed 004 eq. 2) to measured pairs. Returns the
    coefficients a0..a_degree and the residuals (m). The fit runs on r scaled to [0, 1] for
    conditioning, then the coefficients are converted back to pixels."""
    r = np.asarray(radius_px, dtype=float)
    d = np.asarray(distance_m, dtype=float)
    scale = float(np.max(np.abs(r))) or 1.0
    A = np.vander(r / scale, degree + 1, increasing=True)
    coef_scaled, *_ = np.linalg.lstsq(A, d, rcond=None)
    coef = coef_scaled / scale ** np.arange(degree + 1)
    residuals = np.polynomial.polynomial.polyval(r, coef) - d
    return coef, residuals
