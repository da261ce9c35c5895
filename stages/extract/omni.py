"""Line points of an omnidirectional (catadioptric) image along the scan lines of
Ribeiro et al. (2015).

The scan lines are the ones of the tables (stages.common.scanlines.ScanLines): 72 radial lines
(line k at 5k deg counter-clockwise from the robot's forward direction) and 72 + 72 spirals
(start angle 5k deg, direction 0 counter-clockwise, 1 clockwise). They are walked in the image
through the calibration (stages.common.camera.OmniCamera):

- once per calibration (``ScanLinePixels``, cached): every scan line is sampled densely in the
  image (radial lines along their image ray at ``sample_step_px``, spirals from their ground
  polyline resampled to the same pixel spacing), rounded to pixels, consecutive duplicates
  removed; each pixel keeps the ground position of the samples it holds (robot frame, metres),
  its ground distance from the robot centre and the ground arc length along its scan line;
- per frame (``extract_frame``): one gather of the scan-line pixels, their colour classes
  (stages.common.colour, field green estimated per frame), and run detection on the
  concatenated class sequence. Short holes are closed first (up to ``white_hole_px`` non-white
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

Only every ``spiral_start_step``-th spiral start angle is walked (2: 36 spirals each way, 10 deg
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
import json
import math

import numpy as np

from ..common import colour
from ..common.scanlines import ScanLines

_SL = ScanLines()

confs = {
    "default": {
        "colour": copy.deepcopy(colour.confs["default"]),
        # the scan lines; must equal the map's (stages.build_map conf)
        "scanlines": {
            "robot_radius": _SL.robot_radius,
            "max_range": _SL.max_range,
            "spiral_end_radius": _SL.spiral_end_radius,
        },
        "sample_step_px": 0.5,  # sampling of a scan line in the image before rounding
        "min_green_px": 2,  # green run before and after a white run: pixels ...
        "min_green_m": 0.04,  # ... and ground metres along the line
        "max_gap_px": 3,  # unclassified pixels allowed between green and white (blurred edges)
        "white_hole_px": 2,  # non-white pixels inside a white run that are closed
        "start_margin_m": 0.15,  # white this near a spiral's start that is no crossing blocks
        # the spiral (the robot stands on or next to a line: its first crossing is unseen)
        "min_white_px": 1,  # white run: at least this many pixels ...
        "min_white_m": 0.03,  # ... and this wide on the ground (m) ...
        "max_white_m": 0.4,  # ... and at most this wide (m) ...
        "far_white_px": 2,  # ... unless it is at most this many pixels long
        "spiral_start_step": 2,  # walk every 2nd spiral start angle (seed: 36 each way, 10 deg)
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


def scanlines_of(conf: dict) -> ScanLines:
    """The scan-line definition of an extraction conf."""
    s = conf["scanlines"]
    return ScanLines(robot_radius=float(s["robot_radius"]), max_range=float(s["max_range"]),
                     spiral_end_radius=float(s["spiral_end_radius"]))


# ---------------------------------------------------------------------------- precomputation


@dataclasses.dataclass
class ScanLinePixels:
    """Every scan line of one calibration as image pixels, concatenated line after line.

    Per pixel sample: ``u``, ``v`` (int), ``line`` (index into the lines), ``s`` (ground arc
    length along the line, m), ``dist`` (ground distance from the robot centre, m), ``xy`` (ground
    point in the robot frame, m), ``uv`` (sub-pixel image position). Lines: radial 0..71, spirals
    72..215 (72 + 72 * direction + start index), then the extra radial lines.
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
    valid: np.ndarray  # (h, w) floor pixels used to estimate the field colour
    image_size: tuple[int, int]  # (w, h)
    cell: int  # block size of the local green luminance map
    key: np.ndarray = None  # monotone sort key: s + line * LINE_SPAN
    flat: np.ndarray = None  # v * w + u
    block: np.ndarray = None  # flat index into the local green luminance map
    line_start_s: np.ndarray = None  # (n_lines,) arc length of each line's first pixel

    LINE_SPAN = 1000.0  # m, larger than any scan line

    def __post_init__(self):
        w, h = self.image_size
        self.key = self.s + self.line * self.LINE_SPAN
        self.flat = self.v * w + self.u
        first = np.flatnonzero(np.r_[True, self.line[1:] != self.line[:-1]])
        self.line_start_s = np.full(int(self.line.max()) + 1 if len(self.line) else 0, np.inf)
        self.line_start_s[self.line[first]] = self.s[first]
        self.block = colour.FieldColour.block_index(self.u, self.v, (h // self.cell,
                                                                     w // self.cell), self.cell)

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
    step = float(conf["sample_step_px"])
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
        for k in range(0, sl.n_angles, int(conf["spiral_start_step"])):
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
    # floor pixels for the field-colour estimate: the annulus of the scan lines, mask applied
    vv_, uu_ = np.indices((h, w))
    rad_img = np.hypot(uu_ - cu, vv_ - cv_)
    valid = (rad_img >= r0) & (rad_img <= r1)
    if mask is not None:
        valid &= mask
    return ScanLinePixels(scanlines=sl, u=ui, v=vi, line=line_o.astype(np.int64), s=s_m,
                          dist=d_m, xy=xy_m, uv=uv_m, masked=masked, n_radial=sl.n_angles,
                          n_extra=n_extra, extra_angles=extra_angles, valid=valid,
                          image_size=(w, h), cell=int(conf["colour"]["local_cell"]))


_CACHE: dict[str, ScanLinePixels] = {}


def _cache_key(camera, conf, mask) -> str:
    h = hashlib.sha256()
    h.update(json.dumps(camera.to_dict(), sort_keys=True).encode())
    keys = ("scanlines", "sample_step_px", "spiral_start_step", "points_radial_lines")
    h.update(json.dumps({k: conf[k] for k in keys}, sort_keys=True).encode())
    h.update(str(conf["colour"]["local_cell"]).encode())
    if mask is not None:
        h.update(np.packbits(mask).tobytes())
    return h.hexdigest()


def scanline_pixels(camera, conf: dict, mask: np.ndarray | None = None) -> ScanLinePixels:
    """``build_scanline_pixels`` cached per calibration, scan-line conf and mask."""
    key = _cache_key(camera, conf, mask)
    if key not in _CACHE:
        if len(_CACHE) >= 8:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = build_scanline_pixels(camera, conf, mask)
    return _CACHE[key]


# ---------------------------------------------------------------------------- per frame


def classify_scanlines(image_bgr: np.ndarray, pix: ScanLinePixels, conf: dict):
    """Colour classes of every scan-line pixel of a frame, and the frame's field colour."""
    ccfg = conf["colour"]
    yuv = colour.to_yuv(image_bgr)
    fc = colour.estimate_field_colour(yuv, ccfg, pix.valid)
    labels = colour.classify_pixels(yuv, pix.flat, pix.block, fc, ccfg)
    labels[pix.masked] = colour.OTHER
    return labels, fc


def _runs(labels, line):
    """Runs of equal class on the concatenated lines: start, end (inclusive), class, line."""
    n = len(labels)
    change = np.ones(n, bool)
    change[1:] = (labels[1:] != labels[:-1]) | (line[1:] != line[:-1])
    start = np.flatnonzero(change)
    end = np.concatenate([start[1:], [n]]) - 1
    return start, end, labels[start], line[start]


@dataclasses.dataclass
class WhiteRuns:
    """Accepted white runs (crossings) of a frame, in order along each scan line."""

    line: np.ndarray  # scan-line index
    mid_s: np.ndarray  # arc length (m) of the middle of the run along its line
    width: np.ndarray  # ground width (m) between the mid-points of its edges
    length: np.ndarray  # pixels
    blocked: np.ndarray  # lines where white that is not a crossing comes first (see below)


def find_white_runs(labels: np.ndarray, pix: ScanLinePixels, conf: dict) -> WhiteRuns:
    """Green -> white -> green runs on the concatenated scan lines (see module doc)."""
    n = len(labels)
    if n == 0:
        z = np.zeros(0)
        return WhiteRuns(z.astype(np.int64), z, z, z.astype(np.int64), z.astype(np.int64))
    start, end, cls, line = _runs(labels, pix.line)
    # close holes: where a path runs obliquely along a line's edge, the rounded pixels step out
    # of the line and back in, and mixed edge pixels fall between the classes. Non-white runs
    # of up to white_hole_px pixels between two white runs become white; unclassified runs of
    # up to max_gap_px between two green runs become green. A lone white pixel between green is
    # kept (far lines are one pixel wide); its ground width decides.
    nr = len(start)
    if nr >= 3:
        length = end - start + 1
        inner = np.zeros(nr, bool)
        inner[1:-1] = (cls[:-2] == cls[2:]) & (line[:-2] == line[1:-1]) & (line[1:-1] == line[2:])
        nb = np.empty_like(cls)
        nb[1:-1] = cls[:-2]
        fill = inner & (((nb == colour.WHITE) & (cls != colour.WHITE)
                         & (length <= conf["white_hole_px"]))
                        | ((nb == colour.GREEN) & (cls == colour.OTHER)
                           & (length <= conf["max_gap_px"])))
        if fill.any():
            cls = np.where(fill, nb, cls)
            labels = np.repeat(cls, length)
            start, end, cls, line = _runs(labels, pix.line)
    length = end - start + 1
    s = pix.s
    green_m = s[end] - s[start]  # ground extent of a run (between its first and last pixel)
    nr = len(start)

    def neighbour(direction):
        """Index of the run beside each run, skipping one short unclassified gap."""
        idx = np.arange(nr) + direction
        inside = (idx >= 0) & (idx < nr)
        idx = np.clip(idx, 0, nr - 1)
        gap = inside & (cls[idx] == colour.OTHER) & (length[idx] <= conf["max_gap_px"]) & (
            line[idx] == line)
        idx2 = np.clip(idx + direction * gap, 0, nr - 1)
        inside2 = inside & (idx + direction * gap >= 0) & (idx + direction * gap < nr)
        return idx2, inside2

    prev, prev_ok = neighbour(-1)
    nxt, nxt_ok = neighbour(+1)
    is_green = (cls == colour.GREEN) & (length >= conf["min_green_px"]) & (
        green_m >= conf["min_green_m"])
    cand = ((cls == colour.WHITE) & prev_ok & nxt_ok & (line[prev] == line) & (line[nxt] == line)
            & is_green[prev] & is_green[nxt])
    j = np.flatnonzero(cand)
    # edges half-way between the last green pixel and the first white one (mid-gap)
    left = 0.5 * (s[end[prev[j]]] + s[start[j]])
    right = 0.5 * (s[end[j]] + s[start[nxt[j]]])
    width = right - left
    # how far the run reaches away from the robot: on a radial line its width; on a spiral that
    # grazes a line (runs along it) much less than the path length inside the white
    dist = pix.dist
    depth = np.abs(0.5 * (dist[end[j]] + dist[start[nxt[j]]])
                   - 0.5 * (dist[end[prev[j]]] + dist[start[j]]))
    ok = ((length[j] >= conf["min_white_px"]) & (width >= conf["min_white_m"])
          & ((depth <= conf["max_white_m"]) | (length[j] <= conf["far_white_px"])))
    accepted = np.zeros(nr, bool)
    accepted[j[ok]] = True
    # a spiral reports its first crossing only: if white that is not a crossing comes first (a
    # graze along a line, a corner, white blurred into the surroundings, the robot standing on
    # a line at the spiral's start), its first crossing is unseen and the spiral is "blocked"
    first_acc = np.full(pix.n_lines, nr)
    acc = np.flatnonzero(accepted)
    np.minimum.at(first_acc, line[acc], acc)
    before = (np.arange(nr) < first_acc[line]) & (s[end] - s[start] >= conf["min_white_m"])
    near_start = s[start] - pix.line_start_s[line] <= conf["start_margin_m"]
    blocked = np.unique(line[(cls == colour.WHITE) & ~accepted & (before | near_start)])
    j = j[ok]
    return WhiteRuns(line[j], 0.5 * (left + right)[ok], width[ok], length[j], blocked)


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
    """The per-frame arrays from the accepted white runs. A spiral reports only its first
    crossing, so a blocked spiral (see find_white_runs) reports none."""
    line, mid_s = runs.line, runs.mid_s
    sl = pix.scanlines
    n = sl.n_angles
    key = mid_s + line * pix.LINE_SPAN
    dist = np.interp(key, pix.key, pix.dist)
    x = np.interp(key, pix.key, pix.xy[:, 0])
    y = np.interp(key, pix.key, pix.xy[:, 1])
    pu = np.interp(key, pix.key, pix.uv[:, 0])
    pv = np.interp(key, pix.key, pix.uv[:, 1])

    radial = np.full((n, sl.max_crossings), np.nan, np.float32)
    is_rad = line < n
    rl = line[is_rad]  # runs come in order along each line: nearest first
    if len(rl):
        first = np.searchsorted(rl, rl, side="left")
        rank = np.arange(len(rl)) - first
        keep = rank < sl.max_crossings
        radial[rl[keep], rank[keep]] = dist[is_rad][keep]
    spiral = np.full((2, n), np.nan, np.float32)
    is_sp = (line >= n) & (line < 3 * n)
    sp = line[is_sp] - n
    if len(sp):
        uniq, idx = np.unique(sp, return_index=True)
        spiral.reshape(-1)[uniq] = dist[is_sp][idx]
    blocked = runs.blocked[(runs.blocked >= n) & (runs.blocked < 3 * n)] - n
    spiral.reshape(-1)[blocked] = np.nan
    points = np.stack([x, y], axis=1).astype(np.float32)
    points_px = np.stack([pu, pv], axis=1).astype(np.float32)
    return {"radial": radial, "spiral": spiral, "points": points, "points_px": points_px}


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
