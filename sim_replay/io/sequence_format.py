"""What a valid sequence JSON is (docs/design.md §5.1): pydantic models of the document.

Only what the readers use is checked; any other key is ignored (``info`` is kept whole, key order
included). Validation stops at the first problem in document order (``info``, ``camera``,
``drone``, ``instances``, ``categories``, ``images``, ``annotations``; list items in order), reported as a
``validation.SequenceFormatError`` naming the file, the key path and the value.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

import numpy as np
from pydantic import (
    ConfigDict,
    Field,
    PlainValidator,
    PrivateAttr,
    TypeAdapter,
    ValidationInfo,
    WrapValidator,
    field_validator,
    model_validator,
)

from dronekey.geometry.camera import CalibrationError, CameraModel
from dronekey.sim_replay.io.validation import (
    Bbox,
    FrameIndex,
    FrameRate,
    ImageId,
    Integer,
    Matrix3,
    Numbers,
    PositiveInteger,
    ReaderModel,
    RotationMatrix,
    Text,
    Vector3,
    describe_value,
    finite_array,
    problem,
)

__all__ = [
    "CATEGORIES",
    "DEFAULT_FPS",
    "DEFAULT_KEYPOINT_NAMES",
    "N_KEYPOINTS",
    "SKELETON",
    "AnnotationEntry",
    "CameraObject",
    "Category",
    "DroneObject",
    "ImageEntry",
    "InstanceObject",
    "KeypointTriples",
    "Keypoints3d",
    "SequenceDocument",
    "SequenceInfo",
    "keypoint_names",
]

N_KEYPOINTS = 4
SKELETON = [[1, 2], [2, 3], [3, 4], [4, 1]]
DEFAULT_KEYPOINT_NAMES = ("prop1", "prop2", "prop3", "prop4")
DEFAULT_FPS = 30.0


def _keypoint_triples(value: Any) -> np.ndarray:
    """COCO ``[u, v, flag] x 4`` as a (4, 3) array, the flags 0, 1 or 2."""
    flat = finite_array(value)
    if flat.shape != (3 * N_KEYPOINTS,):
        raise problem(f"must be 12 numbers [u, v, flag] x 4, got {flat.size}")
    triples = flat.reshape(N_KEYPOINTS, 3)
    if not np.all(np.isin(triples[:, 2], (0, 1, 2))):
        raise problem(f"visibility flags must be 0, 1 or 2, got {triples[:, 2].tolist()}")
    return triples


Keypoints3d = Annotated[np.ndarray, PlainValidator(lambda value: finite_array(value, (N_KEYPOINTS, 3)))]
KeypointTriples = Annotated[np.ndarray, PlainValidator(_keypoint_triples)]


# ====================================================================== the §5.1 objects


class SequenceInfo(ReaderModel):
    """``info``: free-form metadata, kept whole in ``entries``; only ``fps`` is checked."""

    model_config = ConfigDict(extra="allow")

    fps: FrameRate = DEFAULT_FPS
    _entries: dict[str, Any] = PrivateAttr(default_factory=dict)

    @model_validator(mode="wrap")
    @classmethod
    def _keep_entries(cls, value: Any, handler: Callable[[Any], SequenceInfo]) -> SequenceInfo:
        info = handler(value)
        info._entries = dict(value)  # the handler refused anything but an object
        return info

    @property
    def entries(self) -> dict[str, Any]:
        """Every key of the file's ``info``, in the file's order."""
        return self._entries


class CameraObject(ReaderModel):
    """``camera``: image size and OpenCV intrinsics (docs/design.md §5.2)."""

    width: PositiveInteger
    height: PositiveInteger
    K: Matrix3
    dist: Numbers = Field(default_factory=lambda: np.zeros(0))
    _camera: CameraModel = PrivateAttr()

    @model_validator(mode="after")
    def _usable(self) -> CameraObject:
        try:
            self._camera = CameraModel(self.width, self.height, self.K, self.dist.ravel())
        except CalibrationError as exc:
            raise problem(str(exc)) from None
        return self

    @property
    def camera(self) -> CameraModel:
        """The calibration this object describes."""
        return self._camera


class DroneObject(ReaderModel):
    """``drone``: the model's name and its propeller hubs (body FRD, metres)."""

    model: Text
    keypoints_3d: Keypoints3d


class InstanceObject(ReaderModel):
    """One entry of ``instances`` (multi-drone files): a drone's instance id, model and hubs."""

    instance_id: FrameIndex
    model: Text
    keypoints_3d: Keypoints3d


class Category(ReaderModel):
    """One entry of ``categories``: only its keypoint names are read."""

    keypoints: list[Text] | None = None

    @field_validator("keypoints", mode="before")
    @classmethod
    def _four_names(cls, value: Any) -> Any:
        if isinstance(value, list) and len(value) != N_KEYPOINTS:
            raise problem(f"DroneKey needs 4 keypoints, the file lists {len(value)}")
        return value


def _up_to_the_named_keypoints(value: Any, handler: Callable[[Any], list[Category]]) -> list[Category]:
    """Categories up to the first that names keypoints: the only ones read (and so checked)."""
    if isinstance(value, list):
        named = (i for i, c in enumerate(value) if isinstance(c, dict) and c.get("keypoints") is not None)
        value = value[: next(named, len(value) - 1) + 1]
    return handler(value)


Categories = Annotated[list[Category], WrapValidator(_up_to_the_named_keypoints)]
CATEGORIES = TypeAdapter(Categories)


def keypoint_names(categories: list[Category]) -> tuple[str, ...]:
    """The first category's keypoint names; ``DEFAULT_KEYPOINT_NAMES`` when none names them."""
    named = (c.keypoints for c in categories if c.keypoints is not None)
    return tuple(next(named, DEFAULT_KEYPOINT_NAMES))


class ImageEntry(ReaderModel):
    """One entry of ``images``: a frame of the sequence."""

    id: ImageId
    frame_index: FrameIndex
    file_name: Text
    timestamp_ns: Integer
    width: PositiveInteger
    height: PositiveInteger


class AnnotationEntry(ReaderModel):
    """One entry of ``annotations``: one drone in one image, with its 6DoF.

    ``instance_id`` (absent in single-drone files: 0) tells the drones of a sequence apart.
    """

    image_id: ImageId
    instance_id: FrameIndex = 0
    keypoints: KeypointTriples  # (4, 3): u, v (pixels), visibility flag
    bbox: Bbox
    rotation: RotationMatrix  # body -> camera
    translation: Vector3  # body origin in the camera frame, metres


class SequenceDocument(ReaderModel):
    """A whole sequence JSON in our layout.

    Validation context (``model_validate(..., context=...)``): ``camera`` / ``drone`` set to a value
    means the caller replaces the file's object, which is then not read (its field holds None);
    image sizes are checked against the camera in use.
    """

    info: SequenceInfo
    camera: CameraObject | None
    drone: DroneObject | None
    instances: list[InstanceObject] | None = None
    categories: Categories = Field(default_factory=list)
    images: list[ImageEntry]
    annotations: list[AnnotationEntry]

    @field_validator("camera", "drone", mode="wrap")
    @classmethod
    def _unless_given(cls, value: Any, handler: Callable[[Any], Any], info: ValidationInfo) -> Any:
        if (info.context or {}).get(info.field_name) is not None:
            return None
        if value is None:
            raise problem(f"must be an object, got {describe_value(value)}")
        return handler(value)

    @field_validator("instances")
    @classmethod
    def _distinct_instances(cls, instances: list[InstanceObject] | None) -> list[InstanceObject] | None:
        seen: set[int] = set()
        for i, instance in enumerate(instances or ()):
            if instance.instance_id in seen:
                raise problem(f"instance_id {instance.instance_id} repeats", f"[{i}].instance_id")
            seen.add(instance.instance_id)
        return instances

    @field_validator("images")
    @classmethod
    def _distinct_frames_of_the_camera(
        cls, images: list[ImageEntry], info: ValidationInfo
    ) -> list[ImageEntry]:
        camera = (info.context or {}).get("camera")  # the caller's, else the file's (if it was valid)
        if camera is None and info.data.get("camera") is not None:
            camera = info.data["camera"].camera
        seen: set[int | str] = set()
        for i, image in enumerate(images):
            if image.id in seen:
                raise problem(f"duplicate image id {image.id!r}", f"[{i}].id")
            seen.add(image.id)
            if camera is not None and (image.width, image.height) != camera.size:
                raise problem(
                    f"image size {image.width}x{image.height} differs from the camera's {camera.size}",
                    f"[{i}]",
                )
        if len({image.frame_index for image in images}) != len(images):
            raise problem("frame_index values repeat")
        return images

    @field_validator("annotations")
    @classmethod
    def _one_per_instance_and_known_image(
        cls, annotations: list[AnnotationEntry], info: ValidationInfo
    ) -> list[AnnotationEntry]:
        if "images" not in info.data:
            return annotations  # the images' own problem is reported
        image_ids = {image.id for image in info.data["images"]}
        listed = info.data.get("instances")
        instance_ids = None if listed is None else {instance.instance_id for instance in listed}
        first: dict[tuple[int | str, int], int] = {}
        for i, annotation in enumerate(annotations):
            image_id, instance_id = annotation.image_id, annotation.instance_id
            if image_id not in image_ids:
                raise problem(f"no image has id {image_id!r}", f"[{i}].image_id")
            if instance_ids is not None and instance_id not in instance_ids:
                raise problem(
                    f"instance_id {instance_id} is not listed in instances {sorted(instance_ids)}",
                    f"[{i}].instance_id",
                )
            key = (image_id, instance_id)
            if key in first:
                raise problem(
                    f"image {image_id!r} already has annotations[{first[key]}] of instance {instance_id}; "
                    "a drone appears at most once per image",
                    f"[{i}].image_id",
                )
            first[key] = i
        return annotations
