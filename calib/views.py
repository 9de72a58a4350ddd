"""What the stages pass along: board points seen in one picture, and pictures left out (with why)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BoardView", "RejectedView"]


@dataclass(frozen=True)
class BoardView:
    """Board points found in one image.

    Attributes
    ----------
    image_points : (N, 2) float32
        Pixel coordinates (origin at the top-left pixel's centre, docs/design.md §4).
    object_points : (N, 3) float32
        The same points in the board frame (z = 0), metres.
    """

    image_points: np.ndarray
    object_points: np.ndarray

    def __len__(self) -> int:
        return len(self.image_points)


@dataclass(frozen=True)
class RejectedView:
    """A picture left out of the calibration, and why (one short phrase)."""

    name: str
    reason: str

    def to_dict(self) -> dict:
        return {"view": self.name, "reason": self.reason}
