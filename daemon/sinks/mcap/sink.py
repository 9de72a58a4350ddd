"""MCAP log of what the daemon sees, readable in Foxglove (docs/design.md §6.3).

Channels (``channels.py``): Foxglove's own types with Foxglove's published protobuf schemas, the
project's track and status messages as JSON with their JSON schemas:

======================== ============================ ==============================================
topic                    schema                       what
======================== ============================ ==============================================
/camera/image            foxglove.CompressedImage     JPEG bytes at ``image_rate_hz``, ``image_max_width`` px
/camera/calibration      foxglove.CameraCalibration   intrinsics of /camera/image (its size), ~1 Hz
/dronekey/annotations    foxglove.ImageAnnotations    keypoints with order labels 1-4, crop ROI, track labels
/tf                      foxglove.FrameTransforms     camera frame (= camera id) -> drone_<track_id>
/dronekey/scene          foxglove.SceneUpdate         camera frustum, a quadcopter per track, its recent path
/camera/fix, /camera/fov foxglove.LocationFix,        with --camera-geo: the camera on the map and its
                         foxglove.GeoJSON             field of view, ~1 Hz
/dronekey/fix            foxglove.LocationFix         with --camera-geo: each track, ENU covariance
/dronekey/tracks         dronekey.Track (JSON)        the Zenoh track message, one per track update
/dronekey/status         dronekey.Status (JSON)       the Zenoh status message
======================== ============================ ==============================================

Every message goes to the file and, with ``live`` (``--foxglove-ws``), to the live WebSocket view;
with ``mcap.enabled`` false only to the live view.

Files are chunked and compressed (zstd by default), named ``<prefix>_<camera_id>_<UTC start>.mcap``
and rotated by size or duration; retention deletes the oldest of these files (never anything else)
to keep their total size and the free disk space within bounds (``retention``).

Crash safety: every completed chunk is in the kernel when ``handle_update`` returns and survives
SIGKILL; a chunk is closed at least every ``chunk_max_age_s`` (``recording``). A killed file has no
summary or footer: read it with ``mcap.stream_reader.StreamReader`` (or ``mcap recover``), see
docs/outputs.md.

Faults never leave the sink: an unwritable or full folder makes ``health()`` report
``{"writable": False, "error": ...}`` (and ``failing()`` say "not recording: ..."), the frames that
miss the log are counted, and the sink retries every ``retry_interval_s`` while tracking goes on.
"""

from __future__ import annotations

import datetime as dt
import errno
import logging
import re
import time
from pathlib import Path

from dronekey.daemon import messages
from dronekey.daemon.config.camera import check_camera_id
from dronekey.daemon.config.mcap import McapConfig
from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.base import FrameUpdate, Sink
from dronekey.daemon.sinks.foxglove_ws import FoxgloveLiveServer
from dronekey.daemon.sinks.mcap.channels import ChannelSpec, channel_specs
from dronekey.daemon.sinks.mcap.frame_content import FrameContent, Message, periodic_due
from dronekey.daemon.sinks.mcap.recording import Recording, compression_type, file_metadata
from dronekey.daemon.sinks.mcap.retention import MB, Retention, min_free_bytes
from dronekey.geometry.camera import CameraModel

__all__ = ["McapSink"]

log = logging.getLogger(__name__)

_RETENTION_CHECK_S = 5.0
_FILE_PREFIX = re.compile(r"^[A-Za-z0-9_.\-]+$")


class McapSink(Sink):
    """Writes every frame update into rotating MCAP files (see the module docstring).

    Parameters
    ----------
    config : McapConfig
        The ``mcap`` section: ``dir`` (the folder, created if missing; ``load_config`` fills in its
        default), ``image_rate_hz`` (JPEG images per second of frame time; 0 records none),
        ``image_max_width`` (wider images are downscaled, calibration and annotations follow),
        ``jpeg_quality``, ``rotate_size_mb`` and ``rotate_duration_s`` (start a new file at this size,
        MB = 10^6 bytes, or age, s), ``retention_total_mb`` (delete the oldest recordings of this
        camera while all of them together exceed this), ``min_free_mb`` (delete the oldest while the
        disk has less free space than this, and if still short stop writing and retry; None: the
        lesser of 500 MB and 5 % of the disk) and ``compression``.
    camera : CameraModel
        Intrinsics at the source resolution (the frames' size).
    camera_id : str
        Camera id: file-name part and the frame id of the images, calibration and /tf parent.
    camera_geo : CameraGeo, optional
        Adds WGS84 fields to /dronekey/tracks, as on Zenoh, and the map channels.
    live : FoxgloveLiveServer, optional
        The live view: gets every message too, and is closed with the sink.
    chunk_size : int
        Uncompressed bytes per chunk, at most (>= 1024).
    chunk_max_age_s : float
        A chunk is closed at the latest this long after its first message (bounds the loss on SIGKILL).
    retry_interval_s : float
        Wait between attempts to open a file after a failure.
    file_prefix : str
        Names are ``<file_prefix>_<camera_id>_<YYYYmmddTHHMMSS.mmm>Z.mcap``; retention touches only these.

    Raises
    ------
    ValueError
        Naming ``mcap.dir`` if it is not set, ``camera_id``, or a keyword argument out of range.
    """

    name = "mcap"

    def __init__(
        self,
        config: McapConfig,
        camera: CameraModel,
        camera_id: str,
        *,
        camera_geo: CameraGeo | None = None,
        live: FoxgloveLiveServer | None = None,
        chunk_size: int = 1 << 20,
        chunk_max_age_s: float = 2.0,
        retry_interval_s: float = 5.0,
        file_prefix: str = "dronekey",
    ) -> None:
        if config.dir is None and config.enabled:
            raise ValueError("mcap.dir must be a folder, got None")
        for name, value, ok, allowed in (
            ("chunk_size", chunk_size, chunk_size >= 1024, ">= 1024"),
            ("chunk_max_age_s", chunk_max_age_s, chunk_max_age_s > 0, "> 0"),
            ("retry_interval_s", retry_interval_s, retry_interval_s > 0, "> 0"),
            (
                "file_prefix",
                file_prefix,
                bool(_FILE_PREFIX.match(file_prefix)),
                "letters, digits, '_', '-', '.'",
            ),
        ):
            if not ok:
                raise ValueError(f"{name} must be {allowed}, got {value!r}")
        self._record = bool(config.enabled)
        self._directory = Path(config.dir if config.dir is not None else ".")
        self._camera = camera
        self._camera_id = check_camera_id(camera_id)
        self._specs: list[ChannelSpec] = channel_specs(with_geo=camera_geo is not None)
        self._content = FrameContent(config, camera, self._camera_id, camera_geo)
        self._live = live
        self._live_periodic_t_ns: int | None = None
        self._rotate_bytes = int(config.rotate_size_mb * MB)
        self._rotate_duration_s = config.rotate_duration_s
        self._retention = Retention(
            self._directory,
            file_prefix,
            self._camera_id,
            total_bytes=int(config.retention_total_mb * MB),
            min_free_bytes=min_free_bytes(self._directory, config.min_free_mb),
        )
        self._chunk_size = int(chunk_size)
        self._chunk_max_age_s = float(chunk_max_age_s)
        self._compression = compression_type(config.compression)
        self._retry_interval_s = float(retry_interval_s)
        self._prefix = file_prefix

        self._recording: Recording | None = None
        self._closed = False
        self._writable = True
        self._error: str | None = None
        self._failing: str | None = None  # the same, the reason first (a status line is short)
        self._next_open_mono = 0.0
        self._next_retention_mono = 0.0
        self._files_opened = 0
        self._frames_not_recorded = 0
        self._counts = {spec.topic: 0 for spec in self._specs}
        self._last_frame: tuple[int, int] | None = None  # (frame t_ns, monotonic ns when it arrived)
        self._pending_status: dict | None = None

    # ------------------------------------------------------------------ Sink interface
    def handle_update(self, update: FrameUpdate) -> None:
        """Record one frame (``FrameContent``) and send it to the live view."""
        if self._closed:
            return
        t_ns = int(update.t_ns)
        self._last_frame = (t_ns, time.monotonic_ns())
        frame = self._content.frame(update)
        if self._content.image_size_changed:  # re-send the calibration for the new size
            self._content.image_size_changed = False
            self._live_periodic_t_ns = None
            if self._recording is not None:
                self._recording.last_calibration_t_ns = None
        status = self._pending_status
        if status is not None:
            frame.append(("/dronekey/status", t_ns, messages.to_json_bytes(status)))
            self._pending_status = None
        if self._live is not None:
            if periodic_due(self._live_periodic_t_ns, t_ns):
                self._send_live(self._content.periodic(t_ns))
                self._live_periodic_t_ns = t_ns
            self._send_live(frame)
        if not self._record:
            return
        if not self._ensure_recording(t_ns):
            self._frames_not_recorded += 1
            return
        try:
            self._rotate_if_due(t_ns)
            if self._recording is None:
                self._frames_not_recorded += 1
                return
            if periodic_due(self._recording.last_calibration_t_ns, t_ns):
                self._write_all(self._content.periodic(t_ns))
                self._recording.last_calibration_t_ns = t_ns
            self._write_all(frame)
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
        data = messages.to_json_bytes(status)
        self._send_live([("/dronekey/status", t_ns, data)])
        if not self._record or not self._ensure_recording(t_ns):
            return
        try:
            self._write("/dronekey/status", t_ns, data)
            self._recording.close_chunk_if_older(self._chunk_max_age_s)  # also while frames stall
        except OSError as exc:
            self._fail(exc)

    def wants_image(self, t_ns: int) -> bool:
        """True for the frames on the image grid (``image_rate_hz`` of frame time), so the queue
        carries a full frame only for the images that will be written."""
        offers = self._content.offers
        if self._closed or not offers.due(t_ns):
            return False
        offers.taken(t_ns)
        return True

    def health(self) -> dict:
        """``writable``, ``error``, current ``file`` and its size, file and message counters."""
        rec = self._recording
        return {
            "writable": self._writable,
            "error": self._error,
            "file": str(rec.path) if rec is not None else None,
            "file_mb": round(rec.size_bytes / MB, 3) if rec is not None else None,
            "files_opened": self._files_opened,
            "files_deleted": self._retention.files_deleted,
            "compression": self._compression.name.lower(),
            "messages": sum(self._counts.values()),
            "frames_not_recorded": self._frames_not_recorded,
            "min_free_mb": round(self._retention.min_free_bytes / MB, 1),
            "live": f"ws://{self._live.host}:{self._live.port}" if self._live is not None else None,
        }

    def failing(self) -> str | None:
        """``not recording: <why>`` while no file can be written, else None."""
        return None if self._writable else self._failing

    def fault_counts(self) -> dict[str, int]:
        """``{"not recorded": frames}``: frames that reached the sink but not the log."""
        return {"not recorded": self._frames_not_recorded}

    def close(self) -> None:
        """Finalise the current file (summary, footer, fsync) and stop the live view."""
        self._closed = True
        self._finish_recording()
        if self._live is not None:
            self._live.close()

    # ------------------------------------------------------------------ public read-outs
    @property
    def message_counts(self) -> dict[str, int]:
        """Messages written per topic since the sink started (all files)."""
        return dict(self._counts)

    @property
    def current_file(self) -> Path | None:
        return self._recording.path if self._recording is not None else None

    # ------------------------------------------------------------------ destinations
    def _send_live(self, items: list[Message]) -> None:
        if self._live is not None:
            for topic, t_ns, data in items:
                self._live.log(topic, t_ns, data)

    def _write_all(self, items: list[Message]) -> None:
        for topic, t_ns, data in items:
            self._write(topic, t_ns, data)

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
            if free < self._retention.min_free_bytes:
                raise OSError(errno.ENOSPC, self._retention.low_space_text(free))
            self._recording = Recording(
                self._new_path(),
                self._specs,
                self._compression,
                self._chunk_size,
                file_metadata(self._camera_id, self._camera),
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
        if free < self._retention.min_free_bytes:
            self._finish_recording()
            self._set_unwritable(OSError(errno.ENOSPC, self._retention.low_space_text(free)))
            self._next_open_mono = now + self._retry_interval_s

    def _enforce_retention(self) -> int:
        """Delete the oldest finished recordings beyond the bounds; returns the free bytes."""
        rec = self._recording
        return self._retention.enforce(rec.path if rec else None, rec.size_bytes if rec else 0)
