"""DriveRestorer backbones side by side on held-out restoration pairs.

For every restorer given (sd, svd, dd2, dd2_mask) and every degraded clip of the given pairs
files (each training stage of each held-out run), restore the clip and print:

- PSNR of the degraded and of the restored clip against ground truth, and the mean gain (dB);
- flicker: the temporal-difference error ``mean |(x[t+1] - x[t]) - (g[t+1] - g[t])|`` (0-255 units)
  of a clip x against its ground truth g: change between consecutive frames that the true video
  does not have. Lower is steadier; a per-frame model that hallucinates details independently
  per frame scores high;
- restore time of a 40-frame clip, wall-clock and process CPU seconds (measured on the first
  clip, scaled to 40 frames); with one thread the CPU seconds are the wall time on an idle core,
  the honest figure when other jobs share the machine;
- the fine-tuning job's CPU ms per training step and CPU minutes, as recorded in the checkpoint.

Pairs whose scene was in a restorer's training set are skipped for that restorer (the checkpoint
records its training scenes). Example::

    python benchmarks/restorer.py --restorer sd=R/sd.pt svd=R/svd.pt dd2=R/dd2.pt dd2_mask=R/dd2_mask.pt \\
        --pairs results/pairs_heldout
"""

from __future__ import annotations

import argparse
import multiprocessing
import time

import numpy as np


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float(10.0 * np.log10(255.0**2 / max(mse, 1e-10)))


def flicker(clip: np.ndarray, gt: np.ndarray) -> float:
    """Temporal-difference error of (T,H,W,3) uint8 clips, in 0-255 units."""
    dx = np.diff(clip.astype(np.float32), axis=0)
    dg = np.diff(gt.astype(np.float32), axis=0)
    return float(np.mean(np.abs(dx - dg)))


def mean(values: list[float]) -> float:
    return float(np.mean(values)) if values else float("nan")


def evaluate_restorer(item: str, pair_files: list, steps: int | None, strength: float | None, stages_per_run: int, threads: int) -> tuple:
    """One table row: ARCH=CHECKPOINT restored on every held-out clip of the pairs files."""
    import torch

    from recondreamer.restorer.checkpoint import load_checkpoint
    from recondreamer.restorer.data import load_pairs_file
    from recondreamer.restorer.inference import load_restorer, restore_clip

    torch.set_num_threads(threads)
    arch, _, path = item.partition("=")
    restorer = load_restorer(path)
    payload = load_checkpoint(path, "restorer")
    trained_on = set(payload.get("training_scenes", []))
    train_ms = payload.get("metrics", {}).get("cpu_ms_per_step", float("nan"))
    train_minutes = train_ms * payload.get("metrics", {}).get("steps", 0) / 60000.0
    gains, degraded_psnr, restored_psnr, flicker_degraded, flicker_restored = [], [], [], [], []
    seconds_per_40 = cpu_seconds_per_40 = float("nan")
    for file in pair_files:
        content = load_pairs_file(file)
        if str(content["scene_id"]) in trained_on:
            continue
        gt = content["gt"]
        structure = content["structure"] if restorer.unet_config.uses_structure else None
        stages = np.arange(len(content["degraded"]))
        if stages_per_run:
            stages = np.unique(np.linspace(0, len(stages) - 1, stages_per_run).round().astype(int))
        for degraded in content["degraded"][stages]:
            start, start_cpu = time.perf_counter(), time.process_time()
            restored = restore_clip(restorer, degraded, structure, num_steps=steps, strength=strength)
            seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - start_cpu
            if not gains:
                seconds_per_40 = seconds * 40 / len(degraded)
                cpu_seconds_per_40 = cpu_seconds * 40 / len(degraded)
            d = np.mean([psnr(a, b) for a, b in zip(degraded, gt)])
            r = np.mean([psnr(a, b) for a, b in zip(restored, gt)])
            degraded_psnr.append(d)
            restored_psnr.append(r)
            gains.append(r - d)
            flicker_degraded.append(flicker(degraded, gt))
            flicker_restored.append(flicker(restored, gt))
    return (
        arch or restorer.arch, len(gains), mean(degraded_psnr), mean(restored_psnr), mean(gains),
        mean(flicker_degraded), mean(flicker_restored), seconds_per_40, cpu_seconds_per_40, train_ms, train_minutes,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--restorer", nargs="+", required=True, help="ARCH=CHECKPOINT pairs")
    parser.add_argument("--pairs", nargs="+", required=True, help="held-out restoration-pairs directories or .npz files")
    parser.add_argument("--steps", type=int, default=None, help="DDIM steps (default: each checkpoint's)")
    parser.add_argument("--strength", type=float, default=None, help="sampling strength, 1 = from noise (default: each checkpoint's)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads per restorer (default 1)")
    parser.add_argument("--jobs", type=int, default=1, help="restorers evaluated in parallel processes (default 1)")
    parser.add_argument(
        "--stages-per-run", type=int, default=0,
        help="evaluate this many training stages per pairs file, spread from earliest to latest (0 = all)",
    )
    args = parser.parse_args()

    from recondreamer.restorer.data import find_pairs_files

    files = find_pairs_files(args.pairs)
    jobs = [(item, files, args.steps, args.strength, args.stages_per_run, args.threads) for item in args.restorer]
    if args.jobs > 1:
        with multiprocessing.get_context("spawn").Pool(args.jobs) as pool:
            rows = pool.starmap(evaluate_restorer, jobs)
    else:
        rows = [evaluate_restorer(*job) for job in jobs]
    header = (
        f"{'backbone':10s} {'clips':>5s} {'PSNR deg':>9s} {'PSNR rest':>9s} {'gain dB':>8s} {'flick deg':>9s} {'flick rest':>10s} "
        f"{'s / 40 fr':>9s} {'cpu s / 40':>10s} {'train CPU ms/step':>17s} {'train CPU min':>13s}"
    )
    print(f"DDIM steps {args.steps or 'default'}, strength {args.strength or 'default'}, threads={args.threads}; wall-clock timings depend on other jobs sharing the CPU, CPU seconds much less")
    print(header)
    print("-" * len(header))
    for arch, clips, d, r, g, fd, fr, s, cpu_s, ms, minutes in rows:
        print(f"{arch:10s} {clips:5d} {d:9.2f} {r:9.2f} {g:8.2f} {fd:9.2f} {fr:10.2f} {s:9.1f} {cpu_s:10.1f} {ms:17.0f} {minutes:13.1f}")


if __name__ == "__main__":
    main()
