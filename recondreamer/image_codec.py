"""RGB frames to and from PNG/JPEG bytes through OpenCV.

OpenCV against Pillow on the project's frames (``python benchmarks/opencv_images.py``): the same
pixels, JPEG decoding in about half the time (240x160 and 1920x1280), PNG decoding of 240x160
frames in 0.8 of it and PNG encoding in 0.7-0.8; only 1920x1280 PNGs decode slower (1.2-1.5x
Pillow's time; the synthetic frames are at most 240x160, Waymo's are JPEGs). OpenCV holds
channels in BGR order; these functions take and give RGB.
"""

from __future__ import annotations

import cv2
import numpy as np

PNG_COMPRESS_LEVEL = 1  # fast: frames are written once per render and read a few times
JPEG_QUALITY = 95
# EXIF orientation is ignored, as Pillow's decoder does: a frame's pixels are taken as stored.
_READ_FLAGS = cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION


def decode_rgb(data: bytes) -> np.ndarray | None:  # -> (H,W,3) uint8, None when not a decodable image
    """An encoded image (PNG, JPEG or any format OpenCV reads) as RGB; grey and alpha are dropped to RGB."""
    decoded = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), _READ_FLAGS)
    if decoded is None:
        return None
    if decoded.dtype != np.uint8:  # 16-bit PNG
        decoded = (decoded >> 8).astype(np.uint8)
    return cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB)


def encode_rgb(rgb: np.ndarray, image_format: str) -> bytes:  # (H,W,3) uint8 -> bytes
    """``image_format`` 'png' (compression level 1) or 'jpg' (quality 95, 4:2:0)."""
    if image_format == "png":
        options, suffix = [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESS_LEVEL], ".png"
    elif image_format == "jpg":
        options, suffix = [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY], ".jpg"
    else:
        raise ValueError(f"image format {image_format!r}: expected png or jpg")
    ok, encoded = cv2.imencode(suffix, cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR), options)
    if not ok:
        raise ValueError(f"OpenCV could not encode a {rgb.shape} image as {image_format}")
    return encoded.tobytes()
