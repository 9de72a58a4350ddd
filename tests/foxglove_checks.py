"""Decode and validate the Foxglove log's messages with Foxglove's published protobuf schemas.

The reference is ``foxglove-schemas-protobuf`` (Foxglove's own generated ``*_pb2`` modules), not the
schema the writer put in the file: a channel's ``FileDescriptorSet`` must describe the same message
as the published one, and each message must parse with the published class, carry no field the
published schema lacks, and re-encode to the same bytes.
"""

from __future__ import annotations

import importlib

from google.protobuf import descriptor_pb2
from google.protobuf.message import Message
from json_checks import strict_json

_PB2_MODULE = {"GeoJSON": "GeoJSON_pb2"}


def published_class(schema_name: str) -> type[Message]:
    """The published protobuf class of ``foxglove.<Name>``."""
    package, _, name = schema_name.partition(".")
    assert package == "foxglove", schema_name
    module = importlib.import_module(f"foxglove_schemas_protobuf.{_PB2_MODULE.get(name, name + '_pb2')}")
    return getattr(module, name)


def _fields(descriptor) -> list[tuple]:
    return sorted(
        (
            f.name,
            f.number,
            f.type,
            f.is_repeated,
            (f.message_type or f.enum_type).full_name if (f.message_type or f.enum_type) else "",
        )
        for f in descriptor.fields
    )


def schema_matches_published(schema_name: str, schema_data: bytes) -> list[str]:
    """Where the channel's ``FileDescriptorSet`` differs from the published schema (empty: none)."""
    published = published_class(schema_name).DESCRIPTOR
    files = descriptor_pb2.FileDescriptorSet.FromString(schema_data).file
    by_name = {f"{f.package}.{m.name}": m for f in files for m in f.message_type}
    problems = []
    for full_name, message in by_name.items():
        if not full_name.startswith("foxglove."):
            continue
        reference = published.file.pool.FindMessageTypeByName(full_name)
        ours = sorted(
            (f.name, f.number, f.type, f.label == f.LABEL_REPEATED, f.type_name.lstrip("."))
            for f in message.field
        )
        if ours != _fields(reference):
            problems.append(f"{full_name}: {ours} != {_fields(reference)}")
    if schema_name not in by_name:
        problems.append(f"{schema_name} is not in the channel's descriptor set")
    return problems


def decode(schema_name: str, encoding: str, data: bytes):
    """A message decoded by its channel's encoding: the published protobuf class, or strict JSON."""
    if encoding == "json":
        return strict_json(data)
    assert encoding == "protobuf", encoding
    message = published_class(schema_name).FromString(data)
    unknown = _unknown_fields(message)
    assert not unknown, f"{schema_name}: fields the published schema lacks: {unknown}"
    assert message.SerializeToString() == data, f"{schema_name}: does not re-encode to the same bytes"
    return message


def _unknown_fields(message: Message) -> list[str]:
    from google.protobuf import unknown_fields

    found = [
        f"{message.DESCRIPTOR.full_name}#{f.field_number}" for f in unknown_fields.UnknownFieldSet(message)
    ]
    for field, value in message.ListFields():
        if field.message_type is None:
            continue
        values = value if field.is_repeated else [value]
        for item in values:
            if isinstance(item, Message):
                found += _unknown_fields(item)
    return found
