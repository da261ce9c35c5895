"""Our SURF (stages.common.surf) against cases computed by hand, and the uniform interface of
stages.common.local_features over SURF, SIFT and ORB."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import norm

from stages.common import local_features as lf
from stages.common import surf
from stages.common.errors import FieldlocError

BAY = {**surf.confs["default"], "edge_ratio": 0.0}  # the detector exactly as Bay et al.


def box_kernels(size: int):
    """Dxx, Dyy, Dxy of Bay et al.'s figure 1 as explicit size x size arrays (centre at
    size // 2), written from the lobe geometry, not from the integral-image code."""
    lobe = size // 3
    b = size // 2
    dyy = np.zeros((size, size))
    # three stacked lobes of lobe rows each, 2 lobe - 1 columns wide, weights 1 -2 1
    cols = slice(b - lobe + 1, b + lobe)
    dyy[0:lobe, cols] = 1
    dyy[lobe:2 * lobe, cols] = -2
    dyy[2 * lobe:3 * lobe, cols] = 1
    dxx = dyy.T.copy()
    dxy = np.zeros((size, size))
    # four lobe x lobe squares around the centre pixel, one pixel apart
    dxy[b - lobe:b, b + 1:b + 1 + lobe] = 1  # top right
    dxy[b + 1:b + 1 + lobe, b - lobe:b] = 1  # bottom left
    dxy[b - lobe:b, b - lobe:b] = -1  # top left
    dxy[b + 1:b + 1 + lobe, b + 1:b + 1 + lobe] = -1  # bottom right
    return dxx, dyy, dxy


def direct_det(image: np.ndarray, size: int, row: int, col: int):
    """det(H) and trace at one pixel by multiplying the explicit kernels with the patch."""
    dxx, dyy, dxy = box_kernels(size)
    b = size // 2
    patch = image[row - b:row + b + 1, col - b:col + b + 1]
    area = size * size
    xx, yy, xy = ((k * patch).sum() / area for k in (dxx, dyy, dxy))
    return xx * yy - (0.9 * xy) ** 2, xx + yy


def gaussian_blob(n: int, centre, sigma: float, contrast: float, background: float = 0.5):
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    return background + contrast * np.exp(-((xx - centre[0]) ** 2 + (yy - centre[1]) ** 2)
                                          / (2 * sigma ** 2))


def strongest_dark_blob(sigma: float, conf: dict):
    """(the strongest keypoint, the image) of a dark Gaussian blob of ``sigma`` at (150.4,
    149.8) in a 301 px image, checked: found at its centre, its Laplacian positive (dark
    blob), its det(H) as ``blob_det`` says, and described."""
    centre = (150.4, 149.8)
    img = gaussian_blob(301, centre, sigma, -0.4)
    kp, desc = surf.detect_and_describe(img, None, conf)
    assert len(kp) >= 1 and desc.shape == (len(kp), 64)
    best = kp[0]
    assert np.hypot(best[0] - centre[0], best[1] - centre[1]) < 0.1 * sigma + 0.2
    assert best[surf.LAPLACIAN] == 1.0  # dark blob: positive trace
    assert best[surf.RESPONSE] == pytest.approx(surf.blob_det(0.4), rel=0.15)
    return best, img


def test_box_responses_equal_a_direct_convolution():
    rng = np.random.default_rng(3)
    img = gaussian_blob(160, (71.3, 83.6), 6.0, -0.3) + 0.05 * rng.standard_normal((160, 160))
    ii, bad, unit = surf.integral_images(img)
    pyramid = surf.hessian_pyramid(ii, bad, unit, surf.check_conf(BAY))
    checked = 0
    for step, sizes, dets, traces in pyramid[:3]:
        for layer, size in enumerate(sizes):
            for i, j in [(rng.integers(0, dets.shape[1]), rng.integers(0, dets.shape[2]))
                         for _ in range(40)] + [(round(83.6 / step), round(71.3 / step))]:
                r, c = i * step, j * step
                b = size // 2
                if r - b < 0 or c - b < 0 or r + b >= 160 or c + b >= 160:
                    assert dets[layer, i, j] == -np.inf  # the filter leaves the image
                    continue
                det, trace = direct_det(img, size, r, c)
                assert dets[layer, i, j] == pytest.approx(det, rel=1e-4, abs=1e-9)
                assert traces[layer, i, j] == pytest.approx(trace, rel=1e-4, abs=1e-7)
                checked += 1
    assert checked > 300


def test_responses_skip_filters_that_touch_invalid_pixels():
    img = gaussian_blob(120, (60, 60), 4.0, -0.3)
    mask = np.ones((120, 120), bool)
    mask[:, 90:] = False
    ii, bad, unit = surf.integral_images(img, mask)
    step, sizes, dets, _ = surf.hessian_pyramid(ii, bad, unit, surf.check_conf(BAY))[0]
    cols = np.arange(dets.shape[2]) * step
    for layer, size in enumerate(sizes):
        reaches = cols + size // 2 >= 90
        assert np.all(dets[layer][:, reaches] == -np.inf)
        inside = (cols - size // 2 >= 0) & ~reaches
        assert np.all(np.isfinite(dets[layer][size // 2 // step + 1:-(size // 2 // step + 1),
                                              inside]))


def test_a_blob_is_detected_at_its_matching_scale():
    """The box filters' lobes are wider than sigma = 1.2 L / 9: from their geometry a Gaussian
    blob of width sigma_b responds most to lobes of l = 1.68 sigma_b (L = 5.0 sigma_b), i.e.
    s = 0.67 sigma_b; the discrete lobes (2 l - 1 high) and the interpolation give ~0.74. The
    detected scale must follow the blob's size (scale covariance) at that ratio, at the
    blob's centre, with det(H) as ``blob_det`` predicts and the Laplacian's sign of a dark
    blob."""
    u = np.linspace(0.5, 4.0, 20001)
    f = (2 * np.pi / (9 * u ** 2)) * (2 * norm.cdf(u) - 1) * 2 * (
        norm.cdf(1.5 * u) - 3 * norm.cdf(0.5 * u) + 1)
    u_best = u[np.argmin(f)]
    assert u_best == pytest.approx(1.68, abs=0.01)
    assert -f.min() == pytest.approx(surf.BLOB_RESPONSE, rel=1e-3)
    ratios = []
    for sigma in (2.5, 3.2, 4.0, 5.0, 8.0, 10.0, 13.0):
        best, _ = strongest_dark_blob(sigma, BAY)
        ratios.append(best[surf.SCALE] / sigma)
    ratios = np.array(ratios)
    assert np.all((ratios > 0.4 * u_best) & (ratios < 0.5 * u_best + 0.02))  # 0.67 .. 0.86
    assert ratios.max() / ratios.min() < 1.15
    # a bright blob: negative Laplacian
    kp, _ = surf.detect_and_describe(gaussian_blob(201, (100.4, 99.8), 5.0, 0.4), None, BAY)
    assert kp[0][surf.LAPLACIAN] == -1.0


def textured_image(n: int, seed: int) -> np.ndarray:
    """Random elongated blobs and bars of several sizes: keypoints with a defined orientation."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    img = np.full((n, n), 0.5)
    for _ in range(60):
        x, y = rng.uniform(20, n - 20, 2)
        s1, s2 = rng.uniform(2.0, 7.0), rng.uniform(1.0, 3.0)
        a = rng.uniform(0, np.pi)
        u = (xx - x) * math.cos(a) + (yy - y) * math.sin(a)
        v = -(xx - x) * math.sin(a) + (yy - y) * math.cos(a)
        # an egg: brighter on one side, so that its orientation is defined
        img += rng.choice([-1, 1]) * 0.3 * np.exp(-(u / s1) ** 2 / 2 - (v / s2) ** 2 / 2) * (
            1 + 0.5 * np.tanh(u / s1))
    return np.clip(np.round(img * 255), 0, 255).astype(np.uint8)


def test_rotating_the_image_by_90_deg_rotates_the_orientation_and_keeps_the_descriptor():
    n = 257  # odd: the rotation maps the sampling grid (even coordinates) onto itself
    img = textured_image(n, 5)
    rot = np.ascontiguousarray(np.rot90(img))  # (x, y) -> (y, n - 1 - x): turns -90 deg
    kp, desc = surf.detect_and_describe(img, None, surf.confs["default"])
    kr, dr = surf.detect_and_describe(rot, None, surf.confs["default"])
    assert len(kp) >= 20
    mapped = np.column_stack([kp[:, 1], n - 1 - kp[:, 0]])
    d = np.hypot(mapped[:, None, 0] - kr[None, :, 0], mapped[:, None, 1] - kr[None, :, 1])
    j = d.argmin(1)
    same = d[np.arange(len(kp)), j] < 0.05
    assert same.mean() > 0.95  # the detector sees exactly the same keypoints
    k, r = kp[same], kr[j[same]]
    np.testing.assert_allclose(r[:, surf.SCALE], k[:, surf.SCALE], rtol=1e-4)
    turn = np.angle(np.exp(1j * (r[:, surf.ORIENTATION] - k[:, surf.ORIENTATION])))
    assert np.median(np.abs(turn + np.pi / 2)) < math.radians(3)
    assert np.mean(np.abs(turn + np.pi / 2) < math.radians(15)) > 0.9
    dist = np.linalg.norm(desc[same] - dr[j[same]], axis=1)
    assert np.median(dist) < 0.1  # unit vectors: unrelated descriptors are ~1 apart
    assert np.median(np.linalg.norm(desc[same][:, None] - dr[j[same]][None], axis=2)) > 0.5
    # upright SURF keeps orientation 0, and its descriptors do not follow the rotation
    ku, du = surf.detect_and_describe(img, None, surf.confs["upright"])
    kru, dru = surf.detect_and_describe(rot, None, surf.confs["upright"])
    assert np.all(ku[:, surf.ORIENTATION] == 0)
    # exact same-run: one detector, upright or not
    np.testing.assert_array_equal(ku[:, :3], kp[:, :3])
    du_pairs = np.linalg.norm(du[same] - dru[j[same]], axis=1)
    assert np.median(du_pairs) > 3 * np.median(dist)


def test_the_edge_test_removes_responses_along_an_oblique_line():
    """On a straight line at 30 deg, Bay's box det(H) stays positive along the whole line (the
    true det(H) of a ridge is 0); the default edge test rejects those keypoints."""
    n = 301
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    t = math.radians(30)
    dist = -(xx - 150) * math.sin(t) + (yy - 150) * math.cos(t)
    img = 0.3 + 0.4 * np.clip(6.0 - np.abs(dist) + 0.5, 0, 1)  # a 12 px line, no ends inside
    kp_bay, _ = surf.detect_and_describe(img, None, BAY)
    kp, _ = surf.detect_and_describe(img, None, surf.confs["default"])
    assert len(kp_bay) >= 20
    near = np.abs(-(kp_bay[:, 0] - 150) * math.sin(t) + (kp_bay[:, 1] - 150) * math.cos(t))
    assert np.all(near < 4 * kp_bay[:, 2])  # on the line (and on its sides, for larger filters)
    assert len(kp) == 0
    # turned onto an image axis, the same line gives Bay's detector nothing either
    axis = 0.3 + 0.4 * np.clip(6.0 - np.abs(yy - 150) + 0.5, 0, 1)
    assert len(surf.detect_and_describe(axis, None, BAY)[0]) == 0
    assert surf.min_roundness(10.0) == pytest.approx(40 / 121)


GAUSSIAN_BAY = {**BAY, "hessian": "gaussian"}  # Bay's detector with Gaussian derivatives


@pytest.mark.parametrize("geometric_layers, layers", [(0, 12), (3, 15)])
def test_gaussian_layers_give_the_hessian_of_a_quadratic_in_the_boxes_units(geometric_layers,
                                                                             layers):
    """On I = a x^2 + b y^2 + c x y a Gaussian blur leaves the second derivatives as they are
    and central differences are exact, so every layer, whichever pyramid level it is computed
    on, holds (4 BLOB_RESPONSE)^2 sigma^4 (4 a b - c^2) with sigma = L / BLOB_SIZE (the
    Gaussian a box filter of size L stands for), and the trace's sign of 2 a + 2 b; away from
    the borders, where pyrDown reflects the image. With ``geometric_layers`` 3 the sizes are
    15 2^(o + k / 3), k = -1..3, in octave o."""
    n = 400
    yy, xx = np.mgrid[0:n, 0:n].astype(float) - 200.0
    a, b, c = 4e-6, 2.5e-6, -1.5e-6
    img = 0.4 + a * xx ** 2 + b * yy ** 2 + c * xx * yy
    ii, bad, unit = surf.integral_images(img)
    conf = surf.check_conf({**GAUSSIAN_BAY, "octaves": 3, "geometric_layers": geometric_layers})
    pyramid = surf.hessian_pyramid(ii, bad, unit, conf, img)
    r = 2 ** (1 / 3)
    want_sizes = ([[15 / r, 15, 15 * r, 15 * r * r, 30], [30 / r, 30, 30 * r, 30 * r * r, 60]]
                  if geometric_layers else [[9, 15, 21, 27], [15, 27, 39, 51]])
    assert [step for step, _, _, _ in pyramid] == [2, 4, 8]
    for (_, sizes, _, _), want in zip(pyramid, want_sizes):
        np.testing.assert_allclose(sizes, want, rtol=1e-12)
    checked = 0
    for step, sizes, dets, traces in pyramid:
        for layer, size in enumerate(sizes):
            sigma = size / surf.BLOB_SIZE
            want = (4 * surf.BLOB_RESPONSE) ** 2 * sigma ** 4 * (4 * a * b - c * c)
            lo, hi = (90 + step - 1) // step, (310 - 1) // step
            inner = dets[layer, lo:hi, lo:hi]
            assert inner.size and np.allclose(inner, want, rtol=0.02)
            assert np.all(traces[layer, lo:hi, lo:hi] > 0)
            checked += 1
    assert checked == layers
    assert surf.BLOB_SIZE == pytest.approx(3 * 1.68, abs=0.01)  # L of a blob's best box (above)


def test_gaussian_hessian_detects_a_blob_where_and_as_large_as_the_boxes_do():
    """The Gaussian layers stand for the box filters: a Gaussian blob is found at its centre,
    at the scale the boxes give it (within 10 %), with det(H) as ``blob_det`` says."""
    for sigma in (3.2, 5.0, 8.0, 13.0):
        centre = (150.4, 149.8)
        img = gaussian_blob(301, centre, sigma, -0.4)
        box = surf.detect_and_describe(img, None, BAY)[0][0]
        kp, desc = surf.detect_and_describe(img, None, GAUSSIAN_BAY)
        g = kp[0]
        assert desc.shape == (len(kp), 64)
        assert np.hypot(g[0] - centre[0], g[1] - centre[1]) < 0.1 * sigma + 0.2
        assert g[surf.SCALE] == pytest.approx(box[surf.SCALE], rel=0.1)
        assert g[surf.RESPONSE] == pytest.approx(surf.blob_det(0.4), rel=0.15)
        assert g[surf.LAPLACIAN] == 1.0


def test_gaussian_hessian_has_no_response_along_an_oblique_line():
    """The true det(H) of a straight ridge is 0 at any angle: on the 30 deg line where Bay's
    boxes respond all along (the edge test's case), the Gaussian derivatives find nothing,
    with or without the edge test: the largest det(H) on the line (what is left of the
    pixels' ramp and the differences' error) is under a quarter of the default threshold and
    a tenth of the boxes' largest."""
    n = 301
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    t = math.radians(30)
    dist = -(xx - 150) * math.sin(t) + (yy - 150) * math.cos(t)
    img = 0.3 + 0.4 * np.clip(6.0 - np.abs(dist) + 0.5, 0, 1)
    assert len(surf.detect_and_describe(img, None, GAUSSIAN_BAY)[0]) == 0
    ii, bad, unit = surf.integral_images(img)

    def biggest(conf):
        return max(float(np.max(d[np.isfinite(d)])) for _, _, d, _ in surf.hessian_pyramid(
            ii, bad, unit, surf.check_conf(conf), img))

    assert biggest(GAUSSIAN_BAY) < 0.25 * surf.confs["default"]["threshold"]
    assert biggest(GAUSSIAN_BAY) < 0.1 * biggest(BAY)
    with pytest.raises(FieldlocError, match="hessian must be one of"):
        surf.check_conf({**BAY, "hessian": "log"})


def test_the_doubled_image_lies_at_half_its_pixels_minus_a_quarter():
    """``double_image``: pixel k of the doubled image lies at k / 2 - 1 / 4 of the image (a ramp
    says where), the mask doubles by its nearest pixel, and keypoints come back by the same
    map: (10, 20) at scale 4 of the doubled image is (4.75, 9.75) at scale 2."""
    yy, xx = np.mgrid[0:40, 0:50].astype(float)
    img = 0.2 + 0.004 * xx + 0.002 * yy
    mask = np.ones(img.shape, bool)
    mask[:, 30:] = False
    big, big_mask = surf.doubled_image(img, mask)
    assert big.shape == big_mask.shape == (80, 100)
    y2, x2 = np.mgrid[0:80, 0:100].astype(float)
    want = 0.2 + 0.004 * (x2 / 2 - 0.25) + 0.002 * (y2 / 2 - 0.25)
    np.testing.assert_allclose(big[1:-1, 1:-1], want[1:-1, 1:-1], atol=1e-6)
    assert big_mask[:, :60].all() and not big_mask[:, 60:].any()
    kp = surf.halved_keypoints(np.array([[10.0, 20.0, 4.0, 0.3, 1e-3, -1.0]]))
    np.testing.assert_allclose(kp, [[4.75, 9.75, 2.0, 0.3, 1e-3, -1.0]])


@pytest.mark.parametrize("conf", [{**BAY, "double_image": True},
                                  {**GAUSSIAN_BAY, "double_image": True}],
                         ids=["boxes", "gaussian"])
def test_a_blob_below_the_first_octave_is_found_at_its_scale_in_the_doubled_image(conf):
    """Bay's first searched filter is L = 15 (s = 2.0; L = 9 only a neighbour), so the default
    finds no keypoint on a blob of sigma 1.6 (its best box L = 5.04 sigma = 8). Doubling the
    image (the blob then has sigma 3.2, where the boxes find it) finds it at its centre in
    the image's pixels, at the scale the detector gives a
    blob (s = 0.67-0.86 sigma for the boxes, test_a_blob_is_detected_at_its_matching_scale;
    1.2 BLOB_SIZE / 9 = 0.67 sigma for the Gaussians, up to the interpolation), with its
    det(H) and its Laplacian's sign; a larger blob is found as without the option (within
    10 %). The default misses a blob of sigma 2.0 too."""
    centre = (60.4, 59.8)
    for sigma in (1.6, 2.0):
        small = gaussian_blob(121, centre, sigma, -0.4)
        assert len(surf.detect_and_describe(small, None, BAY)[0]) == 0
        assert len(surf.detect_and_describe(small, None, GAUSSIAN_BAY)[0]) == 0
    for sigma in (1.6, 2.0, 2.5, 5.0):
        img = gaussian_blob(121, centre, sigma, -0.4)
        kp, desc = surf.detect_and_describe(img, None, conf)
        assert len(kp) >= 1 and desc.shape == (len(kp), 64)
        best = kp[0]
        assert np.hypot(best[0] - centre[0], best[1] - centre[1]) < 0.1 * sigma + 0.2
        assert 0.6 < best[surf.SCALE] / sigma < 0.86
        # within 20 %: the linear interpolation of the doubled image flattens a narrow blob
        assert best[surf.RESPONSE] == pytest.approx(surf.blob_det(0.4), rel=0.2)
        assert best[surf.LAPLACIAN] == 1.0
        if sigma == 5.0:
            plain = surf.detect_and_describe(img, None, {**conf, "double_image": False})[0][0]
            assert best[surf.SCALE] == pytest.approx(plain[surf.SCALE], rel=0.1)


def test_geometric_layers_give_every_blob_the_same_scale_per_sigma():
    """Bay's sizes grow by linear steps (9, 15, 21, 27; then 15, 27, 39, 51, ...: neighbours
    up to 1.8x apart) and the scale interpolated between them follows a blob's sigma only
    roughly (s / sigma 0.68-0.80 over sigma 3-14, and no keypoint at all for some sizes
    between the octaves). With ``geometric_layers`` 3 each octave searches 15 2^(o + k / 3):
    every blob is found, at its centre, at s = 1.2 BLOB_SIZE / 9 = 0.672 of its sigma within
    3 % (the Gaussian derivatives' own ratio), and its det(H) as ``blob_det`` says."""
    conf = {**GAUSSIAN_BAY, "geometric_layers": 3}
    want = 1.2 * surf.BLOB_SIZE / 9
    ratios, linear = [], []
    for sigma in np.geomspace(3.0, 14.0, 15):
        best, img = strongest_dark_blob(sigma, conf)
        ratios.append(best[surf.SCALE] / sigma)
        plain = surf.detect_and_describe(img, None, GAUSSIAN_BAY)[0]
        linear.append(plain[0, surf.SCALE] / sigma if len(plain) else np.nan)
    np.testing.assert_allclose(ratios, want, rtol=0.03)
    linear = np.array(linear)
    assert np.isnan(linear).any() or np.nanmax(linear) / np.nanmin(linear) > 1.08
    # octave o + 1 begins with the last two sizes of octave o: the same layers, every second
    # sample
    img = gaussian_blob(301, (150.4, 149.8), 6.0, -0.4)
    ii, bad, unit = surf.integral_images(img)
    (_, s0, d0, t0), (_, s1, d1, t1) = surf.hessian_pyramid(
        ii, bad, unit, surf.check_conf({**conf, "octaves": 2}), img)
    assert s1[:2] == s0[-2:]
    # float32 box-filter responses of the same sizes at the same points: within a few ulp of
    # the octave's largest response (-inf where undefined, at the same places)
    for a, b in ((d1[:2], d0[-2:, ::2, ::2]), (t1[:2], t0[-2:, ::2, ::2])):
        assert np.array_equal(np.isfinite(a), np.isfinite(b))
        scale = np.abs(b[np.isfinite(b)]).max()
        np.testing.assert_allclose(np.where(np.isfinite(a), a, 0), np.where(np.isfinite(b), b, 0),
                                   rtol=1e-5, atol=1e-6 * scale)


def test_refine_moves_follows_the_fit_to_the_sample_it_points_to():
    """A quadratic det(H) over (column, row, layer), long and narrow along the diagonal, with its
    peak at column 10.3, row 10.7, layer 2.1: its largest samples are (10, 10) and (11, 11)
    (equal; the first in raster order wins), and the fit there finds the peak exactly, 0.7 of
    a sample away in the row, which Bay's refinement rejects. With refine_moves the fit moves
    to row 11, where the offset is (0.3, -0.3, 0.1): the keypoint at the peak, in pixels at
    the octave's step, with the peak's value and the size interpolated at layer 2.1."""
    rows, cols, layers = 21, 21, 5
    ll, rr, cc = np.meshgrid(np.arange(layers), np.arange(rows), np.arange(cols), indexing="ij")
    x, y, s_ = 10.3, 10.7, 2.1
    dets = (100.0 - 100.0 * ((cc - rr) - (x - y)) ** 2 - ((cc + rr) - (x + y)) ** 2
            - 0.5 * (ll - s_) ** 2).astype(np.float32)
    traces = np.ones_like(dets)
    sizes = np.array([9.0, 15.0, 21.0, 27.0, 33.0])
    step = 2
    out = np.empty((16, 6))
    assert dets[2, 10, 10] == dets[2, 11, 11] == dets[2].max()
    bay = sum(surf._extrema(dets[i - 1], dets[i], dets[i + 1], traces[i], 0.0, step,
                            sizes[i], 6.0, out, 0) for i in (1, 2, 3))
    assert bay == 0
    n = sum(surf._extrema_moving(dets, traces, i, 0.0, step, sizes, 5, out, 0)
            for i in (1, 2, 3))
    assert n == 1
    kp = out[0]
    np.testing.assert_allclose(kp[:2], [x * step, y * step], atol=1e-3)
    assert kp[surf.SCALE] == pytest.approx((21.0 + 0.1 * 6.0) * 1.2 / 9, rel=1e-3)
    assert kp[surf.RESPONSE] == pytest.approx(100.0, abs=1e-3)
    # no move allowed: rejected as Bay's refinement rejects it
    assert surf._extrema_moving(dets, traces, 2, 0.0, step, sizes, 0, out, 0) == 0


def test_refine_moves_keeps_every_keypoint_of_bays_refinement_and_adds_some():
    """A maximum whose first fit lies within half a sample is kept as it was; the others are
    followed instead of rejected."""
    img = textured_image(257, 7)
    conf = {**GAUSSIAN_BAY, "geometric_layers": 3}
    bay = surf.detect_and_describe(img, None, conf)[0]
    moved = surf.detect_and_describe(img, None, {**conf, "refine_moves": 5})[0]
    assert len(moved) > len(bay) >= 20
    d = np.abs(bay[:, None, :3] - moved[None, :, :3]).sum(2)
    assert np.all(d.min(1) == 0)


def test_the_new_options_check_their_values_and_default_to_bay():
    for bad, why in (({**BAY, "geometric_layers": 3}, "needs hessian 'gaussian'"),
                     ({**GAUSSIAN_BAY, "geometric_layers": 9}, "must be 0..8"),
                     ({**BAY, "refine_moves": -1}, "refine_moves must be 0..10")):
        with pytest.raises(FieldlocError, match=why):
            surf.check_conf(bad)
    # confs written before the options read as without them
    old = {k: v for k, v in surf.confs["default"].items()
           if k not in ("geometric_layers", "double_image", "refine_moves")}
    c = surf.check_conf(old)
    assert c["geometric_layers"] == 0 and c["double_image"] is False and c["refine_moves"] == 0


def test_mask_edges_make_no_keypoints_and_max_keypoints_keeps_the_strongest():
    img = textured_image(201, 2)
    dark = img.copy()
    dark[:, 120:] = 0  # a black region outside the valid mask, with a hard edge
    mask = np.ones(img.shape, bool)
    mask[:, 120:] = False
    kp, _ = surf.detect_and_describe(dark, mask, surf.confs["default"])
    assert len(kp) > 5
    assert np.all(kp[:, 0] < 120)
    # no keypoint on the masked edge: those of the masked image are those of the unmasked one
    full, _ = surf.detect_and_describe(img, None, surf.confs["default"])
    inner = full[full[:, 0] + 3.75 * full[:, 2] < 119]
    d = np.hypot(kp[:, None, 0] - inner[None, :, 0], kp[:, None, 1] - inner[None, :, 1])
    assert np.all(d.min(1) < 1e-6)
    few, _ = surf.detect_and_describe(img, None, {**surf.confs["default"], "max_keypoints": 5})
    np.testing.assert_array_equal(few, full[:5])  # exact same-run: one detection, truncated
    assert np.all(np.diff(full[:, surf.RESPONSE]) <= 0)


def test_bad_input_is_a_user_error():
    with pytest.raises(FieldlocError, match="2D grey"):
        surf.detect_and_describe(np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(FieldlocError, match="mask is"):
        surf.detect_and_describe(np.zeros((10, 10), np.uint8), np.ones((5, 5), bool))
    with pytest.raises(FieldlocError, match="octaves"):
        surf.check_conf({**surf.confs["default"], "octaves": 0})
    with pytest.raises(FieldlocError, match="misses key"):
        surf.check_conf({"threshold": 1e-4})
    kp, desc = surf.detect_and_describe(np.full((64, 64), 128, np.uint8))
    assert kp.shape == (0, 6) and desc.shape == (0, 64)


# ---------------------------------------------------------------------------- local_features


@pytest.mark.parametrize("name, dim, dtype", [("surf", 64, np.float32),
                                              ("surf-upright", 64, np.float32),
                                              ("sift", 128, np.float32), ("orb", 32, np.uint8)])
def test_one_interface_for_three_detectors(name, dim, dtype):
    img = textured_image(257, 7)
    kp, desc = lf.detect_and_describe(img, None, name)
    assert kp.ndim == 2 and kp.shape[1] == len(lf.KEYPOINT_COLUMNS) and len(kp) >= 10
    assert desc.shape == (len(kp), dim) and desc.dtype == dtype
    assert np.all(np.diff(kp[:, 4]) <= 0)  # strongest first
    assert np.all(np.abs(kp[:, 3]) <= np.pi + 1e-9) and np.all(kp[:, 2] > 0)
    assert set(np.unique(kp[:, 5])) <= ({-1.0, 1.0} if name.startswith("surf") else {0.0})
    assert lf.descriptor_metric(name) == ("hamming" if name == "orb" else "l2")


@pytest.mark.parametrize("name", ["surf", "sift", "orb"])
def test_orientations_share_one_convention(name):
    """All three report orientations in pixel axes (from +x towards +y): turning the image by
    -90 deg (np.rot90) turns the orientation of the same keypoints by -90 deg."""
    n = 257
    img = textured_image(n, 11)
    kp, _ = lf.detect_and_describe(img, None, name)
    kr, _ = lf.detect_and_describe(np.ascontiguousarray(np.rot90(img)), None, name)
    mapped = np.column_stack([kp[:, 1], n - 1 - kp[:, 0]])
    d = np.hypot(mapped[:, None, 0] - kr[None, :, 0], mapped[:, None, 1] - kr[None, :, 1])
    same = (d < 1.0) & (np.abs(np.log(kr[None, :, 2] / kp[:, None, 2])) < 0.1)
    # SIFT repeats a keypoint for each strong orientation: take the closest turn per keypoint
    turn = np.abs(np.angle(np.exp(1j * (kr[None, :, 3] - kp[:, None, 3] + np.pi / 2))))
    best = np.where(same, turn, np.inf).min(1)
    assert np.isfinite(best).sum() >= 10
    assert np.median(best[np.isfinite(best)]) < math.radians(5)


def test_opencv_detectors_respect_the_mask():
    img = textured_image(257, 3)
    mask = np.ones(img.shape, bool)
    mask[100:160, 100:160] = False
    for name in ("sift", "orb"):
        kp, desc = lf.detect_and_describe(img, mask, name)
        assert len(kp) > 5 and len(desc) == len(kp)
        inside = (kp[:, 0] > 97) & (kp[:, 0] < 163) & (kp[:, 1] > 97) & (kp[:, 1] < 163)
        assert not inside.any()


def test_feature_confs():
    assert lf.resolve_feature_conf(None)["features"] == "surf"
    c = lf.resolve_feature_conf({"features": "sift", "max_keypoints": 50})
    assert c["max_keypoints"] == 50 and c["contrast_threshold"] == 0.04
    assert lf.resolve_feature_conf("surf", {"threshold": 1e-3})["threshold"] == 1e-3
    with pytest.raises(FieldlocError, match="unknown features"):
        lf.resolve_feature_conf({"features": "akaze"})
    with pytest.raises(FieldlocError, match="unknown conf key"):
        lf.resolve_feature_conf({"features": "orb", "threshold": 1.0})
    with pytest.raises(FieldlocError, match="uint8"):
        lf.detect_and_describe(np.zeros((64, 64)), None, "sift")
    geometric = lf.resolve_feature_conf("surf-geometric")
    assert geometric["hessian"] == "gaussian" and geometric["geometric_layers"] == 3
    assert geometric["refine_moves"] == 5
    assert lf.resolve_feature_conf("surf")["geometric_layers"] == 0  # the default keeps Bay's


def test_a_template_database_takes_the_geometric_scales_by_conf():
    """`fieldloc build-templates DIR -c features.hessian=gaussian -c
    features.geometric_layers=3`: the overrides reach the template method's upright floor SURF,
    which then detects with them."""
    from stages import build_templates
    from stages.common import ground_features as gf
    from stages.common.conf import resolve_conf

    conf = resolve_conf(build_templates.confs, "default",
                        {"features": {"hessian": "gaussian", "geometric_layers": 3}})
    features = gf.check_conf(build_templates.ground_conf(conf))["features"]
    assert features["upright"] and features["threshold"] == 3e-5
    assert features["hessian"] == "gaussian" and features["geometric_layers"] == 3
    img = textured_image(257, 7)
    kp, _ = lf.detect_and_describe(img, None, features)
    plain, _ = lf.detect_and_describe(img, None, build_templates.confs["default"]["features"])
    # exact same-run: two confs, here
    assert len(kp) >= 10 and not np.array_equal(kp[:, :3], plain[:len(kp), :3])
