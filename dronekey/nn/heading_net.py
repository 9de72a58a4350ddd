"""The patch classifiers in torch (training and export; the runtime runs their ONNX exports through
``dronekey.perception.heading_model`` and ``dronekey.perception.drone_verifier``).

Input: a 64 px BGR patch turned front-up around the keypoints (``canonical_patches``), normalised
by ``patches_to_tensor``. ``HeadingNet`` is a small CNN whose head keeps where its features are
(flatten, not global pooling: "top" against "bottom" is the front/back answer). Two wrappers fix
how the answer may depend on the keypoints' order:

- ``Antisymmetric`` (front/back): the patch turned 180 degrees (the twin order) gets exactly the
  opposite logit;
- ``Symmetric`` (drone or not): the patch and its 180-degree turn get the same logit, so the
  verdict does not depend on which order the keypoints came in;
- ``GatedAntisymmetric`` (front/back with a gate): a two-logit net, the first read antisymmetric
  (which end is the front), the second symmetric (whether the body shows a front at all); the
  order's probability is pulled to 0.5 as far as the second says there is nothing to read.
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["Antisymmetric", "GatedAntisymmetric", "HeadingNet", "Symmetric"]


class HeadingNet(nn.Module):
    """3x3 conv blocks (stride 2, then 2x2 max-pools: 64 -> 4 px), flatten, MLP -> one logit.

    Parameters
    ----------
    channels : the widths of the four stages (32, 32, 16 and 8 px).
    patch_size : input side, px (a multiple of 16).
    repeats : 3x3 conv blocks in each of the two last stages (16 and 8 px); 1 is the four-conv net
        of the default front/back classifier and the verifier, 2 the deeper, opt-in front/back
        classifier's (eighteenth session; docs/model.md).
    outputs : logits per patch: 1 (returned as (B,)) or 2 (``GatedAntisymmetric``'s, (B, 2)).
    """

    def __init__(
        self,
        channels: tuple[int, int, int, int] = (16, 32, 64, 96),
        patch_size: int = 64,
        repeats: int = 1,
        outputs: int = 1,
    ) -> None:
        super().__init__()
        if patch_size % 16:
            raise ValueError(f"patch_size must be a multiple of 16, got {patch_size}")
        if repeats < 1:
            raise ValueError(f"repeats must be at least 1, got {repeats}")
        if outputs not in (1, 2):
            raise ValueError(f"outputs must be 1 or 2, got {outputs}")
        self.outputs = outputs
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
            nn.Linear(64, outputs),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.head(self.features(x))
        return out.squeeze(1) if self.outputs == 1 else out


class _HalfTurnPaired(nn.Module):
    """A net ``f`` run on a patch and on the same patch turned 180 degrees (the twin order), in
    one batch; the subclasses say how the two answers combine."""

    def __init__(self, f: nn.Module) -> None:
        super().__init__()
        self.f = f

    def pair(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``f(x)`` and ``f(rot180(x))``."""
        both = self.f(torch.cat([x, torch.flip(x, dims=(2, 3))]))
        n = x.shape[0]
        return both[:n], both[n:]


class Antisymmetric(_HalfTurnPaired):
    """``logit(x) = (f(x) - f(rot180(x))) / 2``: the twin order gets exactly ``-logit``, so the
    exported probabilities of an order and its twin always sum to 1."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        here, turned = self.pair(x)
        return 0.5 * (here - turned)


class Symmetric(_HalfTurnPaired):
    """``logit(x) = (f(x) + f(rot180(x))) / 2``: an order and its twin get the same logit."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        here, turned = self.pair(x)
        return 0.5 * (here + turned)


class GatedAntisymmetric(_HalfTurnPaired):
    """The front/back answer of a two-logit ``f`` (``HeadingNet(outputs=2)``), gated by whether
    there is one: ``h = (f0(x) - f0(rot180(x))) / 2`` says which end is the front,
    ``g = (f1(x) + f1(rot180(x))) / 2`` whether the body shows one, and the order's probability is
    ``p = 1/2 + (sigmoid(h) - 1/2) sigmoid(g)``, returned as its logit. The twin order still gets
    exactly ``-logit``; a patch the gate finds no front in reads 0.5, however sure ``h`` is."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        here, turned = self.pair(x)
        order = 0.5 * (here[:, 0] - turned[:, 0])
        shows_front = 0.5 * (here[:, 1] + turned[:, 1])
        p = 0.5 + (torch.sigmoid(order) - 0.5) * torch.sigmoid(shows_front)
        return torch.log(p) - torch.log1p(-p)


def _block(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True)
    )
