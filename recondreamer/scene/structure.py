"""Structure maps: 3D boxes and HD-map lines drawn into any camera.

Three products, all with the plain pinhole model (no lens distortion, as the NTA-IoU / NTL-IoU
code projects):

- ``project_box_2d``: the projected 2D box of a 3D box (min/max of its corners), with a
  fully-inside flag and near-plane handling (metric ground truth);
- ``structure_channels``: (C,H,W) float32 conditioning channels for the restorer, named by
  ``STRUCTURE_CHANNELS``;
- ``draw_structure_map``: an RGB picture of the same for people.

Geometry that crosses the camera's near plane is clipped in 3D against the plane ``z = NEAR``
before projection (projecting a point behind the camera flips it through the image centre and
would draw a wrong segment); what remains is clipped in 2D to a margin around the image.

Boxes are drawn as FILLED faces, not wireframes: at the restorer's 240x160 a wireframe is a few
scattered pixels that say little about which pixels a vehicle covers, while filled faces give
the silhouette, occlusion between boxes (painter's order, far to near) and, through the
per-face inverse depth, a sense of distance. Only faces turned towards the camera are drawn;
for a convex box they cover exactly its silhouette without overlapping each other.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageDraw

from recondreamer.scene.cameras import transform_points, world_to_camera
from recondreamer.scene.types import Box, Polyline

NEAR = 0.1  # metres: near plane of every structure projection

STRUCTURE_CHANNELS = (
    "box_vehicle",  # 1 where a vehicle box is the nearest box surface
    "box_vulnerable",  # 1 where a pedestrian or cyclist box is nearest
    "box_sign",  # 1 where a sign box is nearest
    "box_inverse_depth",  # 1/z (1/m, capped at 1) of the nearest box face, 0 where no box
    "box_track_code",  # per-track code in [0.25, 1] (stable hash of the track id), 0 where no box
    "road_line",  # lane markings and crosswalk outlines
    "road_edge",  # curbs / road boundaries
    "lane_center",  # lane centre lines
)
_CHANNEL = {name: index for index, name in enumerate(STRUCTURE_CHANNELS)}
_CLASS_CHANNEL = {
    "vehicle": "box_vehicle",
    "pedestrian": "box_vulnerable",
    "cyclist": "box_vulnerable",
    "sign": "box_sign",
}
_LINE_CHANNEL = {
    "road_line": "road_line",
    "crosswalk": "road_line",
    "road_edge": "road_edge",
    "lane_center": "lane_center",
}

CLASS_COLOURS = {  # RGB of each box class in draw_structure_map
    "vehicle": (40, 110, 255),
    "pedestrian": (255, 50, 50),
    "cyclist": (255, 150, 0),
    "sign": (200, 40, 220),
}
LINE_COLOURS = {  # RGB of each polyline kind in draw_structure_map
    "road_line": (255, 255, 255),
    "crosswalk": (160, 220, 255),
    "road_edge": (255, 90, 40),
    "lane_center": (150, 150, 40),
}

# Corner index = 4*sx + 2*sy + sz (bits: +x, +y, +z), the order of Box.corners().
_BOX_FACES = np.array(
    [
        [0, 1, 3, 2],  # -x (rear)
        [4, 6, 7, 5],  # +x (front, along the heading)
        [0, 4, 5, 1],  # -y (right)
        [2, 3, 7, 6],  # +y (left)
        [0, 2, 6, 4],  # -z (bottom)
        [1, 5, 7, 3],  # +z (top)
    ]
)
_FRONT_FACE = 1
_BOX_EDGES = np.array([(i, i | bit) for bit in (4, 2, 1) for i in range(8) if not i & bit])  # (12,2)


@dataclass(frozen=True)
class Box2D:
    """The projected 2D box of one 3D box in one camera.

    ``xyxy`` = (x_min, y_min, x_max, y_max) pixels of the part of the box in front of the near
    plane (not clipped to the image); NaN when no part is in front. ``in_front``: some part of
    the box lies in front of the near plane. ``fully_inside``: all 8 corners are in front and
    project inside [0, width] x [0, height].
    """

    track_id: str
    label: str
    xyxy: np.ndarray  # (4,) float
    fully_inside: bool
    in_front: bool


def track_code(track_id: str) -> float:
    """A per-track value in [0.25, 1], the same in every frame and every run (CRC32 of the id)."""
    return 0.25 + 0.75 * (zlib.crc32(track_id.encode("utf-8")) % 4096) / 4095.0


def _pinhole(points_cam: np.ndarray, K: np.ndarray) -> np.ndarray:  # (N,3) with z > 0 -> (N,2)
    return (points_cam[:, :2] / points_cam[:, 2:3]) @ K[:2, :2].T + K[:2, 2]


def _clip_polygon(polygon: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:  # (N,D) -> (M,D)
    """Sutherland-Hodgman: keep the part of a convex polygon where ``p @ normal + offset >= 0``."""
    if len(polygon) == 0:
        return polygon
    distance = polygon @ normal + offset  # (N,)
    if np.all(distance >= 0):  # the common case: nothing to clip
        return polygon
    kept = []
    for i in range(len(polygon)):
        j = (i + 1) % len(polygon)
        if distance[i] >= 0:
            kept.append(polygon[i])
        if (distance[i] >= 0) != (distance[j] >= 0):
            s = distance[i] / (distance[i] - distance[j])
            kept.append(polygon[i] + s * (polygon[j] - polygon[i]))
    return np.array(kept).reshape(-1, polygon.shape[1])


def _clip_to_rect(polygon: np.ndarray, width: int, height: int, margin: float) -> np.ndarray:  # (N,2) -> (M,2)
    low, high = polygon.min(axis=0), polygon.max(axis=0)
    if low[0] >= -margin and low[1] >= -margin and high[0] <= width + margin and high[1] <= height + margin:
        return polygon
    for normal, offset in (
        ((1.0, 0.0), margin),
        ((-1.0, 0.0), width + margin),
        ((0.0, 1.0), margin),
        ((0.0, -1.0), height + margin),
    ):
        polygon = _clip_polygon(polygon, np.array(normal), offset)
    return polygon


def _clip_segments_near(p0: np.ndarray, p1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # (S,3) x2 -> (S',3) x2
    """Clip camera-frame segments to ``z >= NEAR``; segments wholly behind are dropped."""
    d0, d1 = p0[:, 2] - NEAR, p1[:, 2] - NEAR
    keep = (d0 >= 0) | (d1 >= 0)
    p0, p1, d0, d1 = p0[keep], p1[keep], d0[keep], d1[keep]
    crossing = (d0 < 0) != (d1 < 0)
    s = np.where(crossing, d0 / np.where(crossing, d0 - d1, 1.0), 0.0)[:, None]
    hit = p0 + s * (p1 - p0)
    p0 = np.where((d0 < 0)[:, None], hit, p0)
    p1 = np.where((d1 < 0)[:, None], hit, p1)
    return p0, p1


def _clip_segments_rect(
    a: np.ndarray, b: np.ndarray, width: int, height: int, margin: float
) -> tuple[np.ndarray, np.ndarray]:
    """Liang-Barsky clipping of 2D segments (S,2) to the image grown by ``margin``."""
    delta = b - a
    t0, t1 = np.zeros(len(a)), np.ones(len(a))
    bounds = ((0, -margin, -1.0), (0, width + margin, 1.0), (1, -margin, -1.0), (1, height + margin, 1.0))
    for axis, bound, sign in bounds:
        # Inside when sign * (a + t*delta - bound) <= 0.
        p = sign * delta[:, axis]
        q = sign * (bound - a[:, axis])
        parallel = p == 0
        ratio = np.where(parallel, 0.0, q / np.where(parallel, 1.0, p))
        t0 = np.where(~parallel & (p < 0), np.maximum(t0, ratio), t0)
        t1 = np.where(~parallel & (p > 0), np.minimum(t1, ratio), t1)
        t1 = np.where(parallel & (q < 0), -1.0, t1)  # parallel and outside: reject
    keep = t0 <= t1
    return (a + t0[:, None] * delta)[keep], (a + t1[:, None] * delta)[keep]


def project_box_2d(box: Box, K: np.ndarray, cam_to_world: np.ndarray, width: int, height: int) -> Box2D:
    """The 2D box (min/max of projected corners) of a 3D box, with near-plane handling."""
    K = np.asarray(K, dtype=np.float64)
    corners = transform_points(world_to_camera(cam_to_world), box.corners())  # (8,3) camera
    if np.all(corners[:, 2] > NEAR):
        uv = _pinhole(corners, K)
        xyxy = np.concatenate([uv.min(axis=0), uv.max(axis=0)])
        inside = bool(xyxy[0] >= 0 and xyxy[1] >= 0 and xyxy[2] <= width and xyxy[3] <= height)
        return Box2D(box.track_id, box.label, xyxy, fully_inside=inside, in_front=True)
    if np.all(corners[:, 2] <= NEAR):
        return Box2D(box.track_id, box.label, np.full(4, np.nan), fully_inside=False, in_front=False)
    # Partly behind: the visible solid's vertices are the corners in front plus the points where
    # edges cross the near plane; their projections bound the visible part.
    p0, p1 = _clip_segments_near(corners[_BOX_EDGES[:, 0]], corners[_BOX_EDGES[:, 1]])
    uv = _pinhole(np.concatenate([p0, p1]), K)
    xyxy = np.concatenate([uv.min(axis=0), uv.max(axis=0)])
    return Box2D(box.track_id, box.label, xyxy, fully_inside=False, in_front=True)


def project_boxes_2d(boxes: list[Box], K: np.ndarray, cam_to_world: np.ndarray, width: int, height: int) -> list[Box2D]:
    return [project_box_2d(box, K, cam_to_world, width, height) for box in boxes]


@dataclass
class _Face:
    box_index: int
    face_index: int
    polygon: np.ndarray  # (M,2) pixels, clipped
    inverse_depth: float


def _visible_faces(boxes: list[Box], K: np.ndarray, world_to_cam: np.ndarray, width: int, height: int) -> list[_Face]:
    """Camera-facing faces of every box, near-plane and image clipped, in painter's order (far first)."""
    if not boxes:
        return []
    margin = float(max(width, height))
    corners = np.stack([box.corners() for box in boxes])  # (B,8,3) world
    corners = corners @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]  # (B,8,3) camera
    centres = corners.mean(axis=1)  # (B,3)
    face_corners = corners[:, _BOX_FACES]  # (B,6,4,3)
    face_centres = face_corners.mean(axis=2)  # (B,6,3)
    # A face's outward normal points from the box centre to the face centre; the face is seen
    # when the camera (the origin) lies on its outer side.
    seen = np.einsum("bfk,bfk->bf", face_centres - centres[:, None], -face_centres) > 0  # (B,6)
    seen &= np.any(face_corners[..., 2] > NEAR, axis=2)
    order = np.argsort(-np.linalg.norm(centres, axis=1), kind="stable")  # far boxes first
    near_plane = np.array([0.0, 0.0, 1.0])
    faces = []
    for box_index in order:
        for face_index in np.flatnonzero(seen[box_index]):
            polygon3d = _clip_polygon(face_corners[box_index, face_index], near_plane, -NEAR)
            if len(polygon3d) < 3:
                continue
            polygon = _clip_to_rect(_pinhole(polygon3d, K), width, height, margin)
            if len(polygon) < 3:
                continue
            inverse_depth = min(1.0, 1.0 / float(polygon3d[:, 2].mean()))
            faces.append(_Face(int(box_index), int(face_index), polygon, inverse_depth))
    return faces


def _line_runs(
    polylines: list[Polyline], K: np.ndarray, world_to_cam: np.ndarray, width: int, height: int
) -> list[tuple[str, list[tuple[float, float]]]]:
    """(kind, pixel points of one connected run) of every polyline, near-plane and image clipped.

    Clipping cuts a polyline into segments; segments that still join end to start are merged
    back into runs so that each run is one drawing call.
    """
    margin = float(max(width, height))
    runs = []
    for polyline in polylines:
        points = transform_points(world_to_cam, polyline.points)  # (M,3) camera
        p0, p1 = _clip_segments_near(points[:-1], points[1:])
        if len(p0) == 0:
            continue
        a, b = _clip_segments_rect(_pinhole(p0, K), _pinhole(p1, K), width, height, margin)  # (S,2) each
        if len(a) == 0:
            continue
        breaks = np.flatnonzero(np.any(b[:-1] != a[1:], axis=1)) + 1  # segment indices that start a new run
        for start, stop in zip(np.r_[0, breaks], np.r_[breaks, len(a)], strict=True):
            run = np.concatenate([a[start:stop], b[stop - 1 : stop]])
            runs.append((polyline.kind, [tuple(p) for p in run.tolist()]))
    return runs


def line_width(height: int) -> int:
    """Line thickness in pixels: NTL-IoU's 20 px at 1280 px image height, scaled (at least 1)."""
    return max(1, round(height * 20 / 1280))


def structure_channels(
    boxes: list[Box], polylines: list[Polyline], K: np.ndarray, cam_to_world: np.ndarray, width: int, height: int
) -> np.ndarray:  # (C,H,W) float32, C = len(STRUCTURE_CHANNELS)
    """The restorer's structure conditioning: box class masks, box inverse depth and track code, map lines.

    Map lines are hidden where a box surface covers them (boxes stand on the road).
    """
    K = np.asarray(K, dtype=np.float64)
    world_to_cam = world_to_camera(cam_to_world)
    box_index = Image.new("I", (width, height), 0)  # 1 + index of the nearest box, 0 = none
    inverse_depth = Image.new("F", (width, height), 0.0)
    draw_index, draw_depth = ImageDraw.Draw(box_index), ImageDraw.Draw(inverse_depth)
    for face in _visible_faces(boxes, K, world_to_cam, width, height):
        polygon = [tuple(p) for p in face.polygon]
        draw_index.polygon(polygon, fill=face.box_index + 1)
        draw_depth.polygon(polygon, fill=face.inverse_depth)
    channels = np.zeros((len(STRUCTURE_CHANNELS), height, width), dtype=np.float32)
    index = np.asarray(box_index)  # (H,W) int32
    covered = index > 0
    class_of = np.array([-1] + [_CHANNEL[_CLASS_CHANNEL[box.label]] for box in boxes])  # (1+B,) channel per index
    code_of = np.array([0.0] + [track_code(box.track_id) for box in boxes], dtype=np.float32)  # (1+B,)
    for name in set(_CLASS_CHANNEL.values()):
        channels[_CHANNEL[name]] = class_of[index] == _CHANNEL[name]
    channels[_CHANNEL["box_inverse_depth"]] = np.asarray(inverse_depth)
    channels[_CHANNEL["box_track_code"]] = code_of[index]

    width_px = line_width(height)
    line_images = {name: Image.new("L", (width, height), 0) for name in set(_LINE_CHANNEL.values())}
    line_draws = {name: ImageDraw.Draw(image) for name, image in line_images.items()}
    for kind, run in _line_runs(polylines, K, world_to_cam, width, height):
        line_draws[_LINE_CHANNEL[kind]].line(run, fill=255, width=width_px, joint="curve")
    for name, image in line_images.items():
        channels[_CHANNEL[name]] = (np.asarray(image) > 0) & ~covered
    return channels


def track_colour(label: str, track_id: str) -> tuple[int, int, int]:
    """Class colour scaled by a per-track brightness, so tracks of one class stay apart."""
    scale = 0.45 + 0.55 * (track_code(track_id) - 0.25) / 0.75
    return tuple(int(round(c * scale)) for c in CLASS_COLOURS[label])


def draw_structure_map(
    boxes: list[Box], polylines: list[Polyline], K: np.ndarray, cam_to_world: np.ndarray, width: int, height: int
) -> np.ndarray:  # (H,W,3) uint8
    """An RGB picture: map lines by kind, then boxes as filled faces (class colour, per-track
    brightness, lighter front face showing the heading) with dark outlines, far boxes first."""
    K = np.asarray(K, dtype=np.float64)
    world_to_cam = world_to_camera(cam_to_world)
    image = Image.new("RGB", (width, height), (0, 0, 0))
    draw = ImageDraw.Draw(image)
    width_px = line_width(height)
    for kind, run in _line_runs(polylines, K, world_to_cam, width, height):
        draw.line(run, fill=LINE_COLOURS[kind], width=width_px, joint="curve")
    for face in _visible_faces(boxes, K, world_to_cam, width, height):
        box = boxes[face.box_index]
        colour = track_colour(box.label, box.track_id)
        if face.face_index == _FRONT_FACE:
            colour = tuple(min(255, c + 90) for c in colour)
        draw.polygon([tuple(p) for p in face.polygon], fill=colour, outline=(20, 20, 20))
    return np.asarray(image)


__all__ = [
    "Box2D",
    "NEAR",
    "STRUCTURE_CHANNELS",
    "draw_structure_map",
    "line_width",
    "project_box_2d",
    "project_boxes_2d",
    "structure_channels",
    "track_code",
    "track_colour",
]
