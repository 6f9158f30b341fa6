"""What the recorded frames can tell a restorer about the gate's novel-trajectory renders.

    python experiments/observation_bound.py --out results/novel-view-pairs

Run it on the folder of experiments/novel_view_pairs.py or cycle_pairs.py (it reuses that folder's
gate scenes and gate pairs and makes what is missing: about 3 min); docs/foundation.md cites its
table. Everything here is measured against the true novel views and their depth, which only the
synthetic benchmark has: it is an analysis of the gate, not a method.

Two questions, on the Street Gaussians renders the foundation's restorer gate restores (the final
model along shift@3 and shift@6 of the gate scenes, seeds 20000-20003):

1. Where is the render wrong? Each pixel of the true novel view is "observed" when some recorded
   frame saw its surface point (the point, from the true novel depth, projects into that recorded
   camera within 5% + 5 cm of the recorded depth; a sky pixel when the recorded camera sees sky in
   the same direction). Replacing the observed pixels by the truth bounds what any use of the
   recorded frames could gain; what remains lies on surfaces no recorded frame saw, which only a
   learned prior can fill. Windows: the frame of the same timestamp, +-4 frames, the whole clip.

2. Do LiDAR points carry it (the condition FreeVS and StreetCrafter give their generators)? The
   LiDAR points of the same timestamp that the recorded camera sees (within 5% of the nearest
   point's depth in a 3x3 window) take their recorded colours and are splatted into the novel camera
   (nearest point per pixel; a point more than 10% behind the nearest of its 5x5 window is dropped,
   as background showing through gaps between foreground points). Printed: the pixels they cover,
   the render's and the points' PSNR on those pixels, and the render with them pasted in.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from early_snapshot_pairs import GATE_SEEDS, gate_pairs, synth  # the sibling experiments' steps, shared

TRAJECTORIES = ("shift@3", "shift@6")
WINDOWS = {"same frame": 0, "+-4 frames": 4, "whole clip": None}  # recorded frames around each timestamp
NEAR_M = 0.1


def _in_image(scene, u: np.ndarray, v: np.ndarray, z: np.ndarray) -> np.ndarray:
    return (z > NEAR_M) & (u >= 0) & (u < scene.width) & (v >= 0) & (v < scene.height)


def coloured_lidar(scene, frame: int) -> tuple[np.ndarray, np.ndarray]:  # (N,3) world points, (N,3) uint8 colours
    """The LiDAR points of ``frame`` that its recorded camera sees, with their recorded colours."""
    from scipy.ndimage import minimum_filter

    from recondreamer.scene.cameras import pixel_indices, project_points, world_to_camera

    points = scene.lidar(frame)
    uv, z = project_points(points, scene.K, world_to_camera(scene.cam_to_world[frame]), scene.distortion)
    u, v = pixel_indices(uv)
    keep = _in_image(scene, u, v, z)
    points, u, v, z = points[keep], u[keep], v[keep], z[keep]
    nearest = np.full((scene.height, scene.width), np.inf)
    np.minimum.at(nearest, (v, u), z)
    visible = z <= minimum_filter(nearest, size=3)[v, u] * 1.05
    return points[visible], scene.image(frame)[v[visible], u[visible]]


def splat_points(scene, points: np.ndarray, colours: np.ndarray, cam_to_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Coloured points seen from ``cam_to_world``: (H,W,3) uint8 image and (H,W) bool coverage."""
    from scipy.ndimage import minimum_filter

    from recondreamer.scene.cameras import pixel_indices, project_points, world_to_camera

    uv, z = project_points(points, scene.K, world_to_camera(cam_to_world), scene.distortion)
    u, v = pixel_indices(uv)
    keep = _in_image(scene, u, v, z)
    u, v, z, colours = u[keep], v[keep], z[keep], colours[keep]
    far_first = np.argsort(-z)  # nearer points overwrite farther ones
    image = np.zeros((scene.height, scene.width, 3), np.uint8)
    depth = np.full((scene.height, scene.width), np.inf)
    image[v[far_first], u[far_first]] = colours[far_first]
    depth[v[far_first], u[far_first]] = z[far_first]
    covered = np.isfinite(depth) & (depth <= minimum_filter(depth, size=5) * 1.1)
    image[~covered] = 0
    return image, covered


def seen_by_each_frame(scene, trajectory: str, frame: int, recorded_depths: np.ndarray) -> np.ndarray:  # (T,H,W) bool
    """For each recorded frame, the pixels of the true novel view (``trajectory`` at ``frame``) whose
    surface it saw; ``recorded_depths`` (T,H,W) are the recorded frames' depth maps."""
    from recondreamer.scene.cameras import pixel_indices, project_points, transform_points, world_to_camera

    height, width = scene.height, scene.width
    depth = scene.novel_depth(trajectory, frame).reshape(-1)  # 0 on sky
    sky = depth <= 0
    rows, cols = np.mgrid[0:height, 0:width]
    rays = np.stack([cols, rows, np.ones_like(cols)], -1).reshape(-1, 3) @ np.linalg.inv(scene.K).T  # (HW,3), z = 1
    novel_pose = scene.trajectory(trajectory)[frame]
    surface = transform_points(novel_pose, rays * np.where(sky, 1.0, depth)[:, None])  # (HW,3) world
    sky_offset = (rays @ novel_pose[:3, :3].T) * 1e6  # sky: a direction, placed far from whichever camera looks
    seen = np.zeros((len(recorded_depths), height * width), bool)
    for other, recorded_depth_map in enumerate(recorded_depths):
        pose = scene.cam_to_world[other]
        points = np.where(sky[:, None], pose[:3, 3] + sky_offset, surface)
        uv, z = project_points(points, scene.K, world_to_camera(pose))
        u, v = pixel_indices(uv)
        inside = _in_image(scene, u, v, z)
        recorded_depth = np.zeros(len(z))
        recorded_depth[inside] = recorded_depth_map[v[inside], u[inside]]
        same_surface = np.abs(recorded_depth - z) <= 0.05 * z + 0.05
        seen[other] = inside & np.where(sky, recorded_depth <= 0, same_surface & (recorded_depth > 0))
    return seen.reshape(-1, height, width)


def observed_pixels(scene, trajectory: str, frame: int, recorded: list[int]) -> np.ndarray:  # (H,W) bool
    """Pixels of the true novel view (``trajectory`` at ``frame``) whose surface some ``recorded`` frame saw."""
    depths = np.stack([scene.depth(other) for other in range(scene.num_frames)])
    return seen_by_each_frame(scene, trajectory, frame, depths)[recorded].any(0)


def measure_clip(scene, pairs_file: Path, trajectory: str) -> dict:
    """One gate clip: the render's PSNR, the observed-pixel bounds and the LiDAR paste (per-frame means, as the gate)."""
    from recondreamer.generative.data import load_pairs_file
    from recondreamer.generative.scoring import mean_psnr

    content = load_pairs_file(pairs_file)
    truth, render = content["gt"], content["degraded"][int(np.argmax(content["stages"]))]
    frames = scene.num_frames
    row = {"render": mean_psnr(render, truth)}
    depths = np.stack([scene.depth(t) for t in range(frames)])
    seen = np.stack([seen_by_each_frame(scene, trajectory, t, depths) for t in range(frames)])  # (T novel, T recorded, H, W)
    distance = np.abs(np.arange(frames)[:, None] - np.arange(frames)[None, :])  # (T,T) frames apart
    for name, window in WINDOWS.items():
        within = distance <= (frames if window is None else window)
        masks = (seen & within[:, :, None, None]).any(1)  # (T,H,W)
        row[f"observed {name}"] = float(masks.mean())
        row[f"bound {name}"] = mean_psnr(np.where(masks[..., None], truth, render), truth)
    pasted, covered = render.copy(), []
    squared_render, squared_lidar = [], []
    for t in range(frames):
        lidar_image, mask = splat_points(scene, *coloured_lidar(scene, t), scene.trajectory(trajectory)[t])
        pasted[t][mask] = lidar_image[mask]
        covered.append(mask.mean())
        squared_render.append(((render[t][mask] / 255.0 - truth[t][mask] / 255.0) ** 2).mean())
        squared_lidar.append(((lidar_image[mask] / 255.0 - truth[t][mask] / 255.0) ** 2).mean())
    row |= {"lidar covered": float(np.mean(covered)), "render on lidar": float(-10 * np.log10(np.mean(squared_render))),
            "lidar on lidar": float(-10 * np.log10(np.mean(squared_lidar))), "lidar pasted": mean_psnr(pasted, truth)}
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="working folder (resumable; the other restorer experiments')")
    args = parser.parse_args()
    out = args.out
    for folder in ("logs", "gate_scenes", "gate_runs", "gate_pairs"):
        (out / folder).mkdir(parents=True, exist_ok=True)
    with ThreadPoolExecutor(2) as pool:
        scene_dirs = list(pool.map(lambda s: synth(s[1], f"gate-{s[0]:03d}", out / "gate_scenes" / f"gate-{s[0]:03d}", True), enumerate(GATE_SEEDS)))
        list(pool.map(lambda scene: gate_pairs(scene, out), scene_dirs))

    from recondreamer.scene import load_scene

    for trajectory in TRAJECTORIES:
        rows = []
        for scene_dir in scene_dirs:
            pairs_file = out / "gate_pairs" / scene_dir.name / f"{scene_dir.name}__{scene_dir.name}__{trajectory}.npz"
            rows.append(measure_clip(load_scene(scene_dir), pairs_file, trajectory))
        mean = {key: float(np.mean([row[key] for row in rows])) for key in rows[0]}
        print(f"{trajectory}: render {mean['render']:.2f} dB (mean of {len(rows)} gate clips)")
        for name in WINDOWS:
            print(f"  observed in the {name:10}: {mean[f'observed {name}']:.2f} of the pixels; with them true {mean[f'bound {name}']:.2f} dB "
                  f"({mean[f'bound {name}'] - mean['render']:+.2f})")
        print(f"  LiDAR of the same frame: covers {mean['lidar covered']:.3f} of the pixels; there the render {mean['render on lidar']:.2f} dB, "
              f"the points {mean['lidar on lidar']:.2f} dB; pasted into the render {mean['lidar pasted']:.2f} dB ({mean['lidar pasted'] - mean['render']:+.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
