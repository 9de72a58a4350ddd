"""The channels of the Foxglove log (docs/design.md §6.3): topic, schema and encoding, shared by the
MCAP file and the live WebSocket view so both carry the same bytes.

Foxglove's own message types use Foxglove's published protobuf schemas (the ``FileDescriptorSet``
that ``foxglove-sdk`` ships with its message classes): schema encoding ``protobuf``, messages
``protobuf``. The project's track and status messages keep their JSON schemas (``jsonschema`` /
``json``), reduced to what Foxglove's JSON schema parser types (``foxglove_compatible``).
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass

from foxglove import messages as fgm

from dronekey.daemon import messages

__all__ = ["GEO_TOPICS", "TOPICS", "ChannelSpec", "channel_specs", "foxglove_compatible"]


@dataclass(frozen=True)
class ChannelSpec:
    """One channel: its schema (name, encoding, bytes) and the encoding of its messages."""

    topic: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    message_encoding: str


_PROTOBUF_TOPICS: dict[str, type] = {
    "/camera/image": fgm.CompressedImage,
    "/camera/calibration": fgm.CameraCalibration,
    "/dronekey/annotations": fgm.ImageAnnotations,
    "/tf": fgm.FrameTransforms,
    "/dronekey/scene": fgm.SceneUpdate,
    "/camera/fix": fgm.LocationFix,
    "/camera/fov": fgm.GeoJson,
    "/dronekey/fix": fgm.LocationFix,
}
_JSON_TOPICS = {
    "/dronekey/tracks": ("dronekey.Track", "track"),
    "/dronekey/status": ("dronekey.Status", "status"),
}

# Topics written only with the camera's geodetic pose (--camera-geo).
GEO_TOPICS = ("/camera/fix", "/camera/fov", "/dronekey/fix")

# topic -> schema name, in the order channels are declared.
TOPICS: dict[str, str] = {
    **{topic: cls.get_schema().name for topic, cls in _PROTOBUF_TOPICS.items()},
    **{topic: name for topic, (name, _) in _JSON_TOPICS.items()},
}


def channel_specs(with_geo: bool) -> list[ChannelSpec]:
    """Every channel of the log; the map channels (``GEO_TOPICS``) only ``with_geo``."""
    specs = []
    for topic, cls in _PROTOBUF_TOPICS.items():
        if topic in GEO_TOPICS and not with_geo:
            continue
        schema = cls.get_schema()
        specs.append(ChannelSpec(topic, schema.name, schema.encoding, bytes(schema.data), "protobuf"))
    for topic, (name, contract) in _JSON_TOPICS.items():
        data = json.dumps(foxglove_compatible(messages.load_schema(contract)), separators=(",", ":")).encode()
        specs.append(ChannelSpec(topic, name, "jsonschema", data, "json"))
    return specs


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
    before = list(props)
    for name in before:
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
    if set(before) - set(props):
        node["required"] = [k for k in node.get("required", []) if k in props]
        node.pop("additionalProperties", None)  # the removed fields are still in the messages
