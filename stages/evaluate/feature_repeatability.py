"""Repeatability and matching score of local features under a known homography, after the
protocol of Mikolajczyk and Schmid (Mikolajczyk et al., "A comparison of affine region
detectors", IJCV 2005; as vlbenchmarks' RepeatabilityBenchmark computes it).

Regions. A keypoint (x, y, scale) stands for the circle of radius ``REGION_SCALES`` x scale
around it (stages.common.local_features: scale is a sigma for every detector). Image A's
circles are mapped into image B by the homography H (A -> B); a circle goes through H's local
affine map at its centre, which for the similarities used here (rotation, scale, translation)
is exact: a circle of radius r |det J|^(1/2). (For a general homography this replaces the
projected ellipse by the circle of the same area.)

Overlap error of a region a of A (projected into B) and a region b of B: 1 - |a n b| / |a u b|
after both circles are scaled by the factor that gives a a radius of ``NORMALISED_RADIUS``
(30 px) about their own centres, the centres staying where they are: the error then depends on
the relative scale and the distance of the centres in pixels, not on how large the detector
draws its regions. Two circles' intersection is the lens area, in closed form.

Common part. Only regions wholly inside both images count: a region of A must lie on A's valid
pixels and, projected, on B's; likewise for B's regions through H^-1.

Repeatability. Candidate correspondences are the pairs with overlap error < ``max_error``
(0.4); one-to-one correspondences are taken greedily in order of increasing error;
repeatability = correspondences / min(n_A, n_B) over the regions of the common part.

Matching score. Descriptors are matched one-to-one by nearest neighbour: the pairs in order of
increasing descriptor distance (L2, or Hamming for binary descriptors), each taken when
neither of its features is matched yet (pairs of opposite Laplacian sign excluded when both
features carry a sign). A descriptor match is correct when it is the geometric correspondence
of that feature; matching score = correct matches / min(n_A, n_B).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import NamedTuple

import numpy as np

from ..common.errors import FieldlocError
from ..common.jit import njit

REGION_SCALES = 3.0  # region radius in units of the keypoint's scale
NORMALISED_RADIUS = 30.0  # px, the reference region's radius for the overlap error
MAX_OVERLAP_ERROR = 0.4


class ImageFeatures(NamedTuple):
    """One image's side of a pair: its ``keypoints`` (N, >= 3: x, y, scale, ...; column 5 the
    Laplacian sign if present), their ``descriptors`` (N, D), the image's ``shape`` (h, w) and
    its ``valid`` pixels (bool (h, w); None: all). What the protocol reads of an image, kept
    together so the two images of a pair cannot be mixed up argument by argument."""

    keypoints: np.ndarray
    descriptors: np.ndarray
    shape: tuple[int, int]
    valid: np.ndarray | None = None


@dataclass
class PairScores:
    """The scores of one image pair."""

    repeatability: float
    matching_score: float
    correspondences: int  # one-to-one geometric correspondences
    correct_matches: int  # descriptor matches equal to the geometric correspondence
    n_a: int  # regions of A in the common part
    n_b: int
    detected_a: int  # all keypoints of A
    detected_b: int

    def as_dict(self) -> dict:
        return asdict(self)


# ---------------------------------------------------------------------------- geometry


def similarity_homography(angle: float = 0.0, scale: float = 1.0, centre=(0.0, 0.0),
                          centre_b=None) -> np.ndarray:
    """The 3 x 3 homography that rotates by ``angle`` (rad, in pixel axes: from +x towards +y)
    and scales by ``scale`` about ``centre`` of A, which lands on ``centre_b`` (default the
    same point) of B."""
    cx, cy = (float(v) for v in centre)
    bx, by = (cx, cy) if centre_b is None else (float(v) for v in centre_b)
    c, s = scale * math.cos(angle), scale * math.sin(angle)
    return np.array([[c, -s, bx - c * cx + s * cy],
                     [s, c, by - s * cx - c * cy],
                     [0.0, 0.0, 1.0]])


def project_points(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Points (N, 2) through the homography H."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    p = np.column_stack([xy, np.ones(len(xy))]) @ np.asarray(H, dtype=float).T
    return p[:, :2] / p[:, 2:3]


def project_circles(H: np.ndarray, xy: np.ndarray, radius: np.ndarray):
    """Centres (N, 2) and radii (N,) of circles mapped by H through its local affine map: the
    radius is scaled by |det J|^(1/2) of H's Jacobian at the centre (exact for similarities)."""
    H = np.asarray(H, dtype=float)
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    q = np.column_stack([xy, np.ones(len(xy))]) @ H.T
    w = q[:, 2]
    u, v = q[:, 0] / w, q[:, 1] / w
    # J = (H[:2, :2] - [u, v]^T H[2, :2]) / w
    j00 = (H[0, 0] - u * H[2, 0]) / w
    j01 = (H[0, 1] - u * H[2, 1]) / w
    j10 = (H[1, 0] - v * H[2, 0]) / w
    j11 = (H[1, 1] - v * H[2, 1]) / w
    det = np.abs(j00 * j11 - j01 * j10)
    return np.column_stack([u, v]), np.asarray(radius, dtype=float) * np.sqrt(det)


def circle_overlap_error(distance, r_a, r_b) -> np.ndarray:
    """1 - |A n B| / |A u B| of circles of radii r_a, r_b whose centres are ``distance``
    apart (arrays broadcast)."""
    d = np.asarray(distance, dtype=float)
    ra = np.asarray(r_a, dtype=float)
    rb = np.asarray(r_b, dtype=float)
    d, ra, rb = np.broadcast_arrays(d, ra, rb)
    small = np.minimum(ra, rb)
    big = np.maximum(ra, rb)
    inter = np.zeros(d.shape)
    inside = d <= big - small
    inter[inside] = np.pi * small[inside] ** 2
    lens = (~inside) & (d < ra + rb)
    if lens.any():
        dl, a, b = d[lens], ra[lens], rb[lens]
        ca = np.clip((dl ** 2 + a ** 2 - b ** 2) / (2 * dl * a), -1.0, 1.0)
        cb = np.clip((dl ** 2 + b ** 2 - a ** 2) / (2 * dl * b), -1.0, 1.0)
        k = (-dl + a + b) * (dl + a - b) * (dl - a + b) * (dl + a + b)
        inter[lens] = (a ** 2 * np.arccos(ca) + b ** 2 * np.arccos(cb)
                       - 0.5 * np.sqrt(np.maximum(k, 0.0)))
    union = np.pi * (ra ** 2 + rb ** 2) - inter
    return 1.0 - inter / union


def candidate_correspondences(centres_a: np.ndarray, radii_a: np.ndarray,
                              centres_b: np.ndarray, radii_b: np.ndarray,
                              max_error: float = MAX_OVERLAP_ERROR,
                              normalised_radius: float | None = NORMALISED_RADIUS):
    """Pairs (i, j, error) of regions of A (already in B's frame) and of B whose normalised
    overlap error is below ``max_error``; ``normalised_radius`` None: the regions as they are."""
    from scipy.spatial import cKDTree

    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if len(centres_a) == 0 or len(centres_b) == 0:
        return empty
    ra = np.asarray(radii_a, dtype=float)
    rb = np.asarray(radii_b, dtype=float)
    f = np.ones(len(ra)) if normalised_radius is None else normalised_radius / ra
    # the error is at least 1 - (r_small / r_big)^2, so a candidate's scaled radius is at most
    # f r_a / sqrt(1 - max_error), and its centre closer than the sum of the two radii
    reach = f * ra * (1.0 + 1.0 / math.sqrt(1.0 - max_error)) * (1.0 + 1e-9)
    tree = cKDTree(centres_b)
    near = tree.query_ball_point(centres_a, reach)
    i = np.repeat(np.arange(len(ra)), [len(n) for n in near])
    if len(i) == 0:
        return empty
    j = np.concatenate([np.asarray(n, dtype=np.int64) for n in near])
    d = np.linalg.norm(centres_a[i] - centres_b[j], axis=1)
    err = circle_overlap_error(d, f[i] * ra[i], f[i] * rb[j])
    keep = err < max_error
    return i[keep].astype(np.int64), j[keep], err[keep]


@njit(cache=True, nogil=True)
def _greedy(i, j, n_a, n_b):
    """One-to-one pairs taken in the given order when both ends are still free."""
    used_a = np.zeros(n_a, np.bool_)
    used_b = np.zeros(n_b, np.bool_)
    out = np.empty((min(n_a, n_b), 2), np.int64)
    n = 0
    for k in range(i.shape[0]):
        a = i[k]
        b = j[k]
        if not used_a[a] and not used_b[b]:
            used_a[a] = True
            used_b[b] = True
            out[n, 0] = a
            out[n, 1] = b
            n += 1
            if n == out.shape[0]:
                break
    return out[:n].copy()


def greedy_one_to_one(i: np.ndarray, j: np.ndarray, cost: np.ndarray, n_a: int,
                      n_b: int) -> np.ndarray:
    """(M, 2) one-to-one pairs: the candidates (i, j) in order of increasing ``cost`` (ties in
    the given order), each taken when neither end is taken yet."""
    order = np.argsort(cost, kind="stable")
    return _greedy(np.ascontiguousarray(np.asarray(i, np.int64)[order]),
                   np.ascontiguousarray(np.asarray(j, np.int64)[order]), int(n_a), int(n_b))


# ---------------------------------------------------------------------------- descriptors


def descriptor_distances(desc_a: np.ndarray, desc_b: np.ndarray, metric: str = "l2"):
    """(N_a, N_b) distances: Euclidean ('l2') or Hamming ('hamming', uint8 bit strings)."""
    if metric == "l2":
        a = np.asarray(desc_a, dtype=np.float64)
        b = np.asarray(desc_b, dtype=np.float64)
        d2 = (a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2.0 * a @ b.T
        return np.sqrt(np.maximum(d2, 0.0))
    if metric == "hamming":
        a = np.unpackbits(np.asarray(desc_a, dtype=np.uint8), axis=1).astype(np.float32)
        b = np.unpackbits(np.asarray(desc_b, dtype=np.uint8), axis=1).astype(np.float32)
        # bits differ where exactly one is set: |a| + |b| - 2 a.b
        return (a.sum(1)[:, None] + b.sum(1)[None, :] - 2.0 * a @ b.T).astype(np.float64)
    raise FieldlocError(f"unknown descriptor metric '{metric}' (l2 or hamming)")


# ---------------------------------------------------------------------------- the protocol


def _clearance(valid: np.ndarray | None, shape, xy: np.ndarray) -> np.ndarray:
    """Distance (px) from points to the nearest invalid pixel or the image border."""
    import cv2

    h, w = shape
    m = np.ones((h, w), bool) if valid is None else np.asarray(valid, dtype=bool)
    # pixels outside the image are invalid too: pad by one invalid pixel
    padded = np.zeros((h + 2, w + 2), np.uint8)
    padded[1:-1, 1:-1] = m
    dist = cv2.distanceTransform(padded, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
    xi = np.rint(xy[:, 0]).astype(np.int64)
    yi = np.rint(xy[:, 1]).astype(np.int64)
    inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    out = np.zeros(len(xy))
    out[inside] = dist[yi[inside], xi[inside]]
    return out


def common_part(kp: np.ndarray, H: np.ndarray, shape_own, valid_own, shape_other, valid_other,
                region_scales: float = REGION_SCALES) -> np.ndarray:
    """bool (N,): keypoints whose region lies on valid pixels of their own image and, mapped by
    H, of the other image."""
    kp = np.asarray(kp, dtype=float)
    if len(kp) == 0:
        return np.zeros(0, bool)
    r = region_scales * kp[:, 2]
    own = _clearance(valid_own, shape_own, kp[:, :2]) >= r
    c, rp = project_circles(H, kp[:, :2], r)
    other = _clearance(valid_other, shape_other, c) >= rp
    return own & other


def _keypoints(kp) -> np.ndarray:
    kp = np.asarray(kp, dtype=float)
    if kp.size == 0:
        return np.zeros((0, 3))
    if kp.ndim != 2 or kp.shape[1] < 3:
        raise FieldlocError(f"keypoints must be (N, >= 3): x, y, scale; got shape {kp.shape}")
    return kp


def evaluate_pair(image_a: ImageFeatures, image_b: ImageFeatures, H: np.ndarray, *,
                  metric: str = "l2", max_error: float = MAX_OVERLAP_ERROR,
                  region_scales: float = REGION_SCALES,
                  normalised_radius: float | None = NORMALISED_RADIUS,
                  use_laplacian: bool = True) -> PairScores:
    """Repeatability and matching score of the keypoints and descriptors of images A and B
    (ImageFeatures each), with H the homography A -> B. See the module docstring."""
    desc_a, shape_a, valid_a = image_a.descriptors, image_a.shape, image_a.valid
    desc_b, shape_b, valid_b = image_b.descriptors, image_b.shape, image_b.valid
    kp_a, kp_b = _keypoints(image_a.keypoints), _keypoints(image_b.keypoints)
    H = np.asarray(H, dtype=float)
    if H.shape != (3, 3) or not np.isfinite(H).all() or abs(np.linalg.det(H)) < 1e-12:
        raise FieldlocError("the homography must be an invertible 3 x 3 matrix")
    Hinv = np.linalg.inv(H)
    in_a = common_part(kp_a, H, shape_a, valid_a, shape_b, valid_b, region_scales)
    in_b = common_part(kp_b, Hinv, shape_b, valid_b, shape_a, valid_a, region_scales)
    ia, ib = np.flatnonzero(in_a), np.flatnonzero(in_b)
    a, b = kp_a[ia], kp_b[ib]
    n_a, n_b = len(a), len(b)
    n_min = min(n_a, n_b)
    if n_min == 0:
        return PairScores(0.0, 0.0, 0, 0, n_a, n_b, len(kp_a), len(kp_b))
    ca, ra = project_circles(H, a[:, :2], region_scales * a[:, 2])
    ci, cj, err = candidate_correspondences(ca, ra, b[:, :2], region_scales * b[:, 2],
                                            max_error, normalised_radius)
    geometric = greedy_one_to_one(ci, cj, err, n_a, n_b)
    partner = np.full(n_a, -1, np.int64)
    partner[geometric[:, 0]] = geometric[:, 1]

    dist = descriptor_distances(np.asarray(desc_a)[ia], np.asarray(desc_b)[ib], metric)
    if use_laplacian and a.shape[1] > 5 and b.shape[1] > 5:
        sa, sb = a[:, 5][:, None], b[:, 5][None, :]
        dist = np.where((sa * sb) < 0, np.inf, dist)
    di, dj = np.nonzero(np.isfinite(dist))
    matches = greedy_one_to_one(di, dj, dist[di, dj], n_a, n_b)
    correct = int(np.count_nonzero(partner[matches[:, 0]] == matches[:, 1]))
    return PairScores(repeatability=len(geometric) / n_min, matching_score=correct / n_min,
                      correspondences=len(geometric), correct_matches=correct, n_a=n_a,
                      n_b=n_b, detected_a=len(kp_a), detected_b=len(kp_b))


def warp_pair(image: np.ndarray, valid: np.ndarray | None, H: np.ndarray):
    """Image B = ``image`` warped by H (bilinear), and its valid mask: pixels whose source lies
    on valid pixels of A (nearest), the one-pixel rim next to invalid source pixels removed
    (their bilinear values mix in invalid ones)."""
    import cv2

    h, w = image.shape[:2]
    src_valid = np.ones((h, w), np.uint8) if valid is None else np.asarray(valid, np.uint8)
    warped = cv2.warpPerspective(image, H, (w, h), flags=cv2.INTER_LINEAR,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    vb = cv2.warpPerspective(src_valid, H, (w, h), flags=cv2.INTER_NEAREST,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    vb = cv2.erode(vb, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT,
                   borderValue=0).astype(bool)
    warped = warped.copy()
    warped[~vb] = 0
    return warped, vb
