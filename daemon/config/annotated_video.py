"""The ``annotated_video`` section: the H.264 video of the frames with the tracks drawn on them."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator

from dronekey.daemon.config.section import Section

__all__ = ["VIDEO_SUFFIXES", "AnnotatedVideoConfig"]

VIDEO_SUFFIXES = (".mp4", ".mkv", ".mov")


class AnnotatedVideoConfig(Section):
    """Annotated video output (``--annotated-video FILE``); off while ``path`` is null.

    Every frame is drawn and encoded (libx264, yuv420p, the source's frame rate) on the output's own
    worker; when encoding falls behind the source, the oldest waiting frames are dropped and counted.
    """

    path: Path | None = Field(None, description="video file (.mp4, .mkv or .mov); null: off")
    crf: int = Field(23, ge=0, le=51, description="x264 constant rate factor: lower is better and larger")
    preset: Literal["ultrafast", "superfast", "veryfast", "faster", "fast", "medium"] = Field(
        "veryfast", description="x264 speed preset: slower presets make smaller files for more CPU"
    )
    threads: int = Field(2, ge=0, le=64, description="encoder threads (0: x264 picks, about 1.5 per core)")
    keyframe_interval_s: float = Field(
        2.0, gt=0, le=60, description="a keyframe (and MP4 fragment) this often: a killed daemon loses less"
    )
    queue_frames: int = Field(8, ge=1, le=256, description="frames waiting for the encoder (drop oldest)")

    @field_validator("path")
    @classmethod
    def _video_suffix(cls, v: Path | None) -> Path | None:
        if v is not None and v.suffix.lower() not in VIDEO_SUFFIXES:
            raise ValueError(f"must end in {', '.join(VIDEO_SUFFIXES)} (the container is chosen by it)")
        return v
