"""Metric building blocks against closed forms and hand-made cases."""

import numpy as np
import pytest
import scipy.linalg
from op_tester import BaseTester

from recondreamer.evaluation import frechet, image_metrics, lanes, nta_iou
from recondreamer.scene.types import Polyline

# ---------------------------------------------------------------- Frechet distance / FID


def test_frechet_matches_closed_form_for_1d_and_diagonal_gaussians():
    # 1-D: (m1 - m2)^2 + (s1 - s2)^2.
    value = frechet.frechet_distance(np.array([1.0]), np.array([[4.0]]), np.array([-2.0]), np.array([[9.0]]))
    assert value == pytest.approx(9.0 + (2.0 - 3.0) ** 2)
    # Commuting (diagonal) covariances: sum of (sqrt(a) - sqrt(b))^2.
    a, b = np.array([1.0, 4.0, 0.25]), np.array([9.0, 1.0, 0.25])
    value = frechet.frechet_distance(np.zeros(3), np.diag(a), np.ones(3), np.diag(b))
    assert value == pytest.approx(3.0 + np.sum((np.sqrt(a) - np.sqrt(b)) ** 2))


def test_frechet_matches_scipy_sqrtm_route_on_random_covariances():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(6, 6)), rng.normal(size=(6, 6))
    cov1, cov2 = a @ a.T, b @ b.T + np.eye(6)
    m1, m2 = rng.normal(size=6), rng.normal(size=6)
    root = scipy.linalg.sqrtm(cov1 @ cov2).real
    expected = np.sum((m1 - m2) ** 2) + np.trace(cov1) + np.trace(cov2) - 2 * np.trace(root)
    assert frechet.frechet_distance(m1, cov1, m2, cov2) == pytest.approx(expected, rel=1e-8)


@pytest.mark.parametrize("sizes", [(24, 24, 96), (24, 72, 96), (72, 24, 96), (150, 200, 16)])
def test_frechet_from_samples_matches_the_covariance_route(sizes):
    """The low-rank fast path (no D x D matrix) against its reference twin, fewer and more samples than dimensions."""
    n1, n2, dim = sizes
    rng = np.random.default_rng(n1 + n2)
    x = rng.normal(size=(n1, dim)) @ rng.normal(size=(dim, dim)) * 0.1
    y = rng.normal(size=(n2, dim)) * 1.3 + 0.2
    s1, s2 = frechet.gaussian_stats(x), frechet.gaussian_stats(y)
    reference = frechet.frechet_distance(s1.mean, s1.cov, s2.mean, s2.cov)
    assert frechet.frechet_distance_from_samples(x, y) == pytest.approx(reference, rel=1e-6)
    assert frechet.fid_from_features(x, y)["fid"] == pytest.approx(reference, rel=1e-6)
    assert frechet.frechet_distance_from_samples(x, x) == pytest.approx(0.0, abs=1e-9 * reference)


def test_fid_of_identical_sets_is_zero_and_grows_with_noise():
    rng = np.random.default_rng(1)
    features = rng.normal(size=(200, 8))
    assert frechet.fid_from_features(features, features)["fid"] == pytest.approx(0.0, abs=1e-8)
    values = [frechet.fid_from_features(features, features + rng.normal(scale=s, size=features.shape))["fid"] for s in (0.1, 0.5, 2.0)]
    assert values[0] < values[1] < values[2]


def test_fid_reports_rank_deficiency_and_rejects_too_few_samples():
    rng = np.random.default_rng(2)
    result = frechet.fid_from_features(rng.normal(size=(5, 16)), rng.normal(size=(5, 16)))
    assert result["covariance_full_rank"] is False and result["num_samples"] == [5, 5]
    assert np.isfinite(result["fid"]) and result["fid"] > 0
    with pytest.raises(ValueError, match="at least 2 samples"):
        frechet.fid_from_features(rng.normal(size=(1, 4)), rng.normal(size=(5, 4)))
    with pytest.raises(ValueError, match="dimensions differ"):
        frechet.fid_from_features(rng.normal(size=(5, 4)), rng.normal(size=(5, 3)))


class TestKID:
    def test_equal_distributions_give_zero(self):
        rng = np.random.default_rng(3)
        result = frechet.kid_from_features(rng.normal(size=(2000, 4)), rng.normal(size=(2000, 4)), subset_size=500, num_subsets=20)
        assert abs(result["kid"]) < 3 * result["kid_std"] / np.sqrt(result["num_subsets"]) + 1e-3
        assert result["kid_std"] > 0 and result["subset_size"] == 500

    def test_shifted_gaussians_match_the_closed_form(self):
        # 1-D, kernel (xy + 1)^3 = x^3 y^3 + 3 x^2 y^2 + 3 x y + 1, so the population MMD^2 is
        # (E x^3 - E y^3)^2 + 3 (E x^2 - E y^2)^2 + 3 (E x - E y)^2; for N(0,1) vs N(1,1):
        # moments (0, 1, 0) and (1, 2, 4): 16 + 3 + 3 = 22.
        rng = np.random.default_rng(4)
        result = frechet.kid_from_features(rng.normal(size=(20000, 1)), rng.normal(loc=1.0, size=(20000, 1)), subset_size=1000, num_subsets=20)
        assert result["kid"] == pytest.approx(22.0, rel=0.1)

    def test_unbiased_estimator_matches_a_loop_reference(self):
        rng = np.random.default_rng(5)
        x, y = rng.normal(size=(7, 3)), rng.normal(size=(7, 3))
        k = lambda a, b: (a @ b / 3 + 1) ** 3  # noqa: E731
        m = len(x)
        within = sum(k(x[i], x[j]) + k(y[i], y[j]) for i in range(m) for j in range(m) if i != j) / (m * (m - 1))
        across = sum(k(x[i], y[j]) for i in range(m) for j in range(m)) / m**2
        assert frechet.mmd2_unbiased(x, y) == pytest.approx(within - 2 * across)

    def test_exceptions(self):
        rng = np.random.default_rng(6)
        with pytest.raises(ValueError, match="at least 2 samples"):
            frechet.kid_from_features(rng.normal(size=(1, 3)), rng.normal(size=(5, 3)))
        with pytest.raises(ValueError, match="same D"):
            frechet.kid_from_features(rng.normal(size=(5, 3)), rng.normal(size=(5, 2)))
        with pytest.raises(ValueError, match="subset size"):
            frechet.kid_from_features(rng.normal(size=(5, 3)), rng.normal(size=(5, 3)), subset_size=6)


class TestPooledFID:
    def test_full_dimension_equals_the_plain_fid(self):
        rng = np.random.default_rng(7)
        a, b = rng.normal(size=(300, 5)), rng.normal(loc=0.5, size=(300, 5))
        assert frechet.pooled_fid_from_features(a, b, dim=5)["fid"] == pytest.approx(frechet.fid_from_features(a, b)["fid"], rel=1e-9)

    def test_shifted_gaussians_give_the_squared_shift(self):
        rng = np.random.default_rng(8)
        shift = np.array([1.0, -0.5, 0.0, 0.25])
        result = frechet.pooled_fid_from_features(rng.normal(size=(20000, 4)) + shift, rng.normal(size=(20000, 4)))
        assert result["fid_dim"] == 4 and result["fid"] == pytest.approx(float(shift @ shift), abs=0.02)

    def test_dimension_follows_the_sample_count(self):
        assert frechet.fid_dimension(192, 128) == 48
        assert frechet.fid_dimension(24, 128) == 6
        assert frechet.fid_dimension(10000, 128) == 128
        assert frechet.fid_dimension(2, 128) == 1

    def test_pooling_segments_removes_the_small_sample_bias(self):
        # 8 segments of 24 frames, both sets from one distribution: the true FID is 0. Averaging
        # per-segment FIDs (24 samples in 16 dimensions) is biased far above it; pooling is not.
        rng = np.random.default_rng(9)
        segments = [(rng.normal(size=(24, 16)), rng.normal(size=(24, 16))) for _ in range(8)]
        per_segment = np.mean([frechet.fid_from_features(a, b)["fid"] for a, b in segments])
        pooled = frechet.pooled_fid_from_features(np.concatenate([a for a, _ in segments]), np.concatenate([b for _, b in segments]))
        assert pooled["num_samples"] == [192, 192] and pooled["fid_dim"] == 16
        assert pooled["fid"] < 0.25 * per_segment

    def test_a_precomputed_basis_gives_the_same_value(self):
        # The findings' bootstrap passes the reference's basis, computed once, to every run.
        rng = np.random.default_rng(11)
        a, b = rng.normal(size=(96, 32)), rng.normal(loc=0.3, size=(96, 32))
        dim = frechet.fid_dimension(96, 32)
        expected = frechet.pooled_fid_from_features(a, b)["fid"]
        assert frechet.pooled_fid_from_features(a, b, dim, basis=frechet.reference_basis(b, dim))["fid"] == expected

    def test_exceptions(self):
        rng = np.random.default_rng(10)
        with pytest.raises(ValueError, match="dimension must lie"):
            frechet.pooled_fid_from_features(rng.normal(size=(20, 4)), rng.normal(size=(20, 4)), dim=5)
        with pytest.raises(ValueError, match="same D"):
            frechet.pooled_fid_from_features(rng.normal(size=(20, 4)), rng.normal(size=(20, 3)))
        reference = rng.normal(size=(20, 4))
        with pytest.raises(ValueError, match="basis must be"):
            frechet.pooled_fid_from_features(rng.normal(size=(20, 4)), reference, dim=3, basis=frechet.reference_basis(reference, 2))


# ---------------------------------------------------------------- NTA-IoU matching rules


def test_match_threshold_scales_with_image_size():
    assert nta_iou.match_distance_threshold(480, 320) == pytest.approx(10.0)
    assert nta_iou.match_distance_threshold(240, 160) == pytest.approx(5.0)
    assert nta_iou.match_distance_threshold(1920, 1280) == pytest.approx(40.0)


def test_matching_accepts_near_centres_and_scores_iou():
    gt = np.array([[0, 0, 10, 10]], float)
    near = np.array([[1, 1, 11, 11]], float)  # centre 1.41 px away, IoU 81/119
    assert nta_iou.match_gt_to_detections(gt, near, 5.0)[0] == pytest.approx(81 / 119)
    far = np.array([[6, 0, 16, 10]], float)  # centre 6 px away: beyond the 5 px threshold
    assert nta_iou.match_gt_to_detections(gt, far, 5.0)[0] == 0.0
    assert nta_iou.match_gt_to_detections(gt, np.zeros((0, 4)), 5.0)[0] == 0.0


def test_matching_uses_nearest_centre_not_best_iou_and_reuses_detections():
    gt = np.array([[0, 0, 20, 20]], float)  # centre (10, 10)
    small_same_centre = [9, 9, 11, 11]  # distance 0, IoU 4/400
    big_offset = [0, 0, 22, 22]  # distance 1.41, IoU 400/484
    scores = nta_iou.match_gt_to_detections(gt, np.array([big_offset, small_same_centre], float), 5.0)
    assert scores[0] == pytest.approx(4 / 400)
    two_gt = np.array([[0, 0, 10, 10], [1, 0, 11, 10]], float)
    one_det = np.array([[0, 0, 10, 10]], float)
    assert nta_iou.match_gt_to_detections(two_gt, one_det, 5.0) == pytest.approx([1.0, 9 / 11])


def test_nta_iou_pools_over_all_boxes_of_all_frames():
    gt = [np.array([[0, 0, 10, 10], [20, 20, 30, 30]], float), np.array([[0, 0, 10, 10]], float), np.zeros((0, 4))]
    det = [np.array([[0, 0, 10, 10]], float), np.array([[0, 0, 10, 10]], float), np.array([[0, 0, 5, 5]], float)]
    result = nta_iou.nta_iou(gt, det, 240, 160)
    assert result["nta_iou"] == pytest.approx(2 / 3)  # (1 + 0 + 1) / 3 boxes, not a per-frame mean
    assert result["num_gt_boxes"] == 3
    assert nta_iou.nta_iou([np.zeros((0, 4))], [np.zeros((0, 4))], 240, 160)["nta_iou"] is None


# ---------------------------------------------------------------- lane masks and NTL-IoU

# Camera 1.5 m above the ground at the world origin looking along world +x (OpenCV axes).
CAM_TO_WORLD = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 1.5], [0, 0, 0, 1]], float)
K = np.array([[120.0, 0, 120], [0, 120.0, 80], [0, 0, 1]])


def _pixel(x, y, z=0.0):
    cam = np.array([-y, 1.5 - z, x])
    u, v = (K @ cam)[:2] / cam[2]
    return int(round(v)), int(round(u))


def test_lane_thickness_scales_with_height():
    assert lanes.lane_thickness(1280) == 20
    assert lanes.lane_thickness(320) == 5
    assert lanes.lane_thickness(160) == 3  # 2.5 rounds half up


def test_lane_mask_draws_kept_lines_and_respects_limits():
    line = Polyline("road_line", np.array([[2.0, -2.0, 0.0], [150.0, -2.0, 0.0]]))
    far_side = Polyline("road_line", np.array([[2.0, 12.0, 0.0], [150.0, 12.0, 0.0]]))  # |lateral| > 10 m
    centre = Polyline("lane_center", np.array([[2.0, 0.0, 0.0], [150.0, 0.0, 0.0]]))  # not a lane class
    mask = lanes.lane_mask([line, far_side, centre], K, CAM_TO_WORLD, 240, 160, thickness=1)
    assert mask[_pixel(10.0, -2.0)] and mask[_pixel(40.0, -2.0)]
    assert not mask[_pixel(10.0, 0.0)]  # the lane centre line is not drawn
    assert not mask[_pixel(20.0, 12.0)]  # beyond 10 m lateral
    # Nothing beyond 75 m: the line stops at the 75 m row.
    row_75 = _pixel(75.0, -2.0)[0]
    assert not mask[: row_75 - 1].any()


def test_crosswalk_contributes_only_its_long_sides():
    # 8 m long (along y) by 3 m deep (along x) crosswalk 15 m ahead.
    ring = np.array([[15, -4, 0], [15, 4, 0], [18, 4, 0], [18, -4, 0]], float)
    mask = lanes.lane_mask([Polyline("crosswalk", ring)], K, CAM_TO_WORLD, 240, 160, thickness=1)
    assert mask[_pixel(15.0, 0.0)] and mask[_pixel(18.0, 0.0)]
    assert not mask[_pixel(16.5, 4.0)]  # the short side is left out


def test_ntl_iou_two_class_mean_and_lane_only():
    truth = np.zeros((10, 10), bool)
    truth[:, 4:6] = True
    perfect = lanes.ntl_iou([truth], [truth])
    assert perfect["ntl_iou"] == 1.0 and perfect["lane_iou"] == 1.0
    shifted = np.zeros_like(truth)
    shifted[:, 5:7] = True  # overlaps one of two columns: lane IoU 10/30, background IoU 70/90
    result = lanes.ntl_iou([shifted], [truth])
    assert result["lane_iou"] == pytest.approx(1 / 3)
    assert result["ntl_iou"] == pytest.approx((1 / 3 + 7 / 9) / 2)
    empty = np.zeros_like(truth)
    assert lanes.ntl_iou([empty], [truth])["ntl_iou"] == pytest.approx((0 + 80 / 100) / 2)


# ---------------------------------------------------------------- PSNR / SSIM


def image_pair():
    """(truth uint8, render float in [0,1] with error only in the top half, bottom-half mask)."""
    rng = np.random.default_rng(3)
    truth = rng.integers(0, 256, size=(32, 48, 3), dtype=np.uint8)
    render = truth.astype(float) / 255.0
    render[:16] = np.clip(render[:16] + 0.1, 0, 1)  # error only in the top half
    mask_bottom = np.zeros((32, 48), bool)
    mask_bottom[16:] = True
    return truth, render, mask_bottom


class TestPSNR(BaseTester):
    """``image_metrics.psnr``: over the whole image or inside a mask."""

    def test_smoke_identical_images_give_infinity(self):
        truth, _, _ = image_pair()
        assert image_metrics.psnr(truth, truth) == float("inf")

    def test_correctness_inside_masks(self):
        truth, render, mask_bottom = image_pair()
        assert image_metrics.psnr(render, truth / 255.0, mask_bottom) == float("inf")
        mse_top = np.mean((render[:16] - truth[:16] / 255.0) ** 2)
        self.assert_close(image_metrics.psnr(render, truth / 255.0, ~mask_bottom), -10 * np.log10(mse_top))

    def test_cardinality_empty_mask_gives_none(self):
        truth, render, _ = image_pair()
        assert image_metrics.psnr(render, truth / 255.0, np.zeros((32, 48), bool)) is None

    def test_exception(self):
        truth, _, _ = image_pair()
        with pytest.raises(ValueError, match="differ in size"):
            image_metrics.psnr(truth[:10], truth)


class TestSSIM(BaseTester):
    """``image_metrics.ssim``: kornia's SSIM averaged over the image."""

    def test_correctness_identical_images_give_one(self):
        truth, _, _ = image_pair()
        self.assert_close(image_metrics.ssim(truth, truth), 1.0)

    def test_correctness_an_error_lowers_it(self):
        truth, render, _ = image_pair()
        assert image_metrics.ssim(render, truth / 255.0) < 1.0
