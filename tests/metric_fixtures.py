"""Hand-made metric and FID-feature files, as 'recondreamer evaluate' writes them, for the report tests."""

import json

import numpy as np

from recondreamer.report.layout import features_file, metrics_file

FEATURE_DIM = 6
FRAMES = 12


def write_run(results, segment, run_id, per_trajectory, reference, renders, truth=True):
    """One metrics file and its feature file.

    per_trajectory: {trajectory: {"nta", "ntl", "fid", "kid", "psnr", "ssim"}} (per-segment values);
    reference: (T,D) features of the segment's original frames; renders: {trajectory: (T,D)}.
    """
    trajectories = {}
    for trajectory, values in per_trajectory.items():
        trajectories[trajectory] = {
            "trajectory": trajectory,
            "nta_iou": {"nta_iou": values["nta"], "num_gt_boxes": 12},
            "ntl_iou": {"ntl_iou": values["ntl"], "lane_iou": 0.2},
            "fid": {"fid": values["fid"]},
            "kid": {"kid": values.get("kid", 0.0)},
            "truth": {"psnr": {"mean": values["psnr"]}, "ssim": {"mean": values["ssim"]}} if truth else None,
        }
    path = metrics_file(results, segment, run_id)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"scene": {"scene_id": segment}, "trajectories": trajectories}))
    arrays = {"scene_id": np.array(segment), "feature_model_sha256": np.array("0" * 64), "feature_network": np.array("test features"), "reference": reference}
    arrays.update({f"render:{t}": value for t, value in renders.items()})
    np.savez(features_file(results, segment, run_id), **arrays)


def write_metrics(results, plan, seed=0, truth=True):
    """Random metric files for every (segment, run) of ``plan``.

    Returns {(segment, run, trajectory): values} with the render features under "features",
    and {("reference", segment): features}.
    """
    rng = np.random.default_rng(seed)
    raw = {}
    for segment in plan.segments:
        reference = rng.normal(size=(FRAMES, FEATURE_DIM))
        raw[("reference", segment)] = reference
        for method in plan.runs():
            per_trajectory, renders = {}, {}
            for trajectory in plan.trajectories:
                values = {"nta": rng.uniform(0.05, 0.6), "ntl": rng.uniform(0.4, 0.6), "fid": rng.uniform(50, 300), "kid": rng.uniform(0, 0.1),
                          "psnr": rng.uniform(15, 30), "ssim": rng.uniform(0.3, 0.9)}
                renders[trajectory] = rng.normal(loc=rng.uniform(-1, 1), size=(FRAMES, FEATURE_DIM))
                raw[(segment, method.run_id, trajectory)] = {**values, "features": renders[trajectory]}
                per_trajectory[trajectory] = values
            write_run(results, segment, method.run_id, per_trajectory, reference, renders, truth)
    return raw
