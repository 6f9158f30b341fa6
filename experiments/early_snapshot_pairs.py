"""Does training DriveRestorer on earlier (worse) snapshots help it on novel-trajectory renders?

    python experiments/early_snapshot_pairs.py --out results/early-pairs [--scenes 16] [--steps 3000]

docs/foundation.md cites its tables at 16 and at 40 scenes.

The paper's recipe, as the foundation runs it: pairs of under-trained Street Gaussians renders
along the recorded trajectory and the recorded frames. The foundation takes the snapshots of
steps 250 and 500 (of 700), whose renders (about 22-27 dB) are much better than the renders the
gate restores along shift@3 and shift@6 (about 22 and 19 dB, GATES.md). This trains dd2_mask
restorers from the shipped dd2 world model, alike but for the snapshots their pairs come from,
on the same corpus scenes (seeds of the foundation corpus, Street Gaussians only):
  late:  steps 250 and 500 (the foundation's stages; renders about 23 and 26 dB)
  early: steps 100 and 250 (about 21 and 23 dB: near the shift@3 renders)
and measures both, beside the shipped dd2_mask restorer, with the foundation's gate code on gate
scenes no model saw (seeds 20000-20003, as the foundation's). Every step skips what exists, so a
stopped run continues; two jobs run side by side.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ARMS = {"late": (250, 500), "early": (100, 250)}
SNAPSHOTS = (100, 250, 500)
CORPUS_FIRST_SEED, GATE_SEEDS = 10000, (20000, 20001, 20002, 20003)
SHIPPED = Path(__file__).resolve().parents[1] / "recondreamer" / "weights"


def run(command: list[str], log: Path) -> None:
    with open(log, "w") as handle:
        subprocess.run([sys.executable, "-m", "recondreamer", *command], check=True, stdout=handle, stderr=subprocess.STDOUT)


def synth(seed: int, scene_id: str, out: Path, novel: bool) -> Path:
    if not out.exists():
        run(["synth", "--seed", str(seed), "--preset", "compact", "--scene-id", scene_id, "--out", str(out), *([] if novel else ["--no-novel"])], out.parent.parent / "logs" / f"synth_{scene_id}.log")
    return out


def train_street(scene: Path, run_dir: Path) -> Path:
    """Street Gaussians, the default preset at 700 iterations, with snapshots at SNAPSHOTS."""
    if (run_dir / "model.pt").is_file():
        return run_dir
    import torch

    from recondreamer.recon.config import make_config
    from recondreamer.recon.trainer import train_scene
    from recondreamer.scene import load_scene

    torch.set_num_threads(1)
    config = dataclasses.replace(make_config("street", "default"), iterations=700, snapshot_steps=SNAPSHOTS)
    train_scene(load_scene(scene), config, run_dir)
    return run_dir


def arm_pairs(run_dir: Path, scene: Path, out: Path, stages: tuple[int, ...]) -> None:
    """Original-trajectory pairs from the snapshots of ``stages`` only (a run folder of links to them)."""
    target = out / f"{scene.name}__street.npz"
    if target.exists():
        return
    import torch

    from recondreamer.generative.pairs import make_pairs_for_run

    torch.set_num_threads(1)
    view = out.parent / "views" / out.name / scene.name / "street"
    shutil.rmtree(view, ignore_errors=True)
    (view / "snapshots").mkdir(parents=True)
    for step in stages:
        (view / "snapshots" / f"step_{step:06d}.pt").symlink_to((run_dir / "snapshots" / f"step_{step:06d}.pt").resolve())
    make_pairs_for_run(view, out, len(stages), scene_dir=scene)


def street_run_pairs(scene: Path, run_dir: Path, pairs: Path, trajectories: tuple[str, ...], logs: Path) -> Path:
    """Street Gaussians on ``scene`` (the default preset, 700 iterations) and its pairs along ``trajectories``
    from 4 snapshots (and, on novel trajectories, the final model)."""
    if not (run_dir / "model.pt").is_file():
        run(["train-recon", "--scene", str(scene), "--model", "street", "--out", str(run_dir), "--preset", "default",
             "--seed", "0", "--iterations", "700", "--threads", "1"], logs / f"recon_{scene.name}.log")
    missing = [name for name in trajectories if not (pairs / f"{scene.name}__{run_dir.name}{'' if name == 'original' else '__' + name}.npz").is_file()]
    if missing:
        run(["make-pairs", "--run", str(run_dir), "--scene", str(scene), "--out", str(pairs), "--stages", "4",
             "--trajectories", *missing, "--threads", "1"], logs / f"pairs_{scene.name}.log")
    return pairs


def gate_pairs(scene: Path, out: Path) -> Path:
    """A gate scene's run and its pairs along original, shift@3 and shift@6, as the foundation's gate makes them."""
    return street_run_pairs(scene, out / "gate_runs" / scene.name, out / "gate_pairs" / scene.name, ("original", "shift@3", "shift@6"), out / "logs")


FOUNDATION_RESTORER_STEPS = 3000


def restorer_path(out: Path, arm: str, steps: int) -> Path:
    """Where an arm's restorer goes; a budget other than the foundation's is part of the name."""
    return out / (f"restorer_{arm}.pt" if steps == FOUNDATION_RESTORER_STEPS else f"restorer_{arm}_{steps}steps.pt")


def train_dd2_mask(pairs: list[Path], checkpoint: Path, steps: int, out: Path, flags: tuple[str, ...] = ()) -> Path:
    """A dd2_mask DriveRestorer from the shipped dd2 world model, with the foundation's recipe (EMA 0.999)
    and any further train-restorer ``flags``."""
    if not checkpoint.is_file():
        run(["train-restorer", "--arch", "dd2_mask", "--world-model", str(SHIPPED / "world_model_dd2.pt"), "--pairs", *map(str, pairs),
             "--out", str(checkpoint), "--steps", str(steps), "--ema-decay", "0.999", "--seed", "0", "--threads", "1", *flags],
            out / "logs" / f"{checkpoint.stem}.log")
    return checkpoint


def print_gates(restorers: dict[str, Path], sources: dict[str, str], out: Path) -> dict:
    """Measure each restorer with the foundation's gate code on ``out/gate_pairs``; print and save the table."""
    import torch

    from recondreamer.foundation import gates as gate_code
    from recondreamer.generative.checkpoint import load_checkpoint
    from recondreamer.generative.data import find_pairs_files

    torch.set_num_threads(2)
    pairs = find_pairs_files(sorted((out / "gate_pairs").iterdir()))
    table = {}
    print(f"{'restorer':12} {'pairs from':40} {'trajectory':10} {'clips':>5} {'render':>7} {'restored':>8} {'gain':>6} {'flicker':>13}")
    runs = [(name, checkpoint, False) for name, checkpoint in restorers.items()]
    for name, checkpoint in restorers.items():  # a view-conditioned restorer also without its views: what they add
        if load_checkpoint(checkpoint, "restorer")["config"]["unet"].get("view_condition"):
            runs.append((f"{name}-", checkpoint, True))
            sources[f"{name}-"] = f"{name}, its views withheld"
    for name, checkpoint, withhold in runs:
        result = gate_code.restorer_gate(checkpoint, pairs, withhold_views=withhold)
        table[name] = result
        for trajectory in (*gate_code.NOVEL_GATE_TRAJECTORIES, "original"):
            row = result.get(trajectory)
            if row:
                print(f"{name:12} {sources[name]:40} {trajectory:10} {row['clips']:5d} {row['render_psnr']:7.2f} {row['restored_psnr']:8.2f} "
                      f"{row['gain_db']:+6.2f} {row['render_flicker']:6.2f}->{row['restored_flicker']:5.2f}")
    (out / "gates.json").write_text(json.dumps(table, indent=1, default=str))
    return table


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="working folder (resumable)")
    parser.add_argument("--scenes", type=int, default=16, help="corpus scenes for the pairs (default 16, as the foundation)")
    parser.add_argument("--steps", type=int, default=FOUNDATION_RESTORER_STEPS, help="restorer training steps (default 3000, as the foundation)")
    args = parser.parse_args()
    import logging

    logging.basicConfig(level=logging.WARNING)
    out = args.out
    for folder in ("logs", "corpus", "gate_scenes", "runs", "gate_runs", "gate_pairs", *(f"pairs_{arm}" for arm in ARMS)):
        (out / folder).mkdir(parents=True, exist_ok=True)
    corpus = [(CORPUS_FIRST_SEED + i, f"corpus-{i:03d}") for i in range(args.scenes)]
    gates = [(seed, f"gate-{i:03d}") for i, seed in enumerate(GATE_SEEDS)]
    with ThreadPoolExecutor(2) as pool:
        scenes = list(pool.map(lambda s: synth(s[0], s[1], out / "corpus" / s[1], False), corpus))
        gate_scenes = list(pool.map(lambda s: synth(s[0], s[1], out / "gate_scenes" / s[1], True), gates))

    def corpus_job(scene: Path) -> None:
        run_dir = out / "runs" / scene.name
        subprocess.run([sys.executable, __file__, "--_train", str(scene), str(run_dir)], check=True)
        for arm, stages in ARMS.items():
            subprocess.run([sys.executable, __file__, "--_pairs", str(run_dir), str(scene), str(out / f"pairs_{arm}"), *map(str, stages)], check=True)

    with ThreadPoolExecutor(2) as pool:
        list(pool.map(corpus_job, scenes))
        list(pool.map(lambda scene: gate_pairs(scene, out), gate_scenes))

    with ThreadPoolExecutor(2) as pool:
        restorers = dict(zip(ARMS, pool.map(lambda arm: train_dd2_mask([out / f"pairs_{arm}"], restorer_path(out, arm, args.steps), args.steps, out), ARMS)))
    restorers["shipped"] = SHIPPED / "restorer_dd2_mask.pt"

    sources = {arm: "steps " + " + ".join(map(str, stages)) for arm, stages in ARMS.items()} | {"shipped": "foundation"}
    print_gates(restorers, sources, out)
    return 0


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--_train":
        train_street(Path(sys.argv[2]), Path(sys.argv[3]))
    elif len(sys.argv) > 1 and sys.argv[1] == "--_pairs":
        arm_pairs(Path(sys.argv[2]), Path(sys.argv[3]), Path(sys.argv[4]), tuple(int(s) for s in sys.argv[5:]))
    else:
        sys.exit(main())
