"""Read a real 2DroneKey / 3DronePose COCO keypoint file into ``SequenceAnnotations``.

The mapping (``docs/simulator.md``, "Reading real 2DroneKey / 3DronePose files"): images in frame
order (``frame_index`` when every image has one, else their file names in natural order), one drone
per image, the 6DoF found and decoded by ``coco_pose``. The camera comes from the ``camera``
argument, a ``camera`` object in the file or a ``camera.yaml`` beside it, in that order, scaled to
the images' size; the drone model from the ``drone`` argument, a ``drone`` object in the file, or
a shipped spec name (``mini2``, ``air2s``) found in the category, info or file name.

The file is read in that order and only as far as it is used: an annotation without a labelled
keypoint is skipped (its box and pose are not read), and so is everything but the keys named here.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
from pydantic import TypeAdapter

from dronekey.geometry.camera import CalibrationError, CameraModel
from dronekey.geometry.drone_spec import available_specs, load_spec
from dronekey.sim_replay.annotations import DroneAnnotation, FrameRecord, SequenceAnnotations
from dronekey.sim_replay.io.coco_pose import (
    CocoPoseEncoding,
    PoseDecoding,
    PoseSample,
    RawPose,
    choose_decoding,
    find_raw_pose,
)
from dronekey.sim_replay.io.sequence_format import (
    CATEGORIES,
    DEFAULT_FPS,
    CameraObject,
    DroneObject,
    KeypointTriples,
    keypoint_names,
)
from dronekey.sim_replay.io.validation import (
    Bbox,
    ImageId,
    PositiveIntegerIfGiven,
    ReaderModel,
    SequenceFormatError,
    Text,
    validate_at,
)

__all__ = ["read_coco"]

log = logging.getLogger(__name__)

_AUTO_SAMPLE = 24  # annotations used to choose the pose encoding of a file
_BBOX = TypeAdapter(Bbox)


class CocoImage(ReaderModel):
    """One entry of ``images``; ``frame_index`` and ``timestamp_ns`` are used only when well formed."""

    width: PositiveIntegerIfGiven = None
    height: PositiveIntegerIfGiven = None
    id: ImageId
    file_name: Text
    frame_index: Any = None
    timestamp_ns: Any = None

    @property
    def size(self) -> tuple[int, int] | None:
        """``(width, height)``, or None unless the file gives both."""
        return None if self.width is None or self.height is None else (self.width, self.height)


class _Images(ReaderModel):
    images: list[CocoImage]


class _AnnotationLink(ReaderModel):
    image_id: ImageId


class _Annotations(ReaderModel):
    annotations: list[_AnnotationLink]


class _Keypoints(ReaderModel):
    keypoints: KeypointTriples


@dataclass(frozen=True)
class _LabelledDrone:
    """An annotation with at least one labelled keypoint, before its pose is decoded."""

    frame: int  # position of its image in frame order
    where: str  # key path: annotations[i]
    keypoints_px: np.ndarray  # (4, 2)
    flags: np.ndarray  # (4,) COCO visibility flags
    bbox: tuple[float, float, float, float]
    raw_pose: RawPose | None


def _fail(path: Path, where: str, problem: str) -> NoReturn:
    raise SequenceFormatError(path, where, problem)


def _natural_key(text: str) -> list:
    return [int(tok) if tok.isdigit() else tok for tok in re.split(r"(\d+)", text)]


def _images_in_frame_order(path: Path, doc: dict) -> list[CocoImage]:
    images = validate_at(path, _Images, doc).images
    ids = [image.id for image in images]
    if len(set(ids)) != len(ids):
        _fail(path, "images", "image ids repeat")
    if images and all(isinstance(image.frame_index, int) for image in images):
        return sorted(images, key=lambda image: image.frame_index)
    return sorted(images, key=lambda image: _natural_key(image.file_name))


def _annotations_by_image(path: Path, doc: dict, image_ids: set) -> dict[int | str, tuple[int, dict]]:
    """Each image's annotation (the raw object) and its position in ``annotations``."""
    links = validate_at(path, _Annotations, doc).annotations
    by_image: dict[int | str, tuple[int, dict]] = {}
    for i, link in enumerate(links):
        if link.image_id not in image_ids:
            _fail(path, f"annotations[{i}].image_id", f"no image has id {link.image_id!r}")
        if link.image_id in by_image:
            _fail(
                path,
                f"annotations[{i}].image_id",
                f"image {link.image_id!r} already has annotations[{by_image[link.image_id][0]}]; "
                "a DroneKey sequence has at most one drone per image",
            )
        by_image[link.image_id] = (i, doc["annotations"][i])
    return by_image


def _camera_beside(path: Path) -> CameraModel | None:
    beside = path.parent / "camera.yaml"
    if not beside.is_file():
        return None
    try:
        return CameraModel.load(beside)
    except CalibrationError as exc:
        raise SequenceFormatError(beside, "", f"beside {path.name}, unusable: {exc}") from None


def _camera(path: Path, doc: dict, camera: CameraModel | None, images: list[CocoImage]) -> CameraModel:
    """The camera in use (argument, file object, camera.yaml beside), scaled to the images' size."""
    if camera is None and isinstance(doc.get("camera"), dict):
        camera = validate_at(path, CameraObject, doc["camera"], "camera").camera
    camera = camera or _camera_beside(path)
    if camera is None:
        _fail(
            path,
            "",
            "the file has no 'camera' object and there is no camera.yaml beside it: pass the camera's "
            "calibration (dronekey-sim --verify FILE --calib CAMERA.yaml, or load_sequence(..., camera=...))",
        )
    sizes = {image.size for image in images if image.size is not None}
    if len(sizes) > 1:
        _fail(path, "images", f"images of different sizes in one sequence: {sorted(sizes)}")
    if sizes:
        try:
            camera = camera.scaled_to(*sizes.pop())
        except CalibrationError as exc:
            _fail(path, "images", str(exc))
    return camera


def _infer_drone(path: Path, doc: dict) -> tuple[str, np.ndarray] | None:
    """The one shipped spec whose name appears in the file name, categories or info, if any."""
    texts = [path.stem]
    for cat in doc.get("categories", []) or []:
        if isinstance(cat, dict):
            texts += [str(cat.get("name", "")), str(cat.get("supercategory", ""))]
    if isinstance(doc.get("info"), dict):
        texts += [str(v) for v in doc["info"].values() if isinstance(v, str)]
    blob = re.sub(r"[^a-z0-9]", "", " ".join(texts).lower())
    found = [name for name in available_specs() if name in blob]
    if len(found) != 1:
        return None
    spec = load_spec(found[0])
    log.info("%s: drone model %s inferred from the file's names", path, spec.name)
    return spec.name, spec.keypoints_3d


def _drone(path: Path, doc: dict, drone: tuple[str, np.ndarray] | None) -> tuple[str, np.ndarray]:
    """The drone model and its keypoints_3d (argument, file object, or a name found in the file)."""
    if drone is None and isinstance(doc.get("drone"), dict):
        found = validate_at(path, DroneObject, doc["drone"], "drone")
        drone = found.model, found.keypoints_3d
    drone = drone or _infer_drone(path, doc)
    if drone is None:
        _fail(
            path,
            "",
            "cannot tell the drone model (no 'drone' object, and no single shipped spec name among "
            f"{', '.join(available_specs())} in the category, info or file name): pass it "
            "(--drone NAME|SPEC.yaml, or load_sequence(..., drone=...))",
        )
    return drone


def _frame_rate(path: Path, info: dict, fps: float | None) -> float:
    """The argument, else a positive ``info.fps``, else ``DEFAULT_FPS``."""
    if fps is None:
        fps = info.get("fps") if isinstance(info.get("fps"), int | float) and info.get("fps", 0) > 0 else None
    if fps is None:
        log.info("%s: no fps in the file; timestamps assume %g fps", path, DEFAULT_FPS)
        fps = DEFAULT_FPS
    return fps


def _labelled_drones(
    path: Path, images: list[CocoImage], by_image: dict[int | str, tuple[int, dict]]
) -> list[_LabelledDrone]:
    """The annotations of the images, in frame order, that label at least one keypoint."""
    drones = []
    for frame, image in enumerate(images):
        if image.id not in by_image:
            continue
        i, annotation = by_image[image.id]
        where = f"annotations[{i}]"
        triples = validate_at(path, _Keypoints, annotation, where).keypoints
        keypoints_px, flags = triples[:, :2].copy(), triples[:, 2].astype(int)
        if not np.any(flags > 0):
            continue  # nothing labelled: a frame without a usable drone annotation
        if "bbox" in annotation:
            bbox = validate_at(path, _BBOX, annotation["bbox"], f"{where}.bbox")
        else:
            lo, hi = keypoints_px[flags > 0].min(axis=0), keypoints_px[flags > 0].max(axis=0)
            bbox = (float(lo[0]), float(lo[1]), float(hi[0] - lo[0]), float(hi[1] - lo[1]))
        raw_pose = find_raw_pose(path, annotation, where)
        drones.append(_LabelledDrone(frame, where, keypoints_px, flags, bbox, raw_pose))
    return drones


def _pose_decoding(
    path: Path,
    drones: list[_LabelledDrone],
    encoding: CocoPoseEncoding,
    camera: CameraModel,
    kp3d: np.ndarray,
) -> PoseDecoding | None:
    """How the file's poses decode (None for a keypoints-only file); all or none must have one."""
    with_pose = [d for d in drones if d.raw_pose is not None]
    if not with_pose:
        return None
    if len(with_pose) != len(drones):
        missing = next(d for d in drones if d.raw_pose is None)
        _fail(path, missing.where, "has no rotation / translation while other annotations do")
    sizes = {d.raw_pose.rotation_size for d in with_pose}
    if len(sizes) > 1:
        _fail(path, "annotations", f"rotations of different lengths {sorted(sizes)} in one file")
    usable = [d for d in with_pose if np.count_nonzero(d.flags) >= 3]
    step = max(1, len(usable) // _AUTO_SAMPLE)
    chosen = usable[::step] or with_pose[:1]
    samples = [PoseSample(d.where, d.raw_pose, d.keypoints_px, d.flags) for d in chosen]
    return choose_decoding(path, samples, encoding, camera, kp3d)


def _drone_annotations(
    path: Path, drones: list[_LabelledDrone], decoding: PoseDecoding | None
) -> dict[int, DroneAnnotation]:
    """Each labelled drone by frame position, with its decoded pose when the file has poses."""
    out = {}
    for drone in drones:
        R = t = None
        if decoding is not None:
            pose = decoding.apply(drone.raw_pose)
            if pose is None:
                _fail(path, drone.where, f"pose does not decode as {decoding}")
            R, t = pose
        out[drone.frame] = DroneAnnotation(drone.keypoints_px, drone.flags, drone.bbox, R, t)
    return out


def read_coco(
    path: Path,
    doc: dict,
    *,
    camera: CameraModel | None,
    drone: tuple[str, np.ndarray] | None,
    fps: float | None,
    encoding: CocoPoseEncoding,
) -> SequenceAnnotations:
    """The sequence of the COCO keypoint document ``doc`` read from ``path``.

    Parameters
    ----------
    camera, drone : the caller's calibration and (model name, (4, 3) keypoints_3d in metres), or None.
    fps : frame rate for images without ``timestamp_ns`` (None: the file's, else 30).
    encoding : how the 6DoF is encoded (``"auto"`` fields are chosen by reprojection).

    Raises
    ------
    SequenceFormatError
        The file is malformed or cannot be mapped (the message names the key path and value).
    """
    info = doc.get("info") if isinstance(doc.get("info"), dict) else {}
    images = _images_in_frame_order(path, doc)
    by_image = _annotations_by_image(path, doc, {image.id for image in images})
    camera = _camera(path, doc, camera, images)
    model, kp3d = _drone(path, doc, drone)
    fps = _frame_rate(path, info, fps)
    labelled = _labelled_drones(path, images, by_image)
    decoding = _pose_decoding(path, labelled, encoding, camera, kp3d)
    drones = _drone_annotations(path, labelled, decoding)

    frames = []
    for index, image in enumerate(images):
        width, height = image.size or camera.size
        t_ns = image.timestamp_ns
        if not isinstance(t_ns, int) or isinstance(t_ns, bool):
            t_ns = round(index * 1e9 / fps)
        frames.append(FrameRecord(index, t_ns, image.file_name, width, height, drones.get(index)))
    if decoding is not None:
        info = {**info, "pose_encoding": str(decoding)}
    return SequenceAnnotations(
        name=str(info.get("sequence", path.stem)),
        camera=camera,
        drone_model=model,
        keypoints_3d=kp3d,
        fps=float(fps),
        frames=frames,
        info=info,
        keypoint_names=keypoint_names(validate_at(path, CATEGORIES, doc.get("categories", []), "categories")),
        base_dir=path.parent,
    )
