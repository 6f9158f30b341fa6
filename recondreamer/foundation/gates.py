"""The foundation's gates, measured on gate scenes whose seeds no model saw.

- DriveRestorer (each backbone): on the renders of fully trained Street Gaussians reconstructions
  along novel trajectories (shift@3, shift@6), PSNR against the true novel views must rise by at
  least ``RESTORER_GAIN_GATE_DB`` and the flicker must fall below the render's; on
  original-trajectory pairs (renders of under-trained snapshots, paper Fig. 3) the same gain.
  The gate applies to the paper's restorer (dd2_mask); the other backbones are measured beside it.
- Autoencoder: reconstruction PSNR of the gate scenes' frames at least ``AUTOENCODER_PSNR_GATE_DB``.
- Evaluation models: the detector's AP50 and the lane segmenter's IoU on the gate scenes' recorded
  and true novel views (gates in ``recondreamer.evaluation.gates``); beside them what
  ``train-eval-models`` measured on its held-out corpus scenes.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from recondreamer.errors import RecondreamerError
from recondreamer.evaluation.gates import DETECTOR_AP50_GATE, LANE_IOU_GATE

LOG = logging.getLogger(__name__)

RESTORER_GAIN_GATE_DB = 2.0
AUTOENCODER_PSNR_GATE_DB = 30.0
GATED_RESTORER = "dd2_mask"  # the paper's DriveRestorer; the other backbones are printed beside it
NOVEL_GATE_TRAJECTORIES = ("shift@3", "shift@6")


def gate_clips(pair_files: list[Path], uses_structure: bool) -> dict[str, list[tuple]]:
    """Trajectory -> [(scene_id, render (T,H,W,3), truth, structure, view)]: for novel trajectories
    the render of the final model (the last stage), for the original trajectory every stage;
    ``view`` is the file's reference views (the recorded frames, for novel trajectories) or None."""
    from recondreamer.generative.data import load_pairs_file

    clips: dict[str, list[tuple]] = {}
    for path in pair_files:
        content = load_pairs_file(path)
        trajectory = str(content.get("trajectory", "original"))
        structure = content["structure"] if uses_structure else None
        stages = range(len(content["degraded"])) if trajectory == "original" else [int(np.argmax(content["stages"]))]
        for stage in stages:
            clips.setdefault(trajectory, []).append((str(content["scene_id"]), content["degraded"][stage], content["gt"], structure, content.get("view")))
    return clips


def gate_scores(restorer, clips: dict[str, list[tuple]], views: bool) -> dict[str, dict]:
    """Trajectory -> the summarised clip scores (PSNR, gain, flicker of render and restored clip) of
    ``restorer`` on ``gate_clips``' clips, restored with their reference views when ``views``."""
    from recondreamer.generative.inference import restore_clip
    from recondreamer.generative.scoring import pairs_kind, score_clip, summarise

    return {
        trajectory: summarise([score_clip(pairs_kind(trajectory), render, restore_clip(restorer, render, structure, view=view if views else None), truth)
                               for _, render, truth, structure, view in items])
        for trajectory, items in sorted(clips.items())
    }


def restorer_gate(path: str | Path, pair_files: list[Path], withhold_views: bool = False) -> dict:
    """PSNR of render and restored clip against the truth, gain and flicker, per trajectory.
    ``withhold_views`` restores without the reference views a view-conditioned restorer takes
    (what they add to it)."""
    from recondreamer.generative.checkpoint import load_checkpoint
    from recondreamer.generative.inference import load_restorer

    restorer = load_restorer(path)
    trained_on = set(load_checkpoint(path, "restorer").get("training_scenes", []))
    clips = gate_clips(pair_files, restorer.unet_config.uses_structure)
    seen = sorted({scene for items in clips.values() for scene, *_ in items} & trained_on)
    if seen:
        raise RecondreamerError(f"{path}: the restorer was trained on gate scenes {seen}; gates need scenes no model saw")
    views = restorer.unet_config.view_condition and not withhold_views
    if views and any(view is None for trajectory, items in clips.items() if trajectory != "original" for *_, view in items):
        raise RecondreamerError(f"{path}: a view-conditioned restorer needs gate pairs with reference views (make-pairs writes them on novel trajectories)")
    result: dict = {"arch": restorer.arch}
    for trajectory, scores in gate_scores(restorer, clips, views).items():
        render_psnr, restored_psnr = scores["psnr_degraded"], scores["psnr_restored"]
        render_flicker, restored_flicker = scores["flicker_degraded"], scores["flicker_restored"]
        result[trajectory] = {
            "clips": scores["clips"],
            "render_psnr": render_psnr,
            "restored_psnr": restored_psnr,
            "gain_db": scores["gain"],
            "render_flicker": render_flicker,
            "restored_flicker": restored_flicker,
        }
        LOG.info("restorer %s on %s: %.2f -> %.2f dB (%+.2f), flicker %.2f -> %.2f", restorer.arch, trajectory, render_psnr, restored_psnr,
                 restored_psnr - render_psnr, render_flicker, restored_flicker)
    checked = [t for t in (*NOVEL_GATE_TRAJECTORIES, "original") if t in result]
    result["gate_db"] = RESTORER_GAIN_GATE_DB
    result["passed"] = bool(checked) and all(
        result[t]["gain_db"] >= RESTORER_GAIN_GATE_DB and (t == "original" or result[t]["restored_flicker"] < result[t]["render_flicker"])
        for t in checked
    )
    return result


def autoencoder_gate(path: str | Path, scene_dirs: list[Path]) -> dict:
    from recondreamer.generative.data import load_corpus_frames
    from recondreamer.generative.models import load_autoencoder
    from recondreamer.generative.training import autoencoder_psnr

    autoencoder = load_autoencoder(path)[0]
    values = []
    for scene_dir in scene_dirs:
        _, frames = load_corpus_frames(scene_dir)
        values.append(autoencoder_psnr(autoencoder, frames[0]))
    value = float(np.mean(values))
    return {"psnr_db": value, "gate_db": AUTOENCODER_PSNR_GATE_DB, "passed": value >= AUTOENCODER_PSNR_GATE_DB, "scenes": len(scene_dirs)}


def eval_models_on_scenes(detector: str | Path, lane_segmenter: str | Path, scene_dirs: list[Path], frame_stride: int, min_lidar_points: int) -> dict:
    """The detector's AP50 (also per scene) and the lane segmenter's IoU on the labelled frames of
    ``scene_dirs`` (the recorded and true novel views, every ``frame_stride``-th frame, sampled as
    ``train-eval-models`` samples its held-out scenes), with their gates."""
    from recondreamer.evaluation import inference
    from recondreamer.evaluation.corpus import labelled_samples
    from recondreamer.evaluation.train_eval_models import gate_on_samples
    from recondreamer.scene import load_scene

    samples = [sample for scene_dir in scene_dirs for sample in labelled_samples(load_scene(scene_dir), frame_stride, True, min_lidar_points)]
    scenes = list(dict.fromkeys(sample.scene_id for sample in samples))
    detector_gate = gate_on_samples("vehicle_detector", inference.load_model(detector, "vehicle_detector").module, samples)
    lane_gate = gate_on_samples("lane_segmenter", inference.load_model(lane_segmenter, "lane_segmenter").module, samples)
    return {
        "vehicle_detector": {"ap50": detector_gate["ap50"], "ap50_per_scene": detector_gate["ap50_per_scene"], "gate": DETECTOR_AP50_GATE,
                             "passed": bool(detector_gate["passed"]), "scenes": scenes},
        "lane_segmenter": {"lane_iou": lane_gate["lane_iou"], "gate": LANE_IOU_GATE, "passed": bool(lane_gate["passed"]), "scenes": scenes},
    }


def eval_model_gates(metrics_file: str | Path, detector: str | Path, lane_segmenter: str | Path, scene_dirs: list[Path]) -> dict:
    """:func:`eval_models_on_scenes` on the gate scenes, with ``train-eval-models``' frame stride and
    LiDAR-point threshold, and beside it what ``train-eval-models`` measured on its held-out corpus
    scenes (``metrics_file``), which the world models and restorers saw."""
    metrics = json.loads(Path(metrics_file).read_text())
    settings, corpus = metrics.get("config", {}), metrics.get("corpus", {})
    if "frame_stride" not in settings or "min_lidar_points" not in corpus:
        raise RecondreamerError(f"{metrics_file}: not a train-eval-models metrics.json (no config.frame_stride or corpus.min_lidar_points)")
    result = eval_models_on_scenes(detector, lane_segmenter, scene_dirs, settings["frame_stride"], corpus["min_lidar_points"])
    measured = metrics.get("gates", {})
    for kind, key in (("vehicle_detector", "ap50"), ("lane_segmenter", "lane_iou")):
        before = measured.get(kind, {})
        result[kind]["heldout_corpus"] = {
            key: before.get(key),
            **({"ap50_per_scene": before["ap50_per_scene"]} if "ap50_per_scene" in before else {}),
            "scenes": corpus.get("heldout_scenes"),
        }
        LOG.info("%s on %d gate scene(s): %s %.3f (held-out corpus scenes: %s)", kind, len(result[kind]["scenes"]), key, result[kind][key], before.get(key))
    return result


def _fmt(value, digits: int = 2) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def gate_report(gates: dict) -> str:
    """GATES.md: every gate and its number, and what the set adds to the paper's recipe."""
    lines = [
        "# Foundation gates",
        "",
        "Written by the foundation workflow (`snakemake --cores 2 --configfile config/foundation.yaml`,",
        "rule `foundation_gates`); regenerate it by re-running that rule.",
        f"Gate scenes: seeds {gates['gate_seeds']} (no model saw them); corpus seeds {gates['corpus_seeds'][0]}..{gates['corpus_seeds'][-1]}.",
        "",
        "## DriveRestorer",
        "",
        "PSNR (dB) against the true novel views of the renders of fully trained Street Gaussians reconstructions, and of",
        "the restored renders; original: renders of under-trained snapshots against the recorded frames (paper Fig. 3).",
        f"Gate ({GATED_RESTORER}, the paper's restorer): gain >= {RESTORER_GAIN_GATE_DB:.0f} dB on every row and flicker below the render's",
        "on the novel ones; the other backbones are measured beside it.",
        "",
        "| restorer | trajectory | clips | render PSNR | restored PSNR | gain | render flicker | restored flicker |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for arch, result in gates["restorers"].items():
        for trajectory in (*NOVEL_GATE_TRAJECTORIES, "original"):
            row = result.get(trajectory)
            if row is None:
                continue
            lines.append(
                f"| {arch} | {trajectory} | {row['clips']} | {row['render_psnr']:.2f} | {row['restored_psnr']:.2f} | {row['gain_db']:+.2f} | "
                f"{row['render_flicker']:.2f} | {row['restored_flicker']:.2f} |"
            )
    gated = gates["restorers"].get(GATED_RESTORER, {})
    lines += ["", f"{GATED_RESTORER} gate: **{'passed' if gated.get('passed') else 'NOT passed'}**.", ""]
    autoencoder = gates["autoencoder"]
    detector, lanes = gates["eval_models"]["vehicle_detector"], gates["eval_models"]["lane_segmenter"]
    lines += [
        "## Autoencoder and evaluation models",
        "",
        "| model | measure | value | gate | passed |",
        "|---|---|---:|---:|---|",
        f"| autoencoder | reconstruction PSNR (dB), {autoencoder['scenes']} gate scene(s) | {_fmt(autoencoder['psnr_db'])} | {autoencoder['gate_db']:.0f} | {'yes' if autoencoder['passed'] else 'no'} |",
        f"| vehicle detector | AP50, {len(detector['scenes'])} gate scene(s) | {_fmt(detector['ap50'], 3)} | {detector['gate']} | {'yes' if detector['passed'] else 'no'} |",
        f"| lane segmenter | IoU vs lane markings, {len(lanes['scenes'])} gate scene(s) | {_fmt(lanes['lane_iou'], 3)} | {lanes['gate']} | {'yes' if lanes['passed'] else 'no'} |",
        f"| vehicle detector (beside the gate) | AP50, held-out corpus scenes | {_fmt(detector['heldout_corpus']['ap50'], 3)} | | |",
        f"| lane segmenter (beside the gate) | IoU vs lane markings, held-out corpus scenes | {_fmt(lanes['heldout_corpus']['lane_iou'], 3)} | | |",
        "",
        "The evaluation models are gated, as every model here, on the gate scenes (their recorded and true novel views);",
        "`train-eval-models` held its corpus's last scenes out of their training, but the world models and restorers saw those.",
    ]
    per_scene = {**detector.get("ap50_per_scene", {}), **detector["heldout_corpus"].get("ap50_per_scene", {})}
    if per_scene:
        lines.append("Detector AP50 per scene: " + ", ".join(f"{scene} {_fmt(ap, 3)}" for scene, ap in per_scene.items()) + ".")
    lines += [
        "",
        "## Added to the paper's recipe",
        "",
    ]
    lines += [f"- {item}" for item in gates["recipe"]]
    return "\n".join(lines) + "\n"


def file_gates(spec, gates: dict) -> dict:
    """The gate numbers that belong to one file of a weight set (``weights.WeightFile``)."""
    if spec.kind == "restorer":
        return gates["restorers"].get(spec.arch, {})
    if spec.kind == "autoencoder":
        return gates["autoencoder"]
    if spec.kind in ("vehicle_detector", "lane_segmenter"):
        return gates["eval_models"][spec.kind]
    return {}
