"""Train the evaluation models on a synthetic corpus and print their gates.

    python benchmarks/eval_models.py --out results/eval-bench [--corpus DIR | --scenes 24 --seed-base 9000]

Steps: (1) build the corpus (default preset, 240x160, 40 frames) unless --corpus is given;
(2) ``train_eval_models`` (same code as ``recondreamer train-eval-models``) with the default
step counts. Prints the gate table. How the metrics respond to degradations, on a workflow's
evaluation segments: benchmarks/metric_response.py.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path



def build_corpus(out: Path, scenes: int, seed_base: int) -> Path:
    from recondreamer.scene import write_scene
    from recondreamer.sources.synthetic import generate_segment

    corpus = out / "corpus"
    for seed in range(seed_base, seed_base + scenes):
        path = corpus / f"corpus-{seed:05d}"
        if not path.exists():
            began = time.monotonic()
            write_scene(path, generate_segment(seed, "default"))
            logging.info("corpus scene %s written in %.1fs", path.name, time.monotonic() - began)
    return corpus


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="working directory (corpus, models)")
    parser.add_argument("--corpus", type=Path, default=None, help="existing corpus directory (skips generation)")
    parser.add_argument("--scenes", type=int, default=24, help="corpus scenes to generate (default 24)")
    parser.add_argument("--seed-base", type=int, default=9000, help="first corpus seed (default 9000)")
    parser.add_argument("--holdout-scenes", type=int, default=4, help="held-out scenes for the gates (default 4)")
    parser.add_argument("--detector-steps", type=int, default=None, help="override the default detector training steps")
    parser.add_argument("--detector-upsample", type=int, default=None, help="override the detector's frame enlargement (default 1)")
    parser.add_argument("--lane-steps", type=int, default=None, help="override the default lane-segmenter training steps")
    parser.add_argument("--feature-steps", type=int, default=None, help="override the default feature-network training steps")
    parser.add_argument("--threads", type=int, default=None, help="torch threads")
    parser.add_argument("--force", action="store_true", help="retrain even if model files exist")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s", datefmt="%H:%M:%S")

    import torch

    from recondreamer.evaluation.config import EvalModelsConfig
    from recondreamer.evaluation.train_eval_models import train_eval_models
    if args.threads:
        torch.set_num_threads(args.threads)
    corpus = args.corpus or build_corpus(args.out, args.scenes, args.seed_base)
    began = time.monotonic()
    config = EvalModelsConfig(holdout_scenes=args.holdout_scenes, force=args.force)
    for name in ("detector_steps", "lane_steps", "feature_steps"):
        if getattr(args, name) is not None:
            setattr(config, name, getattr(args, name))
    if args.detector_upsample is not None:
        config.detector.upsample = args.detector_upsample
    metrics = train_eval_models(corpus, args.out / "models", config)
    seconds = time.monotonic() - began

    print(f"\nEvaluation models (corpus {corpus}, {metrics['corpus']['num_train_frames']} training frames, "
          f"{metrics['corpus']['num_heldout_frames']} held-out frames; train + gates {seconds:.0f}s wall)")
    print(f"{'model':<18} {'gate metric':<34} {'value':>8} {'gate':>6} {'passed':>7} {'train s':>8}")
    det, lane, feat = (metrics["gates"][k] for k in ("vehicle_detector", "lane_segmenter", "fid_features"))
    train_s = {k: v["training"].get("seconds", "reused") for k, v in metrics["models"].items()}
    print(f"{'vehicle_detector':<18} {'AP50 (NTA-IoU GT vehicles)':<34} {det['ap50']:>8.3f} {det['gate']:>6} {str(det['passed']):>7} {train_s['vehicle_detector']!s:>8}")
    print(f"{'':<18} {'NTA-IoU of clean held-out frames':<34} {det['nta_iou_clean']:>8.3f}")
    print(f"{'':<18} {'precision / recall at score 0.5':<34} {det['precision_at_threshold']:>8.3f} / {det['recall_at_threshold']:.3f}")
    print(f"{'lane_segmenter':<18} {'lane IoU vs visible markings':<34} {lane['lane_iou']:>8.3f} {lane['gate']:>6} {str(lane['passed']):>7} {train_s['lane_segmenter']!s:>8}")
    print(f"{'':<18} {'NTL-IoU (2-class, vs map) clean':<34} {lane['ntl_iou_clean']:>8.3f}")
    print(f"{'fid_features':<18} {'semantic pixel accuracy / mIoU':<34} {feat['pixel_accuracy']:>8.3f} / {feat['mean_iou']:.3f} {'':>6} {train_s['fid_features']!s:>8}")

    return 0


if __name__ == "__main__":
    sys.exit(main())
