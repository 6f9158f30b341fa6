"""A contact sheet of a scene: frames, depth, semantics, boxes and lanes, novel-view ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from recondreamer.io import atomic_path
from recondreamer.scene.types import SEMANTIC_CLASSES

SEMANTIC_COLOURS = {  # RGB per class name, close to the Cityscapes palette
    "void": (0, 0, 0),
    "road": (128, 64, 128),
    "lane_marking": (255, 255, 255),
    "sidewalk": (244, 35, 232),
    "building": (70, 70, 70),
    "vegetation": (107, 142, 35),
    "pole": (153, 153, 153),
    "vehicle": (0, 0, 142),
    "sky": (70, 130, 180),
}


def colour_semantics(labels: np.ndarray, class_names: tuple[str, ...] = SEMANTIC_CLASSES) -> np.ndarray:  # (H,W) -> (H,W,3)
    palette = np.array([SEMANTIC_COLOURS.get(name, (255, 0, 0)) for name in class_names], dtype=np.uint8)
    return palette[np.clip(labels, 0, len(palette) - 1)]


def colour_depth(depth: np.ndarray) -> np.ndarray:  # (H,W) metres -> (H,W,3) uint8, log scale, black = no hit
    from matplotlib import colormaps

    valid = depth > 0
    scaled = np.zeros_like(depth, dtype=np.float64)
    scaled[valid] = np.clip((np.log(depth[valid]) - np.log(2.0)) / (np.log(150.0) - np.log(2.0)), 0.0, 1.0)
    rgb = (colormaps["turbo"](1.0 - scaled)[..., :3] * 255).astype(np.uint8)
    rgb[~valid] = 0
    return rgb


def overlay(image: np.ndarray, structure: np.ndarray, alpha: float = 0.6) -> np.ndarray:  # (H,W,3) uint8 x2
    drawn = structure.any(axis=-1, keepdims=True)
    blended = (1 - alpha) * image.astype(np.float64) + alpha * structure.astype(np.float64)
    return np.where(drawn, blended, image).astype(np.uint8)


def contact_sheet(scene_dir: str | Path, out: str | Path, frames: list[int] | None = None) -> Path:
    """Write a PNG (or any matplotlib format, by suffix) contact sheet of the scene at ``scene_dir``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from recondreamer.errors import RecondreamerError
    from recondreamer.scene import load_scene
    from recondreamer.scene.structure import draw_structure_map

    scene = load_scene(scene_dir)
    count = scene.num_frames
    frames = sorted({0, count // 2, count - 1}) if frames is None else frames
    for t in frames:
        if not 0 <= t < count:
            raise RecondreamerError(f"--frames: frame {t} is outside the scene's 0..{count - 1}")
    panels: list[tuple[str, callable]] = [("RGB", scene.image)]
    if "depth" in scene.channels:
        panels.append(("depth", lambda t: colour_depth(scene.depth(t))))
    if "semantics" in scene.channels:
        panels.append(("semantics", lambda t: colour_semantics(scene.semantics(t), scene.semantic_classes)))

    def structure(name: str, image_of):
        poses = scene.trajectory(name)
        return lambda t: overlay(image_of(t), draw_structure_map(scene.boxes(t), scene.map_polylines, scene.K, poses[t], scene.width, scene.height))

    panels.append(("boxes + lanes", structure("original", scene.image)))
    for name in scene.novel_trajectories:
        panels.append((f"{name} (true)", structure(name, lambda t, name=name: scene.novel_image(name, t))))
        if name == scene.novel_trajectories[-1] and scene.novel_semantics(name, 0) is not None:
            panels.append((f"{name} semantics", lambda t, name=name: colour_semantics(scene.novel_semantics(name, t), scene.semantic_classes)))
    aspect = scene.height / scene.width
    figure, axes = plt.subplots(len(frames), len(panels), figsize=(2.6 * len(panels), 2.6 * aspect * len(frames) + 0.6), squeeze=False)
    for row, t in enumerate(frames):
        for column, (title, render) in enumerate(panels):
            axis = axes[row, column]
            axis.imshow(render(t), interpolation="nearest")
            axis.set_xticks([])
            axis.set_yticks([])
            if row == 0:
                axis.set_title(title, fontsize=8)
            if column == 0:
                axis.set_ylabel(f"t = {t}", fontsize=8)
    figure.suptitle(f"{scene.scene_id} ({scene.source}, {scene.width}x{scene.height}, {count} frames)", fontsize=9)
    figure.tight_layout()
    out = Path(out)
    with atomic_path(out) as tmp:
        figure.savefig(tmp, format=out.suffix.lstrip(".") or "png", dpi=110)
    plt.close(figure)
    return out
