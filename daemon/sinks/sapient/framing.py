"""SAPIENT's TCP framing: each ``SapientMessage`` is preceded by its length, 4 bytes little-endian.

BSI Flex 335 v2.0 sends every message, whatever its content, as one serialised ``SapientMessage``
wrapper; on TCP the stream carries them back to back, each after an unsigned 32-bit little-endian
byte count (the framing Dstl's SAPIENT middleware and the ``sapient-py`` bindings use too).
``FrameDecoder`` turns received bytes back into messages, whatever way TCP splits them.
"""

from __future__ import annotations

import struct

from google.protobuf.message import DecodeError
from sapient_msg.bsi_flex_335_v2_0.sapient_message_pb2 import SapientMessage

__all__ = ["HEADER", "MAX_MESSAGE_BYTES", "FrameDecoder", "FramingError", "encode_frame"]

HEADER = struct.Struct("<I")
# Far above any message this node exchanges (a Registration is about 1 kB); a length beyond it
# means the stream is not SAPIENT framing (or is out of step), not a message worth buffering.
MAX_MESSAGE_BYTES = 1 << 20


class FramingError(ValueError):
    """Bytes that are not a SAPIENT frame: a length over the limit, or a payload protobuf refuses."""


def encode_frame(message: SapientMessage) -> bytes:
    """``message`` serialised, after its 4-byte little-endian length."""
    payload = message.SerializeToString()
    if len(payload) > MAX_MESSAGE_BYTES:
        raise FramingError(f"message of {len(payload)} bytes exceeds the {MAX_MESSAGE_BYTES}-byte limit")
    return HEADER.pack(len(payload)) + payload


class FrameDecoder:
    """Reassembles ``SapientMessage`` frames from a byte stream fed in chunks of any size."""

    def __init__(self, max_message_bytes: int = MAX_MESSAGE_BYTES) -> None:
        self._buffer = bytearray()
        self._max = max_message_bytes

    def feed(self, data: bytes) -> list[SapientMessage]:
        """The messages completed by ``data`` (possibly none).

        Raises
        ------
        FramingError
            On a length over the limit or an unparsable payload; the stream cannot be trusted after it.
        """
        self._buffer += data
        messages = []
        while len(self._buffer) >= HEADER.size:
            (length,) = HEADER.unpack_from(self._buffer)
            if length > self._max:
                raise FramingError(f"frame length {length} exceeds the {self._max}-byte limit")
            end = HEADER.size + length
            if len(self._buffer) < end:
                break
            message = SapientMessage()
            try:
                message.ParseFromString(bytes(self._buffer[HEADER.size : end]))
            except DecodeError as exc:
                raise FramingError(f"frame of {length} bytes is not a SapientMessage: {exc}") from None
            del self._buffer[:end]
            messages.append(message)
        return messages
