"""Beyond the paper: a DriveRestorer trained on novel-trajectory renders and the lanes' own frames.

    python experiments/novel_view_pairs.py --out results/novel-view-pairs [--scenes 16] [--steps 3000]

docs/foundation.md cites its table.

The paper trains DriveRestorer on renders of under-trained reconstructions along the recorded
trajectory (the foundation does the same). The corpus drives every scene in several lanes, as a
fleet would; a restorer may instead learn from renders of the original drive's reconstruction
along another drive's trajectory, paired with that drive's frames: the very degradation it has to
undo along shift@3 and shift@6, not a stand-in for it. Such a restorer is trained with novel-view
truth, so it is not the paper's DriveRestorer: at most an extra, labelled row.

This trains dd2_mask restorers from the shipped dd2 world model with the foundation's recipe and
budget (3000 steps, EMA 0.999) on the Street Gaussians pairs of the same corpus scenes (seeds
10000 on, as the foundation's), alike but for the trajectories their pairs follow:
  novel:        original + shift@3 + shift@6 (the gate's own strides, on other scenes)
  lane_change:  original + lane_change (a lateral drive the gate does not measure)
  novel_view:   as novel, and the restorer also sees each frame's reference view, the recorded
                frame beside a novel-trajectory render (``train-restorer --view-condition``)
and measures them, beside the shipped dd2_mask restorer, with the foundation's gate code on gate
scenes no model saw (seeds 20000-20003). Every step skips what exists, so a stopped run
continues; two jobs run side by side.
"""

from __future__ import annotations

import argparse
import logging
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from early_snapshot_pairs import (  # the sibling experiment's steps, shared
    CORPUS_FIRST_SEED,
    FOUNDATION_RESTORER_STEPS,
    GATE_SEEDS,
    SHIPPED,
    gate_pairs,
    print_gates,
    restorer_path,
    street_run_pairs,
    synth,
    train_dd2_mask,
)

NOVEL = ("original", "shift@3", "shift@6")
# restorer name -> (trajectories of its pairs, extra train-restorer flags)
ARMS = {"novel": (NOVEL, ()), "lane_change": (("original", "lane_change"), ()), "novel_view": (NOVEL, ("--view-condition",))}


def arm_files(pairs: list[Path], trajectories: tuple[str, ...]) -> list[Path]:
    """The pairs files of ``trajectories`` (make-pairs names novel ones SCENE__RUN__TRAJECTORY.npz)."""
    def trajectory(path: Path) -> str:
        parts = path.stem.split("__")
        return parts[2] if len(parts) > 2 else "original"

    return [path for folder in pairs for path in sorted(folder.glob("*.npz")) if trajectory(path) in trajectories]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="working folder (resumable)")
    parser.add_argument("--scenes", type=int, default=16, help="corpus scenes for the pairs (default 16, as the foundation)")
    parser.add_argument("--steps", type=int, default=FOUNDATION_RESTORER_STEPS, help="restorer training steps (default 3000, as the foundation)")
    parser.add_argument("--arms", nargs="+", choices=list(ARMS), default=list(ARMS), help="which restorers to train (default all)")
    args = parser.parse_args()
    arms = {arm: ARMS[arm] for arm in args.arms}
    logging.basicConfig(level=logging.WARNING)
    out = args.out
    for folder in ("logs", "corpus", "gate_scenes", "runs", "pairs", "gate_runs", "gate_pairs"):
        (out / folder).mkdir(parents=True, exist_ok=True)
    corpus = [(CORPUS_FIRST_SEED + i, f"corpus-{i:03d}") for i in range(args.scenes)]
    gates = [(seed, f"gate-{i:03d}") for i, seed in enumerate(GATE_SEEDS)]
    trajectories = tuple(dict.fromkeys(name for names, _ in arms.values() for name in names))
    with ThreadPoolExecutor(2) as pool:
        scenes = list(pool.map(lambda s: synth(s[0], s[1], out / "corpus" / s[1], True), corpus))
        gate_scenes = list(pool.map(lambda s: synth(s[0], s[1], out / "gate_scenes" / s[1], True), gates))
        pairs = list(pool.map(lambda scene: street_run_pairs(scene, out / "runs" / scene.name, out / "pairs" / scene.name, trajectories, out / "logs"), scenes))
        list(pool.map(lambda scene: gate_pairs(scene, out), gate_scenes))
        restorers = dict(zip(arms, pool.map(
            lambda arm: train_dd2_mask(arm_files(pairs, arms[arm][0]), restorer_path(out, arm, args.steps), args.steps, out, arms[arm][1]), arms)))
    restorers["shipped"] = SHIPPED / "restorer_dd2_mask.pt"
    sources = {arm: " + ".join(names) + (" + views" if flags else "") for arm, (names, flags) in arms.items()} | {"shipped": "foundation (original)"}
    print_gates(restorers, sources, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
