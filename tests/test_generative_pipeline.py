"""The generative stack's commands end to end on one tiny synthetic scene, and resumable training."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from recondreamer.cli import main
from recondreamer.generative.checkpoint import load_checkpoint
from recondreamer.training_loop import resume_path, run_training_loop

# Small tensors: one torch thread each (tests/conftest.py).
pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _blur(frames: np.ndarray) -> np.ndarray:  # (T,H,W,3) uint8 -> box-blurred copy
    from scipy import ndimage

    return ndimage.uniform_filter(frames.astype(np.float32), size=(1, 5, 5, 1)).round().astype(np.uint8)


@pytest.mark.slow
def test_commands_end_to_end_on_a_tiny_scene(tmp_path, capsys):
    from recondreamer.generative.data import scene_sky_masks, scene_structure, scene_vanishing_points, structure_channel_names
    from recondreamer.scene import load_scene, write_scene
    from recondreamer.sources.synthetic import generate_segment

    corpus = tmp_path / "corpus"
    write_scene(corpus / "a", generate_segment(3, "quick"))
    scene = load_scene(corpus / "a")
    common = ["--threads", "1"]
    assert main(["train-autoencoder", "--corpus", str(corpus), "--out", str(tmp_path / "ae.pt"), "--steps", "3", *common]) == 0
    assert load_checkpoint(tmp_path / "ae.pt", "autoencoder")["metrics"]["heldout_psnr"] > 0
    train = ["--steps", "2", "--batch-size", "1", "--window", "4", *common]
    assert main(["pretrain-world-model", "--arch", "dd2", "--corpus", str(corpus), "--autoencoder", str(tmp_path / "ae.pt"),
                 "--out", str(tmp_path / "wm.pt"), *train]) == 0

    # A restoration-pairs file as make-pairs writes it, with blurred frames standing in for renders.
    gt = np.stack([scene.image(t) for t in range(scene.num_frames)])
    pairs = tmp_path / "pairs"
    pairs.mkdir()
    np.savez_compressed(
        pairs / "a__run.npz", gt=gt, degraded=_blur(gt)[None], stages=np.array([10]),
        structure=scene_structure(scene, scene.cam_to_world), structure_channels=np.array(structure_channel_names()),
        vanishing=scene_vanishing_points(scene, scene.cam_to_world), sky=scene_sky_masks(scene),
        scene_id=np.array(scene.scene_id), scene_path=np.array(str(scene.path)), run=np.array("run"),
    )
    assert main(["train-restorer", "--arch", "dd2_mask", "--world-model", str(tmp_path / "wm.pt"), "--pairs", str(pairs),
                 "--out", str(tmp_path / "r.pt"), "--residual-decoding", "on", "--sample-steps", "3", "--strength", "0.5",
                 "--samples", "2", "--pixel-loss-weight", "2", *train]) == 0
    restorer = load_checkpoint(tmp_path / "r.pt", "restorer")
    assert restorer["config"]["train"]["pixel_loss_weight"] == 2.0
    assert restorer["config"]["masks"]["probability"] == 0.5 and restorer["training_scenes"] == [scene.scene_id]
    assert restorer["pair_kinds"] == ["snapshot"]  # the checkpoint says what its pairs taught (the tables' notes name it)
    assert restorer["config"]["restore"] | {"residual_decoding": True, "sample_steps": 3, "strength": 0.5, "samples": 2} == restorer["config"]["restore"]
    assert restorer["config"]["diffusion"]["prediction"] == "v"
    # Residual target space by default, its scale measured on the pairs (blur leaves a non-zero residual).
    assert restorer["config"]["diffusion"]["target_space"] == "residual" and restorer["config"]["diffusion"]["residual_scale"] > 0.0

    # Without options a restorer gets the measured recipe: residual space, timestep power 50, 1 step of 4 averaged
    # samples, residual decoding.
    assert main(["train-restorer", "--arch", "dd2", "--world-model", str(tmp_path / "wm.pt"), "--pairs", str(pairs),
                 "--out", str(tmp_path / "r_default.pt"), *train]) == 0
    default = load_checkpoint(tmp_path / "r_default.pt", "restorer")["config"]
    assert default["train"]["timestep_power"] == 50.0 and default["diffusion"]["target_space"] == "residual"
    assert default["restore"]["sample_steps"] == 1 and default["restore"]["residual_decoding"] is True
    assert default["restore"]["samples"] == 4
    assert default["train"]["pixel_loss_weight"] == 0.0

    # Beyond the paper: a view-conditioned restorer learns from the pairs files that hold reference views.
    assert main(["train-restorer", "--arch", "dd2_mask", "--world-model", str(tmp_path / "wm.pt"), "--pairs", str(pairs),
                 "--out", str(tmp_path / "r_view_none.pt"), "--view-condition", *train]) == 1
    assert "none of the pairs has one" in capsys.readouterr().err and not (tmp_path / "r_view_none.pt").exists()
    with np.load(pairs / "a__run.npz") as content:
        np.savez_compressed(pairs / "a__run__shift@3.npz", **dict(content), view=gt[::-1].copy(), trajectory=np.array("shift@3"))
    assert main(["train-restorer", "--arch", "dd2_mask", "--world-model", str(tmp_path / "wm.pt"), "--pairs", str(pairs),
                 "--out", str(tmp_path / "r_view.pt"), "--view-condition", *train]) == 0
    view_restorer = load_checkpoint(tmp_path / "r_view.pt", "restorer")
    assert view_restorer["config"]["unet"]["view_condition"] is True
    assert view_restorer["pair_kinds"] == ["snapshot", "truth:shift@3"]  # novel-view truth is recorded as such
    np.save(tmp_path / "renders.npy", _blur(gt))
    for trajectory in ("shift@3", "original"):  # with the recorded frames as views, and without views
        assert main(["restore", "--restorer", str(tmp_path / "r_view.pt"), "--scene", str(scene.path), "--renders",
                     str(tmp_path / "renders.npy"), "--trajectory", trajectory, "--out", str(tmp_path / f"restored_view_{trajectory}"),
                     "--samples", "1", *common]) == 0
    (pairs / "a__run__shift@3.npz").unlink()

    assert main(["restore", "--restorer", str(tmp_path / "r.pt"), "--scene", str(scene.path), "--renders", str(tmp_path / "renders.npy"),
                 "--trajectory", "shift@3", "--out", str(tmp_path / "restored"), "--sample-steps", "2", "--samples", "1", *common]) == 0
    assert len(list((tmp_path / "restored").glob("*.png"))) == scene.num_frames
    assert main(["dd4d-generate", "--world-model", str(tmp_path / "wm.pt"), "--scene", str(scene.path), "--trajectory", "lane_change",
                 "--out", str(tmp_path / "dd4d"), "--sample-steps", "2", *common]) == 0
    assert len(list((tmp_path / "dd4d").glob("*.png"))) == scene.num_frames
    # Wrong kinds and mismatched renders are one-line errors (exit code 1).
    assert main(["dd4d-generate", "--world-model", str(tmp_path / "r.pt"), "--scene", str(scene.path), "--trajectory", "shift@3",
                 "--out", str(tmp_path / "x")]) == 1
    # Sampling flags are RestoreConfig's, checked against the checkpoint's window.
    assert main(["restore", "--restorer", str(tmp_path / "r.pt"), "--scene", str(scene.path), "--renders", str(tmp_path / "renders.npy"),
                 "--trajectory", "shift@3", "--out", str(tmp_path / "z"), "--overlap", "99"]) == 1
    assert "--overlap must be smaller than the window" in capsys.readouterr().err and not (tmp_path / "z").exists()
    np.save(tmp_path / "short.npy", gt[:3])
    assert main(["restore", "--restorer", str(tmp_path / "r.pt"), "--scene", str(scene.path), "--renders", str(tmp_path / "short.npy"),
                 "--trajectory", "shift@3", "--out", str(tmp_path / "y")]) == 1


class Interrupted(Exception):
    pass


def test_training_resumes_after_a_kill_and_matches_an_uninterrupted_run(tmp_path):
    def make():
        torch.manual_seed(0)
        return torch.nn.Linear(3, 1)

    target = torch.tensor([[1.0], [2.0], [3.0]])

    def loss_fn_factory(module, fail_at=None):
        calls = {"n": 0}

        def loss_fn(rng, generator):
            calls["n"] += 1
            if fail_at is not None and calls["n"] == fail_at:
                raise Interrupted
            x = torch.from_numpy(rng.normal(size=(3, 3)).astype(np.float32)) + torch.randn(3, 3, generator=generator)
            return torch.mean((module(x) - target) ** 2)

        return loss_fn

    identity = {"arch": "toy"}
    straight = make()
    run_training_loop("toy", straight, loss_fn_factory(straight), 6, 0.05, 1, tmp_path / "a.pt", identity, 2, 100, seed=1)

    interrupted = make()
    with pytest.raises(Interrupted):
        run_training_loop("toy", interrupted, loss_fn_factory(interrupted, fail_at=5), 6, 0.05, 1, tmp_path / "b.pt", identity, 2, 100, seed=1)
    assert load_checkpoint(resume_path(tmp_path / "b.pt"), "training_state")["step"] == 4
    resumed = make()
    run_training_loop("toy", resumed, loss_fn_factory(resumed), 6, 0.05, 1, tmp_path / "b.pt", identity, 2, 100, seed=1)
    for a, b in zip(straight.parameters(), resumed.parameters()):
        assert torch.allclose(a, b)
    # The step count may change on resume (a job extended or cut short): it continues from step 4.
    extended = make()
    stats = run_training_loop("toy", extended, loss_fn_factory(extended), 8, 0.05, 1, tmp_path / "b.pt", identity, 2, 100, seed=1)
    assert stats["steps"] == 8 and not torch.allclose(extended.weight, straight.weight)
    # A resume file of a different job is refused rather than silently used.
    from recondreamer.errors import CheckpointError

    with pytest.raises(CheckpointError, match="different job"):
        run_training_loop("toy", make(), loss_fn_factory(make()), 6, 0.05, 1, tmp_path / "b.pt", {"arch": "other"}, 2, 100, seed=1)
