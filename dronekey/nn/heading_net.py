"""The patch classifiers in torch (training and export; the runtime runs their ONNX exports through
``dronekey.perception.heading_model`` and ``dronekey.perception.drone_verifier``).

Input: a 64 px BGR patch turned front-up around the keypoints (``canonical_patches``), normalised
by ``patches_to_tensor``. ``HeadingNet`` is a small CNN whose head keeps where its features are
(flatten, not global pooling: "top" against "bottom" is the front/back answer). Two wrappers fix
how the answer may depend on the keypoints' order:

- ``Antisymmetric`` (front/back): the patch turned 180 degrees (the twin order) gets exactly the
  opposite logit;
- ``Symmetric`` (drone or not): the patch and its 180-degree turn get the same logit, so the
  verdict does not depend on which order the keypoints came in.
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["Antisymmetric", "HeadingNet", "Symmetric"]


class HeadingNet(nn.Module):
    """3x3 conv blocks (stride 2, then 2x2 max-pools: 64 -> 4 px), flatten, MLP -> one logit.

    Parameters
    ----------
    channels : the widths of the four stages (32, 32, 16 and 8 px).
    patch_size : input side, px (a multiple of 16).
    repeats : 3x3 conv blocks in each of the two last stages (16 and 8 px); 1 is the four-conv net
        of the default front/back classifier and the verifier, 2 the deeper, opt-in front/back
        classifier's (eighteenth session; docs/model.md).
    """

    def __init__(
        self, channels: tuple[int, int, int, int] = (16, 32, 64, 96), patch_size: int = 64, repeats: int = 1
    ) -> None:
        super().__init__()
        if patch_size % 16:
            raise ValueError(f"patch_size must be a multiple of 16, got {patch_size}")
        if repeats < 1:
            raise ValueError(f"repeats must be at least 1, got {repeats}")
        c = channels
        self.features = nn.Sequential(
            _block(3, c[0], stride=2),
            _block(c[0], c[1]),
            nn.MaxPool2d(2),
            _block(c[1], c[2]),
            *(_block(c[2], c[2]) for _ in range(repeats - 1)),
            nn.MaxPool2d(2),
            _block(c[2], c[3]),
            *(_block(c[3], c[3]) for _ in range(repeats - 1)),
            nn.MaxPool2d(2),
        )
        self.head = nn.Sequential(
            nn.Flatten(),
            nn.Dropout(0.2),
            nn.Linear(c[3] * (patch_size // 16) ** 2, 64),
            nn.ReLU(inplace=True),
            nn.Linear(64, 1),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.features(x)).squeeze(1)


class _HalfTurnPaired(nn.Module):
    """``logit(x) = (f(x) + sign * f(rot180(x))) / 2`` for a one-logit ``f``."""

    sign = 1.0

    def __init__(self, f: nn.Module) -> None:
        super().__init__()
        self.f = f

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        both = self.f(torch.cat([x, torch.flip(x, dims=(2, 3))]))
        n = x.shape[0]
        return 0.5 * (both[:n] + self.sign * both[n:])


class Antisymmetric(_HalfTurnPaired):
    """``logit(x) = (f(x) - f(rot180(x))) / 2``: the twin order gets exactly ``-logit``, so the
    exported probabilities of an order and its twin always sum to 1."""

    sign = -1.0


class Symmetric(_HalfTurnPaired):
    """``logit(x) = (f(x) + f(rot180(x))) / 2``: an order and its twin get the same logit."""

    sign = 1.0


def _block(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True)
    )
