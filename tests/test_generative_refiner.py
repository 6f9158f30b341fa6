"""DriveRestorer's pixel refiner: identity at start, input checks, training, checkpoint and restore (tiny sizes)."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from test_generative_models import H, STRUCTURE, W, tiny_model

from recondreamer.cli import main
from recondreamer.errors import CheckpointError, RecondreamerError
from recondreamer.generative.autoencoder import frames_to_tensor, tensor_to_frames
from recondreamer.generative.checkpoint import load_checkpoint, save_checkpoint
from recondreamer.configs import to_dict
from recondreamer.generative.config import RefinerConfig, RestoreConfig
from recondreamer.generative.data import restored_pair_frames, structure_from_uint8
from recondreamer.generative.inference import load_restorer, restore_clip
from recondreamer.generative.models import autoencoder_payload, model_config_dict, refiner_from_payload
from recondreamer.generative.refiner import PixelChannelNorm, PixelRefiner, neighbour_frames, neighbour_stack, refine_frames
from recondreamer.generative.training import RefinerExample, refiner_check_losses, restorer_digest, sample_refiner_batch, train_refiner

# Small tensors: one torch thread each (tests/conftest.py).
pytestmark = pytest.mark.usefixtures("one_torch_thread")

TINY = RefinerConfig(width=4, bottleneck_blocks=1, steps=4, batch_size=2, crop=16, checkpoint_every=2, log_every=2)
TEMPORAL = dataclasses.replace(TINY, temporal_neighbours=2)
FRAMES = 5


def random_frames(n: int, seed: int) -> torch.Tensor:  # (n,3,H,W) in [-1,1]
    return torch.rand(n, 3, H, W, generator=torch.Generator().manual_seed(seed)) * 2.0 - 1.0


def randomised(refiner: PixelRefiner) -> PixelRefiner:
    """Every weight random, the zero-initialised output conv included (it would hide the other branches)."""
    with torch.no_grad():
        for parameter in refiner.parameters():
            parameter.normal_(0.0, 0.1)
    return refiner


def test_a_fresh_refiner_returns_the_restored_frames_exactly():
    refiner = PixelRefiner(TINY, len(STRUCTURE))
    restored, degraded = random_frames(2, 0), random_frames(2, 1)
    structure = torch.rand(2, len(STRUCTURE), H, W)
    assert torch.equal(refiner(restored, degraded, structure), restored)


def test_every_input_reaches_the_output():
    torch.manual_seed(0)
    refiner = randomised(PixelRefiner(TINY, len(STRUCTURE)))
    restored, degraded, structure = random_frames(1, 0), random_frames(1, 1), torch.rand(1, len(STRUCTURE), H, W)
    base = refiner(restored, degraded, structure)
    assert base.shape == (1, 3, H, W)
    assert not torch.allclose(refiner(restored, random_frames(1, 2), structure), base)
    assert not torch.allclose(refiner(restored, degraded, torch.zeros_like(structure)), base)
    assert not torch.allclose(refiner(random_frames(1, 3), degraded, structure) - random_frames(1, 3), base - restored)


def test_the_refiner_is_per_frame():
    torch.manual_seed(0)
    refiner = randomised(PixelRefiner(TINY, 0))
    restored, degraded = random_frames(3, 0), random_frames(3, 1)
    together = refiner(restored, degraded)
    alone = torch.cat([refiner(restored[i : i + 1], degraded[i : i + 1]) for i in range(3)])
    assert torch.allclose(together, alone, atol=1e-6)


def test_the_output_norm_works_per_pixel_so_crops_match_whole_frames():
    features = torch.randn(2, 6, H, W, generator=torch.Generator().manual_seed(0)) * 50.0 - 300.0
    normed = PixelChannelNorm()(features)
    assert torch.allclose(normed.mean(dim=1), torch.zeros(2, H, W), atol=1e-5)
    assert torch.allclose(normed.var(dim=1, unbiased=False), torch.ones(2, H, W), atol=1e-3)
    assert torch.allclose(PixelChannelNorm()(features[:, :, 3:11, 5:17]), normed[:, :, 3:11, 5:17])


def test_features_drifting_before_the_last_conv_do_not_switch_the_correction_off():
    """A dead refiner: features before its last SiLU around -1000, output = input, no gradient."""
    torch.manual_seed(0)
    restored, degraded, structure = random_frames(1, 0), random_frames(1, 1), torch.rand(1, len(STRUCTURE), H, W)
    for output_norm in (True, False):
        # Unbounded, so that the correction read below is the last conv's own output.
        refiner = randomised(PixelRefiner(dataclasses.replace(TINY, output_norm=output_norm, max_correction=0.0), len(STRUCTURE)))
        before = refiner(restored, degraded, structure)
        with torch.no_grad():
            refiner.full_out.conv2.bias -= 1000.0  # every feature before the norm shifted far into SiLU's flat part
        after = refiner(restored, degraded, structure)
        after.square().mean().backward()
        gradient = refiner.conv_in.weight.grad.abs().max().item()
        if output_norm:
            assert torch.allclose(after, before, atol=1e-3) and gradient > 1e-4  # the norm removes a shift shared by all channels
        else:
            assert torch.allclose(after - restored, refiner.conv_out.bias.view(1, 3, 1, 1).expand_as(after), atol=1e-6)
            assert gradient == 0.0


def test_the_correction_is_clipped_to_max_correction_grey_levels():
    torch.manual_seed(0)
    restored, degraded = random_frames(2, 0), random_frames(2, 1)
    for bias in (5.0, -5.0):  # a correction of 5 pixel units = 637 grey levels, far past the bound
        refiner = randomised(PixelRefiner(dataclasses.replace(TINY, max_correction=8.0), 0))
        with torch.no_grad():
            refiner.conv_out.bias.fill_(bias)
        correction = refiner(restored, degraded) - restored
        assert torch.allclose(correction, torch.full_like(correction, np.sign(bias) * 8.0 / 127.5), atol=1e-6)
        unbounded = dataclasses.replace(refiner.config, max_correction=0.0)
        refiner.config = unbounded
        assert (refiner(restored, degraded) - restored).abs().min() > 1.0
    small = randomised(PixelRefiner(dataclasses.replace(TINY, max_correction=1000.0), 0))
    bounded_far_away = small(restored, degraded)
    small.config = dataclasses.replace(small.config, max_correction=0.0)
    assert torch.equal(bounded_far_away, small(restored, degraded))  # corrections within the bound pass unchanged


def test_a_refiner_round_trips_and_one_of_another_code_version_is_refused():
    torch.manual_seed(0)
    refiner = randomised(PixelRefiner(TINY, 0))
    config = to_dict(refiner.config)
    loaded = refiner_from_payload({"config": config, "structure_channels": 0, "state": refiner.state_dict()})
    restored, degraded = random_frames(1, 0), random_frames(1, 1)
    assert loaded.config == refiner.config and torch.equal(loaded(restored, degraded), refiner(restored, degraded))
    del config["output_norm"]  # a refiner written before the field existed: never silently given today's default
    with pytest.raises(RecondreamerError, match=r"missing field\(s\) \['output_norm'\]"):
        refiner_from_payload({"config": config, "structure_channels": 0, "state": refiner.state_dict()})


def test_neighbour_frames_stand_in_with_the_clip_ends():
    assert neighbour_frames(2, 5, 2) == [0, 1, 3, 4]
    assert neighbour_frames(0, 5, 2) == [0, 0, 1, 2]
    assert neighbour_frames(4, 5, 1) == [3, 4]
    assert neighbour_frames(0, 1, 1) == [0, 0]


def test_a_temporal_refiner_starts_as_the_identity_and_sees_its_neighbours():
    torch.manual_seed(0)
    restored, degraded, structure = random_frames(2, 0), random_frames(2, 1), torch.rand(2, len(STRUCTURE), H, W)
    neighbours = torch.rand(2, 4, 6, H, W) * 2.0 - 1.0
    assert torch.equal(PixelRefiner(TEMPORAL, len(STRUCTURE))(restored, degraded, structure, neighbours), restored)
    refiner = randomised(PixelRefiner(TEMPORAL, len(STRUCTURE)))
    base = refiner(restored, degraded, structure, neighbours)
    for k in range(4):  # every neighbour, restored and degraded channels alike
        for channels in (slice(0, 3), slice(3, 6)):
            changed = neighbours.clone()
            changed[:, k, channels] = 0.0
            assert not torch.allclose(refiner(restored, degraded, structure, changed), base)


def test_bad_inputs_give_clear_errors():
    refiner = PixelRefiner(TINY, len(STRUCTURE))
    restored = random_frames(2, 0)
    with pytest.raises(ValueError, match="degraded frames have shape"):
        refiner(restored, random_frames(1, 1), torch.rand(2, len(STRUCTURE), H, W))
    with pytest.raises(ValueError, match="needs structure maps"):
        refiner(restored, random_frames(2, 1), None)
    with pytest.raises(ValueError, match="restored frames must be"):
        refiner(restored[:, :2], random_frames(2, 1)[:, :2], torch.rand(2, len(STRUCTURE), H, W))
    with pytest.raises(ValueError, match="sees single frames"):
        refiner(restored, random_frames(2, 1), torch.rand(2, len(STRUCTURE), H, W), torch.zeros(2, 4, 6, H, W))
    temporal = PixelRefiner(TEMPORAL, 0)
    with pytest.raises(ValueError, match=re.escape(f"needs neighbour frames of shape (2, 4, 6, {H}, {W})")):
        temporal(restored, random_frames(2, 1), None, torch.zeros(2, 2, 6, H, W))
    with pytest.raises(ValueError, match="needs neighbour frames"):
        temporal(restored, random_frames(2, 1))


def test_one_training_step_lowers_the_loss_on_a_fixed_batch():
    torch.manual_seed(0)
    refiner = PixelRefiner(TINY, 0)
    restored, degraded = random_frames(4, 0), random_frames(4, 1)
    target = (restored + degraded) / 2.0
    optimizer = torch.optim.Adam(refiner.parameters(), lr=1e-2)
    losses = []
    for _ in range(2):
        loss = torch.mean((refiner(restored, degraded) - target) ** 2)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert losses[1] < losses[0]


def test_refine_frames_matches_the_module_in_batches():
    torch.manual_seed(0)
    refiner = randomised(PixelRefiner(TINY, len(STRUCTURE)))
    rng = np.random.default_rng(0)
    restored = rng.integers(0, 256, (5, H, W, 3), dtype=np.uint8)
    degraded = rng.integers(0, 256, (5, H, W, 3), dtype=np.uint8)
    structure = torch.rand(5, len(STRUCTURE), H, W)
    out = refine_frames(refiner, restored, degraded, structure, batch_frames=2)
    with torch.no_grad():
        expected = refiner(frames_to_tensor(restored), frames_to_tensor(degraded), structure)
    expected = ((expected.clamp(-1, 1) + 1) * 127.5).round().to(torch.uint8).permute(0, 2, 3, 1).numpy()
    assert out.dtype == np.uint8 and np.array_equal(out, expected)


def test_a_temporal_refiner_sees_the_clip_around_each_frame_across_batches():
    torch.manual_seed(0)
    refiner = randomised(PixelRefiner(TEMPORAL, 0))
    rng = np.random.default_rng(0)
    restored = rng.integers(0, 256, (5, H, W, 3), dtype=np.uint8)
    degraded = rng.integers(0, 256, (5, H, W, 3), dtype=np.uint8)
    out = refine_frames(refiner, restored, degraded, None, batch_frames=2)
    for t in range(5):  # frame by frame, its neighbours gathered by hand
        around = [min(max(t + offset, 0), 4) for offset in (-2, -1, 1, 2)]
        neighbours = torch.cat([frames_to_tensor(restored[around]), frames_to_tensor(degraded[around])], dim=1)[None]
        with torch.no_grad():
            expected = refiner(frames_to_tensor(restored[t : t + 1]), frames_to_tensor(degraded[t : t + 1]), None, neighbours)
        assert np.array_equal(out[t : t + 1], tensor_to_frames(expected))


def tiny_restorer_file(path: Path, seed: int = 0) -> Path:
    model = tiny_model("dd2_mask", "restorer", seed)
    model.restore_config = RestoreConfig(window=4, overlap=1, sample_steps=1, residual_decoding=True)
    save_checkpoint(
        path, "restorer", model.arch, model_config_dict(model), model.unet.state_dict(),
        autoencoder=autoencoder_payload(model.autoencoder), training_scenes=["corpus-001"], world_model="wm.pt",
    )
    return path


def tiny_pairs_file(path: Path, scene_id: str, stages: int = 2) -> Path:
    rng = np.random.default_rng(len(scene_id) + stages)
    gt = rng.integers(0, 256, (FRAMES, H, W, 3), dtype=np.uint8)
    degraded = np.clip(gt[None].astype(np.int16) + rng.integers(-30, 31, (stages, FRAMES, H, W, 3)), 0, 255).astype(np.uint8)
    np.savez_compressed(
        path, gt=gt, degraded=degraded, stages=np.arange(stages) * 100,
        structure=rng.integers(0, 256, (FRAMES, len(STRUCTURE), H, W), dtype=np.uint8),
        vanishing=np.tile([W / 2, H / 2], (FRAMES, 1)), scene_id=np.array(scene_id), trajectory=np.array("original"),
    )
    return path


def test_train_refiner_writes_the_restorer_with_its_refiner_and_restore_uses_it(tmp_path):
    restorer_path = tiny_restorer_file(tmp_path / "r.pt")
    pairs = tiny_pairs_file(tmp_path / "corpus-002__street.npz", "corpus-002")
    stats = train_refiner(restorer_path, [pairs], TINY, tmp_path / "refined.pt")
    assert stats["steps"] == TINY.steps and np.isfinite(stats["final_loss"])
    assert np.isfinite(stats["check_loss"]) and stats["identity_loss"] > 0.0
    payload = load_checkpoint(tmp_path / "refined.pt", "restorer")
    original = load_checkpoint(restorer_path, "restorer")
    assert payload["training_scenes"] == ["corpus-001", "corpus-002"]  # benchmarks skip both
    assert payload["world_model"] == "wm.pt" and payload["refiner"]["restorer"] == str(restorer_path)
    assert all(torch.equal(payload["state"][k], original["state"][k]) for k in original["state"])
    assert not (tmp_path / "refined.pt.resume.pt").exists()

    plain, refined = load_restorer(restorer_path), load_restorer(tmp_path / "refined.pt")
    assert plain.refiner is None and refined.refiner is not None
    with np.load(pairs) as content:
        degraded, structure = content["degraded"][0], content["structure"]
    diffusion_only = restore_clip(plain, degraded, structure)
    assert np.array_equal(restore_clip(refined, degraded, structure, refine=False), diffusion_only)
    expected = refine_frames(refined.refiner, diffusion_only, degraded, structure_from_uint8(structure))
    assert np.array_equal(restore_clip(refined, degraded, structure), expected)

    # The restorer's outputs were cached next to the pairs, named after the restorer.
    cache = tmp_path / f"corpus-002__street.restored-{restorer_digest(plain)}.pt"
    assert cache.is_file()
    cached = torch.load(cache, weights_only=True).numpy()
    assert np.array_equal(cached[0], diffusion_only)

    with pytest.raises(CheckpointError, match="already has a pixel refiner"):
        train_refiner(tmp_path / "refined.pt", [pairs], TINY, tmp_path / "again.pt")


def test_a_refiner_learns_from_and_stores_the_restore_samples_it_was_given(tmp_path):
    restorer_path = tiny_restorer_file(tmp_path / "r.pt")
    pairs = tiny_pairs_file(tmp_path / "corpus-002__street.npz", "corpus-002")
    train_refiner(restorer_path, [pairs], TINY, tmp_path / "refined.pt", samples=3)
    plain, refined = load_restorer(restorer_path), load_restorer(tmp_path / "refined.pt")
    assert plain.restore_config.samples == 1 and refined.restore_config.samples == 3
    # Its training outputs were the 3-sample ones, cached under a name of their own.
    averaged = dataclasses.replace(plain, restore_config=dataclasses.replace(plain.restore_config, samples=3))
    assert restorer_digest(averaged) != restorer_digest(plain)
    cached = torch.load(tmp_path / f"corpus-002__street.restored-{restorer_digest(averaged)}.pt", weights_only=True).numpy()
    with np.load(pairs) as content:
        degraded, structure = content["degraded"][0], content["structure"]
    assert np.array_equal(cached[0], restore_clip(plain, degraded, structure, samples=3))
    assert np.array_equal(restore_clip(refined, degraded, structure, refine=False), cached[0])


def test_a_temporal_refiner_trains_from_the_command_line_and_is_reloaded_as_trained(tmp_path):
    restorer_path = tiny_restorer_file(tmp_path / "r.pt")
    pairs = tiny_pairs_file(tmp_path / "corpus-002__street.npz", "corpus-002")
    out = tmp_path / "refined.pt"
    assert main(["train-refiner", "--restorer", str(restorer_path), "--pairs", str(pairs), "--out", str(out), "--steps", "2",
                 "--batch-size", "2", "--crop", "16", "--width", "4", "--temporal-neighbours", "1"]) == 0
    refined = load_restorer(out)
    assert refined.refiner.config.temporal_neighbours == 1 and refined.refiner.config.output_norm
    with np.load(pairs) as content:
        degraded, structure = content["degraded"][0], content["structure"]
    diffusion_only = restore_clip(refined, degraded, structure, refine=False)
    expected = refine_frames(refined.refiner, diffusion_only, degraded, structure_from_uint8(structure))
    assert np.array_equal(restore_clip(refined, degraded, structure), expected)


def test_a_killed_refiner_job_resumes_and_matches_an_uninterrupted_one(tmp_path):
    restorer_path = tiny_restorer_file(tmp_path / "r.pt")
    pairs = tiny_pairs_file(tmp_path / "corpus-002__street.npz", "corpus-002")
    train_refiner(restorer_path, [pairs], TINY, tmp_path / "straight.pt")
    train_refiner_stopped_at(restorer_path, pairs, tmp_path / "resumed.pt", stop_after=2)
    assert (tmp_path / "resumed.pt.resume.pt").is_file()
    train_refiner(restorer_path, [pairs], TINY, tmp_path / "resumed.pt")
    straight = load_checkpoint(tmp_path / "straight.pt", "restorer")["refiner"]["state"]
    resumed = load_checkpoint(tmp_path / "resumed.pt", "restorer")["refiner"]["state"]
    assert all(torch.allclose(straight[k], resumed[k]) for k in straight)


def train_refiner_stopped_at(restorer_path: Path, pairs: Path, out: Path, stop_after: int) -> None:
    """Run the TINY refiner job and kill it (an exception) during the step after ``stop_after``."""
    import recondreamer.generative.training as training

    real = training.sample_refiner_batch
    calls = {"n": 0}

    def failing(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] > stop_after:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    training.sample_refiner_batch = failing
    try:
        with pytest.raises(KeyboardInterrupt):
            train_refiner(restorer_path, [pairs], TINY, out)
    finally:
        training.sample_refiner_batch = real


def test_the_restored_cache_is_rebuilt_when_it_no_longer_fits(tmp_path):
    pairs = tiny_pairs_file(tmp_path / "p.npz", "corpus-002", stages=2)
    content = dict(np.load(pairs))
    calls = []

    def restore(frames, structure):
        calls.append(1)
        return frames[::-1].copy()

    first = restored_pair_frames(pairs, content, restore, "abc")
    assert len(calls) == 2 and np.array_equal(first[1], content["degraded"][1][::-1])
    restored_pair_frames(pairs, content, restore, "abc")
    assert len(calls) == 2  # cached
    content["degraded"] = content["degraded"][:1]  # the pairs changed: one stage only
    assert restored_pair_frames(pairs, content, restore, "abc").shape[0] == 1 and len(calls) == 3


def test_refiner_batches_are_aligned_crops():
    rng = np.random.default_rng(0)
    gt = rng.integers(0, 256, (3, H, W, 3), dtype=np.uint8)
    degraded = rng.integers(0, 256, (2, 3, H, W, 3), dtype=np.uint8)
    restored = rng.integers(0, 256, (2, 3, H, W, 3), dtype=np.uint8)
    structure = rng.integers(0, 256, (3, len(STRUCTURE), H, W), dtype=np.uint8)
    example = RefinerExample("s", gt, degraded, restored, structure)
    batch = sample_refiner_batch([example], np.random.default_rng(1), dataclasses.replace(TINY, batch_size=3))
    assert batch["restored"].shape == batch["degraded"].shape == batch["target"].shape == (3, 3, 16, 16)
    assert batch["structure"].shape == (3, len(STRUCTURE), 16, 16)
    for i in range(3):  # find where each crop came from by its target, then check the other arrays are from there
        found = [
            (t, y, x) for t in range(3) for y in range(H - 15) for x in range(W - 15)
            if torch.equal(batch["target"][i], frames_to_tensor(gt[t : t + 1, y : y + 16, x : x + 16])[0])
        ]
        assert len(found) == 1
        t, y, x = found[0]
        stages = [k for k in range(2) if torch.equal(batch["degraded"][i], frames_to_tensor(degraded[k, t : t + 1, y : y + 16, x : x + 16])[0])]
        assert len(stages) == 1
        assert torch.equal(batch["restored"][i], frames_to_tensor(restored[stages[0], t : t + 1, y : y + 16, x : x + 16])[0])
        assert torch.equal(batch["structure"][i], structure_from_uint8(structure[t, :, y : y + 16, x : x + 16]))
    assert batch["neighbours"] is None
    batch = sample_refiner_batch([example], np.random.default_rng(1), dataclasses.replace(TEMPORAL, batch_size=3))
    for i in range(3):  # the neighbours are the same crop of the same stage's frames around
        (t, y, x), = [
            (t, y, x) for t in range(3) for y in range(H - 15) for x in range(W - 15)
            if torch.equal(batch["target"][i], frames_to_tensor(gt[t : t + 1, y : y + 16, x : x + 16])[0])
        ]
        stage, = [k for k in range(2) if torch.equal(batch["degraded"][i], frames_to_tensor(degraded[k, t : t + 1, y : y + 16, x : x + 16])[0])]
        rows, cols = slice(y, y + 16), slice(x, x + 16)
        assert torch.equal(batch["neighbours"][i], neighbour_stack(restored[stage], degraded[stage], t, 2, rows, cols))
    with pytest.raises(RecondreamerError, match="larger than"):
        sample_refiner_batch([example], np.random.default_rng(1), dataclasses.replace(TINY, crop=H + 1))


def test_train_refiner_command_rejects_bad_options(tmp_path, capsys):
    restorer_path = tiny_restorer_file(tmp_path / "r.pt")
    pairs = tiny_pairs_file(tmp_path / "corpus-002__street.npz", "corpus-002")
    base = ["train-refiner", "--restorer", str(restorer_path), "--pairs", str(pairs), "--out", str(tmp_path / "o.pt")]
    assert main([*base, "--crop", "0"]) == 1
    assert "--crop must be >= 1" in capsys.readouterr().err
    assert main([*base, "--ema-decay", "1.5"]) == 1
    assert "--ema-decay must be in [0, 1)" in capsys.readouterr().err
    assert main([*base, "--temporal-neighbours", "-1"]) == 1
    assert "--temporal-neighbours must be >= 0" in capsys.readouterr().err
    assert main([*base, "--samples", "0"]) == 1
    assert "--samples must be >= 1" in capsys.readouterr().err
    assert main([*base, "--max-correction", "-1"]) == 1
    assert "--max-correction must be >= 0, got -1.0" in capsys.readouterr().err
    assert main([*base, "--steps", "1", "--batch-size", "1", "--crop", "16", "--width", "4", "--output-norm", "off",
                 "--max-correction", "6"]) == 0
    written = load_restorer(tmp_path / "o.pt").refiner.config
    assert not written.output_norm and written.max_correction == 6.0
    (tmp_path / "o.pt").unlink()
    assert main(["train-refiner", "--restorer", str(pairs), "--pairs", str(pairs), "--out", str(tmp_path / "o.pt")]) == 1
    assert not (tmp_path / "o.pt").exists()


def test_the_check_losses_compare_the_refiner_with_the_identity():
    rng = np.random.default_rng(0)
    gt = rng.integers(0, 256, (3, H, W, 3), dtype=np.uint8)
    restored = rng.integers(0, 256, (2, 3, H, W, 3), dtype=np.uint8)
    example = RefinerExample("s", gt, rng.integers(0, 256, (2, 3, H, W, 3), dtype=np.uint8), restored, None)
    fresh = PixelRefiner(TINY, 0)
    refined, identity = refiner_check_losses(fresh, [example], TINY)
    assert refined == identity > 0.0  # a fresh refiner returns its input exactly
    refined, identity_again = refiner_check_losses(randomised(PixelRefiner(TINY, 0)), [example], TINY)
    assert identity_again == identity and refined != identity  # fixed batches, whatever the refiner


def test_a_refiner_that_does_not_beat_the_identity_is_warned_about(tmp_path, caplog):
    restorer_path = tiny_restorer_file(tmp_path / "r.pt")
    pairs = tiny_pairs_file(tmp_path / "corpus-002__street.npz", "corpus-002")
    with caplog.at_level("WARNING"):
        stats = train_refiner(restorer_path, [pairs], dataclasses.replace(TINY, learning_rate=0.0), tmp_path / "refined.pt")
    assert stats["check_loss"] == stats["identity_loss"]  # never trained: still the identity
    assert "is not 1% below the restorer's own error" in caplog.text
