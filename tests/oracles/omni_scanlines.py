"""Readable oracles of the omni extractor's per-frame steps (numpy), as the extractor computed
them when it classified the whole frame (it now classifies only the scan-line pixels):

- ``whole_image_classes``: the whole frame converted to YUV, the field green estimated from
  one pixel in 6 x 6 of the floor annulus and the local green map from 4 pixels of every
  8 x 8 block (stages.common.colour.estimate_field_colour), then the scan-line pixels
  classified;
- ``white_runs``: the run detection as array passes over the class sequence (runs, holes
  closed, neighbours across a gap, the crossing tests, the blocked lines);
- ``features``: the per-frame arrays, the crossings' middles interpolated by np.interp.

The compiled path (stages.extract.omni) is checked against these within stated tolerances.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from stages.common import colour
from stages.extract import omni


def floor_annulus(camera, pix, mask=None) -> np.ndarray:
    """(h, w) bool: the pixels between the radial scan lines' first and last image radius
    (``pix.radius_px``), where ``mask`` (True: floor) allows."""
    w, h = pix.image_size
    vv, uu = np.indices((h, w))
    r = np.hypot(uu - camera.centre[0], vv - camera.centre[1])
    valid = (r >= pix.radius_px[0]) & (r <= pix.radius_px[1])
    return valid if mask is None else valid & mask


def whole_image_classes(image_bgr, camera, pix, conf, mask=None):
    """(classes of the scan-line samples (one per sample, in line order), field colour)
    with the field green and the local green map of the whole frame."""
    ccfg = omni.colour_conf(conf)
    yuv = colour.to_yuv(image_bgr)
    fc = colour.estimate_field_colour(yuv, ccfg, floor_annulus(camera, pix, mask))
    labels = colour.classify_pixels(yuv, pix.pixels[pix.sample_pixel],
                                    pix.blocks.block[pix.sample_pixel], fc, ccfg)
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


def white_runs(labels, pix, conf):
    """Accepted white runs: SimpleNamespace(line, mid_s, width, length, blocked (bool per
    line)), in order along the concatenated lines."""
    rules = omni.RunRules.of(conf)._asdict()  # the thresholds: RUNS and the conf's max_white_m
    start, end, cls, line = _runs(labels, pix.line)
    nr = len(start)
    if nr >= 3:  # close holes, decided on the runs as found
        length = end - start + 1
        inner = np.zeros(nr, bool)
        inner[1:-1] = (cls[:-2] == cls[2:]) & (line[:-2] == line[1:-1]) & (line[1:-1] == line[2:])
        nb = np.empty_like(cls)
        nb[1:-1] = cls[:-2]
        fill = inner & (((nb == colour.WHITE) & (cls != colour.WHITE)
                         & (length <= rules["white_hole_px"]))
                        | ((nb == colour.GREEN) & (cls == colour.OTHER)
                           & (length <= rules["max_gap_px"])))
        if fill.any():
            cls = np.where(fill, nb, cls)
            start, end, cls, line = _runs(np.repeat(cls, length), pix.line)
    length = end - start + 1
    s = pix.s
    nr = len(start)

    def neighbour(direction):
        """Index of the run beside each run, skipping one short unclassified gap."""
        idx = np.arange(nr) + direction
        inside = (idx >= 0) & (idx < nr)
        idx = np.clip(idx, 0, nr - 1)
        gap = inside & (cls[idx] == colour.OTHER) & (length[idx] <= rules["max_gap_px"]) & (
            line[idx] == line)
        idx2 = np.clip(idx + direction * gap, 0, nr - 1)
        inside2 = inside & (idx + direction * gap >= 0) & (idx + direction * gap < nr)
        return idx2, inside2

    prev, prev_ok = neighbour(-1)
    nxt, nxt_ok = neighbour(+1)
    is_green = (cls == colour.GREEN) & (length >= rules["min_green_px"]) & (
        s[end] - s[start] >= rules["min_green_m"])
    cand = ((cls == colour.WHITE) & prev_ok & nxt_ok & (line[prev] == line) & (line[nxt] == line)
            & is_green[prev] & is_green[nxt])
    j = np.flatnonzero(cand)
    left = 0.5 * (s[end[prev[j]]] + s[start[j]])
    right = 0.5 * (s[end[j]] + s[start[nxt[j]]])
    width = right - left
    dist = pix.dist
    depth = np.abs(0.5 * (dist[end[j]] + dist[start[nxt[j]]])
                   - 0.5 * (dist[end[prev[j]]] + dist[start[j]]))
    ok = ((length[j] >= rules["min_white_px"]) & (width >= rules["min_white_m"])
          & ((depth <= rules["max_white_m"]) | (length[j] <= rules["far_white_px"])))
    accepted = np.zeros(nr, bool)
    accepted[j[ok]] = True
    first_acc = np.full(pix.n_lines, nr)
    acc = np.flatnonzero(accepted)
    np.minimum.at(first_acc, line[acc], acc)
    before = (np.arange(nr) < first_acc[line]) & (s[end] - s[start] >= rules["min_white_m"])
    near_start = s[start] - pix.line_start_s[line] <= rules["start_margin_m"]
    blocked = np.zeros(pix.n_lines, bool)
    blocked[line[(cls == colour.WHITE) & ~accepted & (before | near_start)]] = True
    j = j[ok]
    return SimpleNamespace(line=line[j], mid_s=0.5 * (left + right)[ok], width=width[ok],
                           length=length[j], blocked=blocked)


def features(pix, runs):
    """The per-frame arrays (radial, spiral, points, points_px) of ``white_runs``' runs."""
    line_span = 1000.0  # m, larger than any scan line: one monotone key over all lines
    sample_key = pix.s + pix.line * line_span
    key = runs.mid_s + runs.line * line_span

    def at(values):
        return np.interp(key, sample_key, values)

    n = pix.scanlines.n_angles
    dist = at(pix.dist)
    radial = np.full((n, pix.scanlines.max_crossings), np.nan, np.float32)
    spiral = np.full((2, n), np.nan, np.float32)
    for k in range(n):  # the nearest max_crossings crossings of each radial line
        d = dist[runs.line == k][:pix.scanlines.max_crossings]
        radial[k, :len(d)] = d
    for k in range(2 * n):  # a spiral's first crossing, none when blocked
        d = dist[runs.line == n + k]
        if len(d) and not runs.blocked[n + k]:
            spiral.reshape(-1)[k] = d[0]
    points = np.stack([at(pix.xy[:, 0]), at(pix.xy[:, 1])], axis=1).astype(np.float32)
    points_px = np.stack([at(pix.uv[:, 0]), at(pix.uv[:, 1])], axis=1).astype(np.float32)
    return {"radial": radial, "spiral": spiral, "points": points, "points_px": points_px}


def extract_frame(image_bgr, camera, pix, conf, mask=None):
    """The former extractor end to end: whole-image classes, white_runs, features."""
    labels, _ = whole_image_classes(image_bgr, camera, pix, conf, mask)
    return features(pix, white_runs(labels, pix, conf))
