"""Initial Gaussians from a scene: coloured LiDAR points, a far shell, nearest-neighbour scales."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recondreamer.scene.cameras import pixel_indices, project_points, world_to_camera


@dataclass
class ScenePoints:
    """LiDAR points that the camera saw at their own frame, with the colour it saw."""

    points: np.ndarray  # (N,3) float64 world
    colors: np.ndarray  # (N,3) float32 in [0,1]
    frames: np.ndarray  # (N,) int, frame that captured the point

    def subset(self, index: np.ndarray) -> ScenePoints:
        return ScenePoints(self.points[index], self.colors[index], self.frames[index])

    def __len__(self) -> int:
        return len(self.points)


def normalized_times(
    timestamps: np.ndarray,
) -> np.ndarray:  # (T,) seconds -> (T,) in [0,1]
    span = max(float(timestamps[-1] - timestamps[0]), 1e-6)
    return (timestamps - timestamps[0]) / span


def camera_center_and_extent(cam_to_world: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre of the camera path and its radius x 1.1 (3DGS's scene extent), at least 1 m."""
    centers = cam_to_world[:, :3, 3]
    center = centers.mean(axis=0)
    radius = float(np.linalg.norm(centers - center, axis=1).max()) * 1.1
    return center, max(radius, 1.0)


def colored_lidar_points(scene, frames: list[int] | None = None) -> ScenePoints:
    """Every frame's LiDAR points that project into that frame's image, coloured from it."""
    frames = list(range(scene.num_frames)) if frames is None else frames
    points, colors, owners = [], [], []
    for t in frames:
        lidar = np.asarray(scene.lidar(t), dtype=np.float64)
        if len(lidar) == 0:
            continue
        uv, z = project_points(lidar, scene.K, world_to_camera(scene.cam_to_world[t]))
        front = z > 0.1
        u, v = pixel_indices(np.where(front[:, None], uv, -1.0))
        seen = front & (u >= 0) & (u < scene.width) & (v >= 0) & (v < scene.height)
        image = scene.image(t)
        points.append(lidar[seen])
        colors.append(image[v[seen], u[seen]].astype(np.float32) / 255.0)
        owners.append(np.full(int(seen.sum()), t, dtype=np.int64))
    if not points:
        return ScenePoints(
            np.zeros((0, 3)), np.zeros((0, 3), np.float32), np.zeros(0, np.int64)
        )
    return ScenePoints(
        np.concatenate(points), np.concatenate(colors), np.concatenate(owners)
    )


def subsample(
    points: ScenePoints, max_points: int, rng: np.random.Generator
) -> ScenePoints:
    if len(points) <= max_points:
        return points
    return points.subset(
        np.sort(rng.choice(len(points), size=max_points, replace=False))
    )


def far_shell_points(
    center: np.ndarray,
    radius: float,
    radius_range: tuple[float, float],
    num: int,
    rng: np.random.Generator,
) -> np.ndarray:  # (num,3)
    """Random points between ``radius_range`` x radius around ``center``, above the horizon band.

    They give far background (buildings, hills) something to converge to that LiDAR never hit;
    directions below -10 degrees are excluded because the road is covered by LiDAR.
    """
    dirs = rng.normal(size=(num * 3, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs = dirs[dirs[:, 2] > -np.sin(np.radians(10.0))][:num]
    radii = radius * rng.uniform(radius_range[0], radius_range[1], size=(len(dirs), 1))
    return center + dirs * radii


def lidar_radius(points: np.ndarray, center: np.ndarray) -> float:
    """95th percentile distance of the points from ``center`` (robust to stray far returns)."""
    if len(points) == 0:
        return 50.0
    return max(float(np.percentile(np.linalg.norm(points - center, axis=1), 95)), 1.0)


def knn_log_scales(points: np.ndarray, neighbours: int = 3) -> np.ndarray:  # (N,3)
    """log of the RMS distance to the nearest neighbours, isotropic (3DGS initialisation)."""
    if len(points) < 2:
        return np.full((len(points), 3), np.log(0.1), dtype=np.float32)
    # Imported here: scipy.spatial takes 0.2 s to import, and rendering or scoring a trained model
    # (a short job, 144 of them in the default run) never initialises Gaussians.
    from scipy.spatial import cKDTree

    k = min(neighbours + 1, len(points))
    dist, _ = cKDTree(points).query(points, k=k)
    rms = np.sqrt(np.mean(dist[:, 1:] ** 2, axis=1)).clip(1e-3, None)
    return np.repeat(np.log(rms)[:, None], 3, axis=1).astype(np.float32)


def points_in_box(
    points: np.ndarray, obj_to_world: np.ndarray, size: np.ndarray, margin: float = 0.1
) -> np.ndarray:
    """Mask (N,) of world points inside the box (enlarged by ``margin`` metres on each side)."""
    local = (points - obj_to_world[:3, 3]) @ obj_to_world[:3, :3]
    return np.all(np.abs(local) <= np.asarray(size) / 2 + margin, axis=1)
