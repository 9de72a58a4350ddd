"""One frame in, track updates out: the localiser, keypoint model, pose estimator and tracker glued
together exactly once, for the evaluation and the daemon alike (DESIGN.md §3).

    Frame --Localizer--> KeypointDetection --PoseEstimator--> PoseMeasurement --Tracker--> Tracks

While a track lives, the crop follows the track's predicted pose, and the prediction is the prior
that undoes the network's keypoint-order flips (``keypoint_order``) and picks between the two IPPE
solutions; when that crop shows no drone (presence below the threshold) or its keypoints give no
acceptable pose, the localiser searches the whole frame.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from dronekey.camera import CalibrationError, CameraModel
from dronekey.crop import CropPolicy
from dronekey.drone_spec import DroneSpec, load_spec
from dronekey.keypoint_order import KeypointOrder
from dronekey.localizer import Localizer, LocalizerConfig, box_from_pose
from dronekey.pose import PoseEstimator, PoseRejection
from dronekey.runtime import KeypointModel
from dronekey.tracker import Tracker, TrackerConfig
from dronekey.types import Frame, KeypointDetection, PoseMeasurement, Track, TrackStatus

__all__ = ["PipelineOutput", "PoseTracker", "TrackingPipeline"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class PipelineOutput:
    """What one frame produced.

    tracks : live tracks after this frame (and, once, tracks lost at this frame).
    detection : the keypoints the pose came from, or None when no drone was found.
    measurement : the raw PnP pose of this frame, or None.
    mode : "track" (crop from the prediction), "acquire" (whole-frame search) or "none".
    rejection : why the keypoints gave no pose, when they did not.
    timings_ms : wall time of each stage.
    """

    tracks: tuple[Track, ...]
    detection: KeypointDetection | None
    measurement: PoseMeasurement | None
    mode: str
    rejection: str | None = None
    timings_ms: dict = field(default_factory=dict)


class PoseTracker:
    """The geometric tail of the pipeline: keypoints -> PnP pose -> Kalman tracks.

    Shared by ``TrackingPipeline`` and by the evaluation's oracle mode (ground-truth keypoints).

    Parameters
    ----------
    camera : CameraModel
    spec : DroneSpec
    tracker : TrackerConfig, optional
    keypoint_sigma_px : keypoint noise (px) assumed by the pose estimator's covariance.
    max_reprojection_frac : largest RMS reprojection error accepted, as a fraction of the keypoints'
        apparent spread (a wrong keypoint order fits far worse than this), floor 2 px.
    """

    def __init__(
        self,
        camera: CameraModel,
        spec: DroneSpec,
        tracker: TrackerConfig | None = None,
        keypoint_sigma_px: float = 1.5,
        max_reprojection_frac: float = 0.06,
    ) -> None:
        self.camera = camera
        self.spec = spec
        self.estimator = PoseEstimator(camera, spec, keypoint_sigma_px=keypoint_sigma_px)
        self.tracker = Tracker(tracker)
        self.max_reprojection_frac = max_reprojection_frac
        self.order = KeypointOrder()
        self._prior_track: int | None = None

    def prior(self, t_ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Predicted pose (R, t) of the best live track at ``t_ns`` (confirmed first), or None."""
        predictions = [p for p in self.tracker.predict(t_ns) if p.status != TrackStatus.LOST]
        best = min(predictions, key=lambda p: (p.status != TrackStatus.CONFIRMED, p.track_id), default=None)
        track_id = best.track_id if best is not None else None
        if track_id != self._prior_track:  # the keypoint-order history belongs to one track
            self.order.reset()
            self._prior_track = track_id
        return (best.R, best.t) if best is not None else None

    def order_keypoints(self, detection: KeypointDetection, prior) -> KeypointDetection:
        """The detection with its keypoint order made to fit the prior's projection, when the
        recent history trusts the track (``dronekey.keypoint_order``); unchanged without a prior."""
        if prior is None:
            return detection
        predicted = self.camera.project_body(self.spec.keypoints_3d, *prior)
        keypoints, symmetry = self.order.apply(detection.keypoints_px, predicted)
        return detection if symmetry == 0 else replace(detection, keypoints_px=keypoints)

    def measure(self, detection: KeypointDetection, prior) -> tuple[PoseMeasurement | None, str | None]:
        """PnP pose of a detection (the prior picks the IPPE solution), or None and the reason."""
        result = self.estimator.estimate(detection.keypoints_px, prior=prior)
        if isinstance(result, PoseRejection):
            return None, result.reason
        kp = detection.keypoints_px
        spread = max(np.linalg.norm(kp[i] - kp[j]) for i in range(4) for j in range(i + 1, 4))
        limit = max(2.0, self.max_reprojection_frac * spread)
        if result.reprojection_px > limit:
            return None, f"reprojection {result.reprojection_px:.1f} px > {limit:.1f} px"
        return result, None

    def track(
        self, t_ns: int, measurement: PoseMeasurement | None, detection: KeypointDetection | None
    ) -> list[Track]:
        """Advance the tracker to ``t_ns`` with this frame's measurement (or none)."""
        if measurement is None or detection is None:
            return self.tracker.update(t_ns, [])
        return self.tracker.update(t_ns, [measurement], [detection.presence], [detection.keypoints_px])


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
    providers, threads, mirror_average : passed to ``KeypointModel`` (mirror averaging is on by
        default: a fifth less keypoint error for about 1.6x the inference time).
    localizer, tracker : configs (defaults suit a small drone at 30 fps).
    keypoint_sigma_px, max_reprojection_frac : see ``PoseTracker``.
    """

    def __init__(
        self,
        camera: CameraModel,
        model_path: str | Path | None = None,
        drone: str | Path | DroneSpec = "mini2",
        providers: list[str] | None = None,
        threads: int | None = None,
        mirror_average: bool = True,
        localizer: LocalizerConfig | None = None,
        tracker: TrackerConfig | None = None,
        keypoint_sigma_px: float = 1.5,
        max_reprojection_frac: float = 0.06,
    ) -> None:
        self.camera = camera
        self.spec: DroneSpec = drone if isinstance(drone, DroneSpec) else load_spec(drone)
        self.model = KeypointModel(
            model_path, providers=providers, threads=threads, mirror_average=mirror_average
        )
        crop = CropPolicy(
            **{**self.model.metadata.get("crop_policy", {}), "input_size": self.model.input_size}
        )
        self.localizer = Localizer(self.model, self.spec, crop, localizer)
        self.poses = PoseTracker(camera, self.spec, tracker, keypoint_sigma_px, max_reprojection_frac)
        self.frames = 0

    def info(self) -> dict:
        """Camera, model and drone, for status messages and the Zenoh ``info`` queryable."""
        return {
            "camera": self.camera.to_dict(),
            "model": {
                "path": str(self.model.path),
                "providers": list(self.model.providers),
                "input_size": self.model.input_size,
                "trained_on": self.model.metadata.get("trained_on"),
            },
            "drone": self.spec.to_dict(),
        }

    def process(self, frame: Frame) -> PipelineOutput:
        """Run every stage on one frame (frames must come in time order)."""
        h, w = frame.bgr.shape[:2]
        if (w, h) != self.camera.size:
            cw, ch = self.camera.size
            raise CalibrationError(f"frame {frame.index} is {w}x{h} but the camera model is {cw}x{ch}")
        self.frames += 1
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        prior = self.poses.prior(frame.t_ns)
        detection = measurement = None
        rejection: str | None = None
        mode = "none"
        if prior is not None:
            box = box_from_pose(self.camera, self.spec, *prior)
            if box is not None and _overlaps_frame(box, w, h):
                det = self.poses.order_keypoints(self.localizer.track(frame.bgr, box), prior)
                if det.presence >= self.localizer.config.presence_threshold:
                    measurement, rejection = self.poses.measure(det, prior)
                    if measurement is not None:
                        detection, mode = det, "track"
            timings["track_crop"] = _ms(t0)
        if measurement is None:
            t1 = time.perf_counter()
            det = self.localizer.acquire(frame.bgr)
            timings["acquire"] = _ms(t1)
            if det is not None:
                det = self.poses.order_keypoints(det, prior)
                measurement, rejection = self.poses.measure(det, prior)
                detection, mode = det, "acquire"
        t2 = time.perf_counter()
        tracks = self.poses.track(frame.t_ns, measurement, detection)
        timings["track"] = _ms(t2)
        timings["total"] = _ms(t0)
        return PipelineOutput(tuple(tracks), detection, measurement, mode, rejection, timings)


def _overlaps_frame(box, w: int, h: int) -> bool:
    x, y, bw, bh = box
    return x < w and y < h and x + bw > 0 and y + bh > 0


def _ms(t_start: float) -> float:
    return (time.perf_counter() - t_start) * 1e3
