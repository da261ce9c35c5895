"""Perspective camera of a humanoid robot's head (Schulz et al. 2011, §3: a 752 x 480 colour camera
behind a wide-angle lens), with its pose above the floor.

Model: OpenCV's pinhole camera with radial-tangential distortion (k1, k2, p1, p2, k3) in
normalised coordinates, mounted ``height`` metres above the floor over the point ``position``
(x, y in the robot frame; default the robot's origin) and turned by yaw, pitch and roll
(intrinsic z-y-x: yaw about the robot's up axis, then pitch about the camera's left axis,
pitch > 0 looks down, then roll about the optical axis, roll > 0 turns the camera clockwise as
seen from behind, so the horizon rises towards the image's right side).
Robot frame: x forward, y left, z up; the floor is z = 0.

Pixel coordinates are (u, v): u to the right, v down, origin at the top-left pixel's centre.
"Ideal" pixels are the undistorted pixel coordinates under the same intrinsics (what
``cv2.undistortPoints(..., P=K)`` returns): straight lines in the world are straight there.

calib.yaml for kind perspective::

    kind: perspective
    image_size: [752, 480]            # width, height (px)
    intrinsics: {fx: 330.0, fy: 330.0, cx: 375.5, cy: 239.5}   # px
    distortion: [k1, k2, p1, p2, k3]  # OpenCV radial-tangential model (k3 optional)
    height: 0.55                      # m, optical centre above the floor
    pitch: 0.45                       # rad, nominal; > 0 looks down (per frame: head.csv)
    roll: 0.0                         # rad, nominal; about the optical axis
    yaw: 0.0                          # rad, camera heading relative to the robot's x axis
    position: [0.0, 0.0]              # m, optional: optical centre over the floor (robot x, y)
    pitch_offset: 0.0                 # rad, optional: the camera's mount, added to every pitch
    roll_offset: 0.0                  # rad, optional: the camera's mount, added to every roll

Per frame the head moves: ``with_pose`` gives the same camera at a frame's pitch, roll, yaw,
height and position (what DIR/head.csv holds, see stages.common.dataset).

Mount offsets. head.csv holds the angles the robot measures (joint encoders, IMU); the camera
sits in the head at a small angle of its own that no encoder sees. ``pitch_offset`` and
``roll_offset`` are that angle: every rotation the camera is used at (the nominal pitch and
roll, and each frame's head.csv angles) is turned by them, ``rotation(pitch, roll)`` =
head_rotation(yaw, pitch + pitch_offset, roll + roll_offset). Both default to 0, and a
calib.yaml without them is written back without them. ``fieldloc localize --method mcl
--write-calib`` learns them (and ``height``) from a recording (localize.mount_calibration).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .errors import DatasetError, shown
from .user_numbers import user_number, user_numbers

# camera axes (x right, y down, z along the optical axis) in the robot frame at zero angles
_CAMERA_AXES = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
# largest ideal radius (normalised, tan of the off-axis angle) the model is used up to
_RADIUS_CAP = 6.0
# the highest camera a calib.yaml may give (m): a robot's camera, a few metres at most; a
# height in millimetres or centimetres is refused rather than read as a flying camera
MAX_HEIGHT_M = 10.0
# the lowest (m): a millimetre; below it a value is a unit slip, and the range error of a floor
# point, which grows as 1 / height, overflows (observation_model.range_sigma)
MIN_HEIGHT_M = 1e-3
# the largest mount offset a calib.yaml may give (rad, about 17 deg): a camera screwed into a
# head sits within a few degrees of its drawing; a larger value is a misread unit or a sign of
# another convention, not a mount
MAX_MOUNT_OFFSET = 0.3
# the focal lengths a calib.yaml may give, as shares of the image's size (fx of its width, fy of
# its height): fields of view from about 170 deg down to about 0.6 deg; outside them a value is
# a unit slip (metres, normalised coordinates) or a typo, not a lens
FOCAL_SHARE = (0.05, 100.0)
# the largest distortion coefficient a calib.yaml may give (|k1|, |k2|, |p1|, |p2|, |k3|):
# calibrations of robot cameras hold values below 1, wide lenses a few; beyond 100 a value is a
# typo or another lens model's, and the lens checks' polynomials overflow (max_ideal_radius)
MAX_DISTORTION = 100.0
INTRINSICS_KEYS = ("fx", "fy", "cx", "cy")


def head_rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Rotation (3, 3) taking camera-frame vectors to the robot frame."""
    cy_, sy_ = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    rz = np.array([[cy_, -sy_, 0.0], [sy_, cy_, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx @ _CAMERA_AXES


def _pair(value, where: str) -> tuple[float, float]:
    """calib.yaml's ``position``: [x, y] metres."""
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise DatasetError(f"{where}: 'position' must be [x, y] (m), got {shown(value, 40)}")
    x, y = user_numbers(value, f"{where}: 'position'", error=DatasetError)
    return x, y


@dataclass(eq=False)
class PerspectiveCamera:
    image_size: tuple[int, int] = (752, 480)
    fx: float = 330.0
    fy: float = 330.0
    cx: float = 375.5
    cy: float = 239.5
    distortion: np.ndarray = field(
        default_factory=lambda: np.array([-0.25, 0.05, 0.0, 0.0, 0.0])
    )  # k1, k2, p1, p2, k3
    height: float = 0.55
    pitch: float = 0.45
    roll: float = 0.0
    yaw: float = 0.0
    position: tuple[float, float] = (0.0, 0.0)  # m: optical centre over the floor (robot x, y)
    pitch_offset: float = 0.0  # rad: the mount's pitch, added to every pitch (module doc)
    roll_offset: float = 0.0  # rad: the mount's roll, added to every roll
    _max_radius: float | None = field(default=None, repr=False, compare=False)

    kind = "perspective"

    def __post_init__(self):
        d = np.zeros(5)
        given = np.asarray(self.distortion, dtype=float).ravel()
        d[: len(given)] = given
        self.distortion = d
        self.position = (float(self.position[0]), float(self.position[1]))

    def with_pose(self, pitch: float | None = None, roll: float | None = None,
                  yaw: float | None = None, height: float | None = None,
                  position=None) -> PerspectiveCamera:
        """The same camera (intrinsics, lens) at another pose; None keeps a value. The lens's
        valid cone is carried over, not computed again."""
        self.max_ideal_radius  # noqa: B018 (computed once, shared by the copy)

        def keep(v, old):
            return old if v is None else float(v)

        return replace(self, distortion=self.distortion.copy(),
                       pitch=keep(pitch, self.pitch), roll=keep(roll, self.roll),
                       yaw=keep(yaw, self.yaw), height=keep(height, self.height),
                       position=self.position if position is None else tuple(position),
                       _max_radius=self._max_radius)

    def __eq__(self, other) -> bool:
        return isinstance(other, PerspectiveCamera) and self.to_dict() == other.to_dict()

    __hash__ = None

    # ------------------------------------------------------------------ intrinsics
    @property
    def camera_matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def max_ideal_radius(self) -> float:
        """Largest normalised ideal radius up to which the radial distortion is one-to-one (the
        lens model's valid cone); capped at tan(80.5 deg)."""
        if self._max_radius is None:
            k1, k2, _, _, k3 = self.distortion
            r = np.linspace(0.0, _RADIUS_CAP, 60001)
            r2 = r * r
            slope = 1 + 3 * k1 * r2 + 5 * k2 * r2**2 + 7 * k3 * r2**3  # d/dr of r * radial
            bad = np.nonzero(slope <= 1e-3)[0]
            self._max_radius = float(r[bad[0] - 1]) if len(bad) else _RADIUS_CAP
        return self._max_radius

    def distort_normalized(self, xy) -> np.ndarray:
        """Ideal normalised coordinates (..., 2) -> distorted normalised coordinates."""
        xy = np.asarray(xy, dtype=float)
        x, y = xy[..., 0], xy[..., 1]
        k1, k2, p1, p2, k3 = self.distortion
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.stack([xd, yd], axis=-1)

    def undistort_normalized(self, xy_d, iterations: int = 30) -> np.ndarray:
        """Distorted normalised coordinates (..., 2) -> ideal ones, by Newton's method on the
        distortion model (vectorised). NaN where no ideal point inside the valid cone maps
        there."""
        xy_d = np.asarray(xy_d, dtype=float)
        xd, yd = xy_d[..., 0], xy_d[..., 1]
        k1, k2, p1, p2, k3 = self.distortion
        x, y = xd.copy(), yd.copy()
        for _ in range(iterations):
            r2 = x * x + y * y
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            drad = k1 + r2 * (2 * k2 + 3 * k3 * r2)
            ex = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - xd
            ey = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - yd
            a = radial + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
            b = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
            c = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
            d = radial + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
            det = a * d - b * c
            with np.errstate(divide="ignore", invalid="ignore"):
                sx = (d * ex - b * ey) / det
                sy = (a * ey - c * ex) / det
            # keep steps bounded so a far start cannot jump across the fold
            step = np.hypot(sx, sy)
            limit = 0.5 * (1.0 + np.hypot(x, y))
            scale = np.where(step > limit, limit / np.maximum(step, 1e-300), 1.0)
            x = x - sx * scale
            y = y - sy * scale
            if np.nanmax(np.abs(np.concatenate([np.ravel(sx), np.ravel(sy)])), initial=0) < 1e-13:
                break
        out = np.stack([x, y], axis=-1)
        ok = (np.hypot(x, y) <= self.max_ideal_radius) & np.all(
            np.abs(self.distort_normalized(out) - xy_d) < 1e-8, axis=-1
        )
        return np.where(ok[..., None], out, np.nan)

    def _to_normalized(self, uv) -> np.ndarray:
        uv = np.asarray(uv, dtype=float)
        return np.stack([(uv[..., 0] - self.cx) / self.fx, (uv[..., 1] - self.cy) / self.fy], -1)

    def _to_pixels(self, xy) -> np.ndarray:
        return np.stack([xy[..., 0] * self.fx + self.cx, xy[..., 1] * self.fy + self.cy], -1)

    def undistort_points(self, uv) -> np.ndarray:
        """Distorted image pixels (..., 2) -> ideal (undistorted) pixels under the same
        intrinsics; NaN outside the lens model's valid cone."""
        return self._to_pixels(self.undistort_normalized(self._to_normalized(uv)))

    def distort_points(self, uv_ideal) -> np.ndarray:
        """Ideal pixels (..., 2) -> distorted image pixels (inverse of undistort_points)."""
        return self._to_pixels(self.distort_normalized(self._to_normalized(uv_ideal)))

    # ------------------------------------------------------------------ pose of the camera
    def _angles(self, pitch, roll):
        """The camera's pitch and roll at head angles ``pitch``, ``roll`` (None: nominal):
        the head's plus the mount offsets."""
        return ((self.pitch if pitch is None else float(pitch)) + self.pitch_offset,
                (self.roll if roll is None else float(roll)) + self.roll_offset)

    def rotation(self, pitch: float | None = None, roll: float | None = None) -> np.ndarray:
        """Camera-to-robot rotation (3, 3) at the given head angles (default: nominal), the
        mount offsets added."""
        p, r = self._angles(pitch, roll)
        return head_rotation(self.yaw, p, r)

    def pixel_rays(self, uv, pitch=None, roll=None) -> np.ndarray:
        """Unit viewing rays (..., 3) in the robot frame of distorted pixels; NaN if invalid."""
        xy = self.undistort_normalized(self._to_normalized(uv))
        ray = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
        ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
        return ray @ self.rotation(pitch, roll).T

    def pixel_to_floor(self, uv, pitch=None, roll=None) -> np.ndarray:
        """Distorted pixels (N, 2) -> floor points (N, 2) in the robot frame (x forward, y left).
        NaN for pixels on or above the horizon (their ray never meets the floor)."""
        ray = self.pixel_rays(uv, pitch, roll)
        down = ray[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(down < -1e-9, self.height / -down, np.nan)
        return ray[..., :2] * t[..., None] + np.asarray(self.position)

    def project(self, points, pitch=None, roll=None, *, inside: bool = True,
                clamp: bool = False) -> np.ndarray:
        """3-D points (..., 3) in the robot frame (floor z = 0) -> distorted pixels (..., 2).
        NaN for points behind the camera; see ``camera_points_to_pixels`` for the flags."""
        p = np.asarray(points, dtype=float)
        rel = p - np.array([self.position[0], self.position[1], self.height])
        cam = rel @ self.rotation(pitch, roll)  # = R^T rel per point
        return self.camera_points_to_pixels(cam, inside=inside, clamp=clamp)

    def camera_points_to_pixels(self, cam, *, inside: bool = True,
                                clamp: bool = False) -> np.ndarray:
        """Points (..., 3) in the camera frame (x right, y down, z along the optical axis) ->
        distorted pixels (..., 2). NaN for points behind the camera; with ``inside`` also for
        points outside the image or the lens model's valid cone. With ``clamp`` (for drawing
        outlines that leave the image) points beyond the valid cone are pushed outwards along
        their direction instead of being dropped, so a polygon keeps its shape on the image."""
        cam = np.asarray(cam, dtype=float)
        z = cam[..., 2]
        front = z > 1e-9
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = cam[..., :2] / np.where(front, z, np.nan)[..., None]
        rho = np.hypot(xy[..., 0], xy[..., 1])
        rmax = self.max_ideal_radius
        beyond = rho > rmax
        if clamp:
            with np.errstate(divide="ignore", invalid="ignore"):
                edge = xy * np.where(beyond, rmax / rho, 1.0)[..., None]
            stretch = np.where(beyond, rho / rmax, 1.0)[..., None]
            uv = self._to_pixels(self.distort_normalized(edge) * stretch)
        else:
            uv = self._to_pixels(self.distort_normalized(xy))
            uv[beyond] = np.nan
        if inside:
            w, h = self.image_size
            out = (uv[..., 0] < -0.5) | (uv[..., 0] > w - 0.5) | (uv[..., 1] < -0.5) | (
                uv[..., 1] > h - 0.5
            )
            uv[out] = np.nan
        return uv

    def floor_to_pixel(self, points, pitch=None, roll=None) -> np.ndarray:
        """Floor points (N, 2) in the robot frame -> distorted pixels (N, 2); NaN for points
        behind the camera or outside the image."""
        p = np.asarray(points, dtype=float)
        p3 = np.concatenate([p, np.zeros(p.shape[:-1] + (1,))], axis=-1)
        return self.project(p3, pitch, roll, inside=True)

    def horizon_row(self, u=None, pitch=None, roll=None) -> np.ndarray:
        """Image row v (distorted pixels) of the horizon at columns ``u`` (default: every
        column). The floor lies below (larger v); NaN where the horizon leaves the image."""
        w, h = self.image_size
        u = np.arange(w, dtype=float) if u is None else np.asarray(u, dtype=float)
        r3 = self.rotation(pitch, roll)[2]  # up-component of camera axes
        if abs(r3[1]) < 1e-9:
            return np.full(u.shape, np.nan)
        rmax = self.max_ideal_radius
        xs = np.linspace(-rmax, rmax, 4001)
        ys = -(r3[0] * xs + r3[2]) / r3[1]
        keep = np.hypot(xs, ys) <= rmax
        if keep.sum() < 2:
            return np.full(u.shape, np.nan)
        uv = self._to_pixels(self.distort_normalized(np.stack([xs[keep], ys[keep]], -1)))
        order = np.argsort(uv[:, 0])
        us, vs = uv[order, 0], uv[order, 1]
        if np.any(np.diff(us) <= 0):  # strongly tilted horizon: keep the monotone part
            mono = np.concatenate([[True], np.diff(us) > 0])
            us, vs = us[mono], vs[mono]
        v = np.interp(u, us, vs, left=np.nan, right=np.nan)
        return np.where((v >= -0.5) & (v <= h - 0.5), v, np.nan)

    # ------------------------------------------------------------------ io
    def to_dict(self) -> dict:
        return {
            "kind": "perspective",
            "image_size": [int(self.image_size[0]), int(self.image_size[1])],
            "intrinsics": {
                "fx": float(self.fx), "fy": float(self.fy),
                "cx": float(self.cx), "cy": float(self.cy),
            },
            "distortion": [float(k) for k in self.distortion],
            "height": float(self.height),
            "pitch": float(self.pitch),
            "roll": float(self.roll),
            "yaw": float(self.yaw),
            **({"position": [float(v) for v in self.position]} if any(self.position) else {}),
            **({"pitch_offset": float(self.pitch_offset)} if self.pitch_offset else {}),
            **({"roll_offset": float(self.roll_offset)} if self.roll_offset else {}),
        }

    @classmethod
    def from_dict(cls, d: dict, where: str = "calib") -> PerspectiveCamera:
        if not isinstance(d, dict):
            raise DatasetError(f"{where}: perspective calibration must be a mapping")
        try:
            size = d["image_size"]
            intr = d["intrinsics"]
            if not isinstance(intr, dict):
                raise DatasetError(f"{where}: 'intrinsics' must be a mapping of fx, fy, cx, cy")
            unknown = [str(k) for k in intr if k not in INTRINSICS_KEYS]
            if unknown:
                raise DatasetError(f"{where}: unknown key {shown(f'intrinsics.{unknown[0]}', 40)}"
                                   f" (intrinsics: {', '.join(INTRINSICS_KEYS)})")
            if not isinstance(size, (list, tuple)) or len(size) != 2:
                raise DatasetError(f"{where}: 'image_size' must be [width, height], got"
                                   f" {shown(size, 40)}")

            def number(value, key: str) -> float:
                # every number of the file read one way (stages.common.user_numbers)
                return user_number(value, f"{where}: '{key}'", error=DatasetError)

            dist = np.asarray(user_numbers(d["distortion"], f"{where}: 'distortion'",
                                           error=DatasetError))
            cam = cls(
                image_size=tuple(user_numbers(size, f"{where}: 'image_size'", whole=True,
                                              error=DatasetError)),
                fx=number(intr["fx"], "intrinsics.fx"), fy=number(intr["fy"], "intrinsics.fy"),
                cx=number(intr["cx"], "intrinsics.cx"), cy=number(intr["cy"], "intrinsics.cy"),
                distortion=dist if dist.size in (4, 5) else np.zeros(5),
                height=number(d["height"], "height"),
                pitch=number(d["pitch"], "pitch"),
                roll=number(d.get("roll", 0.0), "roll"),
                yaw=number(d.get("yaw", 0.0), "yaw"),
                position=_pair(d.get("position", (0.0, 0.0)), where),
                pitch_offset=number(d.get("pitch_offset", 0.0), "pitch_offset"),
                roll_offset=number(d.get("roll_offset", 0.0), "roll_offset"),
            )
        except KeyError as e:
            raise DatasetError(f"{where}: perspective calibration misses key {e}") from None
        except (TypeError, ValueError, IndexError) as e:
            raise DatasetError(
                f"{where}: perspective calibration has a malformed value ({e})"
            ) from None
        if dist.size not in (4, 5):
            raise DatasetError(f"{where}: 'distortion' needs 4 or 5 values [k1, k2, p1, p2, k3]")
        values = [cam.fx, cam.fy, cam.cx, cam.cy, cam.height, cam.pitch, cam.roll, cam.yaw,
                  *cam.position, *cam.distortion, cam.pitch_offset, cam.roll_offset]
        if not all(math.isfinite(v) for v in values):
            raise DatasetError(f"{where}: perspective calibration holds a non-finite number")
        if np.abs(cam.distortion).max() > MAX_DISTORTION:
            raise DatasetError(f"{where}: 'distortion' coefficients must lie within"
                               f" +-{MAX_DISTORTION:g}, got"
                               f" [{', '.join(f'{v:g}' for v in cam.distortion)}]")
        if cam.image_size[0] <= 0 or cam.image_size[1] <= 0:
            raise DatasetError(f"{where}: 'image_size' must be positive, got {list(size)}")
        w, h = cam.image_size
        low, high = FOCAL_SHARE
        if not (low * w <= cam.fx <= high * w and low * h <= cam.fy <= high * h):
            raise DatasetError(f"{where}: focal lengths fx, fy must be > 0, between {low:g} and"
                               f" {high:g} times the image's width (fx) and height (fy), got"
                               f" {cam.fx:g}, {cam.fy:g} for {w} x {h} px")
        if not (0 <= cam.cx <= w - 1 and 0 <= cam.cy <= h - 1):
            raise DatasetError(f"{where}: the principal point cx, cy must lie in the image"
                               f" (0..{w - 1}, 0..{h - 1}), got {cam.cx:g}, {cam.cy:g}")
        if not MIN_HEIGHT_M <= cam.height <= MAX_HEIGHT_M:
            raise DatasetError(f"{where}: 'height' must be >= {MIN_HEIGHT_M:g} and <="
                               f" {MAX_HEIGHT_M:g} m (camera above the floor), got"
                               f" {cam.height:g}")
        for name in ("pitch", "roll", "yaw"):
            angle = getattr(cam, name)
            if abs(angle) > math.pi:  # radians: a value beyond pi is most likely degrees
                raise DatasetError(f"{where}: '{name}' must be an angle in radians within"
                                   f" [-pi, pi], got {angle:g} (degrees?)")
        for name in ("pitch_offset", "roll_offset"):
            angle = getattr(cam, name)
            if abs(angle) > MAX_MOUNT_OFFSET:
                raise DatasetError(f"{where}: '{name}' must be a mount angle in radians within"
                                   f" +-{MAX_MOUNT_OFFSET:g}, got {angle:g} (degrees?)")
        corners = cam._to_normalized(np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]]))
        if np.isnan(cam.undistort_normalized(corners)).any():
            raise DatasetError(
                f"{where}: the distortion [{', '.join(f'{v:g}' for v in cam.distortion)}] folds"
                " back inside the image (no one-to-one lens model at its corners)"
            )
        return cam
