"""One MCAP file of the log, written so that a SIGKILL loses at most the chunk in progress.

The file is written straight to its file descriptor (no user-space buffer), so every completed
chunk is in the kernel when a write returns and survives SIGKILL; ``Recording.close_chunk_if_older``
bounds how long a chunk stays open. A file that failed before it held one complete chunk is
deleted, so a full disk leaves no empty files behind. Every channel (``channels.channel_specs``) is
declared at the start of each file with its schema: Foxglove's protobuf schemas, the project's JSON
schemas for tracks and status.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import time
from pathlib import Path

from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

import dronekey
from dronekey.daemon.sinks.mcap.channels import ChannelSpec
from dronekey.geometry.camera import CameraModel

__all__ = ["Recording", "compression_type", "file_metadata"]

log = logging.getLogger(__name__)


def compression_type(name: str) -> CompressionType:
    """The mcap compression for ``name`` (``McapConfig.compression``: zstd, lz4 or none); a missing
    codec falls back to none with a warning."""
    choice = str(name).lower()
    if choice == "none":
        return CompressionType.NONE
    module = "zstandard" if choice == "zstd" else "lz4.frame"
    try:
        __import__(module)
    except ImportError:
        log.warning(
            "MCAP compression %s needs the Python package %s, which is missing: writing uncompressed chunks",
            choice,
            module.split(".")[0],
        )
        return CompressionType.NONE
    return CompressionType.ZSTD if choice == "zstd" else CompressionType.LZ4


def file_metadata(camera_id: str, camera: CameraModel) -> dict[str, str]:
    """The ``dronekey`` metadata record of each file: camera id, version, full-resolution calibration."""
    return {
        "camera_id": camera_id,
        "version": dronekey.__version__,
        "calibration_full_resolution": json.dumps(
            {
                "width": camera.width,
                "height": camera.height,
                "K": camera.K.tolist(),
                "dist": camera.dist.tolist(),
            }
        ),
        "pixel_frames": "/dronekey/tracks: full-frame pixels; /camera/* and annotations: the JPEG's size",
    }


class _FdStream:
    """The minimal file object ``mcap.writer.Writer`` needs, writing straight to a file descriptor.

    No user-space buffering: what the writer wrote is in the kernel (and survives SIGKILL).
    """

    def __init__(self, fd: int) -> None:
        self._fd = fd
        self._position = 0
        self.completed = 0  # end of the last write that went through whole (a whole record)

    def write(self, data: bytes) -> int:
        view = memoryview(data)
        while view:
            written = os.write(self._fd, view)
            view = view[written:]
            self._position += written
        self.completed = self._position
        return len(data)

    def tell(self) -> int:
        return self._position

    def flush(self) -> None:
        """Nothing is buffered here."""


class Recording:
    """One open MCAP file with every channel declared."""

    def __init__(
        self,
        path: Path,
        specs: list[ChannelSpec],
        compression: CompressionType,
        chunk_size: int,
        metadata: dict[str, str],
    ):
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
        self._fd = os.open(path, flags, 0o644)
        try:
            self._stream = _FdStream(self._fd)
            self._writer = Writer(self._stream, chunk_size=chunk_size, compression=compression)
            self._writer.start(profile="", library=f"dronekey {dronekey.__version__}; {LIBRARY_IDENTIFIER}")
            self._channels = {}
            for spec in specs:
                schema_id = self._writer.register_schema(
                    spec.schema_name, spec.schema_encoding, spec.schema_data
                )
                self._channels[spec.topic] = self._writer.register_channel(
                    spec.topic, spec.message_encoding, schema_id
                )
            self._writer.add_metadata("dronekey", metadata)
        except BaseException:
            os.close(self._fd)
            with contextlib.suppress(OSError):
                path.unlink()  # a full disk must not leave an empty file per retry
            raise
        self._preamble_bytes = self._stream.completed  # magic, header, metadata: no message yet
        self.path = path
        self.opened_mono = time.monotonic()
        self.last_calibration_t_ns: int | None = None
        self._sequence = dict.fromkeys(self._channels, 0)
        self._chunk_opened_mono: float | None = None

    @property
    def size_bytes(self) -> int:
        return self._stream.tell()

    def write(self, topic: str, t_ns: int, data: bytes) -> None:
        t = max(int(t_ns), 0)
        self._sequence[topic] += 1
        self._writer.add_message(
            self._channels[topic],
            log_time=t,
            data=data,
            publish_time=t,
            sequence=self._sequence[topic] & 0xFFFFFFFF,
        )
        if self._chunk_opened_mono is None:
            self._chunk_opened_mono = time.monotonic()

    def close_chunk_if_older(self, max_age_s: float) -> None:
        """Finish the chunk in progress if its first message is older than ``max_age_s``."""
        if self._chunk_opened_mono is not None and time.monotonic() - self._chunk_opened_mono >= max_age_s:
            self._writer.flush()
            self._chunk_opened_mono = None

    def finish(self) -> None:
        """Write the summary and footer, sync and close the file (deleted if it failed empty)."""
        try:
            self._writer.finish()
            os.fsync(self._fd)
        except OSError:
            self.abandon()
            raise
        os.close(self._fd)

    def abandon(self) -> None:
        """Close the file as it is (after an I/O error): completed chunks stay readable; a file
        with no complete chunk holds nothing and is deleted."""
        with contextlib.suppress(OSError):
            os.close(self._fd)
        if self._stream.completed <= self._preamble_bytes:
            with contextlib.suppress(OSError):
                self.path.unlink()
