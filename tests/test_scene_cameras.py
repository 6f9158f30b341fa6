"""Camera projection: known points, behind-camera points, Brown-Conrady distortion."""

from __future__ import annotations

import math

import numpy as np
import pytest

from recondreamer.scene.cameras import distort_normalized, project_points, world_to_camera
from scene_fixtures import CAM_TO_EGO, yaw_pose

K = np.array([[100.0, 0.0, 50.0], [0.0, 120.0, 40.0], [0.0, 0.0, 1.0]])


def test_world_to_camera_inverts_a_rigid_pose():
    pose = yaw_pose(3.0, -2.0, 1.0, 0.7) @ CAM_TO_EGO
    np.testing.assert_allclose(world_to_camera(pose) @ pose, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(world_to_camera(pose), np.linalg.inv(pose), atol=1e-12)
    with pytest.raises(ValueError):
        world_to_camera(np.eye(3))


def test_known_points_identity_camera():
    points = np.array([[1.0, 2.0, 10.0], [0.0, 0.0, 5.0], [-3.0, 1.5, 3.0]])
    uv, z = project_points(points, K, np.eye(4))
    np.testing.assert_allclose(uv, [[60.0, 64.0], [50.0, 40.0], [-50.0, 100.0]])
    np.testing.assert_allclose(z, [10.0, 5.0, 3.0])


def test_known_points_driving_camera():
    """Camera 1 m ahead of and 1.5 m above the ego origin, looking along ego x (world = ego here)."""
    world_to_cam = world_to_camera(CAM_TO_EGO)
    ahead, left, up = [11.0, 0.0, 1.5], [11.0, 2.0, 1.5], [11.0, 0.0, 2.5]
    uv, z = project_points(np.array([ahead, left, up]), K, world_to_cam)
    np.testing.assert_allclose(z, [10.0, 10.0, 10.0])
    np.testing.assert_allclose(uv[0], [50.0, 40.0])
    np.testing.assert_allclose(uv[1], [50.0 - 100.0 * 0.2, 40.0])  # left of the car = left in the image
    np.testing.assert_allclose(uv[2], [50.0, 40.0 - 120.0 * 0.1])  # up = towards the top row


def test_points_behind_the_camera_have_no_pixel():
    uv, z = project_points(np.array([[1.0, 1.0, -4.0], [0.0, 0.0, 0.0], [1.0, 1.0, 4.0]]), K, np.eye(4))
    assert np.isnan(uv[:2]).all() and np.isfinite(uv[2]).all()
    np.testing.assert_array_equal(z, [-4.0, 0.0, 4.0])


def opencv_formula(x: float, y: float, k1: float, k2: float, p1: float, p2: float, k3: float) -> tuple[float, float]:
    """The distortion model exactly as OpenCV's camera-calibration documentation writes it."""
    r2 = x**2 + y**2
    r4, r6 = r2**2, r2**3
    radial = 1 + k1 * r2 + k2 * r4 + k3 * r6
    x_distorted = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x**2)
    y_distorted = y * radial + p1 * (r2 + 2 * y**2) + 2 * p2 * x * y
    return x_distorted, y_distorted


def test_distortion_matches_the_opencv_formula():
    rng = np.random.default_rng(3)
    coefficients = np.array([-0.32, 0.12, 0.0011, -0.0007, -0.02])
    cam_points = np.column_stack([rng.uniform(-4, 4, 50), rng.uniform(-3, 3, 50), rng.uniform(2, 30, 50)])
    uv, _ = project_points(cam_points, K, np.eye(4), distortion=coefficients)
    for (x, y, depth), (u, v) in zip(cam_points, uv, strict=True):
        xd, yd = opencv_formula(x / depth, y / depth, *coefficients)
        assert u == pytest.approx(100.0 * xd + 50.0, rel=1e-12, abs=1e-9)
        assert v == pytest.approx(120.0 * yd + 40.0, rel=1e-12, abs=1e-9)


def test_pure_radial_distortion_scales_the_radius():
    """With k1 alone a point at normalized radius r moves to radius r (1 + k1 r^2), same direction."""
    angle, r, k1 = 0.6, 0.5, -0.2
    xy = np.array([[r * math.cos(angle), r * math.sin(angle)]])
    distorted = distort_normalized(xy, np.array([k1, 0, 0, 0, 0]))
    np.testing.assert_allclose(np.hypot(*distorted[0]), r * (1 + k1 * r * r))
    np.testing.assert_allclose(math.atan2(distorted[0, 1], distorted[0, 0]), angle)


def test_zero_distortion_is_pinhole():
    points = np.array([[1.0, -2.0, 7.0]])
    np.testing.assert_array_equal(
        project_points(points, K, np.eye(4), np.zeros(5))[0], project_points(points, K, np.eye(4))[0]
    )


def test_rasterizer_intrinsics_put_a_splat_on_the_scene_pixel():
    """A tiny Gaussian lands on the pixel that the scene's projection convention names."""
    import torch

    from recondreamer.scene.cameras import pixel_indices, rasterizer_intrinsics
    from recondreamer.splat import rasterize

    K = np.array([[40.0, 0.0, 15.5], [0.0, 40.0, 11.5], [0.0, 0.0, 1.0]])
    for point in ([0.3, -0.2, 5.0], [-0.61, 0.37, 4.0]):
        uv, _ = project_points(np.array([point]), K, np.eye(4))
        column, row = pixel_indices(uv)
        out = rasterize(
            torch.tensor([point], dtype=torch.float64),
            torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=torch.float64),
            torch.full((1, 3), 0.004, dtype=torch.float64),
            torch.tensor([0.9], dtype=torch.float64),
            torch.ones(1, 3, dtype=torch.float64),
            torch.eye(4, dtype=torch.float64),
            torch.as_tensor(rasterizer_intrinsics(K)),
            32,
            24,
            backend="torch",
        )
        peak = int(out["alpha"].argmax())
        assert (peak // 32, peak % 32) == (int(row[0]), int(column[0]))


def test_pixel_indices_round_to_the_nearest_centre_and_reject_nan():
    from recondreamer.scene.cameras import pixel_indices

    columns, rows = pixel_indices(np.array([[0.49, -0.49], [0.51, 2.5], [np.nan, np.nan]]))
    assert columns.tolist() == [0, 1, -1] and rows.tolist() == [0, 3, -1]
