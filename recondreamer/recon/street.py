"""Street Gaussians (Yan et al. 2024): static background + one Gaussian set per tracked vehicle.

Vehicle Gaussians live in their box frame; at time t each is moved by its track's box pose
(``obj_to_world``), interpolated between frames (slerp of rotation, lerp of translation). A
vehicle is hidden at times its track has no box. All sets share one ``GaussianSet`` with an
``owner`` row (-1 = background, k = track k), so density control treats them alike while
cloning and splitting happen in each Gaussian's own frame. The sky texture of the base model is
composited behind. Box poses come from the scene (ground truth on synthetic scenes; the paper's
box-pose refinement is not modelled).
"""

from __future__ import annotations

import numpy as np
import torch

from recondreamer.recon.base import GaussianSceneModel
from recondreamer.recon.config import ModelConfig, ReconConfig
from recondreamer.recon.gaussians import (
    initial_rows,
    matrix_to_quat,
    quat_multiply,
    quat_slerp,
)
from recondreamer.recon.init import (
    ScenePoints,
    knn_log_scales,
    normalized_times,
    points_in_box,
)
from recondreamer.splat.projection import quats_to_rotmats

BOX_MARGIN = (
    0.15  # metres added around a box when assigning LiDAR points to its vehicle
)
MIN_SEEN_POINTS = 5


def seen_tracks(scene, points: ScenePoints, labels: set[str]) -> list[str]:
    """Tracks of the modelled labels with at least MIN_SEEN_POINTS camera-seen LiDAR points.

    Vehicles the camera never saw cannot be fitted, so they get no Gaussian set.
    """
    counts: dict[str, int] = {}
    for t in range(scene.num_frames):
        in_frame = points.points[points.frames == t]
        for box in scene.boxes(t):
            if box.label in labels:
                inside = int(
                    points_in_box(
                        in_frame, box.obj_to_world, box.size, BOX_MARGIN
                    ).sum()
                )
                counts[box.track_id] = counts.get(box.track_id, 0) + inside
    return sorted(
        track_id for track_id, count in counts.items() if count >= MIN_SEEN_POINTS
    )


class StreetModel(GaussianSceneModel):
    model_type = "street"
    uses_boxes = True

    def __init__(self, spec: dict, net: ModelConfig) -> None:
        super().__init__(spec, net)
        poses = torch.tensor(
            np.asarray(spec["track_poses"], dtype=np.float32).reshape(
                -1, len(spec["frame_times"]), 4, 4
            )
        )
        self.register_buffer(
            "frame_times", torch.tensor(spec["frame_times"], dtype=torch.float32)
        )  # (T,)
        self.register_buffer(
            "track_quats", matrix_to_quat(poses[..., :3, :3])
        )  # (M,T,4)
        self.register_buffer("track_translations", poses[..., :3, 3].clone())  # (M,T,3)
        present = torch.tensor(
            np.asarray(spec["track_present"], dtype=bool).reshape(poses.shape[:2])
        )
        self.register_buffer("track_present", present)  # (M,T)

    def buffer_fields(self) -> dict[str, torch.dtype]:
        return {"owner": torch.long}

    @property
    def track_ids(self) -> list[str]:
        return list(self._spec["track_ids"])

    def track_poses_at(
        self, time: float
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Box rotations (M,4), translations (M,3) and presence (M,) at normalised ``time``.

        Between two frames where the track exists the pose is interpolated; where only one of
        them has the track, the nearer frame decides (so a vehicle appears/disappears half-way).
        """
        frames = self.frame_times
        count = frames.shape[0]
        if count == 1:
            return (
                self.track_quats[:, 0],
                self.track_translations[:, 0],
                self.track_present[:, 0],
            )
        upper = int(
            torch.searchsorted(
                frames, torch.tensor(float(time), device=frames.device)
            ).clamp(1, count - 1)
        )
        lower = upper - 1
        weight = float(
            np.clip(
                (time - float(frames[lower]))
                / max(float(frames[upper] - frames[lower]), 1e-9),
                0.0,
                1.0,
            )
        )
        q0, q1 = self.track_quats[:, lower], self.track_quats[:, upper]
        t0, t1 = self.track_translations[:, lower], self.track_translations[:, upper]
        p0, p1 = self.track_present[:, lower], self.track_present[:, upper]
        both = p0 & p1
        w = torch.full((q0.shape[0],), weight, device=q0.device)
        quats = torch.where(
            both[:, None],
            quat_slerp(q0, q1, w),
            torch.where(p0[:, None] & (weight <= 0.5), q0, q1),
        )
        translations = torch.where(
            both[:, None],
            t0 + weight * (t1 - t0),
            torch.where(p0[:, None] & (weight <= 0.5), t0, t1),
        )
        present = both | (p0 & (weight <= 0.5)) | (p1 & (weight > 0.5))
        return quats, translations, present

    def gaussians_at(
        self, time: float, static: bool = False
    ) -> dict[str, torch.Tensor]:
        p = self.gaussians.params
        track_quats, track_translations, present = self.track_poses_at(time)
        device = self.device
        identity = torch.tensor([[1.0, 0.0, 0.0, 0.0]], device=device)
        all_quats = torch.cat(
            (identity, track_quats), dim=0
        )  # (M+1,4); row 0 = background
        all_translations = torch.cat(
            (torch.zeros(1, 3, device=device), track_translations), dim=0
        )  # (M+1,3)
        all_present = torch.cat(
            (torch.ones(1, dtype=torch.bool, device=device), present), dim=0
        )  # (M+1,)
        index = self.gaussians.owner + 1  # (N,)
        rotations = quats_to_rotmats(all_quats)[index]  # (N,3,3)
        means = (rotations @ p["means"][:, :, None])[:, :, 0] + all_translations[index]
        quats = quat_multiply(all_quats[index], p["quats"])
        opacities = self.gaussians.opacities() * all_present[index].float()
        return {
            "means": means,
            "quats": quats,
            "scales": self.gaussians.scales(),
            "opacities": opacities,
        }

    @classmethod
    def initial_state(
        cls,
        scene,
        config: ReconConfig,
        points: ScenePoints,
        center: np.ndarray,
        rng: np.random.Generator,
    ) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor], dict]:
        track_ids = seen_tracks(scene, points, set(config.net.object_labels))
        track_index = {track_id: k for k, track_id in enumerate(track_ids)}
        num_frames = scene.num_frames
        poses = np.tile(np.eye(4), (len(track_ids), num_frames, 1, 1))
        present = np.zeros((len(track_ids), num_frames), dtype=bool)
        sizes = np.zeros((len(track_ids), 3))
        # Assign every LiDAR point inside a modelled box to that vehicle, in its box frame.
        owner = np.full(len(points), -1, dtype=np.int64)
        local = points.points.copy()
        for t in range(num_frames):
            in_frame = np.flatnonzero(points.frames == t)
            for box in scene.boxes(t):
                if box.track_id not in track_index:
                    continue
                k = track_index[box.track_id]
                poses[k, t] = box.obj_to_world
                present[k, t] = True
                sizes[k] = box.size
                inside = in_frame[
                    points_in_box(
                        points.points[in_frame], box.obj_to_world, box.size, BOX_MARGIN
                    )
                ]
                owner[inside] = k
                local[inside] = (
                    points.points[inside] - box.obj_to_world[:3, 3]
                ) @ box.obj_to_world[:3, :3]
        background = points.subset(np.flatnonzero(owner < 0))
        background, rows, far_count = cls.background_state(config, background, center, rng)
        all_rows = [rows]
        owners = [np.full(rows["means"].shape[0], -1, dtype=np.int64)]
        for k in range(len(track_ids)):
            members = np.flatnonzero(owner == k)
            if len(members) > config.init.max_object_points:
                members = np.sort(
                    rng.choice(
                        members, size=config.init.max_object_points, replace=False
                    )
                )
            object_points, object_colors = local[members], points.colors[members]
            # Boxes with few LiDAR returns get random points inside the box so the vehicle can be fitted.
            missing = max(config.init.max_object_points // 2 - len(members), 0)
            if missing:
                fill = rng.uniform(-0.5, 0.5, size=(missing, 3)) * sizes[k]
                fill_color = (
                    object_colors.mean(axis=0) if len(members) else np.full(3, 0.5)
                )
                object_points = np.concatenate([object_points, fill])
                object_colors = np.concatenate(
                    [object_colors, np.tile(fill_color, (missing, 1))]
                ).astype(np.float32)
            all_rows.append(
                initial_rows(
                    torch.from_numpy(object_points).float(),
                    torch.from_numpy(object_colors).float(),
                    torch.from_numpy(knn_log_scales(object_points)),
                    config.net.sh_degree,
                    config.init.initial_opacity,
                )
            )
            owners.append(np.full(len(object_points), k, dtype=np.int64))
        merged = {name: torch.cat([r[name] for r in all_rows]) for name in rows}
        spec = {
            "num_far_points": far_count,
            "track_ids": track_ids,
            "frame_times": [
                float(x)
                for x in normalized_times(
                    np.asarray(scene.timestamps, dtype=np.float64)
                )
            ],
            "track_poses": poses.tolist(),
            "track_present": present.tolist(),
            "track_sizes": sizes.tolist(),
        }
        return merged, {"owner": torch.from_numpy(np.concatenate(owners))}, spec
