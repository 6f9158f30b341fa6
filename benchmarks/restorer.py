"""DriveRestorer backbones side by side on held-out restoration pairs.

For every restorer given (sd, svd, dd2, dd2_mask), every sampling setting (DDIM steps x strength)
and every degraded clip of the given pairs files (each training stage of each held-out run and
trajectory), restore the clip and print:

- PSNR of the degraded and of the restored clip against ground truth, and the mean gain (dB), over
  all clips and split by pairs kind: ``orig`` (training-view renders of snapshots, paper Fig. 3)
  and ``novel`` (renders along a true novel trajectory of a synthetic scene, see ``pairs.py``);
- flicker: the temporal-difference error ``mean |(x[t+1] - x[t]) - (g[t+1] - g[t])|`` (0-255 units)
  of a clip x against its ground truth g: change between consecutive frames that the true video
  does not have. Lower is steadier; a per-frame model that hallucinates details independently
  per frame scores high;
- restore time of a 40-frame clip, wall-clock and process CPU seconds (measured on the first
  clip, scaled to 40 frames); with one thread the CPU seconds are the wall time on an idle core,
  the honest figure when other jobs share the machine;
- the fine-tuning job's steps, training-timestep power, CPU ms per step and CPU minutes, as
  recorded in the checkpoint (steps and minutes summed over the jobs of a restorer trained further
  from another with ``--init-restorer``; ms per step of the last job);
- the noise draws averaged per restored window (``--samples``, default each checkpoint's);
- the restorer's target space: ``residual`` (it diffuses the correction to its input) or ``clean``;
- for a restorer with a pixel refiner (``train-refiner``): every setting with and without the
  refiner (column ``refine``), and the refiner job's CPU minutes (training, and restoring its
  pairs where they were not cached yet).

Pairs whose scene was in a restorer's training set are skipped for that restorer (the checkpoint
records its training scenes). ``--training-scenes`` scores the opposite set, only clips of the
restorer's own training scenes: the gap between that gain and the held-out gain measures how much of
what a restorer learned is specific to the scenes it saw. Example::

    python benchmarks/restorer.py --restorer sd=R/sd.pt svd=R/svd.pt dd2=R/dd2.pt dd2_mask=R/dd2_mask.pt \\
        --pairs results/pairs_heldout --steps 1 4 10 --strength 1.0 0.6 0.3 --residual-decoding on off
"""

from __future__ import annotations

import argparse
import itertools
import multiprocessing
import time

from recondreamer.generative.scoring import score_clip, scored_clips, summarise


def evaluate_restorer(
    item: str, pair_files: list, settings: list, stages_per_run: int, threads: int, training_scenes: bool = False
) -> list[dict]:
    """Rows for ARCH=CHECKPOINT: every (steps, strength) setting over every held-out clip (or every
    clip of its training scenes)."""
    import torch

    from recondreamer.generative.checkpoint import load_checkpoint
    from recondreamer.generative.inference import load_restorer, restore_clip
    from recondreamer.generative.training import training_totals

    torch.set_num_threads(threads)
    arch, _, path = item.partition("=")
    restorer = load_restorer(path)
    payload = load_checkpoint(path, "restorer")
    metrics = payload.get("metrics", {})
    train_ms = metrics.get("cpu_ms_per_step", float("nan"))
    train_steps, train_minutes = training_totals(metrics)  # every job of a restorer trained further (--init-restorer)
    timestep_power = payload["config"]["train"].get("timestep_power", float("nan"))
    clips = scored_clips(restorer, payload, pair_files, stages_per_run, training_scenes)
    refiner_metrics = (payload.get("refiner") or {}).get("metrics", {})
    refiner_minutes = refiner_metrics.get("cpu_ms_per_step", float("nan")) * refiner_metrics.get("steps", 0) / 60000.0 + refiner_metrics.get(
        "pairs_cpu_minutes", 0.0
    )
    refine_options = [True, False] if restorer.refiner is not None else [False]
    rows = []
    for (steps, strength, residual, samples), refine in itertools.product(settings, refine_options):
        records = []
        seconds_per_40 = cpu_seconds_per_40 = float("nan")
        for kind, degraded, gt, structure in clips:
            start, start_cpu = time.perf_counter(), time.process_time()
            restored = restore_clip(
                restorer, degraded, structure, num_steps=steps, strength=strength, residual_decoding=residual, samples=samples,
                refine=refine,
            )
            seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - start_cpu
            if not records:
                seconds_per_40 = seconds * 40 / len(degraded)
                cpu_seconds_per_40 = cpu_seconds * 40 / len(degraded)
            records.append(score_clip(kind, degraded, restored, gt))
        rows.append({
            "arch": arch or restorer.arch,
            "space": restorer.diffusion_config.target_space,
            "steps": steps or restorer.restore_config.sample_steps,
            "strength": strength or restorer.restore_config.strength,
            "residual": restorer.restore_config.residual_decoding if residual is None else residual,
            "samples": samples or restorer.restore_config.samples,
            "refine": "on" if refine else ("off" if restorer.refiner is not None else "-"),
            "refiner_minutes": refiner_minutes if restorer.refiner is not None else float("nan"),
            **summarise(records),  # clips, PSNR, gain (all / orig / novel), flicker
            "seconds_per_40": seconds_per_40,
            "cpu_seconds_per_40": cpu_seconds_per_40,
            "train_steps": int(train_steps),
            "timestep_power": timestep_power,
            "train_ms": train_ms,
            "train_minutes": train_minutes,
        })
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--restorer", nargs="+", required=True, help="ARCH=CHECKPOINT pairs")
    parser.add_argument("--pairs", nargs="+", required=True, help="held-out restoration-pairs directories or .npz files")
    parser.add_argument("--steps", type=int, nargs="+", default=[None], help="DDIM step counts to try (default: each checkpoint's)")
    parser.add_argument("--strength", type=float, nargs="+", default=[None], help="sampling strengths to try, 1 = from noise (default: each checkpoint's)")
    parser.add_argument(
        "--residual-decoding", choices=["on", "off"], nargs="+", default=[None],
        help="decode only the change and add it to the input (default: each checkpoint's)",
    )
    parser.add_argument(
        "--samples", type=int, nargs="+", default=[None], help="noise draws averaged per window to try (default: each checkpoint's)"
    )
    parser.add_argument("--threads", type=int, default=1, help="torch threads per restorer (default 1)")
    parser.add_argument("--jobs", type=int, default=1, help="restorers evaluated in parallel processes (default 1)")
    parser.add_argument(
        "--stages-per-run", type=int, default=0,
        help="evaluate this many training stages per pairs file, spread from earliest to latest (0 = all)",
    )
    parser.add_argument(
        "--training-scenes", action="store_true",
        help="score only clips of each restorer's own training scenes (default: only held-out scenes)",
    )
    args = parser.parse_args()

    from recondreamer.generative.data import find_pairs_files

    files = find_pairs_files(args.pairs)
    residual = [None if value is None else value == "on" for value in args.residual_decoding]
    settings = list(itertools.product(args.steps, args.strength, residual, args.samples))
    jobs = [(item, files, settings, args.stages_per_run, args.threads, args.training_scenes) for item in args.restorer]
    if args.jobs > 1:
        with multiprocessing.get_context("spawn").Pool(args.jobs) as pool:
            rows = [row for result in pool.starmap(evaluate_restorer, jobs) for row in result]
    else:
        rows = [row for job in jobs for row in evaluate_restorer(*job)]
    header = (
        f"{'backbone':10s} {'space':>8s} {'steps':>5s} {'strngth':>7s} {'resid':>5s} {'samples':>7s} {'refine':>6s} {'clips':>5s} {'PSNR deg':>8s} {'PSNR rest':>9s} {'gain dB':>7s} "
        f"{'orig':>6s} {'novel':>6s} {'flick deg':>9s} {'flick rest':>10s} {'s / 40 fr':>9s} {'cpu s / 40':>10s} "
        f"{'train steps':>11s} {'t power':>7s} {'train CPU ms/step':>17s} {'train CPU min':>13s} {'refiner CPU min':>15s}"
    )
    scored = "clips of each restorer's training scenes" if args.training_scenes else "held-out clips"
    print(f"{scored}; threads={args.threads}; wall-clock timings depend on other jobs sharing the CPU, CPU seconds much less")
    print(header)
    print("-" * len(header))
    for row in sorted(rows, key=lambda r: (r["residual"], r["steps"], -r["strength"], r["samples"])):
        print(
            f"{row['arch']:10s} {row['space']:>8s} {row['steps']:5d} {row['strength']:7.2f} {'on' if row['residual'] else 'off':>5s} {row['samples']:7d} {row['refine']:>6s} {row['clips']:5d} {row['psnr_degraded']:8.2f} "
            f"{row['psnr_restored']:9.2f} {row['gain']:7.2f} {row['gain_orig']:6.2f} {row['gain_novel']:6.2f} "
            f"{row['flicker_degraded']:9.2f} {row['flicker_restored']:10.2f} {row['seconds_per_40']:9.1f} "
            f"{row['cpu_seconds_per_40']:10.1f} {row['train_steps']:11d} {row['timestep_power']:7g} {row['train_ms']:17.0f} {row['train_minutes']:13.1f} {row['refiner_minutes']:15.1f}"
        )


if __name__ == "__main__":
    main()
