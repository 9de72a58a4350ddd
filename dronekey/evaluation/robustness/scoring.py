"""Scoring one sequence of ``dronekey-eval robustness``: the daemon's pipeline over it, frame by frame.

A fresh ``TrackingPipeline`` (unchanged) runs over every frame; per scored frame it records:

- the drone's track: the best published (confirmed or coasting) track within
  ``max(MATCH_GATE_M, MATCH_GATE_FRACTION * range)`` of the true position (camera frame, metres;
  the range is the true distance from the camera), ranked as ``dronekey-eval pose`` ranks its
  estimate (confirmed before coasting, most hits, oldest id), and its pose against the truth;
- a false track: a published track that is not the drone's (farther than the gate from the truth;
  in a drone-free frame, any published track), and the ids of such tracks; and whether it is
  **off the drone's line of sight** (clutter, or a track of the drone that coasted away from it):
  its direction more than ``LINE_OF_SIGHT_FACTOR`` times the drone's angular radius from the true
  direction, the radius being the spec's hub radius plus half a propeller at the true range. A
  false track on the line of sight is the drone itself read at a wrong range;
- a wrong heading: the drone's track more than ``WRONG_HEADING_DEG`` from the true attitude
  (geodesic angle of R_track^T R_true, so a front/back flip counts), and whether its
  ``heading_confidence`` was >= ``CONFIDENT_HEADING`` (a model without a front/back head gives NaN
  confidences, which never count);
- the pipeline's best detection against the annotated keypoints (for AP^kp);
- why a frame without the drone's track missed it, the first that holds of: a published track
  on the drone's line of sight at a wrong range (``missed_wrong_range``), a tentative track on it
  that was not confirmed (``missed_unconfirmed``), nothing on it at all (``missed_unseen``);
- whether the front/back classifier favoured the right order for the best detection, where that
  detection is the drone's and its keypoints are near one order and clearly not the other
  (``front_back_right``): the classifier's word per frame, apart from what the tracker made of it;
- how honest the published range doubt is (``range_z``): for the published track nearest the
  truth among those on the drone (its own, or one on its line of sight at a wrong range), the
  range error over the standard deviation its ``position_cov`` states along its line of sight, and
  the squared Mahalanobis distance of the true position under that covariance, with whether the
  track was coasting (``position_m2``, ``coasting``): the whole covariance's honesty, measured and
  unmeasured frames apart;
- whether the drone's body shows its front to the camera (``front_shown``, ``front_cues``): where it
  does not, front and back are a coin flip for any heading reader.

Every frame of a drone-free sequence is scored; frames of a drone sequence without an annotation
(the drone out of view) are not.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dronekey.evaluation.oracle import frame_runner
from dronekey.evaluation.pose import (
    CONFIDENT_HEADING,
    WRONG_HEADING_DEG,
    published_track_rank,
    sequence_spec,
)
from dronekey.evaluation.robustness.dither import FrameDither
from dronekey.evaluation.robustness.front_cues import front_shown
from dronekey.geometry.rotations import geodesic_angle_deg, quat_wxyz_to_matrix
from dronekey.perception.keypoint_order import HEADING_TWIN, SYMMETRIES
from dronekey.perception.localizer import LocalizerConfig
from dronekey.sim_replay.annotations import SequenceAnnotations
from dronekey.sim_replay.io.frames import iter_frames
from dronekey.tracking.track_record import line_of_sight_variance
from dronekey.tracking.tracker_config import TrackerConfig
from dronekey.types import PUBLISHED_STATUSES, KeypointDetection, Track, TrackStatus

__all__ = [
    "AXIS_EXCHANGING_ORDERS",
    "AXIS_KEEPING_ORDERS",
    "CONFIDENT_HEADING",
    "LINE_OF_SIGHT_FACTOR",
    "MATCH_GATE_FRACTION",
    "MATCH_GATE_M",
    "ORDER_DECIDED",
    "WRONG_HEADING_DEG",
    "SequenceScores",
    "axis_exchanged",
    "front_back_verdict",
    "keypoint_error_px",
    "match_gate_m",
    "miss_reason",
    "range_z",
    "score_sequence",
]

MATCH_GATE_M = 0.5
MATCH_GATE_FRACTION = 0.25
LINE_OF_SIGHT_FACTOR = 2.0
# A detection's keypoint order is decided when its mean error to the nearer of the true order and
# its front/back twin is below this fraction of the error to the other (as the classifier's
# training data decides it, ``dronekey.training.heading_data``)
ORDER_DECIDED = 0.6


def match_gate_m(t_true: np.ndarray) -> float:
    """Largest distance (m) between a track's position and the true one for the track to be the drone.

    Parameters
    ----------
    t_true : (3,) true position of the drone in the camera frame, metres.

    Returns
    -------
    ``max(MATCH_GATE_M, MATCH_GATE_FRACTION * ||t_true||)``, metres.
    """
    return max(MATCH_GATE_M, MATCH_GATE_FRACTION * float(np.linalg.norm(t_true)))


def on_line_of_sight(t_track: np.ndarray, t_true: np.ndarray, drone_radius_m: float) -> bool:
    """Whether a track lies in the drone's direction from the camera, whatever its range: the
    angle between the two camera-frame positions at most ``LINE_OF_SIGHT_FACTOR`` times the drone's
    angular radius ``atan(drone_radius_m / ||t_true||)``."""
    a, b = np.asarray(t_track, dtype=np.float64), np.asarray(t_true, dtype=np.float64)
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if na <= 0.0 or nb <= 0.0:
        return False
    angle = float(np.arccos(np.clip(a @ b / (na * nb), -1.0, 1.0)))
    return angle <= LINE_OF_SIGHT_FACTOR * float(np.arctan2(drone_radius_m, nb))


def miss_reason(tracks: Sequence[Track], t_true: np.ndarray, drone_radius_m: float) -> str:
    """Why a frame has no drone's track, given every track of the frame and the drone's true
    position ``t_true`` (camera frame, m): "wrong_range" (a published track on the drone's line of
    sight: the frame has no drone's track, so it is beyond the match gate), "unconfirmed" (a
    tentative track on it) or "unseen" (no track on it)."""
    on_sight = [
        tr
        for tr in tracks
        if tr.status is not TrackStatus.LOST and on_line_of_sight(tr.position_m, t_true, drone_radius_m)
    ]
    if any(tr.status in PUBLISHED_STATUSES for tr in on_sight):
        return "wrong_range"
    return "unconfirmed" if any(tr.status is TrackStatus.TENTATIVE for tr in on_sight) else "unseen"


def range_z(track: Track, t_true: np.ndarray) -> float:
    """A track's range error (its distance from the camera minus the true one) over the standard
    deviation its ``position_cov`` gives along its own line of sight; NaN where it gives none."""
    var = line_of_sight_variance(track.position_cov, track.position_m)
    if not var > 0:  # NaN included
        return float("nan")
    return (float(np.linalg.norm(track.position_m)) - float(np.linalg.norm(t_true))) / float(np.sqrt(var))


def position_m2(track: Track, t_true: np.ndarray) -> float:
    """The squared Mahalanobis distance (3 dof) of the true position ``t_true`` (camera frame, m)
    from the track's under its ``position_cov``; NaN where the covariance is not usable."""
    cov = np.asarray(track.position_cov, dtype=np.float64)
    d = np.asarray(t_true, dtype=np.float64).reshape(3) - np.asarray(track.position_m, dtype=np.float64)
    if not np.all(np.isfinite(cov)) or not np.all(np.isfinite(d)):
        return float("nan")
    try:
        return float(d @ np.linalg.solve(cov, d))
    except np.linalg.LinAlgError:
        return float("nan")


def front_back_verdict(detection: KeypointDetection | None, kp_true: np.ndarray) -> float:
    """1.0 where ``detection``'s front/back probability favours the true order (``kp_true``, (4, 2)
    pixels in the spec's order), 0.0 where it favours the twin; NaN without a detection of this
    drone (centroid farther than half the true keypoints' extent), without an answer (NaN or 0.5),
    or where the detection's keypoints are not clearly nearer one order (``ORDER_DECIDED``)."""
    if detection is None or not np.isfinite(detection.heading_p) or detection.heading_p == 0.5:
        return float("nan")
    in_order = _nearer(detection.keypoints_px, kp_true, (SYMMETRIES[0],), (HEADING_TWIN,))
    if in_order is None:
        return float("nan")
    p_true_order = detection.heading_p if in_order else 1.0 - detection.heading_p
    return 1.0 if p_true_order > 0.5 else 0.0


# The keypoint rectangle's re-orderings (new keypoint i = old order[i]) that keep its front/back
# axis (its symmetries: the order itself, its mirrors, its twin) and those that exchange it with the
# left/right axis (each of them turned by a quarter: the two quarter turns and the two diagonal
# reflections).
AXIS_KEEPING_ORDERS = SYMMETRIES
AXIS_EXCHANGING_ORDERS = tuple(tuple(order[i] for i in (1, 2, 3, 0)) for order in SYMMETRIES)


def axis_exchanged(kp_pred: np.ndarray, kp_true: np.ndarray) -> float:
    """1.0 where a detection's keypoints (4, 2) are in an order that exchanges the body's front/back
    and left/right axes (a quarter turn of the true order, ``kp_true`` in the spec's order, or a
    diagonal reflection), 0.0 where the order keeps them; NaN where the detection is not of this
    drone (centroid farther than half the true keypoints' extent) or is not clearly nearer one
    kind of order (``ORDER_DECIDED``). Four hubs seen at a distance fit a level pose in such an
    order too, turned 90 degrees and at a wrong range (a Mini 2 1.28 times too far or 0.78 times
    too near: its hubs are 131 mm apart along the body and 168 mm across), so it shows as a track
    off the gate on the drone's line of sight (docs/evaluation.md, "A quarter turn of the order")."""
    exchanged = _nearer(kp_pred, kp_true, AXIS_EXCHANGING_ORDERS, AXIS_KEEPING_ORDERS)
    return float("nan") if exchanged is None else float(exchanged)


def keypoint_error_px(kp_pred: np.ndarray, kp_true: np.ndarray) -> np.ndarray:
    """Each keypoint's distance (px) from its true hub, the detection's order taken as the nearer of
    the true one and its front/back twin (``HEADING_TWIN``), as the tracker keeps both; (N, 4) for
    N detections (N, 4, 2) against the truth (N, 4, 2, spec order). A detection that is not of this
    drone (centroid farther than half the true keypoints' extent, or not finite) gives NaN. A
    quarter-turned order is not forgiven: it reads the drone at a wrong range."""
    kp = np.asarray(kp_pred, dtype=np.float64).reshape(-1, 4, 2)
    truth = np.asarray(kp_true, dtype=np.float64).reshape(-1, 4, 2)
    in_order = np.linalg.norm(kp - truth, axis=2)
    twin = np.linalg.norm(kp[:, list(HEADING_TWIN)] - truth, axis=2)
    err = np.where(in_order.mean(axis=1, keepdims=True) <= twin.mean(axis=1, keepdims=True), in_order, twin)
    err[~_of_this_drone(kp, truth)] = np.nan
    return err


def _of_this_drone(kp_pred: np.ndarray, kp_true: np.ndarray) -> np.ndarray:
    """Whether each detection's keypoints (..., 4, 2) are this drone's: all finite, and their centroid
    within half the true keypoints' extent (px) of the true centroid; bool of shape (...)."""
    extent = np.ptp(kp_true, axis=-2).max(axis=-1)
    off = np.linalg.norm(kp_pred.mean(axis=-2) - kp_true.mean(axis=-2), axis=-1)
    return np.isfinite(kp_pred).all(axis=(-2, -1)) & (off <= 0.5 * extent)


def _nearer(kp_pred: np.ndarray, kp_true: np.ndarray, first, second) -> bool | None:
    """Whether keypoints (4, 2) lie nearer the truth (4, 2, spec order) in one of the re-orderings
    ``first`` than in any of ``second`` (mean distance of the nearest of each); None where they are
    not this drone's (centroid farther than half the true keypoints' extent, or not finite) or not
    clearly nearer either (the nearer's error at least ``ORDER_DECIDED`` of the other's)."""
    kp = np.asarray(kp_pred, dtype=np.float64)
    truth = np.asarray(kp_true, dtype=np.float64)
    if not _of_this_drone(kp, truth):
        return None
    err_first, err_second = (
        min(float(np.linalg.norm(kp[list(o)] - truth, axis=1).mean()) for o in orders)
        for orders in (first, second)
    )
    if min(err_first, err_second) >= ORDER_DECIDED * max(err_first, err_second):
        return None
    return err_first < err_second


def _stack(rows: list, shape: tuple[int, ...], dtype=np.float64) -> np.ndarray:
    return np.asarray(rows, dtype=dtype).reshape(len(rows), *shape)


@dataclass
class SequenceScores:
    """Per-frame outcome of one sequence (scored frames only, in frame order).

    no_drone : a drone-free sequence: only ``false_frame`` is filled, the other arrays are empty.
    false_frame : (N,) a published track that is not the drone's in the frame.
    false_ids : distinct track ids that were such a track in at least one frame.
    off_sight_frame : (N,) a false track off the drone's line of sight in the frame (every false
        track of a drone-free sequence); ``false_frame & ~off_sight_frame`` is the drone itself read
        at a wrong range. off_sight_ids : distinct ids of such tracks.
    detected : (N,) the frame has a drone's track (see the module's notes).
    R_track, t_track : (N, 3, 3), (N, 3) the drone's track (body -> camera, camera-frame metres);
        NaN where not detected. R_true, t_true : the ground truth.
    wrong_heading : (N,) the drone's track is more than ``WRONG_HEADING_DEG`` off (geodesic angle).
    sure_heading : (N,) the drone's track has a ``heading_confidence`` >= ``CONFIDENT_HEADING``
        (``confident_wrong_heading`` and ``confident_right_heading`` follow from it).
    kp_pred, kp_true : (M, 4, 2) the pipeline's best detection and the annotated keypoints, pixels,
        over the M <= N frames it measured (every frame unless ``measure_every`` > 1).
    area : (M,) annotated box area, pixels^2. score : (M,) presence of the detection (0 without).
    has_pred : (M,) a detection exists.
    missed_wrong_range, missed_unconfirmed, missed_unseen : (N,) why a frame without the drone's
        track missed it (the module's notes); with ``detected`` exactly one of the four holds.
    axis_exchanged : (N,) ``axis_exchanged`` of the pipeline's best detection: 1.0 where its
        keypoint order exchanges the body's axes, 0.0 where it keeps them, NaN undecided or none.
    front_back_right : (N,) 1.0 where the front/back classifier favoured the true order for the
        drone's detection, 0.0 where it favoured the twin, NaN where it was not asked, answered
        0.5, or the detection is not the drone's or its order is undecided.
    range_z : (N,) ``range_z`` of the published track nearest the truth among those on the drone
        (its own, or on its line of sight at a wrong range); NaN where there is none.
    position_m2, coasting : (N,) ``position_m2`` of that track, and whether it was coasting (NaN and
        False where there is none).
    front_shown : (N,) the drone's body shows its front to the camera in the frame
        (``front_cues.front_shown``); None where the sequence does not name its look.
    fps : frames per second of the pipeline alone (all frames of the sequence).
    """

    no_drone: bool
    false_frame: np.ndarray
    false_ids: int
    off_sight_frame: np.ndarray
    off_sight_ids: int
    detected: np.ndarray
    R_track: np.ndarray
    t_track: np.ndarray
    R_true: np.ndarray
    t_true: np.ndarray
    wrong_heading: np.ndarray
    sure_heading: np.ndarray
    kp_pred: np.ndarray
    kp_true: np.ndarray
    area: np.ndarray
    score: np.ndarray
    has_pred: np.ndarray
    missed_wrong_range: np.ndarray
    missed_unconfirmed: np.ndarray
    missed_unseen: np.ndarray
    front_back_right: np.ndarray
    axis_exchanged: np.ndarray
    range_z: np.ndarray
    position_m2: np.ndarray
    coasting: np.ndarray
    front_shown: np.ndarray | None = None
    fps: float = float("nan")

    @property
    def confident_wrong_heading(self) -> np.ndarray:
        """(N,) a wrong heading stated with confidence."""
        return self.wrong_heading & self.sure_heading

    @property
    def confident_right_heading(self) -> np.ndarray:
        """(N,) a drone's track within ``WRONG_HEADING_DEG`` that says so: what the doubt costs."""
        return self.detected & ~self.wrong_heading & self.sure_heading

    @property
    def frames(self) -> int:
        """Scored frames: every frame of a drone-free sequence, the annotated ones otherwise."""
        return int(self.false_frame.size)


def score_sequence(
    seq: SequenceAnnotations,
    model_path: str | Path | None = None,
    *,
    mirror_average: bool = True,
    front_back: bool | str | Path = True,
    verifier: bool | str | Path = True,
    on_frame: Callable[[], object] | None = None,
    dither: FrameDither | None = None,
    localizer: LocalizerConfig | None = None,
    tracker: TrackerConfig | None = None,
    measure_every: int = 1,
    oracle_noise_px: float | None = None,
    oracle_seed: int = 0,
) -> SequenceScores:
    """Run a fresh ``TrackingPipeline`` over a loaded sequence and score every frame.

    Parameters
    ----------
    seq : ``SequenceAnnotations`` (``sim_replay.io.sequence_reader.load_sequence``); ``info.no_drone``
        marks a drone-free sequence.
    model_path : ONNX keypoint model; the shipped one by default.
    mirror_average : passed to the pipeline (the daemon's default).
    front_back, verifier : the pipeline's front/back classifier and drone verifier (``heading_model``
        and ``verifier`` of ``TrackingPipeline``: True the shipped ones, a path another, False none).
    on_frame : called after each frame (a progress bar's ``update``).
    dither : every frame gets its grey level of seeded noise first
        (``dronekey.evaluation.robustness.dither``; one instance for the whole matrix, so its noise
        is drawn once): the figures' noise floor. None: the frames as decoded.
    localizer, tracker : the pipeline's configs (a setting measured before it is shipped); None: the
        defaults, as shipped.
    measure_every : the pipeline's measurement stride (1, every frame, as shipped). The frames
        between measured ones (``PipelineOutput.mode`` "predicted") score their tracks like any
        other frame, but hold no detection to score: they are left out of AP^kp, and the front/back
        and axis verdicts are NaN there.
    oracle_noise_px : None (the pipeline, as shipped), or the network replaced by the ground-truth
        keypoints with this much independent Gaussian noise (px) and no search
        (``dronekey.evaluation.oracle``): what the pose stage makes of keypoints that precise; a
        drone-free sequence then holds nothing to track.
    oracle_seed : the oracle noise's seed.

    Returns
    -------
    SequenceScores
    """
    no_drone = bool(seq.info.get("no_drone", False))
    spec = sequence_spec(seq)
    drone_radius_m = spec.extent_m / 2.0  # the circle that holds every propeller disc
    run = frame_runner(
        seq.camera,
        spec,
        model_path,
        oracle_noise_px=oracle_noise_px,
        oracle_seed=oracle_seed,
        tracker=tracker,
        mirror_average=mirror_average,
        heading_model=front_back,
        verifier=verifier,
        localizer=localizer,
        measure_every=measure_every,
    )
    rows: dict[str, list] = {
        k: []
        for k in (
            "false",
            "off_sight",
            "detected",
            "R_track",
            "t_track",
            "R_true",
            "t_true",
            "wrong",
            "sure",
            "kp_pred",
            "kp_true",
            "area",
            "score",
            "has_pred",
            "miss",
            "front_back",
            "axis",
            "range_z",
            "position_m2",
            "coasting",
        )
    }
    false_ids: set[int] = set()
    off_sight_ids: set[int] = set()
    proc_s, n = 0.0, 0
    for sf in iter_frames(seq):
        frame = sf.frame if dither is None else dither(sf.frame)
        t0 = time.perf_counter()
        ann = sf.record.drone
        out = run(frame, None if no_drone else ann)
        proc_s += time.perf_counter() - t0
        n += 1
        if on_frame is not None:
            on_frame()
        published = [tr for tr in out.tracks if tr.status in PUBLISHED_STATUSES]
        if no_drone:
            rows["false"].append(bool(published))
            rows["off_sight"].append(bool(published))
            false_ids.update(tr.track_id for tr in published)
            off_sight_ids.update(tr.track_id for tr in published)
            continue
        if ann is None or not ann.has_pose:
            continue
        gate = match_gate_m(ann.translation)
        is_drone = [float(np.linalg.norm(tr.position_m - ann.translation)) <= gate for tr in published]
        false_ids.update(tr.track_id for tr, ok in zip(published, is_drone, strict=True) if not ok)
        on_sight = [on_line_of_sight(tr.position_m, ann.translation, drone_radius_m) for tr in published]
        off_sight = [
            tr.track_id
            for tr, ok, seen in zip(published, is_drone, on_sight, strict=True)
            if not ok and not seen
        ]
        off_sight_ids.update(off_sight)
        rows["off_sight"].append(bool(off_sight))
        on_drone = [tr for tr, ok, seen in zip(published, is_drone, on_sight, strict=True) if ok or seen]
        nearest = min(
            on_drone, key=lambda tr: float(np.linalg.norm(tr.position_m - ann.translation)), default=None
        )
        rows["range_z"].append(range_z(nearest, ann.translation) if nearest is not None else np.nan)
        rows["position_m2"].append(position_m2(nearest, ann.translation) if nearest is not None else np.nan)
        rows["coasting"].append(nearest is not None and nearest.status is TrackStatus.COASTING)
        mine = [tr for tr, ok in zip(published, is_drone, strict=True) if ok]
        best = min(mine, key=published_track_rank) if mine else None
        rows["miss"].append(
            None if best is not None else miss_reason(out.tracks, ann.translation, drone_radius_m)
        )
        rows["false"].append(not all(is_drone))
        rows["detected"].append(best is not None)
        rows["R_true"].append(ann.rotation)
        rows["t_true"].append(ann.translation)
        if best is not None:
            R = quat_wxyz_to_matrix(best.quaternion_wxyz)
            rows["wrong"].append(geodesic_angle_deg(R, ann.rotation) > WRONG_HEADING_DEG)
            rows["sure"].append(bool(best.heading_confidence >= CONFIDENT_HEADING))
            rows["R_track"].append(R)
            rows["t_track"].append(best.position_m)
        else:
            rows["wrong"].append(False)
            rows["sure"].append(False)
            rows["R_track"].append(np.full((3, 3), np.nan))
            rows["t_track"].append(np.full(3, np.nan))
        det = out.detection
        if out.mode in ("predicted", "late"):  # nothing was looked for: no detection to score
            rows["front_back"].append(np.nan)
            rows["axis"].append(np.nan)
            continue
        rows["kp_true"].append(ann.keypoints_px)
        rows["area"].append(ann.area)
        rows["has_pred"].append(det is not None)
        rows["kp_pred"].append(det.keypoints_px if det is not None else np.zeros((4, 2)))
        rows["score"].append(det.presence if det is not None else 0.0)
        rows["front_back"].append(front_back_verdict(det, ann.keypoints_px))
        rows["axis"].append(axis_exchanged(det.keypoints_px, ann.keypoints_px) if det is not None else np.nan)
    R_true, t_true = _stack(rows["R_true"], (3, 3)), _stack(rows["t_true"], (3,))
    return SequenceScores(
        no_drone=no_drone,
        false_frame=_stack(rows["false"], (), bool),
        false_ids=len(false_ids),
        off_sight_frame=_stack(rows["off_sight"], (), bool),
        off_sight_ids=len(off_sight_ids),
        detected=_stack(rows["detected"], (), bool),
        R_track=_stack(rows["R_track"], (3, 3)),
        t_track=_stack(rows["t_track"], (3,)),
        R_true=R_true,
        t_true=t_true,
        wrong_heading=_stack(rows["wrong"], (), bool),
        sure_heading=_stack(rows["sure"], (), bool),
        kp_pred=_stack(rows["kp_pred"], (4, 2)),
        kp_true=_stack(rows["kp_true"], (4, 2)),
        area=_stack(rows["area"], ()),
        score=_stack(rows["score"], ()),
        has_pred=_stack(rows["has_pred"], (), bool),
        missed_wrong_range=_stack([m == "wrong_range" for m in rows["miss"]], (), bool),
        missed_unconfirmed=_stack([m == "unconfirmed" for m in rows["miss"]], (), bool),
        missed_unseen=_stack([m == "unseen" for m in rows["miss"]], (), bool),
        front_back_right=_stack(rows["front_back"], ()),
        axis_exchanged=_stack(rows["axis"], ()),
        range_z=_stack(rows["range_z"], ()),
        position_m2=_stack(rows["position_m2"], ()),
        coasting=_stack(rows["coasting"], (), bool),
        front_shown=None if no_drone else front_shown(seq.info, R_true, t_true),
        fps=n / proc_s if proc_s > 0 else float("nan"),
    )
