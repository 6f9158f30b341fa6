"""benchmarks/restorer.py: which clips a restorer is scored on (held-out scenes, or its training scenes)."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SPEC = importlib.util.spec_from_file_location("restorer_benchmark", REPO / "benchmarks" / "restorer.py")
restorer_benchmark = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(restorer_benchmark)

RESTORER = SimpleNamespace(unet_config=SimpleNamespace(uses_structure=False))
PAYLOAD = {"training_scenes": ["corpus-003"]}


def pairs_file(path: Path, scene_id: str, trajectory: str, stages: int) -> Path:
    """A pairs file whose stage s has every degraded pixel equal to s (so a clip names its stage)."""
    degraded = np.stack([np.full((2, 4, 6, 3), stage, np.uint8) for stage in range(stages)])
    np.savez_compressed(
        path, gt=np.zeros((2, 4, 6, 3), np.uint8), degraded=degraded, stages=np.arange(stages) * 100,
        structure=np.zeros((2, 1, 4, 6), np.uint8), vanishing=np.zeros((2, 2), np.float32),
        scene_id=np.array(scene_id), trajectory=np.array(trajectory),
    )
    return path


def test_scored_clips_skip_training_scenes_and_training_scenes_keep_only_them(tmp_path):
    trained = pairs_file(tmp_path / "corpus-003__street.npz", "corpus-003", "original", 4)
    held_out = pairs_file(tmp_path / "corpus-021__street__shift@3.npz", "corpus-021", "shift@3", 4)
    files = [trained, held_out]

    clips = restorer_benchmark.scored_clips(RESTORER, PAYLOAD, files, stages_per_run=2)
    assert [(kind, int(degraded.max())) for kind, degraded, _, _ in clips] == [("novel", 0), ("novel", 3)]

    clips = restorer_benchmark.scored_clips(RESTORER, PAYLOAD, files, stages_per_run=0, training_scenes=True)
    assert [(kind, int(degraded.max())) for kind, degraded, _, _ in clips] == [("orig", s) for s in range(4)]
    assert all(structure is None for *_, structure in clips)  # an image restorer gets no structure maps
