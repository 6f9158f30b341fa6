"""Box error of the Waymo converter against Waymo's own projected labels, every camera.

    python benchmarks/waymo_undistortion.py [SEGMENT.tfrecord]   # default: ../shared/data/waymo/pvps_data_one_frame.tfrecord

For each camera the segment's first frame is converted (``convert-waymo --camera``), and the
rectangle around each laser label's projected 3D corners, clamped to the image, is compared with
Waymo's ``projected_lidar_labels`` of that camera (the same rectangle, projected by Waymo):

- recorded, distorted: the recorded images with the calibration's distortion (the camera model the
  recorded pixels follow);
- recorded, pinhole: the recorded images with the distortion dropped (what a pinhole rasterizer
  fits to recorded images);
- undistorted, pinhole: the converter's undistorted images with the scene's pinhole intrinsics,
  against Waymo's labels moved into the undistorted image with the same camera model (each
  label rectangle's outline through ``cv2.undistortPoints``, the inverse of the converter's remap).

Errors in pixels of the 1920-pixel-wide images: the distance between rectangle centres (median and
largest over the camera's labels) and the largest side-length difference, apart for the labels
inside the image and those cut by its border (a label side within a pixel of it). A cut label's
clamped side, moved into the undistorted image, is a curve, not the new image's border: there the
comparison itself is approximate.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from recondreamer.scene import load_scene
from recondreamer.sources.waymo import schema
from recondreamer.sources.waymo.convert import convert_waymo
from recondreamer.sources.waymo.tfrecord import iter_records
from recondreamer.sources.waymo.undistort import Undistortion, box_fit_errors, projected_labels, undistorted_rectangle

DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "data" / "waymo" / "pvps_data_one_frame.tfrecord"


def camera_errors(tfrecord: Path, frame, camera: str, out: Path) -> dict[str, dict[str, tuple[float, float]]]:
    scene = load_scene(convert_waymo(tfrecord, out, start=0, end=0, camera=camera))
    recorded = scene.metadata["recorded_camera"]
    K, distortion = np.array(recorded["K"]), np.array(recorded["distortion"])
    labels = projected_labels(frame, schema.CAMERA_NAMES[camera], camera)
    undistortion = Undistortion.of_camera(K, distortion, scene.width, scene.height)
    undistorted_labels = {track: undistorted_rectangle(undistortion, rectangle) for track, rectangle in labels.items()}
    return {
        "recorded, distorted": box_fit_errors(scene, labels, K, distortion),
        "recorded, pinhole": box_fit_errors(scene, labels, K, None),
        "undistorted, pinhole": box_fit_errors(scene, undistorted_labels, scene.K, scene.distortion),
    }


def summary(errors: dict[str, tuple[float, float]], tracks: list[str]) -> str:
    if not tracks:
        return "-"
    centre, side = np.array([errors[track] for track in tracks]).T
    return f"{np.median(centre):.2f} / {centre.max():.2f}, side {side.max():.2f}"


def main(tfrecord: Path) -> None:
    frame = schema.Frame.FromString(next(iter_records(tfrecord)))
    print(f"{tfrecord.name}: frame 0; centre error median / max and largest side error, pixels\n")
    print("| camera | images, camera model | labels inside the image | labels cut by its border |")
    print("|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for camera in schema.CAMERA_NAMES:
            errors = camera_errors(tfrecord, frame, camera, Path(tmp) / camera)
            labels = projected_labels(frame, schema.CAMERA_NAMES[camera], camera)
            calibration = next(c for c in frame.context.camera_calibrations if c.name == schema.CAMERA_NAMES[camera])
            size = np.array([calibration.width, calibration.height])
            cut = [track for track, (x0, y0, x1, y1) in labels.items() if min(x0, y0) < 1 or np.any(np.array([x1, y1]) > size - 1)]
            inside = [track for track in labels if track not in cut]
            for model, per_box in errors.items():
                print(f"| {camera} | {model} | {len(inside)}: {summary(per_box, inside)} | {len(cut)}: {summary(per_box, cut)} |")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT)
