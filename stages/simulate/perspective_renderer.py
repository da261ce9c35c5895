"""Perspective camera renderer: what a humanoid robot's head camera shows (Schulz et al. (2011)
§3: a 752 x 480 colour camera behind a wide-angle lens).

It renders the camera-independent world of :mod:`.scene` (a :class:`FieldScene`) through a
:class:`PerspectiveCamera` whose pitch and roll follow the walk (:mod:`.walk`).

Geometry. Every pixel's viewing ray (fixed in the camera, undistorted once) is turned per frame
by the head angles and the robot's pose and cast into the hall: the floor (z = 0) and the walls
(ceiling above them). Floor pixels sample the scene's carpet colour and line field with
``cv2.remap`` (on the 1/32-texel grid of stages.common.fixed_remap, the same under every
OpenCV version); a line's coverage of a pixel is the exact overlap of the pixel's floor footprint
measured across the line (from the per-pixel Jacobian of the floor point) with the rule line
width, so far lines thin out and fade as through a real lens instead of aliasing, and far carpet
is sampled from a prefiltered copy. Goal posts, robots, people and the ball are intersected per
pixel inside their projected bounding boxes (vertical cylinders with caps; the ball as a
sphere), goal nets and the crossbar as vertical panels, all against a depth buffer.

Imaging (all in the scene's display-referred BGR levels, like the omni renderer): lateral
chromatic aberration and lens blur that grow towards the corners of the wide-angle image,
head-motion blur during the exposure, vignetting, the frame's light level and white balance, an
RGGB Bayer mosaic with shot and read noise demosaiced bilinearly (the orange and cyan fringes
next to sharp contrasts that Schulz et al. (2011) filter), and YUV 4:2:2 chroma subsampling.

Renderer interface (see :mod:`stages.simulate`): ``PerspectiveRenderer(conf, scene, seed)``,
``.camera``, ``.prepare(path)`` (head motion over the walk; returns the head CSVs to write),
``.render(pose, frame)``; module functions ``camera_from_conf`` and ``perturbed_camera``.
"""

from __future__ import annotations

import copy
import math

import cv2
import numpy as np

from ..common.camera import MAX_IMAGE_PX
from ..common.conf import check_bounds
from ..common.errors import DatasetError, FieldlocError
from ..common.fixed_remap import fixed_maps, remap_linear
from ..common.perspective_camera import PerspectiveCamera, head_rotation
from . import walk
from .imaging import add_sensor_noise, chroma_subsample, frame_light, jpeg_round_trip, noise_window
from .scene import BGR, sample_texture

PERSPECTIVE_DEFAULTS = {
    "image_size": [752, 480],  # width, height (px): the paper's WXGA camera
    "intrinsics": {"fx": 330.0, "fy": 330.0, "cx": 375.5, "cy": 239.5},  # px
    "distortion": [-0.25, 0.05, 0.0, 0.0, 0.0],  # k1, k2, p1, p2, k3 (wide-angle, barrel)
    "height": 0.55,  # m: camera above the floor (head of a KidSize robot)
    "pitch": 0.45,  # rad: nominal, > 0 looks down
    "roll": 0.0,  # rad: nominal
    "head": copy.deepcopy(walk.HEAD_DEFAULTS),
    "imaging": {
        "blur": 0.55,  # px: lens blur (Gaussian sigma) at the image centre
        "corner_blur": 2.2,  # px: lens blur in the image corners
        "vignetting": 0.45,  # fraction of light lost in the corners
        "chromatic_aberration": 1.2,  # px: red/blue lateral shift in the corners
        "exposure_time": 0.012,  # s: head motion during the exposure blurs the frame
        "noise_sigma": 2.0,  # read noise (grey levels)
        "shot_noise": 0.35,  # sigma = shot_noise * sqrt(level)
        "bayer": True,  # RGGB mosaic + bilinear demosaicing (colour fringes)
        "chroma_subsample": 2,  # horizontal chroma subsampling (YUV 4:2:2); 1: none
        "jpeg_quality": 0,  # > 0: JPEG round trip at this quality (frames stored as JPEG)
    },
    # the carpet's sheen: at grazing view angles artificial turf reflects the hall's light,
    # brighter and less saturated far away; share of the sheen colour at a ray along the floor
    "sheen": 0.0,
    "sheen_power": 3.0,  # falls off as (1 - |cos|)^power towards looking straight down
    "sheen_bgr": [196, 204, 204],
}

_CEILING = np.array([46, 44, 48], np.float32)  # BGR, as the omni renderer's
# the edges of the unit cube, 5 points each (distortion bends projected edges outwards)
_UNIT_OUTLINE = np.unique(np.array(
    [[t if k == axis else a, t if k2 == axis else b_, t if k3 == axis else c_]
     for axis in range(3) for t in np.linspace(0, 1, 5)
     for a in (0.0, 1.0) for b_ in (0.0, 1.0) for c_ in (0.0, 1.0)
     for k, k2, k3 in [(0, 1, 2)]]), axis=0)
_FAR = np.float32(1e9)


def _times_matrix(v: np.ndarray, m: np.ndarray) -> np.ndarray:
    """v @ m for rows v (..., 3) and a 3 x 3 m, each entry v0 m0j + v1 m1j + v2 m2j in this
    order: the rendered pixels do not depend on the BLAS kernel a processor selects."""
    return v[..., 0, None] * m[0] + v[..., 1, None] * m[1] + v[..., 2, None] * m[2]


def _merged(conf: dict | None) -> dict:
    c = copy.deepcopy(PERSPECTIVE_DEFAULTS)
    for key, value in (conf or {}).items():
        if isinstance(value, dict) and isinstance(c.get(key), dict):
            c[key].update(value)
        else:
            c[key] = value
    return c


def camera_from_conf(c: dict) -> PerspectiveCamera:
    """The PerspectiveCamera the renderer draws with (the truth, before any calibration
    error), from the renderer conf (the same keys as calib.yaml)."""
    d = {k: c[k] for k in ("image_size", "intrinsics", "distortion", "height", "pitch", "roll")
         if k in c}
    d["kind"] = "perspective"
    try:
        return PerspectiveCamera.from_dict(d, "conf 'perspective'")
    except DatasetError as e:
        raise FieldlocError(str(e)) from None


# the ranges of the list-valued keys (common.conf.check_bounds, held where simulate's conf is
# resolved); the camera's own checks (a distortion that does not fold the image, the
# intrinsics) are calib.yaml's, in camera_from_conf
BOUNDS = {"image_size": (1, MAX_IMAGE_PX, 2), "distortion": (None, None, (4, 5)),
          "sheen_bgr": BGR, **{f"head.{k}": b for k, b in walk.HEAD_BOUNDS.items()}}


def check_conf(section: dict | None) -> None:
    """The renderer's conf section (merged with the defaults) makes a camera (FieldlocError,
    one line): checked before anything is rendered."""
    camera_from_conf(_merged(section))


# calib_error's mount keys and the largest magnitude each may take: a camera screwed in a few
# degrees off its drawing and a height measured a few centimetres wrong; larger values are a
# misread unit (degrees, millimetres), not a miscalibration to simulate
MOUNT_ERROR_LIMITS = {"pitch_offset": (0.15, "rad"), "roll_offset": (0.15, "rad"),
                      "height_offset": (0.2, "m")}


# px: the largest principal point shift calib_error may give (a principal point read off by a
# tenth of the image is a gross miscalibration; beyond, the written camera is another camera
# whose lens model extract refuses)
MAX_CENTRE_SHIFT_PX = 100.0


def check_calib_error(calib_error: dict) -> None:
    """calib_error's mount keys within MOUNT_ERROR_LIMITS and its centre shift within
    MAX_CENTRE_SHIFT_PX (FieldlocError, one line)."""
    check_bounds(calib_error, {"centre_shift": (-MAX_CENTRE_SHIFT_PX, MAX_CENTRE_SHIFT_PX, 2)},
                 prefix="calib_error.")
    for key, (limit, unit) in MOUNT_ERROR_LIMITS.items():
        value = calib_error.get(key, 0.0)
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise FieldlocError(f"calib_error.{key} must be a number ({unit}), got"
                                f" {str(value)[:40]!r}") from None
        if not abs(v) <= limit:
            raise FieldlocError(f"calib_error.{key} must be within +-{limit:g} {unit}, got"
                                f" {v:g}")


def perturbed_camera(cam: PerspectiveCamera, calib_error: dict) -> PerspectiveCamera:
    """The camera as a miscalibration would record it: principal point shifted by
    ``centre_shift`` px and the focal lengths scaled by ``scale``; the mount recorded as
    ``pitch_offset`` and ``roll_offset`` (rad) when the rendering camera has none, and the
    height as the true one plus ``height_offset`` (m)."""
    du, dv = (float(v) for v in calib_error.get("centre_shift", (0.0, 0.0)))
    scale = float(calib_error.get("scale", 1.0))
    if scale <= 0:
        raise FieldlocError(f"calibration error scale must be > 0, got {scale}")
    check_calib_error(calib_error)
    return PerspectiveCamera(
        image_size=cam.image_size, fx=cam.fx * scale, fy=cam.fy * scale, cx=cam.cx + du,
        cy=cam.cy + dv, distortion=cam.distortion.copy(),
        height=cam.height + float(calib_error.get("height_offset", 0.0)), pitch=cam.pitch,
        roll=cam.roll, yaw=cam.yaw,
        pitch_offset=cam.pitch_offset + float(calib_error.get("pitch_offset", 0.0)),
        roll_offset=cam.roll_offset + float(calib_error.get("roll_offset", 0.0)),
    )


class PerspectiveRenderer:
    """Renders frames of a :class:`~stages.simulate.scene.FieldScene` through a humanoid's
    head camera."""

    kind = "perspective"

    def __init__(self, conf: dict | None, scene, seed: int = 0):
        c = _merged(conf)
        self.conf = c
        self.scene = scene
        self.seed = int(seed)
        self.camera = camera_from_conf(c)
        self.head = None  # per-frame head motion, from prepare()
        self._build_rays()
        self._build_lens()
        self._build_textures()

    # ------------------------------------------------------------------ construction
    def _build_rays(self):
        cam = self.camera
        w, h = cam.image_size
        u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
        xy = cam.undistort_normalized(cam._to_normalized(np.stack([u, v], -1)))
        ray = np.concatenate([xy, np.ones((h, w, 1))], -1)
        self.valid_ray = np.isfinite(ray).all(-1)
        ray = np.nan_to_num(ray, nan=0.0)
        ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
        ray[~self.valid_ray] = (0.0, -1.0, 0.0)  # outside the lens model: straight up
        self.ray_planes = [np.ascontiguousarray(ray[..., k], dtype=np.float32) for k in range(3)]

    def _build_lens(self):
        cam = self.camera
        im = self.conf["imaging"]
        w, h = cam.image_size
        u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
        du, dv = u - np.float32(cam.cx), v - np.float32(cam.cy)
        rc = math.hypot(max(cam.cx, w - 1 - cam.cx), max(cam.cy, h - 1 - cam.cy))
        rn = np.sqrt(du * du + dv * dv) / np.float32(rc)  # 0 centre .. 1 corner
        self.vignette = (1.0 - float(im["vignetting"]) * rn**3.0).astype(np.float32)
        self.corner_weight = np.clip(rn**2.5, 0, 1).astype(np.float32)[..., None]
        ca = float(im["chromatic_aberration"]) / rc
        self.ca_maps = [
            fixed_maps(np.float32(cam.cx) + du * np.float32(1 + s * ca),
                       np.float32(cam.cy) + dv * np.float32(1 + s * ca))
            for s in (1.0, -1.0)  # red outwards, blue inwards
        ]
        # RGGB mosaic in one remap: the source is the B, G, R planes stacked vertically
        # (3h, w); each sensor site reads its colour's plane, red and blue at radially scaled
        # positions (the chromatic aberration)
        site = np.ones((h, w), np.float32)  # plane index: 0 B, 1 G, 2 R
        site[0::2, 0::2] = 2
        site[1::2, 1::2] = 0
        scale = np.float32(1) + np.float32(ca) * (site - 1)
        mx = np.clip(np.float32(cam.cx) + du * scale, 0, w - 1)
        my = np.clip(np.float32(cam.cy) + dv * scale, 0, h - 1) + site * h
        self.mosaic_maps = fixed_maps(mx, my)
        self.noise_bank = np.random.default_rng([self.seed, 0x9E25]).standard_normal(
            (h + 64, w + 64), dtype=np.float32)

    def _build_textures(self):
        sc = self.scene
        # far carpet: a prefiltered copy at 4 texels, blended in where a pixel covers several
        h, w = sc.albedo.shape[:2]
        size = (max(1, w // 4), max(1, h // 4))
        self.albedo_far = cv2.resize(cv2.GaussianBlur(sc.albedo, (0, 0), 1.5), size,
                                     interpolation=cv2.INTER_AREA)
        self.far_scale = (np.float32(size[0] / w), np.float32(size[1] / h))
        self.line_bgr = np.asarray(sc.conf["line_bgr"], np.float32)

    # ------------------------------------------------------------------ the walk
    def prepare(self, path) -> dict:
        """Head motion over ``path`` (a Trajectory). Returns the CSV files to write beside the
        dataset: ``head`` (the measured angles, what the robot records) and ``head_truth``
        (the angles the frames were rendered with), as {stem: (csv kind, columns)}."""
        rng = np.random.default_rng([self.seed, 0x4EAD])
        cam = self.camera
        self.head = walk.head_motion(path.stamps, path.poses, cam.pitch, cam.roll,
                                     self.conf["head"], rng)
        stamps = np.asarray(path.stamps, dtype=float)
        return {
            "head": ("head", {"stamp": stamps, "pitch": self.head["measured_pitch"],
                              "roll": self.head["measured_roll"]}),
            "head_truth": ("head", {"stamp": stamps, "pitch": self.head["pitch"],
                                    "roll": self.head["roll"]}),
        }

    def head_at(self, frame: int) -> tuple[float, float, tuple[float, float, float]]:
        """True (pitch, roll, (yaw_rate, pitch_rate, roll_rate)) at ``frame``; the nominal
        angles and no motion before prepare()."""
        if self.head is None or frame >= len(self.head["pitch"]):
            return self.camera.pitch, self.camera.roll, (0.0, 0.0, 0.0)
        h = self.head
        return (float(h["pitch"][frame]), float(h["roll"][frame]),
                (float(h["yaw_rate"][frame]), float(h["pitch_rate"][frame]),
                 float(h["roll_rate"][frame])))

    # ------------------------------------------------------------------ rendering
    def render(self, pose, frame: int) -> np.ndarray:
        """The BGR uint8 image seen from ``pose`` (x, y, theta) at ``frame`` of the scene, with
        the head angles of the walk (see prepare)."""
        pitch, roll, rates = self.head_at(frame)
        return self.render_view(pose, pitch, roll, frame, rates)

    def render_view(self, pose, pitch: float, roll: float, frame: int = 0,
                    angular_rate=(0.0, 0.0, 0.0), return_layers: bool = False):
        """The frame seen from ``pose`` with the head at ``pitch``/``roll``; ``angular_rate``
        (yaw, pitch, roll rates, rad/s) blurs along the head's motion. With ``return_layers``
        also a dict of bool masks ``objects`` (opaque things: posts, crossbar, robots, people,
        ball) and ``floor`` (carpet not covered by things) and ``floor_xy`` (field coordinates
        of each pixel's floor point, NaN off the floor)."""
        img, layers = self.scene_image(pose, pitch, roll, frame, layers=return_layers)
        out = self._imaging(img, frame, angular_rate)
        return (out, layers) if return_layers else out

    def _field_rotation(self, pose, pitch, roll) -> np.ndarray:
        c, s = math.cos(pose[2]), math.sin(pose[2])
        rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return _times_matrix(rz, head_rotation(self.camera.yaw, pitch, roll))

    def scene_image(self, pose, pitch, roll, frame, layers: bool = True):
        """BGR float32 scene (display levels, before the camera's imaging) and, with
        ``layers``, the layers of render_view (else None)."""
        cam = self.camera
        sc = self.scene
        R = self._field_rotation(pose, pitch, roll)
        rx, ry, rz = self.ray_planes
        dx = rx * np.float32(R[0, 0]) + ry * np.float32(R[0, 1]) + rz * np.float32(R[0, 2])
        dy = rx * np.float32(R[1, 0]) + ry * np.float32(R[1, 1]) + rz * np.float32(R[1, 2])
        dz = rx * np.float32(R[2, 0]) + ry * np.float32(R[2, 1]) + rz * np.float32(R[2, 2])
        px, py, pz = float(pose[0]), float(pose[1]), float(cam.height)
        wx0, wx1, wy0, wy1 = sc.walls
        with np.errstate(divide="ignore", invalid="ignore"):
            # rays that miss the floor (or meet it beyond the hall) end 100 m away
            t_floor = np.minimum(np.float32(pz) / np.maximum(-dz, np.float32(1e-6)),
                                 np.float32(100.0))
            tx = np.maximum((wx1 - px) / dx, (wx0 - px) / dx)
            ty = np.maximum((wy1 - py) / dy, (wy0 - py) / dy)
        np.minimum(tx, _FAR, out=tx)  # rays parallel to a wall never reach it
        np.minimum(ty, _FAR, out=ty)
        t_wall = np.minimum(tx, ty)
        floor = (t_floor < t_wall) & self.valid_ray
        FX = px + t_floor * dx
        FY = py + t_floor * dy
        img = self._floor(FX, FY, floor)
        if float(self.conf["sheen"]) > 0:
            self._sheen(img, dz, floor)
        depth = np.minimum(t_floor, t_wall)
        rows = np.nonzero(~floor.all(axis=1))[0]
        if len(rows):
            band = slice(int(rows[0]), int(rows[-1]) + 1)
            wall = ~floor[band]
            img[band] = np.where(wall[..., None], self._walls(
                dx[band], dy[band], dz[band], tx[band], ty[band], t_wall[band], px, py, pz),
                img[band])
        # upright things, each tested per pixel inside its projected bounding box
        movers = sc.movers_at(frame)
        cyls = list(sc.posts) + [c for parts in movers for c in parts]
        casters = [c for c in cyls[len(sc.posts):] if c.z0 <= 0 and c.kind != "marker"]
        # shadow boxes reach 2.4 x the shadow's scale (darkening < 0.5 % at their edge)
        boxes = [(c.x - 2.4 * self._shadow_reach(c), c.y - 2.4 * self._shadow_reach(c),
                  c.x + 2.4 * self._shadow_reach(c), c.y + 2.4 * self._shadow_reach(c),
                  0.0, 0.0) for c in casters]
        boxes += [(p.p0[0], p.p0[1], p.p1[0], p.p1[1], p.z0, p.z1) for p in sc.panels]
        boxes += [(c.x - c.radius, c.y - c.radius, c.x + c.radius, c.y + c.radius, c.z0, c.z1)
                  for c in cyls]
        crops = self._crops(pose, pitch, roll, self._box_outlines(boxes)) if boxes else []
        rays = (dx, dy, dz)
        objects = np.zeros(floor.shape, bool)
        k = 0
        for c in casters:
            if crops[k] is not None:
                self._shadow(img, FX, FY, floor, crops[k], c)
            k += 1
        for p in sc.panels:
            if crops[k] is not None:
                self._panel(img, depth, objects, rays, pose, crops[k], p)
            k += 1
        for c in cyls:
            if crops[k] is not None:
                self._cylinder(img, depth, objects, rays, pose, crops[k], c)
            k += 1
        if not layers:
            return img, None
        x0, x1, y0, y1 = sc.field.world_bounds()
        on_carpet = floor & (FX >= x0) & (FX <= x1) & (FY >= y0) & (FY <= y1)
        FX[~floor] = np.nan
        FY[~floor] = np.nan
        return img, {"objects": objects, "floor": on_carpet & ~objects,
                     "floor_xy": np.stack([FX, FY], -1)}

    def _floor(self, FX, FY, floor) -> np.ndarray:
        sc = self.scene
        ar = np.float32(sc.albedo_res)
        mx = (FX - np.float32(sc.walls[0])) / ar - np.float32(0.5)
        my = (FY - np.float32(sc.walls[2])) / ar - np.float32(0.5)
        # the floor footprint of one pixel: Jacobian of (FX, FY) by finite differences
        jux, juy, jvx, jvy = (np.empty_like(FX) for _ in range(4))
        np.subtract(FX[:, 1:], FX[:, :-1], out=jux[:, :-1])
        np.subtract(FY[:, 1:], FY[:, :-1], out=juy[:, :-1])
        np.subtract(FX[1:], FX[:-1], out=jvx[:-1])
        np.subtract(FY[1:], FY[:-1], out=jvy[:-1])
        jux[:, -1], juy[:, -1] = jux[:, -2], juy[:, -2]
        jvx[-1], jvy[-1] = jvx[-2], jvy[-2]
        foot = np.maximum(np.abs(jux) + np.abs(juy), np.abs(jvx) + np.abs(jvy))
        # carpet colour: 1 cm texels where a pixel covers about one, the prefiltered 4 cm copy
        # on the rows above, where a pixel covers several (the split chosen per frame)
        h, w = FX.shape
        far_rows = np.median(foot[:, :: max(1, w // 8)], axis=1) > np.float32(
            3 * sc.albedo_res)
        split = int(np.argmin(far_rows)) if not far_rows.all() else h
        img = np.empty((h, w, 3), np.float32)
        if split < h:
            img[split:] = remap_linear(sc.albedo, mx[split:], my[split:], cv2.BORDER_REPLICATE)
        if split > 0:
            kx, ky = self.far_scale
            img[:split] = remap_linear(
                self.albedo_far, (mx[:split] + np.float32(0.5)) * kx - np.float32(0.5),
                (my[:split] + np.float32(0.5)) * ky - np.float32(0.5), cv2.BORDER_REPLICATE)
        # lines: coverage of the footprint across the line (normal from cos 2phi, sin 2phi)
        lx0, ly0 = sc.line_origin
        lr = np.float32(sc.line_res)
        lmx = (FX - np.float32(lx0)) / lr
        lmy = (FY - np.float32(ly0)) / lr
        lf = remap_linear(sc.line_field, lmx, lmy, cv2.BORDER_CONSTANT, (50.0, 1.0, 0.0, 0.0))
        hw = np.float32(0.5 * sc.field.line_width)
        cand = (lf[..., 0] < hw + np.float32(0.5) * foot) & floor
        idx = np.nonzero(cand)
        if len(idx[0]):
            dn, c2n, s2n, paint = lf[idx].T
            norm = np.sqrt(c2n * c2n + s2n * s2n)
            inv = np.float32(1.0) / np.maximum(norm, np.float32(1e-6))
            c2n *= inv
            s2n *= inv
            coverage_of_normal = np.minimum(norm, np.float32(1.0))
            half = np.float32(0.5)

            def across(jx, jy):
                q = half * (jx * jx * (1 + c2n) + jy * jy * (1 - c2n)) + jx * jy * s2n
                return np.sqrt(np.maximum(q, 0))

            a = across(jux[idx], juy[idx]) + across(jvx[idx], jvy[idx])
            fp = coverage_of_normal * a + (1 - coverage_of_normal) * foot[idx]
            fp = np.maximum(fp, np.float32(1e-4))
            cover = (np.minimum(dn + half * fp, hw) - np.maximum(dn - half * fp, -hw)) / fp
            cover = np.clip(cover, 0, 1) * np.clip(paint, 0, 1)
            llr = np.float32(sc.line_light_res)
            bright = sample_texture(sc.line_light, (FX[idx] - np.float32(lx0)) / llr,
                             (FY[idx] - np.float32(ly0)) / llr)
            col = self.line_bgr[None, :] * bright[:, None]
            sub = img[idx]
            img[idx] = sub + (col - sub) * cover[:, None]
        return img

    def _sheen(self, img, dz, floor):
        """Blend the floor towards the sheen colour by sheen * (1 - |dz|)^sheen_power (dz: the
        ray's vertical component, -1 looking straight down) (in place)."""
        k = np.float32(self.conf["sheen"]) * (np.float32(1.0) - np.abs(dz)) ** np.float32(
            self.conf["sheen_power"])
        k = np.where(floor, k, np.float32(0.0))[..., None]
        img += (np.asarray(self.conf["sheen_bgr"], np.float32)[None, None, :] - img) * k

    def _walls(self, dx, dy, dz, tx, ty, t_wall, px, py, pz) -> np.ndarray:
        """Wall texture (or the ceiling above the walls) for a band of rows; the perimeter
        coordinate as in the omni renderer: from (x0, y0) along +x, then +y, -x, -y."""
        sc = self.scene
        x0, x1, y0, y1 = sc.walls
        lx, ly = x1 - x0, y1 - y0
        hx = px + t_wall * dx
        hy = py + t_wall * dy
        s = np.where(ty <= tx, np.where(dy < 0, hx - x0, lx + ly + (x1 - hx)),
                     np.where(dx > 0, lx + (hy - y0), 2 * lx + ly + (y1 - hy)))
        z = pz + t_wall * dz
        wr = np.float32(sc.wall_res)
        mx = np.clip(s / wr, -1.0, 1e6).astype(np.float32)
        my = np.clip(z / wr, -1.0, 1e6).astype(np.float32)
        tex = remap_linear(sc.wall_texture, mx, my, cv2.BORDER_WRAP).astype(np.float32)
        hgt = float(sc.conf["wall_height"])
        tex *= (0.75 + 0.25 * np.clip(z / hgt, 0, 1)).astype(np.float32)[..., None]
        return np.where((z > hgt)[..., None], _CEILING, tex)

    # ------------------------------------------------------------------ upright things
    def _crops(self, pose, pitch, roll, outlines: np.ndarray) -> list:
        """Image (rows, columns) slices that can show each thing whose outline (field-frame
        3-D points, (M, K, 3)) is given; None for things behind the camera or off the image."""
        cam = self.camera
        w, h = cam.image_size
        c, s = math.cos(pose[2]), math.sin(pose[2])
        rel = outlines - np.array([pose[0], pose[1], cam.height])
        robot = np.stack([c * rel[..., 0] + s * rel[..., 1], -s * rel[..., 0] + c * rel[..., 1],
                          rel[..., 2]], -1)
        camc = _times_matrix(robot, cam.rotation(pitch, roll))
        near = 0.02
        front = camc[..., 2] > near
        uv = cam.camera_points_to_pixels(np.where(front[..., None], camc, 1.0), inside=False,
                                         clamp=True)
        uv[~front] = np.nan
        out = []
        for m in range(len(outlines)):
            if not front[m].any():
                out.append(None)
                continue
            if front[m].all():
                pts = uv[m]
            else:
                # reaches behind the camera: add the outline's crossings of the near plane
                # (pairs of points in front and behind span the part in front, a convex set)
                a, b = camc[m][front[m]][:, None, :], camc[m][~front[m]][None, :, :]
                k = (a[..., 2] - near) / (a[..., 2] - b[..., 2])
                cut = (a + (b - a) * k[..., None]).reshape(-1, 3)
                cut[:, 2] = near
                pts = cam.camera_points_to_pixels(np.concatenate([camc[m][front[m]], cut]),
                                                  inside=False, clamp=True)
            lo = np.floor(np.nanmin(pts, 0)).astype(int) - 3
            hi = np.ceil(np.nanmax(pts, 0)).astype(int) + 4
            u0, v0 = max(lo[0], 0), max(lo[1], 0)
            u1, v1 = min(hi[0], w), min(hi[1], h)
            out.append((slice(v0, v1), slice(u0, u1)) if u1 > u0 and v1 > v0 else None)
        return out

    @staticmethod
    def _box_outlines(boxes) -> np.ndarray:
        """Points on the edges (corners and 3 points between) of boxes (M, 6): x0, y0, x1, y1,
        z0, z1; a box with x0, y0 -> x1, y1 along a panel gives the panel's outline."""
        b = np.asarray(boxes, float).reshape(-1, 6)
        u = _UNIT_OUTLINE
        x = b[:, None, 0] + (b[:, None, 2] - b[:, None, 0]) * u[None, :, 0]
        y = b[:, None, 1] + (b[:, None, 3] - b[:, None, 1]) * u[None, :, 1]
        z = b[:, None, 4] + (b[:, None, 5] - b[:, None, 4]) * u[None, :, 2]
        return np.stack([x, y, z], -1)

    def _cylinder(self, img, depth, objects, rays, pose, crop, cyl):
        r = float(cyl.radius)
        ball = cyl.kind == "ball"
        dx, dy, dz = (a[crop] for a in rays)
        ox, oy = np.float32(pose[0] - cyl.x), np.float32(pose[1] - cyl.y)
        pz = np.float32(self.camera.height)
        with np.errstate(invalid="ignore", divide="ignore"):
            if ball:  # a sphere of the cylinder's radius at half its height
                oz = pz - np.float32(0.5 * (cyl.z0 + cyl.z1))
                b = ox * dx + oy * dy + oz * dz
                disc = b * b - (ox * ox + oy * oy + oz * oz - r * r)
                t = -b - np.sqrt(disc)
                hit = (disc > 0) & (t > 0.02)
                nz = (oz + t * dz) / r
            else:
                a2 = dx * dx + dy * dy
                b = ox * dx + oy * dy
                disc = b * b - a2 * (ox * ox + oy * oy - r * r)
                t = (-b - np.sqrt(disc)) / a2
                z = pz + t * dz
                hit = (disc > 0) & (t > 0.02) & (z >= cyl.z0) & (z <= cyl.z1)
                # the top cap (seen from above) and the bottom cap
                for zc in (cyl.z1, cyl.z0):
                    tc = (np.float32(zc) - pz) / dz
                    cx_, cy_ = ox + tc * dx, oy + tc * dy
                    cap = (tc > 0.02) & (cx_ * cx_ + cy_ * cy_ <= r * r) & ~(hit & (t <= tc))
                    t = np.where(cap, tc, t)
                    hit |= cap
                nz = None
        hit &= t < depth[crop]
        if not hit.any():
            return
        hx, hy = ox + t * dx, oy + t * dy
        face = -(hx * dx + hy * dy) / (r * np.sqrt(dx * dx + dy * dy) + np.float32(1e-6))
        shade = np.float32(0.55) + np.float32(0.45) * np.clip(face, 0, 1)
        if ball:
            shade = shade * np.sqrt(np.clip(1 - nz * nz, 0.1, 1)) + np.float32(0.2) * np.clip(
                nz, 0, 1)
        else:
            z = pz + t * dz
            shade = shade * (np.float32(0.85) + np.float32(0.15) * np.clip(z / 1.5, 0, 1))
        col = np.asarray(cyl.bgr, np.float32)[None, None, :] * shade[..., None]
        sub = img[crop]
        sub[hit] = col[hit]
        depth[crop][hit] = t[hit]
        objects[crop] |= hit

    def _panel(self, img, depth, objects, rays, pose, crop, panel):
        (x0, y0), (x1, y1) = panel.p0, panel.p1
        dx, dy, dz = (a[crop] for a in rays)
        ex, ey = np.float32(x1 - x0), np.float32(y1 - y0)
        qx, qy = np.float32(x0 - pose[0]), np.float32(y0 - pose[1])
        den = dx * ey - dy * ex
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (qx * ey - qy * ex) / den
            u = (qx * dy - qy * dx) / den
        z = np.float32(self.camera.height) + t * dz
        vis = (t > 0.05) & (u >= 0) & (u <= 1) & (z >= panel.z0) & (z <= panel.z1) & (
            t < depth[crop])
        if not vis.any():
            return
        col = np.asarray(panel.bgr, np.float32)
        sub = img[crop]
        if panel.net:  # strings every 10 cm, see-through between them
            idx = np.nonzero(vis)
            s = u[idx] * np.float32(2 * np.pi / 0.1 * math.hypot(float(ex), float(ey)))
            zz = z[idx] * np.float32(2 * np.pi / 0.1)
            mesh = 0.5 + 0.5 * np.maximum(np.cos(s) ** 8, np.cos(zz) ** 8)
            a = (np.float32(panel.alpha) * mesh)[:, None]
            px = sub[idx]
            sub[idx] = px + (col - px) * a
        else:
            sub[vis] = col * 0.95
            depth[crop][vis] = t[vis]
            objects[crop] |= vis

    @staticmethod
    def _shadow_reach(cyl) -> float:
        return cyl.radius * 1.6 + 0.08

    def _shadow(self, img, FX, FY, floor, crop, cyl):
        """A soft shadow on the floor around the foot of a mover (light from the ceiling)."""
        reach = self._shadow_reach(cyl)
        d2 = (FX[crop] - np.float32(cyl.x)) ** 2 + (FY[crop] - np.float32(cyl.y)) ** 2
        s = 1.0 - 0.5 * np.exp(-d2 / np.float32(2 * (0.75 * reach) ** 2))
        s = np.where(floor[crop], s, 1.0).astype(np.float32)
        img[crop] *= s[..., None]

    # ------------------------------------------------------------------ the camera
    def _imaging(self, img, frame: int, angular_rate) -> np.ndarray:
        sc = self.scene
        im = self.conf["imaging"]
        h, w = img.shape[:2]
        # lateral chromatic aberration: red scaled outwards, blue inwards (with the Bayer
        # mosaic below, in the same remap)
        if float(im["chromatic_aberration"]) > 0 and not im["bayer"]:
            b_ch, g_ch, r_ch = cv2.split(img)
            (rx, ry), (bx, by) = self.ca_maps
            r_ch = cv2.remap(r_ch, rx, ry, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            b_ch = cv2.remap(b_ch, bx, by, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            img = cv2.merge([b_ch, g_ch, r_ch])
        # lens blur growing towards the corners (the corner blur at half resolution)
        if float(im["blur"]) > 0:
            sharp = cv2.GaussianBlur(img, (0, 0), float(im["blur"]))
        else:
            sharp = img
        if float(im["corner_blur"]) > 0:
            small = cv2.resize(img, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
            soft = cv2.resize(cv2.GaussianBlur(small, (0, 0), float(im["corner_blur"]) / 2),
                              (w, h), interpolation=cv2.INTER_LINEAR)
            np.subtract(soft, sharp, out=soft)
            soft *= self.corner_weight
            soft += sharp
            img = soft
        else:
            img = sharp
        # head motion during the exposure
        yaw_rate, pitch_rate, _ = (float(v) for v in angular_rate)
        f = self.camera.fx
        su = yaw_rate * float(im["exposure_time"]) * f
        sv = pitch_rate * float(im["exposure_time"]) * f
        length = math.hypot(su, sv)
        if length > 0.7:
            n = int(math.ceil(length / 2)) + 1
            k = np.zeros((2 * n + 1, 2 * n + 1), np.float32)
            for s in np.linspace(-0.5, 0.5, 4 * n + 1):
                k[int(round(n + s * sv)), int(round(n + s * su))] += 1
            img = cv2.filter2D(img, -1, k / k.sum())
        # light level, white balance, vignetting; sensor noise from a bank shifted per frame
        gain, wb = frame_light(sc, frame)
        wb = wb.astype(np.float32)
        rng = np.random.default_rng([self.seed, int(frame), 0x9E25])
        oy, ox = (int(v) for v in rng.integers(0, 64, 2))
        noise = noise_window(self.noise_bank, rng, oy, ox, h, w)
        read, shot = im["noise_sigma"], im["shot_noise"]
        if im["bayer"]:
            planes = np.ascontiguousarray(img.transpose(2, 0, 1)).reshape(3 * h, w)
            raw = cv2.remap(planes, *self.mosaic_maps, cv2.INTER_LINEAR)
            raw *= self.vignette
            gb, gg, gr = (float(v) for v in np.float32(gain) * wb)
            raw[0::2, 0::2] *= gr
            raw[0::2, 1::2] *= gg
            raw[1::2, 0::2] *= gg
            raw[1::2, 1::2] *= gb
            add_sensor_noise(raw, noise, shot, read)
            raw8 = np.clip(raw + 0.5, 0, 255).astype(np.uint8)
            out = cv2.cvtColor(raw8, cv2.COLOR_BayerBG2BGR)
        else:
            img = img * (self.vignette[..., None] * (np.float32(gain) * wb))
            add_sensor_noise(img, noise[..., None], shot, read)
            out = np.clip(img + 0.5, 0, 255).astype(np.uint8)
        out = chroma_subsample(out, int(im["chroma_subsample"]), "decimate")
        return jpeg_round_trip(out, int(im.get("jpeg_quality", 0)))
