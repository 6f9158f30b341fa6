"""Camera geometry: rigid inverses and point projection (pinhole plus Brown-Conrady distortion).

Cameras use OpenCV axes (x right, y down, z forward). Poses are (4,4) camera-to-world matrices;
projection takes the inverse, world-to-camera, so that one inverse serves many projections.
"""

from __future__ import annotations

import numpy as np


def world_to_camera(cam_to_world: np.ndarray) -> np.ndarray:  # (4,4) -> (4,4)
    """Inverse of a rigid camera-to-world pose (rotation transposed, not a general inverse)."""
    cam_to_world = np.asarray(cam_to_world, dtype=np.float64)
    if cam_to_world.shape != (4, 4):
        raise ValueError(f"cam_to_world must be (4,4), got {cam_to_world.shape}")
    rotation_t = cam_to_world[:3, :3].T
    inverse = np.eye(4)
    inverse[:3, :3] = rotation_t
    inverse[:3, 3] = -rotation_t @ cam_to_world[:3, 3]
    return inverse


def transform_points(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:  # (4,4), (N,3) -> (N,3)
    """Apply a (4,4) rigid transform to (N,3) points."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return points @ matrix[:3, :3].T + matrix[:3, 3]


def distort_normalized(xy: np.ndarray, distortion: np.ndarray) -> np.ndarray:  # (N,2) -> (N,2)
    """Brown-Conrady distortion of normalized image coordinates (x/z, y/z).

    ``distortion`` = (k1, k2, p1, p2, k3) in OpenCV's order and meaning (radial k1 k2 k3,
    tangential p1 p2), which is also the order of Waymo's camera intrinsics after fu fv cu cv.
    """
    k1, k2, p1, p2, k3 = (float(c) for c in np.asarray(distortion, dtype=np.float64).reshape(5))
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=1)


def project_points(
    points_world: np.ndarray,  # (N,3)
    K: np.ndarray,  # (3,3)
    world_to_cam: np.ndarray,  # (4,4)
    distortion: np.ndarray | None = None,  # (5,) k1 k2 p1 p2 k3
) -> tuple[np.ndarray, np.ndarray]:  # uv (N,2) pixels, z (N,) metres along the optical axis
    """Project world points into pixels, OpenCV convention: u = fx * x/z + s * y/z + cx (after distortion).

    Points with ``z <= 0`` (on or behind the camera plane) have no image position: their ``uv``
    is NaN. Filter with ``z`` (e.g. ``z > near``) before using ``uv``.
    """
    K = np.asarray(K, dtype=np.float64)
    cam = transform_points(np.asarray(world_to_cam, dtype=np.float64), points_world)
    z = cam[:, 2]
    in_front = z > 0
    safe_z = np.where(in_front, z, 1.0)
    normalized = cam[:, :2] / safe_z[:, None]  # (N,2)
    if distortion is not None and np.any(np.asarray(distortion) != 0):
        normalized = distort_normalized(normalized, distortion)
    homogeneous = np.concatenate([normalized, np.ones((len(z), 1))], axis=1)  # (N,3)
    uv = homogeneous @ K[:2, :].T  # (N,2)
    uv[~in_front] = np.nan
    return uv, z


def pixel_indices(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # (N,2) -> (N,), (N,) int64
    """Column and row of the pixel containing each projected point (pixel centres at integers).

    NaN coordinates (points behind the camera) map to -1, outside every image.
    """
    index = np.floor(np.nan_to_num(uv, nan=-1.0) + 0.5).astype(np.int64)
    return index[:, 0], index[:, 1]


def rasterizer_intrinsics(K):  # (3,3) -> (3,3), numpy array or torch tensor
    """Intrinsics for code that puts pixel centres at integer + 0.5 (``recondreamer.splat``, gsplat).

    Scene intrinsics follow OpenCV (top-left pixel centre at (0, 0)); moving the principal point
    by half a pixel makes both conventions sample the same rays.
    """
    shifted = K.clone() if hasattr(K, "clone") else np.array(K, dtype=np.float64)
    shifted[0, 2] += 0.5
    shifted[1, 2] += 0.5
    return shifted
