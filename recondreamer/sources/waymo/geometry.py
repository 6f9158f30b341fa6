"""Waymo geometry: transforms, camera axes, box poses and range-image-to-point conversion.

Conventions (Waymo Open Dataset v1):

- vehicle frame: x forward, y left, z up; ``Frame.pose`` is vehicle-to-global;
- Waymo camera frame: x forward (optical axis), y left, z up; the calibration extrinsic is
  camera-to-vehicle. A point (x, y, z) in it lands at the normalised image coordinates
  (-y/x, -z/x) before lens distortion;
- range image rows run from the highest beam (row 0) to the lowest; columns run from
  azimuth +pi (column 0, behind the car) down to -pi, measured about the vehicle's z axis
  (the laser's own yaw on the car is taken out).
"""

from __future__ import annotations

import zlib

import numpy as np

from recondreamer.sources.waymo import schema

# Rotation of OpenCV camera axes (x right, y down, z forward) into Waymo camera axes
# (x forward, y left, z up): its columns are the OpenCV axes written in Waymo axes.
WAYMO_FROM_OPENCV = np.array(
    [
        [0.0, 0.0, 1.0],  # Waymo x (forward) = OpenCV z
        [-1.0, 0.0, 0.0],  # Waymo y (left) = -OpenCV x
        [0.0, -1.0, 0.0],  # Waymo z (up) = -OpenCV y
    ]
)


def transform_matrix(transform) -> np.ndarray:  # (4,4)
    """A Waymo ``Transform`` message (16 row-major doubles) as a 4x4 array."""
    values = np.asarray(transform.transform, dtype=np.float64)
    if values.shape != (16,):
        raise ValueError(f"a Waymo transform has 16 values, got {values.size}")
    return values.reshape(4, 4)


def camera_to_ego_opencv(extrinsic: np.ndarray) -> np.ndarray:  # (4,4)
    """Camera-to-vehicle for OpenCV camera axes, from Waymo's camera-to-vehicle extrinsic (4,4)."""
    axes = np.eye(4)
    axes[:3, :3] = WAYMO_FROM_OPENCV
    return extrinsic @ axes


def intrinsics(values) -> tuple[np.ndarray, np.ndarray]:
    """``K`` (3,3) and distortion ``(k1, k2, p1, p2, k3)`` (5,) from Waymo's 9 intrinsic values."""
    values = np.asarray(values, dtype=np.float64)
    if values.shape != (9,):
        raise ValueError(f"Waymo camera intrinsics have 9 values (fu fv cu cv k1 k2 p1 p2 k3), got {values.size}")
    fu, fv, cu, cv = values[:4]
    K = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
    return K, values[4:9].copy()


def box_to_vehicle(box) -> np.ndarray:  # (4,4)
    """Pose of an upright ``Label.Box`` in the vehicle frame: centre at the origin, x along the heading."""
    cos_h, sin_h = np.cos(box.heading), np.sin(box.heading)
    pose = np.eye(4)
    pose[:3, :3] = [[cos_h, -sin_h, 0.0], [sin_h, cos_h, 0.0], [0.0, 0.0, 1.0]]
    pose[:3, 3] = (box.center_x, box.center_y, box.center_z)
    return pose


def rigid_inverse(pose: np.ndarray) -> np.ndarray:  # (4,4)
    """Inverse of a rigid 4x4 transform (rotation transposed)."""
    inverse = np.eye(4)
    inverse[:3, :3] = pose[:3, :3].T
    inverse[:3, 3] = -pose[:3, :3].T @ pose[:3, 3]
    return inverse


def decode_matrix_float(compressed: bytes) -> np.ndarray:
    """A zlib-compressed serialized ``MatrixFloat`` as a float32 array of its declared shape."""
    matrix = schema.MatrixFloat.FromString(zlib.decompress(compressed))
    shape = tuple(matrix.shape.dims)
    values = np.array(matrix.data, dtype=np.float32)
    if int(np.prod(shape)) != values.size:
        raise ValueError(f"MatrixFloat holds {values.size} values but its shape is {shape}")
    return values.reshape(shape)


def beam_inclinations(calibration, height: int) -> np.ndarray:  # (H,) radians, row 0 = highest beam
    """Inclination of each range image row from a ``LaserCalibration``.

    The calibration lists inclinations from the lowest beam up; when it lists none, the beams
    are spread uniformly over [min, max] at row centres.
    """
    listed = np.asarray(calibration.beam_inclinations, dtype=np.float64)
    if listed.size:
        if listed.size != height:
            raise ValueError(f"laser calibration lists {listed.size} beam inclinations for a {height}-row range image")
        ascending = listed
    else:
        low, high = calibration.beam_inclination_min, calibration.beam_inclination_max
        ascending = low + (high - low) * (np.arange(height) + 0.5) / height
    return ascending[::-1].copy()


def euler_to_rotation(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:  # (...,3,3)
    """Rotation Rz(yaw) @ Ry(pitch) @ Rx(roll) (Waymo's 3-2-1 convention), for arrays of angles."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    rotation = np.empty(np.shape(roll) + (3, 3))
    rotation[..., 0, 0] = cy * cp
    rotation[..., 0, 1] = cy * sp * sr - sy * cr
    rotation[..., 0, 2] = cy * sp * cr + sy * sr
    rotation[..., 1, 0] = sy * cp
    rotation[..., 1, 1] = sy * sp * sr + cy * cr
    rotation[..., 1, 2] = sy * sp * cr - cy * sr
    rotation[..., 2, 0] = -sp
    rotation[..., 2, 1] = cp * sr
    rotation[..., 2, 2] = cp * cr
    return rotation


def range_image_to_points(
    range_image: np.ndarray,  # (H,W) metres, <= 0 = no return
    inclinations: np.ndarray,  # (H,) radians, row 0 = highest beam
    extrinsic: np.ndarray,  # (4,4) laser to vehicle
    pixel_pose: np.ndarray | None = None,  # (H,W,6) roll pitch yaw x y z, vehicle to global per pixel
    frame_pose: np.ndarray | None = None,  # (4,4) vehicle to global of the frame
) -> np.ndarray:  # (N,3) float64 vehicle frame of the frame pose
    """Points of the valid range image cells in the vehicle frame.

    The azimuth of column c is ((W - c - 0.5) / W * 2 - 1) * pi, corrected by the laser's yaw
    on the vehicle. A raw TOP range image carries a per-pixel vehicle pose (the car moves during
    the spin); its points are moved to the global frame with that pose and brought back into
    the frame pose's vehicle frame, so that they line up with the labels.
    """
    height, width = range_image.shape
    if inclinations.shape != (height,):
        raise ValueError(f"{inclinations.shape[0]} beam inclinations for a {height}-row range image")
    azimuth_correction = np.arctan2(extrinsic[1, 0], extrinsic[0, 0])
    ratios = (np.arange(width, 0, -1) - 0.5) / width
    azimuth = (ratios * 2.0 - 1.0) * np.pi - azimuth_correction  # (W,)
    valid = range_image > 0  # (H,W)
    rows, cols = np.nonzero(valid)
    distance = range_image[rows, cols].astype(np.float64)
    cos_incl = np.cos(inclinations)[rows]
    local = np.stack(
        [
            np.cos(azimuth)[cols] * cos_incl * distance,
            np.sin(azimuth)[cols] * cos_incl * distance,
            np.sin(inclinations)[rows] * distance,
        ],
        axis=-1,
    )  # (N,3) laser frame
    points = local @ extrinsic[:3, :3].T + extrinsic[:3, 3]  # (N,3) vehicle frame at each pixel's time
    if pixel_pose is None:
        return points
    if frame_pose is None:
        raise ValueError("a range image with per-pixel poses needs the frame pose")
    pose = pixel_pose[rows, cols].astype(np.float64)  # (N,6)
    rotation = euler_to_rotation(pose[:, 0], pose[:, 1], pose[:, 2])  # (N,3,3)
    global_points = np.einsum("nij,nj->ni", rotation, points) + pose[:, 3:]
    to_vehicle = rigid_inverse(frame_pose)
    return global_points @ to_vehicle[:3, :3].T + to_vehicle[:3, 3]
