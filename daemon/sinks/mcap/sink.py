"""MCAP log of what the daemon sees, readable in Foxglove (docs/design.md §6.3).

Channels (schema encoding ``jsonschema``, message encoding ``json``):

======================== ============================ ==============================================
topic                    schema                       what
======================== ============================ ==============================================
/camera/image            foxglove.CompressedImage     JPEG, ``image_rate_hz``, ``image_max_width`` px at most
/camera/calibration      foxglove.CameraCalibration   intrinsics of /camera/image (its size), ~1 Hz
/dronekey/annotations    foxglove.ImageAnnotations    keypoints with order labels 1-4, crop ROI, track labels
/tf                      foxglove.FrameTransforms     camera frame (= camera id) -> drone_<track_id>
/dronekey/tracks         dronekey.Track               the Zenoh track message, one per track update
/dronekey/status         dronekey.Status              the Zenoh status message
======================== ============================ ==============================================

Files are chunked and compressed (zstd by default), named ``<prefix>_<camera_id>_<UTC start>.mcap``
and rotated by size or duration; retention deletes the oldest of these files (never anything else)
to keep their total size and the free disk space within bounds.

Crash safety: the file is written straight to the file descriptor (no user-space buffer), so every
completed chunk is in the kernel when ``handle_update`` returns and survives SIGKILL; a chunk is
closed at least every ``chunk_max_age_s``. A killed file has no summary or footer: read it with
``mcap.stream_reader.StreamReader`` (or ``mcap recover``), see docs/outputs.md.

Faults never leave the sink: an unwritable or full folder makes ``health()`` report
``{"writable": False, "error": ...}`` (and ``failing()`` say "not recording: ..."), the frames that
miss the log are counted, and the sink retries every ``retry_interval_s`` while tracking goes on.
A file that failed before it held one complete chunk is deleted, so a full disk leaves no empty
files behind, one per retry.

Free space: by default the sink keeps the lesser of 500 MB and 5 % of the disk free (a fixed 500 MB
would leave nothing to record on an 8 GB card), and says the figure once when it starts.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import errno
import json
import logging
import os
import re
import shutil
import time
from pathlib import Path

import cv2
import numpy as np
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

import dronekey
from dronekey.daemon import messages
from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.base import FrameUpdate, Sink
from dronekey.daemon.sinks.mcap import foxglove
from dronekey.geometry.camera import CameraModel

__all__ = ["TOPICS", "McapSink"]

log = logging.getLogger(__name__)

TOPICS: dict[str, str] = {
    "/camera/image": "foxglove.CompressedImage",
    "/camera/calibration": "foxglove.CameraCalibration",
    "/dronekey/annotations": "foxglove.ImageAnnotations",
    "/tf": "foxglove.FrameTransforms",
    "/dronekey/tracks": "dronekey.Track",
    "/dronekey/status": "dronekey.Status",
}

_MB = 1_000_000
_MIN_FREE_FLOOR_MB = 500.0  # the default free-space reserve on big disks ...
_MIN_FREE_SHARE = 0.05  # ... and on small ones this share of the disk, whichever is less
_CALIBRATION_PERIOD_NS = 1_000_000_000  # re-written so a reader seeking anywhere finds one nearby
_RETENTION_CHECK_S = 5.0


def _schema_data() -> dict[str, bytes]:
    schemas = dict(foxglove.FOXGLOVE_SCHEMAS)
    schemas["dronekey.Track"] = foxglove.foxglove_compatible(messages.load_schema("track"))
    schemas["dronekey.Status"] = foxglove.foxglove_compatible(messages.load_schema("status"))
    return {name: json.dumps(schema, separators=(",", ":")).encode() for name, schema in schemas.items()}


def _compression(name: str) -> CompressionType:
    """The mcap compression for ``name``; a missing codec falls back to none with a warning."""
    choice = str(name).lower()
    if choice == "none":
        return CompressionType.NONE
    if choice not in ("zstd", "lz4"):
        raise ValueError(f"compression must be 'zstd', 'lz4' or 'none', got {name!r}")
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


class _Recording:
    """One open MCAP file with every channel declared."""

    def __init__(self, path: Path, compression: CompressionType, chunk_size: int, metadata: dict[str, str]):
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
        self._fd = os.open(path, flags, 0o644)
        try:
            self._stream = _FdStream(self._fd)
            self._writer = Writer(self._stream, chunk_size=chunk_size, compression=compression)
            self._writer.start(profile="", library=f"dronekey {dronekey.__version__}; {LIBRARY_IDENTIFIER}")
            schema_ids = {
                name: self._writer.register_schema(name, "jsonschema", data)
                for name, data in _schema_data().items()
            }
            self._channels = {
                topic: self._writer.register_channel(topic, "json", schema_ids[schema])
                for topic, schema in TOPICS.items()
            }
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
        self._sequence = dict.fromkeys(TOPICS, 0)
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


class McapSink(Sink):
    """Writes every frame update into rotating MCAP files (see the module docstring).

    Parameters
    ----------
    directory : str or Path
        Folder of the recordings (created if missing).
    camera : CameraModel
        Intrinsics at the source resolution (the frames' size).
    camera_id : str
        Camera id: file-name part and the frame id of the images, calibration and /tf parent.
    camera_geo : CameraGeo, optional
        Adds WGS84 fields to /dronekey/tracks, as on Zenoh.
    image_rate_hz : float
        JPEG images per second of frame time; 0 records no images.
    image_max_width : int
        Images wider than this are downscaled (calibration and annotations follow), pixels.
    jpeg_quality : int
        1-100.
    rotate_size_mb, rotate_duration_s : float
        Start a new file when the current one reaches this size (MB = 10^6 bytes) or age (s).
    retention_total_mb : float
        Delete the oldest recordings of this camera while all of them together exceed this.
    min_free_mb : float or None
        Delete the oldest recordings while the disk has less free space than this; if it is still
        short, stop writing (``health()`` and ``failing()`` say so) and retry. None: the lesser of
        500 MB and 5 % of the disk that holds ``directory``.
    chunk_size : int
        Uncompressed bytes per chunk, at most.
    chunk_max_age_s : float
        A chunk is closed at the latest this long after its first message (bounds the loss on SIGKILL).
    compression : {"zstd", "lz4", "none"}
    retry_interval_s : float
        Wait between attempts to open a file after a failure.
    file_prefix : str
        Names are ``<file_prefix>_<camera_id>_<YYYYmmddTHHMMSS.mmm>Z.mcap``; retention touches only these.
    """

    name = "mcap"

    def __init__(
        self,
        directory: str | Path,
        camera: CameraModel,
        camera_id: str,
        *,
        camera_geo: CameraGeo | None = None,
        image_rate_hz: float = 2.0,
        image_max_width: int = 960,
        jpeg_quality: int = 80,
        rotate_size_mb: float = 1024.0,
        rotate_duration_s: float = 3600.0,
        retention_total_mb: float = 10240.0,
        min_free_mb: float | None = None,
        chunk_size: int = 1 << 20,
        chunk_max_age_s: float = 2.0,
        compression: str = "zstd",
        retry_interval_s: float = 5.0,
        file_prefix: str = "dronekey",
    ) -> None:
        _require(image_rate_hz >= 0, "image_rate_hz", image_rate_hz, ">= 0")
        _require(image_max_width >= 16, "image_max_width", image_max_width, ">= 16")
        _require(1 <= jpeg_quality <= 100, "jpeg_quality", jpeg_quality, "in [1, 100]")
        _require(rotate_size_mb > 0, "rotate_size_mb", rotate_size_mb, "> 0")
        _require(rotate_duration_s > 0, "rotate_duration_s", rotate_duration_s, "> 0")
        _require(retention_total_mb > 0, "retention_total_mb", retention_total_mb, "> 0")
        _require(min_free_mb is None or min_free_mb >= 0, "min_free_mb", min_free_mb, ">= 0 or None")
        _require(chunk_size >= 1024, "chunk_size", chunk_size, ">= 1024")
        _require(chunk_max_age_s > 0, "chunk_max_age_s", chunk_max_age_s, "> 0")
        _require(retry_interval_s > 0, "retry_interval_s", retry_interval_s, "> 0")
        _require(
            bool(re.fullmatch(r"[A-Za-z0-9_.\-]+", file_prefix)),
            "file_prefix",
            file_prefix,
            "letters, digits, '_', '-', '.'",
        )
        self._directory = Path(directory)
        self._camera = camera
        self._camera_id = messages.check_camera_id(camera_id)
        self._camera_geo = camera_geo
        self._image_period_ns = int(1e9 / image_rate_hz) if image_rate_hz > 0 else None
        self._image_max_width = int(image_max_width)
        self._jpeg_params = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)]
        self._rotate_bytes = int(rotate_size_mb * _MB)
        self._rotate_duration_s = float(rotate_duration_s)
        self._retention_bytes = int(retention_total_mb * _MB)
        self._min_free_bytes = _min_free_bytes(self._directory, min_free_mb)
        self._chunk_size = int(chunk_size)
        self._chunk_max_age_s = float(chunk_max_age_s)
        self._compression = _compression(compression)
        self._retry_interval_s = float(retry_interval_s)
        self._prefix = file_prefix
        self._our_name = re.compile(
            rf"^{re.escape(file_prefix)}_{re.escape(self._camera_id)}_\d{{8}}T\d{{6}}\.\d{{3}}Z(-\d+)?\.mcap$"
        )

        self._recording: _Recording | None = None
        self._closed = False
        self._writable = True
        self._error: str | None = None
        self._failing: str | None = None  # the same, the reason first (a status line is short)
        self._next_open_mono = 0.0
        self._next_retention_mono = 0.0
        self._files_opened = 0
        self._files_deleted = 0
        self._frames_not_recorded = 0
        self._counts = dict.fromkeys(TOPICS, 0)
        self._last_frame: tuple[int, int] | None = None  # (frame t_ns, monotonic ns when it arrived)
        self._pending_status: dict | None = None
        self._images = _ImageSchedule(self._image_period_ns)  # the sink thread's: images written
        self._offers = _ImageSchedule(self._image_period_ns)  # the pipeline thread's: images queued
        self._image_camera: CameraModel | None = None
        self._image_size: tuple[int, int] | None = None
        self._source_size_warned = False
        self._set_image_geometry(camera.width, camera.height)

    # ------------------------------------------------------------------ Sink interface
    def handle_update(self, update: FrameUpdate) -> None:
        """Record one frame: tracks, annotations, transforms, and an image when one is due."""
        if self._closed:
            return
        self._last_frame = (int(update.t_ns), time.monotonic_ns())
        if not self._ensure_recording(update.t_ns):
            self._frames_not_recorded += 1
            return
        try:
            self._rotate_if_due(update.t_ns)
            if self._recording is None:
                self._frames_not_recorded += 1
                return
            self._write_frame(update)
            if self._pending_status is not None:
                self._write("/dronekey/status", update.t_ns, messages.to_json_bytes(self._pending_status))
                self._pending_status = None
            self._recording.close_chunk_if_older(self._chunk_max_age_s)
            self._check_disk_if_due()
        except OSError as exc:
            self._frames_not_recorded += 1  # (and the chunk in progress, which is lost with it)
            self._fail(exc)

    def handle_status(self, status: dict) -> None:
        """Record a status message (built by ``messages.status_message``).

        Its log time is the frame clock extrapolated to now (frame t_ns of the last update plus the
        wall time since), so it sits among the frames for file sources (PTS) and live ones alike;
        a status that comes before the first frame waits for it.
        """
        if self._closed:
            return
        if self._last_frame is None:
            self._pending_status = status
            return
        frame_t_ns, arrived_ns = self._last_frame
        t_ns = frame_t_ns + (time.monotonic_ns() - arrived_ns)
        if not self._ensure_recording(t_ns):
            return
        try:
            self._write("/dronekey/status", t_ns, messages.to_json_bytes(status))
            self._recording.close_chunk_if_older(self._chunk_max_age_s)  # also while frames stall
        except OSError as exc:
            self._fail(exc)

    def wants_image(self, t_ns: int) -> bool:
        """True for the frames on the image grid (``image_rate_hz`` of frame time), so the queue
        carries a full frame only for the images that will be written."""
        if self._closed or not self._offers.due(t_ns):
            return False
        self._offers.taken(t_ns)
        return True

    def health(self) -> dict:
        """``writable``, ``error``, current ``file`` and its size, file and message counters."""
        rec = self._recording
        return {
            "writable": self._writable,
            "error": self._error,
            "file": str(rec.path) if rec is not None else None,
            "file_mb": round(rec.size_bytes / _MB, 3) if rec is not None else None,
            "files_opened": self._files_opened,
            "files_deleted": self._files_deleted,
            "compression": self._compression.name.lower(),
            "messages": sum(self._counts.values()),
            "frames_not_recorded": self._frames_not_recorded,
            "min_free_mb": round(self._min_free_bytes / _MB, 1),
        }

    def failing(self) -> str | None:
        """``not recording: <why>`` while no file can be written, else None."""
        return None if self._writable else self._failing

    def fault_counts(self) -> dict[str, int]:
        """``{"not recorded": frames}``: frames that reached the sink but not the log."""
        return {"not recorded": self._frames_not_recorded}

    def close(self) -> None:
        """Finalise the current file (summary, footer, fsync)."""
        self._closed = True
        self._finish_recording()

    # ------------------------------------------------------------------ public read-outs
    @property
    def message_counts(self) -> dict[str, int]:
        """Messages written per topic since the sink started (all files)."""
        return dict(self._counts)

    @property
    def current_file(self) -> Path | None:
        return self._recording.path if self._recording is not None else None

    # ------------------------------------------------------------------ frame content
    def _write_frame(self, update: FrameUpdate) -> None:
        t_ns = int(update.t_ns)
        for track in update.tracks:
            message = messages.track_message(track, self._camera_id, self._camera_geo)
            self._write("/dronekey/tracks", t_ns, messages.to_json_bytes(message))
        if update.image is not None and self._images.due(t_ns):
            self._write_image(t_ns, update.image)
        if self._recording.last_calibration_t_ns is None or not (
            0 <= t_ns - self._recording.last_calibration_t_ns < _CALIBRATION_PERIOD_NS
        ):
            self._write_calibration(t_ns)
        sx, sy = self._image_scale()
        annotations = foxglove.image_annotations(t_ns, update.detection, update.tracks, (sx, sy))
        self._write("/dronekey/annotations", t_ns, messages.to_json_bytes(annotations))
        transforms = foxglove.frame_transforms(t_ns, self._camera_id, update.tracks)
        if transforms["transforms"]:
            self._write("/tf", t_ns, messages.to_json_bytes(transforms))

    def _write_image(self, t_ns: int, image: np.ndarray) -> None:
        height, width = image.shape[:2]
        if self._source_size != (width, height):
            self._set_image_geometry(width, height)
        out_w, out_h = self._image_size
        small = (
            image
            if (out_w, out_h) == (width, height)
            else cv2.resize(image, (out_w, out_h), interpolation=cv2.INTER_AREA)
        )
        ok, jpeg = cv2.imencode(".jpg", small, self._jpeg_params)
        if not ok:
            raise ValueError(f"JPEG encoding failed for an image of shape {image.shape}")
        message = foxglove.compressed_image(t_ns, self._camera_id, jpeg.tobytes())
        self._write("/camera/image", t_ns, messages.to_json_bytes(message))
        self._images.taken(t_ns)

    def _set_image_geometry(self, width: int, height: int) -> None:
        """Size of the published images for frames of ``width`` x ``height``, and their calibration."""
        camera = self._camera
        if (width, height) != (camera.width, camera.height):
            if not self._source_size_warned:
                log.warning(
                    "frames are %dx%d but the calibration is %dx%d: scaling the calibration",
                    width,
                    height,
                    camera.width,
                    camera.height,
                )
                self._source_size_warned = True
            camera = foxglove.scaled_camera(camera, width, height)
        if width > self._image_max_width:
            out_w, out_h = self._image_max_width, max(1, round(height * self._image_max_width / width))
        else:
            out_w, out_h = width, height
        self._source_size = (width, height)
        self._image_size = (out_w, out_h)
        self._image_camera = foxglove.scaled_camera(camera, out_w, out_h)
        if self._recording is not None:
            self._recording.last_calibration_t_ns = None  # re-write it for the new size

    def _image_scale(self) -> tuple[float, float]:
        (src_w, src_h), (out_w, out_h) = self._source_size, self._image_size
        return out_w / src_w, out_h / src_h

    def _write_calibration(self, t_ns: int) -> None:
        message = foxglove.camera_calibration(t_ns, self._camera_id, self._image_camera)
        self._write("/camera/calibration", t_ns, messages.to_json_bytes(message))
        self._recording.last_calibration_t_ns = int(t_ns)

    def _write(self, topic: str, t_ns: int, data: bytes) -> None:
        self._recording.write(topic, t_ns, data)
        self._counts[topic] += 1

    # ------------------------------------------------------------------ files
    def _ensure_recording(self, t_ns: int) -> bool:
        """Open a file if none is open and a retry is due; False if there is none to write to."""
        if self._recording is not None:
            return True
        now = time.monotonic()
        if now < self._next_open_mono:
            return False
        self._next_open_mono = now + self._retry_interval_s
        try:
            self._directory.mkdir(parents=True, exist_ok=True)
            free = self._enforce_retention()
            if free < self._min_free_bytes:
                raise OSError(errno.ENOSPC, self._low_space_text(free))
            self._recording = _Recording(
                self._new_path(), self._compression, self._chunk_size, self._metadata()
            )
        except OSError as exc:
            self._set_unwritable(exc)
            return False
        self._files_opened += 1
        if not self._writable:
            log.info("MCAP recording recovered: writing %s", self._recording.path)
        else:
            log.info("MCAP recording to %s", self._recording.path)
        self._writable, self._error, self._failing = True, None, None
        self._next_retention_mono = time.monotonic() + _RETENTION_CHECK_S
        return True

    def _new_path(self) -> Path:
        now = dt.datetime.now(dt.UTC)
        stamp = f"{now:%Y%m%dT%H%M%S}.{now.microsecond // 1000:03d}Z"
        path = self._directory / f"{self._prefix}_{self._camera_id}_{stamp}.mcap"
        n = 0
        while path.exists():
            n += 1
            path = self._directory / f"{self._prefix}_{self._camera_id}_{stamp}-{n}.mcap"
        return path

    def _metadata(self) -> dict[str, str]:
        camera = self._camera
        return {
            "camera_id": self._camera_id,
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

    def _rotate_if_due(self, t_ns: int) -> None:
        rec = self._recording
        too_big = rec.size_bytes >= self._rotate_bytes
        too_old = time.monotonic() - rec.opened_mono >= self._rotate_duration_s
        if not (too_big or too_old):
            return
        log.info("MCAP rotating %s (%s)", rec.path.name, "size" if too_big else "duration")
        self._finish_recording()
        self._next_open_mono = 0.0
        self._ensure_recording(t_ns)

    def _finish_recording(self) -> None:
        rec, self._recording = self._recording, None
        if rec is None:
            return
        try:
            rec.finish()
        except OSError as exc:
            log.warning("MCAP could not finalise %s (%s); its completed chunks stay readable", rec.path, exc)

    def _fail(self, exc: OSError) -> None:
        rec, self._recording = self._recording, None
        if rec is not None:
            rec.abandon()
        self._set_unwritable(exc)
        self._next_open_mono = time.monotonic() + self._retry_interval_s

    def _set_unwritable(self, exc: OSError) -> None:
        where = exc.filename if exc.filename else self._directory
        text = f"{where}: {exc.strerror or exc}"
        if text != self._error:
            log.warning("MCAP recording stopped: %s; retrying every %.0f s", text, self._retry_interval_s)
        self._writable, self._error = False, text
        self._failing = f"not recording: {exc.strerror or exc} ({where})"

    # ------------------------------------------------------------------ retention and disk space
    def _check_disk_if_due(self) -> None:
        now = time.monotonic()
        if now < self._next_retention_mono:
            return
        self._next_retention_mono = now + _RETENTION_CHECK_S
        free = self._enforce_retention()
        if free < self._min_free_bytes:
            self._finish_recording()
            self._set_unwritable(OSError(errno.ENOSPC, self._low_space_text(free)))
            self._next_open_mono = now + self._retry_interval_s

    def _low_space_text(self, free: int) -> str:
        return (
            f"free disk space {free / _MB:.0f} MB is below min_free_mb={self._min_free_bytes / _MB:.0f} "
            "and no older recording is left to delete"
        )

    def _our_files(self) -> list[tuple[float, str, int]]:
        """(mtime, name, size) of this camera's recordings, oldest first."""
        files = []
        with os.scandir(self._directory) as entries:
            for entry in entries:
                if self._our_name.match(entry.name) and entry.is_file(follow_symlinks=False):
                    st = entry.stat(follow_symlinks=False)
                    files.append((st.st_mtime, entry.name, st.st_size))
        files.sort()
        return files

    def _enforce_retention(self) -> int:
        """Delete the oldest finished recordings beyond the size and free-space bounds; returns free bytes."""
        current = self._recording.path.name if self._recording is not None else None
        current_size = self._recording.size_bytes if self._recording is not None else 0
        older = [f for f in self._our_files() if f[1] != current]
        total = current_size + sum(size for _, _, size in older)
        free = shutil.disk_usage(self._directory).free
        while older and (total > self._retention_bytes or free < self._min_free_bytes):
            _, name, size = older.pop(0)
            with contextlib.suppress(FileNotFoundError):
                (self._directory / name).unlink()
            self._files_deleted += 1
            total -= size
            free = shutil.disk_usage(self._directory).free
            log.info("MCAP retention deleted %s (%.1f MB)", name, size / _MB)
        return free


class _ImageSchedule:
    """Which frames get an image at ``period_ns`` of frame time: the first frame at or after each
    slot of a fixed grid (so the mean rate is exact whatever the frame rate), restarting the grid
    when frames skip a slot or time goes back.

    Parameters
    ----------
    period_ns : int or None
        Grid period in ns; None: no images at all.
    """

    def __init__(self, period_ns: int | None) -> None:
        self._period_ns = period_ns
        self._next_t_ns: int | None = None

    def due(self, t_ns: int) -> bool:
        """True if the frame at ``t_ns`` should get an image."""
        if self._period_ns is None:
            return False
        slot = self._next_t_ns
        return slot is None or t_ns >= slot or t_ns < slot - 2 * self._period_ns  # or time went back

    def taken(self, t_ns: int) -> None:
        """The frame at ``t_ns`` got its image: move to the next slot."""
        slot, period = self._next_t_ns, self._period_ns
        on_grid = slot is not None and 0 <= t_ns - slot < period
        self._next_t_ns = slot + period if on_grid else t_ns + period


def _min_free_bytes(directory: Path, min_free_mb: float | None) -> int:
    """The free space to keep, in bytes: ``min_free_mb``, or by default the lesser of 500 MB and
    5 % of the disk that holds ``directory`` (its nearest existing parent); logged once."""
    if min_free_mb is not None:
        log.info("MCAP keeps %.0f MB free on the disk of %s (mcap.min_free_mb)", min_free_mb, directory)
        return int(min_free_mb * _MB)
    probe = directory.absolute()
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    try:
        total = shutil.disk_usage(probe).total
    except OSError as exc:
        log.warning("MCAP cannot measure the disk of %s (%s): keeping 500 MB free", directory, exc)
        return int(_MIN_FREE_FLOOR_MB * _MB)
    keep = min(_MIN_FREE_FLOOR_MB * _MB, _MIN_FREE_SHARE * total)
    log.info(
        "MCAP keeps %.0f MB free on the %.1f GB disk of %s (mcap.min_free_mb null: the lesser of "
        "%.0f MB and %.0f %% of the disk)",
        keep / _MB,
        total / 1e9,
        directory,
        _MIN_FREE_FLOOR_MB,
        _MIN_FREE_SHARE * 100,
    )
    return int(keep)


def _require(ok: bool, name: str, value, allowed: str) -> None:
    if not ok:
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
