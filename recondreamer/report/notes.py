"""What a run's tables must say about themselves: the stand-ins, the recipe, the budgets.

The paper's tables name Stable Diffusion, SVD, DriveDreamer-2, YOLO11, TwinLiteNet and
Inception; this project trains small models of its own in their place. ``run_notes`` reads the
workflow config of the run and the model files it used, and returns the notes every table
carries: what each stand-in is (architecture, parameters, training), which changes to the
paper's DriveRestorer recipe are on, and the training budget of every method compared. Nothing
here is typed by hand: parameter counts come from the weight files, budgets from the config.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from recondreamer.report.layout import (
    BACKBONE_LABELS,
    RESTORER_LABELS,
    format_stride,
    model_path,
    restorer_checkpoint_path,
    weight_set_dir,
    world_model_path,
)

EVAL_MODEL_KINDS = {"detector": "vehicle_detector", "lane_model": "lane_segmenter", "fid_model": "fid_features"}  # config key -> weight-set kind
WORLD_MODEL_OF = {"sd": "sd", "svd": "svd", "dd2": "dd2", "dd2_mask": "dd2"}  # dd2_mask fine-tunes the dd2 world model


@dataclass(frozen=True)
class WeightFile:
    path: Path
    payload: dict

    @property
    def parameters(self) -> int:
        # Generative checkpoints keep their weights under "state", evaluation model files under "state_dict".
        return state_parameters(self.payload.get("state", self.payload.get("state_dict", {})))


def state_parameters(state: Mapping) -> int:
    """Number of parameters in a state dict (buffers such as batch-norm statistics excluded)."""
    excluded = ("running_mean", "running_var", "num_batches_tracked")
    return int(sum(math.prod(value.shape) for key, value in state.items() if hasattr(value, "shape") and not key.endswith(excluded)))


def _millions(count: int) -> str:
    return f"{count / 1e6:.2f} M"


def _load(path: Path) -> WeightFile | None:
    import torch

    if not path.is_file():
        return None
    payload = torch.load(path, map_location="cpu", weights_only=False)
    return WeightFile(path, payload if isinstance(payload, dict) else {})


def pdus_reach(stride: float, iterations: int, update_every: int | None, max_offset: float | None) -> list[float]:
    """The offsets (metres) of a PDUS run's updates, as train-recondreamer schedules them."""
    from recondreamer.methods.pdus import PdusSchedule

    schedule = PdusSchedule.for_iterations(stride, iterations, update_every, 6.0 if max_offset is None else max_offset)
    return schedule.offsets()


def recon_iterations(config: Mapping) -> int:
    from recondreamer.recon.config import make_config

    recon = config["recon"]
    return int(recon["iterations"]) if recon.get("iterations") else make_config("street", recon["preset"]).iterations


def pair_kind_trajectories(payload: dict, kind: str) -> list[str]:
    """The trajectories of a restorer's pairs of one kind (``cycle`` or ``truth``; its ``pair_kinds``
    are ``generative.data.pair_kind`` values such as ``cycle:shift@3``)."""
    return [entry.split(":", 1)[1] for entry in payload.get("pair_kinds", []) if entry.startswith(f"{kind}:")]


def restorer_recipe(payload: dict) -> list[str]:
    """The changes to the paper's DriveRestorer recipe that a restorer checkpoint has on."""
    config = payload.get("config", {})
    diffusion, train, restore = config.get("diffusion", {}), config.get("train", {}), config.get("restore", {})
    changes = []
    if diffusion.get("target_space") == "residual":
        changes.append("residual target (the restorer generates the clean - degraded latent difference)")
    if diffusion.get("prediction") == "v":
        changes.append("v-prediction")
    if train.get("timestep_power", 1.0) != 1.0:
        changes.append(f"training timesteps weighted towards noisy steps (density ~ t^{train['timestep_power'] - 1:g})")
    if train.get("ema_decay", 0.0):
        changes.append(f"weight averaging (EMA {train['ema_decay']:g})")
    if train.get("pixel_loss_weight", 0.0):
        changes.append(f"image-space loss (weight {train['pixel_loss_weight']:g})")
    if restore.get("residual_decoding"):
        changes.append("residual decoding (output = render + decoded change)")
    if restore.get("samples", 1) > 1:
        changes.append(f"{restore['samples']} noise draws averaged per window")
    if restore.get("sample_steps"):
        changes.append(f"{restore['sample_steps']}-step DDIM sampling at strength {restore.get('strength', 1.0):g}")
    if payload.get("refiner"):
        changes.append("a pixel refiner on the restorer's output")
    cycles, truths = pair_kind_trajectories(payload, "cycle"), pair_kind_trajectories(payload, "truth")
    if cycles:
        changes.append(
            f"cycle pairs: reconstructions trained on renders of the lateral drives {', '.join(cycles)} render the recorded "
            "trajectory, paired with the recorded frames (no novel-view truth)"
        )
    if truths:
        changes.append(f"novel-view truth pairs along {', '.join(truths)} (beyond the paper: the loop never has these views)")
    return changes


def weight_set_name(config, folder: Path) -> str:
    """How the notes name a run's weight set: a user's folder by its path; the shipped set by the
    code version that trained it, not by where the package is installed, so that two clones give
    the same tables to the byte."""
    if config.get("foundation", {}).get("weights", "shipped") != "shipped":
        return f"the weight set {folder}"
    from recondreamer.foundation.weights import read_manifest

    version = str(read_manifest(folder).get("code_version") or "unknown")
    return f"the shipped weight set (trained by code version {version[:7]})"


def run_notes(config: Mapping) -> dict[int, list[str]]:
    """Notes per table number for the run described by a validated workflow config."""
    experiment = config["experiment"]
    lines_models: list[str] = []

    # DriveRestorer backbones (and the world models they start from)
    restorer_budget = []
    recipes: dict[str, list[str]] = {}
    novel_truth = False  # whether any restorer learned from novel-view truth
    for arch in experiment["restorer_backbones"]:
        path = Path(restorer_checkpoint_path(config, arch))
        restorer = _load(path)
        world = _load(Path(world_model_path(config, WORLD_MODEL_OF[arch])))
        label = RESTORER_LABELS.get(arch, arch)
        if restorer is None:
            lines_models.append(f"{label}: restorer file {path} not found (notes incomplete).")
            continue
        steps = restorer.payload.get("metrics", {}).get("total_steps") or restorer.payload.get("config", {}).get("train", {}).get("steps")
        scenes = restorer.payload.get("training_scenes", [])
        own = config["restorer"]["checkpoints"].get(arch)
        world_text = (
            f"pretrained {world.payload.get('config', {}).get('train', {}).get('steps', '?')} steps as a world model on the synthetic corpus"
            if world is not None else "world model not in this run"
        )
        origin = f"the user's file {own}" if own else f"{world_text}, then fine-tuned {steps} steps as DriveRestorer on pairs of {len(scenes)} scene(s)"
        lines_models.append(f"{label}: a stand-in, a {_millions(restorer.parameters)}-parameter latent UNet ({origin}).")
        restorer_budget.append(f"{arch} {steps}")
        recipes[arch] = restorer_recipe(restorer.payload)
        novel_truth |= bool(pair_kind_trajectories(restorer.payload, "truth"))

    autoencoder = _load(Path(model_path(config, "autoencoder")))
    if autoencoder is not None:
        psnr = autoencoder.payload.get("metrics", {}).get("heldout_psnr")
        lines_models.append(
            f"Latent autoencoder (stand-in for Stable Diffusion's VAE): {_millions(autoencoder.parameters)} parameters, "
            f"{autoencoder.payload.get('config', {}).get('steps', '?')} steps on the corpus"
            + (f", {psnr:.2f} dB on held-out frames." if isinstance(psnr, float) else ".")
        )

    eval_descriptions = {
        "detector": ("NTA-IoU detector", "YOLO11x", "a CenterNet-style CNN"),
        "lane_model": ("NTL-IoU lane segmenter", "TwinLiteNet", "a TwinLiteNet-style ESPNet CNN segmenting the rendered lane markings"),
        "fid_model": ("FID/KID features", "InceptionV3", "multi-scale pooled stages of a semantic-segmentation CNN"),
    }
    for key, (role, paper_name, what) in eval_descriptions.items():
        own = config["eval_models"].get(key)
        path = Path(own) if own else Path(model_path(config, EVAL_MODEL_KINDS[key]))
        if own:
            lines_models.append(f"{role}: the user's file {own} in place of {paper_name}.")
            continue
        model = _load(path)
        if model is None:
            lines_models.append(f"{role}: a stand-in for {paper_name} ({what}); file {path} not found (notes incomplete).")
            continue
        run = model.payload.get("training", {}).get("run", {})
        scenes = len(model.payload.get("training", {}).get("train_scenes", []))
        lines_models.append(
            f"{role}: a stand-in for {paper_name}, {what} of {_millions(model.parameters)} parameters, "
            f"trained {run.get('steps', '?')} steps on {scenes} synthetic corpus scene(s)."
        )

    iterations = recon_iterations(config)
    pair_sources = []
    weights = weight_set_dir(config)
    weights_name = None if weights is None else weight_set_name(config, weights)  # reads the manifest once
    if weights is not None:
        pair_sources.append(f"the corpus scene reconstructions of {weights_name}")
    elif config["restorer"]["pair_segment_backbones"]:
        pair_sources.append(
            f"the evaluation segments' baseline runs ({', '.join(BACKBONE_LABELS.get(b, b) for b in config['restorer']['pair_segment_backbones'])}) "
            "along their recorded trajectories"
        )
    if weights is None and config["restorer"]["pair_corpus_scenes"]:
        pair_sources.append(f"{config['restorer']['pair_corpus_scenes']} corpus scene reconstruction(s)")
    if weights is None and config["restorer"]["cycle_corpus_scenes"] and config["restorer"]["cycle_trajectories"]:
        pair_sources.append(
            f"cycles on {config['restorer']['cycle_corpus_scenes']} corpus scene(s) along {', '.join(config['restorer']['cycle_trajectories'])}"
        )
    budgets = [
        f"Training budgets: every reconstruction (baseline, DriveDreamer4D, ReconDreamer) {iterations} iterations; "
        f"DriveRestorer fine-tuning steps: {', '.join(restorer_budget) or 'n/a'}; restoration pairs from {' and '.join(pair_sources) or 'nothing'} "
        + ("(renders of the recorded trajectory with its frames, never novel-view truth)." if not novel_truth else
           "(including novel-view truth: beyond the paper, see the recipe line)."),
    ]
    recipe_lines = []
    distinct = {tuple(v) for v in recipes.values()}
    if len(distinct) == 1:
        changes = next(iter(distinct))
        recipe_lines.append("Changes to the paper's DriveRestorer recipe on in this run: " + ("; ".join(changes) if changes else "none") + ".")
    else:
        for arch, changes in recipes.items():
            recipe_lines.append(f"Changes to the paper's recipe ({RESTORER_LABELS.get(arch, arch)}): " + ("; ".join(changes) if changes else "none") + ".")

    origin = "trained in this run" if weights is None else f"trained once on the synthetic corpus, from {weights_name} (gates in its GATES.md)"
    common = [f"Stand-ins (small models {origin}, named with the paper's models they replace): " + " ".join(lines_models), *recipe_lines, *budgets]
    if str(config["recon"].get("device") or "cpu").startswith("cuda"):
        common.append(
            "Reconstructions trained on CUDA: gsplat's backward pass adds gradients with atomic operations, in an order "
            "that changes from run to run, so a rerun with the same seeds gives slightly different numbers "
            "(on the CPU they repeat bit for bit)."
        )
    methods = config.get("methods", {})
    stride_lines = []
    for stride in experiment["strides"]:
        offsets = pdus_reach(float(stride), iterations, methods.get("update_every"), methods.get("max_offset"))
        reach = max(offsets) if offsets else 0.0
        stride_lines.append(f"{format_stride(float(stride))} m: {len(offsets)} update(s) at {', '.join(f'{o:g}' for o in offsets)} m, reach {reach:g} m")
    table5 = common + ["PDUS updates and reach per stride: " + "; ".join(stride_lines) + "."]
    return {1: common, 2: common, 3: common, 4: common, 5: table5}
