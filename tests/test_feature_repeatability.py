"""The Mikolajczyk-Schmid protocol (stages.evaluate.feature_repeatability) on cases computed by
hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stages.common.errors import FieldlocError
from stages.evaluate import feature_repeatability as fr


def grid_overlap_error(d, ra, rb, n=2001):
    """1 - IoU of two circles by counting points of a fine grid (independent of the lens
    formula)."""
    lo, hi = -max(ra, rb) - 1, d + max(ra, rb) + 1
    x = np.linspace(lo, hi, n)
    xx, yy = np.meshgrid(x, x - (lo + hi) / 2 + d / 2)
    a = xx ** 2 + yy ** 2 <= ra ** 2
    b = (xx - d) ** 2 + yy ** 2 <= rb ** 2
    return 1 - (a & b).sum() / (a | b).sum()


def test_circle_overlap_error_by_hand():
    # concentric 30 and 20: IoU = 400 / 900
    assert fr.circle_overlap_error(0.0, 30.0, 20.0) == pytest.approx(1 - 4 / 9)
    # a circle of 10 inside one of 30 (offset 5): IoU = 100 / 900
    assert fr.circle_overlap_error(5.0, 30.0, 10.0) == pytest.approx(1 - 1 / 9)
    # apart, touching: no overlap
    assert fr.circle_overlap_error(50.0, 30.0, 20.0) == pytest.approx(1.0)
    # equal circles of radius R at distance R: the lens is R^2 (2 pi / 3 - sqrt(3) / 2)
    lens = 2 * math.pi / 3 - math.sqrt(3) / 2
    assert fr.circle_overlap_error(30.0, 30.0, 30.0) == pytest.approx(1 - lens / (2 * math.pi
                                                                                 - lens))
    for d, ra, rb in [(7.0, 30.0, 26.0), (12.0, 30.0, 35.0), (20.0, 15.0, 9.0)]:
        assert fr.circle_overlap_error(d, ra, rb) == pytest.approx(
            grid_overlap_error(d, ra, rb), abs=3e-3)
    # broadcasting and symmetry
    e = fr.circle_overlap_error([0.0, 7.0], 30.0, [20.0, 26.0])
    assert e.shape == (2,) and e[1] == pytest.approx(fr.circle_overlap_error(7.0, 26.0, 30.0))


def test_regions_are_normalised_to_30_px_with_the_centres_kept():
    """Two circles of radius 2 px, 3 px apart: as drawn 1 - IoU = 0.92; scaled to 30 px about
    their own centres, which stay 3 px apart, 0.12: a correspondence."""
    ca, cb = np.array([[10.0, 10.0]]), np.array([[13.0, 10.0]])
    i, j, e = fr.candidate_correspondences(ca, np.array([2.0]), cb, np.array([2.0]),
                                           normalised_radius=None)
    assert len(i) == 0
    assert fr.circle_overlap_error(3.0, 2.0, 2.0) == pytest.approx(0.92, abs=0.005)
    i, j, e = fr.candidate_correspondences(ca, np.array([2.0]), cb, np.array([2.0]))
    assert (i.tolist(), j.tolist()) == ([0], [0])
    assert e[0] == pytest.approx(fr.circle_overlap_error(3.0, 30.0, 30.0))
    assert e[0] == pytest.approx(0.12, abs=0.005)
    assert e[0] == pytest.approx(grid_overlap_error(3.0, 30.0, 30.0), abs=3e-3)
    # scale 1.4 apart fails whatever the position: 1 - 1 / 1.96 = 0.49 > 0.4
    i, j, e = fr.candidate_correspondences(ca, np.array([2.0]), ca, np.array([2.8]))
    assert len(i) == 0


def test_similarity_homography_and_circle_projection():
    H = fr.similarity_homography(math.radians(90), 2.0, centre=(50.0, 50.0))
    # +x turns towards +y (pixel axes) and doubles
    np.testing.assert_allclose(fr.project_points(H, [[50, 50], [51, 50]]), [[50, 50], [50, 52]],
                               atol=1e-12)
    c, r = fr.project_circles(H, np.array([[60.0, 50.0]]), np.array([3.0]))
    np.testing.assert_allclose(c, [[50.0, 70.0]], atol=1e-12)
    assert r[0] == pytest.approx(6.0)
    Ht = fr.similarity_homography(0.0, 1.0, (0, 0), centre_b=(5, -2))
    np.testing.assert_allclose(fr.project_points(Ht, [[1, 1]]), [[6, -1]])


def test_greedy_one_to_one_takes_the_cheapest_first():
    pairs = fr.greedy_one_to_one(np.array([0, 0, 1, 1, 2]), np.array([0, 1, 0, 1, 1]),
                                 np.array([0.1, 0.2, 0.05, 0.3, 0.15]), 3, 2)
    # (1, 0) 0.05 first, then (0, 0) is blocked, (2, 1) 0.15 next
    assert pairs.tolist() == [[1, 0], [2, 1]]


def hand_case(rng_seed: int = 0):
    """Four keypoints in A (101 x 101), B = A turned by 90 deg about the centre:
    b0, b1 = the images of a0, a1; b2 = the image of a2 at twice its scale (overlap error
    0.75); b3 far from everything. Descriptors: a0 ~ b0, a1 nearest to b3 (a wrong match),
    a2 ~ b2, a3 unlike all."""
    H = fr.similarity_homography(math.radians(90), 1.0, (50.0, 50.0))
    a = np.array([[30.0, 40.0, 2.0, 0, 1, 1], [60.0, 35.0, 3.0, 0, 1, 1],
                  [45.0, 62.0, 2.5, 0, 1, -1], [70.0, 70.0, 2.0, 0, 1, 1]])
    p = fr.project_points(H, a[:, :2])
    b = np.array([[*p[0], 2.0, 0, 1, 1], [*p[1], 3.0, 0, 1, 1], [*p[2], 5.0, 0, 1, -1],
                  [15.0, 90.0, 2.0, 0, 1, 1]])
    e = np.eye(4)
    da = np.array([e[0], e[1], e[2], -e[0] - e[1] - e[2]])
    db = np.array([e[0] + 0.1 * e[3], e[1] + 0.5 * e[3], e[2], e[1] + 0.1 * e[3]])
    return a, da, b, db, H


def test_repeatability_and_matching_score_by_hand():
    a, da, b, db, H = hand_case()
    s = fr.evaluate_pair(fr.ImageFeatures(a, da, (101, 101)), fr.ImageFeatures(b, db, (101, 101)),
                         H)
    assert (s.n_a, s.n_b) == (4, 4)
    assert s.correspondences == 2 and s.repeatability == pytest.approx(2 / 4)
    # descriptor matches: (a2, b2) 0, (a0, b0) 0.1, (a1, b3) 0.1 (before (a1, b1) 0.5), so only
    # (a0, b0) is both a descriptor match and a geometric correspondence
    assert s.correct_matches == 1 and s.matching_score == pytest.approx(1 / 4)
    # with opposite Laplacian signs a0 and b0 may not match
    b2 = b.copy()
    b2[0, 5] = -1
    image_a, image_b2 = fr.ImageFeatures(a, da, (101, 101)), fr.ImageFeatures(b2, db, (101, 101))
    s2 = fr.evaluate_pair(image_a, image_b2, H)
    assert s2.correct_matches == 0 and s2.repeatability == pytest.approx(2 / 4)
    s3 = fr.evaluate_pair(image_a, image_b2, H, use_laplacian=False)
    assert s3.correct_matches == 1


def test_only_regions_in_the_common_part_count():
    a, da, b, db, H = hand_case()
    valid_b = np.ones((101, 101), bool)
    # invalidate where a1 (60, 35) lands in B: H maps it to (65, 60)
    valid_b[55:66, 58:72] = False
    s = fr.evaluate_pair(fr.ImageFeatures(a, da, (101, 101)),
                         fr.ImageFeatures(b, db, (101, 101), valid_b), H)
    # a1 (and b1, on the invalid pixels themselves) leave: 1 correspondence of 3 and 3
    assert (s.n_a, s.n_b) == (3, 3)
    assert s.correspondences == 1 and s.repeatability == pytest.approx(1 / 3)
    # a region reaching over the image border is out too
    near_border = np.array([[3.0, 50.0, 2.0, 0, 1, 1]])
    assert not fr.common_part(near_border, np.eye(3), (101, 101), None, (101, 101), None)[0]
    assert fr.common_part(near_border + [[4.0, 0, 0, 0, 0, 0]], np.eye(3), (101, 101), None,
                          (101, 101), None)[0]


def test_hamming_distances_and_bad_input():
    a = np.array([[0b10110000, 0], [255, 255]], np.uint8)
    b = np.array([[0b10000000, 0], [0, 0]], np.uint8)
    # exact integers: bit counts
    np.testing.assert_array_equal(fr.descriptor_distances(a, b, "hamming"), [[2, 3], [15, 16]])
    with pytest.raises(FieldlocError, match="metric"):
        fr.descriptor_distances(a, b, "cosine")
    with pytest.raises(FieldlocError, match="homography"):
        one = fr.ImageFeatures(np.zeros((1, 3)), np.zeros((1, 2)), (10, 10))
        fr.evaluate_pair(one, one, np.zeros((3, 3)))
    none = fr.ImageFeatures(np.zeros((0, 6)), np.zeros((0, 64)), (10, 10))
    s = fr.evaluate_pair(none, none, np.eye(3))
    assert s.repeatability == 0.0 and s.n_a == 0


def test_warp_pair_moves_image_and_mask():
    img = np.zeros((60, 60), np.uint8)
    img[10:20, 30:40] = 200
    H = fr.similarity_homography(0.0, 1.0, (0, 0), centre_b=(5, 3))  # a shift by (5, 3)
    warped, valid = fr.warp_pair(img, None, H)
    assert warped[13:23, 35:45].min() == 200 and warped[10:13, 30:35].max() == 0
    assert not valid[:4, :].any() and not valid[:, :6].any() and valid[10:50, 10:50].all()
