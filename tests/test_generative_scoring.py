"""recondreamer.generative.scoring: which clips a restorer is scored on (held-out scenes, or its
training scenes), and how a clip and a set of clips are scored."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from recondreamer.generative.scoring import flicker, mean_psnr, print_gain_table, score_clip, scored_clips, summarise

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

    clips = scored_clips(RESTORER, PAYLOAD, files, stages_per_run=2)
    assert [(kind, int(degraded.max())) for kind, degraded, _, _ in clips] == [("novel", 0), ("novel", 3)]

    clips = scored_clips(RESTORER, PAYLOAD, files, stages_per_run=0, training_scenes=True)
    assert [(kind, int(degraded.max())) for kind, degraded, _, _ in clips] == [("orig", s) for s in range(4)]
    assert all(structure is None for *_, structure in clips)  # an image restorer gets no structure maps


def test_mean_psnr_scores_the_clip_as_saved_uint8_frames():
    gt = np.full((2, 4, 4, 3), 100, dtype=np.uint8)
    assert mean_psnr(gt + 0.4, gt) == float("inf")  # rounds back to the truth
    assert mean_psnr(gt.astype(np.float64) + 300, gt) == pytest.approx(10 * np.log10(255**2 / 155**2))  # clipped at 255


def test_clip_scores_and_their_summary_split_the_gain_by_kind():
    gt = np.full((3, 4, 4, 3), 100, dtype=np.uint8)

    def off_by(levels: list[int]) -> np.ndarray:  # the truth with each frame brightened by its level
        return gt + np.array(levels, np.uint8)[:, None, None, None]

    degraded, restored = off_by([10, 20, 10]), off_by([5, 5, 5])
    score = score_clip("novel", degraded, restored.astype(np.float64) + 0.3, gt)  # scored as the saved uint8 clip
    assert score.psnr_restored == pytest.approx(20 * np.log10(255 / 5))
    assert score.gain == pytest.approx(score.psnr_restored - np.mean([20 * np.log10(255 / d) for d in (10, 20, 10)]))
    assert (score.flicker_degraded, score.flicker_restored) == (flicker(degraded, gt), 0.0) and score.flicker_degraded == 10.0

    other = score_clip("novel", restored, degraded, gt)  # the same clips swapped: the opposite gain
    row = summarise([score, other])
    assert row["clips"] == 2 and row["gain"] == pytest.approx(0.0, abs=1e-12) and row["gain_novel"] == pytest.approx(0.0, abs=1e-12)
    assert np.isnan(row["gain_orig"])  # no orig clips
    assert row["flicker_degraded"] == pytest.approx(5.0) and row["psnr_restored"] == pytest.approx((score.psnr_restored + other.psnr_restored) / 2)


def test_gain_table_rows_average_over_all_clips_and_each_kind(capsys):
    print_gain_table({"a": [("orig", 1.0), ("novel", 2.0), ("novel", 4.0)], "b": [("novel", -1.0)]})
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].split() == ["a", "2.33", "1.00", "3.00"]
    assert lines[2].split() == ["b", "-1.00", "-", "-1.00"]
