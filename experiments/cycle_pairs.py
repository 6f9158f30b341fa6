"""Cycle pairs: novel-view degradation along the recorded trajectory, without novel-view truth.

    python experiments/cycle_pairs.py --out results/novel-view-pairs [--scenes 16] [--steps 3000] [--arms cycle view deep]

Run it on the folder of experiments/novel_view_pairs.py (it reuses that folder's corpus scenes,
Street Gaussians runs, pairs and gate pairs, and makes what is missing); docs/foundation.md cites
its table.

Cycle pairs (recondreamer/generative/cycle.py, ``make-cycle-pairs``) carry the degradation of a
converged reconstruction seen a lane away, with the recorded frames as truth: each corpus scene's
Street Gaussians run A renders shift@K, a run B trains on those renders alone and renders the
recorded trajectory. No frame of any lateral drive is used.

This trains dd2_mask restorers from the shipped dd2 world model with the foundation's recipe and
budget (3000 steps, EMA 0.999) on the cycle pairs of K = 3 and 6 (B's snapshot at step 350 and its
final model) together with the foundation's own pairs (A's snapshots along the recorded
trajectory), and measures them beside the shipped dd2_mask restorer with the foundation's gate code
on the gate scenes:
  cycle:  the paper's inputs (render, boxes, map);
  view:   beyond the paper, also each frame's reference view (``train-restorer --view-condition``):
          the view the reconstruction was trained on at the same timestamp. At the gate that is the
          recorded frame beside a novel-trajectory render; in a cycle pair it is A's shift@K render
          beside B's render (what B was trained on). The foundation's pairs have none.
  deep:   the cycle arm with a restorer UNet of two residual blocks per level (``--blocks-per-level 2``;
          the second starts as the identity): does capacity limit what the pairs teach?
  right:  the cycle arm with run A rendering shift@-3 and shift@-6 (to the right) instead: run B's
          recorded trajectory then lies to the LEFT of the views it trained on, as the gate's
          shift@3 and shift@6 lie to the left of the recorded views (with left shifts, B's
          render is worst at the right image edge, the gate's at the left edge).
  both:   the cycle arm with the cycle pairs of both sides.
Every step skips what exists, so a stopped run continues; two jobs run side by side.
"""

from __future__ import annotations

import argparse
import logging
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from early_snapshot_pairs import (  # the sibling experiments' steps, shared
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

LEFT_SHIFTS, RIGHT_SHIFTS = ("shift@3", "shift@6"), ("shift@-3", "shift@-6")
CYCLE_ITERATIONS = 700  # run B's, as run A's (its snapshot: half of them)
ARMS = {  # restorer name -> (run A's cycle trajectories, extra train-restorer flags)
    "cycle": (LEFT_SHIFTS, ()),
    "view": (LEFT_SHIFTS, ("--view-condition",)),
    "deep": (LEFT_SHIFTS, ("--blocks-per-level", "2")),
    "right": (RIGHT_SHIFTS, ()),
    "both": (LEFT_SHIFTS + RIGHT_SHIFTS, ()),
}
DEFAULT_ARMS = ("cycle", "view", "deep")
DEFAULT_SCENES = 16


def arm_name(arm: str, scenes: int) -> str:
    """An arm's restorer name; a scene count other than the default is part of it, so a folder grown
    to more scenes trains a new restorer instead of reusing the smaller one."""
    return arm if scenes == DEFAULT_SCENES else f"{arm}_{scenes}scenes"


def cycle_pairs(scene_dir: Path, run_a: Path, shift: str, run_b: Path, pairs: Path) -> Path:
    """Run B on run A's renders along ``shift`` (700 iterations, as run A); its pairs (make-cycle-pairs)."""
    target = pairs / f"{scene_dir.name}__{shift}.npz"
    if target.exists():
        return target
    import torch

    from recondreamer.generative.cycle import make_cycle_pairs
    from recondreamer.recon.config import make_config

    torch.set_num_threads(1)
    return make_cycle_pairs(run_a, scene_dir, shift, run_b, pairs, make_config("street", "default", iterations=CYCLE_ITERATIONS))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="working folder (resumable; experiments/novel_view_pairs.py's)")
    parser.add_argument("--scenes", type=int, default=DEFAULT_SCENES, help="corpus scenes for the pairs (default 16, as the foundation)")
    parser.add_argument("--steps", type=int, default=FOUNDATION_RESTORER_STEPS, help="restorer training steps (default 3000, as the foundation)")
    parser.add_argument("--arms", nargs="+", choices=list(ARMS), default=list(DEFAULT_ARMS), help=f"which restorers to train (default {' '.join(DEFAULT_ARMS)})")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    out = args.out
    for folder in ("logs", "corpus", "gate_scenes", "runs", "pairs", "gate_runs", "gate_pairs", "cycle_runs", "pairs_cycle"):
        (out / folder).mkdir(parents=True, exist_ok=True)
    corpus = [(CORPUS_FIRST_SEED + i, f"corpus-{i:03d}") for i in range(args.scenes)]
    gates = [(seed, f"gate-{i:03d}") for i, seed in enumerate(GATE_SEEDS)]

    def cycle_job(job: tuple[Path, str]) -> None:
        scene, shift = job
        run_b = out / "cycle_runs" / scene.name / shift
        with open(out / "logs" / f"cycle_{scene.name}_{shift}.log", "w") as log:
            subprocess.run([sys.executable, __file__, "--_cycle", str(scene), str(out / "runs" / scene.name), shift, str(run_b), str(out / "pairs_cycle")],
                           check=True, stdout=log, stderr=subprocess.STDOUT)

    with ThreadPoolExecutor(2) as pool:
        scenes = list(pool.map(lambda s: synth(s[0], s[1], out / "corpus" / s[1], True), corpus))
        gate_scenes = list(pool.map(lambda s: synth(s[0], s[1], out / "gate_scenes" / s[1], True), gates))
        list(pool.map(lambda scene: street_run_pairs(scene, out / "runs" / scene.name, out / "pairs" / scene.name, ("original",), out / "logs"), scenes))
        list(pool.map(lambda scene: gate_pairs(scene, out), gate_scenes))
        shifts = sorted({shift for arm in args.arms for shift in ARMS[arm][0]})
        list(pool.map(cycle_job, [(scene, shift) for scene in scenes for shift in shifts]))
        recorded = [out / "pairs" / scene.name / f"{scene.name}__{scene.name}.npz" for scene in scenes]

        def arm_pairs(arm: str) -> list[Path]:
            return [*recorded, *(out / "pairs_cycle" / f"{scene.name}__{shift}.npz" for scene in scenes for shift in ARMS[arm][0])]

        restorers = dict(zip(args.arms, pool.map(
            lambda arm: train_dd2_mask(arm_pairs(arm), restorer_path(out, arm_name(arm, args.scenes), args.steps), args.steps, out, ARMS[arm][1]), args.arms)))
    restorers["shipped"] = SHIPPED / "restorer_dd2_mask.pt"
    sources = {"cycle": "original + cycle 3, 6", "view": "same, + reference views", "deep": "same, 2 blocks per level",
               "right": "original + cycle -3, -6", "both": "original + cycle 3, 6, -3, -6", "shipped": "foundation"}
    print_gates(restorers, sources, out)
    return 0


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--_cycle":
        cycle_pairs(Path(sys.argv[2]), Path(sys.argv[3]), sys.argv[4], Path(sys.argv[5]), Path(sys.argv[6]))
    else:
        sys.exit(main())
