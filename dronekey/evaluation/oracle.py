"""Oracle keypoints: the pipeline's geometric tail fed the ground truth plus pixel noise.

The network's place taken by the annotated keypoints with Gaussian noise of ``noise_px`` per
coordinate, drawn independently for every frame and keypoint; everything after the network is the
daemon's own (``dronekey.pipeline.PoseTracker``: PnP with the prior's IPPE pick, the reprojection
and range checks, the Kalman tracks and their confirmation). What an evaluation prints on it is
what the pose stage makes of keypoints right on average and off by independent noise of that size:
a yardstick for how precise a detector must be, not a bound. A network's errors persist from frame
to frame (the filter averages less of them away) and have long tails, which costs range; but they
keep the shape of a drone, so the PnP branch of a far drone is seldom wrong, where independent
noise flips it (docs/evaluation.md, forty-fourth session).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from dronekey.geometry.camera import CameraModel
from dronekey.geometry.drone_spec import DroneSpec
from dronekey.pipeline import PipelineOutput, PoseTracker, TrackingPipeline
from dronekey.tracking.tracker_config import TrackerConfig
from dronekey.types import Frame, KeypointDetection

__all__ = ["OracleKeypoints", "frame_runner"]

# The least keypoint noise the filter is told (px): at 0 px the pose is exact, and a zero
# measurement covariance would make the filter's gains singular.
_MIN_TOLD_SIGMA_PX = 0.1


class OracleKeypoints:
    """A stand-in for ``TrackingPipeline``: ground-truth keypoints plus noise, then PnP and tracks.

    Parameters
    ----------
    camera : CameraModel
        The sequence's calibrated camera.
    spec : DroneSpec
        The drone's keypoint geometry (the sequence's own).
    noise_px : float
        Standard deviation of the Gaussian noise added to each keypoint coordinate, px, >= 0. The
        filter is told the same noise (at least 0.1 px), as a deployment tuned to its detector is.
    seed : int
        Seed of the noise (one stream per instance: the same seed gives the same figures).
    tracker : TrackerConfig, optional
        The tracker's settings; None: as shipped.

    Raises
    ------
    ValueError
        ``noise_px`` negative or not finite.
    """

    def __init__(
        self,
        camera: CameraModel,
        spec: DroneSpec,
        noise_px: float,
        seed: int = 0,
        tracker: TrackerConfig | None = None,
    ) -> None:
        if not (np.isfinite(noise_px) and noise_px >= 0):
            raise ValueError(f"noise_px must be a finite number >= 0 px, got {noise_px}")
        self.noise_px = float(noise_px)
        self.poses = PoseTracker(
            camera, spec, keypoint_sigma_px=max(self.noise_px, _MIN_TOLD_SIGMA_PX), tracker=tracker
        )
        self._rng = np.random.default_rng(seed)

    def process(self, frame: Frame, keypoints_px: np.ndarray | None) -> PipelineOutput:
        """One frame: ``keypoints_px`` ((4, 2) px, the spec's order; None where the frame holds no
        drone) with this frame's noise, measured and tracked as the pipeline measures a detection."""
        detection = measurement = None
        if keypoints_px is not None:
            noisy = keypoints_px + self._rng.normal(0.0, self.noise_px, np.shape(keypoints_px))
            detection = KeypointDetection(noisy, 1.0, (0, 0, 1))
            measurement = self.poses.measure(detection, self.poses.prior(frame.t_ns))[0]
        tracks = self.poses.track(frame.t_ns, measurement, detection)
        mode = "none" if measurement is None else "track"
        return PipelineOutput(tuple(tracks), detection, measurement, mode)


def frame_runner(
    camera: CameraModel,
    spec: DroneSpec,
    model_path: str | Path | None = None,
    *,
    oracle_noise_px: float | None = None,
    oracle_seed: int = 0,
    tracker: TrackerConfig | None = None,
    **pipeline_settings,
) -> Callable[[Frame, object], PipelineOutput]:
    """What an evaluation runs on each frame, ``run(frame, annotation) -> PipelineOutput``.

    The daemon's ``TrackingPipeline`` (``model_path`` and ``pipeline_settings`` passed to it; the
    annotation unread), or with ``oracle_noise_px`` an ``OracleKeypoints`` fed the annotation's
    keypoints (none where the annotation is None or has no pose)."""
    if oracle_noise_px is None:
        pipeline = TrackingPipeline(camera, model_path, drone=spec, tracker=tracker, **pipeline_settings)
        return lambda frame, annotation: pipeline.process(frame)
    oracle = OracleKeypoints(camera, spec, oracle_noise_px, seed=oracle_seed, tracker=tracker)

    def run(frame: Frame, annotation) -> PipelineOutput:
        drone_here = annotation is not None and getattr(annotation, "has_pose", True)
        return oracle.process(frame, annotation.keypoints_px if drone_here else None)

    return run
