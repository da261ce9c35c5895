"""Colour classes green / white / other, in the style of seed 000 (luminance thresholds and an
ellipse in the UV plane), adapted to each frame so that lighting changes do not need a new
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

The perspective extractor reuses the same functions; ``class_counts`` gives the seed-000 grid of
class counts per 8 x 8 block.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

GREEN, WHITE, OTHER = 0, 1, 2
Y_REF = 100.0  # luminance the field green search rescales chroma to
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
        vv, uu = np.indices(shape[:2])
        return self.local_y(uu, vv)

    def as_dict(self) -> dict:
        return {"y": self.y, "u": self.u, "v": self.v, "axes": list(self.axes),
                "found": self.found, "share": self.share}


def to_yuv(image_bgr: np.ndarray) -> np.ndarray:
    """BGR uint8 -> YUV uint8 (BT.601, U and V centred on 128)."""
    return cv2.cvtColor(image_bgr, cv2.COLOR_BGR2YUV)


def estimate_field_colour(yuv: np.ndarray, conf: dict, valid: np.ndarray | None = None,
                          step: int = 6) -> FieldColour:
    """The field green of a frame from its dominant green chroma cluster (see module doc).
    ``valid``: bool mask (h, w) of the floor pixels to look at; ``step``: subsampling."""
    sub = yuv[::step, ::step]
    if valid is not None:
        sub = sub[valid[::step, ::step]]
    sub = sub.reshape(-1, 3)
    n_valid = max(len(sub), 1)
    y = sub[:, 0].astype(np.int32)
    cu, cv_ = sub[:, 1].astype(np.int32) - 128, sub[:, 2].astype(np.int32) - 128
    hue = np.degrees(np.arctan2(cv_, cu))
    h0, h1 = conf["green_hue_deg"]
    y0, y1 = conf["green_search_y"]
    cand = ((hue >= h0) & (hue <= h1) & (cu * cu + cv_ * cv_ >= conf["green_min_chroma"] ** 2)
            & (y >= y0) & (y <= y1))
    found = False
    u_c, v_c = (float(a) for a in conf["green_nominal_uv"])
    spread = 0.0
    share = float(cand.sum()) / n_valid
    y_field = float(np.median(y)) if len(y) else 100.0
    if share >= conf["green_min_share"]:
        # chroma rescaled to one luminance (Y_REF): under a brightness gradient the field's
        # chroma grows with its light, its chromaticity does not
        yy = y[cand].astype(np.float32)
        scale = Y_REF / np.maximum(yy, 1.0)
        uu = cu[cand].astype(np.float32) * scale
        vv = cv_[cand].astype(np.float32) * scale
        bins = (np.clip(uu + 128.0, 0, 255).astype(np.int32) >> 3) * 32 + (
            np.clip(vv + 128.0, 0, 255).astype(np.int32) >> 3)
        hist = np.bincount(bins, minlength=1024).reshape(32, 32).astype(np.float32)
        hist = cv2.GaussianBlur(hist, (3, 3), 0)
        pi, pj = np.unravel_index(int(np.argmax(hist)), hist.shape)
        nu, nv = 8.0 * pi + 4.0 - 128.0, 8.0 * pj + 4.0 - 128.0
        rad2 = conf["green_cluster_radius"] ** 2
        for _ in range(3):  # mean shift towards the cluster centre
            near = (uu - nu) ** 2 + (vv - nv) ** 2 <= rad2
            if not near.any():
                break
            nu, nv = float(uu[near].mean()), float(vv[near].mean())
        near = (uu - nu) ** 2 + (vv - nv) ** 2 <= rad2
        if near.sum() >= 10:
            found = True
            y_field = float(np.median(yy[near]))
            back = y_field / Y_REF  # to chroma at the field's luminance
            u_c, v_c = 128.0 + nu * back, 128.0 + nv * back
            spread = back * float(np.sqrt(0.5 * (uu[near].var() + vv[near].var())))
            share = float(near.sum()) / n_valid
    k = conf["green_spread_k"]
    axes = (max(conf["green_axes"][0], k * spread), max(conf["green_axes"][1], k * spread))
    fc = FieldColour(y=y_field, u=u_c, v=v_c, axes=axes, found=found, share=share)
    fc.cell = int(conf["local_cell"])
    if found:
        fc.y_map = _local_green_luminance(yuv, fc, conf, valid)
    return fc


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
    sub = yuv[:hb * cell:step, :wb * cell:step].astype(np.float32)
    y = sub[..., 0]
    green = _green_chroma(sub[..., 1], sub[..., 2], y, fc) & (y >= fc.y * 0.3) & (y <= fc.y * 2.2)
    if valid is not None:
        green &= valid[:hb * cell:step, :wb * cell:step]
    g = green.astype(np.float32)
    gs = g.reshape(hb, k, wb, k).sum(axis=(1, 3))
    ys = (y * g).reshape(hb, k, wb, k).sum(axis=(1, 3))
    fill = int(conf["local_fill"]) | 1
    gs_f = cv2.boxFilter(gs, -1, (fill, fill), normalize=False, borderType=cv2.BORDER_CONSTANT)
    ys_f = cv2.boxFilter(ys, -1, (fill, fill), normalize=False, borderType=cv2.BORDER_CONSTANT)
    own = gs >= 0.25 * k * k
    ymap = np.where(own, ys / np.maximum(gs, 1e-6),
                    np.where(gs_f > 0, ys_f / np.maximum(gs_f, 1e-6), fc.y))
    return ymap.astype(np.float32)


def _green_chroma(u, v, y, fc: FieldColour) -> np.ndarray:
    """Chroma test of the green ellipse, chroma rescaled to the field's luminance:
    ((U-128) y_f / Y - (u_g-128))^2 / a^2 + (...)^2 / b^2 <= 1, multiplied through by Y^2."""
    y = np.maximum(y, np.float32(1.0))
    du = (u - np.float32(128.0)) * np.float32(fc.y) - np.float32(fc.u - 128.0) * y
    dv = (v - np.float32(128.0)) * np.float32(fc.y) - np.float32(fc.v - 128.0) * y
    a2, b2 = np.float32(fc.axes[0] ** 2), np.float32(fc.axes[1] ** 2)
    return du * du * b2 + dv * dv * a2 <= y * y * (a2 * b2)


def classify_yuv(yuv_pixels: np.ndarray, fc: FieldColour, conf: dict,
                 y_green: np.ndarray | float | None = None) -> np.ndarray:
    """Classes (GREEN, WHITE, OTHER; uint8) of YUV pixels (..., 3). ``y_green``: the local
    green luminance at each pixel (default: the frame's)."""
    p = np.asarray(yuv_pixels).astype(np.float32)
    y, u, v = p[..., 0], p[..., 1], p[..., 2]
    yg = np.float32(fc.y) if y_green is None else np.asarray(y_green, dtype=np.float32)
    white_y = np.maximum(yg + np.float32(conf["white_contrast"]) * (np.float32(255.0) - yg),
                         np.float32(conf["white_min_y"]))
    du, dv = u - np.float32(128.0), v - np.float32(128.0)
    sat = np.float32(conf["white_max_saturation"])
    white = (y >= white_y) & (du * du + dv * dv <= (sat * sat) * (y * y))
    green = ((y >= np.float32(conf["green_min_ratio"]) * yg)
             & (y <= np.float32(conf["green_max_ratio"]) * yg) & _green_chroma(u, v, y, fc))
    out = np.full(y.shape, OTHER, dtype=np.uint8)
    out[green] = GREEN
    out[white] = WHITE
    return out


def classify_image(image_bgr: np.ndarray, conf: dict, valid: np.ndarray | None = None,
                   fc: FieldColour | None = None) -> tuple[np.ndarray, FieldColour]:
    """Classes of every pixel of a BGR image (pixels outside ``valid`` are OTHER) and the
    frame's field colour."""
    yuv = to_yuv(image_bgr)
    if fc is None:
        fc = estimate_field_colour(yuv, conf, valid)
    labels = classify_yuv(yuv, fc, conf, fc.local_y_image(yuv.shape))
    if valid is not None:
        labels[~valid] = OTHER
    return labels, fc


def class_counts(labels: np.ndarray, cell: int = 8) -> np.ndarray:
    """Seed 000's subsampled colour-class images: (h // cell, w // cell, 3) counts of
    GREEN, WHITE, OTHER per cell x cell block (partial blocks at the border are dropped)."""
    h, w = labels.shape
    hb, wb = h // cell, w // cell
    blocks = labels[:hb * cell, :wb * cell].reshape(hb, cell, wb, cell)
    out = np.empty((hb, wb, 3), dtype=np.uint16)
    for c in (GREEN, WHITE, OTHER):  # three classes, not pixels
        out[..., c] = (blocks == c).sum(axis=(1, 3))
    return out


def classify_grid(image_bgr: np.ndarray, conf: dict, valid: np.ndarray | None = None,
                  cell: int = 8) -> tuple[np.ndarray, FieldColour]:
    """Class counts per cell x cell block of a BGR image (see class_counts) and the frame's
    field colour."""
    labels, fc = classify_image(image_bgr, conf, valid)
    return class_counts(labels, cell), fc


def hue_deg(u, v) -> np.ndarray:
    """Angle (deg) of the chroma (U - 128, V - 128), the hue used by the green search."""
    return np.degrees(np.arctan2(np.asarray(v, float) - 128.0, np.asarray(u, float) - 128.0))


def uv_ellipse(fc: FieldColour, n: int = 64) -> np.ndarray:
    """(n, 2) points of the green ellipse in the UV plane at the field's luminance (plots)."""
    t = np.linspace(0, 2 * math.pi, n)
    return np.stack([fc.u + fc.axes[0] * np.cos(t), fc.v + fc.axes[1] * np.sin(t)], axis=1)
