"""Lens undistortion of a Waymo camera with OpenCV, and the check of boxes against Waymo's labels.

Waymo's cameras follow OpenCV's Brown-Conrady model (``k1 k2 p1 p2 k3``). The converter remaps
every image onto a pinhole camera (``cv2.initUndistortRectifyMap`` + ``cv2.remap``), so that the
rasterizer, the structure maps and the metrics, which all project with a plain pinhole, use the
camera model the pixels follow. The pinhole intrinsics are OpenCV's
``getOptimalNewCameraMatrix`` with ``alpha=0``: every pixel of the undistorted image comes from
inside the recorded one (no invented border; the map reaches at most 0.12 px past the recorded
image on the real segment's five cameras, filled by replicating the edge pixel), with focal
lengths changed by at most 0.9 %. A camera without distortion (``export-waymo``'s synthetic
segments) keeps its intrinsics and its JPEG bytes.
Both cameras use OpenCV's pixel convention (pixel centres at integers), as the scene format does.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from recondreamer.errors import ConversionError
from recondreamer.image_codec import decode_rgb, encode_rgb
from recondreamer.scene.cameras import project_points, world_to_camera

# undistortPoints inverts the distortion by fixed-point iteration, by default 5 steps without a
# convergence check (up to 5e-4 px off inside the FRONT image); these criteria iterate to convergence.
_POINT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


@dataclass(frozen=True)
class Undistortion:
    """One camera's remap from its distorted images to pinhole images of the same size."""

    K: np.ndarray  # (3,3) the recorded (distorted) camera
    distortion: np.ndarray  # (5,) k1 k2 p1 p2 k3
    pinhole_K: np.ndarray  # (3,3) the camera the undistorted images obey (distortion zero)
    width: int
    height: int
    map_x: np.ndarray  # (H,W) float32: for each undistorted pixel, its column in the recorded image
    map_y: np.ndarray  # (H,W) float32: its row

    @classmethod
    def of_camera(cls, K: np.ndarray, distortion: np.ndarray, width: int, height: int) -> Undistortion:
        K = np.asarray(K, dtype=np.float64)
        distortion = np.asarray(distortion, dtype=np.float64).reshape(5)
        size = (int(width), int(height))
        if np.any(distortion != 0):
            pinhole_K, _ = cv2.getOptimalNewCameraMatrix(K, distortion, size, 0.0, size)
        else:
            pinhole_K = K.copy()
        map_x, map_y = cv2.initUndistortRectifyMap(K, distortion, None, pinhole_K, size, cv2.CV_32FC1)
        return cls(K, distortion, pinhole_K, size[0], size[1], map_x, map_y)

    @property
    def is_identity(self) -> bool:
        return not np.any(self.distortion != 0)

    def image(self, image: np.ndarray) -> np.ndarray:  # (H,W,C) uint8 -> (H,W,C) uint8
        """The undistorted image (bilinear interpolation of the recorded pixels)."""
        if image.shape[:2] != (self.height, self.width):
            raise ValueError(f"image is {image.shape[1]}x{image.shape[0]}, the camera {self.width}x{self.height}")
        return cv2.remap(image, self.map_x, self.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def jpeg(self, data: bytes, where: str) -> bytes:
        """A recorded JPEG undistorted and encoded again as JPEG (``image_codec``); the bytes
        themselves when the camera has no distortion."""
        if self.is_identity:
            return data
        decoded = decode_rgb(data)
        if decoded is None:
            raise ConversionError(f"{where}: camera image cannot be decoded as JPEG")
        try:
            return encode_rgb(self.image(decoded), "jpg")
        except ValueError as error:
            raise ConversionError(f"{where}: the undistorted camera image could not be encoded ({error})") from error

    def points(self, uv: np.ndarray) -> np.ndarray:  # (N,2) recorded pixels -> (N,2) undistorted pixels
        """Where recorded pixel positions lie in the undistorted image (the inverse of the remap)."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 1, 2)
        undistorted = cv2.undistortPoints(uv, self.K, self.distortion, None, None, self.pinhole_K, _POINT_CRITERIA)
        return undistorted.reshape(-1, 2)


def projected_labels(frame, camera_name: int, camera: str) -> dict[str, np.ndarray]:
    """Waymo's own ``projected_lidar_labels`` of one camera, by laser label id: (4,) x0 y0 x1 y1 pixels.

    Each is the smallest rectangle around the label's 3D corners projected with the camera's
    distortion, clamped to the recorded image; its id is the laser label's with a camera suffix.
    """
    labels = {}
    for camera_labels in frame.projected_lidar_labels:
        if camera_labels.name != camera_name:
            continue
        for label in camera_labels.labels:
            box = label.box  # centre_x/y; length = extent along u, width = extent along v
            half = np.array([box.length, box.width]) / 2
            centre = np.array([box.center_x, box.center_y])
            labels[label.id.removesuffix(f"_{camera}")] = np.concatenate([centre - half, centre + half])
    return labels


def undistorted_rectangle(undistortion: Undistortion, rectangle: np.ndarray, samples: int = 64) -> np.ndarray:
    """The smallest rectangle (x0 y0 x1 y1) around a recorded-image rectangle's outline moved into
    the undistorted image (``samples`` points an edge), clamped to that image."""
    x0, y0, x1, y1 = rectangle
    steps = np.linspace(0.0, 1.0, samples)
    outline = np.concatenate([
        np.stack([x0 + (x1 - x0) * steps, np.full(samples, y0)], 1), np.stack([x0 + (x1 - x0) * steps, np.full(samples, y1)], 1),
        np.stack([np.full(samples, x0), y0 + (y1 - y0) * steps], 1), np.stack([np.full(samples, x1), y0 + (y1 - y0) * steps], 1),
    ])
    moved = undistortion.points(outline)
    size = np.array([undistortion.width, undistortion.height])
    return np.concatenate([np.clip(moved.min(0), 0, size), np.clip(moved.max(0), 0, size)])


def box_fit_errors(scene, labels: dict[str, np.ndarray], K: np.ndarray, distortion: np.ndarray | None) -> dict[str, tuple[float, float]]:
    """Per matched label: the centre error and the largest side error (pixels) of the rectangle
    around frame 0's box corners projected with ``K`` and ``distortion``, clamped to the image,
    against the label rectangle (x0 y0 x1 y1)."""
    world_to_cam = world_to_camera(scene.cam_to_world[0])
    size = np.array([scene.width, scene.height])
    errors = {}
    for box in scene.boxes(0):
        if box.track_id not in labels:
            continue
        uv, z = project_points(box.corners(), K, world_to_cam, distortion)
        if not np.all(z > 0):
            raise ValueError(f"box {box.track_id} has corners behind the camera, yet Waymo projects it")
        low, high = np.clip(uv.min(0), 0, size), np.clip(uv.max(0), 0, size)
        truth = labels[box.track_id]
        centre_error = float(np.hypot(*((low + high) / 2 - (truth[:2] + truth[2:]) / 2)))
        side_error = float(np.abs((high - low) - (truth[2:] - truth[:2])).max())
        errors[box.track_id] = (centre_error, side_error)
    return errors
