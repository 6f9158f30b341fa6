"""The procedural driving world: road, roadside structure, parked and moving vehicles, ego motion.

``build_world(seed)`` draws everything from one ``numpy.random.Generator(seed)`` in a fixed order,
so a seed always gives the same world. The world does not depend on the image size or the
number of frames; vehicle placements are checked over ``horizon`` seconds (at least 3.9 s, the
40-frame segment), so that no vehicle ever enters the corridor of the evaluation cameras (the
ego lane and the two lanes to its left, up to 6 m left of the ego) nor collides with another.

Primitives (all analytic, ray-cast by ``render.py``): yaw-rotated boxes (buildings, vehicles,
lamp arms), vertical cylinders (poles, tree trunks) and spheres (tree crowns); the ground is the
road height field of ``road.py``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from recondreamer.scene.types import SEMANTIC_CLASSES
from recondreamer.sources.synthetic.road import RoadLayout, sample_layout

SEM = {name: index for index, name in enumerate(SEMANTIC_CLASSES)}

# Box materials: how render.py textures a box.
PLAIN, FACADE, CAR, VAN, BUS, TRUCK = range(6)
VEHICLE_KINDS = {"car": CAR, "van": VAN, "bus": BUS, "truck": TRUCK}
MIN_HORIZON_S = 3.9  # seconds of a 40-frame, 10 Hz segment: worlds are valid at least this long
LEAD_GAP_EGO_LANE = 12.0  # metres from the cameras to the rear of a vehicle in the ego lane
LEAD_GAP_LEFT_LANES = 10.0  # same for the two lanes left of the ego (novel cameras drive there)
KIND_CHOICES = ("car",) * 5 + ("van",) * 3 + ("bus", "truck")  # size classes after the first three
ROLE_CHOICES = ("lead",) * 3 + ("slower", "oncoming", "oncoming", "overtake")  # roles after the first five
SAME_LANE_GAP = 4.0  # metres between consecutive vehicles of one lane
BODY_COLORS = np.array(
    [
        [0.92, 0.92, 0.92],  # white
        [0.72, 0.73, 0.75],  # silver
        [0.08, 0.08, 0.09],  # black
        [0.32, 0.33, 0.35],  # dark grey
        [0.70, 0.08, 0.07],  # red
        [0.10, 0.22, 0.62],  # blue
        [0.06, 0.12, 0.30],  # dark blue
        [0.12, 0.38, 0.18],  # green
        [0.90, 0.72, 0.10],  # yellow
        [0.85, 0.40, 0.08],  # orange
        [0.45, 0.28, 0.18],  # brown
    ]
)
FACADE_COLORS = np.array(
    [
        [0.80, 0.72, 0.58],  # sandstone
        [0.62, 0.30, 0.22],  # brick
        [0.66, 0.66, 0.64],  # concrete
        [0.88, 0.86, 0.80],  # white render
        [0.50, 0.44, 0.38],  # brown
        [0.52, 0.58, 0.64],  # blue-grey
        [0.78, 0.62, 0.46],  # ochre
    ]
)


@dataclass(frozen=True)
class VehicleTrack:
    """A vehicle moving at constant speed along a lane (speed 0: parked)."""

    track_id: str
    kind: str  # "car" | "van" | "bus" | "truck"
    size: np.ndarray  # (3,) length, width, height metres
    color: np.ndarray  # (3,) RGB in [0, 1]
    lane_d: float  # road d of the lane it drives in
    s0: float  # road s of its centre at time 0
    speed: float  # m/s along +s (negative: oncoming)
    reverse: bool  # heading opposite to +s (oncoming, or parked facing backwards)

    def s_at(self, time: np.ndarray | float) -> np.ndarray:
        return self.s0 + self.speed * np.asarray(time, dtype=np.float64)


@dataclass
class Primitives:
    """Struct-of-arrays snapshot of every primitive at one time."""

    box_center: np.ndarray  # (B,3)
    box_yaw: np.ndarray  # (B,)
    box_half: np.ndarray  # (B,3) half length, half width, half height
    box_color: np.ndarray  # (B,3)
    box_material: np.ndarray  # (B,) int
    box_pattern: np.ndarray  # (B,3) facade: window spacing, floor height, texture id
    box_semantic: np.ndarray  # (B,) uint8
    box_instance: np.ndarray  # (B,) int32, 0 or 1 + track index
    cyl_base: np.ndarray  # (C,3) centre of the bottom disc
    cyl_radius: np.ndarray  # (C,)
    cyl_height: np.ndarray  # (C,)
    cyl_color: np.ndarray  # (C,3)
    cyl_semantic: np.ndarray  # (C,) uint8
    sph_center: np.ndarray  # (S,3)
    sph_radius: np.ndarray  # (S,)
    sph_color: np.ndarray  # (S,3)


@dataclass
class World:
    """One procedural driving world (see the module docstring)."""

    seed: int
    layout: RoadLayout
    ego_speed: float  # m/s along the ego lane centre
    horizon: float  # seconds over which the vehicle constraints were checked
    tracks: list[VehicleTrack]  # moving vehicles first, then parked ones
    static: Primitives  # buildings, lamps, trees (no vehicles)
    sun: np.ndarray  # (3,) unit vector towards the sun, world frame
    sky_zenith: np.ndarray  # (3,)
    sky_horizon: np.ndarray  # (3,)
    asphalt: np.ndarray  # (3,)
    texture_seed: int
    s_extent: tuple[float, float]  # road s range covered by buildings and map polylines

    @property
    def track_ids(self) -> list[str]:
        return [track.track_id for track in self.tracks]

    def ego_pose(self, time: float) -> np.ndarray:  # (4,4) ego-to-world
        x, y, heading = self.layout.frame.to_world(self.ego_speed * time, 0.0)
        pose = np.eye(4)
        cos_h, sin_h = np.cos(heading), np.sin(heading)
        pose[:3, :3] = [[cos_h, -sin_h, 0.0], [sin_h, cos_h, 0.0], [0.0, 0.0, 1.0]]
        pose[:3, 3] = [x, y, 0.0]
        return pose

    def vehicle_poses(self, time: float) -> tuple[np.ndarray, np.ndarray]:  # (V,3) centres, (V,) yaws
        frame = self.layout.frame
        s = np.array([track.s_at(time) for track in self.tracks])
        d = np.array([track.lane_d for track in self.tracks])
        x, y, heading = frame.to_world(s, d)
        heights = np.array([track.size[2] for track in self.tracks])
        reverse = np.array([track.reverse for track in self.tracks])
        yaw = np.where(reverse, heading + np.pi, heading)
        return np.stack([x, y, heights / 2.0], axis=1), np.arctan2(np.sin(yaw), np.cos(yaw))

    def primitives_at(self, time: float) -> Primitives:
        """Static primitives plus every vehicle at ``time``."""
        centers, yaws = self.vehicle_poses(time)
        count = len(self.tracks)
        st = self.static
        return Primitives(
            box_center=np.concatenate([centers, st.box_center]),
            box_yaw=np.concatenate([yaws, st.box_yaw]),
            box_half=np.concatenate([np.array([t.size for t in self.tracks]) / 2.0, st.box_half]),
            box_color=np.concatenate([np.array([t.color for t in self.tracks]), st.box_color]),
            box_material=np.concatenate([np.array([VEHICLE_KINDS[t.kind] for t in self.tracks]), st.box_material]),
            box_pattern=np.concatenate([np.zeros((count, 3)), st.box_pattern]),
            box_semantic=np.concatenate([np.full(count, SEM["vehicle"], np.uint8), st.box_semantic]),
            box_instance=np.concatenate([np.arange(1, count + 1, dtype=np.int32), st.box_instance]),
            cyl_base=st.cyl_base,
            cyl_radius=st.cyl_radius,
            cyl_height=st.cyl_height,
            cyl_color=st.cyl_color,
            cyl_semantic=st.cyl_semantic,
            sph_center=st.sph_center,
            sph_radius=st.sph_radius,
            sph_color=st.sph_color,
        )


# ----------------------------------------------------------------------------------------------
# Sampling
# ----------------------------------------------------------------------------------------------


def _vehicle_size(rng: np.random.Generator, kind: str) -> np.ndarray:  # (3,)
    ranges = {
        "car": ((4.0, 4.8), (1.75, 1.9), (1.4, 1.55)),
        "van": ((4.7, 5.3), (1.9, 2.05), (1.75, 2.1)),
        "bus": ((10.0, 12.0), (2.5, 2.55), (3.0, 3.3)),
        "truck": ((7.0, 9.5), (2.4, 2.5), (3.0, 3.6)),
    }[kind]
    return np.array([rng.uniform(low, high) for low, high in ranges])


def _vehicle_color(rng: np.random.Generator) -> np.ndarray:  # (3,)
    base = BODY_COLORS[rng.integers(len(BODY_COLORS))]
    return np.clip(base + rng.uniform(-0.05, 0.05, 3), 0.02, 0.98)


def _gaps_ok(track: VehicleTrack, others: list[VehicleTrack], times: np.ndarray) -> bool:
    """No overlap with vehicles of the same lane at the window ends (motion is linear: enough)."""
    for other in others:
        if abs(other.lane_d - track.lane_d) > 0.5:
            continue
        gap = other.s_at(times) - track.s_at(times)  # (2,)
        clearance = 0.5 * (other.size[0] + track.size[0]) + SAME_LANE_GAP
        if not (np.all(gap >= clearance) or np.all(gap <= -clearance)):
            return False
    return True


def _sample_moving(
    rng: np.random.Generator, layout: RoadLayout, ego_speed: float, horizon: float, camera_forward: float
) -> list[VehicleTrack]:
    """At least 8 moving vehicles in 3+ size classes: leaders, overtakers, slower ones, oncoming."""
    count = int(rng.integers(10, 15))
    heavy = "bus" if rng.random() < 0.5 else "truck"
    kinds = ["car", "van", heavy] + [str(kind) for kind in rng.choice(KIND_CHOICES, 3 * count)]
    first_roles = ["overtake", "oncoming", "oncoming", "lead", "lead"]
    roles = [first_roles[i] for i in rng.permutation(len(first_roles))] + [str(role) for role in rng.choice(ROLE_CHOICES, 3 * count)]
    times = np.array([0.0, horizon])
    camera_s = ego_speed * times + camera_forward  # (2,) road s of the cameras
    lanes = layout.forward_lane_centers
    tracks: list[VehicleTrack] = []
    for kind, role in zip(kinds, roles):  # spare candidates replace those that found no room
        if len(tracks) == count:
            break
        size = _vehicle_size(rng, kind)
        color = _vehicle_color(rng)
        half_length = size[0] / 2.0
        for _attempt in range(60):
            if role == "lead":  # ego lane or the two lanes to its left: always well ahead of the cameras
                lane = int(rng.integers(1, 4))
                min_gap = LEAD_GAP_EGO_LANE if lane == 1 else LEAD_GAP_LEFT_LANES
                speed = ego_speed + rng.uniform(-2.5, 4.0)
                s0 = camera_s[0] + half_length + rng.uniform(min_gap, 55.0)
                track = VehicleTrack("", kind, size, color, float(lanes[lane]), s0, speed, False)
                if np.any(track.s_at(times) - half_length - camera_s < min_gap):
                    continue
            elif role == "overtake":  # right lane, starts beside or behind the cameras, ends ahead
                speed = ego_speed + rng.uniform(3.0, 7.0)
                s0 = camera_s[0] + rng.uniform(-12.0, 4.0)
                track = VehicleTrack("", kind, size, color, float(lanes[0]), s0, speed, False)
                if track.s_at(horizon) - half_length - camera_s[1] < 3.0:
                    continue
            elif role == "slower":  # right lane, ahead, slower than the ego
                speed = ego_speed + rng.uniform(-4.0, -1.0)
                s0 = camera_s[0] + half_length + rng.uniform(15.0, 60.0)
                track = VehicleTrack("", kind, size, color, float(lanes[0]), s0, speed, False)
                if np.any(track.s_at(times) - half_length - camera_s < 3.0):
                    continue
            else:  # oncoming lanes, driving towards the ego
                lane_d = float(rng.choice(layout.oncoming_lane_centers))
                speed = -rng.uniform(8.0, 13.0)
                s0 = camera_s[0] + rng.uniform(15.0, 130.0)
                track = VehicleTrack("", kind, size, color, lane_d, s0, speed, True)
            if _gaps_ok(track, tracks, times):
                tracks.append(track)
                break
    return tracks


def _sample_parked(rng: np.random.Generator, layout: RoadLayout, s_start: float, s_end: float) -> list[VehicleTrack]:
    """Cars and vans in the right parking strip, with empty spaces."""
    tracks: list[VehicleTrack] = []
    s = s_start + rng.uniform(0.0, 6.0)
    while s < s_end:
        kind = "car" if rng.random() < 0.7 else "van"
        size = _vehicle_size(rng, kind)
        if rng.random() < 0.75:
            d = layout.parking_center + rng.uniform(-0.12, 0.12)
            track = VehicleTrack("", kind, size, _vehicle_color(rng), d, s + size[0] / 2.0, 0.0, bool(rng.random() < 0.2))
            tracks.append(track)
        s += size[0] + rng.uniform(1.0, 4.0)
    return tracks


class _StaticBuilder:
    """Collects static primitives in lists and freezes them into arrays."""

    def __init__(self) -> None:
        self.boxes: list[tuple] = []
        self.cylinders: list[tuple] = []
        self.spheres: list[tuple] = []

    def box(self, center, yaw, size, color, material, semantic, pattern=(0.0, 0.0, 0.0)) -> None:
        self.boxes.append((center, yaw, np.asarray(size) / 2.0, color, material, pattern, semantic))

    def freeze(self) -> Primitives:
        def stack(rows, index, width=None, dtype=np.float64):
            values = [row[index] for row in rows]
            if not values:
                return np.zeros((0, width) if width else (0,), dtype)
            return np.asarray(values, dtype=dtype)

        b, c, s = self.boxes, self.cylinders, self.spheres
        return Primitives(
            box_center=stack(b, 0, 3),
            box_yaw=stack(b, 1),
            box_half=stack(b, 2, 3),
            box_color=stack(b, 3, 3),
            box_material=stack(b, 4, dtype=np.int64),
            box_pattern=stack(b, 5, 3),
            box_semantic=stack(b, 6, dtype=np.uint8),
            box_instance=np.zeros(len(b), np.int32),
            cyl_base=stack(c, 0, 3),
            cyl_radius=stack(c, 1),
            cyl_height=stack(c, 2),
            cyl_color=stack(c, 3, 3),
            cyl_semantic=stack(c, 4, dtype=np.uint8),
            sph_center=stack(s, 0, 3),
            sph_radius=stack(s, 1),
            sph_color=stack(s, 2, 3),
        )


def _place(layout: RoadLayout, s: float, d: float, z: float) -> tuple[np.ndarray, float]:
    x, y, heading = layout.frame.to_world(s, d)
    return np.array([float(x), float(y), z]), float(heading)


def _sample_static(rng: np.random.Generator, layout: RoadLayout, s_start: float, s_end: float) -> Primitives:
    """Buildings with window facades, street lamps and trees on both sides of the road."""
    builder = _StaticBuilder()
    for side in (-1.0, 1.0):  # right, left
        curb = layout.curb_right if side < 0 else layout.curb_left
        sidewalk = layout.sidewalk_right if side < 0 else layout.sidewalk_left
        s = s_start
        while s < s_end:  # buildings
            length = rng.uniform(8.0, 26.0)
            depth = rng.uniform(8.0, 16.0)
            height = rng.uniform(5.0, 12.0) if rng.random() < 0.5 else rng.uniform(12.0, 28.0)
            setback = rng.uniform(0.3, 2.5)
            d = curb + side * (sidewalk + setback + depth / 2.0)
            center, heading = _place(layout, s + length / 2.0, d, height / 2.0)
            color = np.clip(FACADE_COLORS[rng.integers(len(FACADE_COLORS))] + rng.uniform(-0.06, 0.06, 3), 0, 1)
            pattern = (rng.uniform(2.4, 3.6), rng.uniform(3.0, 3.6), float(rng.integers(1 << 20)))
            builder.box(center, heading, (length, depth, height), color, FACADE, SEM["building"], pattern)
            s += length + (0.0 if rng.random() < 0.4 else rng.uniform(2.0, 8.0))
        lamp_s = []
        s = s_start + rng.uniform(0.0, 20.0)
        while s < s_end:  # street lamps: pole, arm over the road, lamp head
            height = rng.uniform(6.5, 8.0)
            d = curb - side * 0.5
            base, heading = _place(layout, s, d, 0.0)
            builder.cylinders.append((base, 0.1, height, np.array([0.45, 0.46, 0.48]), SEM["pole"]))
            arm_center, _ = _place(layout, s, d + side * 0.9, height - 0.1)
            builder.box(arm_center, heading + np.pi / 2.0, (1.8, 0.12, 0.12), np.array([0.45, 0.46, 0.48]), PLAIN, SEM["pole"])
            head_center, _ = _place(layout, s, d + side * 1.7, height - 0.25)
            builder.box(head_center, heading, (0.6, 0.35, 0.18), np.array([0.85, 0.85, 0.75]), PLAIN, SEM["pole"])
            lamp_s.append(s)
            s += rng.uniform(22.0, 32.0)
        s = s_start + rng.uniform(0.0, 8.0)
        while s < s_end:  # trees on the sidewalk, clear of the lamps
            if rng.random() < 0.7 and min(abs(s - np.array(lamp_s)), default=99.0) > 2.5:
                trunk_height = rng.uniform(2.6, 3.4)
                crown = rng.uniform(1.3, 2.3)
                base, _ = _place(layout, s, curb - side * 1.0, 0.0)
                builder.cylinders.append((base, rng.uniform(0.12, 0.22), trunk_height + 0.3, np.array([0.35, 0.24, 0.15]), SEM["vegetation"]))
                green = np.array([0.18, 0.42, 0.14]) * rng.uniform(0.7, 1.2) + rng.uniform(-0.03, 0.03, 3)
                builder.spheres.append((base + np.array([0.0, 0.0, trunk_height + 0.8 * crown]), crown, np.clip(green, 0, 1)))
            s += rng.uniform(7.0, 15.0)
    return builder.freeze()


def build_world(seed: int, horizon: float = MIN_HORIZON_S, camera_forward: float = 1.5) -> World:
    """The world of ``seed``; vehicle constraints hold for ``max(horizon, 3.9)`` seconds."""
    rng = np.random.Generator(np.random.PCG64(seed))
    horizon = max(float(horizon), MIN_HORIZON_S)
    layout = sample_layout(rng)
    ego_speed = float(rng.uniform(8.0, 12.0))
    s_extent = (-40.0, ego_speed * horizon + 180.0)
    moving = _sample_moving(rng, layout, ego_speed, horizon, camera_forward)
    parked = _sample_parked(rng, layout, -15.0, ego_speed * horizon + 90.0)
    tracks = [dataclasses.replace(track, track_id=f"vehicle-{i:02d}") for i, track in enumerate(moving)]
    tracks += [dataclasses.replace(track, track_id=f"parked-{i:02d}") for i, track in enumerate(parked)]
    static = _sample_static(rng, layout, *s_extent)
    elevation = np.radians(rng.uniform(25.0, 60.0))
    azimuth = rng.uniform(0.0, 2.0 * np.pi)
    sun = np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
    return World(
        seed=seed,
        layout=layout,
        ego_speed=ego_speed,
        horizon=horizon,
        tracks=tracks,
        static=static,
        sun=sun,
        sky_zenith=np.clip(np.array([0.22, 0.42, 0.78]) + rng.uniform(-0.06, 0.06, 3), 0, 1),
        sky_horizon=np.clip(np.array([0.78, 0.84, 0.92]) + rng.uniform(-0.04, 0.04, 3), 0, 1),
        asphalt=np.array([0.31, 0.31, 0.33]) * rng.uniform(0.85, 1.15),
        texture_seed=int(rng.integers(1 << 30)),
        s_extent=s_extent,
    )

