"""The quick workflow, built once per test session and shared by every end-to-end test module.

``quick_foundation`` is a workflow copy in a temporary folder in which config/quick-foundation.yaml
has built its weight set; ``quick_experiment`` is the same copy after config/quick.yaml with
.test/config.yaml (the quick experiment on that set) has run. Both fail, not skip, when a run fails.
"""

import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
QUICK_WEIGHTS = "results/quick-foundation/weights"
EXPERIMENT_CONFIGS = ("config/quick.yaml", ".test/config.yaml")
TRAINING_COMMANDS = ("train-autoencoder", "pretrain-world-model", "train-restorer", "train-eval-models")


def snakemake(root: Path, *args: str, timeout: int = 1700) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "snakemake", *args], check=False, cwd=root, capture_output=True, text=True, timeout=timeout)


def copy_workflow(root: Path) -> Path:
    """The files a workflow run needs, copied into ``root``."""
    for name in ("Snakefile", "workflow", "config", "profiles", ".test"):
        source = REPO / name
        (shutil.copytree if source.is_dir() else shutil.copy)(source, root / name)
    return root


@dataclass
class WorkflowRun:
    root: Path
    run: subprocess.CompletedProcess

    @property
    def log(self) -> str:
        return self.run.stdout + self.run.stderr


@pytest.fixture(scope="session")
def quick_foundation(tmp_path_factory) -> WorkflowRun:
    root = copy_workflow(tmp_path_factory.mktemp("wf"))
    run = snakemake(root, "--cores", "2", "--printshellcmds", "--configfile", "config/quick-foundation.yaml")
    assert run.returncode == 0, run.stderr[-5000:]
    return WorkflowRun(root, run)


@pytest.fixture(scope="session")
def quick_experiment(quick_foundation) -> WorkflowRun:
    root = quick_foundation.root
    run = snakemake(root, "--cores", "2", "--printshellcmds", "--configfile", *EXPERIMENT_CONFIGS)
    assert run.returncode == 0, run.stderr[-5000:]
    return WorkflowRun(root, run)
