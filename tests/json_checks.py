"""JSON checks shared by the tests of the daemon's messages (Zenoh, MCAP): ``from json_checks import ...``.

``schema_errors`` is a small JSON Schema (draft 2020-12) validator covering the keywords our schemas
and Foxglove's use (jsonschema is not a dependency); ``strict_json`` parses refusing NaN and Infinity.
"""

from __future__ import annotations

import base64
import binascii
import json
import math

_TYPES = {
    "object": lambda v: isinstance(v, dict),
    "array": lambda v: isinstance(v, list),
    "string": lambda v: isinstance(v, str),
    "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v),
    "boolean": lambda v: isinstance(v, bool),
    "null": lambda v: v is None,
}


def schema_errors(value, schema: dict, path: str = "$") -> list[str]:
    """Violations of ``schema`` by ``value`` (empty when valid)."""
    errors: list[str] = []
    kinds = schema.get("type")
    if kinds is not None:
        kinds = kinds if isinstance(kinds, list) else [kinds]
        if not any(_TYPES[k](value) for k in kinds):
            return [f"{path}: {value!r} is not of type {kinds}"]
    if "const" in schema and value != schema["const"]:
        errors.append(f"{path}: {value!r} != const {schema['const']!r}")
    if "enum" in schema and value not in schema["enum"]:
        errors.append(f"{path}: {value!r} not in {schema['enum']}")
    if "oneOf" in schema:
        matches = sum(not schema_errors(value, alt, path) for alt in schema["oneOf"])
        if matches != 1:
            errors.append(f"{path}: {value!r} matches {matches} of oneOf, not 1")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if "minimum" in schema and value < schema["minimum"]:
            errors.append(f"{path}: {value} < minimum {schema['minimum']}")
        if "maximum" in schema and value > schema["maximum"]:
            errors.append(f"{path}: {value} > maximum {schema['maximum']}")
    if isinstance(value, str) and schema.get("contentEncoding") == "base64":
        try:
            base64.b64decode(value, validate=True)
        except binascii.Error:
            errors.append(f"{path}: not base64")
    if isinstance(value, list):
        if len(value) < schema.get("minItems", 0):
            errors.append(f"{path}: {len(value)} items < minItems {schema['minItems']}")
        if len(value) > schema.get("maxItems", math.inf):
            errors.append(f"{path}: {len(value)} items > maxItems {schema['maxItems']}")
        if "items" in schema:
            for i, item in enumerate(value):
                errors += schema_errors(item, schema["items"], f"{path}[{i}]")
    if isinstance(value, dict):
        props = schema.get("properties", {})
        errors += [f"{path}: lacks required {k!r}" for k in schema.get("required", []) if k not in value]
        for key, deps in schema.get("dependentRequired", {}).items():
            if key in value:
                errors += [f"{path}: {key!r} requires {d!r}" for d in deps if d not in value]
        extra = schema.get("additionalProperties", True)
        for key, item in value.items():
            if key in props:
                errors += schema_errors(item, props[key], f"{path}.{key}")
            elif extra is False:
                errors.append(f"{path}: unexpected property {key!r}")
            elif isinstance(extra, dict):
                errors += schema_errors(item, extra, f"{path}.{key}")
    return errors


def strict_json(payload: bytes):
    """Parse JSON refusing the non-standard NaN / Infinity tokens."""

    def refuse(token):
        raise ValueError(f"invalid JSON token {token}")

    return json.loads(payload, parse_constant=refuse)
