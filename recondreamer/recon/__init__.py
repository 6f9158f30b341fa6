"""Gaussian-splatting reconstruction backbones (street, pvg, deformable, s3) and one trainer.

Public API: ``load_model(path)``, ``render_trajectory(model, scene, cam_to_world)``,
``train_scene(scene, config, run_dir)``, ``make_config(model, preset)``, ``TrainingSet`` /
``TrainingView``. See ``docs/reconstruction.md``.
"""

from importlib import import_module

# Public name -> defining module. Imported on first use (PEP 562) so that ``recondreamer --help``,
# which only needs ``recondreamer.recon.config``, does not pay for importing torch.
_EXPORTS = {
    "GaussianSceneModel": "recondreamer.recon.base",
    "load_model": "recondreamer.recon.checkpoint",
    "MODEL_TYPES": "recondreamer.recon.config",
    "PRESETS": "recondreamer.recon.config",
    "ReconConfig": "recondreamer.recon.config",
    "make_config": "recondreamer.recon.config",
    "TrainingSet": "recondreamer.recon.data",
    "TrainingView": "recondreamer.recon.data",
    "render_frames": "recondreamer.recon.render",
    "render_trajectory": "recondreamer.recon.render",
    "Trainer": "recondreamer.recon.trainer",
    "train_scene": "recondreamer.recon.trainer",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'recondreamer.recon' has no attribute {name!r}")
    return getattr(import_module(_EXPORTS[name]), name)
