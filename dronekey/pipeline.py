"""One frame in, track updates out: the localiser, keypoint model, pose estimator and tracker glued
together exactly once, for the evaluation and the daemon alike (docs/design.md §3).

    Frame --Localizer--> KeypointDetection --plausibility--> --PoseEstimator--> PoseMeasurement
          --Tracker--> Tracks

Every live track gets a crop around its predicted pose, all in one batched inference; the
prediction is the prior that turns the detection to the track's front (the heading twin, whose
evidence the tracker weighs), undoes the network's other keypoint-order flips (``keypoint_order``)
and picks between the two IPPE solutions. The localiser then searches the frame outside the live
tracks' regions: with its full budget (``LocalizerConfig.max_candidates``) when no confirmed track
was measured this frame and every ``search_every`` frames, and with ``max_search_candidates`` every
``search_more_every`` frames while fewer than ``TrackerConfig.max_tracks`` tracks are confirmed, so
a second drone is found within a fifth of a second of entering the view. Every candidate that holds
a drone becomes a measurement of its own, so each starts a tentative hypothesis and only the ones
whose evidence holds are confirmed. The tracker assigns all of the frame's poses to its tracks at
once (Hungarian, ``dronekey.tracking.tracker``). Every detection must pass the plausibility gate
(``dronekey.perception.plausibility``) before its pose reaches the tracker.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from dronekey.checks import int_at_least
from dronekey.frame_image import FrameImage
from dronekey.geometry.camera import CalibrationError, CameraModel
from dronekey.geometry.crop import CropPolicy
from dronekey.geometry.drone_spec import DroneSpec, load_spec
from dronekey.perception.drone_verifier import load_verifier
from dronekey.perception.frame_change import frame_change
from dronekey.perception.heading_model import load_heading_model
from dronekey.perception.keypoint_model import HEADING_TWIN, KeypointModel
from dronekey.perception.keypoint_order import SYMMETRIES, KeypointOrder, reordered
from dronekey.perception.localizer import (
    Localizer,
    LocalizerConfig,
    box_from_keypoints,
    box_from_pose,
    box_overlap,
    keypoint_spread,
)
from dronekey.perception.plausibility import PlausibilityConfig, check_detection, check_pose
from dronekey.perception.pose import PoseEstimator
from dronekey.tracking.tracker import Tracker, TrackPrediction
from dronekey.tracking.tracker_config import TrackerConfig
from dronekey.types import Frame, KeypointDetection, PoseMeasurement, PoseRejection, Track, TrackStatus

__all__ = ["Measured", "PipelineOutput", "PoseTracker", "TrackingPipeline", "airframe_range_span"]

log = logging.getLogger(__name__)

_HELD = (TrackStatus.CONFIRMED, TrackStatus.COASTING)  # confirmed tracks, measured this frame or not


@dataclass(frozen=True, slots=True)
class Measured:
    """One detection that became a pose this frame: its keypoints (in the order the pose uses),
    the pose, the track whose crop it came from (None: from the whole-frame search), and how much
    its propellers changed since the previous frame above their surroundings
    (``dronekey.perception.frame_change``, grey levels; NaN on the first frame)."""

    detection: KeypointDetection
    measurement: PoseMeasurement
    track_id: int | None = None
    change: float = float("nan")  # its pixels' change since the previous frame, grey levels


@dataclass(frozen=True, slots=True)
class PipelineOutput:
    """What one frame produced.

    tracks : live tracks after this frame (and, once, tracks lost at this frame).
    detection : the keypoints of the best track's pose this frame (confirmed tracks first), or None.
    measurement : that raw PnP pose, or None.
    mode : "track" (``detection`` came from a track's crop), "acquire" (from the whole-frame
        search), "predicted" (a frame between two measured ones, ``measure_every``: the tracks
        predicted, nothing detected), "late" (the same for a frame taken late,
        ``TrackingPipeline.process``) or "none".
    rejection : why the best candidate gave no pose, when nothing did.
    timings_ms : wall time of each stage.
    measured : every detection that became a pose this frame, best first.
    """

    tracks: tuple[Track, ...]
    detection: KeypointDetection | None
    measurement: PoseMeasurement | None
    mode: str
    rejection: str | None = None
    timings_ms: dict = field(default_factory=dict)
    measured: tuple[Measured, ...] = ()


class PoseTracker:
    """The geometric tail of the pipeline: keypoints -> plausibility -> PnP pose -> Kalman tracks.

    Shared by ``TrackingPipeline`` and by the evaluation's oracle mode (ground-truth keypoints).

    Parameters
    ----------
    camera : CameraModel
    spec : DroneSpec
    tracker : TrackerConfig, optional
    keypoint_sigma_px : keypoint noise (px, per coordinate) assumed by the pose estimator's
        covariance, hence by the position filter and the gates. 3: the network's keypoints of a
        30-110 px drone move by a few pixels from frame to frame, and told 1.5 the filter followed
        each reading's range; on the tuning seeds (with ``TrackerConfig.accel_std_mps2`` 2) the
        swarm's IDF1 went 0.517 -> 0.585, Tab. VI of seed 202 5.14 -> 5.01 deg, 0.320 -> 0.309 m,
        and the robustness matrix's out-of-gate frames 151.7 -> 97.4 per 1,000 (docs/evaluation.md).
    max_reprojection_frac : largest RMS reprojection error accepted, as a fraction of the keypoints'
        apparent spread (a wrong keypoint order fits far worse than this), floor 2 px. 2.5 %: the
        shipped network's detections of drones fitted a rigid pose within 1.2 % of their spread
        (tuning seeds, 739 detections), clutter in frame-sized crops misfit by 3-4 %.
    plausibility : PlausibilityConfig, optional
        The gate every detection and its pose must pass.
    """

    def __init__(
        self,
        camera: CameraModel,
        spec: DroneSpec,
        tracker: TrackerConfig | None = None,
        keypoint_sigma_px: float = 3.0,
        max_reprojection_frac: float = 0.025,
        plausibility: PlausibilityConfig | None = None,
    ) -> None:
        self.camera = camera
        self.spec = spec
        self.estimator = PoseEstimator(camera, spec, keypoint_sigma_px=keypoint_sigma_px)
        self.tracker = Tracker(tracker)
        self.max_reprojection_frac = max_reprojection_frac
        self.plausibility = plausibility or PlausibilityConfig()
        # Per track: its keypoint-order history (key None: callers that name no track, one at a time).
        self._orders: dict[int | None, KeypointOrder] = {}

    def predictions(self, t_ns: int) -> list[TrackPrediction]:
        """Every live track's predicted pose at ``t_ns``, best first (confirmed, then by id)."""
        predictions = [p for p in self.tracker.predict(t_ns) if p.status != TrackStatus.LOST]
        predictions.sort(key=lambda p: (p.status != TrackStatus.CONFIRMED, p.track_id))
        live = {p.track_id for p in predictions}
        for track_id in [k for k in self._orders if k is not None and k not in live]:
            del self._orders[track_id]
        return predictions

    def prior(self, t_ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Predicted pose (R, t) of the best live track at ``t_ns`` (confirmed first), or None."""
        best = next(iter(self.predictions(t_ns)), None)
        return (best.R, best.t) if best is not None else None

    def order(self, track_id: int | None = None) -> KeypointOrder:
        """The keypoint-order history of one track (None: of the caller that names none)."""
        return self._orders.setdefault(track_id, KeypointOrder())

    def order_keypoints(
        self, detection: KeypointDetection, prior, track_id: int | None = None
    ) -> KeypointDetection:
        """The detection turned to the prior's front (the heading twin, with its front/back
        probability), then with the other order flips undone when the track's history trusts it
        (``dronekey.perception.keypoint_order``); unchanged without a prior."""
        if prior is None:
            return detection
        predicted = self.camera.project_body(self.spec.keypoints_3d, *prior)
        kp = detection.keypoints_px
        known = np.isfinite(detection.heading_p)  # without a front/back head, KeypointOrder alone
        if known and np.abs(kp[HEADING_TWIN] - predicted).mean() < np.abs(kp - predicted).mean():
            detection = reordered(detection, HEADING_TWIN)
        _, symmetry = self.order(track_id).apply(detection.keypoints_px, predicted)
        return detection if symmetry == 0 else reordered(detection, SYMMETRIES[symmetry])

    def measure_detection(
        self, detection: KeypointDetection, prior
    ) -> tuple[PoseMeasurement | None, str | None]:
        """``measure`` after the plausibility gate on the detection itself (its crop, the frame,
        collapsed pairs, spread): what the pipeline does with every network detection."""
        reason = check_detection(detection, self.camera.size, self.plausibility)
        if reason is not None:
            return None, reason
        return self.measure(detection, prior)

    def measure(self, detection: KeypointDetection, prior) -> tuple[PoseMeasurement | None, str | None]:
        """PnP pose of keypoints (the prior picks the IPPE solution) that passes the reprojection and
        range checks, or None and why."""
        result = self.estimator.estimate(detection.keypoints_px, prior=prior)
        if isinstance(result, PoseRejection):
            return None, result.reason
        limit = max(2.0, self.max_reprojection_frac * keypoint_spread(detection.keypoints_px))
        if result.reprojection_px > limit:
            return None, f"reprojection {result.reprojection_px:.1f} px > {limit:.1f} px"
        reason = check_pose(result, detection, self.camera, self.spec, self.plausibility)
        if reason is not None:
            return None, reason
        return result, None

    def track(
        self, t_ns: int, measurement: PoseMeasurement | None, detection: KeypointDetection | None
    ) -> list[Track]:
        """Advance the tracker to ``t_ns`` with this frame's measurement (or none)."""
        if measurement is None or detection is None:
            return self.tracker.update(t_ns, [])
        return self.track_all(t_ns, [Measured(detection, measurement)])

    def track_all(self, t_ns: int, measured: list[Measured]) -> list[Track]:
        """Advance the tracker to ``t_ns`` with every pose of this frame."""
        return self.tracker.update(
            t_ns,
            [m.measurement for m in measured],
            [m.detection.presence for m in measured],
            [m.detection.keypoints_px for m in measured],
            [m.detection.heading_p for m in measured],
            [m.change for m in measured],
            [m.detection.drone_p for m in measured],
        )


class TrackingPipeline:
    """The DroneKey pipeline for one calibrated camera.

    Parameters
    ----------
    camera : CameraModel
        Intrinsics at the resolution of the frames that will be processed.
    model_path : path, optional
        ONNX keypoint model; the shipped one by default.
    drone : str, path or DroneSpec
        Drone spec name (``mini2``, ``air2s``), YAML file or spec: the 3D keypoints PnP uses.
    drone_alternatives : drone specs the site may also see (names, YAML files or specs). One camera
        reads a drone's range from its size, and cannot tell two airframes of the same shape apart
        (the swarm's Air 2S read as a Mini 2 comes out 30 % short; docs/evaluation.md), so every
        published track's line-of-sight doubt is kept at least the largest relative difference of
        their diagonals from ``drone``'s times its range (``TrackerConfig.range_std_floor``; Air 2S
        beside Mini 2: 0.418). The range itself stays ``drone``'s. Empty (default): one airframe.
    providers, threads, mirror_average : passed to ``KeypointModel`` (mirror averaging is on by
        default: a fifth less keypoint error for about 1.6x the inference time).
    heading_model : the front/back classifier (``dronekey.perception.heading_model``): True the
        shipped one, a path another, False none (the keypoint network's own head decides, which
        answers 0.5 on every crop with the shipped network).
    verifier : the drone verifier (``dronekey.perception.drone_verifier``): True the shipped one
        (none when the package ships none), a path another, False none; its verdict is
        confirmation evidence (``TrackerConfig.confirm_drone_p``).
    localizer, tracker, plausibility : configs (defaults suit a small drone at 30 fps).
    keypoint_sigma_px, max_reprojection_frac : see ``PoseTracker``.
    search_every : frames between whole-frame searches while a confirmed track is measured (the
        search also runs on every frame without one), so that a drone outside the live tracks is
        found; 0 never searches while tracking. A search costs about 20-60 ms on the 2-core box
        (saliency, up to 6 crops and their mirrors, refines), so every 30 frames (1 s) keeps it
        to 1-2 ms per frame.
    max_search_candidates : the budget of the search for more drones while fewer than
        ``TrackerConfig.max_tracks`` tracks are confirmed (candidates on the live tracks' regions
        are not proposed, so the budget goes to the rest of the frame): 2 keeps the search to a
        saliency pass and at most two crops (and their refines), about 15-20 ms here; 0 never
        searches for more drones while tracking.
    search_more_every : frames between searches for more drones (1: every frame). A new drone
        needs only one search to start a track (its crop follows it every frame from then on), so
        6 (5 Hz at 30 fps) delays its track by at most 0.2 s and cuts the search's cost per frame
        six-fold (17.4 to about 3 ms a frame on the 2-core box, one drone tracked).
    wide_look_every : frames between the frames on which a track may look wide
        (``Localizer.track_looking_wide``: a crop the network is not sure of, presence below
        ``LocalizerConfig.wide_look_presence``, is read again twice as large, in case it was sized
        from a range read too far and clips the drone), staggered over the tracks; a track whose
        wide look was taken may look again the next frame. 1 (every frame) costs nothing where the
        network is sure of its crops (docs/evaluation.md, twenty-third session); 0 never looks wide.
    measure_every : the measurement stride: while every live track is confirmed, its last hit sure
        of its crop (presence at least ``LocalizerConfig.wide_look_presence``) and no search is due,
        the drones are measured (crops, network, classifiers, PnP) on every ``measure_every``-th
        frame only, and on the frames between the tracks are predicted to the frame's time and
        published (``Tracker.advance``; ``PipelineOutput.mode`` "predicted"). A tentative,
        coasting or doubted track, or a search, is measured on every frame. 1 (the default)
        measures every frame; 2 halves the network's work on a steadily tracked drone, for several
        cameras on one box, at an accuracy cost (docs/evaluation.md, docs/performance.md,
        twenty-eighth session).
    """

    def __init__(
        self,
        camera: CameraModel,
        model_path: str | Path | None = None,
        drone: str | Path | DroneSpec = "mini2",
        drone_alternatives: tuple[str | Path | DroneSpec, ...] = (),
        providers: list[str] | None = None,
        threads: int | None = None,
        mirror_average: bool = True,
        heading_model: bool | str | Path = True,
        verifier: bool | str | Path = True,
        localizer: LocalizerConfig | None = None,
        tracker: TrackerConfig | None = None,
        keypoint_sigma_px: float = 3.0,
        max_reprojection_frac: float = 0.025,
        plausibility: PlausibilityConfig | None = None,
        search_every: int = 30,
        max_search_candidates: int = 2,
        search_more_every: int = 6,
        wide_look_every: int = 1,
        measure_every: int = 1,
    ) -> None:
        self.wide_look_every = int_at_least("wide_look_every", wide_look_every, 0)
        self.measure_every = int_at_least("measure_every", measure_every, 1)
        self.search_every = int_at_least("search_every", search_every, 0)
        self.max_search_candidates = int_at_least("max_search_candidates", max_search_candidates, 0)
        self.search_more_every = int_at_least("search_more_every", search_more_every, 1)
        self.camera = camera
        self.spec: DroneSpec = _spec(drone)
        self.alternatives: tuple[DroneSpec, ...] = tuple(_spec(d) for d in drone_alternatives)
        tracker = tracker or TrackerConfig()
        span = airframe_range_span(self.spec, self.alternatives)
        if span > tracker.range_std_floor:
            tracker = replace(tracker, range_std_floor=span)
        self.model = KeypointModel(
            model_path,
            providers=providers,
            threads=threads,
            mirror_average=mirror_average,
            heading_model=load_heading_model(heading_model),
            verifier=load_verifier(verifier),
        )
        crop = CropPolicy(
            **{**self.model.metadata.get("crop_policy", {}), "input_size": self.model.input_size}
        )
        self.localizer = Localizer(self.model, self.spec, crop, localizer)
        self.poses = PoseTracker(
            camera, self.spec, tracker, keypoint_sigma_px, max_reprojection_frac, plausibility
        )
        self.frames = 0
        self._predicted_run = 0  # frames predicted in a row since the last measured one
        self.helper_cpu_s = 0.0  # CPU seconds spent on the helper thread (the early saliency passes)
        # The early saliency passes run on one long-lived thread (OpenCV and numpy release the GIL,
        # so it uses a second core). Not a thread per pass: OpenCV keeps the per-thread data of every
        # thread that ever called it until the process exits (a probe: +12.5 MiB over 18,000 passes,
        # an hour of one camera's; docs/performance.md, thirty-first session). Its thread ends with
        # the pipeline.
        self._helper = ThreadPoolExecutor(max_workers=1, thread_name_prefix="saliency")
        self._previous_image: FrameImage | None = None
        self._widened: set[int] = set()  # tracks whose wide look was taken last frame

    def info(self) -> dict:
        """Camera, model and drone, for status messages and the Zenoh ``info`` queryable."""
        return {
            "camera": self.camera.to_dict(),
            "model": {
                "path": str(self.model.path),
                "providers": list(self.model.providers),
                "input_size": self.model.input_size,
                "trained_on": self.model.metadata.get("trained_on"),
                "front_back": str(heading.path) if (heading := self.model.heading_model) else None,
                "verifier": str(verifier.path) if (verifier := self.model.verifier) else None,
            },
            "drone": self.spec.to_dict(),
            "drone_alternatives": [spec.name for spec in self.alternatives],
            "range_std_floor": self.poses.tracker.config.range_std_floor,
        }

    def process(self, frame: Frame, late: bool = False) -> PipelineOutput:
        """Run every stage on one frame (frames must come in time order).

        ``late``: the frame was taken late (the daemon's ``tracking.late_after_ms``). It is then
        predicted instead of measured (``PipelineOutput.mode`` "late"), as a frame between two
        measured ones is, when the stride's conditions hold (``_may_predict``), so that after a slow
        frame the pipeline catches up instead of carrying its lateness into the next frames. Never
        more than ``max(1, measure_every)`` frames in a row go unmeasured."""
        w, h = frame.size
        if (w, h) != self.camera.size:
            cw, ch = self.camera.size
            raise CalibrationError(f"frame {frame.index} is {w}x{h} but the camera model is {cw}x{ch}")
        self.frames += 1
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        between = self.measure_every > 1 and self.frames % self.measure_every != 0
        if (between or late) and self._predicted_run < self.measure_every and self._may_predict():
            tracks = self.poses.tracker.advance(frame.t_ns)
            self._previous_image = frame.image
            self._predicted_run += 1
            timings["total"] = _ms(t0)
            return PipelineOutput(
                tuple(tracks), None, None, "predicted" if between else "late", None, timings
            )
        self._predicted_run = 0
        due = self._search_due()
        early = self._helper.submit(_timed, self.localizer.saliency, frame.image) if due else None
        measured, regions, rejections, state = self._track_crops(frame, w, h)
        timings["track_crop"] = _ms(t0)
        saliency, helper_s = early.result() if early is not None else (None, 0.0)
        self.helper_cpu_s += helper_s
        budget, more_only = self._search_budget(state)
        exclude = regions[1] if more_only else regions[0]
        if budget:
            t1 = time.perf_counter()
            for det in self.localizer.acquire_all(frame.image, exclude, budget, saliency):
                measurement, rejection = self.poses.measure_detection(det, None)
                if measurement is not None:
                    measured.append(Measured(det, measurement))
                else:
                    rejections.append(rejection)
            timings["acquire"] = _ms(t1)
        t2 = time.perf_counter()
        measured = [
            replace(m, change=frame_change(frame.image, self._previous_image, m.detection.keypoints_px))
            for m in measured
        ]
        self._previous_image = frame.image  # kept, not copied: a frame's image is read-only
        tracks = self.poses.track_all(frame.t_ns, measured)
        timings["track"] = _ms(t2)
        timings["total"] = _ms(t0)
        best = measured[0] if measured else None
        mode = "none" if best is None else ("track" if best.track_id is not None else "acquire")
        return PipelineOutput(
            tuple(tracks),
            best.detection if best else None,
            best.measurement if best else None,
            mode,
            None if best else next(iter(rejections), None),
            timings,
            tuple(measured),
        )

    def _may_predict(self) -> bool:
        """Whether this frame may be predicted instead of measured (between two measured ones,
        ``measure_every``, or taken late): no search due, every live track confirmed and its last
        hit sure of its crop (presence at least ``LocalizerConfig.wide_look_presence``: a crop the
        network doubts may be cut from a range gone wrong, and is measured again on the next frame)."""
        return not self._search_due() and self.poses.tracker.all_confirmed(
            self.localizer.config.wide_look_presence
        )

    def _search_due(self) -> bool:
        """Whether this frame is one of the periodic searches' (``search_every``, or
        ``search_more_every`` with a budget), known before the track crops: its saliency pass then
        runs on the other core meanwhile (the swarm clip's slowest frames were search frames, 49-61
        ms, 7.6 of them the pass). A frame searched because no confirmed track was measured runs
        the pass after its (cheap) track crops."""
        periodic = bool(self.search_every) and self.frames % self.search_every == 0
        more = bool(self.max_search_candidates) and self.frames % self.search_more_every == 0
        return periodic or more

    def _search_budget(self, state: tuple[bool, int]) -> tuple[int, bool]:
        """Candidates the search may check this frame (0: no search) and whether it looks for more
        drones only (every live track's region left out), from (whether ``max_tracks`` tracks are
        confirmed or no track could start, confirmed tracks measured this frame)."""
        full, n_measured = state
        if n_measured == 0 or (self.search_every and self.frames % self.search_every == 0):
            return self.localizer.config.max_candidates, False
        if full or self.frames % self.search_more_every:
            return 0, True
        return self.max_search_candidates, True

    def _wide_look_due(self, track_id: int) -> bool:
        """Whether a track's drone is read in a wide crop this frame (``wide_look_every``)."""
        every = self.wide_look_every
        return every > 0 and ((self.frames + track_id) % every == 0 or track_id in self._widened)

    def _track_crops(
        self, frame: Frame, w: int, h: int
    ) -> tuple[list[Measured], list, list[str], tuple[bool, int]]:
        """One crop per live track (best first), one batch: the poses they gave, the regions the
        search leaves out (the measured tracks' predicted and keypoint boxes), why the
        others gave none, and (whether the tracks are full: ``max_tracks`` of them confirmed or no
        room for another, confirmed tracks measured)."""
        owners, boxes = [], []
        predictions = self.poses.predictions(frame.t_ns)
        for p in predictions:
            box = box_from_pose(self.camera, self.spec, p.R, p.t)
            if (
                box is not None
                and _overlaps_frame(box, w, h)
                and max(box[2], box[3]) <= _MAX_BOX_FRAMES * max(w, h)
            ):
                owners.append(p)
                boxes.append(box)
        verify = [p.status is TrackStatus.TENTATIVE for p in owners]  # the verifier confirms, no more
        measured: list[Measured] = []
        rejections: list[str] = []
        taken: list = []  # keypoint boxes already measured this frame
        threshold = self.localizer.config.presence_threshold
        found = []  # (prediction, detection, keypoint box) of the crops that hold a drone, best first
        wide = [self._wide_look_due(p.track_id) for p in owners]
        dets, widened = self.localizer.track_looking_wide(frame.image, boxes, verify, wide)
        self._widened = {p.track_id for p, wide_taken in zip(owners, widened, strict=True) if wide_taken}
        for p, det in zip(owners, dets, strict=True):
            if det.presence >= threshold:
                det = self.poses.order_keypoints(det, (p.R, p.t), p.track_id)
                found.append((p, det, box_from_keypoints(det.keypoints_px, self.spec)))
        for p, det, box in _one_reading_per_drone(found):
            prior = (p.R, p.t)
            measurement, rejection = self.poses.measure_detection(det, prior)
            if measurement is None:
                rejections.append(rejection)
                continue
            measured.append(Measured(det, measurement, p.track_id))
            taken.append(box)
        confirmed = {p.track_id for p in owners if p.status == TrackStatus.CONFIRMED}
        n_measured = sum(m.track_id in confirmed for m in measured)
        n_room = self.poses.tracker.config.max_tracks - len(predictions)
        n_confirmed = sum(p.status in _HELD for p in predictions)
        full = n_room <= 0 or n_confirmed >= self.poses.tracker.config.max_tracks
        # Regions the search leaves out: the measured drones (keypoint boxes, their tracks' predicted
        # boxes), and for the search for more drones every live track's predicted box; the full
        # search looks again where an unmeasured track's crop may have missed its drone.
        measured_ids = {m.track_id for m in measured}
        recover = taken + [b for p, b in zip(owners, boxes, strict=True) if p.track_id in measured_ids]
        return measured, (recover, taken + boxes), rejections, (full, n_measured)


def _spec(drone: str | Path | DroneSpec) -> DroneSpec:
    return drone if isinstance(drone, DroneSpec) else load_spec(drone)


def airframe_range_span(drone: DroneSpec, alternatives: tuple[DroneSpec, ...]) -> float:
    """How far, as a share of the range, ``drone``'s range may be off when the drone seen is one of
    ``alternatives``: the largest ``|diagonal_alt / diagonal - 1|`` (0 without alternatives). Range
    goes with size, so a drone of the same shape ``k`` times larger is ``k`` times farther than read."""
    return max((abs(alt.diagonal_m / drone.diagonal_m - 1.0) for alt in alternatives), default=0.0)


def _timed(fn, *args) -> tuple:
    """``fn(*args)`` and the CPU seconds it took on the thread that ran it."""
    started = time.thread_time()
    value = fn(*args)
    return value, time.thread_time() - started


def _one_reading_per_drone(found: list) -> list:
    """Of crops whose keypoint boxes overlap by more than a third (two tracks on one drone), keep one:
    the better-ranked track's, unless another reads the drone more than 10 % wider.

    A track's crop that has closed in on its drone reads it small, is cut tighter on that reading
    and reads it smaller still, until the crop no longer holds the drone (seq11 of seed 101: a
    second track on the drone drifted from 5.4 to 22 m in 100 frames, its crop down to 32 px on a
    drone 50 px wide, while the track that still framed it coasted). The wider reading is the one
    whose crop holds the whole drone, so it wins; the narrowed track coasts and is dropped.
    """
    kept: list = []
    for item in found:
        clash = next((k for k, other in enumerate(kept) if box_overlap(item[2], other[2]) > 1 / 3), None)
        if clash is None:
            kept.append(item)
        elif max(item[2][2], item[2][3]) > 1.1 * max(kept[clash][2][2], kept[clash][2][3]):
            kept[clash] = item
    return kept


# A track whose predicted box is more than twice the frame's size (a prediction run into the camera)
# gets no crop: no crop that large can be cut, or would show a drone the network can read.
_MAX_BOX_FRAMES = 2.0


def _overlaps_frame(box, w: int, h: int) -> bool:
    x, y, bw, bh = box
    return x < w and y < h and x + bw > 0 and y + bh > 0


def _ms(t_start: float) -> float:
    return (time.perf_counter() - t_start) * 1e3
