"""One track inside the tracker: its two filters, lifecycle counters and evidence.

Internal to :mod:`dronekey.tracking`: :class:`~dronekey.tracking.tracker.Tracker` owns the records
and publishes them as :class:`~dronekey.types.Track` (``TrackRecord.to_track``). The front/back
log-odds live here (``heading_log_odds``); how measurements move them is
:mod:`dronekey.tracking.heading`, and how they move the orientation is
:mod:`dronekey.tracking.orientation_update`.
"""

from __future__ import annotations

import math
from collections import deque
from typing import NamedTuple

import numpy as np

from dronekey.geometry.apparent_size import keypoint_spread
from dronekey.geometry.rotations import matrix_to_quat_wxyz
from dronekey.tracking.keypoint_overlap import KeypointMotion
from dronekey.tracking.orientation_filter import OrientationFilter
from dronekey.tracking.position_filter import ConstantVelocityFilter
from dronekey.tracking.tracker_config import TrackerConfig
from dronekey.types import PoseMeasurement, Track, TrackStatus

__all__ = [
    "NS_PER_S",
    "SURE_LOG_ODDS",
    "HitEvidence",
    "TrackRecord",
    "line_of_sight_variance",
    "size_bound_log_odds",
    "with_range_doubt",
]

NS_PER_S = 1_000_000_000


def _line_of_sight(position_m: np.ndarray) -> tuple[float, np.ndarray]:
    """(range m, unit vector) from the camera to a camera-frame position; range NaN or 0 at the
    camera's centre or for a position that is not finite."""
    position = np.asarray(position_m, dtype=np.float64)
    range_m = float(np.linalg.norm(position))
    return range_m, position / range_m if range_m > 0 else position


def line_of_sight_variance(cov: np.ndarray, position_m: np.ndarray) -> float:
    """Variance (m^2) of a camera-frame position's covariance ``cov`` (3, 3) along the camera's line
    of sight to it, ``position_m`` (m): the range doubt. NaN at the camera's centre."""
    range_m, u = _line_of_sight(position_m)
    if not range_m > 0:
        return float("nan")
    return float(u @ np.asarray(cov, dtype=np.float64) @ u)


def with_range_doubt(cov: np.ndarray, position_m: np.ndarray, scale: float, floor: float) -> np.ndarray:
    """``cov`` (3, 3, m^2) with its standard deviation along the line of sight to ``position_m``
    (camera frame, m) raised to ``max(scale * s, floor * range)``; the other directions unchanged."""
    cov = np.asarray(cov, dtype=np.float64)
    range_m, u = _line_of_sight(position_m)
    if not (range_m > 0 and math.isfinite(range_m) and np.all(np.isfinite(cov))):
        return cov
    var = float(u @ cov @ u)
    wanted = max(scale * math.sqrt(max(var, 0.0)), floor * range_m) ** 2
    return cov + max(wanted - var, 0.0) * np.outer(u, u)


SURE_LOG_ODDS = 2.0 * math.atanh(0.5)  # heading_confidence 0.5: the outputs' "sure"


def size_bound_log_odds(spread_px: float, full_spread_px: float) -> float:
    """The most heading log-odds a drone whose hubs are ``spread_px`` apart may be published with:
    0 up to ``full_spread_px / 2``, rising linearly to ``SURE_LOG_ODDS`` at ``full_spread_px``
    (``TrackerConfig.heading_full_spread_px``) and on at that slope."""
    half = full_spread_px / 2.0
    return max(0.0, SURE_LOG_ODDS * (spread_px - half) / half)


class HitEvidence(NamedTuple):
    """What one hit says about its track being a drone: the confirmation rule's inputs.

    range_m : the measurement's distance from the camera, m (set when the hit is applied).
    presence : the keypoint network's presence score (NaN when unknown).
    change : how much its pixels changed since the previous frame, grey levels (NaN when unknown).
    drone_p : the drone verifier's probability (NaN without a verifier).
    """

    range_m: float
    presence: float
    change: float
    drone_p: float


class TrackRecord:
    """One track's filters and lifecycle counters, born from its first measurement at ``t_ns``."""

    def __init__(
        self,
        track_id: int,
        t_ns: int,
        measurement: PoseMeasurement,
        hit: HitEvidence,
        keypoints_px: np.ndarray | None,
        config: TrackerConfig,
    ) -> None:
        cov = measurement.covariance
        self.track_id = track_id
        self.status = TrackStatus.CONFIRMED if config.confirm_hits <= 1 else TrackStatus.TENTATIVE
        self.born_ns = t_ns
        self.t_ns = t_ns
        self.last_hit_ns = t_ns
        self.hits = 1
        self.frames = 1  # update calls seen, the birth frame included
        self.misses = 0  # update calls since the last hit
        self.still_hits = 0  # hits in a row whose pixels changed less than confirm_min_change
        self.window: deque[bool] = deque([True], maxlen=config.confirm_window)
        self.position = ConstantVelocityFilter(
            measurement.t, cov[:3, :3], config.initial_velocity_std_mps, config.accel_std_mps2
        )
        # orientation, rotation_misses and branch_evidence (log-odds that the IPPE solution not
        # followed is the right one), as a restart sets them
        self.reinitialise_orientation(measurement.R, cov[3:, 3:], config)
        self.score = hit.presence
        self.heading_full_spread_px = config.heading_full_spread_px
        self.spread_px: float | None = None  # the last hit's hub spread (with the size bound), kept on a miss
        self.keypoints_px = keypoints_px
        self.reprojection_px = float(measurement.reprojection_px)
        self.keypoint_motion = KeypointMotion()  # where its keypoints are expected (association)
        self.keypoint_motion.observe(t_ns, keypoints_px)
        self.evidence: deque[HitEvidence] = deque(maxlen=config.confirm_window)  # its latest hits
        self.evidence.append(hit._replace(range_m=float(np.linalg.norm(measurement.t))))
        self.heading_log_odds: float | None = None  # None: no front/back evidence yet (NaN inputs)
        # The look's mean log-odds for the followed front, over the last frames (None: not averaged),
        # and the flight's accumulated log-odds (heading_from_motion), which that mean does not hold
        self.heading_look_log_odds: float | None = None
        self.heading_motion_log_odds = 0.0
        self.heading_cap = config.heading_confidence_cap
        self.heading_look_rate = 1.0 / config.heading_look_frames if config.heading_look_frames > 0 else 0.0

    def add_heading_evidence(self, heading_p: float, weight: float, look: bool = True) -> None:
        """Fold one measurement's probability that its front (turned to this track's) is right;
        ``look`` says it is the front/back classifier's (averaged into ``heading_look_log_odds``),
        not the flight's."""
        if not math.isfinite(heading_p):
            return
        p = min(max(heading_p, 0.02), 0.98)
        evidence = math.log(p / (1 - p))
        prior = self.heading_log_odds or 0.0
        value = prior + weight * evidence
        self.heading_log_odds = max(-self.heading_cap, min(self.heading_cap, value))
        if not look:
            motion = self.heading_motion_log_odds + weight * evidence
            self.heading_motion_log_odds = max(-self.heading_cap, min(self.heading_cap, motion))
        elif self.heading_look_rate > 0:
            mean = self.heading_look_log_odds
            self.heading_look_log_odds = (
                evidence if mean is None else mean + self.heading_look_rate * (evidence - mean)
            )

    def restart_heading(self, heading_p: float) -> None:
        """Forget the front/back evidence (the accumulated, the look's mean and the flight's) and
        start again from ``heading_p`` in full, as a new track does."""
        self.heading_log_odds, self.heading_look_log_odds = None, None
        self.heading_motion_log_odds = 0.0
        self.add_heading_evidence(heading_p, 1.0)

    def turn_heading_around(self) -> None:
        """The followed front becomes the back: every log-odds for it changes sign."""
        if self.heading_log_odds is not None:
            self.heading_log_odds = -self.heading_log_odds
        if self.heading_look_log_odds is not None:
            self.heading_look_log_odds = -self.heading_look_log_odds
        self.heading_motion_log_odds = -self.heading_motion_log_odds

    @property
    def keypoints_px(self) -> np.ndarray | None:
        """The last hit's keypoints (full-frame px); None after a miss."""
        return self._keypoints_px

    @keypoints_px.setter
    def keypoints_px(self, keypoints_px: np.ndarray | None) -> None:
        self._keypoints_px = keypoints_px
        if keypoints_px is not None and self.heading_full_spread_px > 0:
            self.spread_px = keypoint_spread(keypoints_px)

    @property
    def published_heading_log_odds(self) -> float | None:
        """The log-odds the outputs are told: the accumulated ones, but never more than the look's
        recent mean (plus the flight's evidence) says. A drone seen from one side for a long time
        gives the same answer on every frame, right or wrong, so the length of the run must not turn
        a weak answer into a sure one (docs/pose-and-tracking.md, "Front or back"). With
        ``heading_full_spread_px`` the look may say no more than a drone of its size in the image
        can show (``size_bound_log_odds``)."""
        look = math.inf if self.heading_look_log_odds is None else self.heading_look_log_odds
        if self.heading_full_spread_px > 0 and self.spread_px is not None:
            look = min(look, size_bound_log_odds(self.spread_px, self.heading_full_spread_px))
        if self.heading_log_odds is None or look == math.inf:
            return self.heading_log_odds
        return min(self.heading_log_odds, look + self.heading_motion_log_odds)

    @property
    def heading_confidence(self) -> float:
        log_odds = self.published_heading_log_odds
        if log_odds is None:
            return float("nan")
        # 2p - 1 with p = sigmoid(L), the probability that the published front is right. Below 0
        # (L < 0, inside the turn-around hysteresis) the published front is more likely wrong than
        # right: no confidence in it at all, 0, not a negative figure outputs would have to refuse.
        return max(0.0, math.tanh(log_odds / 2))

    def predict_to(self, t_ns: int) -> None:
        dt = (t_ns - self.t_ns) / NS_PER_S
        self.position.predict(dt)
        self.orientation.predict(dt)
        self.t_ns = t_ns

    def reinitialise_orientation(
        self, R: np.ndarray, rotation_cov: np.ndarray, config: TrackerConfig
    ) -> None:
        """Restart the orientation filter on ``R`` (body -> camera) with the measurement's rotation
        covariance (rad^2), forgetting the gate misses and the IPPE-solution evidence."""
        self.orientation = OrientationFilter(
            R,
            rotation_cov,
            config.initial_angular_velocity_std_radps,
            config.angular_accel_std_radps2,
            config.angular_velocity_tau_s,
        )
        self.rotation_misses = 0
        self.branch_evidence = 0.0

    def rotation_cov_cam(self) -> np.ndarray:
        """Orientation covariance in the camera frame, with the front/back doubt about the body's
        vertical axis (the two-point mixture's variance q (1 - q) pi^2)."""
        cov = np.array(self.orientation.rotation_cov_cam, dtype=np.float64)
        log_odds = self.published_heading_log_odds
        if log_odds is not None:
            q = 1.0 / (1.0 + math.exp(-log_odds))
            axis = self.orientation.rotation[:, 2]  # body z (down) in the camera frame
            cov = cov + q * (1 - q) * math.pi**2 * np.outer(axis, axis)
        return cov

    def to_track(self, config: TrackerConfig, status: TrackStatus | None = None) -> Track:
        """The published track: the filters' state, the position covariance widened along the line
        of sight (``TrackerConfig.range_std_scale`` / ``range_std_floor``)."""
        R = self.orientation.rotation
        position = self.position.position_m
        return Track(
            track_id=self.track_id,
            t_ns=self.t_ns,
            status=status or self.status,
            position_m=position,
            velocity_mps=self.position.velocity_mps,
            position_cov=with_range_doubt(
                self.position.covariance[:3, :3], position, config.range_std_scale, config.range_std_floor
            ),
            quaternion_wxyz=matrix_to_quat_wxyz(R),
            rotation_std_rad=np.sqrt(np.clip(np.diag(self.rotation_cov_cam()), 0.0, None)),
            keypoints_px=self.keypoints_px,
            score=self.score,
            reprojection_px=self.reprojection_px,
            hits=self.hits,
            age_s=(self.t_ns - self.born_ns) / NS_PER_S,
            heading_confidence=self.heading_confidence,
        )
