"""Data passed along the frame flow of docs/design.md §3: Source -> Localizer -> KeypointModel ->
PoseEstimator -> Tracker -> Sinks. Plain dataclasses with units and frames in the field docs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from dronekey.frame_image import FrameImage, as_frame_image

__all__ = [
    "PUBLISHED_STATUSES",
    "Frame",
    "KeypointDetection",
    "PoseMeasurement",
    "PoseRejection",
    "RejectionCode",
    "Track",
    "TrackStatus",
]


@dataclass(frozen=True, slots=True)
class Frame:
    """One decoded image.

    index : frame number from the source, starting at 0.
    t_ns : capture time in integer nanoseconds (Unix epoch for live sources, stream PTS for files).
    image : the pixels (``dronekey.frame_image``): the decoder's YUV planes, converted to colour
        only where a stage needs it, or an (H, W, 3) uint8 BGR array (wrapped on construction).
    """

    index: int
    t_ns: int
    image: FrameImage

    def __post_init__(self) -> None:
        object.__setattr__(self, "image", as_frame_image(self.image))

    @property
    def bgr(self) -> np.ndarray:
        """The whole frame, (H, W, 3) uint8 BGR, read-only (converted on first use)."""
        return self.image.bgr()

    @property
    def size(self) -> tuple[int, int]:
        """(width, height), px."""
        return self.image.size


@dataclass(frozen=True, slots=True)
class KeypointDetection:
    """The keypoint model's answer for one crop, mapped back to full-frame pixels.

    keypoints_px : (4, 2) float, pixel coordinates in keypoint order (origin at the centre of the
        top-left pixel).
    presence : probability in [0, 1] that the crop holds a drone.
    roi : (x0, y0, side) of the square crop in full-frame pixels: column and row of its top-left
        pixel and its side, integers (see ``dronekey.geometry.crop``).
    heading_p : probability in [0.5, 1] the network gives to ``keypoints_px`` being in the spec's
        order rather than its 180-degree twin (front and back exchanged); NaN for a model without a
        front/back head. ``heading_confidence`` is 2 p - 1: 0 a coin flip, 1 certain.
    spread_scale : the factor by which the model's spread calibration scaled the keypoints about
        their centroid (``dronekey.perception.spread_calibration``; 1: none), so the network's own
        spread is the keypoints' over ``spread_scale``.
    drone_p : probability in [0, 1] the drone verifier gives to the crop holding a drone
        (``dronekey.perception.drone_verifier``); NaN without a verifier.
    """

    keypoints_px: np.ndarray
    presence: float
    roi: tuple[int, int, int]
    heading_p: float = float("nan")
    spread_scale: float = 1.0
    drone_p: float = float("nan")

    @property
    def heading_confidence(self) -> float:
        """How sure the network is of the front/back order, in [0, 1] (NaN: no front/back head)."""
        return 2.0 * self.heading_p - 1.0


@dataclass(frozen=True, slots=True)
class PoseMeasurement:
    """One 6DoF pose from the keypoints of one frame: ``p_cam = R @ p_body + t``.

    R : (3, 3) body -> camera rotation.
    t : (3,) body origin in the camera frame, metres.
    reprojection_px : RMS reprojection error of the keypoints, pixels.
    covariance : (6, 6) measurement covariance of [t (m), rotation vector (rad)] in the camera frame.
    alternative : the other IPPE solution as (R, t, reprojection_px), or None.
    method : "ippe" or "paper".
    keypoint_sigma_px : keypoint noise (px, per coordinate) that ``covariance`` assumes; lets the
        tracker turn the two solutions' reprojection errors into a likelihood ratio. NaN if unknown.
    """

    R: np.ndarray
    t: np.ndarray
    reprojection_px: float
    covariance: np.ndarray
    alternative: tuple[np.ndarray, np.ndarray, float] | None = None
    method: str = "ippe"
    keypoint_sigma_px: float = float("nan")


class RejectionCode(StrEnum):
    """Machine-readable class of a pose rejection (for counters and logs)."""

    BAD_SHAPE = "bad_shape"
    NON_FINITE = "non_finite"
    OUTSIDE_FRAME = "outside_frame"
    DUPLICATE = "duplicate"
    COLLINEAR = "collinear"
    CROSSED = "crossed"
    SOLVER_FAILED = "solver_failed"
    BEHIND_CAMERA = "behind_camera"
    UNOBSERVABLE = "unobservable"
    REPROJECTION = "reprojection"


@dataclass(frozen=True, slots=True)
class PoseRejection:
    """No pose for these keypoints (the pose estimator's other answer).

    code : the class of problem, stable for counting.
    reason : a sentence for people, with the offending values.
    """

    code: RejectionCode
    reason: str

    def __bool__(self) -> bool:  # lets callers write ``if not result: ...``
        return False


class TrackStatus(StrEnum):
    """Lifecycle of a track: tentative until confirmed by enough hits, coasting while predicted
    without measurements, lost when it has coasted for too long (its last update)."""

    TENTATIVE = "tentative"
    CONFIRMED = "confirmed"
    COASTING = "coasting"
    LOST = "lost"


# What ground stations are sent (MAVLink, SBS-1) and what the evaluation scores as the filtered
# estimate: tentative tracks are not yet confirmed (false alarms on a map are worse than a short
# delay); a lost track's last update says it is gone, and nothing new about where it is.
PUBLISHED_STATUSES = frozenset({TrackStatus.CONFIRMED, TrackStatus.COASTING})


@dataclass(slots=True)
class Track:
    """A filtered drone track at time ``t_ns`` (what the sinks publish).

    position_m, velocity_mps : (3,) camera frame (OpenCV: x right, y down, z forward).
    position_cov : (3, 3) covariance of position_m, m^2.
    quaternion_wxyz : (4,) body -> camera rotation, w >= 0.
    rotation_std_rad : (3,) standard deviation of the orientation (rotation vector components).
    keypoints_px : (4, 2) last measured keypoints in full-frame pixels, or None while coasting and on
        a frame between measured ones (the pipeline's measurement stride, nothing measured there).
    score : presence score of the last measurement in [0, 1].
    reprojection_px : RMS reprojection error of the last measurement, pixels.
    heading_confidence : how sure the track is that its front is the drone's front and not the back
        (the 180-degree twin about the body's vertical axis), in [0, 1]: 0 no idea, 1 certain; NaN
        when the model has no front/back head. ``rotation_std_rad`` and the orientation covariance
        already include the doubt (up to pi / 2 rad of yaw while it is a coin flip).
    """

    track_id: int
    t_ns: int
    status: TrackStatus
    position_m: np.ndarray
    velocity_mps: np.ndarray
    position_cov: np.ndarray
    quaternion_wxyz: np.ndarray
    rotation_std_rad: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    keypoints_px: np.ndarray | None = None
    score: float = 0.0
    reprojection_px: float = float("nan")
    hits: int = 0
    age_s: float = 0.0
    heading_confidence: float = float("nan")
