"""Iterate the frames of a sequence together with their ground truth, from its video or image folder.

Where the pixels come from:

* by default, from the records' ``file_name`` relative to the sequence's ``base_dir`` (the JSON's
  folder): ``seq13.mp4#12`` is frame 12 of the video ``seq13.mp4``; any other name is an image file
  (``seq13/000012.png``, or a real dataset's ``000012.jpg``);
* or from an explicit ``source``: a video file (frame ``k`` of a ``...#k`` name, else the record's
  index), or an image folder holding either the relative ``file_name`` or just its base name.

Counts and sizes are checked: a video with another number of frames than the JSON describes, a
missing or unreadable image, or a frame of another size raises ``FrameSourceError``.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from dronekey.sim_replay.annotations import FrameRecord, SequenceAnnotations
from dronekey.types import Frame

__all__ = ["FrameSourceError", "SequenceFrame", "iter_frames", "resolve_source"]

_VIDEO_REF = re.compile(r"^(?P<video>.+)#(?P<frame>\d+)$")


class FrameSourceError(RuntimeError):
    """The video or images of a sequence are missing, unreadable or disagree with its JSON."""


class SequenceFrame(NamedTuple):
    """One frame of a sequence: pixels and ground truth.

    index : frame index (the JSON's ``frame_index``). t_ns : timestamp, integer ns (the JSON's).
    bgr : (H, W, 3) uint8 image. record : the frame's ground truth (``record.drone`` may be None).
    """

    index: int
    t_ns: int
    bgr: np.ndarray
    record: FrameRecord

    @property
    def frame(self) -> Frame:
        """The pixels as the ``Frame`` the daemon's pipeline consumes."""
        return Frame(self.index, self.t_ns, self.bgr)


def _video_ref(file_name: str) -> tuple[str, int] | None:
    match = _VIDEO_REF.match(file_name)
    return (match["video"], int(match["frame"])) if match else None


def resolve_source(sequence: SequenceAnnotations, source: str | Path | None = None) -> Path:
    """The video file or image folder the frames of ``sequence`` are read from.

    Raises
    ------
    FrameSourceError
        No source given and none can be derived from the records, or the path does not exist.
    """
    if source is not None:
        source = Path(source)
        if not source.exists():
            raise FrameSourceError(f"video or image folder not found: {source}")
        return source
    if not sequence.frames:
        raise FrameSourceError(f"sequence {sequence.name!r} has no frames")
    if sequence.base_dir is None:
        raise FrameSourceError(
            f"sequence {sequence.name!r} was not read from a file: pass the video or image folder"
        )
    refs = [_video_ref(r.file_name) for r in sequence.frames]
    if all(ref is None for ref in refs):
        return Path(sequence.base_dir)
    videos = {ref[0] if ref else None for ref in refs}
    if len(videos) != 1:
        shown = ", ".join(sorted(str(v) for v in videos))
        raise FrameSourceError(f"sequence {sequence.name!r} mixes frames of several sources: {shown}")
    video = Path(sequence.base_dir) / videos.pop()
    if not video.is_file():
        raise FrameSourceError(f"video not found: {video} (named by the JSON's file_name entries)")
    return video


def _check_size(bgr: np.ndarray, record: FrameRecord, origin: str) -> None:
    if bgr.shape[:2] != (record.height, record.width):
        raise FrameSourceError(
            f"{origin}: frame {record.index} is {bgr.shape[1]}x{bgr.shape[0]}, "
            f"the JSON says {record.width}x{record.height}"
        )


def _iter_video(sequence: SequenceAnnotations, video: Path) -> Iterator[SequenceFrame]:
    frame_numbers = []
    for record in sequence.frames:
        ref = _video_ref(record.file_name)
        frame_numbers.append(ref[1] if ref else record.index)
    if any(b <= a for a, b in itertools.pairwise(frame_numbers)):
        raise FrameSourceError(f"{video}: the JSON's video frame numbers are not increasing")
    cap = cv2.VideoCapture(str(video))
    try:
        if not cap.isOpened():
            raise FrameSourceError(f"{video}: OpenCV cannot open this video")
        in_video = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        described = frame_numbers[-1] + 1 if frame_numbers else 0
        if in_video > 0 and in_video != described:
            raise FrameSourceError(f"{video} has {in_video} frames but the JSON describes {described}")
        position = 0
        for record, number in zip(sequence.frames, frame_numbers, strict=True):
            while position < number:
                if not cap.grab():
                    raise FrameSourceError(
                        f"{video} ends after {position} frames, the JSON needs {described}"
                    )
                position += 1
            ok, bgr = cap.read()
            if not ok:
                raise FrameSourceError(f"{video} ends after {position} frames, the JSON needs {described}")
            position += 1
            _check_size(bgr, record, str(video))
            yield SequenceFrame(record.index, record.t_ns, bgr, record)
    finally:
        cap.release()


def _iter_images(sequence: SequenceAnnotations, folder: Path) -> Iterator[SequenceFrame]:
    for record in sequence.frames:
        if _video_ref(record.file_name):
            raise FrameSourceError(
                f"frame {record.index} is a video frame ({record.file_name}), not an image"
            )
        path = folder / record.file_name
        if not path.is_file() and (folder / Path(record.file_name).name).is_file():
            path = folder / Path(record.file_name).name
        if not path.is_file():
            raise FrameSourceError(f"frame {record.index}: image not found: {path}")
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise FrameSourceError(f"frame {record.index}: OpenCV cannot read the image {path}")
        _check_size(bgr, record, str(path))
        yield SequenceFrame(record.index, record.t_ns, bgr, record)


def iter_frames(sequence: SequenceAnnotations, source: str | Path | None = None) -> Iterator[SequenceFrame]:
    """Yield every frame of ``sequence`` in order with its ground truth.

    Parameters
    ----------
    sequence : annotations, e.g. from ``sequence_reader.load_sequence``.
    source : video file or image folder; default: derived from the records (see ``resolve_source``).

    Raises
    ------
    FrameSourceError
        Missing or unreadable media, or a frame count or size that differs from the JSON; raised
        before the first frame for a missing source or a wrong video frame count.
    """
    path = resolve_source(sequence, source)
    return _iter_video(sequence, path) if path.is_file() else _iter_images(sequence, path)
