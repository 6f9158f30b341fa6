"""TwinLiteNet written out with the public release's state_dict layout: strict loading of both
checkpoint forms, refusal of wrong or unsafe files, the parameter count, head shapes and lane masks.

No real weights are used: state dicts are filled with random values of the release's shapes. A
forward pass at the release's 360x640 input costs a few seconds on one core, so only four frames run.
"""

import pathlib

import numpy as np
import pytest
import torch

from recondreamer.errors import RecondreamerError
from recondreamer.evaluation.twinlitenet import (
    INPUT_HEIGHT,
    INPUT_WIDTH,
    TWINLITENET_PARAMETERS,
    TWINLITENET_STATE_SHAPES,
    TwinLiteNet,
    lane_masks,
    load_twinlitenet,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")

BUFFER_SUFFIXES = ("running_mean", "running_var", "num_batches_tracked")


def random_state(seed: int) -> dict[str, torch.Tensor]:
    """A state dict of the release's keys and shapes with random values that keep activations finite."""
    generator = torch.Generator().manual_seed(seed)
    state = {}
    for key, shape in TWINLITENET_STATE_SHAPES:
        if key.endswith("num_batches_tracked"):
            state[key] = torch.randint(0, 10**6, shape, generator=generator, dtype=torch.int64)
        elif key.endswith("running_var"):
            state[key] = torch.rand(shape, generator=generator) + 0.5
        elif len(shape) == 4:  # convolution kernels, scaled by their fan-in
            state[key] = torch.randn(shape, generator=generator) / float(np.prod(shape[1:])) ** 0.5
        else:
            state[key] = 0.2 * torch.randn(shape, generator=generator) + (1.0 if key.endswith("bn.weight") else 0.0)
    return state


class WritesAFile:
    """Unpickling this object writes ``target``: the kind of payload a weights file must never run."""

    def __init__(self, target: pathlib.Path):
        self.target = target

    def __reduce__(self):
        return (pathlib.Path.write_text, (self.target, "unpickled"))


@pytest.fixture(scope="module")
def random_model() -> TwinLiteNet:
    model = TwinLiteNet()
    model.load_state_dict(random_state(1), strict=True)
    return model.eval()


@pytest.fixture(scope="module")
def release_size_output(random_model):
    """One frame at the release's input size, its network input, and both heads' outputs."""
    frame = np.random.default_rng(2).integers(0, 256, (1, INPUT_HEIGHT, INPUT_WIDTH, 3), dtype=np.uint8)
    image = torch.from_numpy(frame).permute(0, 3, 1, 2).float() / 255.0  # test_image.py: RGB / 255
    with torch.no_grad():
        drivable, lane = random_model(image)
    return frame, drivable, lane


def test_module_state_dict_is_the_release_layout():
    state = TwinLiteNet().state_dict()
    assert [(key, tuple(value.shape)) for key, value in state.items()] == list(TWINLITENET_STATE_SHAPES)
    assert len(TWINLITENET_STATE_SHAPES) == 183
    assert state["encoder.level2.0.bn.bn.num_batches_tracked"].dtype == torch.int64


def test_parameter_count_is_the_release_figure():
    from_shapes = sum(int(np.prod(shape)) for key, shape in TWINLITENET_STATE_SHAPES if not key.endswith(BUFFER_SUFFIXES))
    from_module = sum(parameter.numel() for parameter in TwinLiteNet().parameters())
    assert from_shapes == from_module == TWINLITENET_PARAMETERS == 439_633
    assert round(from_module / 1e6, 1) == 0.4  # the paper's "0.4 M parameters"


@pytest.mark.parametrize("form", ["bare", "dataparallel_state_dict", "model"])
def test_saved_weights_load_strictly(tmp_path, form):
    state = random_state(3)
    if form == "bare":
        payload = state
    elif form == "dataparallel_state_dict":  # train.py's checkpoint.pth.tar around a DataParallel model
        payload = {"epoch": 7, "state_dict": {f"module.{key}": value for key, value in state.items()}, "lr": 5e-4}
    else:
        payload = {"model": state}
    path = tmp_path / "best.pth"
    torch.save(payload, path)
    loaded = load_twinlitenet(path).state_dict()
    assert list(loaded) == list(state)
    for key, value in state.items():
        assert loaded[key].dtype == value.dtype, key
        assert torch.equal(loaded[key], value), key
    assert not load_twinlitenet(path).training


def test_missing_key_is_named(tmp_path):
    state = {f"module.{key}": value for key, value in random_state(4).items()}
    del state["module.encoder.sa.key_conv.bias"]
    path = tmp_path / "missing.pth"
    torch.save(state, path)
    with pytest.raises(RecondreamerError) as raised:
        load_twinlitenet(path)
    message = str(raised.value)
    assert str(path) in message
    assert "missing" in message and "encoder.sa.key_conv.bias" in message
    assert "misshapen" not in message and "unexpected" not in message


def test_misshapen_and_unexpected_keys_are_named(tmp_path):
    state = random_state(5)
    state["encoder.b2.conv.weight"] = torch.zeros(131, 130, 3, 3)
    state["encoder.extra.weight"] = torch.zeros(3)
    path = tmp_path / "misshapen.pth"
    torch.save(state, path)
    with pytest.raises(RecondreamerError) as raised:
        load_twinlitenet(path)
    message = str(raised.value)
    assert str(path) in message
    assert "encoder.b2.conv.weight (expected (131, 131, 3, 3), found (131, 130, 3, 3))" in message
    assert "unexpected" in message and "encoder.extra.weight" in message
    assert "missing" not in message


def test_code_carrying_pickle_is_refused_unrun(tmp_path):
    path = tmp_path / "evil.pth"
    target = tmp_path / "written_by_unpickling.txt"
    torch.save({"state_dict": WritesAFile(target)}, path)
    with pytest.raises(RecondreamerError, match=str(path)):
        load_twinlitenet(path)
    assert not target.exists()
    # The payload is live: an unrestricted unpickler does write the file.
    control = tmp_path / "control.pth"
    control_target = tmp_path / "control.txt"
    torch.save({"state_dict": WritesAFile(control_target)}, control)
    torch.load(control, weights_only=False)
    assert control_target.read_text() == "unpickled"


def test_foreign_files_are_refused_with_their_name(tmp_path):
    not_torch = tmp_path / "notes.pth"
    not_torch.write_bytes(b"these are not weights")
    not_a_dict = tmp_path / "list.pth"
    torch.save([torch.zeros(2)], not_a_dict)
    not_tensors = tmp_path / "config.pth"
    torch.save({"encoder.level1.conv.weight": [1, 2, 3]}, not_tensors)
    for path, reason in [(not_torch, "not a torch weights file"), (not_a_dict, "holds a list"), (not_tensors, "not named tensors"), (tmp_path / "absent.pth", "not found")]:
        with pytest.raises(RecondreamerError) as raised:
            load_twinlitenet(path)
        assert str(path) in str(raised.value) and reason in str(raised.value)


def test_heads_have_the_release_shapes(release_size_output):
    _, drivable, lane = release_size_output
    assert drivable.shape == lane.shape == (1, 2, INPUT_HEIGHT, INPUT_WIDTH) == (1, 2, 360, 640)
    assert torch.isfinite(drivable).all() and torch.isfinite(lane).all()
    assert not torch.equal(drivable, lane)  # two separate decoders


def test_lane_masks_follow_the_lane_head(random_model, release_size_output):
    frame, _, lane = release_size_output
    expected = (lane.argmax(dim=1) == 1).numpy()  # test_image.py: torch.max(x1, 1) on RGB / 255
    assert 0.0 < expected.mean() < 1.0  # the comparison below can fail
    masks = lane_masks(random_model, frame)
    assert masks.dtype == bool and masks.shape == (1, INPUT_HEIGHT, INPUT_WIDTH)
    np.testing.assert_array_equal(masks, expected)


def test_lane_masks_at_frame_size(random_model):
    frames = np.random.default_rng(6).integers(0, 256, (2, 96, 144, 3), dtype=np.uint8)
    masks = lane_masks(random_model, frames, batch_size=1)
    assert masks.dtype == bool and masks.shape == (2, 96, 144)


def test_lane_masks_reject_bad_input(random_model):
    with pytest.raises(ValueError, match="frames"):
        lane_masks(random_model, np.zeros((2, 96, 144, 3), dtype=np.float32))
    with pytest.raises(ValueError, match="frames"):
        lane_masks(random_model, np.zeros((96, 144, 3), dtype=np.uint8))
    training = TwinLiteNet().train()
    with pytest.raises(ValueError, match="eval"):
        lane_masks(training, np.zeros((1, 96, 144, 3), dtype=np.uint8))
