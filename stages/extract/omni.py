"""Line points of an omnidirectional (catadioptric) image along the scan lines of
Ribeiro et al. (2015).

The scan lines are the ones of the tables (stages.common.scanlines.ScanLines): 72 radial lines
(line k at 5k deg counter-clockwise from the robot's forward direction) and 72 + 72 spirals
(start angle 5k deg, direction 0 counter-clockwise, 1 clockwise). They are walked in the image
through the calibration (stages.common.camera.OmniCamera):

- once per calibration (``ScanLinePixels``, cached): every scan line is sampled densely in the
  image (radial lines along their image ray at ``SAMPLE_STEP_PX``, spirals from their ground
  polyline resampled to the same pixel spacing), rounded to pixels, consecutive duplicates
  removed; each pixel keeps the ground position of the samples it holds (robot frame, metres),
  its ground distance from the robot centre and the ground arc length along its scan line;
  the distinct pixels (~40,000 of a 480 x 480 frame) are listed once with their blocks of the
  local green map;
- per frame (``extract_frame``): only those pixels are read and classified, and
  the few that the field green and the local green map are estimated from, the whole-frame
  estimates' (stages.common.colour's pixel samples: compiled, no whole-frame pass); then run
  detection on the concatenated class sequence (one compiled pass,
  ``_white_runs``; its thresholds are ``RUNS``, tuned constants, and the preset's
  ``max_white_m``). Short holes are closed first (up to ``white_hole_px`` non-white
  pixels between white ones, up to ``max_gap_px`` unclassified pixels between green ones),
  then a crossing is a white run with a green run (>= ``min_green_px`` pixels and >=
  ``min_green_m``) before and after it, allowing up to ``max_gap_px`` unclassified pixels
  (blurred edges) in between, a width (between the mid-points of its edges, in ground metres
  along the line) of at least ``min_white_m`` and ``min_white_px`` pixels, and a depth (how far
  it reaches away from the robot) of at most ``max_white_m`` (runs of up to ``far_white_px``
  pixels always pass: far away one pixel spans more than a line's width). The middle of the
  white run in ground metres is the line point.
- a spiral reports only its first crossing: when white that is not a crossing comes before it
  (a graze along a line, a corner, the robot standing on a line at the spiral's start) the
  first crossing is unseen and the spiral reports none (on rendered frames this keeps 97 % of
  the reported spirals within 5 cm of the table instead of 72 %).

Only every ``SPIRAL_START_STEP``-th spiral start angle is walked (2: 36 spirals each way, 10 deg
apart, as in the paper); the others stay NaN. Radial crossings closer together than the
extraction can separate merge into one white run (rejected if deeper than ``max_white_m``).

Per frame (the features schema, stages.common.features_file):
    radial     (72, 4)  distances (m) of the first 4 crossings per radial line, nearest first,
                        NaN padded (the tables' layout at heading 0)
    spiral     (2, 72)  ground radius (m) of the first crossing per spiral, NaN if none
    points     (N, 2)   every crossing found (radial, spiral, then the optional extra radial
                        lines of ``points_radial_lines``) in the robot frame (x forward, y left)
    points_px  (N, 2)   the same points in the image (u, v)

Teams with their own line detector bring line points instead of images;
``stages.common.scanlines.bin_points_to_scanlines`` turns them into the same radial/spiral
layout.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import math
from types import MappingProxyType
from typing import NamedTuple

import numpy as np

from ..common import colour
from ..common.jit import njit
from ..common.scanlines import MAX_RANGE_M, ScanLines

_SL = ScanLines()

# the colour classes (stages.common.colour, whose defaults the perspective extractor's COLOUR
# shares): its defaults, read only; the preset's "colour" group holds the keys a user sets for
# a venue (USER_COLOUR_KEYS), laid over these by colour_conf
COLOUR = MappingProxyType(copy.deepcopy(colour.confs["default"]))
# the minimum green ellipse: a camera whose chroma noise speckles the carpet needs a wider one
# (docs/team-formats.md, the NuBot frame: -c colour.green_axes=[24,24])
USER_COLOUR_KEYS = ("green_axes",)

# px, the sampling of a scan line in the image before rounding to pixels: half a pixel, so that
# consecutive samples fall on the same or a neighbouring pixel (duplicates are merged)
SAMPLE_STEP_PX = 0.5
# walk every 2nd spiral start angle: 36 spirals each way, 10 deg apart, as in Ribeiro et al.
# (2015); the others stay NaN
SPIRAL_START_STEP = 2

# What the user chooses; the tuned numbers are named constants beside their code: COLOUR,
# SAMPLE_STEP_PX, SPIRAL_START_STEP and RUNS (the run detection's thresholds).
confs = {
    "default": {
        # the venue's colour keys (USER_COLOUR_KEYS; the others are COLOUR's)
        "colour": {k: copy.deepcopy(COLOUR[k]) for k in USER_COLOUR_KEYS},
        # the scan lines; must equal the map's (stages.build_map conf)
        "scanlines": {
            "robot_radius": _SL.robot_radius,
            "max_range": _SL.max_range,
            "spiral_end_radius": _SL.spiral_end_radius,
        },
        # m, the deepest white run that is a crossing (how far it reaches away from the robot;
        # runs of up to RUNS.far_white_px pixels always pass): deeper white is wider than any
        # line (a white patch, a graze along a line)
        "max_white_m": 0.4,
        "points_radial_lines": 0,  # extra radial lines (evenly spaced) for `points`; 0 = none
    },
}
# denser line points for the heading histogram: 360 extra radial lines, 1 deg apart
confs["dense"] = {**copy.deepcopy(confs["default"]), "points_radial_lines": 360}
# real catadioptric images (minho-lab): bright lines bloom and blur over several pixels where one
# pixel spans 0.1-0.25 m, so a line crossed at 3-4 m gives a white run up to ~0.6 m deep. On
# rendered frames this lets a few grazing runs through (table agreement within 5 cm 0.975 ->
# 0.962 on omni-clean), so the default keeps 0.4.
confs["real"] = {**copy.deepcopy(confs["default"]), "max_white_m": 0.6}


def former_layout() -> dict:
    """The tuned constants at the conf keys they held before they left the preset. A features
    file written then stored them in its conf; extract compares them with these values to
    tell whether the file can be resumed or reused (stages.extract)."""
    return {"colour": {k: v for k, v in COLOUR.items() if k not in USER_COLOUR_KEYS},
            "sample_step_px": SAMPLE_STEP_PX, "spiral_start_step": SPIRAL_START_STEP,
            **RUNS._asdict()}


# the ranges the extractor's numeric keys must lie in to run at all (common.conf.check_bounds,
# checked when the conf is resolved): a range of 0 m leaves no scan line (the colour keys'
# ranges are colour.BOUNDS: a pair given one number unpacks into nothing)
BOUNDS = {**{f"colour.{k}": colour.BOUNDS[k] for k in USER_COLOUR_KEYS},
          "scanlines.robot_radius": (0, None),
          "scanlines.max_range": ((0,), MAX_RANGE_M),
          "scanlines.spiral_end_radius": ((0,), MAX_RANGE_M),
          "points_radial_lines": (0, 3600),
          # a line's white run is centimetres deep (blooming on real frames: up to ~0.6 m)
          "max_white_m": ((0,), 5.0)}


def check_conf(conf: dict) -> None:
    """What BOUNDS does not say (FieldlocError): the scan lines must be walkable, as
    build-map's are (common.scanlines.ScanLines.check)."""
    scanlines_of(conf).check("conf 'scanlines': ")


def colour_conf(conf: dict) -> dict:
    """The full colour conf the colour functions take: COLOUR with the conf's venue keys."""
    return {**COLOUR, **conf["colour"]}


def scanlines_of(conf: dict) -> ScanLines:
    """The scan-line definition of an extraction conf."""
    s = conf["scanlines"]
    return ScanLines(robot_radius=float(s["robot_radius"]), max_range=float(s["max_range"]),
                     spiral_end_radius=float(s["spiral_end_radius"]))


# ---------------------------------------------------------------------------- precomputation


@dataclasses.dataclass
class ScanLinePixels:
    """Every scan line of one calibration as image pixels, concatenated line after line.

    Per sample: ``u``, ``v`` (int), ``line`` (index into the lines), ``s`` (ground arc length
    along the line, m), ``dist`` (ground distance from the robot centre, m), ``xy`` (ground
    point in the robot frame, m), ``uv`` (sub-pixel image position). Lines: radial 0..71,
    spirals 72..215 (72 + 72 * direction + start index), then the extra radial lines.

    The pixels the samples lie on, each once (``pixels``, flat indices v * w + u; a pixel that
    several lines cross is a sample of each, ``sample_pixel``), are what a frame reads and
    classifies (stages.common.colour's pixel samples), in raster order, with their blocks of
    the local green map and their floor flags from the dataset mask (``blocks``).

    The field green and the local green map are estimated from the pixels that
    stages.common.colour.estimate_field_colour takes of the floor annulus (the annulus of the
    radial lines, ``radius_px``, and the mask), read alone: ``colour_flat``, one pixel in
    FIELD_COLOUR_STEP x FIELD_COLOUR_STEP (~2,000), and ``map_flat``, 2 x 2 per block of the
    local green map (~5,000), so that both are the whole-frame estimates. Not from the
    scan-line pixels: the scan lines run across and along the field lines, and in a block a
    line passes through the green pixels they cross are mostly its bright blurred edge (in a
    dark frame of omni-default, seed 3, such blocks came out 5-24 grey levels above their
    carpet and the frame lost half its crossings); the field green from one scan-line pixel
    per 6 x 6 px cell was 1.6 grey levels off on average, which moved real minho-lab frames'
    points enough to change their localisation.
    """

    scanlines: ScanLines
    u: np.ndarray
    v: np.ndarray
    line: np.ndarray
    s: np.ndarray
    dist: np.ndarray
    xy: np.ndarray
    uv: np.ndarray
    masked: np.ndarray  # sample lies on a masked pixel (dataset mask): always OTHER
    n_radial: int
    n_extra: int
    extra_angles: np.ndarray
    radius_px: tuple[float, float]  # image radii of the radial lines' first and last pixel
    image_size: tuple[int, int]  # (w, h)
    cell: int  # block size of the local green luminance map
    colour_flat: np.ndarray  # the field green's pixels (above), v * w + u
    map_flat: np.ndarray  # the local green map's pixels (above), v * w + u
    pixels: np.ndarray = None  # (m,) the samples' pixels, each once, in raster order
    sample_pixel: np.ndarray = None  # (n,) each sample's index into pixels
    blocks: colour.PixelBlocks = None  # pixels' blocks of the local green map, floor flags
    map_blocks: colour.PixelBlocks = None  # the blocks of map_flat (reordered as pixels)
    read_flat: np.ndarray = None  # what a frame reads: pixels, map_flat, colour_flat
    line_start_s: np.ndarray = None  # (n_lines,) arc length of each line's first pixel
    geometry: ScanGeometry = None  # the per-sample arrays the run detection reads

    FIELD_COLOUR_STEP = 6  # px, estimate_field_colour's default subsampling step

    def __post_init__(self):
        w, h = self.image_size
        first = np.flatnonzero(np.r_[True, self.line[1:] != self.line[:-1]])
        self.line_start_s = np.full(self.n_lines, np.inf)
        self.line_start_s[self.line[first]] = self.s[first]
        # the pixels, each once, in raster order (the image is read so)
        shape = (max(h // self.cell, 1), max(w // self.cell, 1))
        flat, index, inverse = np.unique(self.v * w + self.u, return_index=True,
                                         return_inverse=True)
        self.pixels = flat.astype(np.int32)  # (int32: less to read per frame)
        self.sample_pixel = inverse.astype(np.int32)
        floor = ~self.masked[index]
        self.blocks = colour.PixelBlocks.of(colour.FieldColour.block_index(
            flat % w, flat // w, shape, self.cell).astype(np.int32), floor, shape)
        # the map's pixels in the order PixelBlocks asks for: the first (top left) of every
        # block, then the second, ...
        map_block = colour.FieldColour.block_index(self.map_flat % w, self.map_flat // w,
                                                   shape, self.cell)
        step = max(self.cell // 2, 1)  # (the grid's: 2 x 2 pixels per block)
        map_rank = (self.map_flat // w // step) % 2 * 2 + (self.map_flat % w // step) % 2
        order = np.lexsort((map_block, map_rank))
        self.map_flat = self.map_flat[order].astype(np.int32)
        self.map_blocks = colour.PixelBlocks.of(map_block[order].astype(np.int32),
                                                np.ones(len(order), bool), shape)
        self.read_flat = np.concatenate([self.pixels, self.map_flat, self.colour_flat]).astype(
            np.int32)
        self.geometry = ScanGeometry(self.sample_pixel, self.line, self.s, self.dist, self.xy,
                                     self.uv, self.line_start_s)

    @property
    def n_lines(self) -> int:
        return self.n_radial + 2 * self.scanlines.n_angles + self.n_extra

    @property
    def size(self) -> int:
        return len(self.u)


def _dedupe(u, v, line, *per_sample):
    """Merge consecutive samples that fall on the same pixel of the same line: integer pixel of
    the first, mean of each per-sample array."""
    new = np.ones(len(u), bool)
    new[1:] = (u[1:] != u[:-1]) | (v[1:] != v[:-1]) | (line[1:] != line[:-1])
    grp = np.cumsum(new) - 1
    n = grp[-1] + 1 if len(grp) else 0
    cnt = np.bincount(grp, minlength=n).astype(float)
    means = []
    for a in per_sample:
        a = np.asarray(a, float)
        if a.ndim == 1:
            means.append(np.bincount(grp, a, minlength=n) / cnt)
        else:
            means.append(np.stack([np.bincount(grp, a[:, i], minlength=n) / cnt
                                   for i in range(a.shape[1])], axis=1))
    return (u[new], v[new], line[new], *means)


def build_scanline_pixels(camera, conf: dict, mask: np.ndarray | None = None) -> ScanLinePixels:
    """Sample every scan line of ``conf`` in the image of ``camera`` (see module doc).
    ``mask``: optional bool (h, w), True where the image shows usable floor."""
    sl = scanlines_of(conf)
    step = float(SAMPLE_STEP_PX)
    w, h = camera.image_size
    cu, cv_ = camera.centre
    d_max = min(sl.max_range, camera.max_distance)
    r0 = max(float(camera.valid_radius[0]), float(np.nan_to_num(
        camera.radius_of_distance(sl.robot_radius), nan=camera.valid_radius[0])))
    r1 = float(camera.radius_of_distance(d_max - 1e-6))
    if not np.isfinite(r1):
        r1 = float(camera.valid_radius[1])
    r1 = min(r1, float(camera.valid_radius[1]))

    n_extra = int(conf.get("points_radial_lines", 0) or 0)
    extra_angles = (dataclasses.replace(sl, n_angles=n_extra).radial_angles if n_extra
                    else np.zeros(0))
    bearings = np.concatenate([sl.radial_angles, extra_angles])
    ray_ids = np.concatenate([np.arange(sl.n_angles),
                              sl.n_angles * 3 + np.arange(n_extra)])

    parts = []  # (line ids, sub-pixel u, v, ground x, y, arc length s, distance)
    # radial lines: straight image rays from the centre, r0..r1 px
    r = np.arange(r0, r1 + 1e-9, step)
    if len(r) >= 2:
        dist = camera.distance_of_radius(r)
        alpha = camera.bearing_to_image_angle(bearings)  # (L,)
        uu = cu + r[None, :] * np.cos(alpha)[:, None]
        vv = cv_ - r[None, :] * np.sin(alpha)[:, None]
        xx = dist[None, :] * np.cos(bearings)[:, None]
        yy = dist[None, :] * np.sin(bearings)[:, None]
        L = len(bearings)
        parts.append((np.repeat(ray_ids, len(r)), uu.ravel(), vv.ravel(), xx.ravel(), yy.ravel(),
                      np.tile(dist - dist[0], L), np.tile(dist, L)))
    # spirals: ground polylines of the scan-line definition, densified to the pixel step
    r_end_px = float(np.nan_to_num(camera.radius_of_distance(min(sl.spiral_end_radius, d_max)),
                                   nan=r1))
    n_turn = int(math.ceil(2 * math.pi * max(r_end_px, 1.0) / step)) + 1
    dense = dataclasses.replace(sl, spiral_samples_per_turn=max(n_turn, sl.spiral_samples_per_turn))
    for direction in (0, 1):
        for k in range(0, sl.n_angles, SPIRAL_START_STEP):
            pts = dense.spiral_points(direction, k)
            rad = np.hypot(pts[:, 0], pts[:, 1])
            keep = rad <= d_max
            pts, rad = pts[keep], rad[keep]
            seg = np.hypot(*np.diff(pts, axis=0).T)
            s = np.concatenate([[0.0], np.cumsum(seg)])
            px = camera.robot_to_pixel(pts)
            parts.append((np.full(len(pts), sl.n_angles * (1 + direction) + k), px[:, 0],
                          px[:, 1], pts[:, 0], pts[:, 1], s, rad))
    line, fu, fv, gx, gy, s, dist = (np.concatenate(c) for c in zip(*parts))
    ok = np.isfinite(fu) & np.isfinite(fv)
    ui = np.rint(np.where(ok, fu, -1.0)).astype(np.int64)
    vi = np.rint(np.where(ok, fv, -1.0)).astype(np.int64)
    ok &= (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
    rr = np.hypot(fu - cu, fv - cv_)
    ok &= (rr >= camera.valid_radius[0]) & (rr <= camera.valid_radius[1])
    # lines in the order radial, spiral, extra; samples along each line in order
    order = np.lexsort((s, line))
    order = order[ok[order]]
    ui, vi, line_o = ui[order], vi[order], line[order]
    ui, vi, line_o, s_m, d_m, xy_m, uv_m = _dedupe(
        ui, vi, line_o, s[order], dist[order],
        np.stack([gx[order], gy[order]], 1), np.stack([fu[order], fv[order]], 1))
    masked = np.zeros(len(ui), bool) if mask is None else ~mask[vi, ui]
    # the field green's and the local green map's pixels, as estimate_field_colour takes them
    # of the floor annulus: every FIELD_COLOUR_STEP-th of every FIELD_COLOUR_STEP-th row, and
    # 2 x 2 per block
    cell = int(COLOUR["local_cell"])

    def floor_grid(step, stop_v, stop_u):
        gv, gu = np.mgrid[0:stop_v:step, 0:stop_u:step]
        rr = np.hypot(gu - cu, gv - cv_)
        on_floor = (rr >= r0) & (rr <= r1)
        if mask is not None:
            on_floor &= mask[gv, gu]
        return (gv * w + gu)[on_floor]

    colour_step = ScanLinePixels.FIELD_COLOUR_STEP
    return ScanLinePixels(scanlines=sl, u=ui, v=vi, line=line_o.astype(np.int32), s=s_m,
                          dist=d_m, xy=xy_m, uv=uv_m, masked=masked, n_radial=sl.n_angles,
                          n_extra=n_extra, extra_angles=extra_angles, radius_px=(r0, r1),
                          image_size=(w, h), cell=cell,
                          colour_flat=floor_grid(colour_step, h, w),
                          map_flat=floor_grid(max(cell // 2, 1), (h // cell) * cell,
                                              (w // cell) * cell))


_CACHE: dict[tuple, ScanLinePixels] = {}


def _frozen(value):
    """A hashable copy of a mapping of lists, numbers and strings (a part of a cache key)."""
    if isinstance(value, dict):
        return tuple(sorted((k, _frozen(v)) for k, v in value.items()))
    if isinstance(value, (list, tuple)):
        return tuple(_frozen(v) for v in value)
    return value


def _cache_key(camera, conf, mask) -> tuple:
    """What ScanLinePixels depends on: the calibration, the scan-line conf and the mask (a
    digest). Built every frame, so without serialising anything."""
    return (_frozen(camera.to_dict()), _frozen({k: conf[k] for k in _SCANLINE_KEYS}),
            None if mask is None else hashlib.sha256(np.packbits(mask)).hexdigest())


_SCANLINE_KEYS = ("scanlines", "points_radial_lines")
# the last call's camera, mask, calibration, scan-line values and result: the frames of a
# dataset come with the same objects
_LAST: dict = {}


def scanline_pixels(camera, conf: dict, mask: np.ndarray | None = None) -> ScanLinePixels:
    """``build_scanline_pixels`` cached per calibration, scan-line conf and mask. The same
    camera and mask objects as in the last call, the camera's calibration and the conf's
    scan-line values unchanged, take the last result without building the key (a mask array
    is recognised as the same object: one changed in place is not noticed)."""
    calib = camera.to_dict()
    values = [conf[k] for k in _SCANLINE_KEYS]
    last = _LAST.get("call")
    if (last is not None and last[0] is camera and last[1] is mask and last[2] == calib
            and last[3] == values):
        return last[4]
    key = _cache_key(camera, conf, mask)
    if key not in _CACHE:
        if len(_CACHE) >= 8:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = build_scanline_pixels(camera, conf, mask)
    _LAST["call"] = (camera, mask, calib, values, _CACHE[key])
    return _CACHE[key]


# ---------------------------------------------------------------------------- per frame


def classify_scanlines(image_bgr: np.ndarray, pix: ScanLinePixels, conf: dict):
    """Colour classes of the scan-line pixels ``pix.pixels`` of a frame, and the frame's field
    colour, without a whole-frame pass (stages.common.colour's pixel samples): the field green
    from ``pix.colour_flat``, the local green map from ``pix.map_flat``, then the YUV values
    and classes of the scan-line pixels."""
    ccfg = colour_conf(conf)
    m, n_map = len(pix.pixels), len(pix.map_flat)
    rows = colour.yuv_rows_at(image_bgr, pix.read_flat)  # (one gather, one conversion)
    fc = colour.field_colour_of_samples(rows[m + n_map:], ccfg)
    colour.local_green_map(colour.planes_of(rows[m:m + n_map]), pix.map_blocks, fc, ccfg)
    return colour.classify_blocks(colour.planes_of(rows[:m]), pix.blocks, fc, ccfg), fc


class ScanGeometry(NamedTuple):
    """ScanLinePixels' per-sample arrays that the run detection reads (a bundle for compiled
    code): pixel (index into ScanLinePixels.pixels), line index, arc length s (m), ground
    distance (m), ground point xy (n, 2, m), image position uv (n, 2, px), and per line the
    arc length of its first pixel."""

    pixel: np.ndarray
    line: np.ndarray
    s: np.ndarray
    dist: np.ndarray
    xy: np.ndarray
    uv: np.ndarray
    line_start_s: np.ndarray


class RunTuning(NamedTuple):
    """The tuned thresholds of a crossing (module doc), all but the preset's max_white_m. Set
    with the extractor and held since by the drawn-geometry tests (tests/test_extract_omni.py:
    line widths, grey edges, lighting) and the table agreement on rendered frames
    (tests/test_extract_omni.py, docs/results.md)."""

    min_green_px: int  # green run before and after a white run: pixels ...
    min_green_m: float  # ... and ground metres along the line
    max_gap_px: int  # unclassified pixels allowed between green and white (blurred edges)
    white_hole_px: int  # non-white pixels inside a white run that are closed
    # m: white this near a spiral's start that is no crossing blocks the spiral (the robot
    # stands on or next to a line: its first crossing is unseen)
    start_margin_m: float
    min_white_px: int  # white run: at least this many pixels ...
    min_white_m: float  # ... and this wide on the ground (m) ...
    far_white_px: int  # ... and at most max_white_m deep unless at most this many pixels long


RUNS = RunTuning(min_green_px=2, min_green_m=0.04, max_gap_px=3, white_hole_px=2,
                 start_margin_m=0.15, min_white_px=1, min_white_m=0.03, far_white_px=2)


class RunRules(NamedTuple):
    """The thresholds of a crossing (module doc) for compiled code: RUNS and the conf's
    max_white_m."""

    min_green_px: int
    min_green_m: float
    max_gap_px: int
    white_hole_px: int
    start_margin_m: float
    min_white_px: int
    min_white_m: float
    max_white_m: float
    far_white_px: int

    @classmethod
    def of(cls, conf: dict) -> RunRules:
        return cls(max_white_m=float(conf["max_white_m"]), **RUNS._asdict())


@dataclasses.dataclass
class WhiteRuns:
    """Accepted white runs (crossings) of a frame, in order along each scan line."""

    line: np.ndarray  # scan-line index
    mid_s: np.ndarray  # arc length (m) of the middle of the run along its line
    width: np.ndarray  # ground width (m) between the mid-points of its edges
    length: np.ndarray  # pixels
    blocked: np.ndarray  # (n_lines,) bool: white that is no crossing comes first (see below)
    dist: np.ndarray  # ground distance (m) of the middle from the robot centre
    xy: np.ndarray  # (N, 2) the middle in the robot frame (m)
    uv: np.ndarray  # (N, 2) the middle in the image (px)


def find_white_runs(labels: np.ndarray, pix: ScanLinePixels, conf: dict) -> WhiteRuns:
    """Green -> white -> green runs on the concatenated scan lines (see module doc), by one
    compiled pass (_white_runs). ``labels``: the classes of ``pix.pixels``
    (classify_scanlines)."""
    line, mid_s, width, length, blocked, dist, xy, uv = _white_runs(
        np.ascontiguousarray(labels, np.uint8), pix.geometry, RunRules.of(conf))
    return WhiteRuns(line, mid_s, width, length, blocked, dist, xy, uv)


@njit(cache=True, nogil=True)
def _class_runs(labels, pixel, line, start, cls):
    """Runs of equal class on the concatenated lines (sample i has the class of its pixel,
    ``labels[pixel[i]]``) into ``start`` (first sample) and ``cls``, both of at least n + 1
    entries; returns their number. Without branches (where a run ends is unpredictable):
    every sample is written as the start of the next run, which only a change keeps."""
    nr = 0
    last_class, last_line = -1, -1
    for i in range(pixel.shape[0]):
        c = np.int64(labels[pixel[i]])
        start[nr] = i
        cls[nr] = c
        nr += (c != last_class) | (line[i] != last_line)
        last_class, last_line = c, line[i]
    return nr


@njit(cache=True, nogil=True)
def _close_holes(start, cls, nr, line, r, out_start, out_cls):
    """The runs after closing short holes (module doc): where a path runs obliquely along a
    line's edge, the rounded pixels step out of the line and back in, and mixed edge pixels
    fall between the classes. Non-white runs of up to ``white_hole_px`` samples between two
    white runs become white, unclassified runs of up to ``max_gap_px`` between two green runs
    green (decided on the runs as found, all at once), then equal neighbours on a line merge.
    A lone white pixel between green is kept (far lines are one pixel wide); its ground width
    decides. Returns the number of runs."""
    m = 0
    for k in range(nr):
        c = cls[k]
        if 0 < k < nr - 1 and cls[k - 1] == cls[k + 1] and line[start[k - 1]] == line[start[k]] \
                and line[start[k]] == line[start[k + 1]]:
            length = start[k + 1] - start[k]
            nb = cls[k - 1]
            if (nb == colour.WHITE and c != colour.WHITE and length <= r.white_hole_px) or (
                    nb == colour.GREEN and c == colour.OTHER and length <= r.max_gap_px):
                c = nb
        if m == 0 or c != out_cls[m - 1] or line[start[k]] != line[out_start[m - 1]]:
            out_start[m] = start[k]
            out_cls[m] = c
            m += 1
    return m


@njit(cache=True, nogil=True)
def _white_runs(labels, g, r):
    """find_white_runs, compiled: the runs of the class sequence with its holes closed, the
    white runs with a long enough green run on both sides (gaps allowed) that are wide and
    shallow enough, the lines they block, and each accepted run's middle interpolated along
    its line. Returns (line, mid_s, width, length, blocked (n_lines,) bool, dist, xy, uv)."""
    line, s = g.line, g.s
    n = line.shape[0]
    start0 = np.empty(n + 1, np.int32)
    cls0 = np.empty(n + 1, np.uint8)
    nr = _class_runs(labels, g.pixel, line, start0, cls0)
    start0[nr] = n
    start = np.empty(nr + 1, np.int64)
    cls = np.empty(nr, np.uint8)
    nr = _close_holes(start0, cls0, nr, line, r, start, cls)
    start[nr] = n
    end = start[1:] - 1
    rline = np.empty(nr, np.int64)
    green = np.zeros(nr, np.bool_)
    for k in range(nr):
        rline[k] = line[start[k]]
        green[k] = (cls[k] == colour.GREEN and end[k] - start[k] + 1 >= r.min_green_px
                    and s[end[k]] - s[start[k]] >= r.min_green_m)
    n_lines = g.line_start_s.shape[0]
    first_acc = np.full(n_lines, nr)
    accepted = np.zeros(nr, np.bool_)
    left = np.empty(nr)
    right = np.empty(nr)
    prev = np.empty(nr, np.int64)
    nxt = np.empty(nr, np.int64)
    n_acc = 0
    for k in range(nr):
        if cls[k] != colour.WHITE:
            continue
        # the runs before and after it, each across one short unclassified gap
        p, q = k - 1, k + 1
        if p > 0 and cls[p] == colour.OTHER and end[p] - start[p] < r.max_gap_px:
            p -= 1
        if q < nr - 1 and cls[q] == colour.OTHER and end[q] - start[q] < r.max_gap_px:
            q += 1
        if p < 0 or q >= nr or rline[p] != rline[k] or rline[q] != rline[k] or not (
                green[p] and green[q]):
            continue
        # edges half-way between the last green pixel and the first white one (mid-gap);
        # depth: how far the run reaches away from the robot (on a spiral grazing a line
        # much less than its path inside the white)
        left[k] = 0.5 * (s[end[p]] + s[start[k]])
        right[k] = 0.5 * (s[end[k]] + s[start[q]])
        depth = abs(0.5 * (g.dist[end[k]] + g.dist[start[q]])
                    - 0.5 * (g.dist[end[p]] + g.dist[start[k]]))
        length = end[k] - start[k] + 1
        if length >= r.min_white_px and right[k] - left[k] >= r.min_white_m and (
                depth <= r.max_white_m or length <= r.far_white_px):
            accepted[k] = True
            prev[k], nxt[k] = p, q
            first_acc[rline[k]] = min(first_acc[rline[k]], k)
            n_acc += 1
    # a spiral reports its first crossing only: if white that is not a crossing comes first (a
    # graze along a line, a corner, white blurred into the surroundings, the robot standing on
    # a line at the spiral's start: at least min_white_m long, or near the line's start), its
    # first crossing is unseen and the line is "blocked"
    blocked = np.zeros(n_lines, np.bool_)
    for k in range(nr):
        if cls[k] == colour.WHITE and not accepted[k]:
            before = k < first_acc[rline[k]] and s[end[k]] - s[start[k]] >= r.min_white_m
            if before or s[start[k]] - g.line_start_s[rline[k]] <= r.start_margin_m:
                blocked[rline[k]] = True
    out_line = np.empty(n_acc, np.int64)
    mid_s = np.empty(n_acc)
    width = np.empty(n_acc)
    out_len = np.empty(n_acc, np.int64)
    dist = np.empty(n_acc)
    xy = np.empty((n_acc, 2))
    uv = np.empty((n_acc, 2))
    j = 0
    for k in range(nr):
        if not accepted[k]:
            continue
        mid = 0.5 * (left[k] + right[k])
        out_line[j], mid_s[j], width[j] = rline[k], mid, right[k] - left[k]
        out_len[j] = end[k] - start[k] + 1
        # the samples around the middle (between the green runs' inner ends), linearly
        i = end[prev[k]]
        while i < start[nxt[k]] - 1 and s[i + 1] <= mid:
            i += 1
        t = (mid - s[i]) / (s[i + 1] - s[i]) if s[i + 1] > s[i] else 0.0
        dist[j] = g.dist[i] + t * (g.dist[i + 1] - g.dist[i])
        for c in range(2):
            xy[j, c] = g.xy[i, c] + t * (g.xy[i + 1, c] - g.xy[i, c])
            uv[j, c] = g.uv[i, c] + t * (g.uv[i + 1, c] - g.uv[i, c])
        j += 1
    return out_line, mid_s, width, out_len, blocked, dist, xy, uv


def extract_frame(image_bgr: np.ndarray, camera, conf: dict, *, mask: np.ndarray | None = None,
                  **frame_info) -> dict[str, np.ndarray]:
    """Scan-line distances and line points of one omni frame (see module doc). ``mask``: bool
    (h, w), True where the image shows usable floor (the dataset's mask.png)."""
    if image_bgr.shape[1] != camera.image_size[0] or image_bgr.shape[0] != camera.image_size[1]:
        from ..common.errors import DatasetError

        raise DatasetError(
            f"image is {image_bgr.shape[1]} x {image_bgr.shape[0]} px, the calibration expects"
            f" {camera.image_size[0]} x {camera.image_size[1]}")
    pix = scanline_pixels(camera, conf, mask)
    labels, fc = classify_scanlines(image_bgr, pix, conf)
    return frame_features(pix, find_white_runs(labels, pix, conf))


def frame_features(pix: ScanLinePixels, runs: WhiteRuns) -> dict[str, np.ndarray]:
    """The per-frame arrays from the accepted white runs (compiled: _scanline_distances). A
    spiral reports only its first crossing, so a blocked spiral (see find_white_runs) reports
    none."""
    sl = pix.scanlines
    radial = np.full((sl.n_angles, sl.max_crossings), np.nan, np.float32)
    spiral = np.full((2, sl.n_angles), np.nan, np.float32)
    _scanline_distances(runs.line, runs.dist, runs.blocked, radial, spiral.reshape(-1))
    return {"radial": radial, "spiral": spiral, "points": runs.xy.astype(np.float32),
            "points_px": runs.uv.astype(np.float32)}


@njit(cache=True, nogil=True)
def _scanline_distances(line, dist, blocked, radial, spiral):
    """Into ``radial`` (n, max crossings) the first crossings of each radial line 0..n-1 (runs
    come in order along each line: nearest first), into ``spiral`` (2 n) the first crossing
    of each spiral n..3n-1 that is not ``blocked`` (bool per line)."""
    n, most = radial.shape
    count = np.zeros(n, np.int64)
    for j in range(line.shape[0]):
        k = line[j]
        if k < n:
            if count[k] < most:
                radial[k, count[k]] = dist[j]
            count[k] += 1
        elif k < 3 * n and not blocked[k] and np.isnan(spiral[k - n]):
            spiral[k - n] = dist[j]


# ---------------------------------------------------------------------------- own line points


def debug_overlay(image: np.ndarray, result: dict[str, np.ndarray]) -> np.ndarray:
    """A copy of the BGR frame with the extracted line points marked: radial and spiral
    crossings as red dots (``points_px``)."""
    import cv2

    out = image.copy()
    pts = result.get("points_px")
    if pts is not None:
        for u, v in np.asarray(pts, dtype=float):
            if np.isfinite(u) and np.isfinite(v):
                cv2.circle(out, (int(round(u)), int(round(v))), 2, (40, 40, 230), -1)
    return out
