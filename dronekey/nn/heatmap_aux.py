"""Training-only auxiliary supervision: propeller heatmaps from the edge backbone's middle stages.

Why. The DroneKey head regresses the four keypoints from the *mean* of the encoder's tokens (paper
eq. 2), so the CNN must learn "a propeller is here" features before the regression can read
positions through the positional encoding. With LEDs at the keypoints (the first round) such
features came almost for free; on drones without them the network sat on the "mean keypoints"
plateau (~29 px median error on 128 px crops after 14 epochs, run r3 in docs/model.md). A dense,
order-free target on the stride-8 and stride-16 feature maps tells the backbone where the
propellers are at every pixel, and a second channel tells it which of them are the front ones
(the nose, gimbal and battery lie inside a stride-16 cell's receptive field).

The heads are 1x1 / depthwise convolutions on forward-hooked features; they are not part of
``DroneKeyNet``, so they are neither exported nor stored in checkpoints (the run's ``state.pt``
keeps them for ``--resume``).

Frames: keypoints in normalised crop units (0 = left/top edge, 1 = right/bottom, ``dronekey.geometry.crop``);
a heatmap cell (i, j) of a G x G map covers [j/G, (j+1)/G) x [i/G, (i+1)/G).
"""

from __future__ import annotations

import torch
from torch import nn

from dronekey.nn.backbones import EdgeBackbone

__all__ = ["HEATMAP_STRIDES", "PropellerHeatmaps", "heatmap_loss", "propeller_targets"]

HEATMAP_STRIDES = (8, 16)
SIGMA_PX = 5.0  # Gaussian radius of a propeller in input pixels (a 128 px crop's propeller is 8-25 px)
FRONT = (0, 3)  # front-right and front-left in the spec's order (1 FR, 2 RR, 3 RL, 4 FL)
PEAK_WEIGHT = 9.0  # extra BCE weight on the peaks: 4 small blobs in a mostly empty map


def _stage_ends(backbone: EdgeBackbone, widths: tuple[int, ...], depths: tuple[int, ...]) -> dict:
    """{stride: (index in ``backbone.features`` of the stage's last module, its channels)}, first
    stage of each stride."""
    index, stride, ends = 3, 2, {}  # the stem is conv, BN, ReLU at stride 2
    for i, blocks in enumerate(depths):
        stride *= 1 if (i == 3 and backbone.stride == 16) else 2
        index += 1 + blocks
        ends.setdefault(stride, (index - 1, int(widths[i + 1])))
    return ends


class PropellerHeatmaps(nn.Module):
    """Two logit maps (every propeller, front propellers) per tapped stride of an edge backbone.

    Parameters
    ----------
    backbone : EdgeBackbone
        The network's backbone; its stride-8 and stride-16 stage outputs are captured by hooks on
        every forward pass of the network.
    widths, depths : tuples
        The backbone's ``edge_widths`` / ``edge_depths`` (``DroneKeyConfig``).
    """

    def __init__(self, backbone: EdgeBackbone, widths: tuple[int, ...], depths: tuple[int, ...]) -> None:
        super().__init__()
        if not isinstance(backbone, EdgeBackbone):
            raise TypeError(f"backbone must be an EdgeBackbone, got {type(backbone).__name__}")
        ends = _stage_ends(backbone, tuple(widths), tuple(depths))
        self._features: dict[int, torch.Tensor] = {}
        self.heads = nn.ModuleDict()
        for stride in HEATMAP_STRIDES:
            index, channels = ends[stride]
            self.heads[str(stride)] = nn.Sequential(
                nn.Conv2d(channels, channels, 3, padding=1, groups=channels),
                nn.ReLU(),
                nn.Conv2d(channels, 2, 1),
            )
            backbone.features[index].register_forward_hook(self._keep(stride))

    def _keep(self, stride: int):
        def hook(_module, _inputs, output):
            self._features[stride] = output

        return hook

    def forward(self) -> dict[int, torch.Tensor]:
        """Logits (B, 2, S/stride, S/stride) per stride, from the last network forward pass."""
        if set(self._features) != set(HEATMAP_STRIDES):
            raise RuntimeError("run the network forward before the heatmap heads")
        return {s: self.heads[str(s)](self._features[s]) for s in HEATMAP_STRIDES}


def propeller_targets(
    keypoints: torch.Tensor, present: torch.Tensor, grid: int, input_size: int
) -> torch.Tensor:
    """Gaussian targets (B, 2, grid, grid) in [0, 1]: channel 0 every propeller, 1 the front two.

    ``keypoints`` (B, 4, 2) normalised crop units, ``present`` (B,) bool; drone-free crops get zeros.
    """
    centres = (torch.arange(grid, dtype=keypoints.dtype, device=keypoints.device) + 0.5) / grid
    sigma = SIGMA_PX / input_size
    dx = centres[None, None, None, :] - keypoints[:, :, 0, None, None]  # (B, K, 1, G)
    dy = centres[None, None, :, None] - keypoints[:, :, 1, None, None]  # (B, K, G, 1)
    blobs = torch.exp(-(dx**2 + dy**2) / (2 * sigma**2))  # (B, K, G, G)
    every = blobs.amax(dim=1)
    front = blobs[:, list(FRONT)].amax(dim=1)
    return torch.stack([every, front], dim=1) * present[:, None, None, None].to(keypoints.dtype)


def heatmap_loss(
    logits: dict[int, torch.Tensor], keypoints: torch.Tensor, present: torch.Tensor, input_size: int
):
    """Peak-weighted BCE of every tapped map against ``propeller_targets``, averaged over strides."""
    total = keypoints.new_zeros(())
    for _stride, logit in logits.items():
        target = propeller_targets(keypoints, present, logit.shape[-1], input_size)
        weight = 1.0 + PEAK_WEIGHT * target
        total = total + nn.functional.binary_cross_entropy_with_logits(logit.float(), target, weight=weight)
    return total / max(1, len(logits))
