"""Sub-commands of the evaluation stage: train-eval-models, evaluate, fid-pool, judge,
study-page, study-ingest."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from recondreamer.cli_options import add_config_options, apply_options
from recondreamer.evaluation.config import DetectorConfig, EvalModelsConfig, ScoringConfig

log = logging.getLogger(__name__)

GATE_FAILED_EXIT = 3
EVAL_MODELS_OPTIONS = ("detector_steps", "lane_steps", "feature_steps", "batch_size", "frame_stride", "holdout_scenes", "max_scenes",
                       "min_lidar_points", "crop", "device", "seed")
SCORING_OPTIONS = ("min_lidar_points", "score_threshold")  # ScoringConfig fields evaluate takes as flags


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "train-eval-models",
        help="train the vehicle detector, lane segmenter and FID feature network on a synthetic corpus",
        description="Train the evaluation models on the corpus scenes (never on evaluation segments), score "
        "their gates (detector AP50 >= 0.9, lane IoU >= 0.7) on held-out corpus scenes and write model files "
        "plus metrics.json to OUT. Existing model files in OUT are reused unless --force.",
    )
    p.add_argument("--corpus", required=True, type=Path, help="directory of corpus scene directories")
    p.add_argument("--out", required=True, type=Path, help="output directory for the model files and metrics.json")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    p.add_argument("--force", action="store_true", help="retrain models whose files already exist in OUT")
    add_config_options(p, EvalModelsConfig, EVAL_MODELS_OPTIONS, title="training (EvalModelsConfig)")
    add_config_options(p, DetectorConfig, ("upsample",), prefix="detector-", title="vehicle detector (DetectorConfig)")
    p.add_argument("--require-gates", action="store_true", help=f"exit with code {GATE_FAILED_EXIT} when a gate is not met")
    p.set_defaults(func=_train_eval_models)

    p = subparsers.add_parser(
        "evaluate",
        help="NTA-IoU, NTL-IoU, FID (and PSNR/SSIM against true novel views) of rendered frames",
        description="Score the renders of one scene along one or more trajectories. Give --trajectory and "
        "--renders once per trajectory, in the same order. With --run, the trained reconstruction is first "
        "rendered along each trajectory into its --renders directory (one process for both steps, as the "
        "workflow does). Writes every metric and the settings that produced it to --out, and the FID features "
        "to --features-out (for fid-pool).",
    )
    p.add_argument("--scene", required=True, type=Path, help="scene directory the renders belong to")
    p.add_argument("--renders", required=True, action="append", type=Path, help="directory of rendered frames 000.png... (repeatable; written first when --run is given)")
    p.add_argument("--run", type=Path, default=None, help="run directory of a trained reconstruction to render into the --renders directories first (default: score existing renders)")
    p.add_argument("--trajectory", required=True, action="append", help="trajectory of the matching --renders: original, shift@Y, lane_change or file:PATH (repeatable)")
    p.add_argument("--models", type=Path, default=None, help="directory written by train-eval-models")
    p.add_argument("--detector", type=Path, default=None, help="vehicle detector model file, or Ultralytics YOLO weights such as yolo11x.pt (needs the [yolo] extra; overrides --models)")
    p.add_argument("--lane-model", type=Path, default=None, help="lane segmenter model file (overrides --models)")
    p.add_argument("--fid-model", type=Path, default=None, help="FID feature network file (overrides --models): a train-eval-models fid_features.pt, or a local copy of pytorch-fid's InceptionV3 weights (pt_inception-2015-12-05-6726825d.pth) for the published FID's 2048-d pool features")
    add_config_options(p, ScoringConfig, SCORING_OPTIONS, title="scoring (ScoringConfig)")
    p.add_argument("--out", required=True, type=Path, help="metrics JSON file to write")
    p.add_argument("--features-out", type=Path, default=None, help="FID feature file (default: OUT with suffix .features.npz)")
    p.add_argument("--device", default="cpu", help="torch device to render the --run on, e.g. cpu or cuda (default cpu; the metric networks run on the CPU)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    p.set_defaults(func=_evaluate)

    p = subparsers.add_parser(
        "fid-pool",
        help="FID and KID pooled over several evaluate runs (scenes and trajectories)",
        description="Pool the FID features written by several 'evaluate' runs: all rendered frames (of every "
        "trajectory, or of --trajectory) against all reference frames (one set per scene). FID is computed in the "
        "leading principal subspace of the reference features (one dimension per 4 samples of the smaller set), "
        "KID in the full feature space.",
    )
    p.add_argument("features", nargs="+", type=Path, help="feature files (.features.npz) written by evaluate")
    p.add_argument("--trajectory", default=None, help="pool only this trajectory's renders (default: every trajectory)")
    p.add_argument("--out", required=True, type=Path, help="JSON file to write")
    p.set_defaults(func=_fid_pool)

    p = subparsers.add_parser(
        "judge",
        help="automatic preference judge: win rates from closeness to the true novel views",
        description="For each clip (scene, trajectory, two methods' renders) prefer the method whose renders are "
        "closer to the scene's true views of that trajectory; write win rates per trajectory (the paper's table 3).",
    )
    p.add_argument("--clip", required=True, action="append", nargs=4, metavar=("SCENE_DIR", "TRAJECTORY", "A=DIR", "B=DIR"), help="one comparison (repeatable)")
    p.add_argument("--metric", choices=["ssim", "psnr"], default="ssim", help="closeness measure: mean per-frame SSIM (default) or PSNR")
    p.add_argument("--out", required=True, type=Path, help="win-rate JSON file to write")
    p.set_defaults(func=_judge)

    p = subparsers.add_parser(
        "study-page",
        help="static HTML page for a human preference study (offline, choices saved as CSV)",
        description="Write OUT/index.html with one pair of animated videos per clip, random top/bottom placement "
        "(recorded in OUT/placement.json, not shown on the page) and a button that downloads the choices as CSV.",
    )
    p.add_argument("--clip", required=True, action="append", nargs=4, metavar=("LABEL", "TRAJECTORY", "A=DIR", "B=DIR"), help="one pair of renders: a scene label, the trajectory, two methods (repeatable)")
    p.add_argument("--out", required=True, type=Path, help="output directory of the page")
    p.add_argument("--seed", type=int, default=0, help="seed of the clip order and placement (default 0)")
    p.add_argument("--fps", type=float, default=10.0, help="frames per second of the videos (default 10)")
    p.add_argument("--format", choices=["webp", "gif"], default="webp", help="animation format (default webp)")
    p.add_argument("--max-width", type=int, default=None, help="downscale wider frames to this width")
    p.set_defaults(func=_study_page)

    p = subparsers.add_parser("study-ingest", help="win rates from study-page CSV files", description="Join the downloaded choice CSVs with the page's placement.json and write win rates per trajectory.")
    p.add_argument("csv", nargs="+", type=Path, help="CSV files downloaded from the study page")
    p.add_argument("--placement", required=True, type=Path, help="placement.json written by study-page")
    p.add_argument("--out", required=True, type=Path, help="win-rate JSON file to write")
    p.set_defaults(func=_study_ingest)


def _train_eval_models(args: argparse.Namespace) -> int:
    import torch

    from recondreamer.evaluation.train_eval_models import train_eval_models

    detector = apply_options(args, DetectorConfig(), ("upsample",), prefix="detector-")
    config = apply_options(args, EvalModelsConfig(force=args.force, detector=detector), EVAL_MODELS_OPTIONS)
    if args.threads:
        torch.set_num_threads(args.threads)
    metrics = train_eval_models(args.corpus, args.out, config)
    for kind, gate in metrics["gates"].items():
        log.info("%s: %s", kind, ", ".join(f"{k}={v}" for k, v in gate.items()))
    if not metrics["all_gates_passed"]:
        log.warning("a gate is not met; see %s", args.out / "metrics.json")
        return GATE_FAILED_EXIT if args.require_gates else 0
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    import torch

    from recondreamer.errors import RecondreamerError
    from recondreamer.evaluation.evaluate import evaluate_scene, load_eval_models, write_features
    from recondreamer.io import write_json_atomic
    from recondreamer.device import resolve_device

    if len(args.renders) != len(args.trajectory):
        raise RecondreamerError(f"give one --renders per --trajectory: got {len(args.renders)} --renders and {len(args.trajectory)} --trajectory")
    scoring = apply_options(args, ScoringConfig(), SCORING_OPTIONS)
    if args.threads:
        torch.set_num_threads(args.threads)
    device = resolve_device(args.device, "--device")
    models = load_eval_models(args.models, args.detector, args.lane_model, args.fid_model)
    if args.run is not None:
        from recondreamer.recon.checkpoint import load_model
        from recondreamer.recon.render import render_to_directories
        from recondreamer.scene import load_scene

        render_to_directories(load_model(args.run).to(device), load_scene(args.scene), list(zip(args.trajectory, args.renders)))
    document, features = evaluate_scene(args.scene, list(zip(args.trajectory, args.renders)), models, scoring.min_lidar_points, scoring.score_threshold)
    features_out = args.features_out or args.out.with_suffix(".features.npz")
    document["settings"]["features_file"] = str(features_out)
    write_features(features_out, document["scene"]["scene_id"], features, models.features)
    write_json_atomic(args.out, document)
    log.info("wrote %s", args.out)
    return 0


def _fid_pool(args: argparse.Namespace) -> int:
    from recondreamer.evaluation.evaluate import pooled_fid
    from recondreamer.io import write_json_atomic

    result = pooled_fid(args.features, args.trajectory)
    write_json_atomic(args.out, result)
    log.info("pooled FID %.4f (%d dims), KID %.5f +- %.5f over %d scenes -> %s", result["fid"], result["fid_dim"], result["kid"], result["kid_std"], result["num_scenes"], args.out)
    return 0


def _judge(args: argparse.Namespace) -> int:
    from recondreamer.frames_io import read_frame_folder
    from recondreamer.evaluation.study import Comparison, judge_pair, parse_method, win_rates
    from recondreamer.io import write_json_atomic
    from recondreamer.scene import load_scene

    comparisons, decisions = [], []
    for scene_dir, trajectory, first, second in args.clip:
        scene = load_scene(scene_dir)
        if trajectory == "original":
            truth = [scene.image(t) for t in range(scene.num_frames)]
        else:
            from recondreamer.errors import RecondreamerError

            if trajectory not in scene.novel_trajectories:
                raise RecondreamerError(f"{scene_dir}: no true views of trajectory {trajectory!r} to judge against (has {scene.novel_trajectories or 'none'})")
            truth = [scene.novel_image(trajectory, t) for t in range(scene.num_frames)]
        (name_a, dir_a), (name_b, dir_b) = parse_method(first), parse_method(second)
        frames_a = read_frame_folder(dir_a, scene.num_frames, (scene.width, scene.height))
        frames_b = read_frame_folder(dir_b, scene.num_frames, (scene.width, scene.height))
        verdict, score_a, score_b = judge_pair(truth, frames_a, frames_b, args.metric)
        winner = {"a": name_a, "b": name_b, "tie": None}[verdict]
        comparisons.append(Comparison(trajectory, name_a, name_b, winner))
        decisions.append({"scene": scene.scene_id, "trajectory": trajectory, name_a: score_a, name_b: score_b, "winner": winner})
        log.info("%s %s: %s %.4f vs %s %.4f -> %s", scene.scene_id, trajectory, name_a, score_a, name_b, score_b, winner or "tie")
    result = {**win_rates(comparisons), "judge": f"automatic: higher mean per-frame {args.metric.upper()} against the true novel views", "decisions": decisions}
    write_json_atomic(args.out, result)
    return 0


def _study_page(args: argparse.Namespace) -> int:
    from recondreamer.evaluation.study import Clip, build_study_page, parse_method

    clips = [Clip(label, trajectory, (parse_method(first), parse_method(second))) for label, trajectory, first, second in args.clip]
    build_study_page(clips, args.out, seed=args.seed, fps=args.fps, media_format=args.format, max_width=args.max_width)
    log.info("wrote %s with %d clips", args.out / "index.html", len(clips))
    return 0


def _study_ingest(args: argparse.Namespace) -> int:
    from recondreamer.evaluation.study import read_study_csvs, win_rates
    from recondreamer.io import write_json_atomic

    comparisons = read_study_csvs(args.csv, args.placement)
    write_json_atomic(args.out, {**win_rates(comparisons), "judge": "people (study page)", "num_answers": len(comparisons)})
    log.info("%d answers -> %s", len(comparisons), args.out)
    return 0
