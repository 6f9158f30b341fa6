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


@pytest.fixture(scope="module")
def one_torch_thread():
    """One torch thread for a module of small-tensor tests: a second thread mostly waits at barriers."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


pytest_plugins = ["workflow_fixtures"]  # the quick workflow run once per session, shared by the end-to-end modules
