"""Read and write sequence annotation JSON: our 3DronePose-style files (docs/design.md §5.1) and the real
2DroneKey / 3DronePose COCO keypoint files.

Writing produces exactly the §5.1 layout, byte-for-byte reproducible (no clocks, hosts or paths),
floats written with Python's shortest round-trip repr so a reader gets the very same float64
values back. Two COCO details are added so pycocotools reads the files unchanged: every annotation
carries ``"iscrowd": 0`` and annotation ids start at 1 (``COCOeval`` takes id 0 for "unmatched").

Reading accepts two layouts, told apart by the top-level keys:

* ours (``camera`` and ``drone`` objects present): validated strictly against §5.1;
* any other COCO keypoint file: mapped as described in ``docs/simulator.md`` ("Reading real
  2DroneKey / 3DronePose files"): images in frame order, one drone per image, the 6DoF found under
  one of several key names and decoded in whichever encoding (rotation matrix, quaternion, Euler
  angles, rotation vector, 6-vector; metres, centimetres or millimetres) reprojects the drone's
  ``keypoints_3d`` onto the annotated keypoints, unless ``CocoPoseEncoding`` names it. The camera
  comes from the ``camera`` argument, a ``camera`` object in the file or a ``camera.yaml`` beside
  it, in that order; the drone model from the ``drone`` argument, a ``drone`` object in the file, or
  a shipped spec name (``mini2``, ``air2s``) found in the category, info or file name.

Every problem in a file raises ``SequenceFormatError`` naming the file, the key path
(``annotations[3].rotation``) and what is wrong with the value.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
from scipy.spatial.transform import Rotation

from dronekey.geometry.camera import CalibrationError, CameraModel
from dronekey.geometry.drone_spec import available_specs, load_spec
from dronekey.sim_replay.annotations import DroneAnnotation, FrameRecord, SequenceAnnotations

__all__ = [
    "ROTATION_ENCODINGS",
    "TRANSLATION_UNITS",
    "CocoPoseEncoding",
    "SequenceFormatError",
    "dumps_sequence",
    "load_sequence",
    "save_sequence",
    "sequence_to_dict",
]

log = logging.getLogger(__name__)

SKELETON = [[1, 2], [2, 3], [3, 4], [4, 1]]
N_KEYPOINTS = 4

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

_ORTHONORMAL_TOL_OURS = 1e-6
_ORTHONORMAL_TOL_COCO = 1e-3
_AUTO_SAMPLE = 24  # annotations used to choose the pose encoding of a COCO file
_DEFAULT_FPS = 30.0


class SequenceFormatError(ValueError):
    """A sequence JSON is malformed or cannot be mapped; names the file, the key path and the problem."""

    def __init__(self, path: str | Path, where: str, problem: str) -> None:
        self.path = str(path)
        self.where = where
        self.problem = problem
        super().__init__(f"{path}: {where}: {problem}" if where else f"{path}: {problem}")


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


# ====================================================================== writing


def _json_default(value: Any) -> Any:
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return value.as_posix()
    raise TypeError(f"cannot write {type(value).__name__} {value!r} to a sequence JSON")


def _dump(value: Any) -> str:
    return json.dumps(value, allow_nan=False, default=_json_default, ensure_ascii=False)


def _annotation_dict(ann_id: int, image_id: int, drone: DroneAnnotation, frame: int) -> dict:
    kp = np.asarray(drone.keypoints_px, dtype=np.float64)
    vis = np.asarray(drone.visibility).astype(int)
    if kp.shape != (N_KEYPOINTS, 2) or vis.shape != (N_KEYPOINTS,):
        raise ValueError(
            f"frame {frame}: keypoints must be (4, 2) with (4,) flags, got {kp.shape}, {vis.shape}"
        )
    if not drone.has_pose:
        raise ValueError(f"frame {frame}: a DroneKey sequence needs the 6DoF of every annotated drone")
    flat: list[float | int] = []
    for (u, v), flag in zip(kp.tolist(), vis.tolist(), strict=True):
        flat += [u, v, int(flag)]
    bbox = [float(x) for x in drone.bbox_xywh]
    return {
        "id": ann_id,
        "image_id": image_id,
        "category_id": 1,
        "keypoints": flat,
        "num_keypoints": int(np.count_nonzero(vis > 0)),
        "bbox": bbox,
        "area": bbox[2] * bbox[3],
        "iscrowd": 0,
        "rotation": np.asarray(drone.rotation, dtype=np.float64).tolist(),
        "translation": np.asarray(drone.translation, dtype=np.float64).ravel().tolist(),
    }


def sequence_to_dict(seq: SequenceAnnotations) -> dict:
    """The §5.1 document of a sequence as plain Python objects (image id = frame index)."""
    info = dict(seq.info)
    info.setdefault("sequence", seq.name)
    info.setdefault("fps", float(seq.fps))
    images, annotations = [], []
    for rec in seq.frames:
        images.append(
            {
                "id": rec.index,
                "file_name": rec.file_name,
                "frame_index": rec.index,
                "timestamp_ns": int(rec.t_ns),
                "width": rec.width,
                "height": rec.height,
            }
        )
        if rec.drone is not None:
            annotations.append(_annotation_dict(len(annotations) + 1, rec.index, rec.drone, rec.index))
    return {
        "info": info,
        "camera": seq.camera.to_dict(),
        "drone": {"model": seq.drone_model, "keypoints_3d": np.asarray(seq.keypoints_3d).tolist()},
        "categories": [
            {"id": 1, "name": "drone", "keypoints": list(seq.keypoint_names), "skeleton": SKELETON}
        ],
        "images": images,
        "annotations": annotations,
    }


def dumps_sequence(seq: SequenceAnnotations) -> str:
    """The JSON text of a sequence: one image or annotation per line, reproducible byte for byte.

    Raises
    ------
    ValueError
        If a value is not finite or a drone annotation lacks its pose.
    """
    doc = sequence_to_dict(seq)
    lines = ["{"]
    for i, (key, value) in enumerate(doc.items()):
        comma = "," if i < len(doc) - 1 else ""
        if key in ("images", "annotations") and value:
            lines.append(f" {_dump(key)}: [")
            lines += [f"  {_dump(item)}," for item in value[:-1]]
            lines += [f"  {_dump(value[-1])}", f" ]{comma}"]
        else:
            lines.append(f" {_dump(key)}: {_dump(value)}{comma}")
    lines.append("}")
    return "\n".join(lines) + "\n"


def save_sequence(seq: SequenceAnnotations, path: str | Path) -> None:
    """Write a sequence JSON through a temporary file renamed at the end (never a partial file)."""
    path = Path(path)
    text = dumps_sequence(seq)
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    try:
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


# ====================================================================== reading: helpers


class _Checker:
    """Validation helpers that raise ``SequenceFormatError`` for one file."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, where: str, problem: str) -> NoReturn:
        raise SequenceFormatError(self.path, where, problem)

    def obj(self, value: Any, where: str) -> dict:
        if not isinstance(value, dict):
            self.fail(where, f"must be an object, got {_describe(value)}")
        return value

    def key(self, parent: dict, key: str, where: str) -> Any:
        if key not in parent:
            self.fail(where, f"missing key {key!r}")
        return parent[key]

    def list_(self, value: Any, where: str) -> list:
        if not isinstance(value, list):
            self.fail(where, f"must be a list, got {_describe(value)}")
        return value

    def integer(self, value: Any, where: str, *, minimum: int | None = None) -> int:
        if isinstance(value, bool) or not isinstance(value, int | float) or int(value) != value:
            self.fail(where, f"must be an integer, got {_describe(value)}")
        if minimum is not None and value < minimum:
            self.fail(where, f"must be >= {minimum}, got {value}")
        return int(value)

    def string(self, value: Any, where: str) -> str:
        if not isinstance(value, str):
            self.fail(where, f"must be a string, got {_describe(value)}")
        return value

    def numbers(self, value: Any, where: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
        """Nested lists of finite numbers (booleans and strings refused) as a float64 array."""

        def flat(v: Any) -> Iterable[Any]:
            if isinstance(v, list):
                for x in v:
                    yield from flat(x)
            else:
                yield v

        bad = next(
            (x for x in flat(value) if isinstance(x, bool) or not isinstance(x, int | float)),
            None,
        )
        if not isinstance(value, list) or bad is not None:
            self.fail(where, f"must be a list of numbers, got {_describe(bad if bad is not None else value)}")
        try:
            arr = np.asarray(value, dtype=np.float64)
        except ValueError:
            self.fail(where, "rows of different lengths")
        if shape is not None and arr.shape != shape:
            want = "x".join(map(str, shape))
            self.fail(where, f"must be {want} numbers, got shape {'x'.join(map(str, arr.shape)) or 'scalar'}")
        if not np.all(np.isfinite(arr)):
            self.fail(where, "numbers must be finite")
        return arr

    def rotation(self, value: Any, where: str, tol: float) -> np.ndarray:
        raw = self.numbers(value, where, (3, 3))
        R = _orthonormal_or_none(raw, tol)
        if R is None:
            self.fail(
                where, f"not a rotation matrix (R^T R = I and det R = 1 within {tol:g}): {raw.tolist()}"
            )
        return R


def _describe(value: Any) -> str:
    text = json.dumps(value, default=str)
    return f"{type(value).__name__} {text[:60] + '...' if len(text) > 60 else text}"


def _orthonormal_or_none(R: np.ndarray, tol: float) -> np.ndarray | None:
    """R itself when it is a rotation within ``tol``, re-orthonormalised (SVD) if tol is loose."""
    if np.abs(R.T @ R - np.eye(3)).max() > tol or abs(np.linalg.det(R) - 1.0) > tol:
        return None
    if tol <= _ORTHONORMAL_TOL_OURS:
        return R
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def _read_document(path: Path) -> dict:
    if not path.is_file():
        raise FileNotFoundError(f"sequence JSON not found: {path}")

    def refuse_constant(name: str) -> NoReturn:
        raise SequenceFormatError(path, "", f"{name} is not valid JSON (numbers must be finite)")

    try:
        doc = json.loads(path.read_text(encoding="utf-8"), parse_constant=refuse_constant)
    except UnicodeDecodeError as exc:
        raise SequenceFormatError(path, "", f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise SequenceFormatError(
            path, f"line {exc.lineno} column {exc.colno}", f"invalid JSON: {exc.msg}"
        ) from None
    if not isinstance(doc, dict):
        raise SequenceFormatError(path, "top level", f"must be an object, got {_describe(doc)}")
    return doc


def _camera_from_object(check: _Checker, value: Any) -> CameraModel:
    cam = check.obj(value, "camera")
    width = check.integer(check.key(cam, "width", "camera"), "camera.width", minimum=1)
    height = check.integer(check.key(cam, "height", "camera"), "camera.height", minimum=1)
    K = check.numbers(check.key(cam, "K", "camera"), "camera.K", (3, 3))
    dist = check.numbers(cam.get("dist", []), "camera.dist")
    try:
        return CameraModel(width, height, K, dist.ravel())
    except CalibrationError as exc:
        check.fail("camera", str(exc))


def _keypoints_3d_from_object(check: _Checker, value: Any) -> tuple[str, np.ndarray]:
    drone = check.obj(value, "drone")
    model = check.string(check.key(drone, "model", "drone"), "drone.model")
    kp3d = check.numbers(check.key(drone, "keypoints_3d", "drone"), "drone.keypoints_3d", (N_KEYPOINTS, 3))
    return model, kp3d


def _keypoint_names(check: _Checker, doc: dict) -> tuple[str, ...]:
    cats = check.list_(doc.get("categories", []), "categories")
    for i, cat in enumerate(cats):
        cat = check.obj(cat, f"categories[{i}]")
        names = cat.get("keypoints")
        if names is None:
            continue
        names = check.list_(names, f"categories[{i}].keypoints")
        if len(names) != N_KEYPOINTS:
            check.fail(
                f"categories[{i}].keypoints", f"DroneKey needs 4 keypoints, the file lists {len(names)}"
            )
        return tuple(check.string(n, f"categories[{i}].keypoints[{j}]") for j, n in enumerate(names))
    return ("prop1", "prop2", "prop3", "prop4")


def _keypoints_and_flags(check: _Checker, ann: dict, where: str) -> tuple[np.ndarray, np.ndarray]:
    flat = check.numbers(check.key(ann, "keypoints", where), f"{where}.keypoints")
    if flat.shape != (3 * N_KEYPOINTS,):
        check.fail(f"{where}.keypoints", f"must be 12 numbers [u, v, flag] x 4, got {flat.size}")
    triples = flat.reshape(N_KEYPOINTS, 3)
    flags = triples[:, 2]
    if not np.all(np.isin(flags, (0, 1, 2))):
        check.fail(f"{where}.keypoints", f"visibility flags must be 0, 1 or 2, got {flags.tolist()}")
    return triples[:, :2].copy(), flags.astype(int)


def _bbox(check: _Checker, ann: dict, where: str, kp: np.ndarray, flags: np.ndarray, required: bool):
    if "bbox" not in ann:
        if required:
            check.fail(where, "missing key 'bbox'")
        pts = kp[flags > 0]
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        return (float(lo[0]), float(lo[1]), float(hi[0] - lo[0]), float(hi[1] - lo[1]))
    box = check.numbers(ann["bbox"], f"{where}.bbox", (4,))
    if box[2] < 0 or box[3] < 0:
        check.fail(f"{where}.bbox", f"width and height must be >= 0, got {box.tolist()}")
    return tuple(float(x) for x in box)


def _image_id(check: _Checker, value: Any, where: str) -> int | str:
    if isinstance(value, str):
        return value
    return check.integer(value, where)


def _annotations_by_image(check: _Checker, doc: dict, image_ids: set) -> dict[Any, tuple[int, dict]]:
    by_image: dict[Any, tuple[int, dict]] = {}
    for i, ann in enumerate(check.list_(check.key(doc, "annotations", "top level"), "annotations")):
        where = f"annotations[{i}]"
        ann = check.obj(ann, where)
        image_id = _image_id(check, check.key(ann, "image_id", where), f"{where}.image_id")
        if image_id not in image_ids:
            check.fail(f"{where}.image_id", f"no image has id {image_id!r}")
        if image_id in by_image:
            check.fail(
                f"{where}.image_id",
                f"image {image_id!r} already has annotations[{by_image[image_id][0]}]; "
                "a DroneKey sequence has at most one drone per image",
            )
        by_image[image_id] = (i, ann)
    return by_image


# ====================================================================== reading: our layout


def _parse_ours(
    check: _Checker, doc: dict, camera: CameraModel | None, drone_override
) -> SequenceAnnotations:
    info = check.obj(check.key(doc, "info", "top level"), "info")
    cam = camera if camera is not None else _camera_from_object(check, doc["camera"])
    model, kp3d = drone_override or _keypoints_3d_from_object(check, doc["drone"])
    names = _keypoint_names(check, doc)
    name = info.get("sequence", check.path.stem)
    fps = info.get("fps", _DEFAULT_FPS)
    if isinstance(fps, bool) or not isinstance(fps, int | float) or not fps > 0 or not math.isfinite(fps):
        check.fail("info.fps", f"must be a positive number, got {_describe(fps)}")

    images = check.list_(check.key(doc, "images", "top level"), "images")
    parsed: list[tuple[int, Any, str, int, int, int]] = []
    seen_ids: set = set()
    for i, img in enumerate(images):
        where = f"images[{i}]"
        img = check.obj(img, where)
        image_id = _image_id(check, check.key(img, "id", where), f"{where}.id")
        if image_id in seen_ids:
            check.fail(f"{where}.id", f"duplicate image id {image_id!r}")
        seen_ids.add(image_id)
        parsed.append(
            (
                check.integer(check.key(img, "frame_index", where), f"{where}.frame_index", minimum=0),
                image_id,
                check.string(check.key(img, "file_name", where), f"{where}.file_name"),
                check.integer(check.key(img, "timestamp_ns", where), f"{where}.timestamp_ns"),
                check.integer(check.key(img, "width", where), f"{where}.width", minimum=1),
                check.integer(check.key(img, "height", where), f"{where}.height", minimum=1),
            )
        )
        if (parsed[-1][4], parsed[-1][5]) != cam.size:
            check.fail(
                where, f"image size {parsed[-1][4]}x{parsed[-1][5]} differs from the camera's {cam.size}"
            )
    indices = [p[0] for p in parsed]
    if len(set(indices)) != len(indices):
        check.fail("images", "frame_index values repeat")

    by_image = _annotations_by_image(check, doc, seen_ids)
    frames = []
    for frame_index, image_id, file_name, t_ns, width, height in sorted(parsed, key=lambda p: p[0]):
        drone = None
        if image_id in by_image:
            i, ann = by_image[image_id]
            where = f"annotations[{i}]"
            kp, flags = _keypoints_and_flags(check, ann, where)
            drone = DroneAnnotation(
                keypoints_px=kp,
                visibility=flags,
                bbox_xywh=_bbox(check, ann, where, kp, flags, required=True),
                rotation=check.rotation(
                    check.key(ann, "rotation", where), f"{where}.rotation", _ORTHONORMAL_TOL_OURS
                ),
                translation=check.numbers(check.key(ann, "translation", where), f"{where}.translation", (3,)),
            )
        frames.append(FrameRecord(frame_index, t_ns, file_name, width, height, drone))
    return SequenceAnnotations(
        name=str(name),
        camera=cam,
        drone_model=model,
        keypoints_3d=kp3d,
        fps=float(fps),
        frames=frames,
        info=info,
        keypoint_names=names,
        base_dir=check.path.parent,
    )


# ====================================================================== reading: real COCO files


@dataclass(frozen=True)
class _RawPose:
    """The pose numbers of one annotation as found, before decoding."""

    rotation: np.ndarray | None  # 3, 4 or 9 numbers (or None with pose6)
    translation: np.ndarray | None
    pose6: np.ndarray | None = None


def _raw_pose(check: _Checker, ann: dict, where: str) -> _RawPose | None:
    scopes = [(ann, where)] + [
        (ann[k], f"{where}.{k}") for k in _POSE_OBJECT_KEYS if isinstance(ann.get(k), dict)
    ]
    for scope, scope_where in scopes:
        rkey = next((k for k in _ROTATION_KEYS if k in scope), None)
        tkey = next((k for k in _TRANSLATION_KEYS if k in scope), None)
        if rkey and tkey:
            rot = check.numbers(scope[rkey], f"{scope_where}.{rkey}").ravel()
            if rot.size not in (3, 4, 9):
                check.fail(f"{scope_where}.{rkey}", f"a rotation has 3, 4 or 9 numbers, got {rot.size}")
            trans = check.numbers(scope[tkey], f"{scope_where}.{tkey}").ravel()
            if trans.size != 3:
                check.fail(f"{scope_where}.{tkey}", f"a translation has 3 numbers, got {trans.size}")
            return _RawPose(rot, trans)
        if rkey or tkey:
            check.fail(
                scope_where, f"has {rkey or tkey!r} but not its {'translation' if rkey else 'rotation'}"
            )
    for k in _POSE6_KEYS:
        if isinstance(ann.get(k), list):
            vec = check.numbers(ann[k], f"{where}.{k}").ravel()
            if vec.size != 6:
                check.fail(f"{where}.{k}", f"a 6DoF vector has 6 numbers, got {vec.size}")
            return _RawPose(None, None, vec)
    return None


@dataclass(frozen=True)
class _Decoding:
    """One way of turning raw pose numbers into (R body->camera, t metres)."""

    rotation: str
    unit: str
    pose6_order: str | None = None

    def __str__(self) -> str:
        order = f", 6-vector order {self.pose6_order}" if self.pose6_order else ""
        return f"rotation {self.rotation}, translation in {self.unit}{order}"

    def apply(self, raw: _RawPose) -> tuple[np.ndarray, np.ndarray] | None:
        rot, trans = raw.rotation, raw.translation
        if raw.pose6 is not None:
            rot, trans = (
                (raw.pose6[:3], raw.pose6[3:]) if self.pose6_order == "rt" else (raw.pose6[3:], raw.pose6[:3])
            )
        R = _decode_rotation(rot, self.rotation)
        return None if R is None else (R, trans * TRANSLATION_UNITS[self.unit])


def _decode_rotation(values: np.ndarray, encoding: str) -> np.ndarray | None:
    """Rotation matrix body -> camera, or None when the numbers do not fit the encoding."""
    n = values.size
    if encoding in ("matrix", "matrix_transposed"):
        if n != 9:
            return None
        R = _orthonormal_or_none(values.reshape(3, 3), _ORTHONORMAL_TOL_COCO)
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


def _candidate_decodings(raw: _RawPose, encoding: CocoPoseEncoding) -> list[_Decoding]:
    """Every decoding allowed by ``encoding`` that fits the size of the raw rotation."""
    rotations = ROTATION_ENCODINGS if encoding.rotation == "auto" else (encoding.rotation,)
    units = tuple(TRANSLATION_UNITS) if encoding.translation_unit == "auto" else (encoding.translation_unit,)
    orders: tuple[str | None, ...] = (None,)
    if raw.pose6 is not None:
        orders = ("rt", "tr") if encoding.pose6_order == "auto" else (encoding.pose6_order,)
    probe = raw.pose6[:3] if raw.pose6 is not None else raw.rotation
    fitting = [rot for rot in rotations if _decode_rotation(probe, rot) is not None]
    return [_Decoding(rot, unit, order) for order in orders for rot in fitting for unit in units]


def _reprojection_px(
    camera: CameraModel, kp3d: np.ndarray, R: np.ndarray, t: np.ndarray, kp: np.ndarray, flags: np.ndarray
) -> float:
    """RMS distance (px) between the labelled keypoints and the projection; inf behind the camera."""
    if np.any((kp3d @ R.T + t)[:, 2] <= 1e-6):
        return math.inf
    labelled = flags > 0
    err = camera.project_body(kp3d, R, t)[labelled] - kp[labelled]
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


def _choose_decoding(
    check: _Checker,
    samples: Sequence[tuple[str, _RawPose, np.ndarray, np.ndarray]],
    encoding: CocoPoseEncoding,
    camera: CameraModel,
    kp3d: np.ndarray,
) -> _Decoding:
    """The decoding whose poses reproject ``kp3d`` onto the annotated keypoints (median RMS px)."""
    first_where, first_raw = samples[0][0], samples[0][1]
    candidates = _candidate_decodings(first_raw, encoding)
    if not candidates:
        size = first_raw.rotation.size if first_raw.rotation is not None else 3
        check.fail(first_where, f"a rotation of {size} numbers cannot be read as {encoding.rotation}")
    scored = []
    for dec in candidates:
        errors = []
        for _, raw, kp, flags in samples:
            pose = dec.apply(raw)
            errors.append(math.inf if pose is None else _reprojection_px(camera, kp3d, *pose, kp, flags))
        scored.append((float(np.median(errors)), dec))
    best_err, best = min(scored, key=lambda s: s[0])
    spread = float(np.median([np.ptp(kp[flags > 0], axis=0).max() for _, _, kp, flags in samples]))
    tolerance = max(3.0, 0.05 * spread)
    explicit = (
        encoding.rotation != "auto"
        and encoding.translation_unit != "auto"
        and (first_raw.pose6 is None or encoding.pose6_order != "auto")
    )
    if best_err <= tolerance or explicit:
        log_fn = log.warning if best_err > tolerance else log.info
        log_fn("%s: pose encoding %s reprojects with a median error of %.3g px", check.path, best, best_err)
        return best
    check.fail(
        first_where,
        "cannot tell how the 6DoF is encoded: no reading of it reprojects the drone's keypoints_3d onto "
        f"the annotated keypoints (best: {best}, median {best_err:.3g} px over {len(samples)} annotations, "
        f"tolerance {tolerance:.3g} px). Check the camera (its calibration file), the drone model and its "
        "keypoint order, or name the encoding (CocoPoseEncoding / --rotation-encoding, --translation-unit)",
    )


def _natural_key(text: str) -> list:
    return [int(tok) if tok.isdigit() else tok for tok in re.split(r"(\d+)", text)]


def _infer_drone(check: _Checker, doc: dict) -> tuple[str, np.ndarray] | None:
    texts = [check.path.stem]
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
    log.info("%s: drone model %s inferred from the file's names", check.path, spec.name)
    return spec.name, spec.keypoints_3d


def _camera_beside(path: Path) -> CameraModel | None:
    beside = path.parent / "camera.yaml"
    if not beside.is_file():
        return None
    try:
        return CameraModel.load(beside)
    except CalibrationError as exc:
        raise SequenceFormatError(beside, "", f"beside {path.name}, unusable: {exc}") from None


def _parse_coco(
    check: _Checker,
    doc: dict,
    camera: CameraModel | None,
    drone_override: tuple[str, np.ndarray] | None,
    fps: float | None,
    encoding: CocoPoseEncoding,
) -> SequenceAnnotations:
    path = check.path
    info = doc.get("info") if isinstance(doc.get("info"), dict) else {}
    images = check.list_(check.key(doc, "images", "top level"), "images")
    parsed = []
    for i, img in enumerate(images):
        where = f"images[{i}]"
        img = check.obj(img, where)
        size = tuple(
            check.integer(img[k], f"{where}.{k}", minimum=1) if k in img else None
            for k in ("width", "height")
        )
        parsed.append(
            {
                "id": _image_id(check, check.key(img, "id", where), f"{where}.id"),
                "file_name": check.string(check.key(img, "file_name", where), f"{where}.file_name"),
                "frame_index": img.get("frame_index"),
                "timestamp_ns": img.get("timestamp_ns"),
                "size": size,
                "where": where,
            }
        )
    ids = [p["id"] for p in parsed]
    if len(set(ids)) != len(ids):
        check.fail("images", "image ids repeat")
    if parsed and all(isinstance(p["frame_index"], int) for p in parsed):
        parsed.sort(key=lambda p: p["frame_index"])
    else:
        parsed.sort(key=lambda p: _natural_key(p["file_name"]))
    by_image = _annotations_by_image(check, doc, set(ids))

    # Camera, drone, fps.
    if camera is None and isinstance(doc.get("camera"), dict):
        camera = _camera_from_object(check, doc["camera"])
    camera = camera or _camera_beside(path)
    if camera is None:
        check.fail(
            "",
            "the file has no 'camera' object and there is no camera.yaml beside it: pass the camera's "
            "calibration (dronekey-sim --verify FILE --calib CAMERA.yaml, or load_sequence(..., camera=...))",
        )
    sizes = {p["size"] for p in parsed if None not in p["size"]}
    if len(sizes) > 1:
        check.fail("images", f"images of different sizes in one sequence: {sorted(sizes)}")
    if sizes:
        try:
            camera = camera.scaled_to(*sizes.pop())
        except CalibrationError as exc:
            check.fail("images", str(exc))
    if drone_override is None and isinstance(doc.get("drone"), dict):
        drone_override = _keypoints_3d_from_object(check, doc["drone"])
    drone = drone_override or _infer_drone(check, doc)
    if drone is None:
        check.fail(
            "",
            "cannot tell the drone model (no 'drone' object, and no single shipped spec name among "
            f"{', '.join(available_specs())} in the category, info or file name): pass it "
            "(--drone NAME|SPEC.yaml, or load_sequence(..., drone=...))",
        )
    model, kp3d = drone
    if fps is None:
        fps = info.get("fps") if isinstance(info.get("fps"), int | float) and info.get("fps", 0) > 0 else None
    if fps is None:
        log.info("%s: no fps in the file; timestamps assume %g fps", path, _DEFAULT_FPS)
        fps = _DEFAULT_FPS

    # Keypoints and raw poses.
    entries = []  # (record index, where, kp, flags, bbox, raw pose)
    for index, p in enumerate(parsed):
        if p["id"] not in by_image:
            continue
        i, ann = by_image[p["id"]]
        where = f"annotations[{i}]"
        kp, flags = _keypoints_and_flags(check, ann, where)
        if not np.any(flags > 0):
            continue  # nothing labelled: a frame without a usable drone annotation
        bbox = _bbox(check, ann, where, kp, flags, required=False)
        entries.append((index, where, kp, flags, bbox, _raw_pose(check, ann, where)))
    with_pose = [e for e in entries if e[5] is not None]
    if with_pose and len(with_pose) != len(entries):
        missing = next(e for e in entries if e[5] is None)
        check.fail(missing[1], "has no rotation / translation while other annotations do")
    decoding = None
    if with_pose:
        kinds = {(e[5].rotation.size if e[5].rotation is not None else 6) for e in with_pose}
        if len(kinds) > 1:
            check.fail("annotations", f"rotations of different lengths {sorted(kinds)} in one file")
        usable = [e for e in with_pose if np.count_nonzero(e[3]) >= 3]
        step = max(1, len(usable) // _AUTO_SAMPLE)
        samples = [(e[1], e[5], e[2], e[3]) for e in usable[::step]] or [
            (e[1], e[5], e[2], e[3]) for e in with_pose[:1]
        ]
        decoding = _choose_decoding(check, samples, encoding, camera, kp3d)

    drones: dict[int, DroneAnnotation] = {}
    for index, where, kp, flags, bbox, raw in entries:
        R = t = None
        if decoding is not None:
            pose = decoding.apply(raw)
            if pose is None:
                check.fail(where, f"pose does not decode as {decoding}")
            R, t = pose
        drones[index] = DroneAnnotation(kp, flags, bbox, R, t)

    frames = []
    for index, p in enumerate(parsed):
        width, height = p["size"] if None not in p["size"] else camera.size
        t_ns = p["timestamp_ns"]
        if not isinstance(t_ns, int) or isinstance(t_ns, bool):
            t_ns = round(index * 1e9 / fps)
        frames.append(FrameRecord(index, t_ns, p["file_name"], width, height, drones.get(index)))
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
        keypoint_names=_keypoint_names(check, doc),
        base_dir=path.parent,
    )


# ====================================================================== reading: entry point


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
    drone_override = None
    if drone is not None:
        spec = load_spec(drone)
        drone_override = (spec.name, spec.keypoints_3d)
    if fps is not None and not (isinstance(fps, int | float) and math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number, got {fps!r}")
    doc = _read_document(path)
    check = _Checker(path)
    if "camera" in doc and "drone" in doc:
        return _parse_ours(check, doc, camera, drone_override)
    return _parse_coco(check, doc, camera, drone_override, fps, pose_encoding or CocoPoseEncoding())
