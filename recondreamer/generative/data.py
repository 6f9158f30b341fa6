"""Training data of the generative stack: corpus sequences and restoration pairs, as latents.

A *sequence* is one camera trajectory of one scene: target frames, the frames used as reference,
structure maps drawn in the target camera, and for restoration pairs the degraded renders of
several training stages. Clips are short windows of a sequence.

World models see what a real one could have seen: videos along driven trajectories, each clip
conditioned on its own first frame and its own structure maps. A synthetic corpus scene is driven
several times, in different lanes, as a fleet would (its original trajectory and the lateral
drives it renders), and every drive is a sequence of its own; no sequence pairs one drive's
frames with another drive's targets (that would be supervised novel-view synthesis on exactly
the evaluation trajectories, which DriveDreamer-2 never had).
"""

from __future__ import annotations

import hashlib
import logging
import os
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from recondreamer.errors import RecondreamerError
from recondreamer.io import atomic_path
from recondreamer.generative.autoencoder import Autoencoder, encode_frames

LOG = logging.getLogger(__name__)


def structure_to_uint8(structure: np.ndarray) -> np.ndarray:  # (...) float in [0,1] -> uint8
    return np.round(np.clip(structure, 0.0, 1.0) * 255.0).astype(np.uint8)


def structure_from_uint8(structure: np.ndarray | torch.Tensor) -> torch.Tensor:  # uint8 -> float in [0,1]
    return torch.as_tensor(structure).float() / 255.0


def scene_structure(scene, cam_to_world: np.ndarray) -> np.ndarray:  # (T,4,4) -> (T,C,H,W) uint8
    """Structure maps (3D boxes, HD map) of every frame drawn in the given cameras."""
    from recondreamer.scene.structure import structure_channels

    maps = [
        structure_channels(scene.boxes(t), scene.map_polylines, scene.K, cam_to_world[t], scene.width, scene.height)
        for t in range(scene.num_frames)
    ]
    return structure_to_uint8(np.stack(maps))


def structure_channel_names() -> tuple[str, ...]:
    from recondreamer.scene.structure import STRUCTURE_CHANNELS

    return tuple(STRUCTURE_CHANNELS)


def scene_sky_masks(scene) -> np.ndarray | None:  # (T,H,W) bool or None
    masks = [scene.sky_mask(t) for t in range(scene.num_frames)]
    if any(m is None for m in masks):
        return None
    return np.stack(masks).astype(bool)


def scene_vanishing_points(scene, cam_to_world: np.ndarray) -> np.ndarray:  # (T,2)
    from recondreamer.generative.masks import vanishing_point

    return np.stack([vanishing_point(scene.K, cam_to_world[t], scene.ego_to_world[t]) for t in range(scene.num_frames)])


@dataclass
class Sequence:
    """One trajectory of one scene, latents pre-encoded (the autoencoder is frozen)."""

    name: str
    scene_id: str
    target: torch.Tensor  # (T,c,h,w) latents of the frames to generate / restore to
    reference: torch.Tensor  # (T,c,h,w) latents of the frames a clip is conditioned on (its own drive's)
    structure: np.ndarray | None  # (T,S,H,W) uint8 structure maps in the target camera
    degraded: torch.Tensor | None = None  # (K,T,c,h,w) latents of degraded renders (pairs)
    view: torch.Tensor | None = None  # (T,c,h,w) latents of the pairs' reference views (pairs files with ``view``)
    degraded_frames: np.ndarray | None = None  # (K,T,H,W,3) uint8, kept for masks and image-space losses
    target_frames: np.ndarray | None = None  # (T,H,W,3) uint8, kept for image-space losses
    sky_masks: np.ndarray | None = None  # (T,H,W) bool
    vanishing: np.ndarray | None = None  # (T,2)
    pair_kind: str | None = None  # pairs only: what the file teaches (``pair_kind``)

    @property
    def num_frames(self) -> int:
        return int(self.target.shape[0])


def find_scene_dirs(root: str | os.PathLike) -> list[Path]:
    """A scene directory itself, or the scene directories directly below a corpus directory."""
    root = Path(root)
    if not root.is_dir():
        raise RecondreamerError(f"{root}: corpus directory does not exist")
    if (root / "scene.json").is_file():
        return [root]
    scenes = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".") and (p / "scene.json").is_file())
    if not scenes:
        raise RecondreamerError(f"{root}: no scene directories (with scene.json) found")
    return scenes


def load_corpus_frames(corpus: str | os.PathLike, max_frames_per_scene: int | None = None) -> tuple[list[str], list[np.ndarray]]:
    """Scene ids and their original (and true novel) frames, each (T,H,W,3) uint8."""
    from recondreamer.scene import load_scene

    ids, frames = [], []
    for scene_dir in find_scene_dirs(corpus):
        scene = load_scene(scene_dir)
        indices = range(scene.num_frames) if max_frames_per_scene is None else np.linspace(0, scene.num_frames - 1, max_frames_per_scene).round().astype(int)
        stack = [scene.image(int(t)) for t in indices]
        for name in scene.novel_trajectories:
            stack += [scene.novel_image(name, int(t)) for t in indices]
        ids.append(scene.scene_id)
        frames.append(np.stack(stack))
    return ids, frames


def load_corpus_sequences(corpus: str | os.PathLike, autoencoder: Autoencoder, with_structure: bool) -> list[Sequence]:
    """Every drive of every corpus scene (the original trajectory and the lateral drives the scene
    renders), each its own sequence referenced by its own frames."""
    from recondreamer.scene import load_scene
    from recondreamer.scene.trajectories import trajectory_cam_to_world

    sequences = []
    for scene_dir in find_scene_dirs(corpus):
        scene = load_scene(scene_dir)
        trajectories = [("original", scene.images())]
        for name in scene.novel_trajectories:
            trajectories.append((name, np.stack([scene.novel_image(name, t) for t in range(scene.num_frames)])))
        for name, frames in trajectories:
            cams = trajectory_cam_to_world(scene.cam_to_world, scene.ego_to_world, name)
            latents = encode_frames(autoencoder, frames)
            sequences.append(
                Sequence(
                    name=f"{scene.scene_id}/{name}",
                    scene_id=scene.scene_id,
                    target=latents,
                    reference=latents,  # a drive's clips are conditioned on its own frames only
                    structure=scene_structure(scene, cams) if with_structure else None,
                )
            )
        LOG.info("corpus scene %s: %d trajectories, %d frames", scene.scene_id, len(trajectories), scene.num_frames)
    return sequences


PAIRS_KEYS = ("gt", "degraded", "stages", "structure", "vanishing")


def load_pairs_file(path: Path) -> dict:
    """Read one restoration-pairs file written by ``make-pairs`` and check its arrays."""
    try:
        with np.load(path, allow_pickle=False) as data:
            content = {key: data[key] for key in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:  # a cut-short .npz is a bad zip archive
        raise RecondreamerError(f"{path}: not a readable restoration-pairs file ({error})") from error
    missing = [key for key in PAIRS_KEYS if key not in content]
    if missing:
        raise RecondreamerError(f"{path}: restoration-pairs file lacks arrays {missing}")
    gt, degraded = content["gt"], content["degraded"]
    if gt.ndim != 4 or degraded.ndim != 5 or degraded.shape[1:] != gt.shape:
        raise RecondreamerError(f"{path}: degraded renders {degraded.shape} do not match ground truth {gt.shape} as (K,T,H,W,3)")
    if "view" in content and content["view"].shape != gt.shape:
        raise RecondreamerError(f"{path}: reference views {content['view'].shape} do not match ground truth {gt.shape} as (T,H,W,3)")
    if "sky" in content:
        content["sky"] = content["sky"].astype(bool, copy=False)
    return content


def pair_kind(content: dict) -> str:
    """What a pairs file teaches: ``snapshot`` (under-trained renders of the recorded trajectory with
    the recorded frames, the paper's pairs), ``cycle:<drive>`` (a reconstruction trained on renders of
    a lateral drive, rendering the recorded trajectory: cycle.py) or ``truth:<trajectory>`` (renders
    of a novel trajectory against its true views: novel-view truth, beyond the paper)."""
    if "cycle_from" in content:
        return f"cycle:{content['cycle_from']}"
    trajectory = str(content.get("trajectory", "original"))
    return "snapshot" if trajectory == "original" else f"truth:{trajectory}"


def find_pairs_files(dirs: list[str | os.PathLike]) -> list[Path]:
    files: list[Path] = []
    for directory in dirs:
        directory = Path(directory)
        if directory.is_file() and directory.suffix == ".npz":
            files.append(directory)
            continue
        if not directory.is_dir():
            raise RecondreamerError(f"{directory}: restoration-pairs directory does not exist")
        found = sorted(directory.glob("*.npz"))
        if not found:
            raise RecondreamerError(f"{directory}: no restoration-pairs files (*.npz)")
        files += found
    return files


def hash_weights(digest, module: torch.nn.Module) -> None:  # digest: a hashlib object, e.g. hashlib.sha1()
    """Feed every weight (and buffer) of ``module`` to ``digest``, by name in sorted order."""
    for name, tensor in sorted(module.state_dict().items()):
        digest.update(name.encode())
        digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())


def autoencoder_digest(autoencoder: Autoencoder) -> str:
    """A short hash of the autoencoder's weights and latent statistics: names its latent caches."""
    digest = hashlib.sha1()
    hash_weights(digest, autoencoder)
    return digest.hexdigest()[:12]


def pair_latents(path: Path, content: dict, autoencoder: Autoencoder, digest: str) -> dict[str, torch.Tensor]:
    """Latents of a pairs file: ``gt`` (T,c,h,w), ``degraded`` (K,T,c,h,w) and, where the file has
    reference views, ``view`` (T,c,h,w).

    Encoding costs about 30 CPU ms per frame, minutes for a set of pairs, and every restorer
    trained on the same pairs and autoencoder needs the same latents: they are cached next to
    the pairs file as ``<stem>.latents-<digest>.pt`` (``digest = autoencoder_digest(autoencoder)``,
    computed once by the caller for all files; written atomically).
    """
    cache = path.with_name(f"{path.stem}.latents-{digest}.pt")
    if cache.is_file():
        cached = torch.load(cache, map_location="cpu", weights_only=True, mmap=True)
        if (cached["gt"].shape[0] == content["gt"].shape[0] and cached["degraded"].shape[:2] == content["degraded"].shape[:2]
                and ("view" in cached) == ("view" in content)):
            return cached
    latents = {"gt": encode_frames(autoencoder, content["gt"]),
               "degraded": torch.stack([encode_frames(autoencoder, stage) for stage in content["degraded"]])}
    if "view" in content:
        latents["view"] = encode_frames(autoencoder, content["view"])
    with atomic_path(cache) as tmp:
        torch.save(latents, tmp)
    return torch.load(cache, map_location="cpu", weights_only=True, mmap=True)  # memory-mapped like a cache hit


def restored_pair_frames(
    path: Path,
    content: dict,
    restore: Callable[[np.ndarray, np.ndarray], np.ndarray],  # (T,H,W,3) uint8 render, (T,S,H,W) uint8 maps -> (T,H,W,3) uint8
    digest: str,
) -> np.ndarray:  # (K,T,H,W,3) uint8, memory-mapped
    """A restorer's output for every degraded stage of a pairs file (what a pixel refiner trains on).

    Restoring costs about 0.1 CPU s per frame; the frames are cached next to the pairs file as
    ``<stem>.restored-<digest>.pt`` (``digest`` names the restorer, e.g. ``training.restorer_digest``;
    written atomically) and memory-mapped like ``mapped_pair_arrays``.
    """
    cache = path.with_name(f"{path.stem}.restored-{digest}.pt")
    expected = content["degraded"].shape
    if cache.is_file() and cache.stat().st_mtime >= path.stat().st_mtime:
        cached = torch.load(cache, weights_only=True, mmap=True).numpy()
        if cached.shape == expected:
            return cached
    restored = np.stack([restore(stage, content["structure"]) for stage in content["degraded"]])
    with atomic_path(cache) as tmp:
        torch.save(torch.from_numpy(restored), tmp)
    return torch.load(cache, weights_only=True, mmap=True).numpy()


MAPPED_PAIRS_ARRAYS = ("gt", "degraded", "structure", "sky")


def mapped_pair_arrays(path: Path, content: dict) -> dict[str, np.ndarray]:
    """A pairs file's frame-sized arrays (``MAPPED_PAIRS_ARRAYS``, where present), memory-mapped from an uncompressed copy.

    A restorer job draws a few frames of one file per step but needs every file at hand. Held in
    RAM, the decompressed arrays of 232 files (58 scenes) took 7.5 GB of a 12.6 GB job; mapped,
    the OS pages in the frames a clip uses and drops pages under memory pressure, so a job's RAM
    no longer grows with the number of scenes. The copy is one file next to the pairs file,
    ``<stem>.arrays.pt`` (written atomically, about twice the pairs file's size; torch's maps hold
    no open file, numpy's would hold one each), rewritten when it is older than the pairs file or
    an array's shape or dtype differ. The maps are copy-on-write: writing to them never changes the copy.
    """
    cache = path.with_name(f"{path.stem}.arrays.pt")
    arrays = {name: content[name] for name in MAPPED_PAIRS_ARRAYS if name in content}
    if cache.is_file() and cache.stat().st_mtime >= path.stat().st_mtime:
        mapped = {name: tensor.numpy() for name, tensor in torch.load(cache, weights_only=True, mmap=True).items()}
        if mapped.keys() == arrays.keys() and all(mapped[n].shape == a.shape and mapped[n].dtype == a.dtype for n, a in arrays.items()):
            return mapped
    with atomic_path(cache) as tmp:
        torch.save({name: torch.from_numpy(np.ascontiguousarray(array)) for name, array in arrays.items()}, tmp)
    return {name: tensor.numpy() for name, tensor in torch.load(cache, weights_only=True, mmap=True).items()}


def load_pair_sequences(files: list[Path], autoencoder: Autoencoder, with_structure: bool, keep_frames: bool) -> list[Sequence]:
    """Restoration pairs as sequences; ``keep_frames`` keeps the degraded and ground-truth pixels
    (for masking and for an image-space loss). Latents and frame-sized arrays are memory-mapped
    from caches next to each pairs file (``pair_latents``, ``mapped_pair_arrays``)."""
    sequences = []
    digest = autoencoder_digest(autoencoder)
    for path in files:
        content = load_pairs_file(path)
        degraded_shape = content["degraded"].shape  # (K,T,H,W,3)
        latents = pair_latents(path, content, autoencoder, digest)
        mapped = mapped_pair_arrays(path, content)
        sequences.append(
            Sequence(
                name=path.stem,
                scene_id=str(content["scene_id"]),
                target=latents["gt"],
                reference=latents["gt"],  # unused by restorers (their reference is the degraded clip start)
                structure=mapped["structure"] if with_structure else None,
                degraded=latents["degraded"],
                view=latents.get("view"),
                degraded_frames=mapped["degraded"] if keep_frames else None,
                target_frames=mapped["gt"] if keep_frames else None,
                sky_masks=mapped.get("sky"),
                vanishing=content["vanishing"],
                pair_kind=pair_kind(content),
            )
        )
        del content  # free this file's decompressed arrays before the next file is read
        LOG.info("pairs %s: %d stages x %d frames", path.name, degraded_shape[0], degraded_shape[1])
    return sequences
