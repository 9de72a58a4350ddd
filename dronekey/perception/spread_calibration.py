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
their centroid by ``r / q``; where they sit, and their order and shape, stay the network's.

It may also know that a drone seen edge-on is read smaller: where the keypoints' aspect ``a``
(shortest pair over longest, ``keypoint_aspect``) is below ``aspect_knee``, the slope grows by
``aspect_slope * (aspect_knee - a)``. On GT-framed crops of the 36 drone sequences of tuning seeds
8001 and 9101 the shipped network, uncalibrated, read the spread at 0.77 / 0.83 of the truth with
``a`` < 0.15, 0.83 / 0.87 at 0.15-0.25, 0.94 / 0.95 at 0.25-0.35 and 0.98-0.99 above: a single
factor leaves edge-on drones 10-20 % too far. Refit so on tuning seed 8001, it raised the tuning
matrix's false-track frames by 29 % (a short pair in tracking is as often a reading gone wrong as an
edge-on drone; docs/evaluation.md, twenty-sixth session), so the shipped model has no aspect term.
The shipped model carries one factor (intercept 0), fitted on tuning renders by
``dronekey-calibrate-spread``, which says why a factor and not a line. The fit is the model's, so it
travels in the ONNX metadata (``spread_calibration``); a model without one is left as it is
(``identity``).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np

__all__ = ["SpreadCalibration", "below_knee", "keypoint_aspect", "normalised_spread"]

METADATA_KEY = "spread_calibration"
SCALE_LIMITS = (0.5, 2.0)  # the most the calibration may shrink or grow a crop's keypoints


def normalised_spread(keypoints: np.ndarray) -> np.ndarray:
    """Longest pairwise distance of each crop's keypoints, (B, 4, 2) -> (B,), in their units."""
    kp = np.asarray(keypoints, dtype=np.float64)
    return np.linalg.norm(kp[:, :, None, :] - kp[:, None, :, :], axis=-1).max(axis=(1, 2))


def below_knee(aspect: np.ndarray, knee: float) -> np.ndarray:
    """``max(0, knee - aspect)`` per crop; an unknown aspect (NaN, a collapsed answer) counts as 1."""
    return np.maximum(knee - np.nan_to_num(np.asarray(aspect, dtype=np.float64), nan=1.0), 0.0)


def keypoint_aspect(keypoints: np.ndarray) -> np.ndarray:
    """Shortest pairwise distance of each crop's keypoints over the longest, (B, 4, 2) -> (B,) in
    [0, 1]: low for a drone seen edge-on (two hubs nearly in line), NaN for a collapsed answer."""
    kp = np.asarray(keypoints, dtype=np.float64)
    d = np.linalg.norm(kp[:, :, None, :] - kp[:, None, :, :], axis=-1)
    pairs = d[:, *np.triu_indices(kp.shape[1], 1)]
    longest = pairs.max(axis=1)
    return np.where(longest > 0, pairs.min(axis=1) / np.where(longest > 0, longest, 1.0), np.nan)


@dataclass(frozen=True)
class SpreadCalibration:
    """``r = intercept + (slope + aspect_slope * max(0, aspect_knee - a)) * q``: the true normalised
    spread given the network's ``q`` and its keypoints' aspect ``a`` (see the module).

    intercept : crop-side units. slope : > 0. ``fitted_on`` says on what (kept in the metadata).
    aspect_knee : in [0, 1); aspect_slope : >= 0; 0 (the default) leaves the aspect out.
    """

    intercept: float = 0.0
    slope: float = 1.0
    fitted_on: str = ""
    aspect_knee: float = 0.0
    aspect_slope: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.intercept) and math.isfinite(self.slope) and self.slope > 0):
            raise ValueError(
                f"spread calibration needs a finite intercept and a slope > 0, "
                f"got intercept {self.intercept!r}, slope {self.slope!r}"
            )
        knee_ok = 0.0 <= self.aspect_knee < 1.0
        if not (knee_ok and math.isfinite(self.aspect_slope) and self.aspect_slope >= 0):
            raise ValueError(
                "spread calibration needs aspect_knee in [0, 1) and a finite aspect_slope >= 0, "
                f"got aspect_knee {self.aspect_knee!r}, aspect_slope {self.aspect_slope!r}"
            )

    @property
    def is_identity(self) -> bool:
        return self.intercept == 0.0 and self.slope == 1.0 and not self.uses_aspect

    @property
    def uses_aspect(self) -> bool:
        return self.aspect_slope > 0.0 and self.aspect_knee > 0.0

    def slopes(self, keypoints: np.ndarray) -> np.ndarray:
        """The slope each crop's keypoints (B, 4, 2) get: ``slope``, grown below the aspect knee."""
        if not self.uses_aspect:
            return np.full(len(keypoints), self.slope)
        return self.slope + self.aspect_slope * below_knee(keypoint_aspect(keypoints), self.aspect_knee)

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
        scale = np.where(q > 1e-3, (self.intercept + self.slopes(kp) * q) / np.maximum(q, 1e-3), 1.0)
        scale = np.clip(scale, *SCALE_LIMITS)
        centre = kp.mean(axis=1, keepdims=True)
        return (centre + scale[:, None, None] * (kp - centre)).astype(np.float32), scale

    def to_metadata(self) -> str:
        """The JSON string stored under ``spread_calibration`` in the ONNX metadata."""
        entry = {"intercept": self.intercept, "slope": self.slope, "fitted_on": self.fitted_on}
        if self.uses_aspect:
            entry |= {"aspect_knee": self.aspect_knee, "aspect_slope": self.aspect_slope}
        return json.dumps(entry)

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
            return cls(
                float(entry["intercept"]),
                float(entry["slope"]),
                str(entry.get("fitted_on", "")),
                float(entry.get("aspect_knee", 0.0)),
                float(entry.get("aspect_slope", 0.0)),
            )
        except (TypeError, ValueError) as exc:
            raise ValueError(f"metadata {METADATA_KEY!r}: {exc}") from None
