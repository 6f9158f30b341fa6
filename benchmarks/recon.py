"""Every reconstruction backbone on one default synthetic segment: time, size, quality.

Targets (issue 4), default preset, one thread: training-view PSNR above 28 dB for ``street``;
each backbone trains in under 2 minutes. Prints one row per backbone: wall and CPU seconds of
training (CPU < wall means the machine was shared), Gaussian count, PSNR/SSIM on the training
views, and PSNR/SSIM against the true novel views of shift@3, shift@6 and lane_change.

    python benchmarks/recon.py [--seed 101] [--scene DIR] [--models street pvg deformable s3]
                               [--preset default] [--iterations N] [--threads 1] [--out DIR]
                               [--profile START STOP]

``--profile START STOP`` also runs torch.profiler over training steps START..STOP-1 of every
backbone and prints its CPU time per step and the operators that take most of it.

``--stages RUNS`` trains nothing: it loads ``RUNS/run-<model>`` (the ``--out`` of an earlier
run) and prints, per backbone, the CPU milliseconds of each stage of a full-resolution training
step on that trained model, with the reference twin of every fast path next to it (kornia SSIM,
targets converted every step, for-loop Adam).
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


def cpu_ms(function, repeats: int = 10) -> float:
    """Mean CPU milliseconds of ``function()`` after two warm-up calls."""
    for _ in range(2):
        function()
    start = time.process_time()
    for _ in range(repeats):
        function()
    return 1e3 * (time.process_time() - start) / repeats


def stage_times(model, scene, config) -> dict[str, float]:
    """CPU ms of the stages of one full-resolution training step of ``model`` (frame 20's view)."""
    import numpy as np
    import torch

    from recondreamer.recon.base import rigid_inverse
    from recondreamer.recon.data import TargetCache, TrainingSet
    from recondreamer.recon.density import build_optimizer
    from recondreamer.recon.losses import image_tensor, ssim_loss
    from recondreamer.recon.sky import pixel_ray_directions
    from recondreamer.recon.ssim import mean_ssim
    from recondreamer.scene.cameras import rasterizer_intrinsics
    from recondreamer.splat import rasterize

    view = TrainingSet.from_scene(scene, [scene.num_frames // 2])[0]
    targets = TargetCache(config.loss.ssim_window).get(view, scene.K)
    time_now = model.normalized_time(view.timestamp)
    cam_to_world = torch.tensor(np.asarray(view.cam_to_world), dtype=torch.float32)
    K = rasterizer_intrinsics(torch.tensor(np.asarray(scene.K), dtype=torch.float32))
    viewmat = rigid_inverse(cam_to_world)
    model.train()

    def deformation():
        g = model.gaussians_at(time_now)
        sum(value.sum() for value in g.values()).backward()

    with torch.no_grad():
        fixed = model.gaussians_at(time_now)
        colors = model.gaussians.sh_coefficients()
    leaves = {k: v.detach().clone().requires_grad_(True) for k, v in fixed.items()}

    def rasterizer():
        out = rasterize(
            leaves["means"], leaves["quats"], leaves["scales"], leaves["opacities"],
            colors, viewmat, K, scene.width, scene.height, backend=config.backend,
        )  # fmt: skip
        (out["rgb"].sum() + out["depth"].sum()).backward()

    image = targets.image.image
    pred = (image + 0.05 * torch.randn_like(image)).clamp(0, 1).requires_grad_(True)

    def kornia_ssim():
        ssim_loss(pred, image, config.loss.ssim_window).backward()

    def fast_ssim():
        (1.0 - mean_ssim(pred, targets.image)).backward()

    def uncached_targets():
        image_tensor(view.image)
        torch.from_numpy(np.array(view.depth, dtype=np.float32))
        torch.from_numpy(np.array(view.sky_mask, dtype=bool))
        pixel_ray_directions(cam_to_world, K, scene.width, scene.height)

    cache = TargetCache(config.loss.ssim_window)
    cache.get(view, scene.K)

    def cached_targets():
        cache.get(view, scene.K)

    def sky():
        model.sky(targets.ray_directions).sum().backward()

    for param in model.parameters():
        param.grad = torch.randn_like(param) * 1e-3
    fused = build_optimizer(model, config.optim)
    loop = torch.optim.Adam(
        [
            {"params": group["params"], "lr": group["lr"]}
            for group in fused.param_groups
        ],
        eps=1e-15,
        foreach=False,
    )
    return {
        "deformation fwd+bwd": cpu_ms(deformation),
        "rasterize fwd+bwd": cpu_ms(rasterizer),
        "SSIM fwd+bwd kornia": cpu_ms(kornia_ssim),
        "SSIM fwd+bwd fast": cpu_ms(fast_ssim),
        "targets uncached": cpu_ms(uncached_targets),
        "targets cached": cpu_ms(cached_targets),
        "sky fwd+bwd": cpu_ms(sky),
        "Adam for-loop": cpu_ms(loop.step),
        "Adam fused": cpu_ms(fused.step),
    }


class StepProfiler:
    """Trainer callback: torch.profiler over steps [start, stop), CPU time per step."""

    def __init__(self, start: int, stop: int) -> None:
        from torch.profiler import ProfilerActivity, profile

        self.start, self.stop = start, stop
        self.profiler = profile(activities=[ProfilerActivity.CPU])
        self.cpu = 0.0

    def __call__(self, trainer) -> None:
        if trainer.step == self.start:
            self.profiler.start()
            self.cpu = time.process_time()
        elif trainer.step == self.stop:
            self.cpu = time.process_time() - self.cpu
            self.profiler.stop()

    def report(self, model_type: str) -> None:
        steps = self.stop - self.start
        print(
            f"\n{model_type}: steps {self.start}-{self.stop - 1}, "
            f"{1e3 * self.cpu / steps:.1f} ms CPU per step under the profiler"
        )
        print(
            self.profiler.key_averages().table(
                sort_by="self_cpu_time_total", row_limit=15, max_name_column_width=40
            )
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
    parser.add_argument(
        "--profile",
        nargs=2,
        type=int,
        metavar=("START", "STOP"),
        help="profile training steps START..STOP-1 of every backbone (operator table)",
    )
    parser.add_argument(
        "--stages",
        metavar="RUNS",
        help="print per-stage CPU times of the trained runs RUNS/run-<model> (no training)",
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

    if args.stages:
        from recondreamer.recon import load_model

        times = {
            model_type: stage_times(
                load_model(Path(args.stages) / f"run-{model_type}"),
                scene,
                make_config(model_type, args.preset),
            )
            for model_type in args.models
        }
        print(
            f"\nCPU ms per call, {args.threads} thread(s), trained models of {args.stages}"
        )
        print("| stage | " + " | ".join(args.models) + " |")
        print("|---|" + "---|" * len(args.models))
        for stage in next(iter(times.values())):
            cells = [f"{times[m][stage]:.2f}" for m in args.models]
            print(f"| {stage} | " + " | ".join(cells) + " |")
        return 0

    truth = {"original": [scene.image(t) for t in range(scene.num_frames)]}
    for name in EVAL_TRAJECTORIES:
        if name in scene.novel_trajectories:
            truth[name] = [scene.novel_image(name, t) for t in range(scene.num_frames)]
    rows = []
    for model_type in args.models:
        overrides = {"iterations": args.iterations} if args.iterations else {}
        config = make_config(model_type, args.preset, **overrides)
        run = out / f"run-{model_type}"
        profiler = StepProfiler(*args.profile) if args.profile else None
        wall, cpu = time.perf_counter(), time.process_time()
        model = train_scene(
            scene, config, run, resume=False, callbacks=[profiler] if profiler else ()
        )
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        if profiler is not None:
            profiler.report(model_type)
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
