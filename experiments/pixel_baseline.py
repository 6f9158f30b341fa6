"""A plain pixel-space CNN restorer, without world model or diffusion: a baseline for DriveRestorer.

Trains the pixel refiner's network (``recondreamer/generative/refiner.py``) on restoration pairs as
if there were no diffusion restorer before it (its "restored" input is the degraded render
itself), with ``train-refiner``'s loss, crops and optimiser, then scores it on held-out pairs the
way ``benchmarks/restorer.py`` scores restorers: mean per-clip PSNR gain over the degraded input
(split by orig / novel clips), flicker, CPU time. What a DriveRestorer gains beyond this number is
what its world-model prior and diffusion are worth on these pairs; docs/generative.md cites it for
that comparison (Design decisions, Refiner). Example::

    python experiments/pixel_baseline.py --pairs results/restorer-dev/pairs-train/corpus-00*.npz \\
        --heldout results/restorer-dev/pairs-heldout --steps 3000 --out results/restorer-dev/s18/pixel_baseline.pt

``--out`` is the training job's checkpoint path: a killed run resumes from ``OUT.resume.pt``, and
the finished network's weights are written there.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from types import SimpleNamespace

from recondreamer.generative.scoring import score_clip, scored_clips, summarise


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pairs", nargs="+", required=True, help="training restoration-pairs directories or .npz files")
    parser.add_argument("--heldout", nargs="+", required=True, help="held-out restoration-pairs directories or .npz files")
    parser.add_argument("--out", required=True, help="checkpoint of the trained network (and its resume file)")
    parser.add_argument("--steps", type=int, default=None, help="training steps (default: RefinerConfig's, as train-refiner)")
    parser.add_argument("--learning-rate", type=float, default=None, help="learning rate (default: RefinerConfig's, as train-refiner)")
    parser.add_argument("--no-output-norm", action="store_true",
                        help="the network without the channel norm before its last conv (as train-refiner --output-norm off)")
    parser.add_argument("--stages-per-run", type=int, default=2, help="held-out stages per pairs file, earliest to latest (0 = all; default 2)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = parser.parse_args()

    import torch

    from recondreamer.io import atomic_path
    from recondreamer.generative.config import RefinerConfig
    from recondreamer.generative.data import find_pairs_files, load_pairs_file, mapped_pair_arrays, structure_from_uint8
    from recondreamer.generative.refiner import PixelRefiner, refine_frames
    from recondreamer.generative.training import RefinerExample, refiner_loss
    from recondreamer.training_loop import finish_job, run_training_loop

    torch.set_num_threads(args.threads)
    overrides = {"steps": args.steps, "learning_rate": args.learning_rate}
    config = dataclasses.replace(RefinerConfig(), output_norm=not args.no_output_norm, **{k: v for k, v in overrides.items() if v is not None})
    examples = []
    for path in find_pairs_files(args.pairs):
        content = load_pairs_file(path)
        mapped = mapped_pair_arrays(path, content)
        examples.append(RefinerExample(str(content["scene_id"]), mapped["gt"], mapped["degraded"], mapped["degraded"], mapped["structure"]))
    torch.manual_seed(config.seed)
    network = PixelRefiner(config, examples[0].structure.shape[1])
    identity = {"kind": "pixel_baseline", "arch": "", "refiner": dataclasses.asdict(config), "pairs": sorted(str(p) for p in args.pairs)}
    stats = run_training_loop(
        "pixel baseline", network, lambda rng, generator: refiner_loss(network, examples, rng, config), config.steps,
        config.learning_rate, config.warmup_steps, args.out, identity, config.checkpoint_every, config.log_every, config.seed,
    )
    with atomic_path(args.out) as tmp:
        torch.save({"config": dataclasses.asdict(config), "state": network.state_dict(), "metrics": stats}, tmp)
    finish_job(args.out)

    trained_on = {"training_scenes": sorted({example.scene_id for example in examples})}
    clips = scored_clips(SimpleNamespace(unet_config=SimpleNamespace(uses_structure=True)), trained_on, find_pairs_files(args.heldout), args.stages_per_run)
    if not clips:
        raise SystemExit(f"no held-out clips in {args.heldout}: every scene is among the training pairs' scenes")
    records, cpu_per_40 = [], float("nan")
    for kind, degraded, gt, structure in clips:
        start = time.process_time()
        output = refine_frames(network, degraded, degraded, structure_from_uint8(structure))
        if not records:
            cpu_per_40 = (time.process_time() - start) * 40 / len(degraded)
        records.append(score_clip(kind, degraded, output, gt))
    row = summarise(records)
    print(f"pixel baseline (no world model, no diffusion): {len(examples)} training pairs files of {len(trained_on['training_scenes'])} scenes")
    header = (
        f"{'clips':>5s} {'PSNR deg':>8s} {'PSNR out':>8s} {'gain dB':>7s} {'orig':>6s} {'novel':>6s} {'flick deg':>9s} {'flick out':>9s} "
        f"{'cpu s / 40':>10s} {'train steps':>11s} {'train CPU ms/step':>17s} {'train CPU min':>13s}"
    )
    print(header)
    print("-" * len(header))
    print(
        f"{row['clips']:5d} {row['psnr_degraded']:8.2f} {row['psnr_restored']:8.2f} {row['gain']:7.2f} {row['gain_orig']:6.2f} "
        f"{row['gain_novel']:6.2f} {row['flicker_degraded']:9.2f} {row['flicker_restored']:9.2f} {cpu_per_40:10.1f} {stats['steps']:11d} "
        f"{stats['cpu_ms_per_step']:17.0f} {stats['cpu_ms_per_step'] * stats['steps'] / 60000.0:13.1f}"
    )


if __name__ == "__main__":
    main()
