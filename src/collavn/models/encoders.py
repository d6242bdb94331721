"""Visual encoders: images ``(B, C, H, W)`` → embeddings ``(B, output_size)``.

Two trunks behind one interface: the torchvision ResNet18 architecture written in plain
torch (same module names, so torchvision ImageNet state dicts load unchanged) and a
small CNN for CPU-sized runs. uint8 RGB input is scaled to [0, 1] and normalised with
the ImageNet statistics; extra channels (depth) are passed through as given.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import torch
from torch import Tensor, nn

from collavn.errors import CheckpointError
from collavn.models.config import EncoderKind

_MEAN = (0.485, 0.456, 0.406)
_STD = (0.229, 0.224, 0.225)


def channels_last(x: Tensor) -> Tensor:
    """``x`` ``(B, C, H, W)`` laid out channels-last (the same values, NHWC strides).

    The CPU convolution kernels (oneDNN) run the small trunks here faster on
    channels-last activations than on NCHW ones; only the memory layout changes, so
    results agree to float rounding, and weights and checkpoints keep their layout.
    """
    return x.contiguous(memory_format=torch.channels_last)


def normalise_rgb(images: Tensor) -> Tensor:
    """Scale uint8 RGB ``(B, 3+k, H, W)`` to float and apply the ImageNet normalisation.

    The first three channels are RGB (uint8 or float in [0, 255]); further channels
    (e.g. normalised depth) are returned unchanged.
    """
    x = images.float()
    rgb = x[:, :3] / 255.0
    mean = rgb.new_tensor(_MEAN).view(1, 3, 1, 1)
    std = rgb.new_tensor(_STD).view(1, 3, 1, 1)
    if x.shape[1] == 3:
        return (rgb - mean) / std
    return torch.cat([(rgb - mean) / std, x[:, 3:]], dim=1)


def with_depth(panorama: Tensor, depth: Tensor | None, max_depth: float, who: str) -> Tensor:
    """``(B, 3, H, W)`` panorama and ``(B, H, W)`` depth → ``(B, 4, H, W)`` float input.

    Depth enters as ``clamp(depth, 0, max_depth) / max_depth`` (0 = no hit, as the
    renderer writes it). ``who`` names the setting that asked for depth, for the error
    when there is none.
    """
    if depth is None:
        raise ValueError(f"{who} is set but no depth was given (the env must render it: "
                         f"EnvConfig(depth=True))")
    b, _, h, w = panorama.shape
    if tuple(depth.shape) != (b, h, w):
        raise ValueError(f"{who}: depth {tuple(depth.shape)} does not fit the panorama "
                         f"{tuple(panorama.shape)}; expected {(b, h, w)}")
    d = depth.float().clamp(0, max_depth) / max_depth
    return torch.cat([panorama.float(), d.unsqueeze(1)], dim=1)


class BasicBlock(nn.Module):
    """torchvision's ResNet BasicBlock (two 3×3 convs and a residual)."""

    def __init__(self, inplanes: int, planes: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(inplanes, planes, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = nn.Conv2d(planes, planes, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.downsample: nn.Module | None = None
        if stride != 1 or inplanes != planes:
            self.downsample = nn.Sequential(
                nn.Conv2d(inplanes, planes, 1, stride, bias=False), nn.BatchNorm2d(planes))

    def forward(self, x: Tensor) -> Tensor:
        """``(B, inplanes, H, W)`` → ``(B, planes, H/stride, W/stride)``."""
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + identity)


class ResNet18Trunk(nn.Module):
    """ResNet18 up to ``layer4`` with torchvision's parameter names (no ``fc``)."""

    output_channels = 512

    def __init__(self, in_channels: int = 3) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(in_channels, 64, 7, 2, 3, bias=False)
        self.bn1 = nn.BatchNorm2d(64)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(3, 2, 1)
        self.layer1 = nn.Sequential(BasicBlock(64, 64), BasicBlock(64, 64))
        self.layer2 = nn.Sequential(BasicBlock(64, 128, 2), BasicBlock(128, 128))
        self.layer3 = nn.Sequential(BasicBlock(128, 256, 2), BasicBlock(256, 256))
        self.layer4 = nn.Sequential(BasicBlock(256, 512, 2), BasicBlock(512, 512))
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")

    def forward(self, x: Tensor) -> Tensor:
        """``(B, C, H, W)`` float → ``(B, 512, H/32, W/32)``."""
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        return self.layer4(self.layer3(self.layer2(self.layer1(x))))


def load_imagenet_weights(trunk: ResNet18Trunk, path: str | Path) -> None:
    """Load a torchvision ``resnet18`` state dict from a local file into ``trunk``.

    ``fc.*`` entries are ignored. For a trunk with extra input channels the RGB part of
    ``conv1`` is copied and the extra input channels are left at their initialisation.

    Raises:
        CheckpointError: The file is missing or does not hold ResNet18 weights.
    """
    try:
        state = torch.load(Path(path), map_location="cpu", weights_only=True)
    except (OSError, RuntimeError, ValueError) as exc:
        raise CheckpointError(f"{path}: cannot read ResNet18 weights ({exc})") from exc
    state = {k: v for k, v in state.items() if not k.startswith("fc.")}
    conv1 = state.get("conv1.weight")
    own = trunk.conv1.weight
    if (conv1 is not None and conv1.dim() == 4 and conv1.shape[0] == own.shape[0]
            and conv1.shape[1] == 3 and own.shape[1] > 3):
        merged = own.detach().clone()
        merged[:, :3] = conv1
        state["conv1.weight"] = merged
    try:
        trunk.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        raise CheckpointError(f"{path}: not a torchvision ResNet18 state dict ({exc})") from exc


class ResNet18Encoder(nn.Module):
    """ResNet18 trunk, global average pooling and a linear layer to ``output_size``."""

    def __init__(self, in_channels: int, output_size: int,
                 weights_path: str | Path | None = None) -> None:
        super().__init__()
        self.output_size = output_size
        self.trunk = ResNet18Trunk(in_channels)
        if weights_path is not None:
            load_imagenet_weights(self.trunk, weights_path)
        self.head = nn.Sequential(nn.Linear(512, output_size), nn.ReLU())

    def forward(self, images: Tensor) -> Tensor:
        """``(B, C, H, W)`` uint8 (or float in [0, 255]) → ``(B, output_size)``."""
        feats = self.trunk(normalise_rgb(images))
        return self.head(feats.mean(dim=(2, 3)))


class SmallCNNEncoder(nn.Module):
    """Four stride-2 3×3 convolutions, adaptive pooling that keeps the aspect ratio.

    A 3×32×128 panorama is pooled to 2×8 cells (azimuth information survives), a
    square goal image to 2×2.
    """

    def __init__(self, in_channels: int, output_size: int, image_hw: tuple[int, int]) -> None:
        super().__init__()
        self.output_size = output_size
        h, w = image_hw
        pool = (2, max(1, round(2 * w / h)))
        chans = (in_channels, 32, 64, 64, 128)
        layers: list[nn.Module] = []
        for cin, cout in itertools.pairwise(chans):
            layers += [nn.Conv2d(cin, cout, 3, 2, 1), nn.ReLU(inplace=True)]
        layers.append(nn.AdaptiveAvgPool2d(pool))
        self.trunk = nn.Sequential(*layers)
        self.head = nn.Sequential(nn.Flatten(), nn.Linear(128 * pool[0] * pool[1], output_size),
                                  nn.ReLU())

    def forward(self, images: Tensor) -> Tensor:
        """``(B, C, H, W)`` uint8 (or float in [0, 255]) → ``(B, output_size)``."""
        return self.head(self.trunk(channels_last(normalise_rgb(images))))


def make_encoder(kind: EncoderKind, image_shape: tuple[int, int, int], output_size: int,
                 weights_path: str | Path | None = None) -> ResNet18Encoder | SmallCNNEncoder:
    """Build the encoder named by ``kind`` for images of ``image_shape = (C, H, W)``."""
    channels, h, w = image_shape
    if kind == "resnet18":
        return ResNet18Encoder(channels, output_size, weights_path)
    if kind == "small":
        if weights_path is not None:
            raise ValueError("ImageNet weights exist only for the resnet18 encoder")
        return SmallCNNEncoder(channels, output_size, (h, w))
    raise ValueError(f"unknown encoder kind {kind!r}")
