"""Typed ground truth of a sequence (docs/design.md §5.1): one record per frame, each visible drone's
keypoints and 6DoF pose, told apart by an instance id that is stable across the sequence.

The JSON reader and writer for this layout (ours and the real 2DroneKey / 3DronePose COCO files)
live in ``sim_replay.io`` (``sequence_reader``, ``sequence_writer``); the renderer produces these
objects directly.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dronekey.geometry.camera import CameraModel

__all__ = [
    "HIDDEN",
    "UNLABELLED",
    "VISIBLE",
    "DroneAnnotation",
    "DroneInstance",
    "FrameRecord",
    "SequenceAnnotations",
]

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
    instance_id : which drone of the sequence this is (stable across frames; 0 in single-drone files).
    """

    keypoints_px: np.ndarray
    visibility: np.ndarray
    bbox_xywh: tuple[float, float, float, float]
    rotation: np.ndarray | None
    translation: np.ndarray | None
    instance_id: int = 0

    @property
    def has_pose(self) -> bool:
        """True when the 6DoF ground truth (rotation and translation) is known."""
        return self.rotation is not None and self.translation is not None

    @property
    def area(self) -> float:
        """COCO area of the instance: the box area in pixels^2 (OKS scale, docs/design.md §4)."""
        return float(self.bbox_xywh[2] * self.bbox_xywh[3])


@dataclass(frozen=True)
class DroneInstance:
    """One drone of a multi-drone sequence: its instance id, model name and hubs (body FRD, metres)."""

    instance_id: int
    model: str
    keypoints_3d: np.ndarray


@dataclass(frozen=True)
class FrameRecord:
    """One image of the sequence; ``drone`` is None on frames without a visible drone.

    With several drones in view, ``drone`` is the one with the lowest instance id and ``others``
    holds the rest in instance order (``drones`` gives them all); single-drone readers that only
    look at ``drone`` must first check ``SequenceAnnotations.is_multi_drone``.
    """

    index: int
    t_ns: int
    file_name: str
    width: int
    height: int
    drone: DroneAnnotation | None = None
    others: tuple[DroneAnnotation, ...] = ()

    @classmethod
    def with_drones(
        cls, index: int, t_ns: int, file_name: str, width: int, height: int, drones: list[DroneAnnotation]
    ) -> FrameRecord:
        """A record of any number of drones (sorted by instance id; ids must be distinct)."""
        ordered = sorted(drones, key=lambda d: d.instance_id)
        ids = [d.instance_id for d in ordered]
        if len(set(ids)) != len(ids):
            raise ValueError(f"frame {index}: instance ids repeat: {ids}")
        first = ordered[0] if ordered else None
        return cls(index, t_ns, file_name, width, height, first, tuple(ordered[1:]))

    @property
    def drones(self) -> tuple[DroneAnnotation, ...]:
        """Every drone annotated in this image, in instance-id order."""
        return () if self.drone is None else (self.drone, *self.others)


@dataclass
class SequenceAnnotations:
    """A whole sequence: camera, drone model, and the per-frame records in frame order.

    ``base_dir`` is the folder the records' ``file_name`` are relative to (the JSON's folder when
    the sequence was read from a file; None for a sequence that was never written).
    ``instances`` lists the drones of a multi-drone sequence (empty for a single-drone one, whose
    one drone is instance 0 of ``drone_model``); an instance id it does not list is a
    ``drone_model`` drone.
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
    instances: tuple[DroneInstance, ...] = ()

    def annotated(self) -> list[FrameRecord]:
        """Frames that carry a drone annotation."""
        return [f for f in self.frames if f.drone is not None]

    def instance_ids(self) -> list[int]:
        """Every instance id annotated in the sequence or listed in ``instances``, ascending."""
        ids = {i.instance_id for i in self.instances}
        ids.update(d.instance_id for f in self.frames for d in f.drones)
        return sorted(ids)

    @property
    def is_multi_drone(self) -> bool:
        """True when the sequence holds more than one drone instance."""
        return len(self.instance_ids()) > 1

    def instance(self, instance_id: int) -> DroneInstance:
        """The model and hubs of a drone instance (``drone_model`` for an unlisted id)."""
        for inst in self.instances:
            if inst.instance_id == instance_id:
                return inst
        return DroneInstance(instance_id, self.drone_model, np.asarray(self.keypoints_3d))

    def require_single_drone(self, purpose: str) -> None:
        """Raise ValueError (one line) when the sequence has several drones; ``purpose`` names the user."""
        if self.is_multi_drone:
            ids = self.instance_ids()
            raise ValueError(
                f"sequence {self.name!r} has {len(ids)} drones (instance ids {ids}); {purpose} scores "
                "one drone per frame (dronekey-eval mot scores several)"
            )
