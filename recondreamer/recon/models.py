"""Backbone registry: model type name -> class (the names of the paper's tables)."""

from __future__ import annotations

from recondreamer.recon.base import GaussianSceneModel
from recondreamer.recon.deformable import DeformableModel
from recondreamer.recon.pvg import PVGModel
from recondreamer.recon.s3 import S3Model
from recondreamer.recon.street import StreetModel

MODEL_CLASSES: dict[str, type[GaussianSceneModel]] = {
    "street": StreetModel,
    "pvg": PVGModel,
    "deformable": DeformableModel,
    "s3": S3Model,
}
