"""The GPU paths: the generative stack's ``--device`` (option parsing, clear errors, CPU numerics,
and on a GPU training and sampling on CUDA against the same model on the CPU), and the gsplat
backend's own rendering of an empty scene."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from recondreamer.cli import build_parser, main
from recondreamer.errors import RecondreamerError
from recondreamer.generative.autoencoder import Autoencoder
from recondreamer.generative.checkpoint import load_checkpoint, save_checkpoint
from recondreamer.generative.config import (
    AutoencoderConfig,
    DiffusionConfig,
    TrainConfig,
    UNetConfig,
)
from recondreamer.generative.data import Sequence
from recondreamer.device import module_device, resolve_device, tensors_to_cpu
from recondreamer.generative.diffusion import NoiseSchedule, diffusion_loss_and_estimate
from recondreamer.generative.inference import load_restorer, restore_clip
from recondreamer.generative.models import (
    GenerativeModel,
    autoencoder_payload,
    model_config_dict,
)
from recondreamer.generative.training import sample_batch, unet_loss
from recondreamer.generative.unet import LatentUNet
from recondreamer.recon.commands import training_config

pytestmark = pytest.mark.usefixtures("one_torch_thread")

CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
H, W = 32, 48  # pixels; latents 8x12
STRUCTURE = ("boxes", "lanes", "edges")
DEVICE_COMMANDS = ("train-autoencoder", "pretrain-world-model", "train-restorer", "restore", "dd4d-generate")


def tiny_restorer(seed: int = 0) -> GenerativeModel:
    """A dd2_mask restorer with every weight random (zero-initialised layers would hide branches)."""
    torch.manual_seed(seed)
    config = UNetConfig(
        arch="dd2_mask", channels=(8, 16), attention_levels=(False, True), temporal_levels=(True, True), num_heads=2,
        time_embed_dim=16, structure_channels=len(STRUCTURE), structure_hidden=4, degraded_condition=True,
    )
    unet = LatentUNet(config)
    autoencoder = Autoencoder(AutoencoderConfig(hidden_channels=(8, 8, 8)))
    with torch.no_grad():
        for parameter in unet.parameters():
            parameter.normal_(0.0, 0.1)
    diffusion = DiffusionConfig(sample_steps=3, target_space="residual", residual_scale=0.5)
    return GenerativeModel(
        kind="restorer", arch="dd2_mask", unet=unet.eval(), autoencoder=autoencoder.eval(), schedule=NoiseSchedule(diffusion),
        unet_config=config, diffusion_config=diffusion, train_config=TrainConfig(window=4, crop=(0, 0), batch_size=2),
        structure_channels=STRUCTURE, frame_size=(H, W),
    )


def clip(seed: int = 0, frames: int = 6) -> tuple[np.ndarray, np.ndarray]:  # (T,H,W,3) uint8, (T,S,H,W) uint8
    rng = np.random.default_rng(seed)
    return (
        rng.integers(0, 256, size=(frames, H, W, 3), dtype=np.uint8),
        rng.integers(0, 256, size=(frames, len(STRUCTURE), H, W), dtype=np.uint8),
    )


# ---------------------------------------------------------------------------------------- CPU


@pytest.mark.parametrize("command", DEVICE_COMMANDS)
def test_every_generative_command_takes_a_device_that_defaults_to_cpu(command):
    parser = build_parser()
    required = {
        "train-autoencoder": ["--corpus", "c", "--out", "o"],
        "pretrain-world-model": ["--arch", "dd2", "--corpus", "c", "--autoencoder", "a", "--out", "o"],
        "train-restorer": ["--arch", "dd2_mask", "--world-model", "w", "--pairs", "p", "--out", "o"],
        "restore": ["--restorer", "r", "--scene", "s", "--renders", "x", "--trajectory", "original", "--out", "o"],
        "dd4d-generate": ["--world-model", "w", "--scene", "s", "--trajectory", "shift@3", "--out", "o"],
    }[command]
    assert parser.parse_args([command, *required]).device == "cpu"
    assert parser.parse_args([command, *required, "--device", "cuda:1"]).device == "cuda:1"


def test_methods_run_their_generative_models_on_the_recon_device_unless_told_otherwise():
    parser = build_parser()
    common = ["--scene", "s", "--model", "street", "--out", "o"]
    recon = parser.parse_args(["train-recondreamer", *common, "--restorer", "r", "--stride", "1.5"])
    assert recon.restorer_device is None and training_config(recon).device == "cpu"  # the restorer follows it
    recon = parser.parse_args(["train-recondreamer", *common, "--restorer", "r", "--stride", "1.5", "--restorer-device", "cuda"])
    assert recon.restorer_device == "cuda"
    dd4d = parser.parse_args(["train-dd4d", *common, "--world-model", "w", "--world-model-device", "cuda"])
    assert dd4d.world_model_device == "cuda"


def test_resolve_device_accepts_cpu_and_names_the_option_in_every_error(monkeypatch):
    assert resolve_device("cpu") == torch.device("cpu")
    with pytest.raises(RecondreamerError, match="--device 'gpu': not a torch device"):
        resolve_device("gpu")
    with pytest.raises(RecondreamerError, match="--restorer-device 'mps': only cpu and cuda"):
        resolve_device("mps", "--restorer-device")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(RecondreamerError, match="--device 'cuda': CUDA is not available here"):
        resolve_device("cuda")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    with pytest.raises(RecondreamerError, match="--device 'cuda:3': only 1 CUDA device"):
        resolve_device("cuda:3")


@pytest.mark.parametrize("command", ["restore", "train-recondreamer", "train-recon"])
def test_cuda_without_cuda_is_a_one_line_error_before_any_work(command, monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    missing = str(tmp_path / "missing")
    argv = {
        "restore": ["restore", "--restorer", missing, "--scene", missing, "--renders", missing, "--trajectory", "original"],
        "train-recondreamer": ["train-recondreamer", "--scene", missing, "--model", "street", "--restorer", "truth", "--stride", "3"],
        "train-recon": ["train-recon", "--scene", missing, "--model", "street"],
    }[command]
    assert main([*argv, "--out", str(tmp_path / "out"), "--device", "cuda"]) == 1
    error = capsys.readouterr().err
    assert "--device 'cuda': CUDA is not available" in error and "Traceback" not in error
    assert not (tmp_path / "out").exists()


def test_diffusion_loss_draws_timesteps_then_noise_from_the_cpu_generator():
    """The CPU draws (their order included) are what a device job replays, so a seed means the same
    training on any device; recomputed here by hand from a twin generator."""
    schedule = NoiseSchedule(DiffusionConfig())
    x0 = torch.randn(3, 2, 4, 5, 6, generator=torch.Generator().manual_seed(1))

    def model_fn(noisy, timesteps):
        return 0.5 * noisy + timesteps.float().reshape(-1, 1, 1, 1, 1) / 1000.0

    for power in (1.0, 3.0):
        loss = diffusion_loss_and_estimate(model_fn, schedule, x0, torch.Generator().manual_seed(7), power)[0]
        twin = torch.Generator().manual_seed(7)
        if power == 1.0:
            timesteps = torch.randint(0, 1000, (3,), generator=twin)
        else:
            timesteps = schedule.sample_timesteps(3, power, twin)
        noise = torch.randn(x0.shape, generator=twin)
        a = schedule.alpha_bar[timesteps].sqrt().reshape(-1, 1, 1, 1, 1)
        s = (1.0 - schedule.alpha_bar[timesteps]).sqrt().reshape(-1, 1, 1, 1, 1)
        expected = torch.mean((model_fn(a * x0 + s * noise, timesteps) - (a * noise - s * x0)) ** 2)
        assert torch.allclose(loss, expected, rtol=1e-6)


def test_checkpoints_hold_cpu_tensors_and_load_onto_the_requested_device(tmp_path):
    restorer = tiny_restorer()
    frames, structure = clip()
    path = tmp_path / "r.pt"
    save_checkpoint(path, "restorer", "dd2_mask", model_config_dict(restorer), restorer.unet.state_dict(),
                    autoencoder=autoencoder_payload(restorer.autoencoder))
    payload = load_checkpoint(path, "restorer")
    assert all(t.device.type == "cpu" for t in payload["state"].values())
    loaded = load_restorer(path, "cpu")
    assert loaded.device == torch.device("cpu") and module_device(loaded.autoencoder) == torch.device("cpu")
    expected = restore_clip(restorer, frames, structure, window=4, overlap=1, seed=2)
    assert np.array_equal(restore_clip(loaded, frames, structure, window=4, overlap=1, seed=2), expected)


def test_tensors_to_cpu_keeps_cpu_tensors_and_the_structure():
    tensor = torch.ones(2)
    value = {"a": tensor, "b": [tensor, (tensor, 3)], "c": "text"}
    moved = tensors_to_cpu(value)
    assert moved["a"] is tensor and moved["b"][1][0] is tensor and moved["b"][1][1] == 3 and moved["c"] == "text"
    assert isinstance(moved["b"][1], tuple)


# --------------------------------------------------------------------------------------- CUDA


@pytest.mark.cuda
@CUDA
def test_cuda_restoration_matches_the_cpu_restoration_of_the_same_model():
    frames, structure = clip(frames=10)
    on_cpu = restore_clip(tiny_restorer(), frames, structure, window=4, overlap=1, seed=2)
    model = tiny_restorer().to("cuda")
    assert model.device.type == "cuda"
    on_cuda = restore_clip(model, frames, structure, window=4, overlap=1, seed=2)
    difference = np.abs(on_cuda.astype(np.int16) - on_cpu.astype(np.int16))
    # Same noise (CPU generator), float32 on both: only rounding differs, a uint8 level here and there.
    assert difference.max() <= 2 and difference.mean() < 0.05


@pytest.mark.cuda
@CUDA
def test_cuda_training_loss_and_gradients_match_the_cpu():
    restorer = tiny_restorer()
    rng = np.random.default_rng(0)
    frames, structure = clip(frames=8)
    latents = torch.randn(1, 8, 4, H // 4, W // 4, generator=torch.Generator().manual_seed(3))
    seq = Sequence(name="s", scene_id="x", target=latents[0] * 0.5, reference=latents[0], structure=structure,
                   degraded=latents, degraded_frames=frames[None], vanishing=np.tile([W / 2, H / 2], (8, 1)))
    train = dataclasses.replace(restorer.train_config, window=4, batch_size=2)
    batch = sample_batch([seq], rng, train, 4, True, True)
    results = {}
    for device in ("cpu", "cuda"):
        unet = tiny_restorer().unet.to(device).train()
        loss = unet_loss(unet, restorer.schedule, batch, torch.Generator().manual_seed(5), 3.0)
        loss.backward()
        results[device] = (loss.item(), torch.cat([p.grad.flatten().cpu() for p in unet.parameters()]))
    assert results["cuda"][0] == pytest.approx(results["cpu"][0], rel=1e-4)
    scale = results["cpu"][1].abs().max().item()
    assert (results["cuda"][1] - results["cpu"][1]).abs().max().item() <= 1e-3 * scale


@pytest.mark.cuda
@CUDA
def test_commands_train_and_sample_on_cuda_and_their_checkpoints_load_on_the_cpu(tmp_path):
    from scipy import ndimage

    from recondreamer.generative.data import (
        scene_sky_masks,
        scene_structure,
        scene_vanishing_points,
        structure_channel_names,
    )
    from recondreamer.frames_io import read_clip
    from recondreamer.scene import load_scene, write_scene
    from recondreamer.sources.synthetic import generate_segment

    write_scene(tmp_path / "corpus" / "a", generate_segment(3, "quick"))
    scene = load_scene(tmp_path / "corpus" / "a")
    cuda = ["--device", "cuda"]
    assert main(["train-autoencoder", "--corpus", str(tmp_path / "corpus"), "--out", str(tmp_path / "ae.pt"), "--steps", "20", *cuda]) == 0
    train = ["--steps", "10", "--batch-size", "2", "--window", "4", *cuda]
    assert main(["pretrain-world-model", "--arch", "dd2", "--corpus", str(tmp_path / "corpus"), "--autoencoder",
                 str(tmp_path / "ae.pt"), "--out", str(tmp_path / "wm.pt"), *train]) == 0
    gt = np.stack([scene.image(t) for t in range(scene.num_frames)])
    blurred = ndimage.uniform_filter(gt.astype(np.float32), size=(1, 5, 5, 1)).round().astype(np.uint8)
    (tmp_path / "pairs").mkdir()
    np.savez_compressed(
        tmp_path / "pairs" / "a__run.npz", gt=gt, degraded=blurred[None], stages=np.array([10]),
        structure=scene_structure(scene, scene.cam_to_world), structure_channels=np.array(structure_channel_names()),
        vanishing=scene_vanishing_points(scene, scene.cam_to_world), sky=scene_sky_masks(scene),
        scene_id=np.array(scene.scene_id), scene_path=np.array(str(scene.path)), run=np.array("run"),
    )
    assert main(["train-restorer", "--arch", "dd2_mask", "--world-model", str(tmp_path / "wm.pt"), "--pairs",
                 str(tmp_path / "pairs"), "--out", str(tmp_path / "r.pt"), *train]) == 0
    for name, kind in (("ae.pt", "autoencoder"), ("wm.pt", "world_model"), ("r.pt", "restorer")):
        payload = load_checkpoint(tmp_path / name, kind)
        assert all(t.device.type == "cpu" for t in payload["state"].values()), name
    np.save(tmp_path / "renders.npy", blurred)
    restore = ["restore", "--restorer", str(tmp_path / "r.pt"), "--scene", str(scene.path), "--renders",
               str(tmp_path / "renders.npy"), "--trajectory", "original"]
    assert main([*restore, "--out", str(tmp_path / "on_cuda"), *cuda]) == 0
    assert main([*restore, "--out", str(tmp_path / "on_cpu")]) == 0
    difference = np.abs(read_clip(tmp_path / "on_cuda").astype(np.int16) - read_clip(tmp_path / "on_cpu").astype(np.int16))
    assert difference.max() <= 3 and difference.mean() < 0.1
    assert main(["dd4d-generate", "--world-model", str(tmp_path / "wm.pt"), "--scene", str(scene.path), "--trajectory",
                 "shift@3", "--out", str(tmp_path / "dd4d"), "--sample-steps", "2", *cuda]) == 0
    assert read_clip(tmp_path / "dd4d").shape == gt.shape


def test_pretrain_world_model_takes_the_unet_width_and_refuses_bad_ones(tmp_path, capsys):
    """The width option of the GPU capacity study (docs/gpu.md): the checkpoint records the levels."""
    from recondreamer.scene import write_scene
    from recondreamer.sources.synthetic import generate_segment

    write_scene(tmp_path / "corpus" / "a", generate_segment(3, "quick"))
    assert main(["train-autoencoder", "--corpus", str(tmp_path / "corpus"), "--out", str(tmp_path / "ae.pt"), "--steps", "1"]) == 0
    common = ["pretrain-world-model", "--arch", "dd2", "--corpus", str(tmp_path / "corpus"), "--autoencoder", str(tmp_path / "ae.pt"),
              "--steps", "1", "--batch-size", "1", "--window", "2"]
    assert main([*common, "--out", str(tmp_path / "wm.pt"), "--channels", "16", "24", "32", "40"]) == 0
    unet = load_checkpoint(tmp_path / "wm.pt", "world_model")["config"]["unet"]
    assert list(unet["channels"]) == [16, 24, 32, 40]
    assert list(unet["attention_levels"]) == [False, False, False, True] and list(unet["temporal_levels"]) == [True] * 4
    assert main([*common, "--out", str(tmp_path / "bad.pt"), "--channels", "16", "20"]) == 1
    assert "--channels 16 20: give at least 2 levels" in capsys.readouterr().err
    assert not (tmp_path / "bad.pt").exists()


def test_gsplat_backend_renders_an_empty_scene_like_the_reference_without_gsplat():
    """gsplat 1.5.3 dies with SIGFPE on zero Gaussians (seen on an H100, docs/gpu.md); the backend
    renders that case itself, which needs no GPU and is checked here against the torch reference."""
    from recondreamer.splat import rasterize
    from recondreamer.splat.gsplat_backend import _empty_scene

    K = torch.tensor([[30.0, 0.0, 16.0], [0.0, 30.0, 12.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    for background in (None, torch.tensor([0.2, 0.4, 0.6], dtype=torch.float64)):
        inputs = [torch.zeros(0, n, dtype=torch.float64, requires_grad=True) for n in (3, 4, 3)]
        bg = None if background is None else background.clone().requires_grad_()
        out = _empty_scene(*inputs, torch.eye(4, dtype=torch.float64), K, 32, 24, bg)
        want = rasterize(*(t.detach() for t in inputs), torch.zeros(0, dtype=torch.float64), torch.zeros(0, 3, dtype=torch.float64),
                         torch.eye(4, dtype=torch.float64), K, 32, 24, background, backend="torch")
        for name in ("rgb", "depth", "alpha", "means2d", "radii", "visible"):
            assert out[name].shape == want[name].shape and torch.equal(out[name].detach(), want[name]), name
        out["means2d"].retain_grad()
        (out["rgb"].sum() + out["depth"].sum() + out["alpha"].sum()).backward()  # runs: the outputs are in the graph
        if bg is not None:
            assert torch.equal(bg.grad, torch.full((3,), 32.0 * 24.0, dtype=torch.float64))
