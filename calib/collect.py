"""Board views from the operator's pictures: every image of a glob, or chosen frames of a video."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dronekey.calib.diagnose import explain_no_board
from dronekey.calib.errors import CalibInputError
from dronekey.calib.patterns import BoardDetector
from dronekey.calib.select_views import ViewCandidate, board_sharpness, pose_descriptor, select_diverse
from dronekey.calib.sources import VideoSampler, expand_image_glob, read_gray
from dronekey.calib.views import BoardView, RejectedView

__all__ = ["Collection", "collect_from_images", "collect_from_video"]

#: Pictures kept aside for ``explain_no_board`` when detection fails everywhere.
_DIAGNOSIS_SAMPLES = 2


@dataclass
class Collection:
    """The views to calibrate from and what was left out.

    Attributes
    ----------
    views, names : lists
        One ``BoardView`` and its picture's name per usable view: the file's path relative to the
        folder all matched files share (its name for a flat folder), or ``video#frame``.
    image_size : (int, int)
        (width, height) of the pictures, pixels.
    rejected : list of RejectedView
        Pictures without a usable board.
    summary : str
        One line on what was read, e.g. ``"board found in 25 of 25 images"``.
    """

    views: list[BoardView]
    names: list[str]
    image_size: tuple[int, int]
    rejected: list[RejectedView] = field(default_factory=list)
    summary: str = ""


def _check_size(size: tuple[int, int] | None, gray: np.ndarray, name: str, first: str) -> tuple[int, int]:
    this = (int(gray.shape[1]), int(gray.shape[0]))
    if size is not None and this != size:
        raise CalibInputError(
            f"pictures differ in size: {first} is {size[0]}x{size[1]} but {name} is {this[0]}x{this[1]}; "
            "calibrate one resolution at a time"
        )
    return this


def collect_from_images(pattern_glob: str, detector: BoardDetector, progress: bool = True) -> Collection:
    """Detect the board in every file matching ``pattern_glob``.

    Raises
    ------
    CalibInputError
        No file matches, a file cannot be decoded, sizes differ, or no picture shows the board.
    """
    files = expand_image_glob(pattern_glob)
    views, names, rejected, samples = [], [], [], []
    base = Path(os.path.commonpath([str(p.parent) for p in files]))
    label = {p: p.relative_to(base).as_posix() for p in files}  # unique even when ** recursed
    size, first = None, label[files[0]]
    for path in tqdm(files, desc="finding the board", unit="image", disable=None if progress else True):
        gray = read_gray(path)
        size = _check_size(size, gray, label[path], first)
        view = detector.detect(gray)
        if view is None:
            rejected.append(RejectedView(label[path], "no board found"))
            if len(samples) < _DIAGNOSIS_SAMPLES:
                samples.append(gray)
            continue
        views.append(view)
        names.append(label[path])
    noun = "image" if len(files) == 1 else "images"
    if not views:
        where = "the one image" if len(files) == 1 else f"any of the {len(files)} images"
        raise CalibInputError(explain_no_board(detector.pattern, samples, where))
    return Collection(views, names, size, rejected, f"board found in {len(views)} of {len(files)} {noun}")


def collect_from_video(
    path: Path,
    detector: BoardDetector,
    frames: int = 200,
    max_views: int = 30,
    progress: bool = True,
) -> Collection:
    """Examine up to ``frames`` evenly spaced frames of a video and keep ``max_views`` sharp, diverse ones.

    Raises
    ------
    CalibInputError
        The video cannot be opened or decoded, or no examined frame shows the board.
    """
    sampler = VideoSampler(Path(path), frames)
    stem = Path(path).name
    candidates, samples = [], []
    size, examined = None, 0
    bar = tqdm(total=sampler.expected, desc="reading video", unit="frame", disable=None if progress else True)
    with bar:
        for index, gray in sampler:
            examined += 1
            bar.update(1)
            size = _check_size(size, gray, f"frame {index}", "frame 0")
            view = detector.detect(gray)
            if view is None:
                if len(samples) < _DIAGNOSIS_SAMPLES and examined % 10 == 1:
                    samples.append(gray)
                continue
            candidates.append(
                ViewCandidate(
                    f"{stem}#{index}", view, board_sharpness(gray, view), pose_descriptor(view, size)
                )
            )
    if examined == 0:
        raise CalibInputError(f"cannot decode any frame of {path}")
    if not candidates:
        raise CalibInputError(
            explain_no_board(detector.pattern, samples, f"any of {examined} frames of {stem}")
        )
    picked = select_diverse(candidates, max_views)
    summary = (
        f"board found in {len(candidates)} of {examined} frames examined (one in {sampler.step}); "
        f"kept {len(picked)} sharp, diverse views"
    )
    return Collection(
        [candidates[i].view for i in picked],
        [candidates[i].name for i in picked],
        size,
        [],
        summary,
    )
