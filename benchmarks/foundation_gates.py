"""The foundation's gates, measured again on a weight set and printed as a table.

    python benchmarks/foundation_gates.py [--weights weights] [--foundation-results results/foundation]

Re-measures, with the same code as the workflow's ``foundation_gates`` rule, every gate of a weight
set on the gate scenes the foundation workflow made (their Street Gaussians renders and pairs
under ``--foundation-results``): each DriveRestorer's PSNR gain and flicker on shift@3, shift@6
and original-trajectory clips, the autoencoder's PSNR, the detector's AP50 and the lane
segmenter's IoU on the gate scenes' labelled frames. Nothing is asserted: the table says which
gates pass. Runs in a few minutes on one CPU core at the compact size.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from recondreamer.foundation import gates
from recondreamer.foundation.weights import shipped_weights_dir, verify_weight_set
from recondreamer.generative.data import find_pairs_files


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--weights", type=Path, default=None, help="weight-set folder (default: the shipped set)")
    parser.add_argument("--foundation-results", type=Path, default=Path("results/foundation"), help="results_dir of the foundation workflow (gate_scenes/, gate_pairs/)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    import torch

    torch.set_num_threads(args.threads)
    folder = args.weights or shipped_weights_dir()
    manifest = verify_weight_set(folder)
    pairs = find_pairs_files(sorted((args.foundation_results / "gate_pairs").iterdir()))
    scenes = sorted((args.foundation_results / "gate_scenes").iterdir())
    print(f"weight set {folder} (code {manifest['code_version']}); gate scenes {', '.join(p.name for p in scenes)}")
    print(f"{'restorer':10} {'trajectory':10} {'clips':>5} {'render':>7} {'restored':>8} {'gain':>6} {'flicker':>13}  gate")
    for name, entry in manifest["files"].items():
        if entry["kind"] != "restorer":
            continue
        result = gates.restorer_gate(folder / name, pairs)
        for trajectory in (*gates.NOVEL_GATE_TRAJECTORIES, "original"):
            row = result.get(trajectory)
            if row:
                print(f"{entry['arch']:10} {trajectory:10} {row['clips']:5d} {row['render_psnr']:7.2f} {row['restored_psnr']:8.2f} "
                      f"{row['gain_db']:+6.2f} {row['render_flicker']:6.2f}->{row['restored_flicker']:5.2f}  "
                      + ("" if entry["arch"] != gates.GATED_RESTORER else ("pass" if result["passed"] else "FAIL")))
    autoencoder = gates.autoencoder_gate(folder / "autoencoder.pt", scenes)
    print(f"autoencoder PSNR {autoencoder['psnr_db']:.2f} dB (gate {autoencoder['gate_db']:.0f}): {'pass' if autoencoder['passed'] else 'FAIL'}")
    sampling = manifest["files"]["vehicle_detector.pt"]["training"]  # how train-eval-models sampled its held-out frames
    measured = gates.eval_models_on_scenes(folder / "vehicle_detector.pt", folder / "lane_segmenter.pt", scenes, sampling["frame_stride"], sampling["min_lidar_points"])
    for kind, key, label in (("vehicle_detector", "ap50", "AP50"), ("lane_segmenter", "lane_iou", "lane IoU")):
        row = measured[kind]
        per_scene = ", ".join(f"{scene} {ap:.3f}" for scene, ap in row.get("ap50_per_scene", {}).items())
        print(f"{kind} {label} {row[key]:.3f} (gate {row['gate']}, {len(row['scenes'])} gate scenes{'; ' + per_scene if per_scene else ''}): "
              f"{'pass' if row['passed'] else 'FAIL'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
