"""Every reconstruction backbone on one default synthetic segment: time, size, quality.

Targets (issue 4), default preset, one thread: training-view PSNR above 28 dB for ``street``;
each backbone trains in under 2 minutes. Prints one row per backbone: wall and CPU seconds of
training (CPU < wall means the machine was shared), Gaussian count, PSNR/SSIM on the training
views, and PSNR/SSIM against the true novel views of shift@3, shift@6 and lane_change.

    python benchmarks/recon.py [--seed 101] [--scene DIR] [--models street pvg deformable s3]
                               [--preset default] [--iterations N] [--threads 1] [--out DIR]
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path


def mean_metrics(renders, truths) -> tuple[float, float]:
    from recondreamer.evaluation.image_metrics import psnr, ssim

    return (
        sum(psnr(r, t) for r, t in zip(renders, truths)) / len(renders),
        sum(ssim(r, t) for r, t in zip(renders, truths)) / len(renders),
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--seed", type=int, default=101, help="synthetic world seed (default: 101)"
    )
    parser.add_argument(
        "--scene",
        help="existing scene directory (default: generate the seed's default segment)",
    )
    parser.add_argument(
        "--models",
        nargs="+",
        default=["street", "pvg", "deformable", "s3"],
        help="backbones to train",
    )
    parser.add_argument(
        "--preset", default="default", help="reconstruction preset (default: default)"
    )
    parser.add_argument(
        "--iterations", type=int, help="override the preset's iterations"
    )
    parser.add_argument(
        "--threads", type=int, default=1, help="torch threads (default: 1)"
    )
    parser.add_argument(
        "--out",
        help="directory for the scene and runs (default: a temporary directory)",
    )
    args = parser.parse_args()

    import torch

    from recondreamer.recon import make_config, render_trajectory, train_scene
    from recondreamer.scene import load_scene, write_scene
    from recondreamer.scene.trajectories import (
        EVAL_TRAJECTORIES,
        trajectory_cam_to_world,
    )

    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S"
    )
    torch.set_num_threads(args.threads)
    out = Path(args.out or tempfile.mkdtemp(prefix="recon-bench-"))
    if args.scene:
        scene = load_scene(args.scene)
    else:
        from recondreamer.sources.synthetic import generate_segment

        scene_dir = out / f"scene-{args.seed}"
        if not scene_dir.exists():
            write_scene(scene_dir, generate_segment(args.seed, preset="default"))
        scene = load_scene(scene_dir)

    truth = {"original": [scene.image(t) for t in range(scene.num_frames)]}
    for name in EVAL_TRAJECTORIES:
        if name in scene.novel_trajectories:
            truth[name] = [scene.novel_image(name, t) for t in range(scene.num_frames)]
    rows = []
    for model_type in args.models:
        overrides = {"iterations": args.iterations} if args.iterations else {}
        config = make_config(model_type, args.preset, **overrides)
        run = out / f"run-{model_type}"
        wall, cpu = time.perf_counter(), time.process_time()
        model = train_scene(scene, config, run, resume=False)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        row = {
            "model": model_type,
            "iters": config.iterations,
            "wall_s": wall,
            "cpu_s": cpu,
            "gaussians": len(model.gaussians),
        }
        for name, frames in truth.items():
            poses = trajectory_cam_to_world(
                scene.cam_to_world, scene.ego_to_world, name
            )
            row[name] = mean_metrics(render_trajectory(model, scene, poses), frames)
        rows.append(row)

    names = list(truth)
    header = (
        "| model | iters | wall s | CPU s | Gaussians | "
        + " | ".join(f"{n} PSNR | {n} SSIM" for n in names)
        + " |"
    )
    print(
        f"\nscene {scene.scene_id} ({scene.width}x{scene.height}, {scene.num_frames} frames), "
        f"preset {args.preset}, {args.threads} thread(s)"
    )
    print(header)
    print("|" + "---|" * (5 + 2 * len(names)))
    for row in rows:
        cells = [
            row["model"],
            str(row["iters"]),
            f"{row['wall_s']:.1f}",
            f"{row['cpu_s']:.1f}",
            str(row["gaussians"]),
        ]
        cells += [f"{row[n][0]:.2f} | {row[n][1]:.3f}" for n in names]
        print("| " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
