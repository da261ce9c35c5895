"""Colour classes green / white / other, in the style of Schulz et al. (2011) (luminance thresholds
and an ellipse in the UV plane), adapted to each frame so that lighting changes do not need a new
colour table.

Per frame (``estimate_field_colour``):
- the field green is the dominant chroma cluster among green-hued pixels of the floor: the peak
  of a 2D histogram of their chroma rescaled to one luminance ((U - 128, V - 128) * 100 / Y, so
  that a lit and a shaded part of the carpet fall together), refined by mean shift; its
  luminance is the median Y of the cluster's pixels;
- a coarse map of the local green luminance (mean Y of green pixels per ``cell`` x ``cell``
  block, gaps filled from neighbouring blocks) follows vignetting, the mirror's radial fall-off
  and shadows.

Per pixel (``classify_yuv``), with y_g the local green luminance:
- white: Y >= y_g + white_contrast * (255 - y_g), Y >= white_min_y, and the saturation
  |(U, V) - neutral| / Y <= white_max_saturation (white is bright and near neutral relative to
  its own brightness; greenish-white line pixels under green light still pass);
- green: Y in [green_min_ratio, green_max_ratio] * y_g, and the chroma rescaled to the field's
  luminance, (U - 128, V - 128) * y_field / Y, inside the ellipse around the field green with
  semi-axes max(green_axes, green_spread_k * cluster spread) along U and V. Rescaling by Y keeps
  the ellipse valid in shaded and vignetted parts, where the chroma shrinks with the light;
- other: everything else (robots, people, the robot's body, the surroundings, blurred edges).

How it is computed (the classes are exactly those of the formulas, evaluated in float32):
- the luminance tests depend on the pixel's Y and its block's local green only: they become
  integer thresholds per block (``luminance_thresholds``), compared with the uint8 Y;
- the chroma tests are evaluated per pixel in float32, operation by operation as the formulas
  (``_chroma_tests``), on strips of rows (``STRIP_ROWS``) so that the temporaries stay small
  and in cache; the 8 x 8 counts are summed from the class masks of each strip.
A per-frame (Y, U) -> V-interval table of both chroma tests would give the same classes, but
its build and a gather per pixel cost about what the float32 arithmetic does, so the tests are
computed (docs/results.md, "Colour classes").

The perspective extractor reuses the same functions; ``classify_grid`` gives the grid of
class counts per 8 x 8 block of Schulz et al. (2011). An extractor that looks at a fixed set
of pixels (the omni scan lines) classifies only those (``yuv_at``, ``classify_blocks``), with
the field green and the local green map estimated from the pixels the whole-frame functions
take (``yuv_rows_at``, ``field_colour_of_samples``, ``local_green_map``): the same estimates.

The compiled kernels these functions call live in ``colour_kernels``; this module prepares
their inputs and turns their results into field colours, masks, class images and counts.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

from .colour_kernels import (
    GREEN,
    GREEN_MAX_Y,
    GREEN_MIN_Y,
    OTHER,
    WHITE,
    WHITE_MIN_Y,
    Y_REF,
    _classify_pixels,
    _fill_blocks,
    _gather_rows,
    _green_candidates,
    _green_cluster,
    _green_map,
    _hue_block_sums,
    _hue_cells,
    _hue_spread,
    _hue_turned,
    _sample_rows,
    _threshold_table,
)
from .conf import PAIR
from .errors import FieldlocError
from .numeric import histogram_peak

# the class codes (GREEN, WHITE, OTHER), the luminance thresholds' channels (WHITE_MIN_Y,
# GREEN_MIN_Y, GREEN_MAX_Y) and Y_REF are colour_kernels', which write them
CLASS_NAMES = ("green", "white", "other")

confs = {
    "default": {
        # field green search: hue window (deg, angle of (U-128, V-128)) and minimum chroma
        "green_hue_deg": [-170.0, -75.0],
        "green_min_chroma": 6.0,
        "green_search_y": [15, 240],  # luminance range of green candidates
        "green_nominal_uv": [105.0, 95.0],  # used when a frame shows too little green
        "green_min_share": 0.03,  # of the valid pixels, to trust the frame's own estimate
        "green_cluster_radius": 14.0,  # UV units around the histogram peak used to refine it
        "green_axes": [14.0, 14.0],  # minimum ellipse semi-axes (U, V), UV units
        "green_spread_k": 2.5,  # ellipse semi-axes >= k * cluster spread (std)
        "green_min_ratio": 0.35,  # green luminance band relative to the local green
        "green_max_ratio": 1.9,
        # white: brighter than the local green and nearly neutral
        "white_contrast": 0.18,  # share of the range between local green Y and 255
        "white_min_y": 60,
        "white_max_saturation": 0.3,  # |UV - 128| / Y
        "local_cell": 8,  # px, block size of the local green luminance map
        "local_fill": 7,  # blocks, window used to fill blocks without green
    },
}

# the ranges the keys above must lie in (common.conf.check_bounds; an extractor adds them under
# its "colour." key): luminance and chroma are bytes (0-255: an ellipse or a radius beyond 255
# UV units holds every chroma, and its square overflows float32 at 1e12), shares lie in
# [0, 1]; the pairs must be pairs (a single number, which ``-c key=V`` makes a one-element
# list, unpacks into nothing), and a window [low, high] (hue, luminance) reversed holds no
# pixel: the search silently falls back to the nominal green; a local cell of 0 px divides by
# zero, one of 1e12 px maps nothing
BYTE = (0, 255)
MAX_SPREAD_K = 100.0  # cluster spreads (std) in an ellipse semi-axis: beyond, every chroma
BOUNDS = {"green_hue_deg": (-360.0, 360.0, PAIR), "green_min_chroma": BYTE,
          "green_search_y": (*BYTE, PAIR), "green_nominal_uv": (*BYTE, 2),
          "green_min_share": (0, 1), "green_cluster_radius": BYTE,
          "green_axes": (*BYTE, 2), "green_spread_k": (0, MAX_SPREAD_K),
          "green_min_ratio": (0, None),
          "green_max_ratio": (0, None), "white_contrast": (0, 1), "white_min_y": BYTE,
          "white_max_saturation": (0, None), "local_cell": (1, 64), "local_fill": (1, None)}
# the same for the keys only some confs hold (the perspective extractor's: a chroma floor of
# green candidates and the hue model, green_model "hue")
OPTIONAL_BOUNDS = {"green_min_saturation": (0, None), "green_hue_tolerance_deg": (0, 180.0),
                   "green_hue_k": (0, None), "green_saturation": (0, None, 2)}


@dataclass
class FieldColour:
    """The field green of one frame."""

    y: float  # median luminance of the field green
    u: float  # chroma centre
    v: float
    axes: tuple[float, float]  # ellipse semi-axes (U, V) used by the green test
    found: bool  # False: too little green, the nominal colour was used
    share: float  # share of valid pixels near the green centre (what the estimate rests on)
    y_map: np.ndarray | None = None  # local green luminance per block
    cell: int = 8
    # the hue model of the green test (conf green_model "hue"; None: the ellipse): unit
    # chroma direction of the field (U, V), cos of the hue tolerance, saturation band
    hue_dir: tuple[float, float] | None = None
    hue_cos: float = 1.0
    saturation: tuple[float, float] = (0.0, math.inf)

    def local_y(self, u, v) -> np.ndarray:
        """Local green luminance at pixel positions (u, v) (integer arrays)."""
        if self.y_map is None:
            return np.full(np.shape(u), self.y, dtype=np.float32)
        return self.y_map.ravel()[self.block_index(u, v, self.y_map.shape, self.cell)]

    @staticmethod
    def block_index(u, v, map_shape, cell) -> np.ndarray:
        """Flat index into a block map of ``map_shape`` of pixels (u, v); callers that look up
        the same pixels every frame compute it once."""
        h, w = map_shape
        i = np.minimum(np.asarray(v) // cell, h - 1)
        j = np.minimum(np.asarray(u) // cell, w - 1)
        return i * w + j

    def local_y_image(self, shape) -> np.ndarray:
        """Local green luminance for every pixel of an image of ``shape`` (h, w)."""
        if self.y_map is None:
            return np.full(shape[:2], self.y, dtype=np.float32)
        return expand_blocks(self.y_map, shape, self.cell)

    def luminance_thresholds(self, conf: dict) -> np.ndarray:
        """``luminance_thresholds`` of the local green map (hb, wb, 3), or of the frame's green
        luminance (3,) when there is no map."""
        return luminance_thresholds(np.float32(self.y) if self.y_map is None else self.y_map,
                                    conf)

    def as_dict(self) -> dict:
        out = {"y": self.y, "u": self.u, "v": self.v, "axes": list(self.axes),
               "found": self.found, "share": self.share}
        if self.hue_dir is not None:
            out.update(hue_tolerance_deg=math.degrees(math.acos(self.hue_cos)),
                       saturation=list(self.saturation))
        return out


class BlockMask:
    """A bool mask of an image (h, w) that is constant on ``cell`` x ``cell`` blocks, kept per
    block (``blocks`` (ceil(h / cell), ceil(w / cell)) bool). Indexed with two slices it gives
    what the full-resolution mask would (``valid[::step, ::step]``, as the field green search
    reads its ``valid``) without building that mask."""

    def __init__(self, blocks: np.ndarray, cell: int, shape):
        self.blocks = np.asarray(blocks, bool)
        self.cell = int(cell)
        self.shape = tuple(shape[:2])

    def __getitem__(self, key) -> np.ndarray:
        rows, cols = key
        r = np.arange(self.shape[0])[rows] // self.cell
        c = np.arange(self.shape[1])[cols] // self.cell
        return self.blocks.take(c, axis=1)[r]  # (the columns first: a few rows to copy)

    def full(self) -> np.ndarray:
        """The full-resolution mask (h, w)."""
        return self[:, :]


def to_yuv(image_bgr: np.ndarray) -> np.ndarray:
    """BGR uint8 -> YUV uint8 (BT.601, U and V centred on 128)."""
    return cv2.cvtColor(image_bgr, cv2.COLOR_BGR2YUV)


def expand_blocks(blocks: np.ndarray, shape, cell: int) -> np.ndarray:
    """A per-block map (hb, wb, ...) at full resolution (h, w, ...): pixel (v, u) takes block
    (min(v // cell, hb - 1), min(u // cell, wb - 1)), as ``FieldColour.block_index``."""
    h, w = shape[:2]
    hb, wb = blocks.shape[:2]
    rows = np.minimum(np.arange(h) // cell, hb - 1)
    cols = np.minimum(np.arange(w) // cell, wb - 1)
    return np.take(np.take(blocks, cols, axis=1), rows, axis=0)


# ---------------------------------------------------------------------------- per pixel


def _chroma_tests(y: np.ndarray, u: np.ndarray, v: np.ndarray, fc: FieldColour, conf: dict,
                  white: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """The chroma tests of the module doc per pixel (planes of equal shape), in float32 with
    the formulas' operations in their order:
        green: ((U-128) y_f - (u_g-128) Y')^2 b^2 + ((V-128) y_f - (v_g-128) Y')^2 a^2
               <= Y'^2 (a^2 b^2), Y' = max(Y, 1) (the ellipse around the field green with the
               chroma rescaled to the field's luminance, multiplied through by Y'^2);
        white: (U-128)^2 + (V-128)^2 <= (sat^2) Y^2.
    With the hue model (``fc.hue_dir`` set) green is instead:
        c . d_f >= cos_tol |c|  and  s_lo Y <= |c| <= s_hi Y,  c = (U-128, V-128)
    (the hue within the tolerance of the field's, the saturation |c| / Y in its band).
    Returns (green, white) bool arrays (white None unless ``white``)."""
    yf = np.asarray(y, np.float32)
    du = np.asarray(u, np.float32) - np.float32(128.0)
    dv = np.asarray(v, np.float32) - np.float32(128.0)
    white_ok = None
    s = None
    if white or fc.hue_dir is not None:
        s = du * du
        s += dv * dv
    if white:
        sat = np.float32(conf["white_max_saturation"])
        white_ok = s <= (sat * sat) * (yf * yf)
    if fc.hue_dir is not None:
        dot = du * np.float32(fc.hue_dir[0])
        dot += dv * np.float32(fc.hue_dir[1])
        y2 = yf * yf
        c2 = np.float32(fc.hue_cos) ** 2
        lo, hi = (np.float32(v_) ** 2 for v_ in fc.saturation)
        green = (dot >= 0) & (dot * dot >= c2 * s) & (s >= lo * y2) & (s <= hi * y2)
        return green, white_ok
    ym = np.maximum(yf, np.float32(1.0))
    fy = np.float32(fc.y)
    du *= fy
    du -= np.float32(fc.u - 128.0) * ym
    dv *= fy
    dv -= np.float32(fc.v - 128.0) * ym
    a2, b2 = np.float32(fc.axes[0] ** 2), np.float32(fc.axes[1] ** 2)
    du *= du
    du *= b2
    dv *= dv
    dv *= a2
    du += dv
    ym *= ym
    ym *= a2 * b2
    return du <= ym, white_ok


def luminance_thresholds(y_green, conf: dict) -> np.ndarray:
    """Integer luminance thresholds (..., 3) [WHITE_MIN_Y, GREEN_MIN_Y, GREEN_MAX_Y] for local
    green luminances ``y_green`` (float, any shape): white needs Y >= WHITE_MIN_Y, green needs
    GREEN_MIN_Y <= Y <= GREEN_MAX_Y. The float32 bounds of the per-pixel formulas rounded
    inwards (Y is an integer), so the tests are exact. uint8 when all fit (always for y_green
    in [0, 255] and the default conf), else int16 (256: never)."""
    yg = np.asarray(y_green, dtype=np.float32)
    white_y = np.maximum(yg + np.float32(conf["white_contrast"]) * (np.float32(255.0) - yg),
                         np.float32(conf["white_min_y"]))
    g_lo = np.float32(conf["green_min_ratio"]) * yg
    g_hi = np.float32(conf["green_max_ratio"]) * yg
    out = np.empty(yg.shape + (3,), np.int16)
    out[..., WHITE_MIN_Y] = np.clip(np.ceil(white_y), 0, 256)
    lo = np.clip(np.ceil(g_lo), 0, 256)
    hi = np.clip(np.floor(g_hi), -1, 255)
    empty = lo > hi
    out[..., GREEN_MIN_Y] = np.where(empty, 255, np.minimum(lo, 255))
    out[..., GREEN_MAX_Y] = np.where(empty, 254, hi)
    if out.min() >= 0 and out.max() <= 255:
        return out.astype(np.uint8)
    return out


def class_masks(y: np.ndarray, u: np.ndarray, v: np.ndarray, fc: FieldColour, conf: dict,
                thresholds) -> tuple[np.ndarray, np.ndarray]:
    """(green, white) bool masks of pixels given as uint8 planes ``y``, ``u``, ``v`` (same
    shape), with ``luminance_thresholds`` as three arrays (white min, green min, green max)
    broadcastable to the planes. A pixel is in one class at most: white wins where both hold."""
    green, white = _chroma_tests(y, u, v, fc, conf)
    w_min, g_min, g_max = thresholds
    yy = y if np.asarray(w_min).dtype == np.uint8 else y.astype(np.int16)
    white &= yy >= w_min
    green &= yy >= g_min
    green &= yy <= g_max
    green &= ~white
    return green, white


def estimate_field_colour(yuv: np.ndarray, conf: dict, valid: np.ndarray | None = None,
                          step: int = 6) -> FieldColour:
    """The field green of a frame from its dominant green chroma cluster (see module doc).
    ``valid``: bool mask (h, w) of the floor pixels to look at (or a BlockMask); ``step``:
    subsampling."""
    sub = _sample_pixels(yuv, step, None if valid is None else valid[::step, ::step])
    fc = field_colour_of_samples(sub, conf)
    if fc.found:
        fc.y_map = _local_green_luminance(yuv, fc, conf, valid)
    return fc


def field_colour_of_samples(sub: np.ndarray, conf: dict) -> FieldColour:
    """The field green (without a local green map) of floor pixels ``sub`` (n, 3) YUV uint8:
    ``estimate_field_colour`` of pixels someone else sampled (the omni extractor samples one
    per 6 x 6 px cell along its scan lines)."""
    n_valid = max(len(sub), 1)
    y8 = sub[:, 0]
    y0, y1 = conf["green_search_y"]
    min_sat = float(conf.get("green_min_saturation", 0.0))
    # the green candidates (hue window, luminance range, chroma relative to luminance: a lit
    # white wall's tint is no field), their chroma rescaled to Y_REF and its histogram, by one
    # compiled pass (_green_candidates)
    y_c, u_c8, v_c8, uu, vv, counts = _green_candidates(
        sub, _green_candidate_chroma(tuple(conf["green_hue_deg"]),
                                     float(conf["green_min_chroma"])),
        min(math.ceil(y0), 256) if y0 > 0 else 0, max(math.floor(y1), -1) if y1 < 255 else 255,
        min_sat > 0, np.float32(min_sat * min_sat))
    found = False
    u_c, v_c = (float(a) for a in conf["green_nominal_uv"])
    spread = 0.0
    share = len(y_c) / n_valid
    y_field = None
    if share >= conf["green_min_share"]:
        # chroma rescaled to one luminance (Y_REF): under a brightness gradient the field's
        # chroma grows with its light, its chromaticity does not
        pi, pj = histogram_peak(counts.reshape(32, 32))
        nu, nv = 8.0 * pi + 4.0 - 128.0, 8.0 * pj + 4.0 - 128.0
        # mean shift towards the cluster centre (3 steps), then the cluster's pixels: their
        # count, median Y and chroma variances (compiled: _green_cluster)
        nu, nv, n_near, y_med, var_u, var_v = _green_cluster(
            uu, vv, y_c, nu, nv, float(conf["green_cluster_radius"] ** 2), 3)
        if n_near >= 10:
            found = True
            y_field = y_med
            back = y_field / Y_REF  # to chroma at the field's luminance
            u_c, v_c = 128.0 + nu * back, 128.0 + nv * back
            spread = back * float(np.sqrt(np.float32(0.5) * (np.float32(var_u)
                                                             + np.float32(var_v))))
            share = float(n_near) / n_valid
    if y_field is None:
        y_field = float(np.median(y8)) if len(y8) else 100.0
    k = conf["green_spread_k"]
    axes = (max(conf["green_axes"][0], k * spread), max(conf["green_axes"][1], k * spread))
    fc = FieldColour(y=y_field, u=u_c, v=v_c, axes=axes, found=found, share=share)
    if conf.get("green_model", "ellipse") == "hue":
        _hue_model(fc, u_c8, v_c8, y_c, conf)
    fc.cell = int(conf["local_cell"])
    return fc


def _hue_model(fc: FieldColour, u8, v8, y8, conf: dict) -> None:
    """The hue model of the green test (module doc) from the green candidates: their hue
    around the field's chroma direction (tolerance: ``green_hue_k`` robust sigmas, at least
    ``green_hue_tolerance_deg``), their median saturation times the ``green_saturation``
    band. Carpet seen near and far differs more in saturation (sheen at grazing angles) than in
    hue."""
    cu, cv_ = fc.u - 128.0, fc.v - 128.0
    n = math.hypot(cu, cv_)
    if n < 1e-6:
        return
    fc.hue_dir = (cu / n, cv_ / n)
    lo_rel, hi_rel = conf["green_saturation"]
    tol = math.radians(float(conf["green_hue_tolerance_deg"]))
    sat = n / max(fc.y, 1.0)
    if fc.found and len(u8):
        # the hue offsets from the field's (numpy's float32 arctan2 of the chroma turned onto
        # the field's direction, compiled: _hue_turned), then within 45 deg of it the median
        # |hue offset| and saturation (compiled: _hue_spread)
        num, den = _hue_turned(u8, v8, np.float32(fc.hue_dir[0]), np.float32(fc.hue_dir[1]))
        n_near, med_d, med_sat = _hue_spread(np.arctan2(num, den), u8, v8, y8,
                                             np.float32(math.radians(45.0)))
        if n_near >= 10:
            sigma = 1.4826 * med_d
            tol = max(tol, float(conf["green_hue_k"]) * sigma)
            sat = med_sat
    fc.hue_cos = math.cos(min(tol, math.radians(60.0)))
    fc.saturation = (lo_rel * sat, hi_rel * sat)


@functools.lru_cache(maxsize=8)
def _green_candidate_chroma(hue_deg: tuple[float, float], min_chroma: float) -> np.ndarray:
    """(65536,) bool [U << 8 | V]: chroma that the field green search considers, hue (deg,
    angle of (U - 128, V - 128)) in the window and chroma at least ``min_chroma``."""
    cu = np.arange(256, dtype=np.int32)[:, None] - 128
    cv_ = np.arange(256, dtype=np.int32)[None, :] - 128
    hue = np.degrees(np.arctan2(cv_, cu))
    ok = ((hue >= hue_deg[0]) & (hue <= hue_deg[1]) & (cu * cu + cv_ * cv_ >= min_chroma ** 2))
    ok = ok.ravel()
    ok.setflags(write=False)
    return ok


def _local_green_luminance(yuv, fc: FieldColour, conf: dict, valid) -> np.ndarray:
    """Mean Y of green pixels per block; blocks without green take the mean of their
    neighbourhood, and the frame's green luminance where there is none at all."""
    cell = fc.cell
    h, w = yuv.shape[:2]
    hb, wb = h // cell, w // cell
    if hb == 0 or wb == 0:
        return None
    # green by chroma (luminance band relative to the frame's green), 2 samples per block side
    step = max(cell // 2, 1)
    k = cell // step
    y_lo, y_hi = _local_green_band(fc)
    mask = None if valid is None else valid[:hb * cell:step, :wb * cell:step]
    if fc.hue_dir is not None:  # the hue model: one compiled pass (_hue_block_sums)
        gs = np.zeros((hb, wb), np.float32)
        ys = np.zeros((hb, wb), np.float32)
        _hue_block_sums(yuv, (step, k, hb, wb), np.zeros((0, 0), bool) if mask is None else
                        np.ascontiguousarray(mask), mask is not None, _hue_test(fc),
                        (y_lo, y_hi), gs, ys)
        return _fill_green_luminance(gs, ys, k, fc, conf)
    y, u, v = cv2.split(np.ascontiguousarray(yuv[:hb * cell:step, :wb * cell:step]))
    green, _ = _chroma_tests(y, u, v, fc, conf, white=False)
    green &= y >= y_lo
    green &= y <= y_hi
    if mask is not None:
        green &= mask
    if k == 1:
        gs, ys = green.astype(np.float32), y * green
    else:  # sums over the k x k samples of each block (integers)
        g8 = green.view(np.uint8)
        yg = y.astype(np.uint16)
        yg *= green
        gs = sum(g8[i::k, j::k] for i in range(k) for j in range(k))
        ys = sum(yg[i::k, j::k] for i in range(k) for j in range(k))
    return _fill_green_luminance(gs.astype(np.float32), ys.astype(np.float32), k, fc, conf)


# the luminance band of the pixels the local green map averages, relative to the frame's green
# luminance: wide (green in deep shade or under a spot still counts), the colour classes'
# narrower band (green_min_ratio, green_max_ratio) then applies relative to the local green
LOCAL_GREEN_BAND = (0.3, 2.2)


def _local_green_band(fc: FieldColour) -> tuple[int, int]:
    """LOCAL_GREEN_BAND around the frame's green luminance as integer bounds [lo, hi] on a
    uint8 Y (the float32 bounds rounded inwards, clipped to 0..255; lo > hi: none)."""
    lo = np.ceil(np.float32(fc.y * LOCAL_GREEN_BAND[0]))
    hi = np.floor(np.float32(fc.y * LOCAL_GREEN_BAND[1]))
    return int(min(max(lo, 0.0), 256.0)), int(max(min(hi, 255.0), -1.0))


def _fill_green_luminance(gs: np.ndarray, ys: np.ndarray, k: int, fc: FieldColour, conf: dict
                          ) -> np.ndarray:
    """The local green luminance map from the per-block count of green samples ``gs`` and sum
    of their Y ``ys`` (float32, of k x k samples per block): their mean where a quarter of the
    samples are green, else the mean over the ``local_fill`` window, else the frame's."""
    out = np.empty(gs.shape, np.float32)
    _fill_blocks(np.ascontiguousarray(gs, np.float32), np.ascontiguousarray(ys, np.float32),
                 int(conf["local_fill"]) | 1, np.full(gs.shape, np.float32(0.25 * k * k)),
                 np.float32(fc.y), out)
    return out


def _labels(green: np.ndarray, white: np.ndarray) -> np.ndarray:
    """Class image (GREEN, WHITE, OTHER) of exclusive green and white masks."""
    out = np.full(green.shape, OTHER, dtype=np.uint8)  # OTHER - 1 = WHITE, OTHER - 2 = GREEN
    out -= white.view(np.uint8)
    out -= green.view(np.uint8) << 1
    return out


def classify_yuv(yuv_pixels: np.ndarray, fc: FieldColour, conf: dict,
                 y_green: np.ndarray | float | None = None) -> np.ndarray:
    """Classes (GREEN, WHITE, OTHER; uint8) of YUV pixels (..., 3). ``y_green``: the local
    green luminance at each pixel (default: the frame's)."""
    p = np.asarray(yuv_pixels, dtype=np.uint8)
    y, u, v = (np.ascontiguousarray(p[..., k]) for k in range(3))
    thr = luminance_thresholds(fc.y if y_green is None else y_green, conf)
    green, white = class_masks(y, u, v, fc, conf, (thr[..., WHITE_MIN_Y],
                                                   thr[..., GREEN_MIN_Y], thr[..., GREEN_MAX_Y]))
    return _labels(green, white)


def classify_pixels(yuv: np.ndarray, flat: np.ndarray, block: np.ndarray | None,
                    fc: FieldColour, conf: dict) -> np.ndarray:
    """Classes (uint8) of the pixels ``flat`` (flat indices v * w + u) of a YUV image, whose
    blocks of ``fc``'s local green map are ``block`` (``FieldColour.block_index``; callers
    that classify the same pixels every frame, like the omni scan lines, compute both once).
    Equal to ``classify_yuv`` with the local green luminance of each pixel."""
    if np.size(flat) == 0:
        return np.zeros(np.shape(flat), np.uint8)
    # one gather of 4-byte pixels (YUV + a pad byte), then their planes
    yuva = cv2.cvtColor(np.ascontiguousarray(yuv), cv2.COLOR_RGB2RGBA)
    y, u, v = _gather_planes(yuva.reshape(-1, 4), flat)[:3]
    thr = fc.luminance_thresholds(conf)
    if fc.y_map is None:
        planes = thr
    elif thr.dtype == np.uint8:
        packed = np.zeros(thr.shape[:2] + (4,), np.uint8)
        packed[..., :3] = thr
        planes = _gather_planes(packed.reshape(-1, 4), block)[:3]
    else:
        thr = thr.reshape(-1, 3)
        planes = [np.take(thr[:, k], block) for k in range(3)]
    return _labels(*class_masks(y, u, v, fc, conf, planes))


def _gather_planes(values: np.ndarray, index: np.ndarray) -> list[np.ndarray]:
    """The four channels of ``values`` (N, 4) uint8 at ``index``, as four contiguous arrays
    of the shape of ``index`` (one gather of 4-byte items, then a split)."""
    rows = np.take(values.view(np.uint32).reshape(-1), index)
    planes = cv2.split(rows.view(np.uint8).reshape(1, -1, 4))
    return [p.reshape(np.shape(index)) for p in planes]


# ---------------------------------------------------------------------------- pixel samples
# Extractors that look at a fixed set of pixels every frame (the omni scan lines: ~40,000 of
# the 230,400 pixels of a 480 x 480 frame) classify only those: their YUV values, the field
# green and the local green map from pixels they read, and their classes, by compiled passes.
# The pixels are kept as planes (one array per channel), so that the arithmetic runs on
# vectors; what cannot (the gather from the image, the sums into the blocks, the thresholds
# looked up per block) runs once per pixel without branches, in the order that suits it (the
# image read in raster order; for the map's sums, consecutive pixels in different blocks).

def yuv_rows_at(image_bgr: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """YUV (n, 3) uint8 of the pixels ``flat`` (flat indices v * w + u) of a BGR image: one
    compiled gather (fastest for pixels in raster order: the image is read as it lies in
    memory), then OpenCV's conversion of just those pixels, so the values are
    ``to_yuv(image)``'s at the same pixels."""
    rows = np.empty((1, len(flat), 3), np.uint8)
    _gather_rows(np.ascontiguousarray(image_bgr).reshape(-1, 3), flat, rows[0])
    return cv2.cvtColor(rows, cv2.COLOR_BGR2YUV)[0]


def yuv_at(image_bgr: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """``yuv_rows_at`` as planes (3, n) uint8 (one array per channel: the compiled passes
    over pixels run on vectors)."""
    return planes_of(yuv_rows_at(image_bgr, flat))


def planes_of(rows: np.ndarray) -> np.ndarray:
    """Pixel rows (n, 3) as planes (3, n), by OpenCV's transpose (faster than numpy's
    copy)."""
    return cv2.transpose(np.ascontiguousarray(rows))


class ChromaTest(NamedTuple):
    """The constants of ``_chroma_tests`` (float32) for compiled code (``_chroma_bits``):
    ellipse (field luminance, centre offsets from neutral, squared semi-axes) or, with
    ``hue``, the hue model (direction, squared cosine of the tolerance, squared saturation
    band); the white saturation limit squared."""

    field_y: np.float32
    du_g: np.float32
    dv_g: np.float32
    a2: np.float32
    b2: np.float32
    ab2: np.float32
    sat2: np.float32
    hue: bool
    hx: np.float32
    hy: np.float32
    c2: np.float32
    s_lo2: np.float32
    s_hi2: np.float32

    @classmethod
    def of(cls, fc: FieldColour, conf: dict) -> ChromaTest:
        f = np.float32
        a2, b2 = f(fc.axes[0] ** 2), f(fc.axes[1] ** 2)
        sat = f(conf["white_max_saturation"])
        hue = fc.hue_dir is not None
        hx, hy = fc.hue_dir if hue else (0.0, 0.0)
        lo, hi = (f(v) ** 2 for v in fc.saturation)
        return cls(f(fc.y), f(fc.u - 128.0), f(fc.v - 128.0), a2, b2, a2 * b2, sat * sat, hue,
                   f(hx), f(hy), f(fc.hue_cos) ** 2, lo, hi)


class PixelBlocks(NamedTuple):
    """The block of a local green map (of ``map_shape`` blocks) of each of a set of distinct
    pixels (``block``, flat index), whether the pixel shows the floor (``floor``; the others
    are OTHER and left out of the map), and the number of floor pixels per block
    (``floor_count``, flat). For local_green_map consecutive pixels should lie in different
    blocks: its sums add one pixel at a time, and an addition to the block just added to waits
    for that one (ScanLinePixels orders the map's pixels so)."""

    block: np.ndarray
    floor: np.ndarray
    floor_count: np.ndarray
    map_shape: tuple[int, int]

    @classmethod
    def of(cls, block: np.ndarray, floor: np.ndarray, map_shape) -> PixelBlocks:
        count = np.bincount(block[floor], minlength=map_shape[0] * map_shape[1])
        return cls(block, floor, count.astype(np.float32), tuple(map_shape))


class LuminanceRules(NamedTuple):
    """The luminance side of the classes, for compiled code: ``luminance_thresholds``'
    constants (float32), the band of Y that the local green map averages (integer bounds,
    LOCAL_GREEN_BAND), its fill window (blocks) and the frame's green luminance."""

    white_contrast: np.float32
    white_min_y: np.float32
    green_min_ratio: np.float32
    green_max_ratio: np.float32
    band_lo: int
    band_hi: int
    fill: int
    field_y: np.float32

    @classmethod
    def of(cls, fc: FieldColour, conf: dict) -> LuminanceRules:
        f = np.float32
        return cls(f(conf["white_contrast"]), f(conf["white_min_y"]), f(conf["green_min_ratio"]),
                   f(conf["green_max_ratio"]), *_local_green_band(fc),
                   int(conf["local_fill"]) | 1, f(fc.y))


def local_green_map(yuv: np.ndarray, px: PixelBlocks, fc: FieldColour, conf: dict) -> None:
    """The local green map of a frame from pixels of it given as YUV planes ``yuv`` (3, n)
    uint8 with their blocks (``px``), by one compiled pass (_green_map): per block the mean
    Y of its floor pixels that are green by chroma with Y in LOCAL_GREEN_BAND times the
    field's, where they are at least a quarter of its floor pixels (and one), else of its
    ``local_fill`` neighbourhood, else the field's. Given the pixels ``estimate_field_colour``
    takes (4 per block), the same map; stored in ``fc.y_map`` (None when not ``fc.found``:
    the frame's green luminance is used everywhere)."""
    fc.y_map = None
    if fc.found:
        y_map = np.empty(px.map_shape, np.float32)
        _green_map(yuv, px, ChromaTest.of(fc, conf), LuminanceRules.of(fc, conf), y_map)
        fc.y_map = y_map


def classify_blocks(yuv: np.ndarray, px: PixelBlocks, fc: FieldColour, conf: dict
                    ) -> np.ndarray:
    """Classes (uint8) of distinct pixels given as YUV planes ``yuv`` (3, n) uint8, with their
    blocks of the local green map (``px``), by one compiled pass (_classify_pixels): the
    formulas of the module doc with the local green luminance of ``fc.y_map``
    (local_green_map; the frame's where None); pixels off the floor are OTHER."""
    y_map = fc.y_map
    if y_map is None:
        y_map = np.full(px.map_shape, np.float32(fc.y), np.float32)
    labels = np.empty(yuv.shape[1], np.uint8)
    _classify_pixels(yuv, px, ChromaTest.of(fc, conf), LuminanceRules.of(fc, conf),
                     np.ascontiguousarray(y_map, np.float32), labels)
    return labels


STRIP_ROWS = 64  # rows of pixels classified together (their temporaries stay in cache)


def _strip_masks(yuv: np.ndarray, fc: FieldColour, conf: dict, valid: np.ndarray | None,
                 rows: int, stop: int | None = None, block: int | None = None):
    """(r0, r1, green, white) for strips of ``rows`` rows of a YUV image, down to row
    ``stop``: the classes of ``classify_masks`` computed strip after strip, so that the
    temporaries are small and reused instead of image-sized. ``block``: pixels of ``yuv`` per
    block of the local green map (default ``fc.cell``; less for a subsampled image)."""
    h, w = yuv.shape[:2]
    stop = h if stop is None else stop
    block = fc.cell if block is None else block
    thr = fc.luminance_thresholds(conf)
    if fc.y_map is not None:  # per block row, expanded to the columns: (3, block rows, w)
        hb, wb = thr.shape[:2]
        cols = np.minimum(np.arange(w) // block, wb - 1)
        thr = np.ascontiguousarray(np.moveaxis(thr[:, cols], 2, 0))
        row_block = np.minimum(np.arange(h) // block, hb - 1)
    for r0 in range(0, stop, rows):
        r1 = min(r0 + rows, stop)
        y, u, v = cv2.split(yuv[r0:r1])
        planes = thr if fc.y_map is None else np.take(thr, row_block[r0:r1], axis=1)
        green, white = class_masks(y, u, v, fc, conf, planes)
        if valid is not None:
            green &= valid[r0:r1]
            white &= valid[r0:r1]
        yield r0, r1, green, white


def classify_masks(yuv: np.ndarray, fc: FieldColour, conf: dict,
                   valid: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(green, white) bool masks of every pixel of a YUV image (h, w, 3), with the local green
    luminance of ``fc``'s block map (pixels outside ``valid`` are in neither)."""
    h, w = yuv.shape[:2]
    green, white = np.empty((h, w), bool), np.empty((h, w), bool)
    for r0, r1, g, wh in _strip_masks(yuv, fc, conf, valid, STRIP_ROWS):
        green[r0:r1], white[r0:r1] = g, wh
    return green, white


def classify_image(image_bgr: np.ndarray, conf: dict, valid: np.ndarray | None = None,
                   fc: FieldColour | None = None) -> tuple[np.ndarray, FieldColour]:
    """Classes of every pixel of a BGR image (pixels outside ``valid`` are OTHER) and the
    frame's field colour."""
    yuv = to_yuv(image_bgr)
    if fc is None:
        fc = estimate_field_colour(yuv, conf, valid)
    return _labels(*classify_masks(yuv, fc, conf, valid)), fc


def block_counts(mask: np.ndarray, cell: int = 8) -> np.ndarray:
    """Number of True pixels per cell x cell block of a bool image (h // cell, w // cell)
    (partial blocks at the border are dropped), uint16."""
    h, w = mask.shape
    hb, wb = h // cell, w // cell
    m = mask[:hb * cell, :wb * cell].view(np.uint8)
    if cell == 8 and m.flags.c_contiguous:
        # the 8 bytes (0 or 1) of a block row summed by one multiplication of their uint64
        rows = (m.view(np.uint64) * np.uint64(0x0101010101010101)) >> np.uint64(56)
        return rows.reshape(hb, cell, wb).sum(axis=1, dtype=np.uint16)
    area = np.float32(cell * cell)
    mean = cv2.resize(m.astype(np.float32), (wb, hb), interpolation=cv2.INTER_AREA)
    return np.rint(mean * area).astype(np.uint16)


def class_counts(labels: np.ndarray, cell: int = 8) -> np.ndarray:
    """Schulz et al.'s subsampled colour-class images: (h // cell, w // cell, 3) counts of
    GREEN, WHITE, OTHER per cell x cell block (partial blocks at the border are dropped)."""
    return _counts(labels == GREEN, labels == WHITE, cell)


def _counts(green: np.ndarray, white: np.ndarray, cell: int) -> np.ndarray:
    g, wh = block_counts(green, cell), block_counts(white, cell)
    out = np.empty(g.shape + (3,), dtype=np.uint16)
    out[..., GREEN] = g
    out[..., WHITE] = wh
    out[..., OTHER] = cell * cell - g - wh
    return out


def classify_grid(image_bgr: np.ndarray, conf: dict, valid: np.ndarray | None = None,
                  cell: int = 8, step: int = 1, green_from: np.ndarray | None = None,
                  white_out: np.ndarray | None = None) -> tuple[np.ndarray, FieldColour]:
    """Class counts per cell x cell block of a BGR image (see class_counts) and the frame's
    field colour. ``step`` > 1 classifies only every ``step``-th pixel of every ``step``-th
    row ((cell / step)^2 pixels per cell, counts scaled by step^2; the field colour is
    estimated as for step 1); it must divide ``cell`` and ``local_cell``. ``green_from``: bool
    mask (h, w) of the pixels the field green is estimated from (default ``valid``; a
    perspective camera's floor below the horizon). ``white_out``: a bool array of the
    (subsampled) image's shape that receives the white mask."""
    yuv = to_yuv(image_bgr)
    fc = estimate_field_colour(yuv, conf, valid if green_from is None else green_from)
    h, w = yuv.shape[:2]
    out = np.empty((h // cell, w // cell, 3), dtype=np.uint16)
    if step > 1:
        if cell % step or fc.cell % step:
            raise FieldlocError(f"colour step {step} must divide the cell ({cell} px) and the local"
                            f" green cell ({fc.cell} px)")
        yuv = yuv[:(h // cell) * cell:step, :(w // cell) * cell:step]
        valid = None if valid is None else valid[:(h // cell) * cell:step,
                                                 :(w // cell) * cell:step]
    sub = cell // step
    rows = max(STRIP_ROWS // sub, 1) * sub
    for r0, r1, green, white in _strip_masks(yuv, fc, conf, valid, rows, out.shape[0] * sub,
                                             fc.cell // step):
        counts = _counts(green, white, sub)
        out[r0 // sub: r1 // sub] = counts if step == 1 else counts * (step * step)
        if white_out is not None:
            white_out[r0:r1, :white.shape[1]] = white
    return out, fc


def hue_deg(u, v) -> np.ndarray:
    """Angle (deg) of the chroma (U - 128, V - 128), the hue used by the green search."""
    return np.degrees(np.arctan2(np.asarray(v, float) - 128.0, np.asarray(u, float) - 128.0))


# ---------------------------------------------------------------------------- compiled path

def classify_cells(yuv: np.ndarray, fc: FieldColour, conf: dict, cell: int,
                   white_out: np.ndarray | None = None) -> np.ndarray | None:
    """``classify_grid``'s class counts (h // cell, w // cell, 3) of a YUV image for the hue
    model (``fc.hue_dir`` set), every pixel, by one compiled pass (``_hue_cells``): the same
    float32 operations as ``class_masks`` per pixel, counted per cell, and the white mask into
    ``white_out`` (uint8 (h, w)) if given. None for the ellipse model (use classify_grid)."""
    if fc.hue_dir is None:
        return None
    h, w = yuv.shape[:2]
    if fc.y_map is not None:  # the local map's thresholds, by one compiled pass
        thr = np.empty(fc.y_map.shape + (3,), np.int16)
        _threshold_table(np.ascontiguousarray(fc.y_map, np.float32),
                         np.float32(conf["white_contrast"]), np.float32(conf["white_min_y"]),
                         np.float32(conf["green_min_ratio"]), np.float32(conf["green_max_ratio"]),
                         thr)
    else:
        thr = np.ascontiguousarray(np.broadcast_to(fc.luminance_thresholds(conf), (1, 1, 3)),
                                   dtype=np.int16)
    local = fc.cell if fc.y_map is not None else max(h, w)
    out = np.zeros((h // cell, w // cell, 3), np.uint16)
    mask = np.zeros((1, 1), np.uint8) if white_out is None else white_out
    sat = np.float32(conf["white_max_saturation"])
    _hue_cells(np.ascontiguousarray(yuv).reshape(h, 3 * w), thr, (int(cell), int(local)),
               np.float32(sat * sat), _hue_test(fc), white_out is not None, out, mask)
    return out


def _hue_test(fc) -> tuple:
    """The hue model's green test as the kernels take it, float32 each: the hue direction
    (hx, hy), its cone's cos^2, and the saturation band's squared bounds (lo, hi)."""
    lo, hi = (np.float32(v) ** 2 for v in fc.saturation)
    return (np.float32(fc.hue_dir[0]), np.float32(fc.hue_dir[1]),
            np.float32(np.float32(fc.hue_cos) ** 2), lo, hi)


def _sample_pixels(yuv: np.ndarray, step: int, mask: np.ndarray | None) -> np.ndarray:
    """The pixels (n, 3) of ``yuv[::step, ::step]`` where ``mask`` (of that shape; None: all)
    holds, row by row: ``yuv[::step, ::step][mask]`` by one compiled pass."""
    rows, cols = -(-yuv.shape[0] // step), -(-yuv.shape[1] // step)
    use = mask is not None
    m = np.ascontiguousarray(mask, dtype=bool) if use else np.zeros((0, 0), bool)
    out = np.empty((np.count_nonzero(m) if use else rows * cols, 3), np.uint8)
    n = _sample_rows(np.ascontiguousarray(yuv), step, m, use, out)
    return out[:n]
