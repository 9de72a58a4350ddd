"""The fusion's gates and noise figures (``FusionConfig``)."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["FusionConfig"]


@dataclass(frozen=True)
class FusionConfig:
    """How tracks of several cameras are associated and fused.

    gate_mahalanobis2 : squared Mahalanobis distance between two cameras' positions (their
        covariances summed) under which they may be the same drone; 16.27 is chi-square with 3
        degrees of freedom at 99.9 %.
    gate_ray2 : squared closest-approach distance of the two viewing rays over its variance across
        both rays (chi-square, 1 degree of freedom; 10.83 is 99.9 %): the rays of one drone meet.
    keep_scale : a pair already fused stays fused up to ``keep_scale`` times the gates (hysteresis:
        fused ids do not flap on one noisy frame).
    max_age_s : a camera's track older than this at the fusion time is left out (stale).
    track_expiry_s : a camera's track not updated for this long is forgotten, as if lost (its
        ``lost`` message went missing); its fused track ends when it had no other camera.
    velocity_std_mps : uncertainty of a track's velocity, used to grow its covariance when it is
        predicted to the fusion time (the track message carries no velocity covariance).
    clock_std_s : uncertainty of the cameras' clock alignment, s; grows the covariance by
        ``(|v| clock_std_s)^2`` per axis.
    min_std_m : floor of each position standard deviation, m (a filter's covariance that is too
        confident must not take the fusion over).
    depth_std_frac : floor of a camera's standard deviation along its ray, as a share of the range.
        A single camera's depth comes from the keypoints' spread and is biased by what biases that
        spread (keypoint scale, the drone model's size): on seq13 renders one camera's filtered
        depth was 35 % off while its covariance claimed 2 %. Across the ray the bearing is good.
    bearing_std_rad : floor of a camera's standard deviation across its ray, as an angle.
    depth_memory_s : for this long after a drone was last triangulated, a one-camera estimate
        weighs in that triangulated position, predicted with its velocity (its covariance grown by
        ``velocity_std_mps`` per second): the camera gives the bearing, the memory the depth. On
        the far preset a camera's own depth was 15-30 m off at 110-145 m, a triangulated one
        within a metre, and the second camera saw the drone on half of the frames.
    include_tentative : fuse tentative tracks too (default: confirmed and coasting, what the
        daemon's MAVLink output sends).
    """

    gate_mahalanobis2: float = 16.27
    gate_ray2: float = 10.83
    keep_scale: float = 2.0
    max_age_s: float = 0.5
    track_expiry_s: float = 5.0
    velocity_std_mps: float = 1.0
    clock_std_s: float = 0.01
    min_std_m: float = 0.01
    depth_std_frac: float = 0.3
    bearing_std_rad: float = 0.003
    depth_memory_s: float = 2.0
    include_tentative: bool = False

    def __post_init__(self) -> None:
        for name in ("gate_mahalanobis2", "gate_ray2", "max_age_s", "track_expiry_s", "min_std_m"):
            value = getattr(self, name)
            if not value > 0:
                raise ValueError(f"{name} must be > 0, got {value!r}")
        for name in (
            "velocity_std_mps",
            "clock_std_s",
            "depth_std_frac",
            "bearing_std_rad",
            "depth_memory_s",
        ):
            value = getattr(self, name)
            if not value >= 0:
                raise ValueError(f"{name} must be >= 0, got {value!r}")
        if not self.keep_scale >= 1:
            raise ValueError(f"keep_scale must be >= 1, got {self.keep_scale!r}")
