"""The world's own ground-truth renderer: vectorised ray casting of analytic primitives.

A bundle of rays (a pinhole camera's pixels or a spinning LiDAR's beams) is cast against the
road height field (every ray) and against boxes, vertical cylinders and spheres. Each primitive
is only tested against the rays inside its footprint on the ray grid (the pixel rectangle of its
bounding box clipped at the near plane, or the elevation x azimuth rectangle of its bounding
sphere), so the cost follows the covered area, not pixels x primitives; ``ExhaustiveRays`` is
the readable every-ray-every-primitive twin the tests compare against. The nearest hit per ray
is found with ``np.minimum.at``; camera rays are then textured (facade windows, vehicle glass, lights and wheels, asphalt, paving, markings with
analytic anti-aliasing) and lit by one directional sun plus ambient light, with distance haze.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recondreamer.sources.synthetic.world import BUS, CAR, FACADE, SEM, TRUCK, VAN, Primitives, World

NEAR = 0.05  # metres: hits closer than this to the ray origin are ignored
GROUND_MAX_DISTANCE = 600.0  # metres: farther ground hits count as sky (the horizon band)
HAZE_DISTANCE = 350.0  # metres: e-folding distance of the blend towards the horizon colour
AMBIENT, DIFFUSE = 0.5, 0.6
NONE, GROUND, BOX, CYLINDER, SPHERE = range(5)
BOX_CORNER_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)  # (8,3)
BOX_EDGES = np.array([(a, b) for a in range(8) for b in range(a + 1, 8) if (a ^ b).bit_count() == 1])  # (12,2)
ROAD_PART, RAISED_PART, CURB_PART = range(3)  # which part of the ground height field was hit


# ----------------------------------------------------------------------------------------------
# Ray bundles
# ----------------------------------------------------------------------------------------------


def _rectangles_to_pairs(
    row0: np.ndarray, row1: np.ndarray, col0: np.ndarray, col1: np.ndarray, num_cols: int, wrap: bool
) -> tuple[np.ndarray, np.ndarray]:  # (M,) ray index, (M,) primitive index
    """All (ray, primitive) pairs of inclusive per-primitive grid rectangles (empty if row1 < row0)."""
    rows = np.maximum(row1 - row0 + 1, 0)
    cols = np.maximum(col1 - col0 + 1, 0)
    counts = rows * cols  # (P,)
    primitive = np.repeat(np.arange(len(counts)), counts)
    start = np.cumsum(counts) - counts
    local = np.arange(int(counts.sum())) - np.repeat(start, counts)
    width = np.repeat(np.maximum(cols, 1), counts)
    row = np.repeat(row0, counts) + local // width
    col = np.repeat(col0, counts) + local % width
    if wrap:
        col = col % num_cols
    return row * num_cols + col, primitive


@dataclass
class PinholeRays:
    """One ray per pixel centre (OpenCV: pixel (u, v) centre at coordinates (u, v)).

    Directions are scaled to unit camera z, so a hit's ray parameter is its depth.
    """

    cam_to_world: np.ndarray  # (4,4)
    K: np.ndarray  # (3,3)
    width: int
    height: int

    def __post_init__(self) -> None:
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(np.float64)
        camera = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1).reshape(-1, 3)  # (N,3)
        self.origin = self.cam_to_world[:3, 3].copy()  # (3,)
        self.dirs = camera @ self.cam_to_world[:3, :3].T  # (N,3)
        self.pixel_angle = 1.0 / fx  # radians per pixel near the optical axis

    def candidates(self, centers: np.ndarray, yaws: np.ndarray, halves: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ray, primitive) pairs whose pixel lies in the bounding rectangle of the projection of
        the primitive's bounding box (centres (P,3), yaws (P,), half sizes (P,3)).

        The box is clipped to the near plane first (its corners in front of it plus the points
        where its edges cross it), so long buildings beside the camera get tight rectangles.
        """
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        local = BOX_CORNER_SIGNS[None] * halves[:, None, :]  # (P,8,3)
        cos_y, sin_y = np.cos(yaws)[:, None], np.sin(yaws)[:, None]
        world = np.stack([cos_y * local[..., 0] - sin_y * local[..., 1], sin_y * local[..., 0] + cos_y * local[..., 1], local[..., 2]], -1)
        camera = (world + centers[:, None, :] - self.origin) @ self.cam_to_world[:3, :3]  # (P,8,3)
        start, end = camera[:, BOX_EDGES[:, 0]], camera[:, BOX_EDGES[:, 1]]  # (P,12,3)
        crosses = (start[..., 2] - NEAR) * (end[..., 2] - NEAR) < 0
        fraction = (NEAR - start[..., 2]) / np.where(crosses, end[..., 2] - start[..., 2], 1.0)
        points = np.concatenate([camera, start + fraction[..., None] * (end - start)], axis=1)  # (P,20,3)
        valid = np.concatenate([camera[..., 2] >= NEAR, crosses], axis=1)  # (P,20)
        z = np.where(valid, np.maximum(points[..., 2], NEAR), 1.0)
        u = cx + fx * points[..., 0] / z
        v = cy + fy * points[..., 1] / z
        col0 = np.clip(np.floor(np.where(valid, u, np.inf).min(axis=1)), 0, self.width)
        col1 = np.clip(np.ceil(np.where(valid, u, -np.inf).max(axis=1)), -1, self.width - 1)
        row0 = np.clip(np.floor(np.where(valid, v, np.inf).min(axis=1)), 0, self.height)
        row1 = np.clip(np.ceil(np.where(valid, v, -np.inf).max(axis=1)), -1, self.height - 1)
        row1 = np.where(valid.any(axis=1), row1, -1)
        return _rectangles_to_pairs(row0.astype(np.int64), row1.astype(np.int64), col0.astype(np.int64), col1.astype(np.int64), self.width, wrap=False)


@dataclass
class SpinningLidarRays:
    """Rings of a spinning LiDAR: ``elevations`` (ascending, radians) x ``azimuths`` equal steps."""

    origin: np.ndarray  # (3,) world
    yaw: float  # radians, heading of the LiDAR's x axis in the world
    elevations: np.ndarray  # (B,)
    num_azimuths: int

    def __post_init__(self) -> None:
        self.step = 2.0 * np.pi / self.num_azimuths
        azimuth = -np.pi + (np.arange(self.num_azimuths) + 0.5) * self.step + self.yaw  # (A,)
        el, az = np.meshgrid(self.elevations, azimuth, indexing="ij")  # (B,A)
        self.dirs = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1).reshape(-1, 3)

    def candidates(self, centers: np.ndarray, yaws: np.ndarray, halves: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ray, primitive) pairs whose beam lies in the angular box of the bounding box's bounding sphere."""
        del yaws  # the bounding sphere does not depend on the orientation
        radii = np.linalg.norm(halves, axis=1)
        rel = centers - self.origin  # (P,3)
        horizontal = np.hypot(rel[:, 0], rel[:, 1])
        distance = np.linalg.norm(rel, axis=1)
        inside = horizontal <= radii
        half_az = np.where(inside, np.pi, np.arcsin(np.clip(radii / np.maximum(horizontal, 1e-9), 0.0, 1.0)))
        azimuth = np.arctan2(rel[:, 1], rel[:, 0]) - self.yaw
        half_el = np.where(distance <= radii, np.pi, np.arcsin(np.clip(radii / np.maximum(distance, 1e-9), 0.0, 1.0)))
        elevation = np.arctan2(rel[:, 2], horizontal)
        row0 = np.searchsorted(self.elevations, elevation - half_el, side="left")
        row1 = np.searchsorted(self.elevations, elevation + half_el, side="right") - 1
        col0 = np.floor((azimuth - half_az + np.pi) / self.step - 0.5).astype(np.int64)
        col1 = np.ceil((azimuth + half_az + np.pi) / self.step - 0.5).astype(np.int64)
        col1 = np.where(inside | (col1 - col0 + 1 >= self.num_azimuths), col0 + self.num_azimuths - 1, col1)
        return _rectangles_to_pairs(row0, row1, col0, col1, self.num_azimuths, wrap=True)


@dataclass
class ExhaustiveRays:
    """Reference twin of the footprint culling above: every ray is tested against every primitive.

    ``cast`` with it must give exactly the hits it gives with the wrapped bundle (tested).
    """

    rays: PinholeRays | SpinningLidarRays

    @property
    def origin(self) -> np.ndarray:
        return self.rays.origin

    @property
    def dirs(self) -> np.ndarray:
        return self.rays.dirs

    def candidates(self, centers: np.ndarray, yaws: np.ndarray, halves: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        num_rays, num_primitives = len(self.rays.dirs), len(centers)
        return np.tile(np.arange(num_rays), num_primitives), np.repeat(np.arange(num_primitives), num_rays)


# ----------------------------------------------------------------------------------------------
# Intersections
# ----------------------------------------------------------------------------------------------


def _rotate_to_local(vectors: np.ndarray, yaw: np.ndarray) -> np.ndarray:  # (M,3), (M,) -> (M,3)
    cos_y, sin_y = np.cos(yaw), np.sin(yaw)
    x, y = vectors[:, 0], vectors[:, 1]
    return np.stack([cos_y * x + sin_y * y, -sin_y * x + cos_y * y, vectors[:, 2]], axis=1)


def _intersect_boxes(origin, dirs, prims: Primitives, box) -> np.ndarray:  # (M,) ray parameter, inf = miss
    origin_local = _rotate_to_local(origin - prims.box_center[box], prims.box_yaw[box])
    dir_local = _rotate_to_local(dirs, prims.box_yaw[box])
    dir_local = np.where(np.abs(dir_local) < 1e-12, 1e-12, dir_local)
    half = prims.box_half[box]
    t1 = (-half - origin_local) / dir_local
    t2 = (half - origin_local) / dir_local
    t_near = np.minimum(t1, t2).max(axis=1)
    t_far = np.maximum(t1, t2).min(axis=1)
    return np.where((t_near <= t_far) & (t_near > NEAR), t_near, np.inf)


def _intersect_cylinders(origin, dirs, prims: Primitives, cyl) -> np.ndarray:  # (M,)
    base = prims.cyl_base[cyl]
    ox, oy = origin[0] - base[:, 0], origin[1] - base[:, 1]
    a = dirs[:, 0] ** 2 + dirs[:, 1] ** 2
    b = 2.0 * (ox * dirs[:, 0] + oy * dirs[:, 1])
    c = ox**2 + oy**2 - prims.cyl_radius[cyl] ** 2
    disc = b * b - 4.0 * a * c
    t = (-b - np.sqrt(np.maximum(disc, 0.0))) / (2.0 * np.maximum(a, 1e-12))
    z = origin[2] + t * dirs[:, 2]
    hit = (disc > 0) & (a > 1e-12) & (t > NEAR) & (z >= base[:, 2]) & (z <= base[:, 2] + prims.cyl_height[cyl])
    return np.where(hit, t, np.inf)


def _intersect_spheres(origin, dirs, prims: Primitives, sph) -> np.ndarray:  # (M,)
    rel = origin - prims.sph_center[sph]
    a = np.einsum("ij,ij->i", dirs, dirs)
    b = 2.0 * np.einsum("ij,ij->i", rel, dirs)
    c = np.einsum("ij,ij->i", rel, rel) - prims.sph_radius[sph] ** 2
    disc = b * b - 4.0 * a * c
    t = (-b - np.sqrt(np.maximum(disc, 0.0))) / (2.0 * a)
    return np.where((disc > 0) & (t > NEAR), t, np.inf)


def _intersect_ground(world: World, origin, dirs) -> tuple[np.ndarray, np.ndarray]:  # (N,) t, (N,) part
    """The road at z = 0 between the kerbs, raised ground (kerb height) outside, kerb faces between."""
    layout = world.layout
    down = dirs[:, 2] < -1e-9
    dz = np.where(down, dirs[:, 2], -1.0)
    t_high = (layout.curb_height - origin[2]) / dz
    t_low = -origin[2] / dz
    _, d_high = layout.frame.to_road(origin[0] + t_high * dirs[:, 0], origin[1] + t_high * dirs[:, 1])
    _, d_low = layout.frame.to_road(origin[0] + t_low * dirs[:, 0], origin[1] + t_low * dirs[:, 1])
    raised_high = layout.surface_height(d_high) > 0
    raised_low = layout.surface_height(d_low) > 0
    kerb = np.where(d_low <= layout.curb_right, layout.curb_right, layout.curb_left)
    fraction = np.clip((d_high - kerb) / np.where(d_high == d_low, 1.0, d_high - d_low), 0.0, 1.0)
    t = np.where(raised_high, t_high, np.where(raised_low, t_high + fraction * (t_low - t_high), t_low))
    part = np.where(raised_high, RAISED_PART, np.where(raised_low, CURB_PART, ROAD_PART)).astype(np.int8)
    distance = t * np.linalg.norm(dirs, axis=1)
    t = np.where(down & (distance < GROUND_MAX_DISTANCE) & (t > NEAR), t, np.inf)
    return t, part


@dataclass
class Hits:
    """Nearest hit per ray."""

    t: np.ndarray  # (N,) ray parameter, inf where nothing was hit
    kind: np.ndarray  # (N,) int8: NONE, GROUND, BOX, CYLINDER, SPHERE
    index: np.ndarray  # (N,) primitive index within its kind
    ground_part: np.ndarray  # (N,) int8, meaningful where kind == GROUND


def cast(world: World, prims: Primitives, rays) -> Hits:
    """Nearest hit of every ray of ``rays`` (PinholeRays, SpinningLidarRays or ExhaustiveRays)."""
    origin, dirs = rays.origin, rays.dirs
    t, ground_part = _intersect_ground(world, origin, dirs)
    kind = np.where(np.isfinite(t), GROUND, NONE).astype(np.int8)
    index = np.zeros(len(dirs), np.int64)
    upright = np.zeros(len(prims.cyl_radius))
    kinds = (  # code, bounding boxes (centres, yaws, half sizes), intersection
        (BOX, prims.box_center, prims.box_yaw, prims.box_half, _intersect_boxes),
        (CYLINDER, prims.cyl_base + np.outer(prims.cyl_height / 2, [0.0, 0.0, 1.0]), upright,
         np.stack([prims.cyl_radius, prims.cyl_radius, prims.cyl_height / 2], axis=1), _intersect_cylinders),
        (SPHERE, prims.sph_center, np.zeros(len(prims.sph_radius)), np.repeat(prims.sph_radius[:, None], 3, axis=1), _intersect_spheres),
    )
    found = []
    for code, centers, yaws, halves, intersect in kinds:
        if len(centers) == 0:
            continue
        ray, primitive = rays.candidates(centers, yaws, halves)
        hit_t = intersect(origin, dirs[ray], prims, primitive)
        keep = np.isfinite(hit_t)
        found.append((code, ray[keep], primitive[keep], hit_t[keep]))
    for _, ray, _, hit_t in found:
        np.minimum.at(t, ray, hit_t)
    for code, ray, primitive, hit_t in found:
        won = hit_t == t[ray]
        kind[ray[won]] = code
        index[ray[won]] = primitive[won]
    return Hits(t=t, kind=kind, index=index, ground_part=ground_part)


# ----------------------------------------------------------------------------------------------
# Texturing and shading
# ----------------------------------------------------------------------------------------------


def _hash01(ix: np.ndarray, iy: np.ndarray, seed: int) -> np.ndarray:  # ints -> [0, 1) floats
    """Integer hash of lattice points (uint32 arithmetic wraps by design)."""
    h = ix.astype(np.int64).astype(np.uint32) * np.uint32(0x27D4EB2D)
    h ^= iy.astype(np.int64).astype(np.uint32) * np.uint32(0x165667B1)
    h ^= np.uint32(seed & 0xFFFFFFFF)
    h ^= h >> np.uint32(15)
    h *= np.uint32(0x2C1B3C6D)
    h ^= h >> np.uint32(12)
    h *= np.uint32(0x297A2D39)
    h ^= h >> np.uint32(15)
    return h.astype(np.float64) / 4294967296.0


def _value_noise(x: np.ndarray, y: np.ndarray, scale: float, seed: int) -> np.ndarray:  # [0, 1)
    """Bilinear value noise with lattice spacing ``scale`` metres."""
    fx, fy = x / scale, y / scale
    ix, iy = np.floor(fx), np.floor(fy)
    tx, ty = fx - ix, fy - iy
    tx, ty = tx * tx * (3 - 2 * tx), ty * ty * (3 - 2 * ty)
    n00, n10 = _hash01(ix, iy, seed), _hash01(ix + 1, iy, seed)
    n01, n11 = _hash01(ix, iy + 1, seed), _hash01(ix + 1, iy + 1, seed)
    return (n00 * (1 - tx) + n10 * tx) * (1 - ty) + (n01 * (1 - tx) + n11 * tx) * ty


def _in(values: np.ndarray, low: float, high: float) -> np.ndarray:
    return (values >= low) & (values <= high)


def _shade_ground(world: World, points, part, footprint) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Colour (M,3), normal (M,3), semantic id (M,) of ground hits."""
    layout, seed = world.layout, world.texture_seed
    s, d = layout.frame.to_road(points[:, 0], points[:, 1])
    count = len(points)
    normal = np.tile([0.0, 0.0, 1.0], (count, 1))
    grain = 0.75 * _value_noise(points[:, 0], points[:, 1], 0.6, seed) + 0.25 * _value_noise(points[:, 0], points[:, 1], 4.0, seed + 1)
    color = world.asphalt[None, :] * (0.85 + 0.3 * grain)[:, None]
    semantic = np.full(count, SEM["road"], np.uint8)
    coverage = np.zeros(count)
    paint = np.zeros((count, 3))
    for marking in layout.markings():  # analytic anti-aliasing across the line
        across = np.clip((0.5 * marking.width + 0.5 * footprint - np.abs(d - marking.d)) / np.maximum(footprint, 1e-3), 0.0, 1.0)
        if marking.dashed:
            across = across * (np.mod(s - marking.dash_phase, marking.dash_period) < marking.dash_length)
        stronger = across > coverage
        coverage = np.where(stronger, across, coverage)
        paint[stronger] = marking.color
    road = part == ROAD_PART
    color = np.where(road[:, None], color * (1 - coverage[:, None]) + paint * (0.9 + 0.1 * grain)[:, None] * coverage[:, None], color)
    semantic[road & (coverage >= 0.5)] = SEM["lane_marking"]
    raised = part == RAISED_PART
    sidewalk = raised & (_in(d, layout.curb_right - layout.sidewalk_right, layout.curb_right) | _in(d, layout.curb_left, layout.curb_left + layout.sidewalk_left))
    joints = (np.mod(s, 1.2) < 0.06) | (np.mod(d, 1.2) < 0.06)
    paving = np.array([0.62, 0.60, 0.57]) * (0.9 + 0.15 * grain)[:, None] * np.where(joints, 0.8, 1.0)[:, None]
    color = np.where(sidewalk[:, None], paving, color)
    semantic[sidewalk] = SEM["sidewalk"]
    grass = raised & ~sidewalk
    color = np.where(grass[:, None], np.array([0.24, 0.38, 0.16]) * (0.7 + 0.5 * grain)[:, None], color)
    semantic[grass] = SEM["vegetation"]
    curb = part == CURB_PART
    _, _, heading = layout.frame.to_world(s, 0.0)
    towards_road = np.where(d < 0, 1.0, -1.0)  # the kerb face looks towards the road
    normal[curb] = np.stack([-np.sin(heading) * towards_road, np.cos(heading) * towards_road, 0 * heading], 1)[curb]
    color[curb] = [0.72, 0.72, 0.70]
    semantic[curb] = SEM["sidewalk"]
    return color, normal, semantic


def _shade_boxes(world: World, prims: Primitives, points, box) -> tuple[np.ndarray, np.ndarray]:
    """Colour (M,3) and world normal (M,3) of box hits: facades with windows, textured vehicles."""
    local = _rotate_to_local(points - prims.box_center[box], prims.box_yaw[box])  # (M,3)
    half = prims.box_half[box]
    axis = np.argmax(np.abs(local) / half, axis=1)
    sign = np.sign(local[np.arange(len(box)), axis])
    normal_local = np.zeros_like(local)
    normal_local[np.arange(len(box)), axis] = sign
    cos_y, sin_y = np.cos(prims.box_yaw[box]), np.sin(prims.box_yaw[box])
    normal = np.stack([cos_y * normal_local[:, 0] - sin_y * normal_local[:, 1], sin_y * normal_local[:, 0] + cos_y * normal_local[:, 1], normal_local[:, 2]], 1)
    color = prims.box_color[box].copy()
    material = prims.box_material[box]
    height = local[:, 2] + half[:, 2]  # above the box base
    vertical = axis != 2

    facade = np.flatnonzero((material == FACADE) & vertical)
    if facade.size:
        spacing, floor, texture = prims.box_pattern[box[facade]].T
        face_axis, face_half, face_height = axis[facade], half[facade], height[facade]
        along = np.where(face_axis == 0, local[facade, 1] + face_half[:, 1], local[facade, 0] + face_half[:, 0])
        face_length = np.where(face_axis == 0, 2 * face_half[:, 1], 2 * face_half[:, 0])
        column, level = np.floor(along / spacing), np.floor(face_height / floor)
        upper = _in(np.mod(along / spacing, 1), 0.22, 0.78) & _in(np.mod(face_height / floor, 1), 0.28, 0.78)
        upper &= (face_height > floor) & (face_height < 2 * face_half[:, 2] - 0.6)
        shop = _in(face_height, 0.4, floor - 0.5) & _in(np.mod(along / (2 * spacing), 1), 0.1, 0.9)
        window = (upper | shop) & _in(along, 0.5, face_length - 0.5)
        tone = _hash01(column + 97 * texture, level, world.texture_seed)
        glass = np.array([0.14, 0.18, 0.24])[None, :] * (0.7 + 0.8 * tone)[:, None] + 0.08
        glass = np.where((tone > 0.92)[:, None], np.array([0.95, 0.82, 0.5]), glass)  # a few lit rooms
        wall_noise = 0.9 + 0.12 * _value_noise(along + 31 * texture, face_height, 0.8, world.texture_seed + 2)
        color[facade] = np.where(window[:, None], glass, color[facade] * wall_noise[:, None])
    roofs = (material == FACADE) & ~vertical
    color[roofs] = 0.45 * color[roofs] + 0.2

    vehicle = np.isin(material, (CAR, VAN, BUS, TRUCK))
    if vehicle.any():
        rel_height = height / (2 * half[:, 2])
        rel_length = local[:, 0] / half[:, 0]
        rel_width = np.abs(local[:, 1]) / half[:, 1]
        heavy = (material == BUS) | (material == TRUCK)
        side = vehicle & (axis == 1)
        front = vehicle & (axis == 0) & (sign > 0)
        rear = vehicle & (axis == 0) & (sign < 0)
        light_band = _in(rel_height, 0.36, 0.48)
        glass = side & np.where(material == BUS, _in(rel_height, 0.45, 0.88) & (np.abs(rel_length) < 0.95) & (np.mod(local[:, 0] + half[:, 0], 1.6) > 0.15),
                                np.where(material == TRUCK, _in(rel_height, 0.6, 0.88) & (rel_length > 0.72), _in(rel_height, 0.58, 0.9) & (np.abs(rel_length) < 0.75)))
        glass |= front & np.where(heavy, _in(rel_height, 0.45, 0.9), _in(rel_height, 0.55, 0.88)) & (rel_width < 0.88)
        glass |= rear & (material != TRUCK) & _in(rel_height, 0.58, 0.88) & (rel_width < 0.82)
        wheel_x = np.where(heavy, 0.75, 0.68) * half[:, 0]
        wheel = side & (np.minimum(np.hypot(local[:, 0] - wheel_x, height - 0.35), np.hypot(local[:, 0] + wheel_x, height - 0.35)) < 0.34)
        bumper = vehicle & vertical & (rel_height < 0.16)
        color = np.where(bumper[:, None], 0.25 * color + 0.05, color)
        color = np.where(glass[:, None], np.array([0.09, 0.11, 0.14]), color)
        color = np.where((front & light_band & _in(rel_width, 0.55, 0.9))[:, None], np.array([0.95, 0.93, 0.8]), color)
        color = np.where((rear & light_band & _in(rel_width, 0.6, 0.92))[:, None], np.array([0.75, 0.05, 0.04]), color)
        color = np.where(wheel[:, None], np.array([0.04, 0.04, 0.04]), color)
    return color, normal


@dataclass
class RenderedView:
    """One rendered camera view."""

    rgb: np.ndarray  # (H,W,3) uint8
    depth: np.ndarray  # (H,W) float32, metres along the optical axis, 0 on sky
    semantics: np.ndarray  # (H,W) uint8 ids into SEMANTIC_CLASSES
    instances: np.ndarray  # (H,W) int32, 0 or 1 + track index
    sky: np.ndarray  # (H,W) bool


def render_view(world: World, prims: Primitives, cam_to_world: np.ndarray, K: np.ndarray, width: int, height: int) -> RenderedView:
    """Render RGB, depth, semantics, instances and the sky mask of one pinhole camera."""
    rays = PinholeRays(np.asarray(cam_to_world, np.float64), np.asarray(K, np.float64), width, height)
    hits = cast(world, prims, rays)
    count = len(rays.dirs)
    color = np.zeros((count, 3))
    normal = np.tile([0.0, 0.0, 1.0], (count, 1))
    semantic = np.full(count, SEM["sky"], np.uint8)
    instance = np.zeros(count, np.int32)
    hit = hits.kind != NONE
    points = rays.origin + np.where(hit, hits.t, 0.0)[:, None] * rays.dirs  # (N,3)

    ground = hits.kind == GROUND
    footprint = hits.t[ground] * rays.pixel_angle  # metres per pixel across the view ray
    color[ground], normal[ground], semantic[ground] = _shade_ground(world, points[ground], hits.ground_part[ground], footprint)

    boxes = hits.kind == BOX
    box = hits.index[boxes]
    color[boxes], normal[boxes] = _shade_boxes(world, prims, points[boxes], box)
    semantic[boxes] = prims.box_semantic[box]
    instance[boxes] = prims.box_instance[box]

    cylinders = hits.kind == CYLINDER
    cyl = hits.index[cylinders]
    radial = points[cylinders, :2] - prims.cyl_base[cyl, :2]
    normal[cylinders] = np.concatenate([radial / prims.cyl_radius[cyl, None], np.zeros((len(cyl), 1))], axis=1)
    bark = 0.85 + 0.3 * _value_noise(np.arctan2(radial[:, 1], radial[:, 0]) * 0.3, points[cylinders, 2], 0.15, world.texture_seed + 3)
    color[cylinders] = prims.cyl_color[cyl] * np.where(prims.cyl_semantic[cyl] == SEM["vegetation"], bark, 1.0)[:, None]
    semantic[cylinders] = prims.cyl_semantic[cyl]

    spheres = hits.kind == SPHERE
    sph = hits.index[spheres]
    normal[spheres] = (points[spheres] - prims.sph_center[sph]) / prims.sph_radius[sph, None]
    p = points[spheres]
    leaves = 0.6 + 0.7 * _value_noise(p[:, 0] + p[:, 2], p[:, 1] - p[:, 2], 0.35, world.texture_seed + 4)
    color[spheres] = prims.sph_color[sph] * leaves[:, None]
    semantic[spheres] = SEM["vegetation"]

    light = AMBIENT + DIFFUSE * np.clip(normal @ world.sun, 0.0, None)
    color = color * light[:, None]
    length = np.linalg.norm(rays.dirs, axis=1)
    haze = 1.0 - np.exp(-np.where(hit, hits.t, 0.0) * length / HAZE_DISTANCE)
    color = color * (1 - haze[:, None]) + world.sky_horizon * haze[:, None]
    up = np.clip(rays.dirs[:, 2] / length, 0.0, 1.0) ** 0.6
    sky_color = world.sky_horizon * (1 - up[:, None]) + world.sky_zenith * up[:, None]
    color = np.where(hit[:, None], color, sky_color)

    shape = (height, width)
    return RenderedView(
        rgb=np.clip(np.round(color * 255.0), 0, 255).astype(np.uint8).reshape(height, width, 3),
        depth=np.where(hit, hits.t, 0.0).astype(np.float32).reshape(shape),
        semantics=semantic.reshape(shape),
        instances=instance.reshape(shape),
        sky=(~hit).reshape(shape),
    )
