"""How each metric responds to true views and to known degradations, and whether it ranks the
upper bound above the baseline; writes both tables into docs/evaluation.md.

    python benchmarks/metric_response.py --results results [--write-docs docs/evaluation.md]

Part 1 (metric response): on the workflow's evaluation segments (their true novel views) and
with the workflow's evaluation models, score for each trajectory of ``--trajectories``: the
true novel views, Gaussian blur (sigma 2 px), noise (sigma 25 grey levels) and the original
frames passed off as the shifted ones (a camera that did not move). NTA-IoU, NTL-IoU, PSNR and
SSIM are means over segments; FID and KID pool all segments, as the tables do.

Part 2 (metric validity): from the workflow's metric files, the upper bound (ReconDreamer with
the true novel views in the loop) against the baseline of the ablation backbone at the widest
shift: on how many segments each metric ranks the upper bound first, and the two FID protocols
side by side (the mean of per-segment FIDs against the pooled FID the tables use). Then the FID
feature choice: pooled FID/KID of the baseline, the upper bound and the true novel views on
every trajectory, with the feature network's last-stage pool alone and with the pools of its
three stages (what ``evaluate`` uses).

Also prints the evaluation models' gates (``metrics.json`` beside them). The models are the run's
own (``RESULTS/eval_models``) or, for a run on a weight set, the folder that built the set's
(``--eval-models results/foundation/eval_models``). ``--write-docs``
replaces the text between the markers ``<!-- metric-response:begin -->`` and
``<!-- metric-response:end -->`` (and ``<!-- eval-gates:... -->`` for the gates) of that file.
"""

from __future__ import annotations

import argparse
import json
import logging
import shlex
import sys
from pathlib import Path

import numpy as np

BEGIN, END = "<!-- metric-response:begin -->", "<!-- metric-response:end -->"
GATES_BEGIN, GATES_END = "<!-- eval-gates:begin -->", "<!-- eval-gates:end -->"


def gates_table(metrics_file: Path) -> str:
    """The evaluation models' gates as train-eval-models recorded them."""
    metrics = json.loads(metrics_file.read_text())
    det, lane, feat = (metrics["gates"][k] for k in ("vehicle_detector", "lane_segmenter", "fid_features"))
    corpus = metrics["corpus"]
    return "\n".join([
        f"Gates of `{metrics_file}` ({corpus['num_train_frames']} training frames, {corpus['num_heldout_frames']} held-out frames of "
        f"{len(corpus['heldout_scenes'])} held-out corpus scenes):",
        "",
        "| model | metric | value | gate |",
        "|---|---|---|---|",
        f"| vehicle detector | AP50 on NTA-IoU ground-truth vehicles | {det['ap50']:.3f} | >= {det['gate']} ({'passed' if det['passed'] else 'missed'}) |",
        f"| | precision / recall at score {det['score_threshold']} | {det['precision_at_threshold']:.3f} / {det['recall_at_threshold']:.3f} | |",
        f"| | NTA-IoU of the clean held-out frames | {det['nta_iou_clean']:.3f} | |",
        f"| lane segmenter | lane IoU against the visible lane markings | {lane['lane_iou']:.3f} | >= {lane['gate']} ({'passed' if lane['passed'] else 'missed'}) |",
        f"| | NTL-IoU (2-class, %) of the clean frames against the map mask | {100 * lane['ntl_iou_clean']:.2f} | |",
        f"| feature network | semantic pixel accuracy / mIoU | {feat['pixel_accuracy']:.3f} / {feat['mean_iou']:.3f} | none |",
    ])


def replace_section(page: str, begin: str, end: str, text: str, name: Path) -> str:
    if begin not in page or end not in page:
        raise SystemExit(f"{name}: no {begin} ... {end} section to replace")
    head, rest = page.split(begin, 1)
    _, tail = rest.split(end, 1)
    return f"{head}{begin}\n{text}\n{end}{tail}"


def degraded_views(scene, trajectory: str) -> dict[str, np.ndarray]:
    """The true views of ``trajectory`` and three known degradations of them, (T,H,W,3) uint8 each."""
    import kornia
    import torch

    truth = np.stack([scene.novel_image(trajectory, t) for t in range(scene.num_frames)])
    tensor = torch.from_numpy(truth).permute(0, 3, 1, 2).float()
    blurred = kornia.filters.gaussian_blur2d(tensor, (9, 9), (2.0, 2.0)).round().clamp(0, 255).byte().permute(0, 2, 3, 1).numpy()
    rng = np.random.default_rng(0)
    noisy = np.clip(truth + rng.normal(0, 25, truth.shape), 0, 255).astype(np.uint8)
    unmoved = np.stack([scene.image(t) for t in range(scene.num_frames)])
    return {"true novel views": truth, "blur sigma 2": blurred, "noise sigma 25": noisy, "original frames (camera not moved)": unmoved}


def response_table(scene_dirs: list[Path], models_dir: Path, trajectories: list[str]) -> str:
    from recondreamer.evaluation import frechet
    from recondreamer.evaluation.evaluate import evaluate_trajectory, load_eval_models
    from recondreamer.evaluation.inference import fid_features
    from recondreamer.scene import load_scene

    models = load_eval_models(models_dir)
    per_case: dict[tuple[str, str], dict[str, list]] = {}
    for path in scene_dirs:
        scene = load_scene(path)
        reference = fid_features(models.features.module, np.stack([scene.image(t) for t in range(scene.num_frames)]))
        for trajectory in trajectories:
            for label, frames in degraded_views(scene, trajectory).items():
                result, features = evaluate_trajectory(scene, trajectory, frames, models, reference, 10, 0.5)
                cell = per_case.setdefault((trajectory, label), {k: [] for k in ("nta", "ntl", "psnr", "ssim", "features", "reference")})
                cell["nta"].append(result["nta_iou"]["nta_iou"])
                cell["ntl"].append(result["ntl_iou"]["ntl_iou"])
                truth = result["truth"]
                cell["psnr"].append(truth["psnr"]["mean"])  # None when every frame is identical to the truth
                cell["ssim"].append(truth["ssim"]["mean"])
                cell["features"].append(features)
                cell["reference"].append(reference)
        logging.info("scored %s", scene.scene_id)

    def mean(values):
        defined = [v for v in values if v is not None]
        return f"{np.mean(defined):.3f}" if defined else "identical"

    size = load_scene(scene_dirs[0])
    lines = [
        f"Metric response ({len(scene_dirs)} evaluation segments, {size.width}x{size.height}, {size.num_frames} frames; "
        "NTA-IoU, NTL-IoU, PSNR, SSIM: means over segments; FID, KID x1000: all segments pooled):",
        "",
        "| trajectory | renders | NTA-IoU | NTL-IoU (%) | FID | KID x1000 | PSNR | SSIM |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for (trajectory, label), cell in per_case.items():
        renders, reference = np.concatenate(cell["features"]), np.concatenate(cell["reference"])
        fid = frechet.pooled_fid_from_features(renders, reference)
        kid = frechet.kid_from_features(renders, reference)
        ntl = f"{100 * np.mean(cell['ntl']):.2f}"
        psnr = [v for v in cell["psnr"] if v is not None]
        lines.append(
            f"| {trajectory} | {label} | {mean(cell['nta'])} | {ntl} | {fid['fid']:.3f} | {1000 * kid['kid']:.2f} +- {1000 * kid['kid_std']:.2f} "
            f"| {f'{np.mean(psnr):.2f}' if psnr else 'identical'} | {mean(cell['ssim'])} |"
        )
    lines += ["", f"FID in {fid['fid_dim']} of {fid['feature_dim']} feature dimensions ({fid['num_samples'][0]} samples per set); KID in all {fid['feature_dim']}."]
    return "\n".join(lines)


def validity_table(results: Path, config_path: Path | None) -> str:
    import yaml

    from recondreamer.evaluation import frechet
    from recondreamer.evaluation.evaluate import read_feature_file
    from recondreamer.report.layout import features_file, metrics_file, trajectory_shift
    from recondreamer.experiment_plan import ExperimentPlan

    config = yaml.safe_load((config_path or results / "run_config.yaml").read_text())
    plan = ExperimentPlan.from_config(config)
    trajectory = max((t for t in plan.trajectories if trajectory_shift(t) is not None), key=lambda t: abs(trajectory_shift(t)))
    upper, base = plan.upper_bound().run_id, plan.baseline(plan.ablation_backbone).run_id
    docs = {run: [json.loads(metrics_file(results, s, run).read_text())["trajectories"][trajectory] for s in plan.segments] for run in (upper, base)}
    keys = {
        "NTA-IoU": lambda d: d["nta_iou"]["nta_iou"], "NTL-IoU": lambda d: d["ntl_iou"]["ntl_iou"],
        "PSNR": lambda d: d["truth"]["psnr"]["mean"], "SSIM": lambda d: d["truth"]["ssim"]["mean"],
        "FID (per segment)": lambda d: -d["fid"]["fid"], "KID (per segment)": lambda d: -d["kid"]["kid"],
    }
    n = len(plan.segments)
    lines = [
        f"Metric validity ({n} segments, {trajectory}): the upper bound ({upper}) against the baseline ({base}).",
        "",
        "| metric | upper bound | baseline | segments where the upper bound is better |",
        "|---|---|---|---|",
    ]
    for name, get in keys.items():
        a = [get(d) for d in docs[upper]]
        b = [get(d) for d in docs[base]]
        pairs = [(x, y) for x, y in zip(a, b) if x is not None and y is not None]
        sign = -1 if "FID" in name or "KID" in name else 1
        shown = lambda values: np.mean([sign * v for v in values])  # noqa: E731
        scale = 1000 if "KID" in name else 1
        lines.append(f"| {name} | {scale * shown([x for x, _ in pairs]):.3f} | {scale * shown([y for _, y in pairs]):.3f} | {sum(x > y for x, y in pairs)}/{len(pairs)} |")
    for run_label, run in (("upper bound", upper), ("baseline", base)):
        files = [read_feature_file(features_file(results, s, run)) for s in plan.segments]
        renders = np.concatenate([f.renders[trajectory] for f in files])
        reference = np.concatenate([f.reference for f in files])
        pooled = frechet.pooled_fid_from_features(renders, reference)
        kid = frechet.kid_from_features(renders, reference)
        lines.append(f"| FID pooled ({pooled['fid_dim']} dims) / KID x1000 pooled, {run_label} | {pooled['fid']:.3f} | {1000 * kid['kid']:.2f} +- {1000 * kid['kid_std']:.2f} | |")
    lines += ["", "The mean of per-segment FIDs (mean over segments, 24-40 frames each against as many dimensions) is listed above only to compare the two protocols; the tables show the pooled values."]
    return "\n".join(lines)


def feature_choice_table(results: Path, models_dir: Path, config_path: Path | None) -> str:
    """Pooled FID / KID of the baseline, the upper bound and the true novel views per trajectory,
    with the FID features as the last stage's pool alone and as the three scales' pools (the choice)."""
    import torch
    import yaml

    from recondreamer.evaluation import frechet, inference
    from recondreamer.frames_io import read_frame_folder
    from recondreamer.experiment_plan import ExperimentPlan
    from recondreamer.scene import load_scene

    config = yaml.safe_load((config_path or results / "run_config.yaml").read_text())
    plan = ExperimentPlan.from_config(config)
    model = inference.load_fid_model(models_dir / "fid_features.pt").module
    scenes = {s: load_scene(results / "scenes" / s) for s in plan.segments}
    runs = {"baseline": plan.baseline(plan.ablation_backbone).run_id, "upper bound": plan.upper_bound().run_id, "true novel views": None}

    def pools(frames: np.ndarray) -> list[np.ndarray]:
        with torch.no_grad():
            stages = model.encode(inference.images_to_tensor(frames, model.config.input_width, model.config.input_height))
        return [x.mean(dim=(2, 3)).numpy() for x in stages]

    choices = {"last stage": lambda p: p[-1], "three scales": lambda p: np.concatenate(p, axis=1)}
    reference = {s: pools(np.stack([sc.image(t) for t in range(sc.num_frames)])) for s, sc in scenes.items()}
    lines = [
        f"FID feature choice ({len(scenes)} segments, all pooled): FID / KID x1000 against the original frames, with the "
        "feature network's last-stage pool alone and with the pools of its three stages (what evaluate uses).",
        "",
        "| features | trajectory | " + " | ".join(runs) + " |",
        "|---|---|" + "---|" * len(runs),
    ]
    for trajectory in plan.trajectories:
        per_run = {}
        for label, run in runs.items():
            per_run[label] = []
            for s, sc in scenes.items():
                if run is None:
                    frames = np.stack([sc.novel_image(trajectory, t) for t in range(sc.num_frames)])
                else:
                    frames = read_frame_folder(results / "renders" / s / run / trajectory, sc.num_frames, (sc.width, sc.height))
                per_run[label].append(pools(frames))
        for name, pick in choices.items():
            ref = np.concatenate([pick(reference[s]) for s in scenes])
            cells = []
            for label in runs:
                rendered = np.concatenate([pick(p) for p in per_run[label]])
                cells.append(f"{frechet.pooled_fid_from_features(rendered, ref)['fid']:.3f} / {1000 * frechet.kid_from_features(rendered, ref)['kid']:.2f}")
            lines.append(f"| {name} | {trajectory} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--results", type=Path, required=True, help="results directory of a workflow run (scenes/, eval_models/, metrics/, run_config.yaml)")
    parser.add_argument("--eval-models", type=Path, default=None, help="folder of the evaluation models and their metrics.json (default RESULTS/eval_models)")
    parser.add_argument("--trajectories", nargs="+", default=["shift@3", "shift@6"], help="trajectories scored in part 1 (default shift@3 shift@6)")
    parser.add_argument("--config", type=Path, default=None, help="the run's workflow config (default RESULTS/run_config.yaml)")
    parser.add_argument("--write-docs", type=Path, default=None, help="Markdown file whose marked section receives both tables")
    parser.add_argument("--threads", type=int, default=None, help="torch threads")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s", datefmt="%H:%M:%S")
    if args.threads:
        import torch

        torch.set_num_threads(args.threads)

    from recondreamer.scene.format import SCENE_FILE

    scene_dirs = sorted(p for p in (args.results / "scenes").iterdir() if (p / SCENE_FILE).is_file())
    models_dir = args.eval_models or args.results / "eval_models"
    text = response_table(scene_dirs, models_dir, args.trajectories)
    if (args.results / "run_config.yaml").is_file() or args.config:
        text += "\n\n" + validity_table(args.results, args.config)
        text += "\n\n" + feature_choice_table(args.results, models_dir, args.config)
    command = "python benchmarks/metric_response.py " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    text = f"Regenerated by `{command}`.\n\n{text}"
    gates = gates_table(models_dir / "metrics.json")
    print(gates + "\n\n" + text)
    if args.write_docs:
        page = replace_section(args.write_docs.read_text(), BEGIN, END, text, args.write_docs)
        page = replace_section(page, GATES_BEGIN, GATES_END, f"Regenerated by `{command}`.\n\n{gates}", args.write_docs)
        args.write_docs.write_text(page)
    return 0


if __name__ == "__main__":
    sys.exit(main())
