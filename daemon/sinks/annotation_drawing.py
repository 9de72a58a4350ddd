"""Draw a frame's tracks onto the image: keypoints with their order, body axes, id, range, heading.

Shared by the daemon's annotated-video output (``annotated_video.py``, from ``Track`` objects) and
``dronekey-annotate`` (from the ``/dronekey/tracks`` JSON messages of an MCAP), so both draw the same
picture:

- the four keypoints (full-frame pixels) as dots numbered 1-4 in the drone spec's order, in the
  MCAP annotations' colours (1 red, 2 green, 3 blue, 4 yellow), joined 1-2-3-4 by a thin line;
- the drone's body axes (FRD, docs/design.md §4) projected through the pose ``p_cam = R p_body + t``:
  x forward red, y right green, z down blue, with a length that spans about ``AXIS_PX`` pixels at
  the drone's range (never less than ``AXIS_MIN_M``), so a distant drone's axes stay visible and
  foreshortening still shows the attitude;
- a label ``#3 confirmed 12.4 m  heading 0.82`` (``heading ?`` below ``HEADING_LABEL_MIN`` or when
  unknown, as the MCAP labels say it).

Images are OpenCV BGR ``uint8``; drawing happens on a copy the caller owns.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from dronekey.daemon.messages import check_heading_confidence
from dronekey.geometry.camera import CameraModel
from dronekey.geometry.rotations import quat_wxyz_to_matrix
from dronekey.types import Track, TrackStatus

__all__ = [
    "AXIS_MIN_M",
    "AXIS_PX",
    "HEADING_LABEL_MIN",
    "KEYPOINT_COLOURS_BGR",
    "TrackOverlay",
    "draw_tracks",
    "track_label",
]

# Below this heading confidence the label says "heading ?": the front may be the back.
HEADING_LABEL_MIN = 0.5
AXIS_PX = 60.0  # on-screen length the axes aim for at the drone's range, pixels
AXIS_MIN_M = 0.2  # ... but never shorter than this in the body frame, metres
# Keypoint order colours, BGR: 1 red, 2 green, 3 blue, 4 yellow (as the MCAP's annotations).
KEYPOINT_COLOURS_BGR = ((50, 50, 255), (50, 255, 50), (255, 128, 80), (25, 230, 255))
_AXIS_COLOURS_BGR = ((0, 0, 255), (0, 200, 0), (255, 0, 0))  # x forward red, y right green, z down blue
_OUTLINE_BGR = (255, 255, 255)
_LABEL_BGR = (0, 165, 255)  # the MCAP's track colour (orange)
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_DRAWN_STATUSES = frozenset({"confirmed", "coasting", "tentative"})


@dataclass(frozen=True)
class TrackOverlay:
    """What is drawn for one track: its id, status, pose (camera frame, m) and last keypoints (px)."""

    track_id: int
    status: str
    position_m: np.ndarray  # (3,)
    quaternion_wxyz: np.ndarray  # (4,) body -> camera
    keypoints_px: np.ndarray | None  # (4, 2) full-frame pixels, or None while coasting
    heading_confidence: float  # [0, 1], NaN when unknown

    @classmethod
    def from_track(cls, track: Track) -> TrackOverlay:
        status = track.status.value if isinstance(track.status, TrackStatus) else str(track.status)
        kp = None if track.keypoints_px is None else np.asarray(track.keypoints_px, float).reshape(4, 2)
        return cls(
            int(track.track_id),
            status,
            np.asarray(track.position_m, dtype=np.float64).reshape(3),
            np.asarray(track.quaternion_wxyz, dtype=np.float64).reshape(4),
            kp,
            check_heading_confidence(track.heading_confidence),
        )

    @classmethod
    def from_message(cls, message: Mapping[str, Any]) -> TrackOverlay:
        """From a track message (``messages.track_message``; JSON null -> NaN).

        Raises
        ------
        ValueError
            Naming the field that is missing or has the wrong shape.
        """
        try:
            kp = message.get("keypoints_px")
            return cls(
                int(message["track_id"]),
                str(message["status"]),
                _floats(message["position_m"], (3,)),
                _floats(message["quaternion_wxyz"], (4,)),
                None if kp is None else _floats(kp, (4, 2)),
                check_heading_confidence(message.get("heading_confidence")),
            )
        except KeyError as exc:
            raise ValueError(f"track message lacks {exc.args[0]!r}") from None

    @property
    def range_m(self) -> float:
        return float(np.linalg.norm(self.position_m))


def _floats(values: Any, shape: tuple[int, ...]) -> np.ndarray:
    """A JSON array (nulls as NaN) as a float array of ``shape``."""

    def nulls_to_nan(v: Any) -> Any:
        return [nulls_to_nan(x) for x in v] if isinstance(v, list) else (math.nan if v is None else v)

    arr = np.asarray(nulls_to_nan(values), dtype=np.float64)
    if arr.shape != shape:
        raise ValueError(f"expected shape {shape}, got {arr.shape}")
    return arr


def track_label(overlay: TrackOverlay) -> str:
    """``#3 confirmed 12.4 m  heading 0.82``; the range is left out when unknown, the heading is
    ``?`` below ``HEADING_LABEL_MIN`` or when unknown."""
    label = f"#{overlay.track_id} {overlay.status}"
    rng = overlay.range_m
    if math.isfinite(rng):
        label += f" {rng:.1f} m"
    confidence = overlay.heading_confidence
    heading = f"{confidence:.2f}" if math.isfinite(confidence) and confidence >= HEADING_LABEL_MIN else "?"
    return f"{label}  heading {heading}"


def _scale(image: np.ndarray) -> float:
    """Line and text scale: 1 at 1080 rows."""
    return max(0.5, image.shape[0] / 1080.0)


def _point(uv: np.ndarray) -> tuple[int, int]:
    return int(round(float(uv[0]))), int(round(float(uv[1])))


def _finite(uv: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(uv))) and bool(np.all(np.abs(uv) < 1e6))


def _draw_keypoints(image: np.ndarray, kp: np.ndarray, s: float) -> None:
    if not _finite(kp):
        return
    pts = [_point(p) for p in kp]
    cv2.polylines(image, [np.array(pts, np.int32)], True, _OUTLINE_BGR, max(1, round(s)), cv2.LINE_AA)
    centre = kp.mean(axis=0)
    for i, (p, colour) in enumerate(zip(pts, KEYPOINT_COLOURS_BGR, strict=True)):
        cv2.circle(image, p, max(2, round(3 * s)), colour, -1, cv2.LINE_AA)
        away = kp[i] - centre
        norm = float(np.linalg.norm(away))
        direction = away / norm if norm > 1e-6 else np.array([0.0, -1.0])
        text_at = kp[i] + direction * 14 * s - np.array([5, -5]) * s
        _text(image, str(i + 1), text_at, colour, 0.5 * s)


def _draw_axes(image: np.ndarray, overlay: TrackOverlay, camera: CameraModel, s: float) -> None:
    t = overlay.position_m
    q = overlay.quaternion_wxyz
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q))) or t[2] <= 0:
        return
    length = max(AXIS_MIN_M, AXIS_PX * s * float(t[2]) / camera.fx)
    R = quat_wxyz_to_matrix(q / np.linalg.norm(q))
    body = np.vstack([np.zeros(3), np.eye(3) * length])
    ends_cam = body @ R.T + t
    if np.any(ends_cam[:, 2] <= 0.05 * t[2]):  # an axis tip behind or at the camera: not drawable
        return
    uv = camera.project_body(body, R, t)
    if not _finite(uv):
        return
    origin = _point(uv[0])
    for tip, colour in zip(uv[1:], _AXIS_COLOURS_BGR, strict=True):
        cv2.arrowedLine(image, origin, _point(tip), colour, max(1, round(2 * s)), cv2.LINE_AA, tipLength=0.2)


def _text(image: np.ndarray, text: str, at: np.ndarray, colour: tuple, scale: float) -> None:
    """Text with a dark backing box, kept inside the image."""
    thickness = max(1, round(scale * 2))
    (w, h), base = cv2.getTextSize(text, _FONT, scale, thickness)
    height, width = image.shape[:2]
    x = int(min(max(float(at[0]), 2), max(2, width - w - 2)))
    y = int(min(max(float(at[1]), h + 2), height - base - 2))
    x0, y0, x1, y1 = x - 2, y - h - 2, x + w + 2, y + base + 2
    roi = image[max(y0, 0) : max(y1, 0), max(x0, 0) : max(x1, 0)]
    roi[...] = (roi * 0.4).astype(image.dtype)
    cv2.putText(image, text, (x, y), _FONT, scale, colour, thickness, cv2.LINE_AA)


def _anchor(overlay: TrackOverlay, camera: CameraModel | None) -> np.ndarray | None:
    """Where the label goes: above the keypoints, else above the projected position."""
    if overlay.keypoints_px is not None and _finite(overlay.keypoints_px):
        return np.array([overlay.keypoints_px[:, 0].min(), overlay.keypoints_px[:, 1].min()])
    if camera is not None and np.all(np.isfinite(overlay.position_m)) and overlay.position_m[2] > 0:
        uv = camera.project(overlay.position_m.reshape(1, 3))[0]
        return uv if _finite(uv) else None
    return None


def draw_tracks(
    image: np.ndarray, overlays: Iterable[TrackOverlay], camera: CameraModel | None = None
) -> np.ndarray:
    """Draw every track that is not lost onto ``image`` (in place) and return it.

    ``camera`` (intrinsics at the image's resolution) is needed for the axes and to place the
    label of a coasting track; without it only keypoints and labels are drawn.
    """
    s = _scale(image)
    for overlay in overlays:
        if overlay.status not in _DRAWN_STATUSES:
            continue
        if overlay.keypoints_px is not None:
            _draw_keypoints(image, overlay.keypoints_px, s)
        if camera is not None:
            _draw_axes(image, overlay, camera, s)
        anchor = _anchor(overlay, camera)
        if anchor is not None:
            _text(image, track_label(overlay), anchor + np.array([0.0, -40.0 * s]), _LABEL_BGR, 0.6 * s)
    return image
