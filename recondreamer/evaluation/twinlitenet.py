"""TwinLiteNet, the drivable-area and lane segmenter that the paper scores NTL-IoU with.

The public release (github.com/CAIC-AD/TwinLiteNet; the facts below were read from the author's
repository chequanghuy/TwinLiteNet at commit 5241418, MIT licence, where ``model/TwinLite.py`` and
``pretrained/best.pth`` are unchanged since they were added) defines the network in
``model/TwinLite.py`` and ships ``pretrained/best.pth``.
This module writes the same network out so that a user's local copy of that file loads with
``load_state_dict(strict=True)``: every parameter and buffer has the release's name and shape
(``TWINLITENET_STATE_SHAPES``, in the release's ``state_dict`` order). No weights ship with the
project; a randomly initialised network is only good for tests.

Facts taken from the release:

- ``best.pth`` is a bare ``state_dict`` saved from a ``torch.nn.DataParallel`` wrapper, so every
  key starts with ``module.``; ``train.py`` also writes ``checkpoint.pth.tar`` holding it under
  ``state_dict``. Both forms are accepted here.
- The network is ``TwinLiteNet(p=2, q=3)``: an ESPNet-C style encoder to 1/8 resolution
  (dilated-pyramid blocks, two residual ones at 1/4 and three at 1/8) ending in a position
  attention and a channel attention branch (DANet), then two decoders of three stride-2
  transposed convolutions each. Every batch norm uses ``eps=1e-3``; every activation is a
  per-channel PReLU.
- Head 1 is the drivable area, head 2 the lane lines; both have 2 channels (background,
  foreground; ``DataSet.py`` stacks the inverted mask first) at the input's full resolution.
- Input: ``test_image.py`` resizes the BGR image from ``cv2.imread`` to 640x360 (width x height,
  ``cv2.resize``'s default bilinear), flips it to RGB and divides by 255 - no mean or std.
  ``DataSet.py`` (``W_=640``, ``H_=360``) and ``val.py`` (traces with a (1,3,360,640) input) agree.
- A pixel is lane where the argmax over the lane head's two channels is 1 (``test_image.py``:
  ``torch.max(x1, 1)``; ``utils.val`` scores the same argmax).
- With p=2, q=3 the network has 439,633 trainable parameters, summed from the shapes (the
  TwinLiteNet paper's "0.4 M"; the release's README gives no count).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from recondreamer.errors import CheckpointError
from recondreamer.evaluation.inference import read_torch_file

INPUT_HEIGHT = 360  # test_image.py: cv2.resize(img, (640, 360)); DataSet.py: H_ = 360
INPUT_WIDTH = 640  # test_image.py: cv2.resize(img, (640, 360)); DataSet.py: W_ = 640
PIXEL_SCALE = 1.0 / 255.0  # test_image.py and utils.val: img.float() / 255.0, no mean/std
LANE_CLASS = 1  # DataSet.py stacks (background, lane) as channels (0, 1); test_image.py takes torch.max(x1, 1)
BN_EPS = 1e-3  # model/TwinLite.py: every BatchNorm2d(..., eps=1e-03)
TWINLITENET_PARAMETERS = 439_633  # trainable parameters of TwinLiteNet(p=2, q=3), summed from the shapes below
DATAPARALLEL_PREFIX = "module."  # test_image.py / val.py wrap the model in DataParallel before load_state_dict

# The release's state_dict (``pretrained/best.pth`` without its ``module.`` prefix), in order.
TWINLITENET_STATE_SHAPES: tuple[tuple[str, tuple[int, ...]], ...] = (
    ("encoder.level1.conv.weight", (16, 3, 3, 3)),
    ("encoder.level1.bn.weight", (16,)),
    ("encoder.level1.bn.bias", (16,)),
    ("encoder.level1.bn.running_mean", (16,)),
    ("encoder.level1.bn.running_var", (16,)),
    ("encoder.level1.bn.num_batches_tracked", ()),
    ("encoder.level1.act.weight", (16,)),
    ("encoder.b1.conv.weight", (19, 19, 3, 3)),
    ("encoder.b1.bn.weight", (19,)),
    ("encoder.b1.bn.bias", (19,)),
    ("encoder.b1.bn.running_mean", (19,)),
    ("encoder.b1.bn.running_var", (19,)),
    ("encoder.b1.bn.num_batches_tracked", ()),
    ("encoder.b1.act.weight", (19,)),
    ("encoder.level2_0.c1.conv.weight", (12, 19, 3, 3)),
    ("encoder.level2_0.d1.conv.weight", (16, 12, 3, 3)),
    ("encoder.level2_0.d2.conv.weight", (12, 12, 3, 3)),
    ("encoder.level2_0.d4.conv.weight", (12, 12, 3, 3)),
    ("encoder.level2_0.d8.conv.weight", (12, 12, 3, 3)),
    ("encoder.level2_0.d16.conv.weight", (12, 12, 3, 3)),
    ("encoder.level2_0.bn.weight", (64,)),
    ("encoder.level2_0.bn.bias", (64,)),
    ("encoder.level2_0.bn.running_mean", (64,)),
    ("encoder.level2_0.bn.running_var", (64,)),
    ("encoder.level2_0.bn.num_batches_tracked", ()),
    ("encoder.level2_0.act.weight", (64,)),
    ("encoder.level2.0.c1.conv.weight", (12, 64, 1, 1)),
    ("encoder.level2.0.d1.conv.weight", (16, 12, 3, 3)),
    ("encoder.level2.0.d2.conv.weight", (12, 12, 3, 3)),
    ("encoder.level2.0.d4.conv.weight", (12, 12, 3, 3)),
    ("encoder.level2.0.d8.conv.weight", (12, 12, 3, 3)),
    ("encoder.level2.0.d16.conv.weight", (12, 12, 3, 3)),
    ("encoder.level2.0.bn.bn.weight", (64,)),
    ("encoder.level2.0.bn.bn.bias", (64,)),
    ("encoder.level2.0.bn.bn.running_mean", (64,)),
    ("encoder.level2.0.bn.bn.running_var", (64,)),
    ("encoder.level2.0.bn.bn.num_batches_tracked", ()),
    ("encoder.level2.0.bn.act.weight", (64,)),
    ("encoder.level2.1.c1.conv.weight", (12, 64, 1, 1)),
    ("encoder.level2.1.d1.conv.weight", (16, 12, 3, 3)),
    ("encoder.level2.1.d2.conv.weight", (12, 12, 3, 3)),
    ("encoder.level2.1.d4.conv.weight", (12, 12, 3, 3)),
    ("encoder.level2.1.d8.conv.weight", (12, 12, 3, 3)),
    ("encoder.level2.1.d16.conv.weight", (12, 12, 3, 3)),
    ("encoder.level2.1.bn.bn.weight", (64,)),
    ("encoder.level2.1.bn.bn.bias", (64,)),
    ("encoder.level2.1.bn.bn.running_mean", (64,)),
    ("encoder.level2.1.bn.bn.running_var", (64,)),
    ("encoder.level2.1.bn.bn.num_batches_tracked", ()),
    ("encoder.level2.1.bn.act.weight", (64,)),
    ("encoder.b2.conv.weight", (131, 131, 3, 3)),
    ("encoder.b2.bn.weight", (131,)),
    ("encoder.b2.bn.bias", (131,)),
    ("encoder.b2.bn.running_mean", (131,)),
    ("encoder.b2.bn.running_var", (131,)),
    ("encoder.b2.bn.num_batches_tracked", ()),
    ("encoder.b2.act.weight", (131,)),
    ("encoder.level3_0.c1.conv.weight", (25, 131, 3, 3)),
    ("encoder.level3_0.d1.conv.weight", (28, 25, 3, 3)),
    ("encoder.level3_0.d2.conv.weight", (25, 25, 3, 3)),
    ("encoder.level3_0.d4.conv.weight", (25, 25, 3, 3)),
    ("encoder.level3_0.d8.conv.weight", (25, 25, 3, 3)),
    ("encoder.level3_0.d16.conv.weight", (25, 25, 3, 3)),
    ("encoder.level3_0.bn.weight", (128,)),
    ("encoder.level3_0.bn.bias", (128,)),
    ("encoder.level3_0.bn.running_mean", (128,)),
    ("encoder.level3_0.bn.running_var", (128,)),
    ("encoder.level3_0.bn.num_batches_tracked", ()),
    ("encoder.level3_0.act.weight", (128,)),
    ("encoder.level3.0.c1.conv.weight", (25, 128, 1, 1)),
    ("encoder.level3.0.d1.conv.weight", (28, 25, 3, 3)),
    ("encoder.level3.0.d2.conv.weight", (25, 25, 3, 3)),
    ("encoder.level3.0.d4.conv.weight", (25, 25, 3, 3)),
    ("encoder.level3.0.d8.conv.weight", (25, 25, 3, 3)),
    ("encoder.level3.0.d16.conv.weight", (25, 25, 3, 3)),
    ("encoder.level3.0.bn.bn.weight", (128,)),
    ("encoder.level3.0.bn.bn.bias", (128,)),
    ("encoder.level3.0.bn.bn.running_mean", (128,)),
    ("encoder.level3.0.bn.bn.running_var", (128,)),
    ("encoder.level3.0.bn.bn.num_batches_tracked", ()),
    ("encoder.level3.0.bn.act.weight", (128,)),
    ("encoder.level3.1.c1.conv.weight", (25, 128, 1, 1)),
    ("encoder.level3.1.d1.conv.weight", (28, 25, 3, 3)),
    ("encoder.level3.1.d2.conv.weight", (25, 25, 3, 3)),
    ("encoder.level3.1.d4.conv.weight", (25, 25, 3, 3)),
    ("encoder.level3.1.d8.conv.weight", (25, 25, 3, 3)),
    ("encoder.level3.1.d16.conv.weight", (25, 25, 3, 3)),
    ("encoder.level3.1.bn.bn.weight", (128,)),
    ("encoder.level3.1.bn.bn.bias", (128,)),
    ("encoder.level3.1.bn.bn.running_mean", (128,)),
    ("encoder.level3.1.bn.bn.running_var", (128,)),
    ("encoder.level3.1.bn.bn.num_batches_tracked", ()),
    ("encoder.level3.1.bn.act.weight", (128,)),
    ("encoder.level3.2.c1.conv.weight", (25, 128, 1, 1)),
    ("encoder.level3.2.d1.conv.weight", (28, 25, 3, 3)),
    ("encoder.level3.2.d2.conv.weight", (25, 25, 3, 3)),
    ("encoder.level3.2.d4.conv.weight", (25, 25, 3, 3)),
    ("encoder.level3.2.d8.conv.weight", (25, 25, 3, 3)),
    ("encoder.level3.2.d16.conv.weight", (25, 25, 3, 3)),
    ("encoder.level3.2.bn.bn.weight", (128,)),
    ("encoder.level3.2.bn.bn.bias", (128,)),
    ("encoder.level3.2.bn.bn.running_mean", (128,)),
    ("encoder.level3.2.bn.bn.running_var", (128,)),
    ("encoder.level3.2.bn.bn.num_batches_tracked", ()),
    ("encoder.level3.2.bn.act.weight", (128,)),
    ("encoder.b3.conv.weight", (32, 256, 3, 3)),
    ("encoder.b3.bn.weight", (32,)),
    ("encoder.b3.bn.bias", (32,)),
    ("encoder.b3.bn.running_mean", (32,)),
    ("encoder.b3.bn.running_var", (32,)),
    ("encoder.b3.bn.num_batches_tracked", ()),
    ("encoder.b3.act.weight", (32,)),
    ("encoder.sa.gamma", (1,)),
    ("encoder.sa.query_conv.weight", (4, 32, 1, 1)),
    ("encoder.sa.query_conv.bias", (4,)),
    ("encoder.sa.key_conv.weight", (4, 32, 1, 1)),
    ("encoder.sa.key_conv.bias", (4,)),
    ("encoder.sa.value_conv.weight", (32, 32, 1, 1)),
    ("encoder.sa.value_conv.bias", (32,)),
    ("encoder.sc.gamma", (1,)),
    ("encoder.conv_sa.conv.weight", (32, 32, 3, 3)),
    ("encoder.conv_sa.bn.weight", (32,)),
    ("encoder.conv_sa.bn.bias", (32,)),
    ("encoder.conv_sa.bn.running_mean", (32,)),
    ("encoder.conv_sa.bn.running_var", (32,)),
    ("encoder.conv_sa.bn.num_batches_tracked", ()),
    ("encoder.conv_sa.act.weight", (32,)),
    ("encoder.conv_sc.conv.weight", (32, 32, 3, 3)),
    ("encoder.conv_sc.bn.weight", (32,)),
    ("encoder.conv_sc.bn.bias", (32,)),
    ("encoder.conv_sc.bn.running_mean", (32,)),
    ("encoder.conv_sc.bn.running_var", (32,)),
    ("encoder.conv_sc.bn.num_batches_tracked", ()),
    ("encoder.conv_sc.act.weight", (32,)),
    ("encoder.classifier.conv.weight", (32, 32, 1, 1)),
    ("encoder.classifier.bn.weight", (32,)),
    ("encoder.classifier.bn.bias", (32,)),
    ("encoder.classifier.bn.running_mean", (32,)),
    ("encoder.classifier.bn.running_var", (32,)),
    ("encoder.classifier.bn.num_batches_tracked", ()),
    ("encoder.classifier.act.weight", (32,)),
    ("up_1_1.deconv.weight", (32, 16, 2, 2)),
    ("up_1_1.bn.weight", (16,)),
    ("up_1_1.bn.bias", (16,)),
    ("up_1_1.bn.running_mean", (16,)),
    ("up_1_1.bn.running_var", (16,)),
    ("up_1_1.bn.num_batches_tracked", ()),
    ("up_1_1.act.weight", (16,)),
    ("up_2_1.deconv.weight", (16, 8, 2, 2)),
    ("up_2_1.bn.weight", (8,)),
    ("up_2_1.bn.bias", (8,)),
    ("up_2_1.bn.running_mean", (8,)),
    ("up_2_1.bn.running_var", (8,)),
    ("up_2_1.bn.num_batches_tracked", ()),
    ("up_2_1.act.weight", (8,)),
    ("up_1_2.deconv.weight", (32, 16, 2, 2)),
    ("up_1_2.bn.weight", (16,)),
    ("up_1_2.bn.bias", (16,)),
    ("up_1_2.bn.running_mean", (16,)),
    ("up_1_2.bn.running_var", (16,)),
    ("up_1_2.bn.num_batches_tracked", ()),
    ("up_1_2.act.weight", (16,)),
    ("up_2_2.deconv.weight", (16, 8, 2, 2)),
    ("up_2_2.bn.weight", (8,)),
    ("up_2_2.bn.bias", (8,)),
    ("up_2_2.bn.running_mean", (8,)),
    ("up_2_2.bn.running_var", (8,)),
    ("up_2_2.bn.num_batches_tracked", ()),
    ("up_2_2.act.weight", (8,)),
    ("classifier_1.deconv.weight", (8, 2, 2, 2)),
    ("classifier_1.bn.weight", (2,)),
    ("classifier_1.bn.bias", (2,)),
    ("classifier_1.bn.running_mean", (2,)),
    ("classifier_1.bn.running_var", (2,)),
    ("classifier_1.bn.num_batches_tracked", ()),
    ("classifier_1.act.weight", (2,)),
    ("classifier_2.deconv.weight", (8, 2, 2, 2)),
    ("classifier_2.bn.weight", (2,)),
    ("classifier_2.bn.bias", (2,)),
    ("classifier_2.bn.running_mean", (2,)),
    ("classifier_2.bn.running_var", (2,)),
    ("classifier_2.bn.num_batches_tracked", ()),
    ("classifier_2.act.weight", (2,)),
)


class ConvBNPReLU(nn.Module):
    """Convolution without bias ("same" padding), batch norm, per-channel PReLU."""

    def __init__(self, c_in: int, c_out: int, kernel_size: int, stride: int = 1):
        super().__init__()
        self.conv = nn.Conv2d(c_in, c_out, kernel_size, stride=stride, padding=kernel_size // 2, bias=False)
        self.bn = nn.BatchNorm2d(c_out, eps=BN_EPS)
        self.act = nn.PReLU(c_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.bn(self.conv(x)))


class UpBNPReLU(nn.Module):
    """2x up-sampling by a 2x2 stride-2 transposed convolution without bias, batch norm, PReLU."""

    def __init__(self, c_in: int, c_out: int):
        super().__init__()
        self.deconv = nn.ConvTranspose2d(c_in, c_out, kernel_size=2, stride=2, bias=False)
        self.bn = nn.BatchNorm2d(c_out, eps=BN_EPS)
        self.act = nn.PReLU(c_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.bn(self.deconv(x)))


class BNPReLU(nn.Module):
    """Batch norm then PReLU; its own module so that the residual blocks' keys read ``bn.bn.*``, ``bn.act.*``."""

    def __init__(self, channels: int):
        super().__init__()
        self.bn = nn.BatchNorm2d(channels, eps=BN_EPS)
        self.act = nn.PReLU(channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.bn(x))


class PlainConv(nn.Module):
    """A bias-free convolution held as ``.conv`` (the release's key layout ``c1.conv.weight``, ``d4.conv.weight``)."""

    def __init__(self, c_in: int, c_out: int, kernel_size: int, stride: int = 1, dilation: int = 1):
        super().__init__()
        padding = (kernel_size // 2) * dilation
        self.conv = nn.Conv2d(c_in, c_out, kernel_size, stride=stride, padding=padding, dilation=dilation, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(x)


def pyramid_widths(c_out: int) -> tuple[int, int]:
    """Channels of the four dilated branches and of the undilated one: c_out // 5 each, the rest to the
    undilated branch (64 -> 12 and 16, 128 -> 25 and 28)."""
    branch = max(c_out // 5, 1)
    return branch, c_out - 4 * branch


class DilatedPyramid(nn.Module):
    """Shared body of the ESP blocks: reduce with ``c1``, then 3x3 convolutions at dilations 1, 2, 4, 8
    and 16, summed cumulatively from dilation 2 upwards (against gridding) and concatenated."""

    def __init__(self, c_in: int, c_out: int, reduce_kernel: int, reduce_stride: int):
        super().__init__()
        branch, first = pyramid_widths(c_out)
        self.c1 = PlainConv(c_in, branch, reduce_kernel, stride=reduce_stride)
        self.d1 = PlainConv(branch, first, 3, dilation=1)
        self.d2 = PlainConv(branch, branch, 3, dilation=2)
        self.d4 = PlainConv(branch, branch, 3, dilation=4)
        self.d8 = PlainConv(branch, branch, 3, dilation=8)
        self.d16 = PlainConv(branch, branch, 3, dilation=16)

    def pyramid(self, x: torch.Tensor) -> torch.Tensor:
        reduced = self.c1(x)
        sum2 = self.d2(reduced)
        sum4 = sum2 + self.d4(reduced)
        sum8 = sum4 + self.d8(reduced)
        sum16 = sum8 + self.d16(reduced)
        return torch.cat([self.d1(reduced), sum2, sum4, sum8, sum16], dim=1)


class DownsamplingPyramid(DilatedPyramid):
    """Halves the resolution: stride-2 3x3 reduction, pyramid, batch norm, PReLU (release: ``DownSamplerB``)."""

    def __init__(self, c_in: int, c_out: int):
        super().__init__(c_in, c_out, reduce_kernel=3, reduce_stride=2)
        self.bn = nn.BatchNorm2d(c_out, eps=BN_EPS)
        self.act = nn.PReLU(c_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (N,c_in,H,W) -> (N,c_out,ceil(H/2),ceil(W/2))
        return self.act(self.bn(self.pyramid(x)))


class ResidualPyramid(DilatedPyramid):
    """Keeps the resolution: 1x1 reduction, pyramid, identity shortcut, batch norm, PReLU
    (release: ``DilatedParllelResidualBlockB``, always with its residual add)."""

    def __init__(self, channels: int):
        super().__init__(channels, channels, reduce_kernel=1, reduce_stride=1)
        self.bn = BNPReLU(channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.bn(x + self.pyramid(x))


class PositionAttention(nn.Module):
    """DANet position attention: every position attends to every other through 1x1 query/key
    projections to channels // 8; the attended values are added back scaled by ``gamma`` (0 at init)."""

    def __init__(self, channels: int):
        super().__init__()
        self.gamma = nn.Parameter(torch.zeros(1))
        self.query_conv = nn.Conv2d(channels, channels // 8, kernel_size=1)
        self.key_conv = nn.Conv2d(channels, channels // 8, kernel_size=1)
        self.value_conv = nn.Conv2d(channels, channels, kernel_size=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n, c, h, w = x.shape
        query = self.query_conv(x).flatten(2).transpose(1, 2)  # (N,HW,C/8)
        key = self.key_conv(x).flatten(2)  # (N,C/8,HW)
        attention = torch.softmax(query @ key, dim=-1)  # (N,HW,HW); row i: weights over positions for position i
        value = self.value_conv(x).flatten(2)  # (N,C,HW)
        attended = value @ attention.transpose(1, 2)  # (N,C,HW)
        return self.gamma * attended.view(n, c, h, w) + x


class ChannelAttention(nn.Module):
    """DANet channel attention: channel affinities from the Gram matrix of the features, turned into
    weights by a softmax of (row maximum - affinity); the result is added back scaled by ``gamma``."""

    def __init__(self):
        super().__init__()
        self.gamma = nn.Parameter(torch.zeros(1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n, c, h, w = x.shape
        features = x.flatten(2)  # (N,C,HW)
        affinity = features @ features.transpose(1, 2)  # (N,C,C)
        affinity = affinity.amax(dim=-1, keepdim=True) - affinity
        attended = torch.softmax(affinity, dim=-1) @ features  # (N,C,HW)
        return self.gamma * attended.view(n, c, h, w) + x


def image_pyramid(x: torch.Tensor, levels: int) -> torch.Tensor:
    """The input image average-pooled (3x3, stride 2, zero padding counted) ``levels`` times, to be
    concatenated with the features of the same resolution (release: ``InputProjectionA``)."""
    for _ in range(levels):
        x = F.avg_pool2d(x, kernel_size=3, stride=2, padding=1)
    return x


class TwinLiteEncoder(nn.Module):
    """ESPNet-C style encoder to 1/8 resolution followed by position and channel attention
    (release: ``ESPNet_Encoder``). ``p`` and ``q`` are the numbers of residual blocks at 1/4 and 1/8."""

    def __init__(self, p: int = 2, q: int = 3):
        super().__init__()
        self.level1 = ConvBNPReLU(3, 16, 3, stride=2)
        self.b1 = ConvBNPReLU(16 + 3, 19, 3)
        self.level2_0 = DownsamplingPyramid(16 + 3, 64)
        self.level2 = nn.ModuleList(ResidualPyramid(64) for _ in range(p))
        self.b2 = ConvBNPReLU(64 + 64 + 3, 131, 3)
        self.level3_0 = DownsamplingPyramid(64 + 64 + 3, 128)
        self.level3 = nn.ModuleList(ResidualPyramid(128) for _ in range(q))
        self.b3 = ConvBNPReLU(128 + 128, 32, 3)
        self.sa = PositionAttention(32)
        self.sc = ChannelAttention()
        self.conv_sa = ConvBNPReLU(32, 32, 3)
        self.conv_sc = ConvBNPReLU(32, 32, 3)
        self.classifier = ConvBNPReLU(32, 32, 1)

    def forward(self, image: torch.Tensor) -> torch.Tensor:  # (N,3,H,W) -> (N,32,H/8,W/8)
        half = self.b1(torch.cat([self.level1(image), image_pyramid(image, 1)], dim=1))  # (N,19,H/2,W/2)
        quarter_in = self.level2_0(half)  # (N,64,H/4,W/4)
        quarter = quarter_in
        for block in self.level2:
            quarter = block(quarter)
        quarter = self.b2(torch.cat([quarter, quarter_in, image_pyramid(image, 2)], dim=1))  # (N,131,H/4,W/4)
        eighth_in = self.level3_0(quarter)  # (N,128,H/8,W/8)
        eighth = eighth_in
        for block in self.level3:
            eighth = block(eighth)
        features = self.b3(torch.cat([eighth_in, eighth], dim=1))  # (N,32,H/8,W/8)
        attended = self.conv_sa(self.sa(features)) + self.conv_sc(self.sc(features))
        return self.classifier(attended)


class TwinLiteNet(nn.Module):
    """TwinLiteNet: shared encoder, one decoder per task.

    ``forward`` takes (N,3,H,W) RGB in [0,1] (see ``lane_masks`` for the release's preprocessing)
    and returns (drivable_logits, lane_logits), each (N,2,8*ceil(H/8),8*ceil(W/8)) - (N,2,360,640)
    for the release's input size. Channel 1 is the foreground class; the "logits" are the last
    PReLU's outputs, as in the release, and only their argmax is used.
    """

    def __init__(self, p: int = 2, q: int = 3):
        super().__init__()
        self.encoder = TwinLiteEncoder(p, q)
        self.up_1_1 = UpBNPReLU(32, 16)  # drivable-area decoder
        self.up_2_1 = UpBNPReLU(16, 8)
        self.up_1_2 = UpBNPReLU(32, 16)  # lane decoder
        self.up_2_2 = UpBNPReLU(16, 8)
        self.classifier_1 = UpBNPReLU(8, 2)  # drivable-area head
        self.classifier_2 = UpBNPReLU(8, 2)  # lane head

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if x.ndim != 4 or x.shape[1] != 3 or not x.is_floating_point():
            raise ValueError(f"TwinLiteNet input must be a float (N,3,H,W) tensor, got {x.dtype} {tuple(x.shape)}")
        features = self.encoder(x)  # (N,32,H/8,W/8)
        drivable = self.classifier_1(self.up_2_1(self.up_1_1(features)))  # (N,2,H,W)
        lane = self.classifier_2(self.up_2_2(self.up_1_2(features)))  # (N,2,H,W)
        return drivable, lane


def _state_dict_of(path: Path, payload) -> dict[str, torch.Tensor]:
    if not isinstance(payload, dict):
        raise CheckpointError(f"{path}: holds a {type(payload).__name__}, expected a TwinLiteNet state_dict (a dict of tensors)")
    for wrapper in ("state_dict", "model"):
        if isinstance(payload.get(wrapper), dict):
            payload = payload[wrapper]
            break
    not_tensors = [key for key, value in payload.items() if not isinstance(key, str) or not isinstance(value, torch.Tensor)]
    if not_tensors:
        raise CheckpointError(f"{path}: not a state_dict; these entries are not named tensors: {_listing(map(repr, not_tensors))}")
    if payload and all(key.startswith(DATAPARALLEL_PREFIX) for key in payload):
        payload = {key[len(DATAPARALLEL_PREFIX) :]: value for key, value in payload.items()}
    return dict(payload)


def _listing(items, limit: int = 20) -> str:
    items = list(items)
    shown = ", ".join(items[:limit])
    return shown if len(items) <= limit else f"{shown}, ... ({len(items) - limit} more)"


def check_twinlitenet_state(path: Path, state: dict[str, torch.Tensor]) -> None:
    """CheckpointError naming ``path`` unless ``state`` has exactly the release's keys and shapes."""
    expected = dict(TWINLITENET_STATE_SHAPES)
    missing = [key for key in expected if key not in state]
    unexpected = [key for key in state if key not in expected]
    misshapen = [f"{key} (expected {expected[key]}, found {tuple(state[key].shape)})" for key in expected if key in state and tuple(state[key].shape) != expected[key]]
    problems = []
    if missing:
        problems.append(f"{len(missing)} missing key(s): {_listing(missing)}")
    if unexpected:
        problems.append(f"{len(unexpected)} unexpected key(s): {_listing(unexpected)}")
    if misshapen:
        problems.append(f"{len(misshapen)} misshapen tensor(s): {_listing(misshapen)}")
    if problems:
        raise CheckpointError(f"{path}: not TwinLiteNet(p=2, q=3) weights (pretrained/best.pth of CAIC-AD/TwinLiteNet); " + "; ".join(problems))


def load_twinlitenet(path: str | Path, device: torch.device | str = "cpu") -> TwinLiteNet:
    """The released TwinLiteNet weights in ``path`` (a bare state_dict, or one under ``state_dict`` or
    ``model``; a DataParallel ``module.`` prefix is removed), loaded strictly, in eval mode on ``device``.

    The file is read with ``torch.load(weights_only=True)``: a pickle that would build anything but
    tensors and plain containers is refused, never run. Every refusal is a CheckpointError naming the file.
    """
    path = Path(path)
    payload = read_torch_file(path, "TwinLiteNet weights file not found (a local copy of pretrained/best.pth of CAIC-AD/TwinLiteNet)",
                              "not a torch weights file that loads without running code")
    state = _state_dict_of(path, payload)
    check_twinlitenet_state(path, state)
    model = TwinLiteNet()
    model.load_state_dict(state, strict=True)
    return model.to(device).eval()


def preprocess(frames: np.ndarray, device: torch.device | str = "cpu") -> torch.Tensor:
    """(T,H,W,3) uint8 RGB -> (T,3,360,640) float in [0,1], the release's network input.

    ``test_image.py`` resizes with ``cv2.resize`` (bilinear, half-pixel centres, no antialiasing,
    result stored as uint8) and divides by 255; the frames here are already RGB, so its BGR->RGB
    flip of ``cv2.imread``'s output is not needed. The resize is the same bilinear filter in torch,
    rounded half up to integers as cv2's uint8 result is: identical to cv2 for 1280x720 and
    1920x1080 frames; for other sizes cv2's 11-bit fixed-point weights put about one value in
    eight 1 grey level away.
    """
    images = torch.from_numpy(np.ascontiguousarray(frames)).to(device).permute(0, 3, 1, 2).float()  # (T,3,H,W)
    if images.shape[-2:] != (INPUT_HEIGHT, INPUT_WIDTH):
        images = F.interpolate(images, size=(INPUT_HEIGHT, INPUT_WIDTH), mode="bilinear", align_corners=False, antialias=False)
        images = torch.floor(images + 0.5).clamp(0.0, 255.0)
    return images * PIXEL_SCALE


@torch.no_grad()
def lane_masks(model: TwinLiteNet, frames: np.ndarray, batch_size: int = 8) -> np.ndarray:
    """(T,H,W,3) uint8 RGB frames -> (T,H,W) bool lane masks, as the release's ``test_image.py`` makes them.

    Frames go in at 640x360 (``preprocess``); a pixel is lane where the lane head's channel 1 beats
    channel 0 (the argmax of the two channels; a tie is background, as ``torch.max`` returns the first index); the 360x640 mask is
    resized back to the frames' size by nearest neighbour. ``batch_size`` frames run at once (the
    position attention holds a 3600x3600 matrix per frame).
    """
    if not isinstance(frames, np.ndarray) or frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3:
        described = f"{frames.dtype} array of shape {frames.shape}" if isinstance(frames, np.ndarray) else type(frames).__name__
        raise ValueError(f"frames must be a (T,H,W,3) uint8 RGB array, got a {described}")
    if batch_size < 1:
        raise ValueError(f"batch_size must be at least 1, got {batch_size}")
    if model.training:
        raise ValueError("model is in training mode (its batch norms would use batch statistics); call model.eval() first")
    device = next(model.parameters()).device
    height, width = frames.shape[1:3]
    masks = np.zeros(frames.shape[:3], dtype=bool)
    for start in range(0, len(frames), batch_size):
        _, lane = model(preprocess(frames[start : start + batch_size], device))  # (B,2,360,640)
        lane_pixels = (lane[:, LANE_CLASS : LANE_CLASS + 1] > lane[:, :1]).float()  # (B,1,360,640); argmax of 2 channels
        resized = F.interpolate(lane_pixels, size=(height, width), mode="nearest")
        masks[start : start + batch_size] = resized[:, 0].bool().cpu().numpy()
    return masks
