"""Omnidirectional (catadioptric) camera renderer: what a MSL robot's mirror camera shows.

Geometry. The mirror model is an :class:`OmniCamera` (the SURF template paper, eq. 2): a floor
point at distance d from the robot appears at image radius r with d = f(r), a fifth-order
polynomial, around an image centre offset from the middle of the 480 x 480 image, at image angle
``forward_angle + bearing``. Beyond the valid radius the depression angle of the viewing ray keeps
falling at ``outer_elevation_rate`` rad/px, so the outer ring shows the far floor, the walls, the
audience and the horizon, up to the mirror's rim. The effective viewpoint sits
``viewpoint_height`` above the floor: an upright thing at horizontal distance t covers the pixels
whose ray reaches height z = H - t tan(depression) within the thing's height span.

Rendering happens on a polar grid (rows: image radius in ``polar_step`` px; columns: image angle
in ``polar_bearings`` steps). The camera is fixed to the robot, so each row's floor distance,
depression angle and pixel footprint, and the polar-to-image map, are computed once. Per frame:
the floor points of the grid move to the field frame (an outer product of row distances and
column directions), the world textures are sampled with cv2.remap on the 1/32-texel grid of
stages.common.fixed_remap (carpet colour, then the line
field), lines get the coverage of the pixel footprint across the line (so far lines fade
instead of aliasing), shadows fall around the feet of things, walls, goals, robots, people and the
ball are drawn where their ray heights say (with a depth buffer), the grid is remapped to the
image, and the robot's own body, the struts of the mirror mount, reflections and the dark
surroundings of the mirror are laid over it. Imaging: vignetting, light level and white balance
of the frame, lens blur, chroma subsampling (the paper's camera delivers YUV 4:1:1), shot and read
noise, optional JPEG artefacts.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ..common.camera import MAX_IMAGE_PX, POLYNOMIAL_COEFFICIENTS, OmniCamera, fit_polynomial
from ..common.conf import PAIR
from ..common.errors import DatasetError, FieldlocError, shown
from ..common.fixed_remap import fixed_maps, remap_linear
from .imaging import add_sensor_noise, chroma_subsample, frame_light, jpeg_round_trip, noise_window
from .scene import sample_texture

# A mirror of our own design: about 40 px at 0.28 m (the body edge), 120 px at 1 m, 180 px at
# 3 m, 200 px at 5.8 m, increasing over the whole image (max floor distance ~16 m at 228 px).
DEFAULT_POLYNOMIAL = [-2.12375, 0.150314, -0.00356398, 4.06874e-05, -2.15966e-07, 4.39107e-10]
# A mirror with the resolution of the MINHO team's own (Ribeiro et al. 2015; minho-lab
# mirror.cfg, smoothed: a
# fifth-order f(r) fitted to the table's 26 marks with pixel-space weights): 0.3 m at 40 px,
# 1 m at 94 px (41 px/m), 2 m at 123 px (24 px/m), 3 m at 145 px (20 px/m), 4 m at 164 px
# (17 px/m), 6.5 m at 193 px. Far lines keep 2-3 px of width, where DEFAULT_POLYNOMIAL's
# 7-11 px/m beyond 3 m leaves them about one pixel under the blur of a real mirror.
TEAM_MIRROR_POLYNOMIAL = [-4.27859, 0.265008, -0.00566672, 5.74037e-05, -2.64699e-07,
                          4.6791e-10]

OMNI_DEFAULTS = {
    "image_size": [480, 480],  # width, height (px)
    "centre": [244.0, 236.5],  # image centre of the mirror (px), off the middle of the image
    "polynomial": DEFAULT_POLYNOMIAL,  # f(r) = sum a_i r^i: floor distance (m) at radius r (px)
    "valid_radius": [40.0, 228.0],  # px: body mask .. outer limit of the usable floor
    "forward_angle": math.pi / 2,  # rad: image angle of the robot's +x (up in the image)
    "mirrored": False,
    "viewpoint_height": 0.75,  # m above the floor
    "rim_radius": 236.0,  # px: the mirror's edge; darkness beyond
    "outer_elevation_rate": 0.03,  # rad/px: how fast rays rise beyond the valid radius
    "body_radius": 37.0,  # px: the robot's own body seen in the mirror
    "struts_deg": [40.0, 130.0, 220.0, 310.0],  # image angles of the mirror mount's struts
    "strut_width": 6.0,  # px
    "shadow_depth": 0.5,  # share of the light a mover's shadow takes at its foot
    "shadow_length": 0.0,  # m of shadow reach per m of the mover's height (beyond its foot)
    "polar_bearings": 1280,  # columns of the polar grid
    "polar_step": 1.0,  # px between rows of the polar grid
    "imaging": {
        "vignetting": 0.45,  # light lost at the rim
        "blur_sigma": 0.8,  # px, lens blur
        "exposure_time": 0.01,  # s: the robot's turning during the exposure smears the world
        "saturation": 0.85,  # chroma kept by the camera's colour processing
        "knee": 0.8,  # share of full scale above which highlights are compressed
        "chroma_subsample": 4,  # horizontal chroma subsampling (1: none)
        "noise_sigma": 2.0,  # read noise (grey levels)
        "shot_noise": 0.35,  # shot noise: sigma = shot_noise * sqrt(level)
        "jpeg_quality": 0,  # > 0: JPEG round trip at this quality
    },
}


# the ranges of the list-valued keys (common.conf.check_bounds, held where simulate's conf is
# resolved); the camera's own checks (centre inside the image, an increasing f(r) over a
# valid ring) are calib.yaml's, in camera_from_conf
MAX_STRUTS = 16  # a mirror mount has a few struts; 0: none
# m: the farthest floor distance f(r) may give at the body edge (the inner valid radius): the
# diagonal of the largest field with its border is about 25 m; beyond, no floor is in view
MAX_FLOOR_RANGE_M = 100.0
BOUNDS = {"image_size": (1, MAX_IMAGE_PX, 2), "centre": (None, None, 2),
          "polynomial": (None, None, POLYNOMIAL_COEFFICIENTS),
          "valid_radius": (0, None, PAIR), "struts_deg": (-360.0, 360.0, (0, MAX_STRUTS))}


def camera_from_conf(c: dict) -> OmniCamera:
    """The OmniCamera the renderer draws with (the truth, before any calibration error), read
    as extract reads calib.yaml (its checks: six coefficients, the centre inside the image, an
    f(r) increasing over the valid ring)."""
    d = {k: c[k] for k in ("image_size", "centre", "polynomial", "valid_radius",
                           "forward_angle", "mirrored") if k in c}
    d.update(kind="omni", version=1)
    try:
        cam = OmniCamera.from_dict(d, "conf 'omni'")
    except DatasetError as e:
        raise FieldlocError(str(e)) from None
    inner = float(cam.distance_of_radius(cam.valid_radius[0]))
    if not inner <= MAX_FLOOR_RANGE_M:
        raise FieldlocError(
            f"conf 'omni.polynomial' places the floor at the body edge {inner:.3g} m away (f(r)"
            f" at valid_radius {cam.valid_radius[0]:g} px); a mirror sees floor nearer than"
            f" {MAX_FLOOR_RANGE_M:g} m")
    return cam


def check_conf(section: dict | None) -> None:
    """The renderer's conf section (merged with the defaults) makes a camera, and its mirror
    keys agree with it (FieldlocError, one line): checked before anything is rendered, after
    each key's own range (simulate.SCALAR_BOUNDS): the body seen in the mirror must leave floor
    in view (``body_radius`` below the outer valid radius and the rim)."""
    c = _merged(section)
    outer = camera_from_conf(c).valid_radius[1]
    edge = min(outer, float(c["rim_radius"]))
    if not float(c["body_radius"]) < edge:
        raise FieldlocError(f"conf 'omni.body_radius' must be below the outer valid radius and"
                            f" rim_radius, {edge:g} px (the floor seen beyond the body), got"
                            f" {shown(c['body_radius'], 40)}")


CALIB_ERROR_DEFAULTS = {
    "centre_shift": [0.0, 0.0],  # px: written centre minus the true one
    "scale": 1.0,  # written f(r) = scale * fitted f(r)
    # a team's mirror table (the MINHO mirror.cfg format): ground marks every `table_step` m
    # out to `table_range` m, their image radii read off with a smooth error (correlated over
    # `radius_error_length_px` of image radius) whose size makes the fitted f(r) place the floor
    # `distance_error` m off (rms over the table's floor); 0: the true f(r) is written
    "distance_error": 0.0,
    "radius_error_length_px": 20.0,
    "table_step": 0.25,
    "table_range": 4.0,
}
_TABLE_ATTEMPTS = 50  # draws of the table's error until its fit is increasing


def _table_marks(cam: OmniCamera, step: float, reach: float):
    """(radius px, distance m) of a mirror table's marks on the true camera: the body edge and
    every ``step`` m out to ``reach``."""
    d0 = float(cam.distance_of_radius(cam.valid_radius[0]))
    d = np.r_[d0, step * np.arange(math.floor(d0 / step) + 1, math.floor(reach / step + 1e-9) + 1)]
    r = cam.radius_of_distance(d)
    ok = np.isfinite(r)
    if ok.sum() < 8:
        raise FieldlocError(f"calib_error: a mirror table out to {reach:g} m every {step:g} m"
                            f" holds only {int(ok.sum())} marks on the floor; 8 are needed")
    return r[ok], d[ok]


def _distance_error(cam: OmniCamera, coef, d) -> float:
    """rms over true distances ``d`` of (written distance - true distance), metres."""
    w = np.polynomial.polynomial.polyval(cam.radius_of_distance(d), coef)
    return float(np.sqrt(np.mean((w - d) ** 2)))


def team_calibration(cam: OmniCamera, calib_error: dict, rng: np.random.Generator):
    """What a team's calibration of the true camera ``cam`` writes: f(r) fitted (fifth order,
    ``fit_polynomial`` as ``fieldloc calibrate``) to a mirror table whose radii are read off
    with a smooth random error (a squared-exponential correlation over
    ``radius_error_length_px``), its size chosen so that the fit places the floor
    ``distance_error`` m off (rms over the table's floor, uniform in distance). A draw whose fit
    does not increase is measured again, as a team would when the calibration tool refuses it.
    Returns (coefficients, outer valid radius: the table's last mark, as read).

    On minho-distance (real: the team's own table against lines at known distances) the
    calibration places the line 4-16 cm too far from 1 to 2 m (0.10 m rms over 0.5-2.25 m), in
    one bump; px errors grow in metres with distance, where the mirror flattens."""
    ce = {**CALIB_ERROR_DEFAULTS, **calib_error}
    target = float(ce["distance_error"])
    step, reach = float(ce["table_step"]), float(ce["table_range"])
    length = float(ce["radius_error_length_px"])
    if not (0 < target < 0.5) or step <= 0 or length <= 0:
        raise FieldlocError("calib_error: 0 < distance_error < 0.5, table_step > 0 and"
                            " radius_error_length_px > 0 are needed")
    r, d = _table_marks(cam, step, reach)
    judged = np.linspace(d[0], d[-1], 64)
    grid = np.linspace(r[0], r[-1], max(8, int(np.ceil(4 * (r[-1] - r[0]) / length)) + 1))
    chol = np.linalg.cholesky(np.exp(-0.5 * ((grid[:, None] - grid[None, :]) / length) ** 2)
                              + 1e-9 * np.eye(len(grid)))

    def off(error):  # metres off of the f(r) fitted to radii read with this error (px)
        return _distance_error(cam, fit_polynomial(r + error, d, degree=5)[0], judged)

    for _ in range(_TABLE_ATTEMPTS):
        shape = np.interp(r, grid, chol @ rng.standard_normal(len(grid)))
        lo, hi = 0.0, 1.0  # size of the reading error: bisect the written error
        while off(hi * shape) < target and hi < 1e3:
            lo, hi = hi, 2 * hi
        for _ in range(30):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if off(mid * shape) < target else (lo, mid)
        read = r + hi * shape
        coef = fit_polynomial(read, d, degree=5)[0]
        rr = np.linspace(cam.valid_radius[0], read[-1], 1000)
        if np.all(np.diff(read) > 0) and np.all(np.diff(
                np.polynomial.polynomial.polyval(rr, coef)) > 0):
            return coef, float(read[-1])
    raise FieldlocError(f"calib_error: no increasing f(r) in {_TABLE_ATTEMPTS} draws of a table"
                        f" with distance_error {target:g}; make it smaller")


def perturbed_camera(cam: OmniCamera, calib_error: dict,
                     rng: np.random.Generator | None = None) -> OmniCamera:
    """The camera as a miscalibration would record it: with ``distance_error`` > 0 the f(r)
    of a team's mirror table (:func:`team_calibration`, drawn from ``rng``) and a valid radius
    that ends at the table's last mark; then the centre shifted by ``centre_shift`` px and f(r)
    scaled by ``scale``."""
    ce = {**CALIB_ERROR_DEFAULTS, **calib_error}
    du, dv = (float(v) for v in ce["centre_shift"])
    scale = float(ce["scale"])
    if scale <= 0:
        raise FieldlocError(f"calibration error scale must be > 0, got {scale}")
    poly = np.asarray(cam.polynomial, dtype=float)
    valid = cam.valid_radius
    if float(ce["distance_error"]) != 0:
        coef, outer = team_calibration(cam, ce, np.random.default_rng(0) if rng is None else rng)
        poly, valid = coef, (cam.valid_radius[0], outer)
    return OmniCamera(
        image_size=cam.image_size,
        centre=(cam.centre[0] + du, cam.centre[1] + dv),
        polynomial=poly * scale,
        valid_radius=valid,
        forward_angle=cam.forward_angle,
        mirrored=cam.mirrored,
    )


def _merged(conf: dict | None) -> dict:
    out = {**OMNI_DEFAULTS, **(conf or {})}
    out["imaging"] = {**OMNI_DEFAULTS["imaging"], **(conf or {}).get("imaging", {})}
    return out


class OmniRenderer:
    """Renders frames of a :class:`~stages.simulate.scene.FieldScene` through an omni camera."""

    kind = "omni"

    def __init__(self, conf: dict | None, scene, seed: int = 0):
        c = _merged(conf)
        self.conf = c
        self.scene = scene
        self.seed = int(seed)
        self._yaw_rate = None
        self.camera = camera_from_conf(c)
        cam = self.camera
        self.H = float(c["viewpoint_height"])
        self.sign = -1.0 if cam.mirrored else 1.0
        w, h = cam.image_size
        rim = float(c["rim_radius"])
        step = float(c["polar_step"])
        nb = int(c["polar_bearings"])
        r0 = max(float(c["body_radius"]) - 4.0, 1.0)
        self.radii = np.arange(r0, rim + 3.0, step)
        r = self.radii
        rv = cam.valid_radius[1]
        d = cam.distance_of_radius(np.minimum(r, rv))
        d = np.maximum(d, 0.02)
        depress = np.arctan2(self.H, d)
        beyond = r > rv
        # rays rise with the radius up to the zenith and no further (past it, their tangent
        # would turn positive again and the far rows would look at the floor once more)
        depress[beyond] = np.maximum(math.atan2(self.H, float(cam.distance_of_radius(rv))) - float(
            c["outer_elevation_rate"]
        ) * (r[beyond] - rv), -math.pi / 2)
        self.tan_depression = np.tan(depress)
        ground = self.tan_depression > 1e-6
        self.distance = np.where(ground, self.H / np.maximum(self.tan_depression, 1e-6), np.inf)
        dd = np.gradient(np.where(ground, self.distance, 1e4), r)
        self.footprint_radial = np.abs(dd).astype(np.float32)  # m per image px along the ray
        self.footprint_tangential = (np.where(ground, self.distance, 1e4) / r).astype(
            np.float32)
        self._fp_max = np.maximum(self.footprint_radial, self.footprint_tangential)[ground]
        self.tan_depression = self.tan_depression.astype(np.float32)
        self._neg_tan = -self.tan_depression
        self.n_ground = int(ground.sum())  # ground rows come first (depression falls with r)
        self.alpha = 2 * np.pi * np.arange(nb) / nb
        self.bearing = self.sign * (self.alpha - cam.forward_angle)
        # polar grid -> image map (one extra wrap-around column)
        uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        du, dv = uu - cam.centre[0], vv - cam.centre[1]
        rad = np.hypot(du, dv)
        ang = np.mod(np.arctan2(-dv, du), 2 * np.pi)
        mx = (ang / (2 * np.pi) * nb).astype(np.float32)
        my = ((rad - r0) / step).astype(np.float32)
        self._to_image = fixed_maps(mx, my)
        self._radius_px = rad.astype(np.float32)
        colour, alpha = self._robot_overlay(rad, ang)
        vig = float(c["imaging"]["vignetting"])
        vignette = (1.0 - vig * np.clip(rad / rim, 0, 1) ** 2.5).astype(np.float32)
        self._keep = ((1.0 - alpha) * vignette)[..., None].astype(np.float32)
        self._overlay = (colour * (alpha * vignette)[..., None]).astype(np.float32)
        # tone curve on quarter grey levels 0..399.75: linear up to the knee, then compressed
        # towards a level above full scale so the brightest parts still clip at 255
        levels = np.arange(1600, dtype=np.float64) / 4.0
        knee = 255.0 * float(c["imaging"]["knee"])
        top = 275.0 - knee
        tone = np.where(levels > knee, knee + top * np.tanh((levels - knee) / max(top, 1e-6)),
                        levels)
        self._tone = np.clip(np.round(tone), 0, 255).astype(np.uint8)
        self._noise = np.random.default_rng([self.seed, 0x401CE]).standard_normal(
            (h + 97, w + 89, 3), dtype=np.float32)

    def prepare(self, path) -> dict:
        """Take the robot's path (a Trajectory) for motion blur: its turn rate per frame.
        Writes no extra files."""
        th = np.unwrap(np.asarray(path.poses, dtype=float)[:, 2])
        t = np.asarray(path.stamps, dtype=float)
        self._yaw_rate = np.gradient(th, t) if len(t) > 1 else np.zeros(len(t))
        return {}

    # ------------------------------------------------------------------ robot-fixed parts
    def _robot_overlay(self, rad, ang):
        """Colour and opacity of what is fixed to the robot: its body, the mount's struts, the
        reflections, and the dark surroundings of the mirror."""
        c = self.conf
        cam = self.camera
        w, h = cam.image_size
        rng = np.random.default_rng([self.seed, 0x0B0D1])
        colour = np.zeros((h, w, 3), np.float32)
        alpha = np.zeros((h, w), np.float32)
        rim = float(c["rim_radius"])
        body = float(c["body_radius"])
        # outside the mirror: the camera's dark housing
        out = np.clip(rad - rim, 0, 1).astype(np.float32)
        colour += out[..., None] * np.array([19, 22, 20], np.float32)
        alpha = np.maximum(alpha, out)
        ring = np.clip(1.0 - np.abs(rad - rim + 1.0) / 2.0, 0, 1).astype(np.float32)
        colour = colour * (1 - ring[..., None]) + ring[..., None] * np.array([70, 72, 70])
        alpha = np.maximum(alpha, ring)
        # struts of the mirror mount: dark bars from the body to the rim
        k = 4
        strut = np.zeros((h * k, w * k), np.uint8)
        glint = np.zeros((h * k, w * k), np.uint8)
        cu, cv_ = cam.centre
        for deg in c["struts_deg"]:
            a = math.radians(deg)
            p0 = (cu + body * 0.8 * math.cos(a), cv_ - body * 0.8 * math.sin(a))
            p1 = (cu + (rim + 5) * math.cos(a), cv_ - (rim + 5) * math.sin(a))
            q0 = tuple(int(round(v * k * 16)) for v in p0)
            q1 = tuple(int(round(v * k * 16)) for v in p1)
            cv2.line(strut, q0, q1, 255, int(round(c["strut_width"] * k)), cv2.LINE_8, 4)
            off = (c["strut_width"] * 0.25) * np.array([math.sin(a), math.cos(a)])
            g0 = tuple(int(round((p + o) * k * 16)) for p, o in zip(p0, off))
            g1 = tuple(int(round((p + o) * k * 16)) for p, o in zip(p1, off))
            cv2.line(glint, g0, g1, 255, max(1, k), cv2.LINE_8, 4)
        sa = cv2.resize(strut, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
        ga = cv2.resize(glint, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
        sa *= (rad > body * 0.8).astype(np.float32)
        strut_col = np.array([24, 24, 27], np.float32)[None, None] * np.ones((h, w, 1))
        strut_col = strut_col + ga[..., None] * 60.0
        colour = colour * (1 - sa[..., None]) + strut_col * sa[..., None]
        alpha = np.maximum(alpha, sa)
        # the body: dark, a lighter ring of the mount, a few bright screws/LEDs, the lens
        b = np.clip(body + 0.5 - rad, 0, 1).astype(np.float32)
        shade = (1.0 - 0.35 * np.clip(rad / body, 0, 1)).astype(np.float32)
        body_col = np.array([52, 44, 50], np.float32) * shade[..., None]
        ringb = np.clip(1.0 - np.abs(rad - 0.82 * body) / 2.5, 0, 1)[..., None]
        body_col = body_col * (1 - ringb) + ringb * np.array([95, 90, 98])
        lens = np.clip(0.35 * body - rad, 0, 1)[..., None]
        body_col = body_col * (1 - lens) + lens * np.array([22, 20, 24])
        for j in range(4):
            a = math.radians(45 + 90 * j + rng.uniform(-8, 8))
            px, py = cu + 0.72 * body * math.cos(a), cv_ - 0.72 * body * math.sin(a)
            uu = np.arange(w)[None, :] - px
            vv = np.arange(h)[:, None] - py
            spot = np.exp(-(uu * uu + vv * vv) / (2 * 2.2**2))[..., None]
            body_col = body_col * (1 - spot) + spot * np.array([238, 240, 245])
        colour = colour * (1 - b[..., None]) + body_col * b[..., None]
        alpha = np.maximum(alpha, b)
        colour += rng.normal(0, 2.0, colour.shape)
        return colour.astype(np.float32), alpha.astype(np.float32)

    # ------------------------------------------------------------------ per frame
    def render(self, pose, frame: int) -> np.ndarray:
        """The BGR uint8 image seen from ``pose`` (x, y, theta) at ``frame`` of the scene."""
        sc = self.scene
        x, y, th = (float(v) for v in pose)
        nr, nb = len(self.radii), len(self.alpha)
        ng = self.n_ground
        psi = th + self.bearing
        cpsi, spsi = np.cos(psi).astype(np.float32), np.sin(psi).astype(np.float32)
        dist = self.distance[:ng].astype(np.float32)[:, None]
        gx = x + dist * cpsi[None, :]
        gy = y + dist * spsi[None, :]

        polar = np.empty((nr, nb + 1, 3), np.float32)  # + a wrap-around column
        img = polar[:, :nb]
        depth = np.full((nr, nb), np.inf, np.float32)
        depth[:ng] = dist
        # floor colour
        ax0, ay0 = sc.walls[0], sc.walls[2]
        ar = sc.albedo_res
        mx = (gx - ax0) / ar - 0.5
        my = (gy - ay0) / ar - 0.5
        floor = remap_linear(sc.albedo, mx, my, cv2.BORDER_REPLICATE)
        floor = floor.astype(np.float32)
        # lines: coverage of the pixel footprint across the line
        lx0, ly0 = sc.line_origin
        lr = sc.line_res
        lf = remap_linear(sc.line_field, (gx - lx0) / lr, (gy - ly0) / lr, cv2.BORDER_CONSTANT,
                          (50.0, 1.0, 0.0, 0.0))
        dline, c2, s2, wear = lf[..., 0], lf[..., 1], lf[..., 2], lf[..., 3]
        img[:ng] = floor
        img[ng:] = 0.0
        # only cells near a line can be covered: the widest footprint bounds the search
        hw = 0.5 * sc.field.line_width
        reach = hw + 0.5 * self._fp_max[:, None]
        near = np.nonzero(dline < reach)
        if len(near[0]):
            ri, ci = near
            c2n, s2n = c2[near], s2[near]
            c2psi = (cpsi * cpsi - spsi * spsi)[ci]
            s2psi = (2 * cpsi * spsi)[ci]
            norm = np.sqrt(c2n * c2n + s2n * s2n) + 1e-6
            cos2 = (c2n * c2psi + s2n * s2psi) / norm
            along = np.sqrt(np.clip(0.5 * (1 + cos2), 0, 1))  # |cos| of line normal vs ray
            across = np.sqrt(np.clip(0.5 * (1 - cos2), 0, 1))
            fp = self.footprint_radial[ri] * along + self.footprint_tangential[ri] * across
            fp += 1e-4
            dn = dline[near]
            cover = (np.minimum(dn + 0.5 * fp, hw) - np.maximum(dn - 0.5 * fp, -hw)) / fp
            cover = (np.clip(cover, 0.0, 1.0) * np.clip(wear[near], 0.0, 1.0))[:, None]
            llr = sc.line_light_res
            bright = sample_texture(sc.line_light, (gx[near] - lx0) / llr,
                                    (gy[near] - ly0) / llr)
            line_col = np.asarray(sc.conf["line_bgr"], np.float32) * bright[:, None]
            img[near] = floor[near] * (1 - cover) + line_col * cover

        movers = sc.movers_at(frame)
        self._shadows(img, dist[:, 0], x, y, th, movers)
        self._walls(img, depth, x, y, cpsi, spsi)
        for panel in sc.panels:
            self._panel(img, depth, x, y, cpsi, spsi, panel)
        things = list(sc.posts) + [cyl for parts in movers for cyl in parts]
        for cyl in things:
            self._cylinder(img, depth, x, y, th, cyl)
        return self._image(polar, frame)

    def _columns(self, x, y, th, cx, cy, half_width):
        """Indices of the polar columns whose rays pass within ``half_width`` rad of the world
        point (cx, cy), and the angle of each ray from that point's direction."""
        wb = math.atan2(cy - y, cx - x)
        rel = wb - th  # bearing in the robot frame
        a_c = self.sign * rel + self.camera.forward_angle
        nb = len(self.alpha)
        j_c = a_c / (2 * np.pi) * nb
        span = int(math.ceil(half_width / (2 * np.pi) * nb)) + 1
        idx = np.arange(int(math.floor(j_c)) - span, int(math.ceil(j_c)) + span + 1) % nb
        delta = (th + self.bearing[idx] - wb + np.pi) % (2 * np.pi) - np.pi
        return idx, delta

    def _rows(self, tmin: float, tmax: float, z0: float, z1: float) -> slice:
        """The polar rows whose rays can reach heights z0..z1 at horizontal distances
        tmin..tmax (the depression angle falls with the row)."""
        hi_tan = (self.H - z0) / max(tmin, 1e-6)
        lo_tan = (self.H - z1) / max(tmax, 1e-6)
        neg = self._neg_tan
        return slice(int(np.searchsorted(neg, -hi_tan, "left")),
                     int(np.searchsorted(neg, -lo_tan, "right")))

    def _shadows(self, img, dist, x, y, th, movers):
        """Soft shadows on the floor around the feet of movers (light from the ceiling): a
        Gaussian dip of ``shadow_depth`` whose reach grows by ``shadow_length`` per metre of the
        thing's height (several lamps: a person's legs darken the carpet well beyond the feet)."""
        depth_share = float(self.conf["shadow_depth"])
        length = float(self.conf["shadow_length"])
        for parts in movers:
            for cyl in parts:
                if cyl.z0 > 0 or cyl.kind == "marker":
                    continue
                dc = math.hypot(cyl.x - x, cyl.y - y)
                reach = cyl.radius * 1.6 + 0.08 + length * (cyl.z1 - cyl.z0)
                if dc < 0.3 or dc - reach > dist[-1]:
                    continue
                half = math.asin(min(1.0, reach / dc))
                idx, delta = self._columns(x, y, th, cyl.x, cyl.y, half)
                rows = np.flatnonzero((dist > dc - reach) & (dist < dc + reach))
                if len(rows) == 0:
                    continue
                dd = dist[rows][:, None]
                d2 = dd * dd + dc * dc - 2 * dd * dc * np.cos(delta)[None, :]
                s = 1.0 - depth_share * np.exp(-d2 / (2 * (0.4 * reach) ** 2))  # ~1 at the edge
                r0, r1 = rows[0], rows[-1] + 1
                img[r0:r1, idx] *= s[..., None].astype(np.float32)

    def _walls(self, img, depth, x, y, cpsi, spsi):
        sc = self.scene
        x0, x1, y0, y1 = sc.walls
        big = 1e9
        with np.errstate(divide="ignore", invalid="ignore"):
            tx = np.where(cpsi > 1e-9, (x1 - x) / cpsi, np.where(cpsi < -1e-9, (x0 - x) / cpsi,
                                                                  big))
            ty = np.where(spsi > 1e-9, (y1 - y) / spsi, np.where(spsi < -1e-9, (y0 - y) / spsi,
                                                                  big))
        t = np.minimum(tx, ty).astype(np.float32)
        hx, hy = x + t * cpsi, y + t * spsi
        # position along the wall perimeter: bottom (+x), right (+y), top (-x), left (-y)
        lx, ly = x1 - x0, y1 - y0
        s = np.where(
            ty <= tx,
            np.where(spsi < 0, hx - x0, lx + ly + (x1 - hx)),
            np.where(cpsi > 0, lx + (hy - y0), 2 * lx + ly + (y1 - hy)),
        )
        # only rows whose rays reach the floor beyond the nearest wall can see a wall
        band = slice(self._rows(float(t.min()), float(t.max()), 0.0, 1e6).start,
                     len(self.radii))
        zb = self.H - t[None, :] * self.tan_depression[band, None]
        vb = (zb >= 0) & (t[None, :] < depth[band])
        if not vb.any():
            return
        wr = sc.wall_res
        mx = np.broadcast_to((s / wr).astype(np.float32)[None, :], zb.shape)
        my = (zb / wr).astype(np.float32)
        tex = remap_linear(sc.wall_texture, mx, my, cv2.BORDER_WRAP).astype(np.float32)
        hgt = sc.conf["wall_height"]
        ceiling = np.array([46, 44, 48], np.float32)
        tex = np.where((zb > hgt)[..., None], ceiling, tex)
        # walls are lit from above
        tex *= (0.75 + 0.25 * np.clip(zb / hgt, 0, 1))[..., None]
        img[band] = np.where(vb[..., None], tex, img[band])
        depth[band] = np.where(vb, t[None, :], depth[band])

    def _panel(self, img, depth, x, y, cpsi, spsi, panel):
        (px0, py0), (px1, py1) = panel.p0, panel.p1
        ex, ey = px1 - px0, py1 - py0
        den = cpsi * ey - spsi * ex
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((px0 - x) * ey - (py0 - y) * ex) / den
            u = ((px0 - x) * spsi - (py0 - y) * cpsi) / den
        hit = np.isfinite(t) & (t > 0.3) & (u >= 0) & (u <= 1)
        idx = np.flatnonzero(hit)
        if len(idx) == 0:
            return
        t = t[idx].astype(np.float32)
        rows = self._rows(float(t.min()), float(t.max()), panel.z0, panel.z1)
        tan = self.tan_depression[rows, None]
        z = self.H - t[None, :] * tan
        sub_depth = depth[rows, idx]
        vis = (z >= panel.z0) & (z <= panel.z1) & (t[None, :] < sub_depth)
        if not vis.any():
            return
        col = np.asarray(panel.bgr, np.float32)
        sub = img[rows, idx]
        if panel.net:
            s = u[idx] * math.hypot(ex, ey)
            mesh = 0.5 + 0.5 * np.maximum(np.cos(2 * np.pi * s / 0.1) ** 8,
                                          (np.cos(2 * np.pi * z / 0.1) ** 8))
            a = (panel.alpha * mesh * vis).astype(np.float32)
            img[rows, idx] = sub * (1 - a[..., None]) + col * a[..., None]
        else:
            img[rows, idx] = np.where(vis[..., None], col * 0.95, sub)
            depth[rows, idx] = np.where(vis, t[None, :], sub_depth)

    def _cylinder(self, img, depth, x, y, th, cyl):
        dc = math.hypot(cyl.x - x, cyl.y - y)
        if dc < cyl.radius + 0.3:  # would be inside our own body
            return
        half = math.asin(min(1.0, cyl.radius / dc))
        idx, delta = self._columns(x, y, th, cyl.x, cyl.y, half)
        off = dc * np.sin(delta)
        inside = (np.abs(off) < cyl.radius) & (np.abs(delta) < np.pi / 2)
        idx, delta, off = idx[inside], delta[inside], off[inside]
        if len(idx) == 0:
            return
        t = (dc * np.cos(delta) - np.sqrt(cyl.radius**2 - off**2)).astype(np.float32)
        rows = self._rows(float(t.min()), float(t.max()), cyl.z0, cyl.z1)
        z = self.H - t[None, :] * self.tan_depression[rows, None]
        sub_depth = depth[rows, idx]
        vis = (z >= cyl.z0) & (z <= cyl.z1) & (t[None, :] < sub_depth)
        if not vis.any():
            return
        face = np.sqrt(np.clip(1 - (off / cyl.radius) ** 2, 0, 1))  # 1 facing us, 0 at edge
        shade = (0.55 + 0.45 * face)[None, :] * (0.85 + 0.15 * np.clip(z / 1.5, 0, 1))
        if cyl.kind == "ball":
            zc = (z - 0.5 * (cyl.z0 + cyl.z1)) / (0.5 * (cyl.z1 - cyl.z0))
            shade = shade * np.sqrt(np.clip(1 - zc**2, 0.1, 1))
        col = np.asarray(cyl.bgr, np.float32)[None, None, :] * shade[..., None]
        img[rows, idx] = np.where(vis[..., None], col, img[rows, idx])
        depth[rows, idx] = np.where(vis, t[None, :], sub_depth)

    # ------------------------------------------------------------------ imaging
    def _image(self, polar, frame: int) -> np.ndarray:
        """Polar grid (with its wrap-around column) -> the camera's BGR uint8 image."""
        sc = self.scene
        im = self.conf["imaging"]
        nb = polar.shape[1] - 1
        if self._yaw_rate is not None and frame < len(self._yaw_rate):
            # turning during the exposure smears the world (not the robot's own parts) along
            # the image angle: a box over the columns swept, wrapping around
            swept = abs(self._yaw_rate[frame]) * float(im["exposure_time"]) / (2 * np.pi) * nb
            k = int(round(swept))
            if k >= 2:
                pad = k // 2 + 1
                ext = np.concatenate([polar[:, nb - pad: nb], polar[:, :nb], polar[:, :pad]],
                                     axis=1)
                polar[:, :nb] = cv2.blur(ext, (k, 1))[:, pad: pad + nb]
        polar[:, -1] = polar[:, 0]
        img = cv2.remap(polar, self._to_image[0], self._to_image[1], cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
        img *= self._keep  # the robot's own parts, with the vignetting folded in
        img += self._overlay
        if im["blur_sigma"] > 0:
            img = cv2.GaussianBlur(img, (0, 0), float(im["blur_sigma"]))
        # light level, white balance and the camera's colour saturation: one 3 x 3 transform
        sat = float(im["saturation"])
        luma = np.array([0.114, 0.587, 0.299], np.float32)
        colour = sat * np.eye(3, dtype=np.float32) + (1.0 - sat) * np.outer(
            np.ones(3, np.float32), luma)
        gain, wb = frame_light(sc, frame)
        light = (gain * wb).astype(np.float32)
        img = cv2.transform(img, colour * light[None, :])
        # sensor noise: read noise plus shot noise, from a bank shifted per frame
        rng = np.random.default_rng([self.seed, int(frame), 0x1A6E])
        h, w = img.shape[:2]
        oy, ox = (int(v) for v in rng.integers(0, (self._noise.shape[0] - h,
                                                    self._noise.shape[1] - w)))
        add_sensor_noise(img, noise_window(self._noise, rng, oy, ox, h, w),
                         im["shot_noise"], im["noise_sigma"])
        # tone curve (highlights compressed above the knee, clipped at full scale) by a table
        np.clip(img, 0.0, 399.0, out=img)
        out = self._tone[(img * 4.0).astype(np.int32)]
        # chroma shared by k neighbouring pixels of a row (a box over k, as in YUV 4:1:1)
        out = chroma_subsample(out, int(im["chroma_subsample"]), "box")
        return jpeg_round_trip(out, int(im["jpeg_quality"]))
