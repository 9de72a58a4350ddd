"""Foxglove message schemas (JSON Schema flavour) and builders for the MCAP log (docs/design.md §6.3).

The schemas follow Foxglove's published JSON schemas (github.com/foxglove/foxglove-sdk,
``schemas/jsonschema``) field for field: timestamps are ``{sec, nsec}``, quaternions ``x, y, z, w``,
image data base64 (``contentEncoding: base64``), 2D image coordinates with the origin at the
top-left *corner* of the top-left pixel. The optional ``message_id``/``lineage`` fields added in
recent SDK versions are left out; Foxglove does not need them.

Foxglove reads a ``jsonschema`` channel with a small parser (``parseJsonSchema`` in Foxglove's MCAP
support) that accepts only one ``type`` per field, arrays of scalars or objects, objects with
``properties`` and ``oneOf`` of numeric constants. ``foxglove_compatible`` turns a standard schema
(like DroneKey's track and status schemas, which have nullable fields and 3x3 nested lists) into
that subset so Foxglove can load the channel; the messages stay the same bytes.
"""

from __future__ import annotations

import base64
import copy
import logging
import math
from collections.abc import Iterable

import numpy as np

from dronekey.daemon import messages
from dronekey.geometry.camera import CameraModel
from dronekey.types import KeypointDetection, Track, TrackStatus

__all__ = [
    "FOXGLOVE_SCHEMAS",
    "HEADING_LABEL_MIN",
    "camera_calibration",
    "compressed_image",
    "foxglove_compatible",
    "frame_transforms",
    "image_annotations",
    "scaled_camera",
    "timestamp",
    "track_label",
]

log = logging.getLogger(__name__)

POINTS, LINE_LOOP = 1, 2  # foxglove.PointsAnnotationType values

# Keypoint order colours (RGBA in [0, 1]): 1 red, 2 green, 3 blue, 4 yellow.
_KEYPOINT_COLOURS = (
    {"r": 1.0, "g": 0.2, "b": 0.2, "a": 1.0},
    {"r": 0.2, "g": 1.0, "b": 0.2, "a": 1.0},
    {"r": 0.3, "g": 0.5, "b": 1.0, "a": 1.0},
    {"r": 1.0, "g": 0.9, "b": 0.1, "a": 1.0},
)
_ROI_COLOUR = {"r": 0.0, "g": 0.9, "b": 1.0, "a": 1.0}
_TRACK_COLOUR = {"r": 1.0, "g": 0.6, "b": 0.0, "a": 1.0}
_CLEAR = {"r": 0.0, "g": 0.0, "b": 0.0, "a": 0.0}
_LABEL_BACKGROUND = {"r": 0.0, "g": 0.0, "b": 0.0, "a": 0.6}
# Below this heading confidence a track label says "heading ?": the front may be the back.
HEADING_LABEL_MIN = 0.5


# --------------------------------------------------------------------------- schema pieces
def _time_schema(description: str) -> dict:
    return {
        "type": "object",
        "title": "time",
        "properties": {
            "sec": {"type": "integer", "minimum": 0},
            "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
        },
        "description": description,
    }


def _xyz_schema(title: str, description: str, names: str, unit: str) -> dict:
    return {
        "title": title,
        "description": description,
        "type": "object",
        "properties": {n: {"type": "number", "description": f"{n} {unit}"} for n in names},
        "required": list(names),
    }


def _color_schema(description: str) -> dict:
    words = {"r": "Red", "g": "Green", "b": "Blue", "a": "Alpha"}
    return {
        "title": "foxglove.Color",
        "description": description,
        "type": "object",
        "properties": {
            k: {"type": "number", "description": f"{w} value between 0 and 1"} for k, w in words.items()
        },
        "required": list(words),
    }


def _point2_schema(description: str) -> dict:
    return _xyz_schema("foxglove.Point2", description, "xy", "coordinate position")


def _metadata_schema() -> dict:
    return {
        "type": "array",
        "items": {
            "title": "foxglove.KeyValuePair",
            "description": "A key with its associated value",
            "type": "object",
            "properties": {
                "key": {"type": "string", "description": "Key"},
                "value": {"type": "string", "description": "Value"},
            },
            "required": ["key", "value"],
        },
        "description": "Additional user-provided metadata associated with the annotation. "
        "Keys must be unique.",
    }


_IMAGE_FRAME = (
    "Frame of reference for the {what}. The origin of the frame is the optical center of the camera. "
    "+x points to the right in the image, +y points down, and +z points into the plane of the image."
)
_CORNER_ORIGIN = "The coordinate uses the top-left corner of the top-left pixel of the image as the origin."


def _compressed_image_schema() -> dict:
    return {
        "title": "foxglove.CompressedImage",
        "description": "A compressed image",
        "type": "object",
        "properties": {
            "timestamp": _time_schema("Timestamp of image"),
            "frame_id": {"type": "string", "description": _IMAGE_FRAME.format(what="image")},
            "data": {"type": "string", "contentEncoding": "base64", "description": "Compressed image data"},
            "format": {
                "type": "string",
                "description": "Image format\n\nSupported values: `jpeg`, `png`, `webp`, `avif`",
            },
        },
        "required": ["timestamp", "frame_id", "data", "format"],
    }


def _matrix_schema(n: int, description: str) -> dict:
    return {
        "type": "array",
        "items": {"type": "number"},
        "minItems": n,
        "maxItems": n,
        "description": description,
    }


def _camera_calibration_schema() -> dict:
    return {
        "title": "foxglove.CameraCalibration",
        "description": "Camera calibration parameters",
        "type": "object",
        "properties": {
            "timestamp": _time_schema("Timestamp of calibration data"),
            "frame_id": {"type": "string", "description": _IMAGE_FRAME.format(what="camera")},
            "width": {"type": "integer", "minimum": 0, "description": "Image width"},
            "height": {"type": "integer", "minimum": 0, "description": "Image height"},
            "distortion_model": {
                "type": "string",
                "description": "Name of distortion model: `plumb_bob` (k1, k2, p1, p2, k3), "
                "`rational_polynomial` (k1, k2, p1, p2, k3, k4, k5, k6) or `kannala_brandt` (k1, k2, k3, k4)",
            },
            "D": {"type": "array", "items": {"type": "number"}, "description": "Distortion parameters"},
            "K": _matrix_schema(
                9, "Intrinsic camera matrix (3x3 row-major matrix) for the raw (distorted) image"
            ),
            "R": _matrix_schema(9, "Rectification matrix (stereo cameras only, 3x3 row-major matrix)"),
            "P": _matrix_schema(12, "Projection/camera matrix (3x4 row-major matrix)"),
        },
    }


def _annotation_common(timestamp_description: str) -> dict:
    return {"timestamp": _time_schema(timestamp_description)}


def _image_annotations_schema() -> dict:
    circle = {
        "title": "foxglove.CircleAnnotation",
        "description": "A circle annotation on a 2D image",
        "type": "object",
        "properties": {
            **_annotation_common("Timestamp of circle"),
            "position": _point2_schema(
                f"Center of the circle in 2D image coordinates (pixels).\n{_CORNER_ORIGIN}"
            ),
            "diameter": {"type": "number", "description": "Circle diameter in pixels"},
            "thickness": {"type": "number", "description": "Line thickness in pixels"},
            "fill_color": _color_schema("Fill color"),
            "outline_color": _color_schema("Outline color"),
            "metadata": _metadata_schema(),
        },
        "required": [
            "timestamp",
            "position",
            "diameter",
            "thickness",
            "fill_color",
            "outline_color",
            "metadata",
        ],
    }
    points = {
        "title": "foxglove.PointsAnnotation",
        "description": "An array of points on a 2D image",
        "type": "object",
        "properties": {
            **_annotation_common("Timestamp of annotation"),
            "type": {
                "title": "foxglove.PointsAnnotationType",
                "description": "Type of points annotation to draw",
                "oneOf": [
                    {"title": "UNKNOWN", "const": 0, "description": "Unknown points annotation type"},
                    {"title": "POINTS", "const": 1, "description": "Individual points: 0, 1, 2, ..."},
                    {
                        "title": "LINE_LOOP",
                        "const": 2,
                        "description": "Closed polygon: 0-1, 1-2, ..., (n-1)-n, n-0",
                    },
                    {
                        "title": "LINE_STRIP",
                        "const": 3,
                        "description": "Connected line segments: 0-1, 1-2, ..., (n-1)-n",
                    },
                    {
                        "title": "LINE_LIST",
                        "const": 4,
                        "description": "Individual line segments: 0-1, 2-3, 4-5, ...",
                    },
                ],
            },
            "points": {
                "type": "array",
                "items": _point2_schema("A point representing a position in 2D space"),
                "description": f"Points in 2D image coordinates (pixels).\n{_CORNER_ORIGIN}",
            },
            "outline_color": _color_schema("Outline color"),
            "outline_colors": {
                "type": "array",
                "items": _color_schema("A color in RGBA format"),
                "description": "Per-point colors, if `type` is `POINTS`, or per-segment stroke colors, "
                "if `type` is "
                "`LINE_LIST`, `LINE_STRIP` or `LINE_LOOP`.",
            },
            "fill_color": _color_schema("Fill color"),
            "thickness": {"type": "number", "description": "Stroke thickness in pixels"},
            "metadata": _metadata_schema(),
        },
        "required": [
            "timestamp",
            "type",
            "points",
            "outline_color",
            "outline_colors",
            "fill_color",
            "thickness",
            "metadata",
        ],
    }
    text = {
        "title": "foxglove.TextAnnotation",
        "description": "A text label on a 2D image",
        "type": "object",
        "properties": {
            **_annotation_common("Timestamp of annotation"),
            "position": _point2_schema(
                f"Bottom-left origin of the text label in 2D image coordinates (pixels).\n{_CORNER_ORIGIN}"
            ),
            "text": {"type": "string", "description": "Text to display"},
            "font_size": {"type": "number", "description": "Font size in pixels"},
            "text_color": _color_schema("Text color"),
            "background_color": _color_schema("Background fill color"),
            "metadata": _metadata_schema(),
        },
        "required": [
            "timestamp",
            "position",
            "text",
            "font_size",
            "text_color",
            "background_color",
            "metadata",
        ],
    }
    return {
        "title": "foxglove.ImageAnnotations",
        "description": "Array of annotations for a 2D image",
        "type": "object",
        "properties": {
            "circles": {"type": "array", "items": circle, "description": "Circle annotations"},
            "points": {"type": "array", "items": points, "description": "Points annotations"},
            "texts": {"type": "array", "items": text, "description": "Text annotations"},
        },
        "required": ["circles", "points", "texts"],
    }


def _frame_transforms_schema() -> dict:
    transform = {
        "title": "foxglove.FrameTransform",
        "description": "A transform between two reference frames in 3D space. "
        "The transform defines the position "
        "and orientation of a child frame within a parent frame.",
        "type": "object",
        "properties": {
            "timestamp": _time_schema("Timestamp of transform"),
            "parent_frame_id": {"type": "string", "description": "Name of the parent frame"},
            "child_frame_id": {"type": "string", "description": "Name of the child frame"},
            "translation": _xyz_schema(
                "foxglove.Vector3",
                "Translation component of the transform, representing the position of the child frame's "
                "origin in the parent frame.",
                "xyz",
                "coordinate length",
            ),
            "rotation": _xyz_schema(
                "foxglove.Quaternion",
                "Rotation component of the transform, representing the orientation of the child frame in the "
                "parent frame",
                "xyzw",
                "value",
            ),
        },
        "required": ["timestamp", "parent_frame_id", "child_frame_id", "translation", "rotation"],
    }
    return {
        "title": "foxglove.FrameTransforms",
        "description": "An array of FrameTransform messages",
        "type": "object",
        "properties": {
            "transforms": {"type": "array", "items": transform, "description": "Array of transforms"}
        },
        "required": ["transforms"],
    }


FOXGLOVE_SCHEMAS: dict[str, dict] = {
    "foxglove.CompressedImage": _compressed_image_schema(),
    "foxglove.CameraCalibration": _camera_calibration_schema(),
    "foxglove.ImageAnnotations": _image_annotations_schema(),
    "foxglove.FrameTransforms": _frame_transforms_schema(),
}


# --------------------------------------------------------------------------- schema subset
def foxglove_compatible(schema: dict) -> dict:
    """A copy of a JSON schema reduced to what Foxglove's ``jsonschema`` parser accepts.

    ``"type": [T, "null"]`` becomes ``"type": T`` (the values may still be null); properties Foxglove
    cannot type (arrays of arrays, objects without ``properties``) are removed from ``properties``
    and named in the schema's ``$comment`` (the messages still carry them); keywords the parser does
    not know are kept, it ignores them. The result types the fields for Foxglove; the original
    schema stays the one to validate messages with.
    """
    out = copy.deepcopy(schema)
    dropped: list[str] = []
    _reduce_object(out, "", dropped)
    if dropped:
        note = "Foxglove cannot type these fields; they are in the messages: " + ", ".join(dropped)
        out["$comment"] = f"{out['$comment']} {note}" if "$comment" in out else note
    return out


def _single_type(node: dict) -> str | None:
    kind = node.get("type")
    if isinstance(kind, list):
        kinds = [k for k in kind if k != "null"]
        kind = kinds[0] if len(kinds) == 1 else None
        if kind is not None:
            node["type"] = kind
    return kind


def _reduce_object(node: dict, path: str, dropped: list[str]) -> None:
    props = node.get("properties") or {}
    schema_props_before = list(props)
    for name in schema_props_before:
        field = props[name]
        where = f"{path}{name}"
        kind = _single_type(field)
        if "oneOf" in field and all(isinstance(alt.get("const"), (int, float)) for alt in field["oneOf"]):
            continue
        if kind == "object" and field.get("properties"):
            _reduce_object(field, f"{where}.", dropped)
        elif kind == "array":
            items = field.get("items") or {}
            item_kind = _single_type(items)
            if item_kind == "object" and items.get("properties"):
                _reduce_object(items, f"{where}[].", dropped)
            elif item_kind not in ("boolean", "string", "number", "integer"):
                del props[name]
                dropped.append(where)
        elif kind not in ("boolean", "string", "number", "integer"):
            del props[name]
            dropped.append(where)
    if set(schema_props_before) - set(props):
        node["required"] = [k for k in node.get("required", []) if k in props]
        node.pop("additionalProperties", None)  # the removed fields are still in the messages


# --------------------------------------------------------------------------- builders
def timestamp(t_ns: int) -> dict[str, int]:
    """Foxglove ``time`` of an integer ns timestamp (negative times clamp to 0)."""
    sec, nsec = divmod(max(int(t_ns), 0), 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def compressed_image(t_ns: int, frame_id: str, jpeg: bytes) -> dict:
    """``foxglove.CompressedImage`` of JPEG bytes."""
    return {
        "timestamp": timestamp(t_ns),
        "frame_id": frame_id,
        "data": base64.b64encode(jpeg).decode("ascii"),
        "format": "jpeg",
    }


def scaled_camera(camera: CameraModel, width: int, height: int) -> CameraModel:
    """``camera`` for an image resized to ``width`` x ``height`` (as cv2.resize maps pixel centres).

    Unlike ``CameraModel.scaled_to`` this allows the rounding of an odd size to change the aspect
    ratio by a fraction of a pixel: x and y scale separately, exactly as the resize does.
    """
    sx, sy = width / camera.width, height / camera.height
    K = camera.K.copy()
    K[0, 0] *= sx
    K[0, 1] *= sx
    K[1, 1] *= sy
    K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return CameraModel(width, height, K, camera.dist.copy(), camera.rms_px)


def _distortion(dist: np.ndarray) -> tuple[str, list[float]]:
    d = [float(v) for v in dist]
    if len(d) <= 5:
        return "plumb_bob", d + [0.0] * (5 - len(d))
    if len(d) > 8 and any(d[8:]):
        log.warning("Foxglove's camera models take at most 8 distortion coefficients; dropping %s", d[8:])
    return "rational_polynomial", d[:8]


def camera_calibration(t_ns: int, frame_id: str, camera: CameraModel) -> dict:
    """``foxglove.CameraCalibration`` of an OpenCV camera model (monocular: R = I, P = [K | 0])."""
    model, D = _distortion(camera.dist)
    K = camera.K
    P = np.hstack([K, np.zeros((3, 1))])
    return {
        "timestamp": timestamp(t_ns),
        "frame_id": frame_id,
        "width": camera.width,
        "height": camera.height,
        "distortion_model": model,
        "D": D,
        "K": [float(v) for v in K.ravel()],
        "R": [float(v) for v in np.eye(3).ravel()],
        "P": [float(v) for v in P.ravel()],
    }


def _corner_point(u: float, v: float, sx: float, sy: float) -> dict[str, float]:
    """Full-frame pixel (centre origin) -> Foxglove point in the resized image (corner origin)."""
    return {"x": (float(u) + 0.5) * sx, "y": (float(v) + 0.5) * sy}


def _points(t: dict, kind: int, pts: list[dict], colour: dict, colours: list[dict], thickness: float) -> dict:
    return {
        "timestamp": t,
        "type": kind,
        "points": pts,
        "outline_color": colour,
        "outline_colors": colours,
        "fill_color": _CLEAR,
        "thickness": thickness,
        "metadata": [],
    }


def _text(t: dict, position: dict, text: str, colour: dict, font_size: float) -> dict:
    return {
        "timestamp": t,
        "position": position,
        "text": text,
        "font_size": font_size,
        "text_color": colour,
        "background_color": _LABEL_BACKGROUND,
        "metadata": [],
    }


def track_label(track: Track) -> str:
    """The text beside a track in the image: ``#<id> <status> <range> m  heading <confidence>``.

    The range is the distance from the camera, m, left out when unknown. The heading part is
    ``Track.heading_confidence`` with two decimals, or ``heading ?`` when it is below
    ``HEADING_LABEL_MIN`` (0.5) or unknown (NaN): the front is not known, so the drone's frame on
    ``/tf`` may point backwards. Example: ``#3 confirmed 12.4 m  heading 0.82``.

    Raises
    ------
    ValueError
        Naming ``heading_confidence`` if it is outside [0, 1].
    """
    rng = float(np.linalg.norm(np.asarray(track.position_m, dtype=np.float64)))
    status = track.status.value if isinstance(track.status, TrackStatus) else str(track.status)
    label = f"#{track.track_id} {status}"
    if math.isfinite(rng):
        label += f" {rng:.1f} m"
    confidence = messages.check_heading_confidence(track.heading_confidence)
    # NaN compares False: unknown reads as "?" too.
    heading = f"{confidence:.2f}" if confidence >= HEADING_LABEL_MIN else "?"
    return f"{label}  heading {heading}"


def image_annotations(
    t_ns: int,
    detection: KeypointDetection | None,
    tracks: Iterable[Track] = (),
    scale: tuple[float, float] = (1.0, 1.0),
) -> dict:
    """``foxglove.ImageAnnotations`` of one frame: the detection's 4 keypoints with their order labels
    1-4, the crop ROI as a box, and a label per track that has keypoints (``track_label``: id,
    status, range and heading confidence).

    Parameters
    ----------
    t_ns : int
        Frame time, ns (the image's timestamp, so Foxglove pairs them).
    detection : KeypointDetection or None
        Keypoints in full-frame pixels (centre origin) and the ROI (x0, y0, side).
    tracks : iterable of Track
    scale : (sx, sy)
        Size of the published image over the full frame's (the JPEG may be downscaled).
    """
    sx, sy = scale
    t = timestamp(t_ns)
    font = max(10.0, 24.0 * sy)
    points, texts = [], []
    if detection is not None:
        kp = np.asarray(detection.keypoints_px, dtype=np.float64).reshape(-1, 2)
        finite = [i for i in range(len(kp)) if np.all(np.isfinite(kp[i]))]
        pts = [_corner_point(kp[i, 0], kp[i, 1], sx, sy) for i in finite]
        colours = [_KEYPOINT_COLOURS[i % 4] for i in finite]
        points.append(_points(t, POINTS, pts, _KEYPOINT_COLOURS[0], colours, max(4.0, 10.0 * sx)))
        for i, p in zip(finite, pts, strict=True):
            label_at = {"x": p["x"] + 6.0 * sx, "y": p["y"] - 6.0 * sy}
            texts.append(_text(t, label_at, str(i + 1), _KEYPOINT_COLOURS[i % 4], font))
        x0, y0, side = (float(v) for v in detection.roi)
        box = [(x0, y0), (x0 + side, y0), (x0 + side, y0 + side), (x0, y0 + side)]  # corner coordinates
        box_pts = [{"x": x * sx, "y": y * sy} for x, y in box]
        points.append(_points(t, LINE_LOOP, box_pts, _ROI_COLOUR, [], max(1.0, 2.0 * sx)))
        texts.append(
            _text(t, {"x": x0 * sx, "y": y0 * sy - 4.0}, f"p={detection.presence:.2f}", _ROI_COLOUR, font)
        )
    for track in tracks:
        if track.keypoints_px is None or track.status == TrackStatus.LOST:
            continue
        kp = np.asarray(track.keypoints_px, dtype=np.float64).reshape(-1, 2)
        if not np.all(np.isfinite(kp)):
            continue
        label = track_label(track)
        corner = _corner_point(kp[:, 0].min(), kp[:, 1].max(), sx, sy)
        texts.append(_text(t, {"x": corner["x"], "y": corner["y"] + font * 1.2}, label, _TRACK_COLOUR, font))
    return {"circles": [], "points": points, "texts": texts}


def frame_transforms(t_ns: int, parent_frame_id: str, tracks: Iterable[Track]) -> dict:
    """``foxglove.FrameTransforms`` camera -> ``drone_<track_id>`` for each track with a finite pose.

    The drone frame is the body frame (FRD) placed by ``p_cam = R @ p_body + t``: translation is
    ``position_m``, rotation the body -> camera quaternion in Foxglove's (x, y, z, w) order.
    """
    t = timestamp(t_ns)
    transforms = []
    for track in tracks:
        p = np.asarray(track.position_m, dtype=np.float64).reshape(-1)
        q = np.asarray(track.quaternion_wxyz, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or q.shape != (4,) or not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
            continue
        norm = float(np.linalg.norm(q))
        if norm < 1e-12:
            continue
        q = q / norm
        transforms.append(
            {
                "timestamp": t,
                "parent_frame_id": parent_frame_id,
                "child_frame_id": f"drone_{int(track.track_id)}",
                "translation": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])},
                "rotation": {"x": float(q[1]), "y": float(q[2]), "z": float(q[3]), "w": float(q[0])},
            }
        )
    return {"transforms": transforms}
