"""benchmarks/restored_pairs.py: second-pass pairs hold the first restorer's outputs and nothing else changes."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SPEC = importlib.util.spec_from_file_location("restored_pairs", REPO / "benchmarks" / "restored_pairs.py")
restored_pairs = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(restored_pairs)

FAKE_RESTORER = SimpleNamespace(unet_config=SimpleNamespace(uses_structure=True))


def fake_restore_clip(restorer, frames, structure, *, num_steps, seed):
    """Adds 1 + the structure's sum (so a missing structure would show) to every pixel."""
    assert restorer is FAKE_RESTORER and num_steps == 1 and seed == 0
    return np.clip(frames.astype(np.int32) + 1 + int(structure.sum()), 0, 255).astype(np.uint8)


def write_pairs(path: Path) -> dict:
    rng = np.random.default_rng(0)
    arrays = {
        "gt": rng.integers(0, 250, size=(3, 4, 6, 3), dtype=np.uint8),
        "degraded": rng.integers(0, 250, size=(2, 3, 4, 6, 3), dtype=np.uint8),
        "stages": np.array([10, 20]),
        "structure": np.zeros((3, 2, 4, 6), dtype=np.uint8),
        "vanishing": np.zeros((3, 2), dtype=np.float32),
        "scene_id": np.array("corpus-021"),
        "trajectory": np.array("shift@3"),
    }
    arrays["structure"][0, 0, 0, :2] = 1  # sum 2
    np.savez_compressed(path, **arrays)
    return arrays


@pytest.fixture
def fake_inference(monkeypatch):
    from recondreamer.restorer import inference

    monkeypatch.setattr(inference, "restore_clip", fake_restore_clip)
    monkeypatch.setattr(inference, "load_restorer", lambda path: FAKE_RESTORER)


def test_every_stage_is_restored_and_the_other_arrays_are_copied(tmp_path, monkeypatch, fake_inference):
    pairs = tmp_path / "pairs"
    pairs.mkdir()
    original = write_pairs(pairs / "corpus-021__street__shift@3.npz")
    monkeypatch.setattr(sys, "argv", ["restored_pairs.py", "--restorer", "r1.pt", "--pairs", str(pairs), "--out", str(tmp_path / "out")])
    restored_pairs.main()

    from recondreamer.restorer.data import load_pairs_file

    written = load_pairs_file(tmp_path / "out" / "corpus-021__street__shift@3.npz")
    assert np.array_equal(written["degraded"], original["degraded"] + 3)  # both stages, each through the fake restorer
    assert set(written) == set(original)
    for key in set(original) - {"degraded"}:
        assert np.array_equal(written[key], original[key]), key


def test_a_file_already_written_is_kept(tmp_path, monkeypatch, fake_inference):
    pairs = tmp_path / "pairs"
    pairs.mkdir()
    write_pairs(pairs / "a__run.npz")
    out = tmp_path / "out"
    out.mkdir()
    (out / "a__run.npz").write_bytes(b"done before")
    monkeypatch.setattr(sys, "argv", ["restored_pairs.py", "--restorer", "r1.pt", "--pairs", str(pairs), "--out", str(out)])
    restored_pairs.main()
    assert (out / "a__run.npz").read_bytes() == b"done before"
