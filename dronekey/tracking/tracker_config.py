"""The tracker's thresholds and noise levels, checked on construction (docs/pose-and-tracking.md)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

__all__ = ["TrackerConfig"]

_MAY_BE_ZERO = frozenset(
    {
        "angular_velocity_tau_s",
        "confirm_max_outliers",
        "confirm_min_change",
        "confirm_drone_p",
        "heading_from_motion",
        "heading_full_spread_px",
        "heading_look_frames",
        "keypoint_overlap_weight",
        "range_std_floor",
    }
)


@dataclass(frozen=True)
class TrackerConfig:
    """Thresholds and noise levels of :class:`~dronekey.tracking.tracker.Tracker`; every field
    is checked on construction.

    Attributes
    ----------
    accel_std_mps2 : standard deviation of the white acceleration of the position model (m/s^2).
        2 (was 4), chosen with the pipeline's ``keypoint_sigma_px`` 3 on the tuning seeds: a
        steadier range for a small drone whose keypoints are noisy, at the price of some lag on a
        drone that turns hard (docs/evaluation.md, tenth session).
    angular_accel_std_radps2 : the same for the orientation model (rad/s^2).
    angular_velocity_tau_s : time constant (s) with which a track's angular velocity relaxes toward
        zero (``dronekey.tracking.orientation_filter``); 0: constant angular velocity. Near
        edge-on views the keypoints can fit a pose tens of degrees off with a tiny reprojection
        error; a run of such readings winds up the angular velocity, which then turns the track
        (to its heading twin, or 90 deg off) on its own, and on through a coast. Off by default:
        1.0 and 0.5 s were within noise on the tuning seeds (docs/evaluation.md, seventeenth
        session).
    initial_velocity_std_mps : prior standard deviation of a new track's velocity (m/s).
    initial_angular_velocity_std_radps : the same for its angular velocity (rad/s).
    position_gate_chi2 : a measurement whose squared Mahalanobis position distance to a track
        exceeds this cannot update it (chi-square, 3 dof; 16.27 keeps 99.9 % of true measurements).
    rotation_gate_chi2 : the same for the rotation innovation.
    keypoint_overlap_weight : weight of the keypoint term of the association cost, in the same
        units as the squared Mahalanobis distance: cost = d^2 + w (1 - IoU), IoU of the
        measurement's keypoint box with the track's expected one (its last, moved by its image
        velocity). It ranks pairs inside the position gate, it gates nothing: at a crossing the
        boxes overlap, and after a coast the moved box is rough. 4 (a quarter of the gate) settles
        two drones whose 3D gates both hold without overriding a clear 3D preference.
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
    coast_frames_per_hit : and a track coasts at most this many frames per measurement it has had:
        its evidence of being a drone. Clutter that passed confirmation on a few frames was
        published for a whole ``max_coast_s`` after it (on six tuning sequences with photo
        backgrounds, 566 of the 758 frames with a false track were coasts), while a drone tracked
        for seconds keeps the full coast through an occlusion. 4 on the tuning seeds (2 cut the far
        preset's intermittent detections short; docs/evaluation.md).
    max_tracks : live tracks at most (tentative ones included); measurements that would start more
        are ignored. The pipeline searches the frame for more drones (every
        ``search_more_every`` frames) while fewer than this many tracks are confirmed.
    confirm_range_spread : the confirming hits' largest range over their smallest, minus one.
    confirm_max_outliers : the confirming hits are the largest set of the window's hits whose
        ranges agree (above), leaving out at most this many; the checks below are taken over that
        set, which must still hold ``confirm_hits`` hits. 0: every hit of the window must agree.
        A reading gone wrong (a collapsed or quarter-turned order, 1.5-2x off in range) on one
        frame of five then no longer vetoes a drone that the others agree on (s8006 of tuning
        seed 8001: six tracks of one drone born and dropped so in 55 frames). Measured with 1 on
        three tuning sets: detection up half a point, but 8001's false-track frames up 16 % (hits
        that agree at a quarter-turned range confirm too), so 0 stays (docs/evaluation.md).
    confirm_presence : their mean presence score at least this (NaN scores are not counted).
    confirm_min_presence : and every one of them at least this: the network must be sure of each
        confirming detection, not on average. On the tuning seeds the shipped model scored 738 of
        the 739 detections of a drone posed within the range gate at 0.999 or more, and the
        clutter it took for a drone 0.74 (median; 0.94 at the 90th percentile).
    confirm_min_change : and each of them a frame change above its surroundings
        (``dronekey.perception.frame_change``) of at least this many grey levels, where known. On
        the tuning seeds 99.8 % of the drone detections changed by 4 or more above their ring, 72 %
        of the clutter detections less (a wire over a tiled roof had been confirmed at 6.4 m and
        held for 120 frames, presence 1.0). 0 turns the check off (a deployment that must report a
        drone hovering with its propellers stopped).
    confirm_drone_p : with a drone verifier (``dronekey.perception.drone_verifier``), the mean of
        its drone probabilities over those hits at least this; hits without a verdict (NaN) are
        not counted. 0 turns the check off. 0.9: the drone-free tracks confirmed on the tuning
        seeds had means of 0.50-0.87 and a real drone's confirming hits 0.98 (median), 0.86 at
        the 10th percentile; 0.9 took the larger drone-free tuning set from 6 confirmed ids to 0
        and the out-of-gate tracks on drone sequences down by a quarter, for 2.6 points of
        detection (far drones the verifier is less sure of confirm later or not at all;
        docs/evaluation.md).
    max_still_hits : a track whose last this many hits all changed less than
        ``confirm_min_change`` is lost: it is clutter that a moving thing (a wire, a bird) passed
        while it was confirmed. One drone detection in 400 changed less on the tuning seeds; 10 in
        a row (a third of a second at 30 fps) leaves a wide margin.
    merge_min_iou, merge_range_ratio : a track that got no measurement this frame is a duplicate of
        one that did, and is dropped at once instead of coasting (and being published) beside it,
        when its expected keypoint box overlaps the measured track's keypoints by at least
        ``merge_min_iou`` (IoU), its range is within ``merge_range_ratio`` (relative) of the
        measured track's, and the two positions are within the position gate of each other
        (``position_gate_chi2``, both covariances). Two tracks on one drone arise when a crop
        reads a drone another track already holds: the pipeline gives the reading to one of them
        (``dronekey.pipeline``, one reading per drone), and the other used to coast for up to
        ``max_coast_s``, its range drifting on its velocity (a flying object in a drone-free tuning
        sequence held two confirmed tracks for 25 frames). Drones that cross at different ranges
        (one passing in front of the other) differ in range by more than the ratio and keep their
        tracks through the occlusion.
    heading_evidence_weight : weight of one frame's front/back log-odds (after the first, which
        counts in full). 0.05: the front/back classifier's errors come in runs (one drone, one
        view), so a frame is worth little on its own; chosen on the tuning matrix (0.3 / 0.15 /
        0.08 / 0.05 / 0.03 gave 3.85 / 2.72 / 2.00 / 1.46 / 1.50 % confidently wrong frames,
        MAE-angle 18.1 / 17.6 / 15.3 / 15.2 / 15.3 deg; docs/evaluation.md).
    heading_switch_log_odds : log-odds against the followed front at which a track turns around.
    heading_confidence_cap : the most log-odds a track can gather either way (7: about 1000 to 1).
    heading_restart_on_reset : when a track's orientation is re-initialised on a measurement after
        ``rotation_reset_after`` gated-out rotations, its front/back evidence starts again from that
        measurement's word, as a new track's does: the evidence was gathered for the old
        orientation, and the new one is often a quarter or half turn from it (a run of
        quarter-turned orders). Kept, the track published 0.53-0.87 confidence on an attitude
        107-177 deg off (Tab. VI seed 101, seq11, frames 266-280, after a reset at 266). On by
        default since the forty-eighth session: on two realizations of the three tuning sets it
        removed confidently wrong frames (56 -> 50, 61 -> 60 of 16,200), turned one sequence's
        heading right and moved no other figure (docs/evaluation.md).
    heading_look_frames : time constant, frames, of the running mean of the front/back classifier's
        per-frame log-odds; the published confidence never exceeds what that mean says (0: off, the
        accumulated log-odds are published).
    heading_full_spread_px : the published confidence is also bounded by the drone's size in the
        image: its log-odds by ``2 atanh(0.5) (s - S / 2) / (S / 2)``, s the longest distance between
        the last detection's hubs (px), S this field: no confidence at all below ``S / 2``, "sure"
        (0.5) allowed from ``S`` on. The front/back classifier's patch puts the hubs about 43.5 px
        apart (the farthest 0.34 of its 64 px side from the centre); a smaller drone is upsampled
        into it, and at half that size its front is a few blurred pixels. Only what the outputs are
        told changes, not the front a track follows. 0 (default): off. Measured at 43.5 on the
        tuning seeds: no front/back-symmetric drone published sure and wrong (1.94 % of the cue-free
        set's frames before), but a fifth of the sure right headings gone with it, those of far
        drones the classifier reads right (docs/evaluation.md, twenty-seventh session).
    heading_from_motion : log-odds per frame given to "the nose points where the drone flies"
        (multirotors mostly fly nose-first): ``w cos(nose, horizontal velocity) min(1, speed / 2
        m/s)``, the horizontal plane taken as the one normal to the drone's own vertical axis. 0
        (default) turns it off: a drone that crabs sideways or flies backwards (a scripted camera
        drone, the Tab. I sequences) would be read the wrong way round.
    range_std_scale, range_std_floor : a published track's position covariance is widened along
        its line of sight to a standard deviation of ``max(range_std_scale * s, range_std_floor *
        range)``, s the filter's own (the filter keeps its covariance; only ``Track.position_cov``
        changes). The filter's range doubt is the keypoints' noise alone, while the network's
        errors come in runs and sometimes read the drone 1.3 times too far or too near (an order
        turned by a quarter): on the tuning drone sequences (seed 8001, 36 sequences, 4,887
        confirmed-track frames) the true range was within one published std on 37 % of the frames
        and within two on 59 %; widened (1.5, 0.07: the least widening that puts 68 % within one
        std and 90 % within two there), 68 % and 91 %; on the reporting seeds, measured after the
        choice, 39 / 67 % before and 77 / 92 % after (docs/evaluation.md, twenty-third session).
    """

    accel_std_mps2: float = 2.0
    angular_accel_std_radps2: float = 8.0
    angular_velocity_tau_s: float = 0.0
    initial_velocity_std_mps: float = 3.0
    initial_angular_velocity_std_radps: float = 2.0
    position_gate_chi2: float = 16.27
    rotation_gate_chi2: float = 16.27
    keypoint_overlap_weight: float = 4.0
    rotation_reset_after: int = 5
    branch_switch_log_odds: float = 2.0
    branch_confidence_cap: float = 7.0
    confirm_hits: int = 3
    confirm_window: int = 5
    max_coast_s: float = 1.0
    coast_frames_per_hit: float = 4.0
    max_tracks: int = 4
    confirm_range_spread: float = 0.5
    confirm_max_outliers: int = 0
    confirm_presence: float = 0.6
    confirm_min_presence: float = 0.98
    confirm_min_change: float = 4.0
    confirm_drone_p: float = 0.9
    max_still_hits: int = 10
    merge_min_iou: float = 0.5
    merge_range_ratio: float = 0.1
    heading_evidence_weight: float = 0.05
    heading_switch_log_odds: float = 1.5
    heading_confidence_cap: float = 7.0
    heading_restart_on_reset: bool = True
    heading_look_frames: float = 30.0
    heading_from_motion: float = 0.0
    heading_full_spread_px: float = 0.0
    range_std_scale: float = 1.5
    range_std_floor: float = 0.07

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type == "bool":
                if not isinstance(value, bool | np.bool_):
                    raise ValueError(f"TrackerConfig.{f.name} must be true or false, got {value!r}")
                continue
            if f.type == "int":
                lowest = 0 if f.name in _MAY_BE_ZERO else 1
                if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < lowest:
                    raise ValueError(f"TrackerConfig.{f.name} must be an integer >= {lowest}, got {value!r}")
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
        if self.confirm_drone_p > 1.0:
            raise ValueError(f"TrackerConfig.confirm_drone_p must be in [0, 1], got {self.confirm_drone_p!r}")
        if self.merge_min_iou > 1.0:
            raise ValueError(f"TrackerConfig.merge_min_iou must be in (0, 1], got {self.merge_min_iou!r}")
        if self.confirm_window < self.confirm_hits:
            raise ValueError(
                f"TrackerConfig.confirm_window must be >= confirm_hits ({self.confirm_hits}), "
                f"got {self.confirm_window}"
            )
