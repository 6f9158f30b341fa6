"""The reference-view input of view-conditioned restorers (UNetConfig.view_condition, tiny sizes)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from test_generative_models import H, W, random_inputs, tiny_model

from recondreamer.configs import to_dict
from recondreamer.errors import RecondreamerError
from recondreamer.generative.config import UNET_FIELDS_ADDED, TrainConfig, unet_config_from_dict
from recondreamer.generative.data import Sequence
from recondreamer.generative.inference import restore_clip
from recondreamer.generative.models import GenerativeModel, restorer_unet_from_world_model
from recondreamer.generative.training import sample_batch
from recondreamer.generative.unet import LatentUNet

# Small tensors: one torch thread each (tests/conftest.py).
pytestmark = pytest.mark.usefixtures("one_torch_thread")

LATENT = (4, H // 4, W // 4)


def view_restorer(world: GenerativeModel) -> GenerativeModel:
    """A dd2_mask restorer with the view input, grown from ``world`` as train-restorer grows it."""
    unet = restorer_unet_from_world_model(world, "dd2_mask", view_condition=True).eval()
    return dataclasses.replace(world, kind="restorer", arch="dd2_mask", unet=unet, unet_config=unet.config)


def restorer_inputs(t: int = 4, seed: int = 3) -> dict:
    x = random_inputs("dd2_mask", t=t)
    g = torch.Generator().manual_seed(seed)
    return x | {"degraded": torch.randn(x["noisy"].shape, generator=g), "view": torch.randn(x["noisy"].shape, generator=g)}


class TestViewInput:
    def test_smoke_and_shape(self):
        restorer = view_restorer(tiny_model("dd2"))
        x = restorer_inputs()
        out = restorer.unet(x["noisy"], x["timesteps"], x["reference"], structure=x["structure"], degraded=x["degraded"], view=x["view"])
        assert out.shape == x["noisy"].shape

    def test_a_new_view_branch_leaves_the_restorer_as_it_was(self):
        # Zero-initialised: grown from a world model, the restorer computes what one without views does.
        world = tiny_model("dd2")
        plain = restorer_unet_from_world_model(world, "dd2_mask").eval()
        viewed = view_restorer(world).unet
        x = restorer_inputs()
        with torch.no_grad():
            expected = plain(x["noisy"], x["timesteps"], x["reference"], structure=x["structure"], degraded=x["degraded"])
            got = viewed(x["noisy"], x["timesteps"], x["reference"], structure=x["structure"], degraded=x["degraded"], view=x["view"])
        torch.testing.assert_close(got, expected, rtol=0, atol=0)

    def test_a_trained_view_branch_reads_the_view(self):
        unet = view_restorer(tiny_model("dd2")).unet
        with torch.no_grad():
            unet.view_in.weight.normal_(0.0, 0.1)
        x = restorer_inputs()
        args = (x["noisy"], x["timesteps"], x["reference"])
        with torch.no_grad():
            first = unet(*args, structure=x["structure"], degraded=x["degraded"], view=x["view"])
            other = unet(*args, structure=x["structure"], degraded=x["degraded"], view=torch.zeros_like(x["view"]))
        assert not torch.allclose(first, other)

    def test_gradients_reach_the_view_branch(self):
        unet = view_restorer(tiny_model("dd2")).unet.train()
        with torch.no_grad():
            unet.view_in.weight.normal_(0.0, 0.1)
        x = restorer_inputs(t=2)
        view = x["view"].requires_grad_(True)
        out = unet(x["noisy"], x["timesteps"], x["reference"], structure=x["structure"], degraded=x["degraded"], view=view)
        out.square().sum().backward()
        assert view.grad is not None and view.grad.abs().sum() > 0
        assert unet.view_in.weight.grad.abs().sum() > 0

    def test_exceptions(self):
        restorer = view_restorer(tiny_model("dd2"))
        x = restorer_inputs()
        args = (x["noisy"], x["timesteps"], x["reference"])
        with pytest.raises(ValueError, match="needs the reference-view latent"):
            restorer.unet(*args, structure=x["structure"], degraded=x["degraded"])
        with pytest.raises(ValueError, match="reference-view latent has shape"):
            restorer.unet(*args, structure=x["structure"], degraded=x["degraded"], view=x["view"][:, :2])
        plain = restorer_unet_from_world_model(tiny_model("dd2"), "dd2_mask")
        with pytest.raises(ValueError, match="no reference-view input"):
            plain(*args, structure=x["structure"], degraded=x["degraded"], view=x["view"])
        with pytest.raises(ValueError, match="needs degraded_condition"):
            LatentUNet(dataclasses.replace(tiny_model("dd2").unet_config, view_condition=True))


class TestStoredConfigs:
    def test_a_config_written_before_the_field_existed_loads_without_views(self):
        config = to_dict(tiny_model("dd2").unet_config)
        for name in UNET_FIELDS_ADDED:
            del config[name]
        assert unet_config_from_dict(config).view_condition is False

    def test_an_unknown_field_is_still_an_error(self):
        config = to_dict(tiny_model("dd2").unet_config) | {"colour": True}
        with pytest.raises(RecondreamerError, match="unknown field"):
            unet_config_from_dict(config)


class TestViewBatches:
    def _sequence(self, with_view: bool, seed: int) -> Sequence:
        g = torch.Generator().manual_seed(seed)
        target = torch.randn(6, *LATENT, generator=g)
        return Sequence(
            name="s", scene_id="s", target=target, reference=target, structure=None,
            degraded=torch.randn(2, 6, *LATENT, generator=g), view=torch.randn(6, *LATENT, generator=g) if with_view else None,
        )

    def test_the_view_crop_matches_the_degraded_crop(self):
        seq = self._sequence(True, 0)
        train = TrainConfig(window=3, crop=(4, 6), batch_size=4)
        batch = sample_batch([seq], np.random.default_rng(2), train, 4, False, True, with_view=True)
        assert batch["view"].shape == batch["degraded"].shape
        for degraded, view in zip(batch["degraded"], batch["view"], strict=True):
            # Locate the clip by its degraded crop, then check the view is the same frames and crop.
            found = [(stage, start, y, x) for stage in range(2) for start in range(4) for y in range(H // 4 - 3) for x in range(W // 4 - 5)
                     if torch.equal(seq.degraded[stage, start:start + 3, :, y:y + 4, x:x + 6], degraded)]
            assert len(found) == 1
            _, start, y, x = found[0]
            assert torch.equal(view, seq.view[start:start + 3, :, y:y + 4, x:x + 6])

    def test_a_sequence_without_views_gets_zeros_and_without_the_flag_there_is_none(self):
        train = TrainConfig(window=3, crop=(0, 0), batch_size=3)
        batch = sample_batch([self._sequence(False, 1)], np.random.default_rng(0), train, 4, False, True, with_view=True)
        assert torch.equal(batch["view"], torch.zeros_like(batch["degraded"]))
        assert sample_batch([self._sequence(True, 1)], np.random.default_rng(0), train, 4, False, True)["view"] is None


class TestRestoreWithViews:
    def _frames(self, seed: int) -> np.ndarray:
        return np.random.default_rng(seed).integers(0, 256, size=(6, H, W, 3), dtype=np.uint8)

    def test_deterministic_and_the_view_matters(self):
        restorer = view_restorer(tiny_model("dd2"))
        with torch.no_grad():
            restorer.unet.view_in.weight.normal_(0.0, 0.5)
        frames, view = self._frames(0), self._frames(1)
        structure = np.random.default_rng(2).random((6, 3, H, W)).astype(np.float32)
        kwargs = {"num_steps": 2, "window": 4, "overlap": 2, "samples": 1, "residual_decoding": False}
        first = restore_clip(restorer, frames, structure, view=view, **kwargs)
        assert np.array_equal(first, restore_clip(restorer, frames, structure, view=view, **kwargs))
        assert not np.array_equal(first, restore_clip(restorer, frames, structure, view=self._frames(3), **kwargs))
        # No view: the frames count as having none (zero latents), as original-trajectory pairs in training.
        assert restore_clip(restorer, frames, structure, **kwargs).shape == frames.shape

    def test_exceptions(self):
        restorer = view_restorer(tiny_model("dd2"))
        frames = self._frames(0)
        structure = np.random.default_rng(2).random((6, 3, H, W)).astype(np.float32)
        with pytest.raises(RecondreamerError, match="reference views .* do not match"):
            restore_clip(restorer, frames, structure, view=frames[:3])
        with pytest.raises(RecondreamerError, match="reference views must be a"):
            restore_clip(restorer, frames, structure, view=frames.astype(np.float32))
        plain = tiny_model("dd2_mask", kind="restorer")
        with pytest.raises(RecondreamerError, match="takes no reference views"):
            restore_clip(plain, frames, structure, view=frames)


class TestGateWithViews:
    """foundation.gates.restorer_gate hands a view-conditioned restorer the pairs' reference views."""

    def _pairs(self, folder, trajectory: str, with_view: bool, seed: int):
        rng = np.random.default_rng(seed)
        frames = rng.integers(0, 256, size=(6, H, W, 3), dtype=np.uint8)
        arrays = {
            "gt": frames, "degraded": np.stack([frames // 2, frames // 3]), "stages": np.array([1, 2]),
            "structure": rng.integers(0, 256, size=(6, 3, H, W), dtype=np.uint8), "vanishing": np.zeros((6, 2)),
            "scene_id": np.array("gate-x"), "trajectory": np.array(trajectory),
        }
        if with_view:
            arrays["view"] = rng.integers(0, 256, size=(6, H, W, 3), dtype=np.uint8)
        path = folder / f"gate-x__{trajectory}.npz"
        np.savez_compressed(path, **arrays)
        return path

    def _checkpoint(self, path):
        from recondreamer.generative.checkpoint import save_checkpoint
        from recondreamer.generative.models import autoencoder_payload, model_config_dict

        restorer = view_restorer(tiny_model("dd2"))
        with torch.no_grad():
            restorer.unet.view_in.weight.normal_(0.0, 0.5)
        save_checkpoint(path, "restorer", "dd2_mask", model_config_dict(restorer), restorer.unet.state_dict(),
                        autoencoder=autoencoder_payload(restorer.autoencoder), training_scenes=[])
        return path

    def test_views_are_used_withheld_on_request_and_required_on_novel_pairs(self, tmp_path):
        from recondreamer.foundation.gates import restorer_gate

        checkpoint = self._checkpoint(tmp_path / "r.pt")
        files = [self._pairs(tmp_path, "original", False, 0), self._pairs(tmp_path, "shift@3", True, 1)]
        with_views = restorer_gate(checkpoint, files)
        withheld = restorer_gate(checkpoint, files, withhold_views=True)
        assert with_views["original"] == withheld["original"]  # no views there either way
        assert with_views["shift@3"]["restored_psnr"] != withheld["shift@3"]["restored_psnr"]
        files[1] = self._pairs(tmp_path, "shift@3", False, 1)
        with pytest.raises(RecondreamerError, match="needs gate pairs with reference views"):
            restorer_gate(checkpoint, files)
