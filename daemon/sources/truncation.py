"""Is a recorded video file cut short? The container's own sizes say so before FFmpeg is asked.

A recording stopped by a power cut, a full disk or a killed recorder ends part-way. FFmpeg then
cannot open an MP4 whose index (the ``moov`` box, written last) is missing, or stops reading
early; this module tells the two apart from "a format FFmpeg does not read", so the user hears
"truncated" and not "use H.264 MP4".

- ISO BMFF (MP4, MOV, M4V, 3GP, fragmented MP4): the top-level boxes are walked; a box that reaches
  past the end of the file, or media data (``mdat``) without an index (``moov``), is truncation.
- RIFF (AVI): a ``RIFF`` chunk that reaches past the end of the file.
- MPEG-TS (188-byte packets): a file that ends inside a packet.

Matroska and other containers are not checked (``None``: nothing known to be wrong).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import BinaryIO

__all__ = ["truncation"]

# Types a top-level ISO BMFF box may have first (``ftyp`` for every MP4; old QuickTime files start
# with one of the others).
_BMFF_FIRST = frozenset({b"ftyp", b"styp", b"moov", b"mdat", b"wide", b"free", b"skip", b"pnot"})
_TS_PACKET = 188


def truncation(path: Path) -> str | None:
    """Why ``path`` looks cut short (one phrase), or None when it does not, or is not understood."""
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as f:
            head = f.read(_TS_PACKET * 2 + 1)
            if len(head) >= 8 and head[4:8] in _BMFF_FIRST:
                return _bmff(f, size)
            if head[:4] == b"RIFF":
                return _riff(f, size)
            if len(head) > _TS_PACKET * 2 and head[0] == head[_TS_PACKET] == head[2 * _TS_PACKET] == 0x47:
                return (
                    None if size % _TS_PACKET == 0 else f"it ends inside an MPEG-TS packet at byte {size:,}"
                )
    except OSError:
        return None
    return None


def _bmff(f: BinaryIO, size: int) -> str | None:
    offset, kinds = 0, set()
    while offset + 8 <= size:
        f.seek(offset)
        header = f.read(16)
        box_size, kind = int.from_bytes(header[:4], "big"), header[4:8]
        if box_size == 1:  # 64-bit size after the type
            if len(header) < 16:
                return f"it ends inside the header of its {_name(kind)} box at byte {size:,}"
            box_size = int.from_bytes(header[8:16], "big")
        elif box_size == 0:  # "to the end of the file": a recorder that never wrote the final size
            box_size = size - offset
        if box_size < 8:
            return None  # malformed, not truncated: FFmpeg's own message is the better one
        kinds.add(kind)
        if offset + box_size > size:
            return (
                f"its {_name(kind)} box at byte {offset:,} needs {box_size:,} bytes "
                f"but the file ends after {size - offset:,}"
            )
        offset += box_size
    if b"mdat" in kinds and b"moov" not in kinds:
        return "it has media data but no index (moov box, written when a recording is finalised)"
    return None


def _riff(f: BinaryIO, size: int) -> str | None:
    offset = 0
    while offset + 8 <= size:
        f.seek(offset)
        header = f.read(8)
        if header[:4] != b"RIFF":  # AVI is RIFF chunks (AVIX past 1 GB); anything after is not ours
            return None
        chunk = int.from_bytes(header[4:8], "little")
        if offset + 8 + chunk > size:
            return (
                f"its {_name(header[:4])} chunk at byte {offset:,} needs {8 + chunk:,} bytes "
                f"but the file ends after {size - offset:,}"
            )
        offset += 8 + chunk + (chunk & 1)
    return None


def _name(kind: bytes) -> str:
    return kind.decode("latin-1") if kind.isascii() and kind.decode("latin-1").isprintable() else repr(kind)
