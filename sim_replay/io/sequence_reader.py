"""Read a sequence JSON into ``SequenceAnnotations``: ours (docs/design.md §5.1) or a real
2DroneKey / 3DronePose COCO keypoint file.

The two layouts are told apart by the top-level keys: with ``camera`` and ``drone`` objects the
file is ours, validated strictly (``sequence_format.SequenceDocument``); any other file is read as
COCO (``coco.read_coco``). Every problem in a file raises ``SequenceFormatError`` naming the file,
the key path and what is wrong with the value.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from dronekey.geometry.camera import CameraModel
from dronekey.geometry.drone_spec import load_spec
from dronekey.sim_replay.annotations import DroneAnnotation, DroneInstance, FrameRecord, SequenceAnnotations
from dronekey.sim_replay.io.coco import read_coco
from dronekey.sim_replay.io.coco_pose import CocoPoseEncoding
from dronekey.sim_replay.io.sequence_format import AnnotationEntry, SequenceDocument, keypoint_names
from dronekey.sim_replay.io.validation import read_json_document, validate_at

__all__ = ["load_sequence"]


def _drone_annotation(entry: AnnotationEntry) -> DroneAnnotation:
    return DroneAnnotation(
        keypoints_px=entry.keypoints[:, :2].copy(),
        visibility=entry.keypoints[:, 2].astype(int),
        bbox_xywh=entry.bbox,
        rotation=entry.rotation,
        translation=entry.translation,
        instance_id=entry.instance_id,
    )


def _read_ours(
    path: Path, doc: dict, camera: CameraModel | None, drone: tuple[str, np.ndarray] | None
) -> SequenceAnnotations:
    """Our layout; ``camera`` / ``drone`` (when given) replace the file's objects unread."""
    document = validate_at(path, SequenceDocument, doc, context={"camera": camera, "drone": drone})
    if camera is None:
        camera = document.camera.camera
    if drone is None:
        drone = document.drone.model, document.drone.keypoints_3d
    by_image: dict[int | str, list[DroneAnnotation]] = {}
    for entry in document.annotations:
        by_image.setdefault(entry.image_id, []).append(_drone_annotation(entry))
    frames = [
        FrameRecord.with_drones(
            image.frame_index,
            image.timestamp_ns,
            image.file_name,
            image.width,
            image.height,
            by_image.get(image.id, []),
        )
        for image in sorted(document.images, key=lambda image: image.frame_index)
    ]
    instances = tuple(
        DroneInstance(i.instance_id, i.model, i.keypoints_3d)
        for i in sorted(document.instances or (), key=lambda i: i.instance_id)
    )
    info = document.info.entries
    return SequenceAnnotations(
        name=str(info.get("sequence", path.stem)),
        camera=camera,
        drone_model=drone[0],
        keypoints_3d=drone[1],
        fps=document.info.fps,
        frames=frames,
        info=info,
        keypoint_names=keypoint_names(document.categories),
        base_dir=path.parent,
        instances=instances,
    )


def load_sequence(
    path: str | Path,
    *,
    camera: CameraModel | str | Path | None = None,
    drone: str | Path | None = None,
    fps: float | None = None,
    pose_encoding: CocoPoseEncoding | None = None,
) -> SequenceAnnotations:
    """Read a sequence JSON: ours (docs/design.md §5.1) or a real 2DroneKey / 3DronePose COCO file.

    Parameters
    ----------
    path : the JSON file. Records' ``file_name`` stay relative to its folder (``base_dir``).
    camera : calibration (a ``CameraModel`` or an OpenCV YAML path) overriding the file's camera;
        needed for a COCO file without a ``camera`` object and without a ``camera.yaml`` beside it.
    drone : spec name or YAML overriding the file's drone model (COCO files rarely carry one).
    fps : frame rate for COCO files without ``timestamp_ns`` (default: the file's, else 30).
    pose_encoding : how a COCO file's 6DoF is encoded; default: chosen by reprojection.

    Raises
    ------
    FileNotFoundError
        The JSON file does not exist.
    SequenceFormatError
        The file is malformed or cannot be mapped (the message names the key path and value).
    dronekey.geometry.camera.CalibrationError, dronekey.geometry.drone_spec.DroneSpecError
        The ``camera`` / ``drone`` argument is unusable.
    """
    path = Path(path)
    if isinstance(camera, str | Path):
        camera = CameraModel.load(camera)
    drone_given = None
    if drone is not None:
        spec = load_spec(drone)
        drone_given = (spec.name, spec.keypoints_3d)
    if fps is not None and not (isinstance(fps, int | float) and math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number, got {fps!r}")
    doc = read_json_document(path)
    if "camera" in doc and "drone" in doc:
        return _read_ours(path, doc, camera, drone_given)
    return read_coco(
        path, doc, camera=camera, drone=drone_given, fps=fps, encoding=pose_encoding or CocoPoseEncoding()
    )
