"""Typed ground truth of a sequence (docs/design.md §5.1): one record per frame, the drone's keypoints
and 6DoF pose when it is visible.

The JSON reader and writer for this layout (ours and the real 2DroneKey / 3DronePose COCO files)
live in ``sim_replay.io`` (``sequence_reader``, ``sequence_writer``); the renderer produces these
objects directly.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dronekey.geometry.camera import CameraModel

__all__ = ["HIDDEN", "UNLABELLED", "VISIBLE", "DroneAnnotation", "FrameRecord", "SequenceAnnotations"]

# COCO visibility flags as used here: 2 visible; 1 labelled but hidden (behind the body, behind an
# occluder, or outside the frame). Coordinates are always the exact projection, whatever the flag.
# 0 (not labelled, coordinates meaningless) never comes from our renderer, only from outside files.
VISIBLE = 2
HIDDEN = 1
UNLABELLED = 0


@dataclass(frozen=True)
class DroneAnnotation:
    """The drone in one frame.

    keypoints_px : (4, 2) full-frame pixels (distorted, i.e. as imaged), keypoint order of the spec.
    visibility : (4,) int, ``VISIBLE`` or ``HIDDEN`` (``UNLABELLED`` only in outside files).
    bbox_xywh : box of the whole drone (propeller discs included) in pixels, clipped to the frame.
    rotation : (3, 3) body -> camera. translation : (3,) body origin in the camera frame, metres.
        Both None when the source file has keypoints but no 6DoF (a 2DroneKey file); our own
        sequences always carry them.
    """

    keypoints_px: np.ndarray
    visibility: np.ndarray
    bbox_xywh: tuple[float, float, float, float]
    rotation: np.ndarray | None
    translation: np.ndarray | None

    @property
    def has_pose(self) -> bool:
        """True when the 6DoF ground truth (rotation and translation) is known."""
        return self.rotation is not None and self.translation is not None

    @property
    def area(self) -> float:
        """COCO area of the instance: the box area in pixels^2 (OKS scale, docs/design.md §4)."""
        return float(self.bbox_xywh[2] * self.bbox_xywh[3])


@dataclass(frozen=True)
class FrameRecord:
    """One image of the sequence; ``drone`` is None on frames without a visible drone."""

    index: int
    t_ns: int
    file_name: str
    width: int
    height: int
    drone: DroneAnnotation | None = None


@dataclass
class SequenceAnnotations:
    """A whole sequence: camera, drone model, and the per-frame records in frame order.

    ``base_dir`` is the folder the records' ``file_name`` are relative to (the JSON's folder when
    the sequence was read from a file; None for a sequence that was never written).
    """

    name: str
    camera: CameraModel
    drone_model: str
    keypoints_3d: np.ndarray
    fps: float
    frames: list[FrameRecord] = field(default_factory=list)
    info: dict = field(default_factory=dict)
    keypoint_names: tuple[str, ...] = ("prop1", "prop2", "prop3", "prop4")
    base_dir: Path | None = None

    def annotated(self) -> list[FrameRecord]:
        """Frames that carry a drone annotation."""
        return [f for f in self.frames if f.drone is not None]
