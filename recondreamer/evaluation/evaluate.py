"""Scoring the renders of one scene along one or more trajectories: NTA-IoU, NTL-IoU, FID and,
where the scene holds the true views of the trajectory, PSNR/SSIM and their masked variants.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from recondreamer.errors import RecondreamerError
from recondreamer.evaluation import frechet, image_metrics, inference, lanes, nta_iou
from recondreamer.frames_io import read_frame_folder

log = logging.getLogger(__name__)

FID_FEATURES_NOTE = (
    "FID uses the project's corpus-trained feature network (semantic-segmentation encoder, global average pools "
    "of its stages at strides 4, 8 and 16), not pytorch-fid's InceptionV3: values compare runs of this project only, never published FIDs"
)


def fid_feature_network(model: inference.LoadedModel) -> str:
    """What the FID features of ``model`` are, for every output that reports FID."""
    if inference.is_inception(model):
        return f"pytorch-fid InceptionV3 (local file, sha256 {model.sha256}): 2048-d pool features, the network of published FIDs"
    return FID_FEATURES_NOTE


@dataclass
class EvalModels:
    detector: inference.LoadedModel
    lanes: inference.LoadedModel
    features: inference.LoadedModel

    def describe(self) -> dict:
        return {
            "vehicle_detector": self.detector.describe(),
            "lane_segmenter": self.lanes.describe(),
            "fid_features": {**self.features.describe(), "feature_dim": self.features.module.config.feature_dim, "note": fid_feature_network(self.features)},
        }


def load_eval_models(models_dir: str | Path | None, detector: str | Path | None = None, lane_model: str | Path | None = None, fid_model: str | Path | None = None) -> EvalModels:
    """The three models from ``models_dir`` (train-eval-models output), each overridable by a file;
    ``fid_model`` may also be a pytorch-fid InceptionV3 state_dict."""
    def pick(kind: str, override):
        if override is not None:
            return Path(override)
        if models_dir is None:
            raise RecondreamerError(f"no {kind} model: give --models DIR (output of train-eval-models) or the model file")
        return Path(models_dir) / inference.MODEL_FILES[kind]

    return EvalModels(
        detector=inference.load_detector(pick("vehicle_detector", detector)),
        lanes=inference.load_model(pick("lane_segmenter", lane_model), "lane_segmenter"),
        features=inference.load_fid_model(pick("fid_features", fid_model)),
    )


def _mean_defined(values: list[float | None]) -> dict:
    defined = [v for v in values if v is not None]
    finite = [v for v in defined if np.isfinite(v)]
    return {
        "mean": float(np.mean(finite)) if finite else None,
        "num_frames": len(defined),
        "num_identical_frames": len(defined) - len(finite),  # PSNR = inf, left out of the mean
    }


def vehicle_track_indices(scene) -> np.ndarray:  # instance ids (1 + index into track_ids) of vehicle tracks
    labels: dict[str, str] = {}
    for t in range(scene.num_frames):
        for box in scene.boxes(t):
            labels.setdefault(box.track_id, box.label)
    return np.array([i + 1 for i, track in enumerate(scene.track_ids) if labels.get(track) == "vehicle"], dtype=np.int64)


def truth_metrics(scene, trajectory: str, frames: np.ndarray, lane_masks: list[np.ndarray]) -> dict | None:
    """PSNR/SSIM over the image, vehicles (instance masks) and lanes (GT lane mask) against the true views."""
    if trajectory != "original" and trajectory not in scene.novel_trajectories:
        return None
    vehicle_ids = vehicle_track_indices(scene)
    columns: dict[str, list] = {k: [] for k in ("psnr", "ssim", "psnr_vehicles", "ssim_vehicles", "psnr_lanes", "ssim_lanes")}
    has_instances = True
    for t, render in enumerate(frames):
        if trajectory == "original":
            truth, instances = scene.image(t), scene.instances(t)
        else:
            truth, instances = scene.novel_image(trajectory, t), scene.novel_instances(trajectory, t)
        columns["psnr"].append(image_metrics.psnr(render, truth))
        ssim_values = image_metrics.ssim_map(render, truth)  # (H,W)
        columns["ssim"].append(float(ssim_values.mean()))
        if instances is None:
            has_instances = False
        else:
            vehicles = np.isin(instances, vehicle_ids)
            columns["psnr_vehicles"].append(image_metrics.psnr(render, truth, vehicles))
            columns["ssim_vehicles"].append(float(ssim_values[vehicles].mean()) if vehicles.any() else None)
        lane = lane_masks[t]
        columns["psnr_lanes"].append(image_metrics.psnr(render, truth, lane))
        columns["ssim_lanes"].append(float(ssim_values[lane].mean()) if lane.any() else None)
    result = {name: _mean_defined(values) for name, values in columns.items() if values}
    result["vehicle_masks"] = "instance masks of vehicle tracks" if has_instances else "not available (scene has no instance masks)"
    result["lane_masks"] = "NTL-IoU ground-truth lane mask"
    return result


def evaluate_trajectory(scene, trajectory: str, frames: np.ndarray, models: EvalModels, reference_features: np.ndarray, min_lidar_points: int, score_threshold: float) -> tuple[dict, np.ndarray]:
    """Every metric of one trajectory's renders (T,H,W,3) uint8 -> (metrics, FID features (T,D))."""
    cams = scene.trajectory(trajectory)  # (T,4,4)
    width, height = scene.width, scene.height
    gt_boxes = [nta_iou.ground_truth_boxes_2d(scene.boxes(t), scene.K, cams[t], width, height, min_lidar_points) for t in range(scene.num_frames)]
    detections = inference.detect_vehicles(models.detector.module, frames, score_threshold)
    agents = nta_iou.nta_iou(gt_boxes, [boxes for boxes, _ in detections], width, height)
    lane_truth = [lanes.lane_mask(scene.map_polylines, scene.K, cams[t], width, height) for t in range(scene.num_frames)]
    lane_pred = list(inference.segment_lanes(models.lanes.module, frames))
    lane_result = lanes.ntl_iou(lane_pred, lane_truth)
    features = inference.fid_features(models.features.module, frames)
    # Per scene: a diagnostic (24-40 frames against as many dimensions); the tables pool the
    # features of all segments instead (make-tables, fid-pool).
    fid = frechet.fid_from_features(features, reference_features)
    kid = frechet.kid_from_features(features, reference_features)
    metrics = {
        "trajectory": trajectory,
        "num_frames": int(len(frames)),
        "nta_iou": agents,
        "ntl_iou": lane_result,
        "fid": fid,
        "kid": kid,
        "truth": truth_metrics(scene, trajectory, frames, lane_truth),
    }
    log.info(
        "%s %s: NTA-IoU %s, NTL-IoU %.4f (lane IoU %s), FID %.3f, KID %.5f (per scene)",
        scene.scene_id, trajectory, _fmt(agents["nta_iou"]), lane_result["ntl_iou"], _fmt(lane_result["lane_iou"]), fid["fid"], kid["kid"],
    )
    return metrics, features


def _fmt(value) -> str:
    return "n/a" if value is None else f"{value:.4f}"


def evaluate_scene(scene_dir: str | Path, renders: list[tuple[str, str | Path]], models: EvalModels, min_lidar_points: int = nta_iou.DEFAULT_MIN_LIDAR_POINTS, score_threshold: float = nta_iou.DETECTION_SCORE_THRESHOLD) -> tuple[dict, dict[str, np.ndarray]]:
    """Metrics of (trajectory, render directory) pairs of one scene, FID per trajectory and pooled.

    Returns the metrics document and the FID features (``reference`` and one entry per trajectory).
    """
    from recondreamer.scene import load_scene

    scene = load_scene(scene_dir)
    names = [name for name, _ in renders]
    if len(set(names)) != len(names):
        raise RecondreamerError(f"a trajectory is given twice: {names}")
    for name in names:
        try:
            scene.trajectory(name)
        except ValueError as error:
            raise RecondreamerError(f"--trajectory {name}: {error}") from None
    frames_by_name = {name: read_frame_folder(directory, scene.num_frames, (scene.width, scene.height)) for name, directory in renders}
    reference = scene.images()
    reference_features = inference.fid_features(models.features.module, reference)
    features = {"reference": reference_features}
    per_trajectory = {}
    for name, frames in frames_by_name.items():
        per_trajectory[name], features[name] = evaluate_trajectory(scene, name, frames, models, reference_features, min_lidar_points, score_threshold)
    pooled = frechet.fid_from_features(np.concatenate([features[n] for n in names]), reference_features)
    document = {
        "scene": {"path": str(Path(scene_dir)), "scene_id": scene.scene_id, "source": scene.source},
        "trajectories": per_trajectory,
        "fid_pooled": {**pooled, "trajectories": names},
        "settings": {
            "image_size": [scene.width, scene.height],
            "renders": {name: str(Path(directory)) for name, directory in renders},
            "models": models.describe(),
            "fid_reference": "ground-truth frames of the original trajectory",
            "fid_feature_network": fid_feature_network(models.features),
            "nta_iou": {
                "min_lidar_points": min_lidar_points,
                "detector_score_threshold": score_threshold,
                "match_distance_px": nta_iou.match_distance_threshold(scene.width, scene.height),
                "match_distance_reference": f"{nta_iou.REFERENCE_MATCH_DISTANCE:g} px at {nta_iou.REFERENCE_SIZE[0]}x{nta_iou.REFERENCE_SIZE[1]}",
                "classes": "vehicle (single-class detector)",
            },
            "ntl_iou": {
                "lane_kinds": list(lanes.LANE_KINDS),
                "max_forward_m": lanes.MAX_FORWARD_M,
                "max_lateral_m": lanes.MAX_LATERAL_M,
                "thickness_px": lanes.lane_thickness(scene.height),
            },
            "ssim_window": image_metrics.SSIM_WINDOW,
        },
    }
    return document, features


def write_features(path: str | Path, scene_id: str, features: dict[str, np.ndarray], model: inference.LoadedModel) -> None:
    """FID features beside a metrics file, so that ``pooled_fid`` can pool them over scenes."""
    import io

    from recondreamer.io import write_bytes_atomic

    arrays = {"scene_id": np.array(scene_id), "feature_model_sha256": np.array(model.sha256), "feature_network": np.array(fid_feature_network(model))}
    arrays.update({("reference" if key == "reference" else f"render:{key}"): value for key, value in features.items()})
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    write_bytes_atomic(path, buffer.getvalue())


@dataclass
class FeatureFile:
    """The FID features of one 'evaluate' run: its scene's reference frames and each trajectory's renders."""

    path: Path
    scene_id: str
    model_sha256: str
    network: str
    reference: np.ndarray  # (T,D)
    renders: dict[str, np.ndarray]  # trajectory -> (T,D)


def read_feature_file(path: str | Path) -> FeatureFile:
    path = Path(path)
    if not path.is_file():
        raise RecondreamerError(f"{path}: FID feature file not found (written by 'recondreamer evaluate' beside metrics.json)")
    try:
        data = dict(np.load(path, allow_pickle=False))
    except Exception as error:
        raise RecondreamerError(f"{path}: not a readable feature file ({error})") from None
    if "reference" not in data or "feature_model_sha256" not in data or "scene_id" not in data:
        raise RecondreamerError(f"{path}: not a feature file written by 'recondreamer evaluate'")
    return FeatureFile(
        path=path,
        scene_id=str(data["scene_id"]),
        model_sha256=str(data["feature_model_sha256"]),
        network=str(data["feature_network"]) if "feature_network" in data else FID_FEATURES_NOTE,
        reference=data["reference"],
        renders={key.removeprefix("render:"): value for key, value in data.items() if key.startswith("render:")},
    )


def pooled_scores(files: list[FeatureFile], trajectory: str | None = None) -> dict:
    """FID and KID of the renders of several evaluations against all their reference frames.

    Renders: every trajectory of every file, or only ``trajectory``; reference: the original
    frames of each scene, once per scene. FID is taken in the leading principal subspace of the
    pooled reference (``frechet.pooled_fid_from_features``), KID in the full feature space.
    """
    if not files:
        raise RecondreamerError("no FID feature files given")
    models = {f.model_sha256 for f in files}
    if len(models) > 1:
        raise RecondreamerError(f"the feature files come from {len(models)} different feature networks; FID cannot pool them: " + ", ".join(str(f.path) for f in files))
    references, scenes, renders = [], [], []
    for f in files:
        if f.scene_id not in scenes:
            references.append(f.reference)
            scenes.append(f.scene_id)
        if trajectory is None:
            renders.extend(f.renders.values())
        elif trajectory in f.renders:
            renders.append(f.renders[trajectory])
        else:
            raise RecondreamerError(f"{f.path}: no features of trajectory {trajectory!r} (has {sorted(f.renders)})")
    if not renders:
        raise RecondreamerError("no rendered-frame features in the given files")
    rendered, reference = np.concatenate(renders), np.concatenate(references)
    fid = frechet.pooled_fid_from_features(rendered, reference)
    kid = frechet.kid_from_features(rendered, reference)
    return {
        "fid": fid["fid"],
        "fid_dim": fid["fid_dim"],
        "kid": kid["kid"],
        "kid_std": kid["kid_std"],
        "kid_subset_size": kid["subset_size"],
        "kid_subsets": kid["num_subsets"],
        "num_samples": fid["num_samples"],
        "feature_dim": fid["feature_dim"],
        "num_scenes": len(scenes),
        "trajectory": trajectory or "all",
        "feature_model_sha256": models.pop(),
        "fid_feature_network": files[0].network,
        "files": [str(f.path) for f in files],
    }


def pooled_fid(feature_files: list[str | Path], trajectory: str | None = None) -> dict:
    """``pooled_scores`` of feature files given by path (the ``fid-pool`` command)."""
    return pooled_scores([read_feature_file(path) for path in feature_files], trajectory)
