"""CNN backbones of the DroneKey network (paper §III-A): image (B, 3, S, S) -> feature map.

Two trunks, both written in plain torch (torchvision is not a dependency):

- ``ResNet50Trunk``: the paper's backbone, torchvision's ResNet-50 (v1.5: stride on the 3x3 conv
  of each bottleneck) without its pooling and classifier; 2048 channels at stride 32, 23.51 M
  parameters.
- ``EdgeBackbone``: our backbone for 2-core edge CPUs: a residual network of depthwise-separable
  blocks (BN + ReLU, all of which ONNX Runtime fuses into its convolutions) that reaches stride 32
  (the paper's H/32 grid) or, optionally, stops downsampling at stride 16 for a finer token grid.

Every backbone exposes ``out_channels`` and ``stride`` so the model can size its projection and
positional encoding.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

__all__ = ["EdgeBackbone", "ResNet50Trunk"]


def _conv_bn(c_in: int, c_out: int, kernel: int, stride: int = 1, groups: int = 1) -> list[nn.Module]:
    """Convolution without bias followed by BatchNorm (the bias would be folded into BN anyway)."""
    return [
        nn.Conv2d(c_in, c_out, kernel, stride=stride, padding=kernel // 2, groups=groups, bias=False),
        nn.BatchNorm2d(c_out),
    ]


# --------------------------------------------------------------------------------------------------
# ResNet-50 (the paper's backbone)
# --------------------------------------------------------------------------------------------------


class _Bottleneck(nn.Module):
    """ResNet v1.5 bottleneck: 1x1 reduce, 3x3 (carries the stride), 1x1 expand x4, identity add."""

    expansion = 4

    def __init__(self, c_in: int, width: int, stride: int) -> None:
        super().__init__()
        c_out = width * self.expansion
        self.body = nn.Sequential(
            *_conv_bn(c_in, width, 1),
            nn.ReLU(inplace=True),
            *_conv_bn(width, width, 3, stride),
            nn.ReLU(inplace=True),
            *_conv_bn(width, c_out, 1),
        )
        self.shortcut = (
            nn.Sequential(*_conv_bn(c_in, c_out, 1, stride))
            if stride != 1 or c_in != c_out
            else nn.Identity()
        )
        self.act = nn.ReLU(inplace=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.body(x) + self.shortcut(x))


class ResNet50Trunk(nn.Module):
    """ResNet-50 up to its last stage: (B, 3, S, S) -> (B, 2048, S/32, S/32).

    Same layer shapes and parameter count (23,508,032) as torchvision's ``resnet50`` minus ``avgpool``
    and ``fc``; randomly initialised (He init, as torchvision), since no weights can be downloaded.
    """

    out_channels = 2048
    stride = 32

    def __init__(self) -> None:
        super().__init__()
        layers: list[nn.Module] = [
            *_conv_bn(3, 64, 7, 2),
            nn.ReLU(inplace=True),
            nn.MaxPool2d(3, stride=2, padding=1),
        ]
        c_in = 64
        for width, blocks, stride in ((64, 3, 1), (128, 4, 2), (256, 6, 2), (512, 3, 2)):
            for i in range(blocks):
                layers.append(_Bottleneck(c_in, width, stride if i == 0 else 1))
                c_in = width * _Bottleneck.expansion
        self.features = nn.Sequential(*layers)
        _init_conv_bn(self)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.features(x)


# --------------------------------------------------------------------------------------------------
# Edge backbone (ours)
# --------------------------------------------------------------------------------------------------


class _SeparableResidual(nn.Module):
    """Two depthwise-separable 3x3 convolutions with an identity shortcut (a 'basic block' whose
    3x3 convs are factorised as depthwise 3x3 + pointwise 1x1)."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.body = nn.Sequential(
            *_conv_bn(channels, channels, 3, groups=channels),
            *_conv_bn(channels, channels, 1),
            nn.ReLU(inplace=True),
            *_conv_bn(channels, channels, 3, groups=channels),
            *_conv_bn(channels, channels, 1),
        )
        self.act = nn.ReLU(inplace=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.body(x) + x)


def _separable_down(c_in: int, c_out: int, stride: int) -> nn.Sequential:
    """Depthwise 3x3 (carries the stride) then pointwise 1x1 to ``c_out``; the stage transition."""
    return nn.Sequential(
        *_conv_bn(c_in, c_in, 3, stride, groups=c_in),
        *_conv_bn(c_in, c_out, 1),
        nn.ReLU(inplace=True),
    )


class EdgeBackbone(nn.Module):
    """Small residual CNN for CPUs: (B, 3, S, S) -> (B, widths[-1], S/stride, S/stride).

    Layout: a full 3x3 stem convolution (stride 2, ``widths[0]`` channels), then four stages; stage
    ``i`` opens with a strided depthwise-separable transition to ``widths[i + 1]`` channels and holds
    ``depths[i]`` separable residual blocks. Stages at 64x64 and below dominate nothing: depthwise
    3x3 + pointwise 1x1 costs about 1/8 of a full 3x3 convolution at these widths, which is what
    keeps the whole network near 1 ms in ONNX Runtime on two cores.

    Parameters
    ----------
    widths : sequence of 5 ints
        Channels of the stem and of the four stages.
    depths : sequence of 4 ints
        Separable residual blocks per stage (after its transition).
    stride : {32, 16}
        Output stride. 32 is the paper's H/32 grid; 16 keeps the last stage at the resolution of the
        third (its transition does not downsample), four times as many tokens.
    """

    def __init__(
        self,
        widths: Sequence[int] = (32, 64, 96, 160, 256),
        depths: Sequence[int] = (1, 2, 2, 2),
        stride: int = 32,
    ) -> None:
        super().__init__()
        widths, depths = tuple(int(w) for w in widths), tuple(int(d) for d in depths)
        if len(widths) != 5 or min(widths) < 1:
            raise ValueError(f"widths must be 5 positive channel counts (stem + 4 stages), got {widths}")
        if len(depths) != 4 or min(depths) < 0:
            raise ValueError(f"depths must be 4 non-negative block counts, got {depths}")
        if stride not in (16, 32):
            raise ValueError(f"stride must be 16 or 32, got {stride}")
        self.out_channels = widths[-1]
        self.stride = stride
        layers: list[nn.Module] = [*_conv_bn(3, widths[0], 3, 2), nn.ReLU(inplace=True)]
        for i, blocks in enumerate(depths):
            down = 1 if (i == 3 and stride == 16) else 2
            layers.append(_separable_down(widths[i], widths[i + 1], down))
            layers.extend(_SeparableResidual(widths[i + 1]) for _ in range(blocks))
        self.features = nn.Sequential(*layers)
        _init_conv_bn(self)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.features(x)


def _init_conv_bn(module: nn.Module) -> None:
    """He-normal convolutions and unit BatchNorm, as torchvision. (No 'zero-gamma' residual init:
    it would cut the gradient of every residual branch at initialisation, see the model's tests.)"""
    for m in module.modules():
        if isinstance(m, nn.Conv2d):
            nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
        elif isinstance(m, nn.BatchNorm2d):
            nn.init.ones_(m.weight)
            nn.init.zeros_(m.bias)
