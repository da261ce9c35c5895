"""SURF, Speeded-Up Robust Features (Bay et al. (2008)), our own: OpenCV's pip wheels leave it
out (patented, ``OPENCV_ENABLE_NONFREE``). The numbers follow the paper, with the OpenCV contrib
and OpenSURF sources where it leaves a choice; options marked "ours" are additions, mostly from
SIFT (Lowe (2004)), and the figures behind them are in docs/results.md.

Detector (Fast-Hessian), on the integral image of the grey image scaled to [0, 1]:
- box filters approximating the second Gaussian derivatives; filter size L (odd), lobe l = L/3.
  Dxx: an L x (2l - 1) box minus 3 times its middle l x (2l - 1) box (weights +1 -2 +1), Dyy
  its transpose, Dxy four l x l boxes around the centre (- + + -: top left, top right, bottom
  left, bottom right). Each response is divided by the filter area L^2, so that the sizes
  compare like scale-normalised derivatives;
- det(H) = Dxx Dyy - (0.9 Dxy)^2, and the sign of the trace Dxx + Dyy (the Laplacian: +1 for a
  dark blob on a bright ground, -1 for a bright one) is kept for matching;
- octave o (0-based) holds the filter sizes 3 (2^(o+1) (i + 1) + 1), i = 0..3 (9, 15, 21, 27;
  15, 27, 39, 51; ...), sampled every ``initial_step`` 2^o pixels; octave o + 1 reuses layers
  1 and 3 of octave o at every second sample;
- ``threshold`` is on det(H) of these area-normalised responses, in (intensity)^2. A Gaussian
  blob of width sigma_b gives its largest det(H) with L ~ 5 sigma_b, detected at s ~ 0.7
  sigma_b where Dxx = Dyy ~ 0.18 c for a peak contrast c (``blob_det``); the default 4e-4
  (OpenSURF's) keeps blobs from c ~ 0.11 (28 grey levels of 255) up;
- a response is computed only where its whole filter lies on valid pixels (the mask);
- maxima over their 3 x 3 x 3 neighbourhood in the two middle layers of each octave, above
  ``threshold`` (of two equal neighbours the first in (layer, row, column) order), are refined
  by a 3D quadratic fit (central differences); offsets beyond half a sample in x, y or scale
  are rejected. Position = sample + offset times the octave's step; scale s = 1.2 / 9 (L +
  offset * the octave's filter increment), the sigma of the Gaussian the filter stands for.

Gaussian derivatives (``hessian: gaussian``, ours; default Bay's boxes, which are not isotropic:
turned images move their keypoints except at multiples of 90 deg). Each layer from the Gaussian
sigma = L / ``BLOB_SIZE`` the box stands for (a cv2.pyrDown pyramid, then a Gaussian at the
coarsest level fine enough for the samples), fourth-order central differences (Dxx (-1, 16,
-30, 16, -1) / 12, Dxy (1, -8, 0, 8, -1) / 12 in x and y), det(H) = Dxx Dyy - Dxy^2 times
(4 BLOB_RESPONSE)^2 sigma^4 (a blob gets the boxes' det(H): ``threshold`` keeps its meaning);
octaves, sizes, samples, masks, extrema, interpolation and reported scale as above.

Geometric scales (``geometric_layers`` n > 0, ours, with ``hessian: gaussian``; preset
``geometric``: n = 3, ``refine_moves`` 5). Bay's sizes, linear within an octave and up to 1.8x
apart, place a blob's scale only roughly (and miss some sizes between octaves), so a
repeatability test's overlap error rejects keypoints found at the right place. Here octave o
searches 15 2^(o + k / n), k = 0..n-1, neighbours 15 2^(o - 1 / n) and 15 2^(o + 1) (the
layout of SIFT, Lowe (2004)), sampled every ``initial_step`` 2^o, the last two sizes the next
octave's first two, the size increment the mean of the two gaps (``layers`` does not apply): a
blob gets s = 0.672 sigma (1.2 BLOB_SIZE / 9) within a few % at every size.

Moving refinement (``refine_moves`` n > 0, ours). Instead of rejecting a maximum whose offset
exceeds half a sample (often in scale, between two layers), the fit moves to the sample and
layer the offset points to and fits again, at most n times (SIFT: 5); rejected when it would
leave the octave's searched layers or the defined samples, or does not settle. It pays with
geometric scales; with Bay's linear sizes it changes nothing measurable.

Doubled image (``double_image``, ours, either hessian): as SIFT, the detector and descriptor
run on the image doubled by linear interpolation (cv2.resize's pixel-area alignment, the mask
by nearest pixel), and keypoints come back as x / 2 - 1 / 4, y / 2 - 1 / 4, scale / 2: the
smallest scale becomes s = 1 (``octaves`` 5 keeps the largest). It costs four times the pixels
for a small gain, so no preset holds it.

Orientation: Haar wavelet responses of size 4s on a grid of step s within radius 6s (109
points), weighted by a Gaussian of sigma 2s, binned by angle in 1 deg bins and summed over a
pi/3 window sliding in 1 deg steps; the longest sum vector gives the orientation. ``upright``
(U-SURF) skips this: orientation 0.

Edge test (``edge_ratio``, ours; 0 leaves Bay et al.'s detector). On a line oblique to the
image axes the boxes' det(H) stays positive where a true ridge's is 0; such responses line up
along every oblique line, vanish when it turns onto an axis and look alike, costing
repeatability and confusing matching. Along a line the orientation window's Haar responses
all point across it, their second-moment matrix M nearly of rank one: a keypoint is rejected
when M's eigenvalue ratio exceeds ``edge_ratio`` (10, SIFT's), i.e. its Foerstner roundness
4 det M / tr(M)^2 < 4 r / (1 + r)^2. ``max_keypoints`` then keeps the strongest survivors.

Descriptor: a 20s square aligned with the orientation, 4 x 4 subregions of 5 x 5 samples (step
s); Haar responses of size 2s rotated into the window's frame, weighted by a Gaussian of sigma
3.3s; each subregion gives (sum dx, sum dy, sum |dx|, sum |dy|): 64 values, unit length.

Orientations are angles in pixel axes (x = column, y = row, pointing down), from +x towards +y.
Haar boxes (even sizes 2 round(2s), 2 round(s)) are centred on the pixel corner nearest each
sample and clipped to the image, as OpenSURF rounds its samples. The four costly loops
(box-filter layers, extrema with interpolation, orientation, descriptor) are numba kernels,
compiled once and cached on disk.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import FieldlocError
from .jit import njit

# keypoint columns (the layout of stages.common.local_features)
X, Y, SCALE, ORIENTATION, RESPONSE, LAPLACIAN = range(6)
N_COLUMNS = 6
DESCRIPTOR_SIZE = 64

confs = {
    "default": {
        "threshold": 4e-4,  # det(H) of area-normalised responses, intensities in [0, 1]
        "octaves": 4,
        "layers": 4,  # per octave (>= 3: extrema are searched in the middle ones)
        "initial_step": 2,  # px between samples in the first octave (doubles per octave)
        "upright": False,  # U-SURF: no orientation assignment (orientation 0)
        "max_keypoints": 0,  # keep the strongest n (0: all)
        # reject keypoints whose Haar responses (orientation window) run mostly one way: the
        # eigenvalue ratio of their second-moment matrix above this (0: keep all, as Bay et al.)
        "edge_ratio": 10.0,
        # the second derivatives of the detector: "box" (Bay et al.'s box filters on the
        # integral image) or "gaussian" (the Gaussians the boxes stand for; module doc)
        "hessian": "box",
        # detect and describe on the image doubled by linear interpolation (as Lowe's SIFT
        # does), keypoints reported in the image's pixels (module doc)
        "double_image": False,
        # > 0: each octave searches this many filter sizes spaced by 2^(1 / n), from L = 15
        # (SIFT's layout of scales; hessian "gaussian" only; module doc); 0: Bay et al.'s
        # ``layers`` sizes 9, 15, 21, 27, ... of linear increments
        "geometric_layers": 0,
        # a fit whose offset exceeds half a sample or layer moves to the neighbour it points
        # to and fits again, at most this many times (Lowe's SIFT: 5); 0: rejected (Bay)
        "refine_moves": 0,
    },
}
confs["upright"] = {**confs["default"], "upright": True}
confs["gaussian"] = {**confs["default"], "hessian": "gaussian"}
# the Gaussian derivatives at SIFT's layout of scales, 3 per octave, and its refinement that
# moves to the sample a fit points to (module doc): the SURF that repeats as SIFT does under
# rotation and scale (bench row surf-quality)
confs["geometric"] = {**confs["gaussian"], "geometric_layers": 3, "refine_moves": 5}

# px between samples in the first octave at most: a longer step strides over the first octave's
# smallest searched filter (15 px) and its blobs (1e12: no sample, no keypoint)
MAX_INITIAL_STEP = 16
HESSIAN_WEIGHT = 0.9  # Dxy weight in det(H) (Bay et al.: 0.9)


def filter_size(octave: int, layer: int) -> int:
    """Box filter size (px) of ``layer`` in ``octave`` (both 0-based): 9, 15, 21, 27 in the
    first octave, then the increment doubles with each octave."""
    return 3 * ((2 ** (octave + 1)) * (layer + 1) + 1)


FIRST_SEARCHED_SIZE = 15  # filter_size(0, 1): the smallest size octave 0 searches


def geometric_sizes(octave: int, n: int) -> list[float]:
    """The filter sizes of ``octave`` when each octave searches ``n`` sizes spaced by 2^(1/n)
    (``geometric_layers``): 15 2^(octave + k / n) for k = -1..n, the first and the last only
    the searched ones' neighbours; octave o + 1 begins with the last two sizes of octave o
    (the same floats, so that their layers are reused)."""
    return [FIRST_SEARCHED_SIZE * 2.0 ** ((octave * n + k) / n) for k in range(-1, n + 1)]


def octave_sizes(conf: dict, octave: int) -> list:
    """The filter sizes of ``octave``: ``geometric_sizes`` when ``geometric_layers`` is set,
    else Bay et al.'s ``layers`` sizes (``filter_size``)."""
    if conf.get("geometric_layers", 0):
        return geometric_sizes(octave, conf["geometric_layers"])
    return [filter_size(octave, i) for i in range(conf["layers"])]


BLOB_RESPONSE = 0.1815  # |Dxx| / c at the centre of a Gaussian blob, at its best filter size
BLOB_SIZE = 5.04  # that best filter size L in units of the blob's sigma (blob_det)
HESSIANS = ("box", "gaussian")


def blob_det(contrast: float) -> float:
    """det(H) at the centre of a Gaussian blob of peak ``contrast`` (intensity, [0, 1] scale)
    for its best filter size: a guide to ``threshold``. With lobes of width l = L / 3 and
    height 2l and u = l / sigma_b, Dxx / c = 2 pi / (9 u^2) (2 Phi(u) - 1) 2 (Phi(1.5 u)
    - 3 Phi(0.5 u) + 1) (Phi the normal distribution), largest in size at u = 1.68 (L = 5.0
    sigma_b, s = 0.67 sigma_b) with 0.1815; Dxy = 0 there."""
    return (BLOB_RESPONSE * contrast) ** 2


def check_conf(conf: dict) -> dict:
    """A complete SURF conf with its values typed; a user error if a key is missing or a value
    is out of range."""
    try:
        c = {
            "threshold": float(conf["threshold"]),
            "octaves": int(conf["octaves"]),
            "layers": int(conf["layers"]),
            "initial_step": int(conf["initial_step"]),
            "upright": bool(conf["upright"]),
            "max_keypoints": int(conf["max_keypoints"]),
            "edge_ratio": float(conf["edge_ratio"]),
            "hessian": str(conf.get("hessian", "box")),
            "double_image": bool(conf.get("double_image", False)),
            "geometric_layers": int(conf.get("geometric_layers", 0)),
            "refine_moves": int(conf.get("refine_moves", 0)),
        }
    except KeyError as e:
        raise FieldlocError(f"surf conf misses key {e}") from None
    except (TypeError, ValueError) as e:
        raise FieldlocError(f"surf conf has a malformed value ({e})") from None
    for key, ok, want in (
            ("octaves", 1 <= c["octaves"] <= 6, "1..6"),
            ("layers", 3 <= c["layers"] <= 8, "3..8"),
            ("initial_step", 1 <= c["initial_step"] <= MAX_INITIAL_STEP,
             f"1..{MAX_INITIAL_STEP} px"),
            ("threshold", c["threshold"] >= 0, ">= 0"),
            ("max_keypoints", c["max_keypoints"] >= 0, ">= 0 (0: all)"),
            ("edge_ratio", c["edge_ratio"] == 0 or c["edge_ratio"] >= 1, "0 (off) or >= 1")):
        if not ok:
            raise FieldlocError(f"surf conf: {key} must be {want}, got {c[key]:g}")
    if c["hessian"] not in HESSIANS:
        raise FieldlocError(f"surf conf: hessian must be one of {', '.join(HESSIANS)},"
                            f" not {c['hessian']!r}")
    if not 0 <= c["refine_moves"] <= 10:
        raise FieldlocError("surf conf: refine_moves must be 0..10")
    if not 0 <= c["geometric_layers"] <= 8:
        raise FieldlocError("surf conf: geometric_layers must be 0..8")
    if c["geometric_layers"] and c["hessian"] != "gaussian":
        raise FieldlocError("surf conf: geometric_layers needs hessian 'gaussian' (box filters"
                            " come in sizes of 3 (2 k + 1) only)")
    return c


# ---------------------------------------------------------------------------- integral images


def check_mask(mask, shape) -> np.ndarray:
    """``mask`` as a bool array of ``shape``; a user error otherwise."""
    m = np.asarray(mask)
    if m.shape != tuple(shape):
        raise FieldlocError(f"mask is {m.shape[1] if m.ndim > 1 else '?'} x {m.shape[0]} px,"
                            f" the image {shape[1]} x {shape[0]}")
    return m.astype(bool, copy=False)


def fill_invalid(image: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """A copy of ``image`` whose pixels outside ``mask`` hold the mean of those inside (rounded
    for integer images): no edge where the valid region ends."""
    out = image.copy()
    fill = float(image[mask].mean()) if mask.any() else 0.0
    out[~mask] = round(fill) if np.issubdtype(image.dtype, np.integer) else fill
    return out


def prepared_image(image_gray: np.ndarray, mask: np.ndarray | None = None):
    """(image, valid mask or None, unit): the grey image as float64 (integer images keep their
    values) with its invalid pixels holding the mean of the valid ones (``fill_invalid``), and
    ``unit``, the factor that scales its values to [0, 1] (1 / the dtype's maximum for integer
    images; float images are expected in [0, 1]). The mask is None when every pixel is
    valid."""
    img = np.asarray(image_gray)
    if img.ndim != 2 or min(img.shape) < 1:
        raise FieldlocError(f"SURF needs a 2D grey image, got shape {img.shape}")
    if img.dtype == np.uint8:
        unit = 1.0 / 255.0
    elif np.issubdtype(img.dtype, np.integer) and not np.issubdtype(img.dtype, np.signedinteger):
        unit = 1.0 / np.iinfo(img.dtype).max
        img = img.astype(np.float64)
    elif np.issubdtype(img.dtype, np.floating):
        img = img.astype(np.float64)
        unit = 1.0
    else:
        raise FieldlocError(f"SURF cannot read an image of dtype {img.dtype}")
    m = None
    if mask is not None:
        m = check_mask(mask, img.shape)
        if m.all():
            m = None
        else:
            img = fill_invalid(img, m)
    return img, m, unit


def integral_images(image_gray: np.ndarray, mask: np.ndarray | None = None):
    """(integral image, integral of the invalid pixels or None, unit): float64 (h + 1, w + 1)
    with a zero first row and column, of ``prepared_image``'s image: invalid pixels take the
    mean of the valid ones, so that the Haar responses of windows reaching over them see no
    edge."""
    return _integrals(*prepared_image(image_gray, mask))


def _integrals(img: np.ndarray, m: np.ndarray | None, unit: float):
    import cv2

    bad = None if m is None else cv2.integral((~m).view(np.uint8), sdepth=cv2.CV_64F)
    ii = cv2.integral(np.ascontiguousarray(img), sdepth=cv2.CV_64F)
    return ii, bad, unit


# ---------------------------------------------------------------------------- kernels


@njit(cache=True, nogil=True, inline="always")
def _box(ii, row, col, rows, cols):
    """Sum of the image over rows [row, row + rows) x cols [col, col + cols), which must lie
    inside the image."""
    r1 = row + rows
    c1 = col + cols
    return ii[r1, c1] - ii[row, c1] - ii[r1, col] + ii[row, col]


@njit(cache=True, nogil=True, inline="always")
def _undefined(bad, masked, r, c, size, h, w):
    """Whether the box filter of ``size`` centred on pixel (r, c) of an h x w image leaves the
    image or (``masked``) covers invalid pixels (``bad``: their integral image)."""
    b = (size - 1) // 2
    return (r - b < 0 or r + b >= h or c - b < 0 or c + b >= w
            or (masked and _box(bad, r - b, c - b, size, size) > 0.5))


@njit(cache=True, nogil=True)
def _hessian_layer(ii, bad, masked, size, step, weight, unit, det, trace):
    """det(H) and the trace Dxx + Dyy of the box filters of ``size`` at the samples
    (row, col) = (i, j) * step, for image values times ``unit``; -inf where the filter leaves
    the image or (``masked``) covers invalid pixels (``bad``: their integral image)."""
    h = ii.shape[0] - 1
    w = ii.shape[1] - 1
    b = (size - 1) // 2
    lobe = size // 3
    lobe_w = 2 * lobe - 1
    half = lobe // 2
    inv_area = unit / (size * size)
    w2 = weight * weight
    for i in range(det.shape[0]):
        r = i * step
        for j in range(det.shape[1]):
            c = j * step
            if _undefined(bad, masked, r, c, size, h, w):
                det[i, j] = -np.inf
                trace[i, j] = 0.0
                continue
            dxx = (_box(ii, r - lobe + 1, c - b, lobe_w, size)
                   - 3.0 * _box(ii, r - lobe + 1, c - half, lobe_w, lobe)) * inv_area
            dyy = (_box(ii, r - b, c - lobe + 1, size, lobe_w)
                   - 3.0 * _box(ii, r - half, c - lobe + 1, lobe, lobe_w)) * inv_area
            dxy = (_box(ii, r - lobe, c + 1, lobe, lobe) + _box(ii, r + 1, c - lobe, lobe, lobe)
                   - _box(ii, r - lobe, c - lobe, lobe, lobe)
                   - _box(ii, r + 1, c + 1, lobe, lobe)) * inv_area
            det[i, j] = dxx * dyy - w2 * dxy * dxy
            trace[i, j] = dxx + dyy


# fourth-order central differences at offsets -2..2: the first and the second derivative
_D1 = np.array([1.0, -8.0, 0.0, 8.0, -1.0]) / 12.0
_D2 = np.array([-1.0, 16.0, -30.0, 16.0, -1.0]) / 12.0


@njit(cache=True, nogil=True)
def _gaussian_layer(blurred, q, step, size, gain, bad, masked, h, w, det, trace):
    """det(H) and the trace of the Hessian of ``blurred`` (the image at 1 / f of its
    resolution, blurred to the layer's sigma) by central differences at its pixels (i, j) * q,
    which lie at (i, j) * step of the full image, times ``gain`` (sigma^4 in these pixels
    and the box filters' scale); -inf where the box filter of ``size`` would leave the image
    or (``masked``) cover invalid pixels, as _hessian_layer."""
    hb = blurred.shape[0] - 1
    wb = blurred.shape[1] - 1
    for i in range(det.shape[0]):
        r = i * step
        y = min(i * q, hb)
        for j in range(det.shape[1]):
            c = j * step
            if _undefined(bad, masked, r, c, size, h, w):
                det[i, j] = -np.inf
                trace[i, j] = 0.0
                continue
            x = min(j * q, wb)
            dxx = 0.0
            dyy = 0.0
            dxy = 0.0
            for u in range(-2, 3):  # fourth-order central differences (module doc)
                xu = min(max(x + u, 0), wb)
                yu = min(max(y + u, 0), hb)
                dxx += _D2[u + 2] * blurred[y, xu]
                dyy += _D2[u + 2] * blurred[yu, x]
                if u != 0:
                    for v in range(-2, 3):
                        if v != 0:
                            yv = min(max(y + v, 0), hb)
                            dxy += _D1[u + 2] * _D1[v + 2] * blurred[yv, xu]
            det[i, j] = gain * (dxx * dyy - dxy * dxy)
            trace[i, j] = dxx + dyy


@njit(cache=True, nogil=True, inline="always")
def _is_maximum(below, mid, above, r, c):
    """Whether mid[r, c] is the maximum of its 3 x 3 x 3 neighbourhood, all of it defined:
    strictly above the neighbours that come before (layer below, then earlier in raster
    order), at least equal to those after, so that of two equal maxima the first wins."""
    v = mid[r, c]
    is_max = True
    finite = True
    for dr in range(-1, 2):
        for dc in range(-1, 2):
            a = above[r + dr, c + dc]
            b = below[r + dr, c + dc]
            m = mid[r + dr, c + dc]
            before = dr < 0 or (dr == 0 and dc < 0)
            if a > v or b >= v or (before and m >= v) or (not before and m > v
                                                           and (dr != 0 or dc != 0)):
                is_max = False
            if a == -np.inf or b == -np.inf or m == -np.inf:
                finite = False
    return is_max and finite


@njit(cache=True, nogil=True, inline="always")
def _quadratic_fit(below, mid, above, r, c):
    """The 3D quadratic fit at mid[r, c] (gradient g and Hessian H by central differences):
    (solved, offset x, y, scale = -H^-1 g in samples and layers, the value's rise 0.5 g . o)."""
    v = mid[r, c]
    gx = 0.5 * (mid[r, c + 1] - mid[r, c - 1])
    gy = 0.5 * (mid[r + 1, c] - mid[r - 1, c])
    gs = 0.5 * (above[r, c] - below[r, c])
    hxx = mid[r, c + 1] + mid[r, c - 1] - 2.0 * v
    hyy = mid[r + 1, c] + mid[r - 1, c] - 2.0 * v
    hss = above[r, c] + below[r, c] - 2.0 * v
    hxy = 0.25 * (mid[r + 1, c + 1] - mid[r + 1, c - 1]
                  - mid[r - 1, c + 1] + mid[r - 1, c - 1])
    hxs = 0.25 * (above[r, c + 1] - above[r, c - 1]
                  - below[r, c + 1] + below[r, c - 1])
    hys = 0.25 * (above[r + 1, c] - above[r - 1, c]
                  - below[r + 1, c] + below[r - 1, c])
    # offset = -H^-1 g by the adjugate
    c00 = hyy * hss - hys * hys
    c01 = hxs * hys - hxy * hss
    c02 = hxy * hys - hxs * hyy
    c11 = hxx * hss - hxs * hxs
    c12 = hxy * hxs - hxx * hys
    c22 = hxx * hyy - hxy * hxy
    d = hxx * c00 + hxy * c01 + hxs * c02
    if d == 0.0 or not np.isfinite(d):
        return False, 0.0, 0.0, 0.0, 0.0
    ox = -(c00 * gx + c01 * gy + c02 * gs) / d
    oy = -(c01 * gx + c11 * gy + c12 * gs) / d
    os_ = -(c02 * gx + c12 * gy + c22 * gs) / d
    return True, ox, oy, os_, 0.5 * (gx * ox + gy * oy + gs * os_)


@njit(cache=True, nogil=True)
def _extrema(below, mid, above, trace, threshold, step, size, size_step, out, n):
    """Append to ``out`` (from row n) the refined 3x3x3 maxima of the middle layer ``mid``;
    return the new row count. Columns as the module's keypoint layout."""
    rows, cols = mid.shape
    for r in range(1, rows - 1):
        for c in range(1, cols - 1):
            v = mid[r, c]
            if not v > threshold:
                continue
            if not _is_maximum(below, mid, above, r, c):
                continue
            solved, ox, oy, os_, rise = _quadratic_fit(below, mid, above, r, c)
            if not solved or abs(ox) > 0.5 or abs(oy) > 0.5 or abs(os_) > 0.5:
                continue
            if n >= out.shape[0]:
                return -1  # the caller grows ``out`` and asks again
            out[n, 0] = (c + ox) * step
            out[n, 1] = (r + oy) * step
            out[n, 2] = (size + os_ * size_step) * (1.2 / 9.0)  # s = 1.2 L / 9
            out[n, 3] = 0.0
            out[n, 4] = v + rise
            out[n, 5] = 1.0 if trace[r, c] >= 0.0 else -1.0
            n += 1
    return n


@njit(cache=True, nogil=True)
def _extrema_moving(dets, traces, layer, threshold, step, sizes, moves, out, n):
    """As _extrema for the maxima of dets[layer] (an octave's layers, ``sizes`` their filter
    sizes), but a fit whose offset exceeds half a sample or layer moves to the neighbouring
    sample (or layer) it points to and fits again there, at most ``moves`` times (Lowe's
    SIFT: 5), instead of being rejected; it is rejected when it would leave the searched
    layers or the defined samples."""
    nl, rows, cols = dets.shape
    for r0 in range(1, rows - 1):
        for c0 in range(1, cols - 1):
            if not dets[layer, r0, c0] > threshold:
                continue
            if not _is_maximum(dets[layer - 1], dets[layer], dets[layer + 1], r0, c0):
                continue
            r = r0
            c = c0
            lay = layer
            kept = False
            ox = oy = os_ = rise = 0.0
            for _ in range(moves + 1):
                solved, ox, oy, os_, rise = _quadratic_fit(dets[lay - 1], dets[lay],
                                                           dets[lay + 1], r, c)
                if not solved:
                    break
                if abs(ox) <= 0.5 and abs(oy) <= 0.5 and abs(os_) <= 0.5:
                    kept = True
                    break
                c += int(np.rint(ox)) if abs(ox) > 0.5 else 0
                r += int(np.rint(oy)) if abs(oy) > 0.5 else 0
                lay += int(np.rint(os_)) if abs(os_) > 0.5 else 0
                if (lay < 1 or lay > nl - 2 or r < 1 or r > rows - 2 or c < 1
                        or c > cols - 2):
                    break
                defined = True
                for dl in range(-1, 2):
                    for dr in range(-1, 2):
                        for dc in range(-1, 2):
                            if dets[lay + dl, r + dr, c + dc] == -np.inf:
                                defined = False
                if not defined:
                    break
            if not kept:
                continue
            if n >= out.shape[0]:
                return -1  # the caller grows ``out`` and asks again
            out[n, 0] = (c + ox) * step
            out[n, 1] = (r + oy) * step
            out[n, 2] = (sizes[lay] + os_ * 0.5 * (sizes[lay + 1] - sizes[lay - 1])) * (1.2 / 9.0)
            out[n, 3] = 0.0
            out[n, 4] = dets[lay, r, c] + rise
            out[n, 5] = 1.0 if traces[lay, r, c] >= 0.0 else -1.0
            n += 1
    return n


@njit(cache=True, nogil=True, inline="always")
def _haar(ii, row, col, size):
    """Haar wavelet responses (dx: right half - left half, dy: lower half - upper half) of the
    size x size square (size even) whose centre is the corner between pixels (row - 1, col - 1)
    and (row, col), i.e. the point (col - 0.5, row - 0.5), clipped to the image. Both from the
    nine corners of the 2 x 2 half-squares. A sample at (x, y) uses the corner nearest to it,
    (floor(x) + 1, floor(y) + 1): the corners map onto corners when the image turns by 90 deg,
    so the responses turn with it."""
    half = size // 2
    h = ii.shape[0] - 1
    w = ii.shape[1] - 1
    r0 = row - half
    r2 = row + half
    c0 = col - half
    c2 = col + half
    r1 = row
    c1 = col
    if r0 < 0 or c0 < 0 or r2 > h or c2 > w:
        r0 = min(max(r0, 0), h)
        r1 = min(max(r1, 0), h)
        r2 = min(max(r2, 0), h)
        c0 = min(max(c0, 0), w)
        c1 = min(max(c1, 0), w)
        c2 = min(max(c2, 0), w)
    a00 = ii[r0, c0]
    a01 = ii[r0, c1]
    a02 = ii[r0, c2]
    a10 = ii[r1, c0]
    a12 = ii[r1, c2]
    a20 = ii[r2, c0]
    a21 = ii[r2, c1]
    a22 = ii[r2, c2]
    # right half minus left half; lower half minus upper half (a11 cancels in both)
    dx = (a22 - a02 - a21 + a01) - (a21 - a01 - a20 + a00)
    dy = (a22 - a12 - a20 + a10) - (a12 - a02 - a10 + a00)
    return dx, dy


@njit(cache=True, nogil=True, inline="always")
def _angle(y, x):
    """atan2(y, x) in [0, 2 pi) by a polynomial (error < 3e-4 rad), cheap enough to bin the
    orientation window's 109 responses by angle (np.arctan2 dominated the kernel)."""
    ax = abs(x)
    ay = abs(y)
    big = max(ax, ay)
    if big == 0.0:
        return 0.0
    a = min(ax, ay) / big
    s = a * a
    r = ((-0.0464964749 * s + 0.15931422) * s - 0.327622764) * s * a + a
    if ay > ax:
        r = 0.5 * np.pi - r
    if x < 0.0:
        r = np.pi - r
    if y < 0.0:
        r = 2.0 * np.pi - r
    if r >= 2.0 * np.pi:
        r -= 2.0 * np.pi
    return r


# the orientation's sample grid: integer offsets (i, j) with i^2 + j^2 < 36 and their
# Gaussian weights for sigma = 2s (in units of s)
_ORI_I, _ORI_J = (a.ravel() for a in np.meshgrid(np.arange(-6, 7), np.arange(-6, 7)))
_ORI_KEEP = _ORI_I ** 2 + _ORI_J ** 2 < 36
_ORI_I = np.ascontiguousarray(_ORI_I[_ORI_KEEP], dtype=np.int64)
_ORI_J = np.ascontiguousarray(_ORI_J[_ORI_KEEP], dtype=np.int64)
_ORI_W = np.exp(-(_ORI_I ** 2 + _ORI_J ** 2) / (2.0 * 2.0 ** 2))


@njit(cache=True, nogil=True)
def _orientation_window(ii, kp, oi, oj, ow, assign, min_round, cap, roundness, keep):
    """From the Haar responses of each keypoint's orientation window, in the order given: the
    Foerstner roundness 4 det(M) / tr(M)^2 of their weighted second-moment matrix M into
    ``roundness``; ``keep`` for those at least ``min_round``, until ``cap`` are kept (the rest
    are not looked at); for the kept ones with ``assign``, the orientation into kp[:, 3]. Returns
    the number kept."""
    kept = 0
    nb = 360  # 1 deg bins
    win = 60  # pi / 3
    bx = np.zeros(nb)
    by = np.zeros(nb)
    hx = np.zeros(oi.shape[0])
    hy = np.zeros(oi.shape[0])
    two_pi = 2.0 * np.pi
    for k in range(kp.shape[0]):
        x = kp[k, 0]
        y = kp[k, 1]
        s = kp[k, 2]
        size = 2 * int(round(2.0 * s))  # 4s, even
        if size < 2:
            size = 2
        mxx = 0.0
        mxy = 0.0
        myy = 0.0
        for p in range(oi.shape[0]):
            col = int(np.floor(x + oi[p] * s)) + 1  # the pixel corner nearest the sample
            row = int(np.floor(y + oj[p] * s)) + 1
            dx, dy = _haar(ii, row, col, size)
            wt = ow[p]
            mxx += wt * dx * dx
            mxy += wt * dx * dy
            myy += wt * dy * dy
            hx[p] = wt * dx
            hy[p] = wt * dy
        tr = mxx + myy
        roundness[k] = 4.0 * (mxx * myy - mxy * mxy) / (tr * tr) if tr > 0.0 else 0.0
        if roundness[k] < min_round:
            keep[k] = False
            continue
        keep[k] = True
        kept += 1
        if assign:
            bx[:] = 0.0
            by[:] = 0.0
            for p in range(oi.shape[0]):
                if hx[p] == 0.0 and hy[p] == 0.0:
                    continue
                b = int(_angle(hy[p], hx[p]) * (nb / two_pi))
                if b >= nb:
                    b = nb - 1
                bx[b] += hx[p]
                by[b] += hy[p]
            sx = 0.0
            sy = 0.0
            for b in range(win):
                sx += bx[b]
                sy += by[b]
            best = sx * sx + sy * sy
            best_x = sx
            best_y = sy
            end = win - 1
            for start in range(1, nb):
                end += 1
                if end == nb:
                    end = 0
                sx += bx[end] - bx[start - 1]
                sy += by[end] - by[start - 1]
                m = sx * sx + sy * sy
                if m > best:
                    best = m
                    best_x = sx
                    best_y = sy
            kp[k, 3] = np.arctan2(best_y, best_x) if best > 0.0 else 0.0
        if kept == cap:
            for rest in range(k + 1, kp.shape[0]):
                keep[rest] = False
            break
    return kept


# descriptor sample offsets (units of s) and their Gaussian weights, sigma = 3.3s
_DESC_U = (np.arange(20) - 9.5).astype(np.float64)
_DESC_W = np.exp(-(_DESC_U[None, :] ** 2 + _DESC_U[:, None] ** 2) / (2.0 * 3.3 ** 2))
_DESC_W = np.ascontiguousarray(_DESC_W)


@njit(cache=True, nogil=True)
def _descriptors(ii, kp, offsets, weights, out):
    """out[k] = the 64-value descriptor of keypoint k."""
    acc = np.zeros(64)
    for k in range(kp.shape[0]):
        x = kp[k, 0]
        y = kp[k, 1]
        s = kp[k, 2]
        co = np.cos(kp[k, 3])
        si = np.sin(kp[k, 3])
        size = 2 * int(round(s))  # 2s, even
        if size < 2:
            size = 2
        acc[:] = 0.0
        for a in range(20):  # along the window's y axis
            v = offsets[a] * s
            for b in range(20):  # along the window's x axis (the orientation)
                u = offsets[b] * s
                col = int(np.floor(x + u * co - v * si)) + 1
                row = int(np.floor(y + u * si + v * co)) + 1
                dx, dy = _haar(ii, row, col, size)
                wt = weights[a, b]
                ru = wt * (dx * co + dy * si)
                rv = wt * (dy * co - dx * si)
                o = ((a // 5) * 4 + b // 5) * 4
                acc[o] += ru
                acc[o + 1] += rv
                acc[o + 2] += abs(ru)
                acc[o + 3] += abs(rv)
        norm = 0.0
        for i in range(64):
            norm += acc[i] * acc[i]
        norm = np.sqrt(norm)
        if norm > 0.0:
            for i in range(64):
                out[k, i] = acc[i] / norm
        else:
            for i in range(64):
                out[k, i] = 0.0


# ---------------------------------------------------------------------------- stages


def hessian_pyramid(ii: np.ndarray, bad: np.ndarray | None, unit: float, conf: dict,
                    image: np.ndarray | None = None):
    """The detector's layers per octave: a list of (step, sizes, dets, traces), dets and traces
    (layers, rows, cols) float32 (det -inf where undefined). ``hessian`` "gaussian" needs the
    ``image`` (``prepared_image``'s) too."""
    h, w = ii.shape[0] - 1, ii.shape[1] - 1
    masked = bad is not None
    bad = bad if masked else np.zeros((1, 1))
    gaussian = conf.get("hessian", "box") == "gaussian"
    if gaussian:
        if image is None:
            raise ValueError("hessian 'gaussian' needs the image")
        levels = _GaussianLevels(np.asarray(image, np.float32) * np.float32(unit))
    out = []
    prev = None
    for o in range(conf["octaves"]):
        step = conf["initial_step"] * 2 ** o
        rows, cols = (h - 1) // step + 1, (w - 1) // step + 1
        sizes = octave_sizes(conf, o)
        dets = np.empty((len(sizes), rows, cols), np.float32)
        traces = np.empty((len(sizes), rows, cols), np.float32)
        for i, size in enumerate(sizes):
            reuse = None
            if prev is not None and size in prev[1]:
                reuse = prev[1].index(size)
            if reuse is not None:  # the same filter at every second sample of the octave below
                dets[i] = prev[2][reuse, ::2, ::2]
                traces[i] = prev[3][reuse, ::2, ::2]
            elif gaussian:
                blurred, q, gain = levels.layer(size, step)
                _gaussian_layer(blurred, q, step, round(size), gain, bad, masked, h, w, dets[i],
                                traces[i])
            else:
                _hessian_layer(ii, bad, masked, size, step, HESSIAN_WEIGHT, unit, dets[i],
                               traces[i])
        prev = (step, sizes, dets, traces)
        out.append(prev)
    return out


class _GaussianLevels:
    """The image blurred to the sigma L / BLOB_SIZE of each box filter size L, at the coarsest
    resolution that keeps it sampled: a pyramid of cv2.pyrDown halvings (each a 5-tap binomial
    blur of variance 1 px^2 and every second pixel, so that pixel k of level n lies on pixel
    k 2^n of the image; variance (4^n - 1) / 3 image px^2 by level n), the rest of the blur a
    Gaussian at the level. A size uses the coarsest level whose pixels are no farther apart
    than its samples (``step``) and whose remaining blur is at least ``MIN_LEVEL_SIGMA`` of its
    pixels, where central differences are close to isotropic."""

    MIN_LEVEL_SIGMA = 1.0

    def __init__(self, image: np.ndarray):
        self.pyramid = [np.ascontiguousarray(image, dtype=np.float32)]

    def layer(self, size: int, step: int):
        """(blurred image at its level, samples apart there, det gain) of filter ``size``."""
        import cv2

        sigma = size / BLOB_SIZE
        n = int(math.log2(step))
        while n > 0 and (sigma ** 2 - (4 ** n - 1) / 3) / 4 ** n < self.MIN_LEVEL_SIGMA ** 2:
            n -= 1
        while len(self.pyramid) <= n:
            self.pyramid.append(cv2.pyrDown(self.pyramid[-1]))
        f = 2 ** n
        rest = math.sqrt(max(sigma ** 2 - (4 ** n - 1) / 3, 0.0)) / f
        blurred = cv2.GaussianBlur(self.pyramid[n], (0, 0), rest) if rest > 0 else \
            self.pyramid[n]
        # sigma^2 L_xx of a blob of contrast c at its sigma is c / 4; the boxes' area-normalised
        # Dxx at their best size is BLOB_RESPONSE c: the gain gives det(H) the boxes' units
        s = sigma / f
        gain = (4.0 * BLOB_RESPONSE) ** 2 * s ** 4
        return np.ascontiguousarray(blurred, dtype=np.float32), step // f, gain


def detect(ii: np.ndarray, bad: np.ndarray | None, unit: float, conf: dict,
           image: np.ndarray | None = None) -> np.ndarray:
    """Fast-Hessian keypoints (N, 6), strongest first, orientation 0 (``integral_images``
    gives ii, bad and unit; ``image``, ``prepared_image``'s, for hessian "gaussian"); all of
    them, ``max_keypoints`` is applied later."""
    buf = np.empty((4096, N_COLUMNS), np.float64)
    n = 0
    for step, sizes, dets, traces in hessian_pyramid(ii, bad, unit, conf, image):
        moves = conf.get("refine_moves", 0)
        size_array = np.asarray(sizes, np.float64)
        for i in range(1, len(sizes) - 1):
            while True:
                if moves:
                    m = _extrema_moving(dets, traces, i, conf["threshold"], step, size_array,
                                        moves, buf, n)
                else:
                    m = _extrema(dets[i - 1], dets[i], dets[i + 1], traces[i],
                                 conf["threshold"], step, float(sizes[i]),
                                 0.5 * (sizes[i + 1] - sizes[i - 1]), buf, n)
                if m >= 0:
                    n = m
                    break
                buf = np.concatenate([buf, np.empty_like(buf)])
    kp = buf[:n]
    if conf.get("refine_moves", 0):  # two maxima may move to the same sample: keep one
        kp = np.unique(kp, axis=0)
    order = np.argsort(-kp[:, RESPONSE], kind="stable")
    return np.ascontiguousarray(kp[order])


def min_roundness(edge_ratio: float) -> float:
    """The Foerstner roundness 4 l1 l2 / (l1 + l2)^2 of eigenvalues in the ratio ``edge_ratio``:
    keypoints below it are rejected (10 -> 0.33)."""
    r = float(edge_ratio)
    return 4.0 * r / (1.0 + r) ** 2


def screen_and_orient(ii: np.ndarray, keypoints: np.ndarray, conf: dict) -> np.ndarray:
    """The keypoints (strongest first) that pass the edge test, at most ``max_keypoints`` of
    them, with their orientations (unless ``upright``)."""
    cap = conf["max_keypoints"] if conf["max_keypoints"] > 0 else len(keypoints)
    kp = np.array(keypoints, dtype=np.float64, order="C")
    if conf["edge_ratio"] == 0:
        kp = np.ascontiguousarray(kp[:cap])
        if conf["upright"]:
            return kp
    if len(kp) == 0:
        return kp
    min_round = min_roundness(conf["edge_ratio"]) if conf["edge_ratio"] > 0 else 0.0
    roundness = np.zeros(len(kp))
    keep = np.zeros(len(kp), np.bool_)
    _orientation_window(ii, kp, _ORI_I, _ORI_J, _ORI_W, not conf["upright"], min_round, cap,
                        roundness, keep)
    return np.ascontiguousarray(kp[keep])


def roundness(ii: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """The Foerstner roundness (N,) of each keypoint's orientation window (the edge test's
    quantity)."""
    kp = np.array(keypoints, dtype=np.float64, order="C")
    out = np.zeros(len(kp))
    if len(kp):
        _orientation_window(ii, kp, _ORI_I, _ORI_J, _ORI_W, False, 0.0, len(kp), out,
                            np.zeros(len(kp), np.bool_))
    return out


def describe(ii: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """The (N, 64) float32 unit descriptors of ``keypoints`` at their orientations."""
    out = np.empty((len(keypoints), DESCRIPTOR_SIZE), np.float32)
    if len(keypoints):
        _descriptors(ii, np.ascontiguousarray(keypoints, dtype=np.float64), _DESC_U, _DESC_W,
                     out)
    return out


def detect_and_describe(image_gray: np.ndarray, mask: np.ndarray | None = None,
                        conf: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """SURF keypoints (N, 6: x, y, scale, orientation, response, laplacian sign) and their
    (N, 64) descriptors, strongest first. ``mask``: bool, True where the image may be used."""
    c = check_conf(confs["default"] if conf is None else conf)
    img, m, unit = prepared_image(image_gray, mask)
    if c["double_image"]:
        img, m = doubled_image(img, m)
    ii, bad, unit = _integrals(img, m, unit)
    kp = screen_and_orient(ii, detect(ii, bad, unit, c, img if c["hessian"] == "gaussian"
                                      else None), c)
    desc = describe(ii, kp)
    if c["double_image"]:
        kp = halved_keypoints(kp)
    return kp, desc


def doubled_image(img: np.ndarray, mask: np.ndarray | None):
    """``prepared_image``'s image (float32, its values unchanged) and mask doubled: the image
    by linear interpolation, pixel k lying at k / 2 - 1 / 4 of the original (cv2.resize's
    alignment of pixel areas), the mask by its nearest pixel (k // 2)."""
    import cv2

    h, w = img.shape
    big = cv2.resize(np.asarray(img, np.float32), (2 * w, 2 * h), interpolation=cv2.INTER_LINEAR)
    if mask is None:
        return big, None
    return big, cv2.resize(mask.view(np.uint8), (2 * w, 2 * h),
                           interpolation=cv2.INTER_NEAREST).view(bool)


def halved_keypoints(keypoints: np.ndarray) -> np.ndarray:
    """Keypoints of the doubled image (``doubled_image``) in the original's pixels: x / 2 - 1 / 4,
    y / 2 - 1 / 4, scale / 2, the rest as they are."""
    kp = np.array(keypoints, dtype=np.float64, order="C")
    kp[:, [X, Y]] = 0.5 * kp[:, [X, Y]] - 0.25
    kp[:, SCALE] *= 0.5
    return kp
