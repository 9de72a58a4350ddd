"""Write a rendered sequence to disk: ``DIR/<name>.mp4`` (or the frame folder ``DIR/<name>/``),
``DIR/<name>.json`` (docs/design.md §5.1) and ``DIR/camera.yaml`` (§5.2).

Everything is written under temporary names (``DIR/.<name>.partial-<pid>...``) and renamed into
place only after the last frame, media first and the JSON last, so an interrupted or failed run
never leaves a file that looks complete; the temporaries are removed on any error, Ctrl-C included.

Video: ``codec="h264"`` (``dronekey-sim``'s default) is libx264 through PyAV at a camera-like bitrate
(``h264_video.py``). ``codec="mp4v"`` is OpenCV's ``VideoWriter`` as before: H.264 (``avc1``) when
the installed OpenCV can encode it; the opencv-python(-headless) pip wheels cannot (their FFmpeg has
no H.264 encoder), so it falls back to MPEG-4 Part 2 (``mp4v``) in the .mp4, which OpenCV, FFmpeg /
PyAV and common desktop players decode (web browsers do not). Image folders hold lossless PNGs
named ``<index:06d>.png``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import os
import re
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from dronekey.geometry.camera import CalibrationError, CameraModel
from dronekey.geometry.drone_spec import DroneSpec
from dronekey.sim_replay.annotations import FrameRecord, SequenceAnnotations
from dronekey.sim_replay.io.h264_video import H264VideoSink
from dronekey.sim_replay.io.sequence_writer import dumps_sequence

__all__ = [
    "VIDEO_CODECS",
    "RenderedFrameLike",
    "RenderedSequenceLike",
    "WrittenSequence",
    "video_fourcc",
    "write_sequence",
]

log = logging.getLogger(__name__)

_SAFE_NAME = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9._-]*$")
VIDEO_CODECS = ("h264", "mp4v")  # h264: libx264 through PyAV; mp4v: OpenCV's VideoWriter


class RenderedFrameLike(Protocol):
    """One rendered frame: ``image`` (H, W, 3) uint8 BGR and its ground truth ``record``."""

    image: np.ndarray
    record: FrameRecord


class RenderedSequenceLike(Protocol):
    """What the writer needs from a rendered sequence (``synthetic_sequence.build_sequence`` returns one)."""

    name: str
    camera: CameraModel
    spec: DroneSpec
    fps: float
    n_frames: int
    info: dict

    def __iter__(self) -> Iterator[RenderedFrameLike]: ...


@dataclasses.dataclass(frozen=True)
class WrittenSequence:
    """What ``write_sequence`` wrote.

    media_path : the video file or the frame folder. seconds : wall time of rendering + encoding.
    """

    json_path: Path
    media_path: Path
    camera_path: Path
    n_frames: int
    n_annotated: int
    seconds: float

    @property
    def frames_per_second(self) -> float:
        """Frames rendered and encoded per second of wall time."""
        return self.n_frames / self.seconds if self.seconds > 0 else float("inf")


@contextlib.contextmanager
def _stderr_silenced() -> Iterator[None]:
    """Silence file descriptor 2 (C libraries print there: FFmpeg's encoder probing)."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


@functools.cache
def video_fourcc() -> str:
    """``"avc1"`` (H.264) if this OpenCV can encode it into an .mp4, else ``"mp4v"`` (MPEG-4 Part 2)."""
    with tempfile.TemporaryDirectory(prefix="dronekey-fourcc-") as tmp, _stderr_silenced():
        writer = cv2.VideoWriter(
            str(Path(tmp) / "probe.mp4"), cv2.VideoWriter_fourcc(*"avc1"), 30.0, (64, 64)
        )
        available = writer.isOpened()
        writer.release()
    fourcc = "avc1" if available else "mp4v"
    log.debug("video codec: %s", fourcc)
    return fourcc


class _VideoSink:
    def __init__(self, path: Path, fps: float, size: tuple[int, int]) -> None:
        self.path = path
        self.fourcc = video_fourcc()
        self._writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*self.fourcc), float(fps), size)
        if not self._writer.isOpened():
            raise OSError(f"OpenCV cannot open a {self.fourcc} video writer for {path}")

    def write(self, index: int, bgr: np.ndarray, name: str) -> str:
        self._writer.write(bgr)
        return f"{name}.mp4#{index}"

    def close(self) -> None:
        self._writer.release()

    def verify(self, n_frames: int, size: tuple[int, int]) -> None:
        cap = cv2.VideoCapture(str(self.path))
        try:
            count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            got = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        finally:
            cap.release()
        if count != n_frames or got != size:
            raise OSError(
                f"the encoded video {self.path} reads back as {count} frames of {got[0]}x{got[1]}, "
                f"expected {n_frames} of {size[0]}x{size[1]}"
            )


class _ImageFolderSink:
    def __init__(self, path: Path) -> None:
        self.path = path
        path.mkdir()

    def write(self, index: int, bgr: np.ndarray, name: str) -> str:
        file = self.path / f"{index:06d}.png"
        if not cv2.imwrite(str(file), bgr):
            raise OSError(f"OpenCV could not write {file}")
        return f"{name}/{file.name}"

    def close(self) -> None:
        pass

    def verify(self, n_frames: int, size: tuple[int, int]) -> None:
        pass


def _check_frame(
    index: int, expected: int, bgr: np.ndarray, record: FrameRecord, size: tuple[int, int]
) -> None:
    width, height = size
    if index != expected:
        raise ValueError(f"frame {expected}: the renderer returned frame index {index}")
    if not isinstance(bgr, np.ndarray) or bgr.dtype != np.uint8 or bgr.shape != (height, width, 3):
        got = f"{getattr(bgr, 'shape', None)} {getattr(bgr, 'dtype', type(bgr).__name__)}"
        raise ValueError(f"frame {index}: image must be ({height}, {width}, 3) uint8 BGR, got {got}")
    if (record.width, record.height) != size:
        raise ValueError(
            f"frame {index}: record size {record.width}x{record.height} is not the camera's {size}"
        )


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def _replace(tmp: Path, final: Path) -> None:
    """Rename ``tmp`` onto ``final``; a folder replaces a folder (the old one is removed after)."""
    if final.is_dir() and not final.is_symlink():
        old = final.with_name(f".{final.name}.old-{os.getpid()}")
        final.rename(old)
        tmp.rename(final)
        shutil.rmtree(old, ignore_errors=True)
    else:
        tmp.replace(final)


def _warn_if_camera_differs(camera_path: Path, camera: CameraModel) -> None:
    if not camera_path.is_file():
        return
    try:
        old = CameraModel.load(camera_path)
    except CalibrationError:
        return
    if old.size != camera.size or not np.allclose(old.K, camera.K) or not np.allclose(old.dist, camera.dist):
        log.warning(
            "%s held another camera (%dx%d); it is replaced, so sequences written there before with "
            "that camera must use the camera in their own JSON",
            camera_path,
            *old.size,
        )


def write_sequence(
    seq: RenderedSequenceLike,
    out_dir: str | Path,
    *,
    images: bool = False,
    on_frame: Callable[[], object] | None = None,
    codec: str = "mp4v",
    bitrate_bps: int | None = None,
) -> WrittenSequence:
    """Render ``seq`` into ``out_dir`` (which must exist) and write video/frames, JSON and camera.

    Parameters
    ----------
    seq : the rendered sequence (see ``RenderedSequenceLike``); iterated once.
    out_dir : output folder.
    images : write a folder of PNG frames instead of the video.
    on_frame : called after each frame is written (a progress bar's ``update``).
    codec : ``h264`` (libx264 through PyAV) or ``mp4v`` (OpenCV's writer); see the module docstring.
        ``dronekey-sim`` defaults to ``h264``; this function keeps ``mp4v`` so the robustness matrix
        renders (and the figures measured on them) stay as they were.
    bitrate_bps : H.264 target bitrate, bit/s; None: about 8 Mbit/s at 1080p30, scaled by pixel rate.

    Raises
    ------
    ValueError
        A frame does not match the sequence (index, image size or dtype, record size).
    OSError
        A file cannot be written. No output or temporary file is left behind in either case.
    """
    out_dir = Path(out_dir)
    if not _SAFE_NAME.match(seq.name):
        raise ValueError(f"sequence name {seq.name!r} is not a safe file name")
    if codec not in VIDEO_CODECS:
        raise ValueError(f"video codec {codec!r} is not one of {', '.join(VIDEO_CODECS)}")
    name, size = seq.name, seq.camera.size
    tag = f"partial-{os.getpid()}"
    final_media = out_dir / (name if images else f"{name}.mp4")
    final_json, final_camera = out_dir / f"{name}.json", out_dir / "camera.yaml"
    tmp_media = out_dir / (f".{name}.{tag}" if images else f".{name}.{tag}.mp4")
    tmp_json, tmp_camera = out_dir / f".{name}.{tag}.json", out_dir / f".camera.{tag}.yaml"
    temporaries = [tmp_media, tmp_json, tmp_camera]
    try:
        start = time.perf_counter()
        if images:
            sink = _ImageFolderSink(tmp_media)
        elif codec == "h264":
            sink = H264VideoSink(tmp_media, seq.fps, size, bitrate_bps)
        else:
            sink = _VideoSink(tmp_media, seq.fps, size)
        records: list[FrameRecord] = []
        try:
            for expected, rendered in enumerate(seq):
                record = rendered.record
                _check_frame(record.index, expected, rendered.image, record, size)
                file_name = sink.write(record.index, rendered.image, name)
                records.append(dataclasses.replace(record, file_name=file_name))
                if on_frame is not None:
                    on_frame()
        finally:
            sink.close()
        seconds = time.perf_counter() - start
        if len(records) != seq.n_frames:
            raise ValueError(f"sequence {name!r} announced {seq.n_frames} frames but rendered {len(records)}")
        sink.verify(len(records), size)
        annotations = SequenceAnnotations(
            name=name,
            camera=seq.camera,
            drone_model=seq.spec.name,
            keypoints_3d=np.asarray(seq.spec.keypoints_3d, dtype=np.float64),
            fps=float(seq.fps),
            frames=records,
            info=dict(seq.info),
            keypoint_names=tuple(seq.spec.keypoint_names),
            base_dir=out_dir,
            instances=tuple(getattr(seq, "instances", ())),  # several drones: the JSON's instances table
        )
        tmp_json.write_text(dumps_sequence(annotations), encoding="utf-8")
        seq.camera.save_yaml(tmp_camera)
        _warn_if_camera_differs(final_camera, seq.camera)
        stale = out_dir / (f"{name}.mp4" if images else name)
        if stale.exists():
            log.warning(
                "%s is from an earlier run; %s describes %s instead", stale, final_json.name, final_media
            )
        _replace(tmp_media, final_media)
        tmp_camera.replace(final_camera)
        tmp_json.replace(final_json)
    except BaseException:
        for path in temporaries:
            _remove(path)
        _remove(tmp_camera.with_name(f".{tmp_camera.name}.tmp.yaml"))  # CameraModel.save_yaml's own
        raise
    n_annotated = sum(r.drone is not None for r in records)
    return WrittenSequence(final_json, final_media, final_camera, len(records), n_annotated, seconds)
