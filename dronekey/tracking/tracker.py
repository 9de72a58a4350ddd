"""Multi-target tracker of drone poses: association, gating, filtering and track lifecycle.

One entry point, :meth:`Tracker.update`, called once per frame with that frame's pose
measurements (as norfair's ``Tracker.update``). Each track holds two filters (docs/design.md §3):

- :class:`~dronekey.tracking.position_filter.ConstantVelocityFilter` on position and velocity in the camera
  frame, stepped with the real time between frames (``t_ns`` differences);
- :class:`~dronekey.tracking.orientation_filter.OrientationFilter`, an error-state filter on the body ->
  camera rotation that cannot jump at +-180 deg or at quaternion sign flips.

Measurements are assigned to tracks by gated nearest neighbour: the cost is the squared
Mahalanobis distance of the position innovation, pairs above ``position_gate_chi2`` are forbidden,
and ``scipy.optimize.linear_sum_assignment`` solves the rest.

Orientation and the IPPE ambiguity: of a measurement's two solutions (``R`` and ``alternative``),
the track is updated with the one nearer its own orientation, if it passes ``rotation_gate_chi2``.
Planar PnP cannot always tell the two apart in one frame, and the estimator follows the track's
prediction when it cannot, so a track that started on the wrong solution would stay there. Each
track therefore keeps the log-odds that the solution it does *not* follow is the right one: it
starts at 0 (no preference) and adds, every frame, the log-likelihood ratio
``(SSR_own - SSR_other) / (2 sigma^2)`` (SSR: summed squared reprojection error of the four
keypoints, sigma: the measurement's ``keypoint_sigma_px``). Above ``branch_switch_log_odds`` the
track's orientation is re-initialised on the other solution and the log-odds change sign (the two
swap roles). They are floored at ``-branch_confidence_cap`` so that no amount of agreement makes a
track deaf to later evidence. Frames that cannot tell the solutions apart add nothing.

A rotation that fails the gate with no usable alternative is skipped (the position is still used);
after ``rotation_reset_after`` in a row the orientation is re-initialised from the measurement.

Front and back (the heading twin). Four propeller hubs fit two poses 180 deg apart about the
body's vertical axis equally well; only the drone's look (the network's front/back head,
``heading_p``) or its flight can tell them apart. Each track keeps both hypotheses as the log-odds
``L`` that the front it follows is the drone's front: a measurement is first turned to whichever of
its pose and its twin is nearer the track (its ``heading_p`` with it), then adds
``heading_evidence_weight * logit(heading_p)`` (frames are correlated, so each counts for less than
one independent vote), clipped to ``+-heading_confidence_cap``. When ``L`` falls below
``-heading_switch_log_odds`` the track turns to the twin and ``L`` changes sign. The published
``Track.heading_confidence`` is ``tanh(L / 2) = 2 q - 1`` with ``q = sigmoid(L)`` (0: a coin flip,
1: certain), and the orientation covariance gains the two-point mixture's variance
``q (1 - q) pi^2`` about the body's vertical axis, so a coin flip reads as pi / 2 rad of yaw
doubt, never as a confident heading. Measurements without a heading probability (NaN: a model with
no front/back head) leave ``L`` alone and the confidence unknown (NaN).

Lifecycle: a new track is TENTATIVE; it becomes CONFIRMED after ``confirm_hits`` hits within its
first ``confirm_window`` frames whose evidence agrees: their ranges within a factor
``1 + confirm_range_spread`` of each other (a real drone cannot halve its distance in a sixth of a
second) and their mean presence at least ``confirm_presence``; otherwise it is dropped. Every
measurement has passed the pipeline's plausibility gate (``dronekey.perception.plausibility``) before it gets
here, and a frame may bring several: each unmatched one starts its own tentative hypothesis, so a
false candidate cannot block the true one, and only the hypotheses whose evidence holds confirm.
A confirmed track without a measurement is COASTING (predicted); one that has coasted longer than
``max_coast_s`` is reported once as LOST and dropped. Every track that was reported ends with
exactly one LOST report.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

import numpy as np
from scipy.optimize import linear_sum_assignment

from dronekey.geometry.rotations import matrix_to_quat_wxyz
from dronekey.tracking.orientation_filter import OrientationFilter
from dronekey.tracking.position_filter import ConstantVelocityFilter
from dronekey.types import PoseMeasurement, Track, TrackStatus

__all__ = ["TrackPrediction", "TrackState", "Tracker", "TrackerConfig", "twin_measurement", "twin_of"]

log = logging.getLogger(__name__)

_NS_PER_S = 1_000_000_000
_FORBIDDEN = 1e12  # assignment cost of a gated-out pair


_MAY_BE_ZERO = frozenset({"heading_from_motion"})


@dataclass(frozen=True)
class TrackerConfig:
    """Thresholds and noise levels of :class:`Tracker`; every field is checked on construction.

    Attributes
    ----------
    accel_std_mps2 : standard deviation of the white acceleration of the position model (m/s^2).
    angular_accel_std_radps2 : the same for the orientation model (rad/s^2).
    initial_velocity_std_mps : prior standard deviation of a new track's velocity (m/s).
    initial_angular_velocity_std_radps : the same for its angular velocity (rad/s).
    position_gate_chi2 : a measurement whose squared Mahalanobis position distance to a track
        exceeds this cannot update it (chi-square, 3 dof; 16.27 keeps 99.9 % of true measurements).
    rotation_gate_chi2 : the same for the rotation innovation.
    rotation_reset_after : after this many consecutive gated-out rotations of an updated track, the
        orientation is re-initialised from the measurement (the track had locked onto a wrong one).
    branch_switch_log_odds : log-odds in favour of the IPPE solution a track does not follow at
        which it switches to it (2: odds of about 7 to 1; the hysteresis between switching and
        switching back is twice this).
    branch_confidence_cap : floor on those log-odds, as a positive number: the most a track can
        be sure of its solution (7: about 1000 to 1).
    confirm_hits, confirm_window : a track is confirmed after ``confirm_hits`` hits within its first
        ``confirm_window`` frames (update calls); otherwise it is dropped.
    max_coast_s : a track without a measurement for longer than this (seconds) is lost.
    max_tracks : live tracks at most; measurements that would start more are ignored.
    confirm_range_spread : the confirming hits' largest range over their smallest, minus one.
    confirm_presence : their mean presence score at least this (NaN scores are not counted).
    heading_evidence_weight : weight of one frame's front/back log-odds.
    heading_switch_log_odds : log-odds against the followed front at which a track turns around.
    heading_confidence_cap : the most log-odds a track can gather either way (7: about 1000 to 1).
    heading_from_motion : log-odds per frame given to "the nose points where the drone flies"
        (multirotors mostly fly nose-first): ``w cos(nose, horizontal velocity) min(1, speed / 2
        m/s)``, the horizontal plane taken as the one normal to the drone's own vertical axis. 0
        (default) turns it off: a drone that crabs sideways or flies backwards (a scripted camera
        drone, the Tab. I sequences) would be read the wrong way round.
    """

    accel_std_mps2: float = 4.0
    angular_accel_std_radps2: float = 8.0
    initial_velocity_std_mps: float = 3.0
    initial_angular_velocity_std_radps: float = 2.0
    position_gate_chi2: float = 16.27
    rotation_gate_chi2: float = 16.27
    rotation_reset_after: int = 5
    branch_switch_log_odds: float = 2.0
    branch_confidence_cap: float = 7.0
    confirm_hits: int = 3
    confirm_window: int = 5
    max_coast_s: float = 1.0
    max_tracks: int = 4
    confirm_range_spread: float = 0.5
    confirm_presence: float = 0.6
    heading_evidence_weight: float = 0.3
    heading_switch_log_odds: float = 1.5
    heading_confidence_cap: float = 7.0
    heading_from_motion: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type == "int":
                if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                    raise ValueError(f"TrackerConfig.{f.name} must be an integer >= 1, got {value!r}")
                continue
            lowest_ok = 0.0 if f.name in _MAY_BE_ZERO else math.nextafter(0.0, 1.0)
            if (
                isinstance(value, bool)
                or not isinstance(value, int | float | np.number)
                or not math.isfinite(value)
                or value < lowest_ok
            ):
                kind = "non-negative" if f.name in _MAY_BE_ZERO else "positive"
                raise ValueError(f"TrackerConfig.{f.name} must be a {kind} finite number, got {value!r}")
        if self.confirm_window < self.confirm_hits:
            raise ValueError(
                f"TrackerConfig.confirm_window must be >= confirm_hits ({self.confirm_hits}), "
                f"got {self.confirm_window}"
            )


@dataclass(frozen=True, slots=True)
class TrackPrediction:
    """A live track's pose predicted to a future time (the PnP prior and the next crop).

    R : (3, 3) body -> camera rotation; t : (3,) position in the camera frame (m);
    position_cov : (3, 3) m^2; rotation_cov : (3, 3) camera-frame rotation vector, rad^2.
    """

    track_id: int
    status: TrackStatus
    t_ns: int
    R: np.ndarray
    t: np.ndarray
    position_cov: np.ndarray
    rotation_cov: np.ndarray


@dataclass(frozen=True, slots=True)
class TrackState:
    """The full filter state of one track at its last update, for publishing or debugging.

    position_velocity_cov : (6, 6) covariance of [position (m), velocity (m/s)], camera frame.
    angular_velocity_radps : (3,) camera frame.
    orientation_cov : (6, 6) covariance of [rotation vector (rad), angular velocity (rad/s)],
        camera frame.
    """

    track_id: int
    status: TrackStatus
    t_ns: int
    position_m: np.ndarray
    velocity_mps: np.ndarray
    position_velocity_cov: np.ndarray
    R: np.ndarray
    angular_velocity_radps: np.ndarray
    orientation_cov: np.ndarray


class _TrackRecord:
    """One track's filters and lifecycle counters (internal to :class:`Tracker`)."""

    def __init__(
        self,
        track_id: int,
        t_ns: int,
        measurement: PoseMeasurement,
        score: float,
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
        self.window: deque[bool] = deque([True], maxlen=config.confirm_window)
        self.rotation_misses = 0
        self.branch_evidence = 0.0  # log-odds that the IPPE solution not followed is the right one
        self.position = ConstantVelocityFilter(
            measurement.t, cov[:3, :3], config.initial_velocity_std_mps, config.accel_std_mps2
        )
        self.orientation = OrientationFilter(
            measurement.R,
            cov[3:, 3:],
            config.initial_angular_velocity_std_radps,
            config.angular_accel_std_radps2,
        )
        self.score = score
        self.keypoints_px = keypoints_px
        self.reprojection_px = float(measurement.reprojection_px)
        self.evidence: deque[tuple[float, float]] = deque(maxlen=config.confirm_window)  # (range, score)
        self.evidence.append((float(np.linalg.norm(measurement.t)), score))
        self.heading_log_odds: float | None = None  # None: no front/back evidence yet (NaN inputs)
        self.heading_cap = config.heading_confidence_cap

    def add_heading_evidence(self, heading_p: float, weight: float) -> None:
        """Fold one measurement's probability that its front (turned to this track's) is right."""
        if not math.isfinite(heading_p):
            return
        p = min(max(heading_p, 0.02), 0.98)
        prior = self.heading_log_odds or 0.0
        value = prior + weight * math.log(p / (1 - p))
        self.heading_log_odds = max(-self.heading_cap, min(self.heading_cap, value))

    @property
    def heading_confidence(self) -> float:
        if self.heading_log_odds is None:
            return float("nan")
        # 2p - 1 with p = sigmoid(L), the probability that the published front is right. Below 0
        # (L < 0, inside the turn-around hysteresis) the published front is more likely wrong than
        # right: no confidence in it at all, 0, not a negative figure outputs would have to refuse.
        return max(0.0, math.tanh(self.heading_log_odds / 2))

    def predict_to(self, t_ns: int) -> None:
        dt = (t_ns - self.t_ns) / _NS_PER_S
        self.position.predict(dt)
        self.orientation.predict(dt)
        self.t_ns = t_ns

    def rotation_cov_cam(self) -> np.ndarray:
        """Orientation covariance in the camera frame, with the front/back doubt about the body's
        vertical axis (the two-point mixture's variance q (1 - q) pi^2)."""
        cov = np.array(self.orientation.rotation_cov_cam, dtype=np.float64)
        if self.heading_log_odds is not None:
            q = 1.0 / (1.0 + math.exp(-self.heading_log_odds))
            axis = self.orientation.rotation[:, 2]  # body z (down) in the camera frame
            cov = cov + q * (1 - q) * math.pi**2 * np.outer(axis, axis)
        return cov

    def to_track(self, status: TrackStatus | None = None) -> Track:
        R = self.orientation.rotation
        return Track(
            track_id=self.track_id,
            t_ns=self.t_ns,
            status=status or self.status,
            position_m=self.position.position_m,
            velocity_mps=self.position.velocity_mps,
            position_cov=self.position.covariance[:3, :3],
            quaternion_wxyz=matrix_to_quat_wxyz(R),
            rotation_std_rad=np.sqrt(np.clip(np.diag(self.rotation_cov_cam()), 0.0, None)),
            keypoints_px=self.keypoints_px,
            score=self.score,
            reprojection_px=self.reprojection_px,
            hits=self.hits,
            age_s=(self.t_ns - self.born_ns) / _NS_PER_S,
            heading_confidence=self.heading_confidence,
        )


class Tracker:
    """Tracks drones over time from per-frame pose measurements.

    Parameters
    ----------
    config : TrackerConfig or None
        Thresholds and noise levels; the defaults suit a small quadcopter seen at 30 fps.
    """

    def __init__(self, config: TrackerConfig | None = None) -> None:
        if config is not None and not isinstance(config, TrackerConfig):
            raise TypeError(f"config must be a TrackerConfig, got {type(config).__name__}")
        self.config = config or TrackerConfig()
        self._tracks: dict[int, _TrackRecord] = {}
        self._next_id = 1
        self._t_ns: int | None = None

    # ------------------------------------------------------------------ public
    def update(
        self,
        t_ns: int,
        measurements: Sequence[PoseMeasurement],
        scores: Sequence[float] | None = None,
        keypoints_px: Sequence[np.ndarray | None] | None = None,
        heading_p: Sequence[float] | None = None,
    ) -> list[Track]:
        """Advance every track to ``t_ns`` and fold in this frame's measurements.

        Parameters
        ----------
        t_ns : int
            Time of the frame, integer nanoseconds; never earlier than the previous call's.
        measurements : sequence of PoseMeasurement
            This frame's poses (any number; usually 0 or 1).
        scores : sequence of float, optional
            Presence score of each measurement, copied to the track it updates (NaN when absent).
        keypoints_px : sequence of (4, 2) arrays or None, optional
            Keypoints each measurement came from, copied to the track it updates.
        heading_p : sequence of float, optional
            Probability that each measurement's front is the drone's front (its keypoints are not
            in the 180-degree twin order); NaN or absent when unknown.

        Returns
        -------
        list of Track
            Every live track (tentative ones included, their status says so) and, once, each track
            lost in this call, ordered by track id.
        """
        measurements = list(measurements)
        for i, m in enumerate(measurements):
            if not isinstance(m, PoseMeasurement):
                raise TypeError(f"measurements[{i}] must be a PoseMeasurement, got {type(m).__name__}")
            if np.shape(m.covariance) != (6, 6) or not np.all(np.isfinite(m.covariance)):
                raise ValueError(
                    f"measurements[{i}].covariance must be a finite 6x6 matrix, "
                    f"got shape {np.shape(m.covariance)}"
                )
        scores = _per_measurement("scores", scores, len(measurements), float("nan"))
        keypoints_px = [
            None if kp is None else np.array(kp, dtype=np.float64)
            for kp in _per_measurement("keypoints_px", keypoints_px, len(measurements), None)
        ]
        heading_p = [
            float(p) for p in _per_measurement("heading_p", heading_p, len(measurements), float("nan"))
        ]
        t_ns = self._check_time(t_ns)

        for track in self._tracks.values():
            track.predict_to(t_ns)
        pairs, unmatched = self._associate(measurements)
        for track_id, j in pairs:
            self._apply(self._tracks[track_id], measurements[j], scores[j], keypoints_px[j], heading_p[j])
        matched = {track_id for track_id, _ in pairs}

        reports: list[Track] = []
        for track in list(self._tracks.values()):
            if track.track_id not in matched:
                self._miss(track)
            if self._is_lost(track):
                if track.status is TrackStatus.TENTATIVE:
                    log.debug("tentative track %d dropped after %d hits", track.track_id, track.hits)
                else:
                    log.info("track %d lost after %d hits", track.track_id, track.hits)
                reports.append(track.to_track(TrackStatus.LOST))
                del self._tracks[track.track_id]
        for j in unmatched:
            if len(self._tracks) >= self.config.max_tracks:
                log.debug("measurement ignored: max_tracks=%d live tracks", self.config.max_tracks)
                continue
            track = _TrackRecord(
                self._next_id, t_ns, measurements[j], scores[j], keypoints_px[j], self.config
            )
            track.add_heading_evidence(heading_p[j], 1.0)  # a new track starts from the network's word
            self._tracks[track.track_id] = track
            self._next_id += 1
        reports.extend(track.to_track() for track in self._tracks.values())
        return sorted(reports, key=lambda tr: tr.track_id)

    def predict(self, t_ns: int) -> list[TrackPrediction]:
        """Each live track's pose predicted to ``t_ns`` (no state changes), for the IPPE prior and
        for placing the next crop."""
        t_ns = self._check_time(t_ns, advance=False)
        out = []
        for track in self._tracks.values():
            dt = (t_ns - track.t_ns) / _NS_PER_S
            x, P = track.position.predicted(dt)
            R, rotation_cov = track.orientation.predicted(dt)
            out.append(TrackPrediction(track.track_id, track.status, t_ns, R, x[:3], P[:3, :3], rotation_cov))
        return out

    def state(self, track_id: int) -> TrackState:
        """Full filter state (means and covariances) of a live track at its last update."""
        if track_id not in self._tracks:
            raise KeyError(f"no live track with track_id={track_id}; live: {sorted(self._tracks)}")
        track = self._tracks[track_id]
        R = track.orientation.rotation
        rot = np.zeros((6, 6))
        rot[:3, :3] = rot[3:, 3:] = R
        return TrackState(
            track_id=track_id,
            status=track.status,
            t_ns=track.t_ns,
            position_m=track.position.position_m,
            velocity_mps=track.position.velocity_mps,
            position_velocity_cov=track.position.covariance,
            R=R,
            angular_velocity_radps=R @ track.orientation.angular_velocity_body_radps,
            orientation_cov=rot @ track.orientation.covariance_body @ rot.T,
        )

    @property
    def track_ids(self) -> list[int]:
        """Ids of the live tracks."""
        return sorted(self._tracks)

    def reset(self) -> list[Track]:
        """Drop every track (e.g. when a source restarts its clock); returns their LOST reports."""
        reports = [track.to_track(TrackStatus.LOST) for track in self._tracks.values()]
        self._tracks.clear()
        self._t_ns = None
        return sorted(reports, key=lambda tr: tr.track_id)

    # ------------------------------------------------------------------ steps
    def _check_time(self, t_ns: int, advance: bool = True) -> int:
        if isinstance(t_ns, bool) or not isinstance(t_ns, int | np.integer):
            raise TypeError(f"t_ns must be an integer number of nanoseconds, got {t_ns!r}")
        t_ns = int(t_ns)
        if self._t_ns is not None and t_ns < self._t_ns:
            raise ValueError(
                f"t_ns={t_ns} is earlier than the previous update's t_ns={self._t_ns}; "
                "call Tracker.reset() when a source restarts its clock"
            )
        if advance:
            self._t_ns = t_ns
        return t_ns

    def _associate(self, measurements: list[PoseMeasurement]) -> tuple[list[tuple[int, int]], list[int]]:
        """Gated nearest-neighbour assignment on the position innovation's Mahalanobis distance."""
        ids = list(self._tracks)
        if not ids or not measurements:
            return [], list(range(len(measurements)))
        cost = np.full((len(ids), len(measurements)), _FORBIDDEN)
        for i, track_id in enumerate(ids):
            filt = self._tracks[track_id].position
            for j, m in enumerate(measurements):
                d2 = filt.mahalanobis_sq(m.t, m.covariance[:3, :3])
                if d2 <= self.config.position_gate_chi2:
                    cost[i, j] = d2
                else:
                    log.debug("track %d: measurement %d gated out (d2 = %.1f)", track_id, j, d2)
        rows, cols = linear_sum_assignment(cost)
        pairs = [(ids[i], int(j)) for i, j in zip(rows, cols, strict=True) if cost[i, j] < _FORBIDDEN]
        used = {j for _, j in pairs}
        return pairs, [j for j in range(len(measurements)) if j not in used]

    def _apply(
        self,
        track: _TrackRecord,
        m: PoseMeasurement,
        score: float,
        keypoints_px: np.ndarray | None,
        heading_p: float = float("nan"),
    ) -> None:
        cfg = self.config
        track.position.update(m.t, m.covariance[:3, :3])
        m, heading_p = self._update_heading(track, m, heading_p)
        self._update_orientation(track, m)
        track.evidence.append((float(np.linalg.norm(m.t)), score))
        track.hits += 1
        track.frames += 1
        track.window.append(True)
        track.last_hit_ns = track.t_ns
        track.score = score
        track.keypoints_px = keypoints_px
        track.reprojection_px = float(m.reprojection_px)
        if track.status is TrackStatus.TENTATIVE:
            if sum(track.window) >= cfg.confirm_hits and self._evidence_agrees(track):
                track.status = TrackStatus.CONFIRMED
                log.info("track %d confirmed", track.track_id)
        else:
            track.status = TrackStatus.CONFIRMED

    def _evidence_agrees(self, track: _TrackRecord) -> bool:
        """The confirmation rule's consistency: ranges within a factor, presence high enough."""
        cfg = self.config
        ranges = [r for r, _ in track.evidence]
        scores = [sc for _, sc in track.evidence if math.isfinite(sc)]
        if max(ranges) > (1.0 + cfg.confirm_range_spread) * min(ranges):
            log.debug(
                "track %d: ranges %.1f-%.1f m disagree; not confirmed",
                track.track_id,
                min(ranges),
                max(ranges),
            )
            return False
        if scores and float(np.mean(scores)) < cfg.confirm_presence:
            log.debug("track %d: mean presence %.2f too low; not confirmed", track.track_id, np.mean(scores))
            return False
        return True

    def _update_heading(
        self, track: _TrackRecord, m: PoseMeasurement, heading_p: float
    ) -> tuple[PoseMeasurement, float]:
        """Turn ``m`` to the track's front (or its twin, whichever is nearer the track), fold its
        front/back evidence, and turn the track around when the evidence says its front is the back.
        Returns the measurement as the track should use it."""
        cfg = self.config
        R_track = track.orientation.rotation
        if not math.isfinite(heading_p):  # no front/back head: the order is the network's, as it is
            return m, heading_p
        if _angle(R_track, twin_of(m.R)) < _angle(R_track, m.R):
            m = twin_measurement(m)
            heading_p = 1.0 - heading_p
        track.add_heading_evidence(heading_p, cfg.heading_evidence_weight)
        if cfg.heading_from_motion > 0:
            track.add_heading_evidence(_nose_first_p(R_track, track.position.velocity_mps, cfg), 1.0)
        if track.heading_log_odds is not None and track.heading_log_odds < -cfg.heading_switch_log_odds:
            log.info(
                "track %d: turned around (front/back log-odds %.1f)", track.track_id, track.heading_log_odds
            )
            self._reinitialise_orientation(track, twin_of(R_track), m.covariance[3:, 3:])
            track.heading_log_odds = -track.heading_log_odds
            m = twin_measurement(m)
        return m, heading_p

    def _update_orientation(self, track: _TrackRecord, m: PoseMeasurement) -> None:
        cfg = self.config
        rot_cov = m.covariance[3:, 3:]
        branches = [(m.R, m.reprojection_px)]
        if m.alternative is not None:
            branches.append((m.alternative[0], m.alternative[2]))
        d2 = [track.orientation.mahalanobis_sq(R, rot_cov) for R, _ in branches]
        own = int(np.argmin(d2))
        if len(branches) == 2 and math.isfinite(m.keypoint_sigma_px) and m.keypoint_sigma_px > 0:
            other_R, other_px = branches[1 - own]
            log_odds = 2.0 * (branches[own][1] ** 2 - other_px**2) / m.keypoint_sigma_px**2
            track.branch_evidence = max(-cfg.branch_confidence_cap, track.branch_evidence + log_odds)
            if track.branch_evidence > cfg.branch_switch_log_odds:
                evidence = track.branch_evidence
                log.info(
                    "track %d: switched to the other IPPE solution (evidence %.1f)",
                    track.track_id,
                    track.branch_evidence,
                )
                self._reinitialise_orientation(track, other_R, rot_cov)
                track.branch_evidence = -evidence  # own and other swap roles
                return
        if d2[own] <= cfg.rotation_gate_chi2:
            track.orientation.update(branches[own][0], rot_cov)
            track.rotation_misses = 0
            return
        track.rotation_misses += 1
        log.debug("track %d: rotation gated out (d2 = %.1f)", track.track_id, d2[own])
        if track.rotation_misses >= cfg.rotation_reset_after:
            log.info(
                "track %d: orientation re-initialised after %d gated-out rotations",
                track.track_id,
                track.rotation_misses,
            )
            self._reinitialise_orientation(track, m.R, rot_cov)

    def _reinitialise_orientation(self, track: _TrackRecord, R: np.ndarray, rotation_cov: np.ndarray) -> None:
        cfg = self.config
        track.orientation = OrientationFilter(
            R, rotation_cov, cfg.initial_angular_velocity_std_radps, cfg.angular_accel_std_radps2
        )
        track.rotation_misses = 0
        track.branch_evidence = 0.0

    def _miss(self, track: _TrackRecord) -> None:
        track.frames += 1
        track.window.append(False)
        track.keypoints_px = None
        if track.status is TrackStatus.CONFIRMED:
            track.status = TrackStatus.COASTING

    def _is_lost(self, track: _TrackRecord) -> bool:
        if track.t_ns - track.last_hit_ns > self.config.max_coast_s * _NS_PER_S:
            return True
        return track.status is TrackStatus.TENTATIVE and track.frames >= self.config.confirm_window


_HALF_TURN_Z = np.diag([-1.0, -1.0, 1.0])  # 180 deg about the body's z axis


def twin_of(R: np.ndarray) -> np.ndarray:
    """The body -> camera rotation of the heading twin: the same drone turned 180 deg about its
    vertical (FRD z) axis, which maps the hubs 1 2 3 4 onto 3 4 1 2."""
    return np.asarray(R) @ _HALF_TURN_Z


def twin_measurement(m: PoseMeasurement) -> PoseMeasurement:
    """``m`` with its rotation (and the IPPE alternative's) turned to the heading twin."""
    alt = m.alternative
    if alt is not None:
        alt = (twin_of(alt[0]), alt[1], alt[2])
    return replace(m, R=twin_of(m.R), alternative=alt)


def _nose_first_p(R: np.ndarray, velocity: np.ndarray, config: TrackerConfig) -> float:
    """Probability that the followed front is right, from the nose-first prior on the velocity."""
    up = R[:, 2]  # body z (down) in the camera frame: the drone's own vertical
    v = np.asarray(velocity, dtype=np.float64)
    v_h = v - (v @ up) * up
    speed = float(np.linalg.norm(v_h))
    if speed < 1e-6:
        return 0.5
    log_odds = config.heading_from_motion * float(R[:, 0] @ v_h / speed) * min(1.0, speed / 2.0)
    return 1.0 / (1.0 + math.exp(-log_odds))


def _angle(A: np.ndarray, B: np.ndarray) -> float:
    """Rotation angle (rad) between two rotation matrices."""
    c = (np.trace(np.asarray(A).T @ np.asarray(B)) - 1.0) / 2.0
    return math.acos(min(1.0, max(-1.0, c)))


def _per_measurement(name: str, values, n: int, default) -> list:
    if values is None:
        return [default] * n
    values = list(values)
    if len(values) != n:
        raise ValueError(f"{name} must have one entry per measurement ({n}), got {len(values)}")
    return values
