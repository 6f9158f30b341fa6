"""How a restored clip is scored against its ground truth: the measures the restorer benchmarks share.

A clip is (T,H,W,3) frames, scored as saved: rounded and clipped to uint8.

- ``mean_psnr``: mean per-frame PSNR (``recondreamer.evaluation.image_metrics.psnr``);
- ``flicker``: change between consecutive frames that the true video does not have;
- ``score_clip``: PSNR and flicker of a restored clip and of its degraded input; its ``gain`` is the
  restoration gain in dB (restored minus degraded PSNR against the same truth);
- ``summarise``: their means over clips, the gain also split by pairs kind, ``orig`` (renders along
  the training trajectory) and ``novel`` (renders along a novel trajectory);
- ``scored_clips``: the clips of restoration-pairs files a restorer is scored on, those of scenes it
  was not trained on (or only those it was);
- ``print_gain_table``: one row per variant of a restore with its mean gain, all / orig / novel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recondreamer.evaluation.image_metrics import psnr

KINDS = ("orig", "novel")


def flicker(clip: np.ndarray, gt: np.ndarray) -> float:
    """Temporal-difference error of (T,H,W,3) uint8 clips against their truth, in 0-255 units:
    change between consecutive frames that the true video does not have (lower is steadier)."""
    dx = np.diff(clip.astype(np.float32), axis=0)
    dg = np.diff(gt.astype(np.float32), axis=0)
    return float(np.mean(np.abs(dx - dg)))


def pairs_kind(trajectory: str) -> str:
    """``orig`` for the original trajectory's pairs, ``novel`` for a novel trajectory's."""
    return "orig" if trajectory == "original" else "novel"


def as_saved(clip: np.ndarray) -> np.ndarray:
    """A clip (float or uint8, 0-255) as saved frames hold it: rounded and clipped to uint8."""
    return np.clip(np.round(clip), 0, 255).astype(np.uint8)


def mean_psnr(clip: np.ndarray, gt: np.ndarray) -> float:  # (T,H,W,3) float or uint8 vs uint8
    """Mean per-frame PSNR of a clip rounded and clipped to uint8 (what a saved frame holds)."""
    return float(np.mean([psnr(a, b) for a, b in zip(as_saved(clip), gt)]))


@dataclass(frozen=True)
class ClipScore:
    """One restored clip against its truth, beside its degraded input."""

    kind: str  # "orig" | "novel"
    psnr_degraded: float
    psnr_restored: float
    flicker_degraded: float
    flicker_restored: float

    @property
    def gain(self) -> float:
        """Restoration gain in dB: restored minus degraded PSNR against the same truth."""
        return self.psnr_restored - self.psnr_degraded


def score_clip(kind: str, degraded: np.ndarray, restored: np.ndarray, gt: np.ndarray) -> ClipScore:
    restored = as_saved(restored)
    return ClipScore(kind, mean_psnr(degraded, gt), mean_psnr(restored, gt), flicker(degraded, gt), flicker(restored, gt))


def _mean(values: list[float]) -> float:
    return float(np.mean(values)) if values else float("nan")


def summarise(scores: list[ClipScore]) -> dict:
    """Means over clips: PSNR and flicker of degraded and restored clips, and the gain over all clips
    (``gain``) and over each kind's (``gain_orig``, ``gain_novel``; NaN without such clips)."""
    return {
        "clips": len(scores),
        "psnr_degraded": _mean([s.psnr_degraded for s in scores]),
        "psnr_restored": _mean([s.psnr_restored for s in scores]),
        "gain": _mean([s.gain for s in scores]),
        **{f"gain_{kind}": _mean([s.gain for s in scores if s.kind == kind]) for kind in KINDS},
        "flicker_degraded": _mean([s.flicker_degraded for s in scores]),
        "flicker_restored": _mean([s.flicker_restored for s in scores]),
    }


def scored_clips(restorer, payload: dict, pair_files: list, stages_per_run: int, training_scenes: bool = False) -> list[tuple]:
    """(kind, degraded, gt, structure) of every clip of the pairs files whose scene the restorer was
    not trained on (with ``training_scenes``: only those it was trained on); ``stages_per_run``
    training stages per file, spread from earliest to latest (0 = all). ``payload`` is the
    restorer's checkpoint (its ``training_scenes``)."""
    from recondreamer.generative.data import load_pairs_file

    trained_on = set(payload.get("training_scenes", []))
    clips = []
    for file in pair_files:
        content = load_pairs_file(file)
        if (str(content["scene_id"]) in trained_on) != training_scenes:
            continue
        kind = pairs_kind(str(content.get("trajectory", "original")))
        stages = np.arange(len(content["degraded"]))
        if stages_per_run:
            stages = np.unique(np.linspace(0, len(stages) - 1, stages_per_run).round().astype(int))
        structure = content["structure"] if restorer.unet_config.uses_structure else None
        clips += [(kind, degraded, content["gt"], structure) for degraded in content["degraded"][stages]]
    return clips


def print_gain_table(gains: dict[str, list[tuple[str, float]]]) -> None:
    """One row per variant (name -> [(kind, gain dB) per clip]): its mean gain over all clips and over
    the orig and novel ones."""
    print(f"{'variant':24s} {'gain dB':>7s} {'orig':>6s} {'novel':>6s}")
    for name, rows in gains.items():
        by_kind = {k: [g for kind, g in rows if kind == k] for k in KINDS}
        split = [f"{np.mean(v):6.2f}" if v else f"{'-':>6s}" for v in by_kind.values()]
        print(f"{name:24s} {np.mean([g for _, g in rows]):7.2f} {split[0]} {split[1]}")
