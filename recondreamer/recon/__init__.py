"""Gaussian-splatting reconstruction backbones (street, pvg, deformable, s3) and one trainer.

Public API: ``load_model(path)``, ``render_trajectory(model, scene, cam_to_world)``,
``train_scene(scene, config, run_dir)``, ``make_config(model, preset)``, ``TrainingSet`` /
``TrainingView``. See ``docs/reconstruction.md``.
"""

from recondreamer.recon.base import GaussianSceneModel
from recondreamer.recon.checkpoint import load_model
from recondreamer.recon.config import MODEL_TYPES, PRESETS, ReconConfig, make_config
from recondreamer.recon.data import TrainingSet, TrainingView
from recondreamer.recon.render import render_frames, render_trajectory
from recondreamer.recon.trainer import Trainer, train_scene

__all__ = [
    "MODEL_TYPES",
    "PRESETS",
    "GaussianSceneModel",
    "ReconConfig",
    "Trainer",
    "TrainingSet",
    "TrainingView",
    "load_model",
    "make_config",
    "render_frames",
    "render_trajectory",
    "train_scene",
]
