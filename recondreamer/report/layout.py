"""Names and places of the experiment's runs: one source of truth for the workflow and the tables.

The Snakemake rules (``workflow/rules/common.smk``) import these helpers to name their outputs,
and the table builder uses the same helpers to find the per-run metric files, so a run id can
never mean one thing to the workflow and another to the tables.

Layout below ``results_dir``::

    scenes/<segment>/                       scene directory (synthetic or converted Waymo)
    runs/<segment>/<run>/                   reconstruction run (train-recon / -recondreamer / -dd4d)
    renders/<segment>/<run>/<trajectory>/   rendered frames 000.png ...
    metrics/<segment>/<run>.json            'recondreamer evaluate' output (all trajectories)
    metrics/<segment>/<run>.features.npz    its FID features (pooled over segments by the tables)
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

BACKBONE_LABELS = {
    "street": "Street Gaussians",
    "pvg": "PVG",
    "deformable": "Deformable-GS",
    "s3": "S3Gaussian",
}
RESTORER_LABELS = {
    "sd": "Stable Diffusion",
    "svd": "Stable Video Diffusion",
    "dd2": "DriveDreamer-2",
    "dd2_mask": "DriveDreamer-2+Mask",
}
METHOD_KINDS = ("baseline", "dd4d", "recondreamer")
# ReconDreamer's "restorer" that hands the loop the true novel views (synthetic scenes): the
# upper bound of what any DriveRestorer could give, and the check that the metrics can rank.
ORACLE_RESTORER = "truth"
UPPER_BOUND_LABEL = "Upper bound: true novel views in the loop"

_SHIFT = re.compile(r"^shift@(-?\d+(?:\.\d+)?)$")


def format_stride(stride: float) -> str:
    """Stride in metres as it appears in run ids and wildcards: one decimal at least (1.5, 6.0)."""
    text = f"{float(stride):.2f}".rstrip("0")
    return text + "0" if text.endswith(".") else text


def trajectory_label(name: str) -> str:
    """'shift@3' -> 'Lane Shift @ 3m', 'lane_change' -> 'Lane Change' (the paper's column names)."""
    match = _SHIFT.match(name)
    if match:
        return f"Lane Shift @ {match.group(1)}m"
    if name == "lane_change":
        return "Lane Change"
    return name


def trajectory_shift(name: str) -> float | None:
    """Lateral offset in metres of a constant-shift trajectory; None for the others."""
    match = _SHIFT.match(name)
    return float(match.group(1)) if match else None


@dataclass(frozen=True)
class Method:
    """One reconstruction run kind of a segment: what a table row is made of."""

    kind: str  # baseline | dd4d | recondreamer
    backbone: str  # street | pvg | deformable | s3
    restorer: str | None = None  # recondreamer only
    stride: float | None = None  # recondreamer only, metres

    def __post_init__(self) -> None:
        if self.kind not in METHOD_KINDS:
            raise ValueError(f"unknown method kind {self.kind!r}; expected one of {METHOD_KINDS}")
        if (self.kind == "recondreamer") != (self.restorer is not None and self.stride is not None):
            raise ValueError("a recondreamer method needs a restorer and a stride, other kinds neither")

    @property
    def run_id(self) -> str:
        if self.kind == "recondreamer":
            return f"recondreamer-{self.backbone}-{self.restorer}-stride{format_stride(self.stride)}"
        return f"{self.kind}-{self.backbone}"

    @property
    def label(self) -> str:
        backbone = BACKBONE_LABELS.get(self.backbone, self.backbone)
        if self.kind == "baseline":
            return backbone
        if self.kind == "dd4d":
            return f"DriveDreamer4D with {backbone}"
        return f"ReconDreamer with {backbone}"

    @classmethod
    def from_run_id(cls, run_id: str) -> Method:
        match = re.fullmatch(r"recondreamer-([a-z0-9]+)-([a-z0-9_]+)-stride(\d+(?:\.\d+)?)", run_id)
        if match:
            return cls("recondreamer", match.group(1), match.group(2), float(match.group(3)))
        kind, _, backbone = run_id.partition("-")
        if kind not in ("baseline", "dd4d") or not backbone:
            raise ValueError(f"not a run id of this workflow: {run_id!r}")
        return cls(kind, backbone)


def run_dir(results_dir: str | Path, segment: str, run_id: str) -> Path:
    return Path(results_dir) / "runs" / segment / run_id


def render_dir(results_dir: str | Path, segment: str, run_id: str, trajectory: str) -> Path:
    return Path(results_dir) / "renders" / segment / run_id / trajectory


def metrics_file(results_dir: str | Path, segment: str, run_id: str) -> Path:
    return Path(results_dir) / "metrics" / segment / f"{run_id}.json"


def features_file(results_dir: str | Path, segment: str, run_id: str) -> Path:
    return metrics_file(results_dir, segment, run_id).with_suffix(".features.npz")


def weight_set_dir(config) -> Path | None:
    """The weight set a workflow config's models come from (``foundation.weights``), or None when
    the run trains them itself (``train``)."""
    source = config.get("foundation", {}).get("weights", "shipped")
    if source == "train":
        return None
    if source == "shipped":
        from recondreamer.foundation.weights import shipped_weights_dir

        return shipped_weights_dir()
    return Path(source)


def model_path(config, kind: str, arch: str | None = None) -> str:
    """Where a run finds one foundation model: in its weight set, or where its DAG trains it
    (``<results_dir>/models/`` for the generative models, ``<results_dir>/eval_models/`` for the
    evaluation models)."""
    from recondreamer.foundation.weights import weight_file

    name = weight_file(kind, arch).name
    folder = weight_set_dir(config)
    if folder is not None:
        return str(folder / name)
    trained = "eval_models" if kind in ("vehicle_detector", "lane_segmenter", "fid_features") else "models"
    return str(Path(config["results_dir"]) / trained / name)


def world_model_path(config, arch: str) -> str:
    return model_path(config, "world_model", arch)


def restorer_checkpoint_path(config, arch: str) -> str:
    """The DriveRestorer the ReconDreamer runs of a workflow config use: the configured local
    file, else the weight set's, else the one the workflow trains (with its pixel refiner when
    restorer.refiner_steps > 0)."""
    own = config["restorer"]["checkpoints"].get(arch)
    if own:
        return own
    if weight_set_dir(config) is None and config["restorer"]["refiner_steps"]:
        return str(Path(config["results_dir"]) / "models" / f"restorer_{arch}_refined.pt")
    return model_path(config, "restorer", arch)
