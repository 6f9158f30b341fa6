"""Scene adaptation: fine-tune a DriveRestorer on the cycle pairs of the scene it will restore.

    python experiments/scene_adaptation.py --out DIR --restorer CKPT [--steps 500] [--ema-decay 0.99]

Run it on the folder of experiments/cycle_pairs.py (it reuses that folder's gate scenes, their
Street Gaussians runs and gate pairs). For each gate scene it makes the scene's own cycle pairs
(``make-cycle-pairs`` along shift@3 and shift@6: the scene's run renders the lateral drive, a second
run trains on those renders alone and renders the recorded trajectory, paired with the recorded
frames), fine-tunes the restorer on them alone (``train-restorer --init-restorer``), and measures
the restorer before and after on that scene's gate pairs with the foundation's scoring.

What the adapted restorer sees of its scene is what the reconstruction trains on (the recorded
frames and LiDAR) and the reconstruction's own renders; no frame of a lateral drive. Its
novel-trajectory columns (shift@3, shift@6) are therefore measured on truth it never saw. Its
original-trajectory column is not a clean measure: the recorded frames it is scored against were
its fine-tuning targets. ``foundation/gates.py``'s ``restorer_gate`` refuses restorers trained on a
gate scene for that reason, so this script scores with its ``gate_scores`` directly.
Every step skips what exists, so a stopped run continues; two jobs run side by side.
"""

from __future__ import annotations

import argparse
import json
import logging
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cycle_pairs import LEFT_SHIFTS  # the sibling experiments' steps, shared
from early_snapshot_pairs import GATE_SEEDS, SHIPPED, run

TRAJECTORIES = (*LEFT_SHIFTS, "original")
CYCLE_SCRIPT = Path(__file__).resolve().parent / "cycle_pairs.py"  # its --_cycle entry makes one scene's cycle pairs


def adapt(base: Path, pairs: Path, checkpoint: Path, steps: int, ema_decay: float, logs: Path) -> Path:
    """The restorer ``base`` fine-tuned on one scene's cycle pairs."""
    if not checkpoint.is_file():
        run(["train-restorer", "--arch", "dd2_mask", "--world-model", str(SHIPPED / "world_model_dd2.pt"), "--init-restorer", str(base),
             "--pairs", str(pairs), "--out", str(checkpoint), "--steps", str(steps), "--ema-decay", str(ema_decay), "--seed", "0", "--threads", "1"],
            logs / f"{checkpoint.stem}.log")
    return checkpoint


def score(checkpoint: Path, gate_pairs: Path) -> dict[str, dict]:
    """Trajectory -> the foundation's clip scores of ``checkpoint`` on one scene's gate pairs."""
    import torch

    from recondreamer.foundation.gates import gate_clips, gate_scores
    from recondreamer.generative.data import find_pairs_files
    from recondreamer.generative.inference import load_restorer

    torch.set_num_threads(1)
    restorer = load_restorer(checkpoint)
    return gate_scores(restorer, gate_clips(find_pairs_files([gate_pairs]), restorer.unet_config.uses_structure), views=False)


def pooled(per_scene: list[dict[str, dict]], trajectory: str, key: str) -> float:
    """Clip-weighted mean of ``key`` over scenes."""
    rows = [scores[trajectory] for scores in per_scene if trajectory in scores]
    return sum(row[key] * row["clips"] for row in rows) / sum(row["clips"] for row in rows)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="experiments/cycle_pairs.py's working folder (resumable)")
    parser.add_argument("--restorer", type=Path, required=True, help="the dd2_mask restorer to adapt")
    parser.add_argument("--steps", type=int, default=500, help="fine-tuning steps per scene (default 500)")
    parser.add_argument("--ema-decay", type=float, default=0.99, help="weight averaging of the fine-tuning (default 0.99)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    out, tag = args.out, f"{args.restorer.stem}_{args.steps}steps_ema{args.ema_decay:g}"
    gates = [f"gate-{i:03d}" for i in range(len(GATE_SEEDS))]
    missing = [g for g in gates if not (out / "gate_runs" / g / "model.pt").is_file()]
    if missing:
        raise SystemExit(f"{out}: no gate runs for {missing}; run experiments/cycle_pairs.py --out {out} first")
    for folder in ("logs", "adapt_cycle_runs", "adapt_pairs", "adapted"):
        (out / folder).mkdir(parents=True, exist_ok=True)

    def cycle_job(job: tuple[str, str]) -> None:
        gate, shift = job
        with open(out / "logs" / f"adapt_cycle_{gate}_{shift}.log", "w") as log:
            subprocess.run([sys.executable, str(CYCLE_SCRIPT), "--_cycle", str(out / "gate_scenes" / gate), str(out / "gate_runs" / gate), shift,
                            str(out / "adapt_cycle_runs" / gate / shift), str(out / "adapt_pairs" / gate)], check=True, stdout=log, stderr=subprocess.STDOUT)

    with ThreadPoolExecutor(2) as pool:
        list(pool.map(cycle_job, [(gate, shift) for gate in gates for shift in LEFT_SHIFTS]))
        adapted = list(pool.map(lambda gate: adapt(args.restorer, out / "adapt_pairs" / gate, out / "adapted" / f"{tag}_{gate}.pt", args.steps,
                                                   args.ema_decay, out / "logs"), gates))
        before = list(pool.map(lambda gate: score(args.restorer, out / "gate_pairs" / gate), gates))
        after = list(pool.map(lambda job: score(job[1], out / "gate_pairs" / job[0]), zip(gates, adapted)))

    print(f"{'scene':9} {'trajectory':10} {'render':>7} {'base':>7} {'adapted':>8} {'gain base':>9} {'gain adapted':>12}")
    for gate, b, a in zip(gates, before, after):
        for trajectory in TRAJECTORIES:
            print(f"{gate:9} {trajectory:10} {b[trajectory]['psnr_degraded']:7.2f} {b[trajectory]['psnr_restored']:7.2f} {a[trajectory]['psnr_restored']:8.2f} "
                  f"{b[trajectory]['gain']:+9.2f} {a[trajectory]['gain']:+12.2f}")
    table = {}
    for trajectory in TRAJECTORIES:
        row = {"render_psnr": pooled(before, trajectory, "psnr_degraded"), "base_gain_db": pooled(before, trajectory, "gain"),
               "adapted_gain_db": pooled(after, trajectory, "gain"), "render_flicker": pooled(before, trajectory, "flicker_degraded"),
               "base_flicker": pooled(before, trajectory, "flicker_restored"), "adapted_flicker": pooled(after, trajectory, "flicker_restored")}
        table[trajectory] = row
        print(f"{'all':9} {trajectory:10} render {row['render_psnr']:.2f} dB, gain {row['base_gain_db']:+.2f} -> {row['adapted_gain_db']:+.2f} dB, "
              f"flicker {row['render_flicker']:.2f} -> {row['base_flicker']:.2f} -> {row['adapted_flicker']:.2f}"
              + ("  (not clean: the recorded frames were fine-tuning targets)" if trajectory == "original" else ""))
    (out / f"adapt_{tag}.json").write_text(json.dumps({"restorer": str(args.restorer), "steps": args.steps, "ema_decay": args.ema_decay, "pooled": table}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
