"""Frame sources: video files, V4L2 devices, network streams, image folders and ``sim://`` presets.

``make_reader`` picks the reader for a ``--source`` string; ``Capture`` runs it on a thread behind
a bounded queue with the live/finite policy (drops, pacing, watchdog, reconnection).
"""

from __future__ import annotations

import re
from pathlib import Path
from urllib.parse import urlsplit

from dronekey.daemon.config.source import SourceConfig
from dronekey.daemon.errors import UsageError
from dronekey.daemon.sources.base import (
    CapturedFrame,
    FrameReader,
    ReadResult,
    SourceOpenError,
    SourceState,
)
from dronekey.daemon.sources.capture import Capture, CaptureStats, FrameQueue
from dronekey.sim_replay.presets import PRESETS

__all__ = [
    "NETWORK_SCHEMES",
    "SIM_SOURCES",
    "Capture",
    "CaptureStats",
    "CapturedFrame",
    "FrameQueue",
    "FrameReader",
    "ReadResult",
    "SourceOpenError",
    "SourceState",
    "make_reader",
]

NETWORK_SCHEMES = frozenset({"rtsp", "rtsps", "rtmp", "http", "https", "tcp", "udp", "srt", "rtp"})
SIM_SOURCES = "sim://" + "|".join(PRESETS)
"""The simulator presets as ``--help`` and the errors name them: one list, the presets module's."""
_SOURCE_HELP = (
    f"a video file, an image folder, /dev/videoN (or N), rtsp:// http:// tcp:// udp:// URL, or {SIM_SOURCES}"
)


def make_reader(config: SourceConfig) -> FrameReader:
    """The reader for ``config.uri``.

    Raises
    ------
    UsageError
        When the string names no kind of source the daemon reads.
    """
    uri = config.uri
    if uri is None:
        raise UsageError(f"no source: give --source SRC ({_SOURCE_HELP}) or source.uri in the config file")
    scheme = urlsplit(uri).scheme.lower() if "://" in uri else ""
    if scheme == "sim":
        from dronekey.daemon.sources.sim import SimReader

        preset = uri[len("sim://") :].strip("/")
        if not preset:
            raise UsageError(f"source: sim:// needs a preset name: {SIM_SOURCES}")
        return SimReader(preset, config.sim)
    if scheme in NETWORK_SCHEMES:
        from dronekey.daemon.sources.opencv_readers import NetworkStreamReader
        from dronekey.daemon.sources.pyav_reader import PyAVStreamReader

        # The watchdog reports the stall after stall_timeout_s; the read gives up (and the capture
        # reconnects) after twice that. PyAV unless source.decoder is opencv: a stream that does not
        # open is usually down, and trying a second library would double every reconnection wait.
        read_timeout_s = 2 * config.stall_timeout_s
        if config.decoder == "opencv":
            return NetworkStreamReader(uri, config.network, read_timeout_s, config.decode_threads)
        return PyAVStreamReader(
            uri, config.network, read_timeout_s, config.decode_threads, fast_decode=config.fast_decode
        )
    if scheme == "file":
        uri = uri[len("file://") :]
    elif scheme:
        raise UsageError(f"source {uri!r}: unknown scheme {scheme!r}; a source is {_SOURCE_HELP}")
    if re.fullmatch(r"\d{1,3}", uri) or uri.startswith("/dev/"):
        from dronekey.daemon.sources.opencv_readers import V4l2Reader

        device = f"/dev/video{uri}" if uri.isdigit() else uri
        return V4l2Reader(device, config.v4l2)
    path = Path(uri).expanduser()
    if path.is_dir():
        from dronekey.daemon.sources.image_folder import ImageFolderReader

        return ImageFolderReader(path, config.image_fps)
    from dronekey.daemon.sources.fallback import FirstThatOpens
    from dronekey.daemon.sources.opencv_readers import VideoFileReader
    from dronekey.daemon.sources.pyav_reader import PyAVFileReader

    if config.decoder == "opencv":
        return VideoFileReader(path, decode_threads=config.decode_threads)
    if config.decoder == "pyav":
        return PyAVFileReader(path, config.decode_threads, fast_decode=config.fast_decode)
    return FirstThatOpens(
        [
            PyAVFileReader(path, config.decode_threads, fast_decode=config.fast_decode),
            VideoFileReader(path, config.decode_threads),
        ]
    )
