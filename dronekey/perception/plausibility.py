"""Is this detection a drone at all? Geometric checks on every detection before it becomes a pose.

The presence score alone let clouds and building corners through (a cloud at the frame's top edge
scored 1.0, its keypoints 12 px above the frame, two of them 0.56 px apart). A real drone's four
propellers obey the geometry the network was trained on, whatever it looks like:

- **inside the crop**: the network was trained on crops framed around the drone, so its keypoints
  lie within the crop (``crop_margin`` of the side outside at most);
- **inside the frame**: a truncated drone may have a propeller or two past the edge, by less than
  ``frame_margin`` of its own spread; its centre never is;
- **no collapsed pairs**: the shortest keypoint pair is at least ``min_pair_frac`` of the longest
  (and ``min_pair_px``); four hubs seen from anywhere but exactly edge-on are apart;
- **spread fits the crop**: the network's own longest pair (before ``spread_calibration``) over the
  crop side lies in ``spread_in_crop``. Every
  crop is cut for a drone (on a track's predicted pose, or again on the keypoints a search crop
  found), framed as in training: 1.3 x the drone's box, the hubs' box grown by a propeller radius.
  For a real drone the network's spread then comes back at 0.44-0.55 of the side whatever its
  attitude (the hubs' geometry alone, every attitude, both specs), and 0.41-0.53 measured on the
  tuning seeds' drones (the network's own error). Clutter read as a drone is not self-consistent:
  re-cut around what the network found, the network finds a smaller "drone" inside it (median 0.32
  of the side on the tuning seeds' drone-free frames). Crops at most ``small_crop_px`` wide may be
  the crop policy's minimum side around a drone smaller than its framing; they keep the loose
  floor ``small_crop_min_spread``;
- **range**: the PnP pose lies in ``range_m``, and its distance agrees with the distance the
  spread implies for the drone's size (``depth_ratio``: foreshortening only shrinks the spread).

Each check returns the reason a detection fails (a short string for logs and the pipeline's
``rejection``), or None.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from dronekey.geometry.camera import CameraModel
from dronekey.geometry.crop import to_normalised
from dronekey.geometry.drone_spec import DroneSpec
from dronekey.types import KeypointDetection, PoseMeasurement

__all__ = ["PlausibilityConfig", "check_detection", "check_pose"]


@dataclass(frozen=True)
class PlausibilityConfig:
    """Limits of a plausible drone detection (see the module docstring)."""

    crop_margin: float = 0.15
    frame_margin: float = 0.5
    min_pair_frac: float = 0.06
    min_pair_px: float = 1.0
    spread_in_crop: tuple[float, float] = (0.38, 1.1)
    small_crop_px: int = 40
    small_crop_min_spread: float = 0.12
    range_m: tuple[float, float] = (0.3, 300.0)
    depth_ratio: tuple[float, float] = (0.35, 1.4)

    def __post_init__(self) -> None:
        lo, hi = self.spread_in_crop
        if not 0 < lo < hi:
            raise ValueError(f"spread_in_crop must satisfy 0 < min < max, got {self.spread_in_crop}")
        lo, hi = self.range_m
        if not 0 < lo < hi:
            raise ValueError(f"range_m must satisfy 0 < min < max, got {self.range_m}")
        lo, hi = self.depth_ratio
        if not 0 < lo < 1 < hi:
            raise ValueError(f"depth_ratio must satisfy 0 < min < 1 < max, got {self.depth_ratio}")
        if not 0 < self.small_crop_min_spread <= self.spread_in_crop[0]:
            raise ValueError(
                f"small_crop_min_spread must be in (0, spread_in_crop[0]], got {self.small_crop_min_spread}"
            )
        if not 0 <= self.min_pair_frac < 1:
            raise ValueError(f"min_pair_frac must be in [0, 1), got {self.min_pair_frac}")


def _pair_lengths(kp: np.ndarray) -> np.ndarray:
    i, j = _pairs(len(kp))
    return np.linalg.norm(kp[i] - kp[j], axis=1)


@functools.lru_cache(maxsize=4)
def _pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Both indices of every pair of ``n`` points (``np.triu_indices(n, 1)``, built once)."""
    return np.triu_indices(n, 1)


def check_detection(
    detection: KeypointDetection, frame_size: tuple[int, int], config: PlausibilityConfig | None = None
) -> str | None:
    """Why ``detection`` (full-frame pixels) cannot be a drone, or None when it can.

    Parameters
    ----------
    detection : KeypointDetection
    frame_size : (width, height) of the frame, pixels.
    config : PlausibilityConfig, optional
    """
    cfg = config or PlausibilityConfig()
    kp = np.asarray(detection.keypoints_px, dtype=np.float64)
    if kp.shape != (4, 2) or not np.all(np.isfinite(kp)):
        return "keypoints not finite"
    side = detection.roi[2]
    rel = to_normalised(kp, detection.roi)
    if rel.min() < -cfg.crop_margin or rel.max() > 1 + cfg.crop_margin:
        return "keypoints outside their crop"
    pairs = _pair_lengths(kp)
    spread = float(pairs.max())
    if pairs.min() < max(cfg.min_pair_px, cfg.min_pair_frac * spread):
        return f"collapsed keypoints ({pairs.min():.1f} px of {spread:.1f} px)"
    w, h = frame_size
    margin = cfg.frame_margin * spread
    centre = kp.mean(axis=0)
    if not (-0.5 <= centre[0] <= w - 0.5 and -0.5 <= centre[1] <= h - 0.5):
        return "keypoints centred outside the frame"
    if kp[:, 0].min() < -0.5 - margin or kp[:, 0].max() > w - 0.5 + margin:
        return "keypoints too far outside the frame"
    if kp[:, 1].min() < -0.5 - margin or kp[:, 1].max() > h - 0.5 + margin:
        return "keypoints too far outside the frame"
    lo, hi = cfg.spread_in_crop
    if side <= cfg.small_crop_px:
        lo = cfg.small_crop_min_spread
    own = spread / side / detection.spread_scale  # the network's own answer, before calibration
    if not lo <= own <= hi:
        return f"keypoint spread {own:.2f} of the crop side is outside [{lo}, {hi}]"
    return None


def check_pose(
    measurement: PoseMeasurement,
    detection: KeypointDetection,
    camera: CameraModel,
    spec: DroneSpec,
    config: PlausibilityConfig | None = None,
) -> str | None:
    """Why the pose of a detection cannot be a drone's (range, depth against spread), or None."""
    cfg = config or PlausibilityConfig()
    t = np.asarray(measurement.t, dtype=np.float64)
    distance = float(np.linalg.norm(t))
    lo, hi = cfg.range_m
    if not (t[2] > 0 and lo <= distance <= hi):
        return f"range {distance:.1f} m outside [{lo}, {hi}] m"
    spread_px = float(_pair_lengths(np.asarray(detection.keypoints_px, dtype=np.float64)).max())
    hubs = np.asarray(spec.keypoints_3d, dtype=np.float64)
    longest_m = float(_pair_lengths(hubs).max())
    implied = 0.5 * (camera.fx + camera.fy) * longest_m / max(spread_px, 1e-6)
    lo, hi = cfg.depth_ratio
    if not lo <= distance / implied <= hi:
        return f"range {distance:.1f} m disagrees with the keypoint spread ({implied:.1f} m)"
    return None
