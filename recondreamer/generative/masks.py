"""Training masks of ``dd2_mask`` (paper supplement): random boxes on the hard regions.

Rendered frames degrade most at the sky/scene boundary and in distant regions near the image
centre, so masks concentrate there:

- the boundary band: pixels within ``band_half_width * H`` of the sky/scene boundary of the
  ground-truth sky mask; without a sky mask (or one with no boundary), a horizontal band around
  the horizon row, the row of the ego-forward vanishing point;
- the distant central region: a ``center_width*W x center_height*H`` rectangle around that
  vanishing point.

Boxes are centred on random pixels of each region and clipped to the union of both regions, so
a masked pixel never lies outside them. Masks are "keep" masks: True keeps the degraded pixel,
False zeroes it (``V_mask = V * M``).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from recondreamer.generative.config import MaskConfig


def vanishing_point(K: np.ndarray, cam_to_world: np.ndarray, ego_to_world: np.ndarray) -> np.ndarray:  # (2,) u, v
    """Image position of the point at infinity straight ahead of the ego, level with the ground.

    K (3,3); cam_to_world, ego_to_world (4,4). Falls back to the principal point when the
    forward direction is behind the camera.
    """
    forward = np.array(ego_to_world[:3, 0], dtype=np.float64)
    forward[2] = 0.0
    norm = np.linalg.norm(forward)
    if norm < 1e-9:
        return np.array([K[0, 2], K[1, 2]], dtype=np.float64)
    direction_cam = cam_to_world[:3, :3].T @ (forward / norm)
    if direction_cam[2] <= 1e-6:
        return np.array([K[0, 2], K[1, 2]], dtype=np.float64)
    uvw = K @ direction_cam
    return uvw[:2] / uvw[2]


def mask_regions(
    height: int,
    width: int,
    config: MaskConfig,
    vanishing_uv: np.ndarray,  # (2,) pixel position of the distant centre / horizon
    sky_mask: np.ndarray | None = None,  # (H,W) bool ground-truth sky
) -> tuple[np.ndarray, np.ndarray]:  # (H,W) bool boundary band, (H,W) bool distant central region
    """The two regions masks may fall in."""
    radius = config.band_half_width * height
    rows = np.arange(height)[:, None]
    cols = np.arange(width)[None, :]
    band = None
    if sky_mask is not None:
        if sky_mask.shape != (height, width):
            raise ValueError(f"sky mask has shape {sky_mask.shape}, expected {(height, width)}")
        sky = sky_mask.astype(bool)
        boundary = sky & ~ndimage.binary_erosion(sky, border_value=1)
        if boundary.any() and not sky.all():
            band = ndimage.distance_transform_edt(~boundary) <= radius
    if band is None:
        band = np.broadcast_to(np.abs(rows - vanishing_uv[1]) <= radius, (height, width)).copy()
    center = (np.abs(cols - vanishing_uv[0]) <= config.center_width * width / 2) & (
        np.abs(rows - vanishing_uv[1]) <= config.center_height * height / 2
    )
    return band, center


def sample_keep_mask(
    height: int,
    width: int,
    config: MaskConfig,
    rng: np.random.Generator,
    vanishing_uv: np.ndarray,
    sky_mask: np.ndarray | None = None,
) -> np.ndarray:  # (H,W) bool, False = masked
    """One frame's keep mask: with probability ``config.probability`` some boxes are masked."""
    keep = np.ones((height, width), dtype=bool)
    if rng.random() >= config.probability:
        return keep
    band, center = mask_regions(height, width, config, vanishing_uv, sky_mask)
    allowed = band | center
    boxes = np.zeros((height, width), dtype=bool)
    for region, count_range in ((band, config.boundary_boxes), (center, config.center_boxes)):
        candidates = np.flatnonzero(region)
        if candidates.size == 0:
            continue
        for _ in range(rng.integers(count_range[0], count_range[1] + 1)):
            row, col = np.unravel_index(candidates[rng.integers(candidates.size)], (height, width))
            box_h, box_w = rng.uniform(config.box_size[0], config.box_size[1], size=2) * height
            top, left = round(row - box_h / 2), round(col - box_w / 2)
            boxes[max(top, 0) : max(top + round(box_h), 0), max(left, 0) : max(left + round(box_w), 0)] = True
    keep[boxes & allowed] = False
    return keep


def sample_clip_masks(
    num_frames: int,
    height: int,
    width: int,
    config: MaskConfig,
    rng: np.random.Generator,
    vanishing_uv: np.ndarray,  # (T,2) or (2,)
    sky_masks: np.ndarray | None = None,  # (T,H,W) bool
) -> np.ndarray:  # (T,H,W) bool keep masks, drawn independently per frame
    uv = np.broadcast_to(np.asarray(vanishing_uv, dtype=np.float64), (num_frames, 2))
    return np.stack(
        [
            sample_keep_mask(height, width, config, rng, uv[t], None if sky_masks is None else sky_masks[t])
            for t in range(num_frames)
        ]
    )
