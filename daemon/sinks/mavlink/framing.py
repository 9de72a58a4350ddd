"""Parsing one UDP datagram on its own.

pymavlink's parser is a byte stream: a datagram that ends inside a message leaves its bytes in
the buffer, and the next datagram is read as their continuation. The two bytes ``FD FF`` (a
MAVLink 2 start and a payload length of 255) thus swallowed the next three valid commands. Over
UDP a message never spans datagrams, so each datagram is parsed from an empty buffer and whatever
is left of it afterwards is dropped with it. Stream links (TCP, serial) keep pymavlink's
continuous parsing.
"""

from __future__ import annotations

import sys

__all__ = ["parse_datagram"]


def _reset(mav) -> None:
    """Empty ``mav``'s parse buffer and put it back to waiting for a start byte."""
    mav.buf = bytearray()
    mav.buf_index = 0
    mav.expected_length = sys.modules[type(mav).__module__].HEADER_LEN_V1 + 2
    mav.have_prefix_error = False


def parse_datagram(mav, data: bytes) -> tuple[list, bool]:
    """The messages of one datagram, and whether any of it was not a valid message.

    Parameters
    ----------
    mav : a dialect ``MAVLink`` parser with ``robust_parsing`` on (``link.use_dialect``).
    data : the datagram.

    Returns
    -------
    ``(messages, malformed)``: the decoded messages, BAD_DATA ones included (their ``reason`` says
    why; signature refusals are among them), and True when some bytes were BAD_DATA or were left
    over at the end (an incomplete message), both dropped.
    """
    _reset(mav)
    try:
        messages = mav.parse_buffer(data) or []
        leftover = mav.buf_len() > 0
    finally:
        _reset(mav)
    malformed = leftover or any(
        m.get_type() == "BAD_DATA" and "signature" not in str(getattr(m, "reason", "")).lower()
        for m in messages
    )
    return messages, malformed
