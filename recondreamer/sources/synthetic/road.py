"""Road geometry: a straight or constant-curvature road, its lanes, markings and kerbs.

Everything on the road is placed in road coordinates ``(s, d)``: ``s`` metres along the ego lane
centre line, ``d`` metres to its left. The centre line passes through the world origin heading
+x (world = ego frame of frame 0, the ego starts on its lane centre). With curvature ``kappa``
the centre line is a circular arc of radius ``1/kappa`` (positive = turning left), so a lateral
move along a frame's ego left axis changes ``d`` and keeps ``s`` exactly: the arc's normals meet
at its centre.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

STRAIGHT = 1e-9  # |kappa| below this is treated as a straight road


@dataclass(frozen=True)
class RoadFrame:
    """Conversions between world (x, y) and road (s, d) coordinates."""

    kappa: float  # 1/m, signed curvature of the centre line

    def to_world(self, s: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World x, y and heading (radians) of road points (any matching shapes)."""
        s = np.asarray(s, dtype=np.float64)
        d = np.asarray(d, dtype=np.float64)
        if abs(self.kappa) < STRAIGHT:
            return s + 0.0 * d, d + 0.0 * s, np.zeros(np.broadcast(s, d).shape)
        radius = 1.0 / self.kappa
        heading = self.kappa * s
        x = radius * np.sin(heading) - d * np.sin(heading)
        y = radius * (1.0 - np.cos(heading)) + d * np.cos(heading)
        return x, y, heading + 0.0 * d

    def to_road(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Road s, d of world points (any matching shapes)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if abs(self.kappa) < STRAIGHT:
            return x + 0.0 * y, y + 0.0 * x
        radius = 1.0 / self.kappa
        sign = np.sign(radius)
        angle = np.arctan2(sign * x, sign * (radius - y))
        distance = np.hypot(x, y - radius)
        return radius * angle, radius - sign * distance


@dataclass(frozen=True)
class Marking:
    """One painted line along the road at constant ``d``."""

    d: float  # metres left of the ego lane centre
    width: float  # metres
    dashed: bool
    color: tuple[float, float, float]  # linear RGB in [0, 1]
    dash_length: float = 3.0  # metres painted
    dash_period: float = 9.0  # metres from one dash start to the next
    dash_phase: float = 0.0  # metres


WHITE = (0.92, 0.92, 0.9)
YELLOW = (0.93, 0.76, 0.2)


@dataclass(frozen=True)
class RoadLayout:
    """Cross-section of the road, constant along it.

    From right to left: right sidewalk, kerb, parking strip, one forward lane right of the ego,
    the ego lane (d = 0), two forward lanes left of it (the evaluation cameras' corridor),
    a centre divider, ``oncoming_lanes`` oncoming lanes, a shoulder, kerb, left sidewalk.
    """

    frame: RoadFrame
    lane_width: float
    parking_width: float
    median_width: float
    oncoming_lanes: int
    shoulder_width: float
    sidewalk_right: float
    sidewalk_left: float
    curb_height: float
    dash_phase: float

    @property
    def forward_lane_centers(self) -> np.ndarray:  # (4,) d of the forward lanes, right to left
        return self.lane_width * np.arange(-1, 3, dtype=np.float64)

    @property
    def divider(self) -> float:  # d of the centre of the divider between the directions
        return 2.5 * self.lane_width + 0.5 * self.median_width

    @property
    def oncoming_lane_centers(self) -> np.ndarray:  # (n,) d of the oncoming lanes, right to left
        start = 2.5 * self.lane_width + self.median_width
        return start + self.lane_width * (np.arange(self.oncoming_lanes) + 0.5)

    @property
    def parking_center(self) -> float:
        return -1.5 * self.lane_width - 0.5 * self.parking_width

    @property
    def curb_right(self) -> float:  # d of the right kerb (road edge)
        return -1.5 * self.lane_width - self.parking_width

    @property
    def curb_left(self) -> float:  # d of the left kerb (road edge)
        return 2.5 * self.lane_width + self.median_width + self.oncoming_lanes * self.lane_width + self.shoulder_width

    @property
    def num_lanes(self) -> int:
        return 4 + self.oncoming_lanes

    def markings(self) -> list[Marking]:
        """Painted lines: dashed lane lines, solid edge lines, a double solid divider."""
        lw = self.lane_width
        dashed = {"dashed": True, "color": WHITE, "dash_phase": self.dash_phase}
        lines = [Marking(-1.5 * lw, 0.15, dashed=False, color=WHITE)]
        lines += [Marking(offset * lw, 0.12, **dashed) for offset in (-0.5, 0.5, 1.5)]
        half_gap = max(0.5 * self.median_width - 0.08, 0.1)
        lines += [Marking(self.divider + side * half_gap, 0.12, dashed=False, color=YELLOW) for side in (-1.0, 1.0)]
        start = 2.5 * lw + self.median_width
        lines += [Marking(start + j * lw, 0.12, **dashed) for j in range(1, self.oncoming_lanes)]
        lines.append(Marking(self.curb_left - self.shoulder_width, 0.15, dashed=False, color=WHITE))
        return lines

    def surface_height(self, d: np.ndarray) -> np.ndarray:  # metres: 0 on the road, kerb height elsewhere
        d = np.asarray(d, dtype=np.float64)
        return np.where((d > self.curb_right) & (d < self.curb_left), 0.0, self.curb_height)


def sample_layout(rng: np.random.Generator) -> RoadLayout:
    """A random road cross-section and curvature (straight in about a third of the seeds)."""
    if rng.random() < 0.35:
        kappa = 0.0
    else:
        kappa = float(rng.choice([-1.0, 1.0]) * rng.uniform(1.0 / 700.0, 1.0 / 260.0))
    return RoadLayout(
        frame=RoadFrame(kappa),
        lane_width=float(rng.uniform(3.4, 3.7)),
        parking_width=float(rng.uniform(2.3, 2.6)),
        median_width=float(rng.choice([0.3, 0.6, 1.2])),
        oncoming_lanes=int(rng.integers(1, 4)),
        shoulder_width=float(rng.uniform(0.4, 1.0)),
        sidewalk_right=float(rng.uniform(3.0, 4.5)),
        sidewalk_left=float(rng.uniform(3.0, 4.5)),
        curb_height=0.15,
        dash_phase=float(rng.uniform(0.0, 9.0)),
    )
