"""The 6DoF of a real 2DroneKey / 3DronePose COCO annotation: where it is kept and how it is encoded.

Files of that layout keep the pose under one of several key names (``rotation`` / ``translation``,
``R`` / ``t``, a nested ``pose`` object, a ``6dof`` 6-vector, ...) and in one of several encodings
(rotation matrix, quaternion, Euler angles, rotation vector; metres, centimetres or millimetres).
``find_raw_pose`` finds the numbers; ``choose_decoding`` picks the encoding whose poses reproject
the drone's ``keypoints_3d`` onto the annotated keypoints, unless ``CocoPoseEncoding`` names it.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
from pydantic import TypeAdapter
from scipy.spatial.transform import Rotation

from dronekey.geometry.camera import CameraModel
from dronekey.sim_replay.io.validation import Numbers, SequenceFormatError, orthonormal_or_none, validate_at

__all__ = [
    "ROTATION_ENCODINGS",
    "TRANSLATION_UNITS",
    "CocoPoseEncoding",
    "PoseDecoding",
    "PoseSample",
    "RawPose",
    "choose_decoding",
    "find_raw_pose",
]

log = logging.getLogger(__name__)

# Rotation encodings a COCO file may use. Euler names are scipy sequences: lower case extrinsic,
# upper case intrinsic axes, e.g. ``euler_ZYX_deg`` is intrinsic yaw-pitch-roll in degrees.
_EULER_SEQUENCES = ("xyz", "zyx", "XYZ", "ZYX")
ROTATION_ENCODINGS = (
    "matrix",  # 3x3 (or 9 numbers, row-major) body -> camera
    "matrix_transposed",  # 3x3 camera -> body
    "quat_wxyz",
    "quat_xyzw",
    "rotvec",  # axis * angle, radians
    *(f"euler_{seq}_{unit}" for seq in _EULER_SEQUENCES for unit in ("deg", "rad")),
)
TRANSLATION_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}

# Where a COCO annotation may keep its pose; looked up at the top level of the annotation and in a
# nested object under one of _POSE_OBJECT_KEYS.
_ROTATION_KEYS = ("rotation", "rotation_matrix", "R", "rot", "quaternion", "quat", "orientation", "euler")
_TRANSLATION_KEYS = ("translation", "t", "trans", "position", "location")
_POSE_OBJECT_KEYS = ("pose", "6dof", "pose_6dof", "object_pose", "drone_pose")
_POSE6_KEYS = ("pose", "6dof", "pose_6dof", "pose6d")

_ORTHONORMAL_TOL = 1e-3  # real files round their matrices
_NUMBERS = TypeAdapter(Numbers)


@dataclass(frozen=True)
class CocoPoseEncoding:
    """How the 6DoF of a real COCO file is encoded; ``"auto"`` picks by reprojection.

    rotation : one of ``ROTATION_ENCODINGS`` or ``"auto"``.
    translation_unit : ``"m"``, ``"cm"``, ``"mm"`` or ``"auto"``.
    pose6_order : for a single 6-vector, ``"rt"`` (rotation first), ``"tr"`` or ``"auto"``.
    """

    rotation: str = "auto"
    translation_unit: str = "auto"
    pose6_order: str = "auto"

    def __post_init__(self) -> None:
        if self.rotation not in ("auto", *ROTATION_ENCODINGS):
            raise ValueError(
                f"rotation encoding {self.rotation!r} is not one of auto, {', '.join(ROTATION_ENCODINGS)}"
            )
        if self.translation_unit not in ("auto", *TRANSLATION_UNITS):
            raise ValueError(f"translation_unit {self.translation_unit!r} is not one of auto, m, cm, mm")
        if self.pose6_order not in ("auto", "rt", "tr"):
            raise ValueError(f"pose6_order {self.pose6_order!r} is not one of auto, rt, tr")


@dataclass(frozen=True)
class RawPose:
    """The pose numbers of one annotation as found, before decoding."""

    rotation: np.ndarray | None  # 3, 4 or 9 numbers (or None with pose6)
    translation: np.ndarray | None
    pose6: np.ndarray | None = None

    @property
    def rotation_size(self) -> int:
        """How many numbers the rotation has (6 for a 6-vector pose)."""
        return self.rotation.size if self.rotation is not None else 6


def _fail(path: Path, where: str, problem: str) -> NoReturn:
    raise SequenceFormatError(path, where, problem)


def _flat_numbers(path: Path, value: Any, where: str) -> np.ndarray:
    return validate_at(path, _NUMBERS, value, where).ravel()


def find_raw_pose(path: Path, annotation: dict, where: str) -> RawPose | None:
    """The pose numbers of ``annotation`` (found at key path ``where``), or None if it has none.

    Raises
    ------
    SequenceFormatError
        Half a pose (a rotation without its translation or the other way round), or numbers of the
        wrong count.
    """
    scopes = [(annotation, where)] + [
        (annotation[k], f"{where}.{k}") for k in _POSE_OBJECT_KEYS if isinstance(annotation.get(k), dict)
    ]
    for scope, scope_where in scopes:
        rkey = next((k for k in _ROTATION_KEYS if k in scope), None)
        tkey = next((k for k in _TRANSLATION_KEYS if k in scope), None)
        if rkey and tkey:
            rotation = _flat_numbers(path, scope[rkey], f"{scope_where}.{rkey}")
            if rotation.size not in (3, 4, 9):
                _fail(path, f"{scope_where}.{rkey}", f"a rotation has 3, 4 or 9 numbers, got {rotation.size}")
            translation = _flat_numbers(path, scope[tkey], f"{scope_where}.{tkey}")
            if translation.size != 3:
                _fail(path, f"{scope_where}.{tkey}", f"a translation has 3 numbers, got {translation.size}")
            return RawPose(rotation, translation)
        if rkey or tkey:
            _fail(
                path, scope_where, f"has {rkey or tkey!r} but not its {'translation' if rkey else 'rotation'}"
            )
    for k in _POSE6_KEYS:
        if isinstance(annotation.get(k), list):
            vector = _flat_numbers(path, annotation[k], f"{where}.{k}")
            if vector.size != 6:
                _fail(path, f"{where}.{k}", f"a 6DoF vector has 6 numbers, got {vector.size}")
            return RawPose(None, None, vector)
    return None


def _decode_rotation(values: np.ndarray, encoding: str) -> np.ndarray | None:
    """Rotation matrix body -> camera, or None when the numbers do not fit the encoding."""
    n = values.size
    if encoding in ("matrix", "matrix_transposed"):
        if n != 9:
            return None
        R = orthonormal_or_none(values.reshape(3, 3), _ORTHONORMAL_TOL)
        return None if R is None else (R if encoding == "matrix" else R.T)
    if encoding.startswith("quat"):
        if n != 4 or np.linalg.norm(values) < 1e-9:
            return None
        xyzw = values if encoding == "quat_xyzw" else np.r_[values[1:], values[0]]
        return Rotation.from_quat(xyzw).as_matrix()
    if n != 3:
        return None
    if encoding == "rotvec":
        return Rotation.from_rotvec(values).as_matrix()
    _, seq, unit = encoding.split("_")
    return Rotation.from_euler(seq, values, degrees=unit == "deg").as_matrix()


@dataclass(frozen=True)
class PoseDecoding:
    """One way of turning raw pose numbers into (R body->camera, t metres)."""

    rotation: str
    unit: str
    pose6_order: str | None = None

    def __str__(self) -> str:
        order = f", 6-vector order {self.pose6_order}" if self.pose6_order else ""
        return f"rotation {self.rotation}, translation in {self.unit}{order}"

    def apply(self, raw: RawPose) -> tuple[np.ndarray, np.ndarray] | None:
        """``(R, t)`` of ``raw`` read this way, or None when its numbers do not fit."""
        rotation, translation = raw.rotation, raw.translation
        if raw.pose6 is not None:
            first, last = raw.pose6[:3], raw.pose6[3:]
            rotation, translation = (first, last) if self.pose6_order == "rt" else (last, first)
        R = _decode_rotation(rotation, self.rotation)
        return None if R is None else (R, translation * TRANSLATION_UNITS[self.unit])


@dataclass(frozen=True)
class PoseSample:
    """One annotation used to choose the decoding: its key path, raw pose and labelled keypoints."""

    where: str
    raw: RawPose
    keypoints_px: np.ndarray  # (4, 2)
    flags: np.ndarray  # (4,) COCO visibility flags


def _candidate_decodings(raw: RawPose, encoding: CocoPoseEncoding) -> list[PoseDecoding]:
    """Every decoding allowed by ``encoding`` that fits the size of the raw rotation."""
    rotations = ROTATION_ENCODINGS if encoding.rotation == "auto" else (encoding.rotation,)
    units = tuple(TRANSLATION_UNITS) if encoding.translation_unit == "auto" else (encoding.translation_unit,)
    orders: tuple[str | None, ...] = (None,)
    if raw.pose6 is not None:
        orders = ("rt", "tr") if encoding.pose6_order == "auto" else (encoding.pose6_order,)
    probe = raw.pose6[:3] if raw.pose6 is not None else raw.rotation
    fitting = [rot for rot in rotations if _decode_rotation(probe, rot) is not None]
    return [PoseDecoding(rot, unit, order) for order in orders for rot in fitting for unit in units]


def _reprojection_px(camera: CameraModel, kp3d: np.ndarray, pose: tuple | None, sample: PoseSample) -> float:
    """RMS distance (px) between the labelled keypoints and the projection; inf behind the camera."""
    if pose is None:
        return math.inf
    R, t = pose
    if np.any((kp3d @ R.T + t)[:, 2] <= 1e-6):
        return math.inf
    labelled = sample.flags > 0
    err = camera.project_body(kp3d, R, t)[labelled] - sample.keypoints_px[labelled]
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


def choose_decoding(
    path: Path,
    samples: Sequence[PoseSample],
    encoding: CocoPoseEncoding,
    camera: CameraModel,
    kp3d: np.ndarray,
) -> PoseDecoding:
    """The decoding whose poses reproject ``kp3d`` onto the annotated keypoints (median RMS px).

    A decoding fully named by ``encoding`` is taken whatever its residual (a warning reports it).

    Raises
    ------
    SequenceFormatError
        No allowed decoding fits the numbers, or none reprojects within tolerance.
    """
    first = samples[0]
    candidates = _candidate_decodings(first.raw, encoding)
    if not candidates:
        size = first.raw.rotation.size if first.raw.rotation is not None else 3
        _fail(path, first.where, f"a rotation of {size} numbers cannot be read as {encoding.rotation}")
    scored = []
    for decoding in candidates:
        errors = [_reprojection_px(camera, kp3d, decoding.apply(s.raw), s) for s in samples]
        scored.append((float(np.median(errors)), decoding))
    best_err, best = min(scored, key=lambda s: s[0])
    spread = float(np.median([np.ptp(s.keypoints_px[s.flags > 0], axis=0).max() for s in samples]))
    tolerance = max(3.0, 0.05 * spread)
    explicit = (
        encoding.rotation != "auto"
        and encoding.translation_unit != "auto"
        and (first.raw.pose6 is None or encoding.pose6_order != "auto")
    )
    if best_err <= tolerance or explicit:
        log_fn = log.warning if best_err > tolerance else log.info
        log_fn("%s: pose encoding %s reprojects with a median error of %.3g px", path, best, best_err)
        return best
    _fail(
        path,
        first.where,
        "cannot tell how the 6DoF is encoded: no reading of it reprojects the drone's keypoints_3d onto "
        f"the annotated keypoints (best: {best}, median {best_err:.3g} px over {len(samples)} annotations, "
        f"tolerance {tolerance:.3g} px). Check the camera (its calibration file), the drone model and its "
        "keypoint order, or name the encoding (CocoPoseEncoding / --rotation-encoding, --translation-unit)",
    )
