"""Baseline vs DriveDreamer4D vs ReconDreamer (PDUS strides) on synthetic scenes: PSNR/SSIM vs true novel views.

    python benchmarks/methods.py --scene results/scenes/seg0 [--scene ...] --restorer models/restorer_dd2_mask.pt \
        --world-model models/world_model_dd2.pt [--model street] [--strides 1.5,6] [--preset default] \
        [--iterations N] [--work /tmp/methods-bench] [--threads 1]

Trains (or resumes) every run under ``--work``, renders shift@3, shift@6 and lane_change, and
prints one row per method and backbone: PSNR / SSIM against the scene's true novel views
(synthetic scenes only), averaged over the scenes, and the training wall time. The full gate
(NTA-IoU, NTL-IoU, FID) is the workflow's evaluation stage; this script is the quick look.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import numpy as np
import torch

from recondreamer.evaluation.image_metrics import psnr, ssim
from recondreamer.methods.dd4d import train_dd4d
from recondreamer.methods.loop import train_recondreamer
from recondreamer.methods.pdus import PdusSchedule
from recondreamer.recon import make_config, render_trajectory, train_scene
from recondreamer.generative.inference import load_restorer, load_world_model
from recondreamer.scene import load_scene
from recondreamer.scene.trajectories import EVAL_TRAJECTORIES, trajectory_cam_to_world


def novel_scores(model, scene) -> dict[str, tuple[float, float]]:
    scores = {}
    for name in EVAL_TRAJECTORIES:
        if name not in scene.novel_trajectories:
            continue
        frames = render_trajectory(model, scene, trajectory_cam_to_world(scene.cam_to_world, scene.ego_to_world, name))
        truth = [scene.novel_image(name, t) for t in range(scene.num_frames)]
        scores[name] = (float(np.mean([psnr(f, g) for f, g in zip(frames, truth)])),
                        float(np.mean([ssim(f, g) for f, g in zip(frames, truth)])))
    return scores


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", action="append", required=True, help="synthetic scene directory (repeatable)")
    parser.add_argument("--restorer", required=True, help="DriveRestorer checkpoint")
    parser.add_argument("--world-model", required=True, help="pretrained dd2 world-model checkpoint")
    parser.add_argument("--model", action="append", default=None, help="backbone (repeatable; default street)")
    parser.add_argument("--strides", default="1.5,6", help="comma-separated PDUS strides in metres")
    parser.add_argument("--preset", default="default", help="reconstruction preset")
    parser.add_argument("--iterations", type=int, default=None, help="override the preset's iterations")
    parser.add_argument("--work", default="/tmp/methods-bench", help="run directories (resumed when present)")
    parser.add_argument("--restore-strength", type=float, default=None, help="restorer strength (default: checkpoint's)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    torch.set_num_threads(args.threads)
    restorer, world = load_restorer(args.restorer), load_world_model(args.world_model)
    strides = [float(s) for s in args.strides.split(",")]
    rows: dict[tuple[str, str], list] = {}
    for scene_dir in args.scene:
        scene = load_scene(scene_dir)
        for backbone in args.model or ["street"]:
            overrides = {"iterations": args.iterations} if args.iterations else {}
            config = make_config(backbone, args.preset, backend="cpu", **overrides)
            methods = ["baseline", "dd4d", *(f"recondreamer dy={stride:g}" for stride in strides)]
            for method in methods:
                run = Path(args.work) / scene.scene_id / backbone / method.replace(" ", "_").replace("=", "")
                started = time.monotonic()
                if method == "baseline":
                    model = train_scene(scene, config, run)
                elif method == "dd4d":
                    model = train_dd4d(scene, config, run, world)
                else:
                    schedule = PdusSchedule.for_iterations(float(method.split("=")[1]), config.iterations)
                    model = train_recondreamer(scene, config, run, restorer, schedule,
                                               restore_strength=args.restore_strength)
                rows.setdefault((backbone, method), []).append((novel_scores(model, scene), time.monotonic() - started))
    print(f"{len(args.scene)} scene(s), preset {args.preset}; PSNR / SSIM vs true novel views; wall s per run "
          "(shared CPU: timings are indicative only)")
    header = "| backbone | method | " + " | ".join(EVAL_TRAJECTORIES) + " | wall s |"
    print(header)
    print("|" + "---|" * (header.count("|") - 1))
    for (backbone, method), results in rows.items():
        cells = []
        for name in EVAL_TRAJECTORIES:
            values = [scores[name] for scores, _ in results if name in scores]
            cells.append(f"{np.mean([v[0] for v in values]):.2f} / {np.mean([v[1] for v in values]):.3f}" if values else "-")
        print(f"| {backbone} | {method} | " + " | ".join(cells) + f" | {np.mean([w for _, w in results]):.0f} |")


if __name__ == "__main__":
    main()
