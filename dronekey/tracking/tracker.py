"""Multi-target tracker of drone poses: association, gating, filtering and track lifecycle.

One entry point, :meth:`Tracker.update`, called once per frame with that frame's pose
measurements (as norfair's ``Tracker.update``). Each track holds two filters (docs/design.md §3):

- :class:`~dronekey.tracking.position_filter.ConstantVelocityFilter` on position and velocity in the camera
  frame, stepped with the real time between frames (``t_ns`` differences);
- :class:`~dronekey.tracking.orientation_filter.OrientationFilter`, an error-state filter on the body ->
  camera rotation that cannot jump at +-180 deg or at quaternion sign flips.

Association is global, one measurement per track and one track per measurement:
``scipy.optimize.linear_sum_assignment`` (the Hungarian algorithm) on the cost
``d^2 + keypoint_overlap_weight * (1 - IoU)``, where ``d^2`` is the squared Mahalanobis distance of
the position innovation (the filter's predicted covariance plus the measurement's) and IoU that of
the measurement's keypoint box with the track's expected one
(:mod:`dronekey.tracking.keypoint_overlap`). Pairs with ``d^2`` above ``position_gate_chi2`` are
forbidden; the keypoint term only ranks. A coasting track's covariance grows with its coast, so a
drone that reappears near its prediction re-attaches to it and keeps its id.

Orientation: of a measurement's two IPPE solutions the track follows the one nearer its own
orientation, and keeps the log-odds that the other is right, switching when they say so
(:mod:`dronekey.tracking.orientation_update`). Front and back: the track keeps the log-odds that
the front it follows is the drone's front, from the network's front/back head, and turns around
when they say it is the back (:mod:`dronekey.tracking.heading`).

Lifecycle: a new track is TENTATIVE; it becomes CONFIRMED after ``confirm_hits`` hits within its
first ``confirm_window`` frames whose evidence agrees: their ranges within a factor
``1 + confirm_range_spread`` of each other (a real drone cannot halve its distance in a sixth of a
second), their mean presence at least ``confirm_presence``, and every one of them a change of
the pixels since the previous frame (``confirm_min_change``: a drone in flight moves and spins
its propellers, clutter in front of a fixed camera does not), and, with a drone verifier, their
mean drone probability at least ``confirm_drone_p``; otherwise it is dropped. Every
measurement has passed the pipeline's plausibility gate (``dronekey.perception.plausibility``) before it gets
here, and a frame may bring several: each unmatched one starts its own tentative hypothesis, so a
false candidate cannot block the true one, and only the hypotheses whose evidence holds confirm.
A confirmed track without a measurement is COASTING (predicted). One that has coasted longer than
``max_coast_s``, or for more than ``coast_frames_per_hit`` frames per hit it has had, or whose
last ``max_still_hits`` hits all left its pixels unchanged, is reported once as LOST and dropped.
Every track that was reported ends with exactly one LOST report.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from dronekey.tracking.heading import update_heading
from dronekey.tracking.keypoint_overlap import box_iou, keypoint_box
from dronekey.tracking.orientation_update import update_orientation
from dronekey.tracking.track_record import NS_PER_S, HitEvidence, TrackRecord
from dronekey.tracking.tracker_config import TrackerConfig
from dronekey.types import PoseMeasurement, Track, TrackStatus

__all__ = ["TrackPrediction", "TrackState", "Tracker"]

log = logging.getLogger(__name__)

_FORBIDDEN = 1e12  # assignment cost of a gated-out pair


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
        self._tracks: dict[int, TrackRecord] = {}
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
        changes: Sequence[float] | None = None,
        drone_p: Sequence[float] | None = None,
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
        changes : sequence of float, optional
            How much each measurement's pixels changed since the previous frame
            (``dronekey.perception.frame_change``, grey levels): confirmation evidence; NaN or
            absent when unknown (no previous frame, no images).
        drone_p : sequence of float, optional
            The drone verifier's probability that each measurement is a drone
            (``dronekey.perception.drone_verifier``): confirmation evidence; NaN or absent without
            a verifier.

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
        changes = [float(c) for c in _per_measurement("changes", changes, len(measurements), float("nan"))]
        drone_p = [float(v) for v in _per_measurement("drone_p", drone_p, len(measurements), float("nan"))]
        hits = [HitEvidence(math.nan, *e) for e in zip(scores, changes, drone_p, strict=True)]
        t_ns = self._check_time(t_ns)

        for track in self._tracks.values():
            track.predict_to(t_ns)
        pairs, unmatched = self._associate(t_ns, measurements, keypoints_px)
        for track_id, j in pairs:
            track = self._tracks[track_id]
            self._apply(track, measurements[j], hits[j], keypoints_px[j], heading_p[j])
        matched = dict(pairs)  # track id -> its measurement's index
        dropped = self._merge_duplicates(t_ns, matched, measurements, hits, keypoints_px, heading_p)

        reports: list[Track] = [track.to_track(self.config, TrackStatus.LOST) for track in dropped]
        for track in list(self._tracks.values()):
            if track.track_id not in matched:
                self._miss(track)
            if self._is_lost(track):
                if track.status is TrackStatus.TENTATIVE:
                    log.debug("tentative track %d dropped after %d hits", track.track_id, track.hits)
                else:
                    log.info("track %d lost after %d hits", track.track_id, track.hits)
                reports.append(track.to_track(self.config, TrackStatus.LOST))
                del self._tracks[track.track_id]
        for j in unmatched:
            if len(self._tracks) >= self.config.max_tracks:
                log.debug("measurement ignored: max_tracks=%d live tracks", self.config.max_tracks)
                continue
            track = TrackRecord(self._next_id, t_ns, measurements[j], hits[j], keypoints_px[j], self.config)
            track.add_heading_evidence(heading_p[j], 1.0)  # a new track starts from the network's word
            self._tracks[track.track_id] = track
            self._next_id += 1
        reports.extend(track.to_track(self.config) for track in self._tracks.values())
        return sorted(reports, key=lambda tr: tr.track_id)

    def advance(self, t_ns: int) -> list[Track]:
        """Advance every track to ``t_ns`` on a frame that was not measured (the pipeline's
        measurement stride, ``TrackingPipeline(measure_every=...)``): each is predicted and reported,
        with neither a hit nor a miss counted, so its lifecycle runs on the measured frames alone.
        The reports carry no keypoints (``Track.keypoints_px`` None: nothing was measured); the
        track keeps its last ones for the next measured frame's association.

        Returns
        -------
        list of Track
            Every live track, ordered by track id.
        """
        t_ns = self._check_time(t_ns)
        reports = []
        for track in self._tracks.values():
            track.predict_to(t_ns)
            report = track.to_track(self.config)
            report.keypoints_px = None
            reports.append(report)
        return sorted(reports, key=lambda tr: tr.track_id)

    def all_confirmed(self, min_score: float = 0.0) -> bool:
        """Whether a track is live and every live one is confirmed (none tentative or coasting),
        its last hit's presence score not below ``min_score`` (a score that is unknown, NaN, is not)."""
        return bool(self._tracks) and all(
            t.status is TrackStatus.CONFIRMED and not t.score < min_score for t in self._tracks.values()
        )

    def predict(self, t_ns: int) -> list[TrackPrediction]:
        """Each live track's pose predicted to ``t_ns`` (no state changes), for the IPPE prior and
        for placing the next crop."""
        t_ns = self._check_time(t_ns, advance=False)
        out = []
        for track in self._tracks.values():
            dt = (t_ns - track.t_ns) / NS_PER_S
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
        reports = [track.to_track(self.config, TrackStatus.LOST) for track in self._tracks.values()]
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

    def _associate(
        self, t_ns: int, measurements: list[PoseMeasurement], keypoints_px: list[np.ndarray | None]
    ) -> tuple[list[tuple[int, int]], list[int]]:
        """Global assignment (Hungarian) on the gated cost d^2 + w (1 - keypoint IoU)."""
        ids = list(self._tracks)
        if not ids or not measurements:
            return [], list(range(len(measurements)))
        weight = self.config.keypoint_overlap_weight
        boxes = [keypoint_box(kp) for kp in keypoints_px]
        cost = np.full((len(ids), len(measurements)), _FORBIDDEN)
        for i, track_id in enumerate(ids):
            track = self._tracks[track_id]
            expected = track.keypoint_motion.predicted_box(t_ns)
            for j, m in enumerate(measurements):
                d2 = track.position.mahalanobis_sq(m.t, m.covariance[:3, :3])
                if d2 <= self.config.position_gate_chi2:
                    cost[i, j] = d2 + weight * (1.0 - box_iou(expected, boxes[j]))
                else:
                    log.debug("track %d: measurement %d gated out (d2 = %.1f)", track_id, j, d2)
        rows, cols = linear_sum_assignment(cost)
        pairs = [(ids[i], int(j)) for i, j in zip(rows, cols, strict=True) if cost[i, j] < _FORBIDDEN]
        used = {j for _, j in pairs}
        return pairs, [j for j in range(len(measurements)) if j not in used]

    def _merge_duplicates(
        self, t_ns: int, matched: dict[int, int], measurements, hits, keypoints_px, heading_p
    ) -> list[TrackRecord]:
        """Drop each duplicate (``_duplicates``) of a measured track; the older of the two (more
        hits) keeps its id and history, and takes this frame's measurement if it was the other's.
        Returns the dropped tracks (``matched`` is updated)."""
        dropped = []
        for duplicate_id, measured_id in self._duplicates(t_ns, set(matched)).items():
            if duplicate_id not in self._tracks or measured_id not in self._tracks:
                continue  # already merged into another
            keep, drop = self._tracks[duplicate_id], self._tracks[measured_id]
            if keep.hits <= drop.hits:
                keep, drop = drop, keep
            else:  # the older track takes the reading
                j = matched.pop(measured_id)
                self._apply(keep, measurements[j], hits[j], keypoints_px[j], heading_p[j])
                matched[keep.track_id] = j
            log.debug("track %d dropped: it follows track %d's drone", drop.track_id, keep.track_id)
            matched.pop(drop.track_id, None)
            dropped.append(self._tracks.pop(drop.track_id))
        return dropped

    def _duplicates(self, t_ns: int, matched: set[int]) -> dict[int, int]:
        """Tracks without a measurement this frame that follow the drone of a track with one
        (``TrackerConfig.merge_min_iou``, ``merge_range_ratio``): {duplicate id: measured track id}."""
        cfg = self.config
        measured = [
            (track, float(np.linalg.norm(track.position.position_m)), keypoint_box(track.keypoints_px))
            for track in (self._tracks[i] for i in sorted(matched))
        ]
        out: dict[int, int] = {}
        for track in self._tracks.values():
            expected = track.keypoint_motion.predicted_box(t_ns)
            if track.track_id in matched or expected is None:
                continue
            range_m = float(np.linalg.norm(track.position.position_m))
            for other, other_range_m, other_box in measured:
                if (
                    abs(range_m / other_range_m - 1.0) <= cfg.merge_range_ratio
                    and box_iou(expected, other_box) >= cfg.merge_min_iou
                    and track.position.mahalanobis_sq(
                        other.position.position_m, other.position.covariance[:3, :3]
                    )
                    <= cfg.position_gate_chi2
                ):
                    out[track.track_id] = other.track_id
                    break
        return out

    def _apply(
        self,
        track: TrackRecord,
        m: PoseMeasurement,
        hit: HitEvidence,
        keypoints_px: np.ndarray | None,
        heading_p: float = float("nan"),
    ) -> None:
        cfg = self.config
        track.position.update(m.t, m.covariance[:3, :3])
        m, heading_p = update_heading(track, m, heading_p, cfg)
        if update_orientation(track, m, cfg) and cfg.heading_restart_on_reset:
            track.restart_heading(heading_p)
        track.evidence.append(hit._replace(range_m=float(np.linalg.norm(m.t))))
        change, score = hit.change, hit.presence
        if math.isfinite(change):
            track.still_hits = track.still_hits + 1 if change < cfg.confirm_min_change else 0
        track.hits += 1
        track.frames += 1
        track.misses = 0
        track.window.append(True)
        track.last_hit_ns = track.t_ns
        track.score = score
        track.keypoints_px = keypoints_px
        track.keypoint_motion.observe(track.t_ns, keypoints_px)
        track.reprojection_px = float(m.reprojection_px)
        if track.status is TrackStatus.TENTATIVE:
            if sum(track.window) >= cfg.confirm_hits and self._evidence_agrees(track):
                track.status = TrackStatus.CONFIRMED
                log.info("track %d confirmed", track.track_id)
        else:
            track.status = TrackStatus.CONFIRMED

    def _evidence_agrees(self, track: TrackRecord) -> bool:
        """The confirmation rule's consistency: ranges within a factor, presence high enough, the
        pixels changing, the verifier (where there is one) calling it a drone."""
        cfg = self.config
        hits = _agreeing_hits(list(track.evidence), 1.0 + cfg.confirm_range_spread)
        if len(track.evidence) - len(hits) > cfg.confirm_max_outliers or len(hits) < cfg.confirm_hits:
            ranges = [e.range_m for e in track.evidence]
            log.debug(
                "track %d: ranges %.1f-%.1f m disagree; not confirmed",
                track.track_id,
                min(ranges),
                max(ranges),
            )
            return False
        scores = [e.presence for e in hits if math.isfinite(e.presence)]
        changes = [e.change for e in hits if math.isfinite(e.change)]
        verdicts = [e.drone_p for e in hits if math.isfinite(e.drone_p)]
        if scores and float(np.mean(scores)) < cfg.confirm_presence:
            log.debug("track %d: mean presence %.2f too low; not confirmed", track.track_id, np.mean(scores))
            return False
        if scores and min(scores) < cfg.confirm_min_presence:
            log.debug("track %d: a hit's presence %.2f too low; not confirmed", track.track_id, min(scores))
            return False
        if changes and min(changes) < cfg.confirm_min_change:
            log.debug(
                "track %d: a hit changed %.1f grey levels only; not confirmed", track.track_id, min(changes)
            )
            return False
        if verdicts and float(np.mean(verdicts)) < cfg.confirm_drone_p:
            log.debug(
                "track %d: the verifier's mean drone probability %.2f too low; not confirmed",
                track.track_id,
                np.mean(verdicts),
            )
            return False
        return True

    def _miss(self, track: TrackRecord) -> None:
        track.frames += 1
        track.misses += 1
        track.window.append(False)
        track.keypoints_px = None
        if track.status is TrackStatus.CONFIRMED:
            track.status = TrackStatus.COASTING

    def _is_lost(self, track: TrackRecord) -> bool:
        if track.t_ns - track.last_hit_ns > self.config.max_coast_s * NS_PER_S:
            return True
        if track.misses > self.config.coast_frames_per_hit * track.hits:
            return True
        if track.still_hits >= self.config.max_still_hits:
            log.info("track %d dropped: unchanged for %d hits (clutter)", track.track_id, track.still_hits)
            return True
        return track.status is TrackStatus.TENTATIVE and track.frames >= self.config.confirm_window


def _agreeing_hits(hits: list[HitEvidence], factor: float) -> list[HitEvidence]:
    """The largest set of ``hits`` whose ranges lie within ``factor`` of each other (largest over
    smallest), in their order; of equal sets, the one holding the later hits."""
    by_range = sorted(range(len(hits)), key=lambda k: hits[k].range_m)
    best: list[int] = []
    lo = 0
    for hi in range(len(by_range)):
        while hits[by_range[hi]].range_m > factor * hits[by_range[lo]].range_m:
            lo += 1
        chosen = by_range[lo : hi + 1]
        if len(chosen) > len(best) or (len(chosen) == len(best) and sum(chosen) > sum(best)):
            best = chosen
    return [hits[k] for k in sorted(best)]


def _per_measurement(name: str, values, n: int, default) -> list:
    if values is None:
        return [default] * n
    values = list(values)
    if len(values) != n:
        raise ValueError(f"{name} must have one entry per measurement ({n}), got {len(values)}")
    return values
