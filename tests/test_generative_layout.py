"""Channels-last conv weights on the CPU (device.use_fast_conv_layout): the fast layout against
the contiguous one as its reference twin, for outputs and gradients."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from recondreamer.generative.autoencoder import Autoencoder
from recondreamer.generative.config import AutoencoderConfig
from recondreamer.device import use_fast_conv_layout
from recondreamer.training_loop import run_training_loop
from recondreamer.generative.unet import LatentUNet
from test_generative_models import H, W, random_inputs, tiny_model, tiny_unet_config

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def conv_weights(module: torch.nn.Module) -> list[torch.Tensor]:
    return [p for p in module.parameters() if p.dim() == 4]


def test_layout_is_channels_last_on_cpu_and_keeps_values():
    torch.manual_seed(0)
    unet = LatentUNet(tiny_unet_config("dd2_mask", degraded=True))
    before = {name: p.detach().clone() for name, p in unet.named_parameters()}
    assert use_fast_conv_layout(unet) is unet
    assert conv_weights(unet) and all(p.is_contiguous(memory_format=torch.channels_last) for p in conv_weights(unet))
    assert not all(p.is_contiguous() for p in conv_weights(unet))  # the layout really changed
    for name, p in unet.named_parameters():
        torch.testing.assert_close(p, before[name], rtol=0, atol=0)


@pytest.mark.parametrize("arch", ["sd", "dd2_mask"])
def test_unet_outputs_and_gradients_match_the_contiguous_twin(arch):
    reference = tiny_model(arch, kind="restorer" if arch == "dd2_mask" else "world_model").unet.train()
    fast = use_fast_conv_layout(copy.deepcopy(reference))
    inputs = random_inputs(arch)
    if arch == "dd2_mask":
        inputs["degraded"] = torch.randn_like(inputs["noisy"])
    cotangent = torch.randn(inputs["noisy"].shape, generator=torch.Generator().manual_seed(5))
    outputs = []
    for unet in (reference, fast):
        unet.zero_grad()
        noisy = inputs["noisy"].clone().requires_grad_(True)
        out = unet(noisy, inputs["timesteps"], inputs["reference"], structure=inputs["structure"], degraded=inputs.get("degraded"))
        out.backward(cotangent)
        outputs.append((out.detach(), noisy.grad, {n: p.grad for n, p in unet.named_parameters()}))
    (ref_out, ref_in_grad, ref_grads), (out, in_grad, grads) = outputs
    torch.testing.assert_close(out, ref_out, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(in_grad, ref_in_grad, rtol=1e-4, atol=1e-5)
    # Some gradients are sums that nearly cancel (a bias in front of a group norm): compare each
    # against the scale of the largest gradient, where float rounding of the two loop orders lies.
    scale = max(grad.abs().max().item() for grad in ref_grads.values())
    for name, grad in ref_grads.items():
        difference = (grads[name] - grad).abs().max().item()
        assert difference <= 2e-6 * scale + 1e-6, f"gradient of {name}: differs by {difference:.3g} (largest gradient {scale:.3g})"


def test_autoencoder_matches_the_contiguous_twin():
    torch.manual_seed(0)
    reference = Autoencoder(AutoencoderConfig(hidden_channels=(8, 8, 8))).eval()
    fast = use_fast_conv_layout(copy.deepcopy(reference))
    images = torch.rand(3, 3, H, W, generator=torch.Generator().manual_seed(1)) * 2 - 1
    with torch.no_grad():
        torch.testing.assert_close(fast.encode(images), reference.encode(images), rtol=1e-4, atol=1e-5)
        latents = reference.encode(images)
        torch.testing.assert_close(fast.decode(latents), reference.decode(latents), rtol=1e-4, atol=1e-5)


def test_generative_model_to_cpu_uses_the_layout():
    model = tiny_model("dd2").to("cpu")
    for module in (model.unet, model.autoencoder):
        assert all(p.is_contiguous(memory_format=torch.channels_last) for p in conv_weights(module))


def test_training_loop_trains_channels_last_and_saves_loadable_weights(tmp_path):
    """The loop converts the module it optimises; its weights load into a fresh contiguous
    module, which then computes what the trained one does."""
    torch.manual_seed(0)
    unet = LatentUNet(tiny_unet_config("sd"))
    inputs = random_inputs("sd")

    def loss_fn(rng: np.random.Generator, generator: torch.Generator) -> torch.Tensor:
        return unet(inputs["noisy"], inputs["timesteps"], inputs["reference"]).square().mean()

    run_training_loop("layout", unet, loss_fn, 3, 1e-3, 1, tmp_path / "out.pt", {"kind": "test"}, 100, 100, 0)
    assert all(p.is_contiguous(memory_format=torch.channels_last) for p in conv_weights(unet))
    path = tmp_path / "state.pt"
    torch.save(unet.state_dict(), path)
    fresh = LatentUNet(tiny_unet_config("sd")).eval()
    fresh.load_state_dict(torch.load(path, weights_only=True))
    with torch.no_grad():
        torch.testing.assert_close(
            fresh(inputs["noisy"], inputs["timesteps"], inputs["reference"]),
            unet(inputs["noisy"], inputs["timesteps"], inputs["reference"]),
            rtol=1e-4, atol=1e-5,
        )
