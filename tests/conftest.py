"""Shared test settings: small thread counts so the suite behaves the same on every 2-core machine."""

import os

os.environ.setdefault("OMP_NUM_THREADS", "2")

import recondreamer  # noqa: E402,F401  (sets OMP_WAIT_POLICY before torch loads OpenMP)

import pytest  # noqa: E402
import torch  # noqa: E402

torch.set_num_threads(2)


@pytest.fixture(scope="session")
def shared_dir():
    """The repository's sibling ``shared/`` folder (spec and test data), when present."""
    from pathlib import Path

    path = Path(__file__).resolve().parents[1].parent / "shared"
    return path
