"""What a reconstruction run promises about repeating itself, and torch's deterministic mode.

On the CPU every step is a fixed sequence of float operations: the C++ rasterizer sums each
splat's gradient over its tiles in one fixed order whatever the number of threads
(``docs/rasterizer.md``), and torch's CPU ops split their work statically. So a CPU run repeats
bit for bit with the same seed, thread count, machine and build. The thread count itself drops
out where no matrix product sums over the Gaussians: MKL's GEMM splits such a sum by thread
count, which the deformation MLP (deformable) and the HexPlane decoders (s3) do in their
backward pass, unless MKL runs in strict conditional-numerical-reproducibility mode
(``MKL_CBWR=AUTO,STRICT`` in the environment before the process starts; its results differ from
the default mode's). On CUDA, gsplat's backward pass and some of torch's CUDA kernels
(``grid_sample``'s backward, used by the sky) add gradients with atomic operations, whose order
changes from run to run: CUDA runs are not bit-reproducible, with or without torch's
deterministic mode.
"""

from __future__ import annotations

import os

import torch

from recondreamer.recon.base import GaussianSceneModel
from recondreamer.recon.config import ReconConfig

CUBLAS_WORKSPACE = ":4096:8"  # what torch's deterministic mode asks of cuBLAS for CUDA matrix products


def use_deterministic_algorithms() -> None:
    """torch's deterministic mode for this process (``torch.use_deterministic_algorithms``), warn-only:
    ops with a deterministic implementation use it, the others (on CUDA, ``grid_sample``'s
    backward) warn instead of stopping the run. gsplat's CUDA kernels are outside its reach."""
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", CUBLAS_WORKSPACE)
    torch.use_deterministic_algorithms(True, warn_only=True)


def mkl_strict() -> bool:
    """True when MKL was asked for strict reproducibility (results independent of the thread count)."""
    return "STRICT" in os.environ.get("MKL_CBWR", "").upper().split(",")


def reproducibility(config: ReconConfig, model: GaussianSceneModel) -> dict:
    """The run notes' account of repeatability: the settings that decide it and what they imply."""
    threads = torch.get_num_threads()
    deterministic = torch.are_deterministic_algorithms_enabled()
    if torch.device(config.device).type == "cuda":
        repeats = (
            "not bit-reproducible: on CUDA, gsplat's backward pass and torch's grid_sample backward add "
            "gradients with atomic operations in an order that changes from run to run"
            + (" (torch's deterministic mode covers torch's other ops only)" if deterministic else "")
        )
    else:
        splits = []  # why another thread count would give other bits
        if config.backend == "torch":
            splits.append("the torch reference backend's reductions split by thread")
        if (model.field_parameters() or model.grid_parameters()) and not mkl_strict():
            splits.append("MKL's matrix products split their sums over the Gaussians by thread; "
                          "MKL_CBWR=AUTO,STRICT removes that")
        repeats = f"bit-identical for the same seed at {threads} thread(s) on the same machine and build" + (
            f"; other thread counts give slightly different results ({'; '.join(splits)})"
            if splits else ", and at any other thread count"
        )
    return {
        "device": config.device,
        "threads": threads,
        "deterministic_algorithms": deterministic,
        "mkl_cbwr": os.environ.get("MKL_CBWR"),
        "repeats": repeats,
    }
