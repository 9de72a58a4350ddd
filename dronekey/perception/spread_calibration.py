"""The keypoint model's size answer, corrected: how far apart its four keypoints really are.

The network places the keypoints well (1-3 px median on the reporting renders, either order) but
reads the drone's *size* partly from the crop it is given: its normalised spread ``q`` (longest
keypoint pair over the crop side) answers the true one ``r`` with a slope well below 1, and too
small on average. On the 36 tuning drone sequences (7,118 crops at 0.75-1.35 x the training
framing, mirror-averaged) it reads 3.6 % of the crop side short on average; by size, drones with
``r`` 0.30-0.40 are read 8 % large and those with ``r`` 0.55-0.70 19 % small.

In tracking the shortfall feeds itself: each crop is cut again on the keypoints the last one gave
(``Localizer.track_many``), so a drone read small gets a tighter crop, in which it is read smaller
still, until the loop settles where the network under-reads by about a fifth: the track's range
drifts 20-30 % too far (seq13: 4.3 m read as 5.5 m) and leaves its gate.

``SpreadCalibration`` maps ``q`` to ``r = intercept + slope * q`` and scales the keypoints about
their centroid by ``r / q``; where they sit, and their order and shape, stay the network's. The
shipped model carries one factor (intercept 0), fitted on tuning renders by
``dronekey-calibrate-spread``, which says why a factor and not a line. The fit is the model's, so it
travels in the ONNX metadata (``spread_calibration``); a model without one is left as it is
(``identity``).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np

__all__ = ["SpreadCalibration", "normalised_spread"]

METADATA_KEY = "spread_calibration"
SCALE_LIMITS = (0.5, 2.0)  # the most the calibration may shrink or grow a crop's keypoints


def normalised_spread(keypoints: np.ndarray) -> np.ndarray:
    """Longest pairwise distance of each crop's keypoints, (B, 4, 2) -> (B,), in their units."""
    kp = np.asarray(keypoints, dtype=np.float64)
    return np.linalg.norm(kp[:, :, None, :] - kp[:, None, :, :], axis=-1).max(axis=(1, 2))


@dataclass(frozen=True)
class SpreadCalibration:
    """``r = intercept + slope * q``: the true normalised spread given the network's (see the module).

    intercept : crop-side units. slope : > 0. ``fitted_on`` says on what (kept in the metadata).
    """

    intercept: float = 0.0
    slope: float = 1.0
    fitted_on: str = ""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.intercept) and math.isfinite(self.slope) and self.slope > 0):
            raise ValueError(
                f"spread calibration needs a finite intercept and a slope > 0, "
                f"got intercept {self.intercept!r}, slope {self.slope!r}"
            )

    @property
    def is_identity(self) -> bool:
        return self.intercept == 0.0 and self.slope == 1.0

    def apply(self, keypoints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Keypoints (B, 4, 2) in normalised crop units -> (calibrated keypoints, scale (B,)).

        Each crop's keypoints are scaled about their centroid by ``scale`` = calibrated spread over
        the network's, within ``SCALE_LIMITS`` (beyond them a line with an intercept is extrapolated
        far past the sizes it was fitted on); collapsed answers (spread below 1e-3) are left alone (scale 1).
        """
        kp = np.asarray(keypoints, dtype=np.float32)
        if self.is_identity:
            return kp, np.ones(len(kp))
        q = normalised_spread(kp)
        scale = np.where(q > 1e-3, (self.intercept + self.slope * q) / np.maximum(q, 1e-3), 1.0)
        scale = np.clip(scale, *SCALE_LIMITS)
        centre = kp.mean(axis=1, keepdims=True)
        return (centre + scale[:, None, None] * (kp - centre)).astype(np.float32), scale

    def to_metadata(self) -> str:
        """The JSON string stored under ``spread_calibration`` in the ONNX metadata."""
        return json.dumps({"intercept": self.intercept, "slope": self.slope, "fitted_on": self.fitted_on})

    @classmethod
    def from_metadata(cls, metadata: dict) -> SpreadCalibration:
        """The calibration in a model's (parsed) metadata; ``identity`` when it has none.

        Raises ValueError naming the key when the entry is malformed.
        """
        entry = metadata.get(METADATA_KEY)
        if entry is None:
            return cls()
        if isinstance(entry, str):
            try:
                entry = json.loads(entry)
            except json.JSONDecodeError as exc:
                raise ValueError(f"metadata {METADATA_KEY!r} is not JSON ({exc})") from None
        if not isinstance(entry, dict) or not {"intercept", "slope"} <= set(entry):
            raise ValueError(f"metadata {METADATA_KEY!r} must hold intercept and slope, got {entry!r}")
        try:
            return cls(float(entry["intercept"]), float(entry["slope"]), str(entry.get("fitted_on", "")))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"metadata {METADATA_KEY!r}: {exc}") from None
