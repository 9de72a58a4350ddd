"""Foxglove's message schemas (JSON Schema flavour) for the MCAP log, and the subset its parser takes.

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

import copy

__all__ = ["FOXGLOVE_SCHEMAS", "foxglove_compatible"]


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
