"""The numba kernels of the colour classes (``colour``): the field green's estimate (the green
candidates among sampled pixels and their chroma histogram, the mean shift of their cluster,
the hue model's offsets and spreads), the local green map (per-block sums of green samples and
the fill of blocks without green), the gathers of sampled pixels, the per-pixel chroma tests
of the classes (``_chroma_bits``), the luminance thresholds per block, the classes of a fixed
set of pixels, and the whole-frame pass of the hue model that counts the classes per cell.
They take plain arrays, numbers and the tuples of constants ``colour`` makes (``ChromaTest``,
``PixelBlocks``, ``LuminanceRules``, ``_hue_test``'s) and write into output arrays;
``colour`` holds the classification API that builds their inputs and reads their results.
Kept apart so that the API reads without the kernels' loops in the way; nothing here imports
``colour``. The class codes and the threshold channels are defined here because the kernels
write them; ``colour`` takes them from here.
"""

from __future__ import annotations

import numpy as np

from .jit import njit
from .numeric import mean32, median32, var32

# the colour classes' codes in a class image (colour.classify_image)
GREEN, WHITE, OTHER = 0, 1, 2
Y_REF = 100.0  # luminance the field green search rescales chroma to
# luminance_thresholds channels: white if Y >= WHITE_MIN_Y; green if GREEN_MIN_Y <= Y <= ...MAX
WHITE_MIN_Y, GREEN_MIN_Y, GREEN_MAX_Y = 0, 1, 2


@njit(cache=True, nogil=True)
def _green_candidates(sub, chroma_ok, y_lo, y_hi, use_sat, min_sat2):
    """estimate_field_colour's green candidates among the sampled pixels ``sub`` (n, 3 YUV):
    chroma ``chroma_ok[U << 8 | V]``, Y in [y_lo, y_hi] and (``use_sat``) (U-128)^2 + (V-128)^2
    >= min_sat2 Y^2 in float32. Returns their Y, U, V in order, their chroma rescaled to Y_REF
    (float32, (U - 128) * (Y_REF / max(Y, 1))) and its 32 x 32 histogram of 8-unit bins."""
    n = sub.shape[0]
    c128 = np.float32(128.0)
    y_ref = np.float32(Y_REF)
    idx = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        y, u, v = sub[i, 0], sub[i, 1], sub[i, 2]
        if not chroma_ok[(np.int64(u) << 8) | np.int64(v)] or y < y_lo or y > y_hi:
            continue
        if use_sat:
            du = np.float32(u) - c128
            dv = np.float32(v) - c128
            yf = np.float32(y)
            if not (du * du + dv * dv >= min_sat2 * (yf * yf)):
                continue
        idx[m] = i
        m += 1
    ys = np.empty(m, np.uint8)
    us = np.empty(m, np.uint8)
    vs = np.empty(m, np.uint8)
    uu = np.empty(m, np.float32)
    vv = np.empty(m, np.float32)
    hist = np.zeros(1024, np.int64)
    for k in range(m):
        i = idx[k]
        ys[k], us[k], vs[k] = sub[i, 0], sub[i, 1], sub[i, 2]
        scale = y_ref / max(np.float32(ys[k]), np.float32(1.0))
        uu[k] = (np.float32(us[k]) - c128) * scale
        vv[k] = (np.float32(vs[k]) - c128) * scale
        bu = min(max(uu[k] + c128, np.float32(0.0)), np.float32(255.0))
        bv = min(max(vv[k] + c128, np.float32(0.0)), np.float32(255.0))
        hist[(np.int64(bu) >> 3) * 32 + (np.int64(bv) >> 3)] += 1
    return ys, us, vs, uu, vv, hist


@njit(cache=True, nogil=True)
def _near_cluster(uu, vv, nu, nv, rad2, bu, bv):
    """The samples with (uu - nu)^2 + (vv - nv)^2 <= rad2 (float32, as numpy evaluates it)
    copied in order into bu, bv; returns their number."""
    m = 0
    for i in range(uu.shape[0]):
        du = uu[i] - nu
        dv = vv[i] - nv
        if du * du + dv * dv <= rad2:
            bu[m] = uu[i]
            bv[m] = vv[i]
            m += 1
    return m


@njit(cache=True, nogil=True)
def _green_cluster(uu, vv, ys, nu, nv, rad2, iterations):
    """estimate_field_colour's mean shift of the green candidates' rescaled chroma (uu, vv
    float32, their luminance ``ys`` uint8) from (nu, nv): ``iterations`` steps to the mean
    of the candidates within sqrt(rad2) (float32 distances, the means by mean32), then those
    candidates' number, median luminance (np.median's, from their histogram) and chroma
    variances (var32). Returns (nu, nv, count, median Y, var U, var V); the last three are 0
    without candidates near."""
    n = uu.shape[0]
    bu = np.empty(n, np.float32)
    bv = np.empty(n, np.float32)
    r2 = np.float32(rad2)
    for _ in range(iterations):
        m = _near_cluster(uu, vv, np.float32(nu), np.float32(nv), r2, bu, bv)
        if m == 0:
            break
        nu, nv = np.float64(mean32(bu[:m])), np.float64(mean32(bv[:m]))
    fu, fv = np.float32(nu), np.float32(nv)
    hist = np.zeros(256, np.int64)
    m = 0
    for i in range(n):
        du = uu[i] - fu
        dv = vv[i] - fv
        if du * du + dv * dv <= r2:
            bu[m] = uu[i]
            bv[m] = vv[i]
            hist[ys[i]] += 1
            m += 1
    if m == 0:
        return nu, nv, 0, 0.0, np.float32(0.0), np.float32(0.0)
    # the median of the integers: the mean of the values at ranks (m - 1) // 2 and m // 2
    lo, hi, cum = -1, -1, 0
    for v in range(256):
        cum += hist[v]
        if lo < 0 and cum >= (m - 1) // 2 + 1:
            lo = v
        if hi < 0 and cum >= m // 2 + 1:
            hi = v
    return nu, nv, m, 0.5 * (float(lo) + float(hi)), var32(bu[:m]), var32(bv[:m])


@njit(cache=True, nogil=True)
def _hue_turned(u8, v8, hx, hy):
    """_hue_model's chroma (U - 128, V - 128) turned onto the field's direction (hx, hy):
    the float32 arrays (dv hx - du hy, du hx + dv hy) whose arctan2 is the hue offset, as
    numpy computed them."""
    n = u8.shape[0]
    num = np.empty(n, np.float32)
    den = np.empty(n, np.float32)
    c128 = np.float32(128.0)
    for i in range(n):
        du = np.float32(u8[i]) - c128
        dv = np.float32(v8[i]) - c128
        num[i] = dv * hx - du * hy
        den[i] = du * hx + dv * hy
    return num, den


@njit(cache=True, nogil=True)
def _hue_spread(d, u8, v8, y8, max_dev):
    """_hue_model's statistics of the green candidates whose hue offset ``d`` (float32, rad)
    from the field's is at most ``max_dev`` (float32): their number, the median |d| and the
    median saturation |(U - 128, V - 128)| / max(Y, 1) (np.hypot in float32), in float32 as
    the numpy expressions it replaces (np.median: the middle value, or the mean of the two
    middle ones; median32)."""
    n = d.shape[0]
    ad = np.empty(n, np.float32)
    sat = np.empty(n, np.float32)
    c128 = np.float32(128.0)
    m = 0
    for i in range(n):
        a = abs(d[i])
        if a <= max_dev:
            ad[m] = a
            hyp = np.hypot(np.float32(u8[i]) - c128, np.float32(v8[i]) - c128)
            sat[m] = hyp / max(np.float32(y8[i]), np.float32(1.0))
            m += 1
    if m == 0:
        return 0, np.nan, np.nan
    return m, median32(ad, m), median32(sat, m)


@njit(cache=True, nogil=True)
def _fill_blocks(gs, ys, fill, own_min, y_frame, out):
    """_fill_green_luminance, compiled: per block ys / gs where gs >= own_min (per block),
    else the sums
    over the fill x fill window around it (blocks beyond the map count 0) divided alike, else
    y_frame; float32 as the numpy expressions (the divisors at least float32(1e-6)). The
    sums are of counts and integer luminances, exact in any order (as cv2.boxFilter's)."""
    h, w = gs.shape
    r = fill // 2
    # summed-area tables of both (float64 holds the integer sums exactly)
    sg = np.zeros((h + 1, w + 1))
    sy = np.zeros((h + 1, w + 1))
    for i in range(h):
        for j in range(w):
            sg[i + 1, j + 1] = sg[i, j + 1] + sg[i + 1, j] - sg[i, j] + gs[i, j]
            sy[i + 1, j + 1] = sy[i, j + 1] + sy[i + 1, j] - sy[i, j] + ys[i, j]
    eps = np.float32(1e-6)
    for i in range(h):
        i0, i1 = max(i - r, 0), min(i + r + 1, h)
        for j in range(w):
            if gs[i, j] >= own_min[i, j]:
                out[i, j] = ys[i, j] / max(gs[i, j], eps)
                continue
            j0, j1 = max(j - r, 0), min(j + r + 1, w)
            g = np.float32(sg[i1, j1] - sg[i0, j1] - sg[i1, j0] + sg[i0, j0])
            if g > 0:
                y = np.float32(sy[i1, j1] - sy[i0, j1] - sy[i1, j0] + sy[i0, j0])
                out[i, j] = y / max(g, eps)
            else:
                out[i, j] = y_frame


@njit(cache=True, nogil=True)
def _hue_block_sums(yuv, blocks, mask, use_mask, hue, band, gs, ys):
    """_local_green_luminance's per-block sums for the hue model: over the samples every
    ``step`` px of the hb x wb blocks (k x k per block; ``blocks``: (step, k, hb, wb)), the
    count of green ones (the hue test of _chroma_tests in float32, ``hue``: _hue_test; Y in
    ``band`` (y_lo, y_hi); in ``mask`` if used) into ``gs`` and their summed Y into
    ``ys``."""
    step, k, hb, wb = blocks
    hx, hy, c2, lo, hi = hue
    y_lo, y_hi = band
    c128 = np.float32(128.0)
    zero = np.float32(0.0)
    # blocks and samples within them counted apart (no integer division per sample)
    for br in range(hb):
        for ka in range(k):
            a = br * k + ka
            i = a * step
            for bc in range(wb):
                for kb in range(k):
                    b = bc * k + kb
                    j = b * step
                    if use_mask and not mask[a, b]:
                        continue
                    y = yuv[i, j, 0]
                    if y < y_lo or y > y_hi:
                        continue
                    yf = np.float32(y)
                    du = np.float32(yuv[i, j, 1]) - c128
                    dv = np.float32(yuv[i, j, 2]) - c128
                    s = du * du
                    s += dv * dv
                    dot = du * hx
                    dot += dv * hy
                    y2 = yf * yf
                    if dot >= zero and dot * dot >= c2 * s and s >= lo * y2 and s <= hi * y2:
                        gs[br, bc] += np.float32(1.0)
                        ys[br, bc] += yf


@njit(cache=True, nogil=True)
def _sample_rows(yuv, step, mask, use_mask, out):
    n = 0
    for a, i in enumerate(range(0, yuv.shape[0], step)):
        for b, j in enumerate(range(0, yuv.shape[1], step)):
            if use_mask and not mask[a, b]:
                continue
            out[n, 0] = yuv[i, j, 0]
            out[n, 1] = yuv[i, j, 1]
            out[n, 2] = yuv[i, j, 2]
            n += 1
    return n


@njit(cache=True, nogil=True)
def _gather_rows(pixels, flat, out):
    """out[i] = pixels[flat[i]] for (n, 3) uint8 rows (numpy's fancy indexing of 3-byte rows
    takes ~10x longer)."""
    for i in range(flat.shape[0]):
        k = flat[i]
        out[i, 0], out[i, 1], out[i, 2] = pixels[k, 0], pixels[k, 1], pixels[k, 2]


@njit(cache=True, nogil=True)
def _chroma_bits(y, u, v, t):
    """(green, white) chroma tests of one YUV pixel: ``_chroma_tests``' float32 operations
    with the constants ``t`` (ChromaTest)."""
    yf = np.float32(y)
    du = np.float32(u) - np.float32(128.0)
    dv = np.float32(v) - np.float32(128.0)
    s = du * du + dv * dv
    white = s <= t.sat2 * (yf * yf)
    if t.hue:
        dot = du * t.hx + dv * t.hy
        y2 = yf * yf
        green = (dot >= np.float32(0.0)) & (dot * dot >= t.c2 * s) & (s >= t.s_lo2 * y2) \
            & (s <= t.s_hi2 * y2)
        return green, white
    ym = max(yf, np.float32(1.0))
    eu = du * t.field_y - t.du_g * ym
    ev = dv * t.field_y - t.dv_g * ym
    return (eu * eu) * t.b2 + (ev * ev) * t.a2 <= (ym * ym) * t.ab2, white


@njit(cache=True, nogil=True)
def _green_map(yuv, px, chroma, lum, y_map):
    """local_green_map, compiled: the green test of every pixel (on vectors), per block the
    number of its green floor pixels in the band and their Y sum (one packed addition a
    pixel), then the map from them (_fill_blocks) into ``y_map``."""
    y8, u8, v8 = yuv[0], yuv[1], yuv[2]
    n = y8.shape[0]
    green_y = np.empty(n, np.uint16)  # green in the band: 2^15 + Y, else 0
    for i in range(n):
        green = _chroma_bits(y8[i], u8[i], v8[i], chroma)[0]
        y = np.uint16(y8[i])
        take = np.uint16(px.floor[i]) & np.uint16(green) & np.uint16(y >= lum.band_lo) \
            & np.uint16(y <= lum.band_hi)
        green_y[i] = (np.uint16(0) - take) & (np.uint16(32768) | y)
    hb, wb = y_map.shape
    sums = np.zeros(hb * wb, np.int64)  # per block: green pixels << 32 | their Y sum
    for i in range(n):
        g = np.int64(green_y[i])
        sums[px.block[i]] += ((g >> 15) << 32) | (g & 0xFF)
    gs = np.empty((hb, wb), np.float32)
    ys = np.empty((hb, wb), np.float32)
    quarter = np.empty((hb, wb), np.float32)  # a quarter of the block's floor pixels, >= 1
    for r in range(hb):
        for c in range(wb):
            b = r * wb + c
            quarter[r, c] = max(np.float32(0.25) * px.floor_count[b], np.float32(1.0))
            gs[r, c] = np.float32(sums[b] >> 32)
            ys[r, c] = np.float32(sums[b] & 0xFFFFFFFF)
    _fill_blocks(gs, ys, lum.fill, quarter, lum.field_y, y_map)


@njit(cache=True, nogil=True)
def _classify_pixels(yuv, px, chroma, lum, y_map, out):
    """classify_blocks, compiled: the chroma tests of every pixel (on vectors); the luminance
    thresholds of the local green map (_block_thresholds) looked up per pixel; the classes
    (on vectors): white wins, pixels off the floor are OTHER."""
    y8, u8, v8 = yuv[0], yuv[1], yuv[2]
    n = y8.shape[0]
    bits = np.empty(n, np.uint8)  # 1 green, 2 white by chroma
    for i in range(n):
        green, white = _chroma_bits(y8[i], u8[i], v8[i], chroma)
        bits[i] = np.uint8(green) | (np.uint8(white) << np.uint8(1))
    hb, wb = y_map.shape
    # the luminance thresholds (each in 0..256) of the blocks with floor pixels, packed 9
    # bits each, then per pixel
    packed = np.zeros(hb * wb, np.uint32)
    for r in range(hb):
        for c in range(wb):
            b = r * wb + c
            if px.floor_count[b] > 0:
                t_white, t_lo, t_hi = _block_thresholds(
                    y_map[r, c], lum.white_contrast, lum.white_min_y, lum.green_min_ratio,
                    lum.green_max_ratio)
                packed[b] = (np.uint32(t_white) | (np.uint32(t_lo) << 9)
                             | (np.uint32(t_hi) << 18))
    at = np.empty(n, np.uint32)
    for i in range(n):
        at[i] = packed[px.block[i]]
    nine = np.uint32(511)
    for i in range(n):
        y = np.uint32(y8[i])
        f = np.uint32(px.floor[i])
        white = f & np.uint32(bits[i] >> 1) & np.uint32(y >= (at[i] & nine))
        green = (f & np.uint32(bits[i] & 1) & np.uint32(y >= ((at[i] >> 9) & nine))
                 & np.uint32(y <= (at[i] >> 18)) & (np.uint32(1) - white))
        out[i] = np.uint8(OTHER - white - (green << 1))


@njit(cache=True, nogil=True)
def _threshold_table(y_map, contrast, min_y, lo_ratio, hi_ratio, out):
    """luminance_thresholds of a local green map (finite), compiled: the same float32
    operations per block (_block_thresholds), as int16 (hb, wb, 3)."""
    for r in range(y_map.shape[0]):
        for c in range(y_map.shape[1]):
            out[r, c, WHITE_MIN_Y], out[r, c, GREEN_MIN_Y], out[r, c, GREEN_MAX_Y] = \
                _block_thresholds(y_map[r, c], contrast, min_y, lo_ratio, hi_ratio)


@njit(cache=True, nogil=True)
def _block_thresholds(yg, contrast, min_y, lo_ratio, hi_ratio):
    """luminance_thresholds of one local green luminance ``yg`` (float32, finite): (white
    min, green min, green max) as integers in 0..256 (an empty green band: 255, 254)."""
    c255 = np.float32(255.0)
    white_y = max(yg + contrast * (c255 - yg), min_y)
    white = min(max(np.ceil(white_y), np.float32(0.0)), np.float32(256.0))
    lo = min(max(np.ceil(lo_ratio * yg), np.float32(0.0)), np.float32(256.0))
    hi = min(max(np.floor(hi_ratio * yg), np.float32(-1.0)), c255)
    if lo > hi:
        return np.int16(white), np.int16(255), np.int16(254)
    return np.int16(white), np.int16(min(lo, c255)), np.int16(hi)


@njit(cache=True, nogil=True)
def _hue_row(px, thresholds, sat2, hue, white, counts):
    """One row of _hue_cells: ``px`` the row's interleaved YUV bytes (3 w), ``thresholds``
    the luminance thresholds per column (white, green low, green high) as float32 (integers,
    so the comparisons are those of the uint8 Y), ``hue`` the green test (_hue_test); the
    white mask (0 / 1) into ``white`` and the white and green pixels added to the column
    ``counts`` (white, green). Branch-free, so that it runs on vectors."""
    t_white, t_lo, t_hi = thresholds
    hx, hy, c2, lo, hi = hue
    col_white, col_green = counts
    c128 = np.float32(128.0)
    zero = np.float32(0.0)
    for c in range(px.shape[0] // 3):
        yf = np.float32(px[3 * c])
        du = np.float32(px[3 * c + 1]) - c128
        dv = np.float32(px[3 * c + 2]) - c128
        s = du * du
        s += dv * dv
        y2 = yf * yf
        is_white = (yf >= t_white[c]) & (s <= sat2 * y2)
        dot = du * hx
        dot += dv * hy
        is_green = ((yf >= t_lo[c]) & (yf <= t_hi[c]) & (dot >= zero) & (dot * dot >= c2 * s)
                    & (s >= lo * y2) & (s <= hi * y2))
        wb = np.uint8(is_white)
        white[c] = wb
        col_white[c] += wb
        col_green[c] += np.uint8(is_green & ~is_white)


@njit(cache=True, nogil=True)
def _hue_cells(yuv_rows, thr, cells, sat2, hue, keep_white, out, mask):
    """classify_cells' pass over the rows (h, 3 w) of a YUV image: each row by _hue_row
    (white wins over green), the column counts summed per cell every ``cell`` rows
    (``cells``: the cell and the local threshold block, px)."""
    cell, local = cells
    w = yuv_rows.shape[1] // 3
    hb, wb = out.shape[0], out.shape[1]
    th, tw = thr.shape[0], thr.shape[1]
    t_white = np.empty(w, np.float32)
    t_lo = np.empty(w, np.float32)
    t_hi = np.empty(w, np.float32)
    scratch = np.empty(w, np.uint8)
    col_white = np.zeros(w, np.uint8)
    col_green = np.zeros(w, np.uint8)
    last = -1
    for r in range(hb * cell):
        tr = min(r // local, th - 1)
        if tr != last:  # the thresholds of this row of local blocks, per column
            last = tr
            tc, left = 0, local  # the column's local block, and its columns still to go
            for c in range(w):
                if left == 0:
                    tc, left = min(tc + 1, tw - 1), local
                left -= 1
                t_white[c] = thr[tr, tc, 0]
                t_lo[c] = thr[tr, tc, 1]
                t_hi[c] = thr[tr, tc, 2]
        row_white = scratch
        if keep_white:
            row_white = mask[r]
        _hue_row(yuv_rows[r], (t_white, t_lo, t_hi), sat2, hue, row_white,
                 (col_white, col_green))
        if r % cell == cell - 1:
            cr = r // cell
            for j in range(wb):
                g = 0
                wh = 0
                for c in range(j * cell, j * cell + cell):
                    g += col_green[c]
                    wh += col_white[c]
                out[cr, j, 0] = g
                out[cr, j, 1] = wh
                out[cr, j, 2] = cell * cell - g - wh
            col_white[:] = 0
            col_green[:] = 0
