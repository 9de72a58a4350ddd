"""Foxglove messages of one frame for the log (docs/design.md §6.3): image, calibration,
annotations and transforms, built as ``foxglove-sdk`` message objects (Foxglove's published
protobuf schemas; ``.encode()`` gives the bytes the channels carry).

Quaternions are ``x, y, z, w``, image data raw JPEG bytes, and 2D image coordinates have their
origin at the top-left *corner* of the top-left pixel (Foxglove's convention; DroneKey's pixels
have it at the pixel's centre).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable

import numpy as np
from foxglove import messages as fgm

from dronekey.daemon import messages
from dronekey.geometry.camera import CameraModel
from dronekey.types import KeypointDetection, Track, TrackStatus

__all__ = [
    "HEADING_LABEL_MIN",
    "LINE_LOOP",
    "POINTS",
    "TRACK_RGBA",
    "camera_calibration",
    "colour",
    "compressed_image",
    "frame_transforms",
    "image_annotations",
    "timestamp",
    "track_label",
]

log = logging.getLogger(__name__)

POINTS, LINE_LOOP = fgm.PointsAnnotationType.Points, fgm.PointsAnnotationType.LineLoop

# Keypoint order colours (RGBA in [0, 1]): 1 red, 2 green, 3 blue, 4 yellow.
_KEYPOINT_RGBA = ((1.0, 0.2, 0.2, 1.0), (0.2, 1.0, 0.2, 1.0), (0.3, 0.5, 1.0, 1.0), (1.0, 0.9, 0.1, 1.0))
_ROI_RGBA = (0.0, 0.9, 1.0, 1.0)
TRACK_RGBA = (1.0, 0.6, 0.0, 1.0)
_LABEL_BACKGROUND_RGBA = (0.0, 0.0, 0.0, 0.6)
# Below this heading confidence a track label says "heading ?": the front may be the back.
HEADING_LABEL_MIN = 0.5


# --------------------------------------------------------------------------- builders
def timestamp(t_ns: int) -> fgm.Timestamp:
    """Foxglove ``Timestamp`` of an integer ns timestamp (negative times clamp to 0)."""
    sec, nsec = divmod(max(int(t_ns), 0), 1_000_000_000)
    return fgm.Timestamp(sec, nsec)


def colour(rgba: tuple[float, float, float, float]) -> fgm.Color:
    """Foxglove ``Color`` of (r, g, b, a) in [0, 1]."""
    r, g, b, a = rgba
    return fgm.Color(r=r, g=g, b=b, a=a)


def compressed_image(t_ns: int, frame_id: str, jpeg: bytes) -> fgm.CompressedImage:
    """``foxglove.CompressedImage`` of JPEG bytes (carried as bytes, not base64)."""
    return fgm.CompressedImage(timestamp=timestamp(t_ns), frame_id=frame_id, data=bytes(jpeg), format="jpeg")


def _distortion(dist: np.ndarray) -> tuple[str, list[float]]:
    d = [float(v) for v in dist]
    if len(d) <= 5:
        return "plumb_bob", d + [0.0] * (5 - len(d))
    if len(d) > 8 and any(d[8:]):
        log.warning("Foxglove's camera models take at most 8 distortion coefficients; dropping %s", d[8:])
    return "rational_polynomial", d[:8]


def camera_calibration(t_ns: int, frame_id: str, camera: CameraModel) -> fgm.CameraCalibration:
    """``foxglove.CameraCalibration`` of an OpenCV camera model (monocular: R = I, P = [K | 0])."""
    model, D = _distortion(camera.dist)
    K = camera.K
    P = np.hstack([K, np.zeros((3, 1))])
    return fgm.CameraCalibration(
        timestamp=timestamp(t_ns),
        frame_id=frame_id,
        width=camera.width,
        height=camera.height,
        distortion_model=model,
        D=D,
        K=[float(v) for v in K.ravel()],
        R=[float(v) for v in np.eye(3).ravel()],
        P=[float(v) for v in P.ravel()],
    )


def _corner_point(u: float, v: float, sx: float, sy: float) -> tuple[float, float]:
    """Full-frame pixel (centre origin) -> Foxglove point in the resized image (corner origin)."""
    return (float(u) + 0.5) * sx, (float(v) + 0.5) * sy


def _points(
    t: fgm.Timestamp,
    kind,
    pts: list[tuple[float, float]],
    rgba: tuple,
    colours: list[tuple],
    thickness: float,
) -> fgm.PointsAnnotation:
    return fgm.PointsAnnotation(
        timestamp=t,
        type=kind,
        points=[fgm.Point2(x=x, y=y) for x, y in pts],
        outline_color=colour(rgba),
        outline_colors=[colour(c) for c in colours],
        fill_color=colour((0.0, 0.0, 0.0, 0.0)),
        thickness=thickness,
    )


def _text(
    t: fgm.Timestamp, at: tuple[float, float], text: str, rgba: tuple, font_size: float
) -> fgm.TextAnnotation:
    return fgm.TextAnnotation(
        timestamp=t,
        position=fgm.Point2(x=at[0], y=at[1]),
        text=text,
        font_size=font_size,
        text_color=colour(rgba),
        background_color=colour(_LABEL_BACKGROUND_RGBA),
    )


def track_label(track: Track) -> str:
    """The text beside a track in the image: ``#<id> <status> <range> m  heading <confidence>``.

    The range is the distance from the camera, m, left out when unknown. The heading part is
    ``Track.heading_confidence`` with two decimals, or ``heading ?`` when it is below
    ``HEADING_LABEL_MIN`` (0.5) or unknown (NaN): the front is not known, so the drone's frame on
    ``/tf`` may point backwards. Example: ``#3 confirmed 12.4 m  heading 0.82``.

    Raises
    ------
    ValueError
        Naming ``heading_confidence`` if it is outside [0, 1].
    """
    rng = float(np.linalg.norm(np.asarray(track.position_m, dtype=np.float64)))
    status = track.status.value if isinstance(track.status, TrackStatus) else str(track.status)
    label = f"#{track.track_id} {status}"
    if math.isfinite(rng):
        label += f" {rng:.1f} m"
    confidence = messages.check_heading_confidence(track.heading_confidence)
    # NaN compares False: unknown reads as "?" too.
    heading = f"{confidence:.2f}" if confidence >= HEADING_LABEL_MIN else "?"
    return f"{label}  heading {heading}"


def image_annotations(
    t_ns: int,
    detection: KeypointDetection | None,
    tracks: Iterable[Track] = (),
    scale: tuple[float, float] = (1.0, 1.0),
) -> fgm.ImageAnnotations:
    """``foxglove.ImageAnnotations`` of one frame: the detection's 4 keypoints with their order labels
    1-4, the crop ROI as a box, and a label per track that has keypoints (``track_label``: id,
    status, range and heading confidence).

    Parameters
    ----------
    t_ns : int
        Frame time, ns (the image's timestamp, so Foxglove pairs them).
    detection : KeypointDetection or None
        Keypoints in full-frame pixels (centre origin) and the ROI (x0, y0, side).
    tracks : iterable of Track
    scale : (sx, sy)
        Size of the published image over the full frame's (the JPEG may be downscaled).
    """
    sx, sy = scale
    t = timestamp(t_ns)
    font = max(10.0, 24.0 * sy)
    points, texts = [], []
    if detection is not None:
        kp = np.asarray(detection.keypoints_px, dtype=np.float64).reshape(-1, 2)
        finite = [i for i in range(len(kp)) if np.all(np.isfinite(kp[i]))]
        pts = [_corner_point(kp[i, 0], kp[i, 1], sx, sy) for i in finite]
        colours = [_KEYPOINT_RGBA[i % 4] for i in finite]
        points.append(_points(t, POINTS, pts, _KEYPOINT_RGBA[0], colours, max(4.0, 10.0 * sx)))
        for i, (x, y) in zip(finite, pts, strict=True):
            texts.append(_text(t, (x + 6.0 * sx, y - 6.0 * sy), str(i + 1), _KEYPOINT_RGBA[i % 4], font))
        x0, y0, side = (float(v) for v in detection.roi)
        box = [(x0, y0), (x0 + side, y0), (x0 + side, y0 + side), (x0, y0 + side)]  # corner coordinates
        box_pts = [(x * sx, y * sy) for x, y in box]
        points.append(_points(t, LINE_LOOP, box_pts, _ROI_RGBA, [], max(1.0, 2.0 * sx)))
        texts.append(_text(t, (x0 * sx, y0 * sy - 4.0), f"p={detection.presence:.2f}", _ROI_RGBA, font))
    for track in tracks:
        if track.keypoints_px is None or track.status == TrackStatus.LOST:
            continue
        kp = np.asarray(track.keypoints_px, dtype=np.float64).reshape(-1, 2)
        if not np.all(np.isfinite(kp)):
            continue
        label = track_label(track)
        x, y = _corner_point(kp[:, 0].min(), kp[:, 1].max(), sx, sy)
        texts.append(_text(t, (x, y + font * 1.2), label, TRACK_RGBA, font))
    return fgm.ImageAnnotations(timestamp=t, points=points, texts=texts)


def frame_transforms(t_ns: int, parent_frame_id: str, tracks: Iterable[Track]) -> fgm.FrameTransforms:
    """``foxglove.FrameTransforms`` camera -> ``drone_<track_id>`` for each track with a finite pose.

    The drone frame is the body frame (FRD) placed by ``p_cam = R @ p_body + t``: translation is
    ``position_m``, rotation the body -> camera quaternion in Foxglove's (x, y, z, w) order.
    """
    t = timestamp(t_ns)
    transforms = []
    for track in tracks:
        p = np.asarray(track.position_m, dtype=np.float64).reshape(-1)
        q = np.asarray(track.quaternion_wxyz, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or q.shape != (4,) or not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
            continue
        norm = float(np.linalg.norm(q))
        if norm < 1e-12:
            continue
        q = q / norm
        transforms.append(
            fgm.FrameTransform(
                timestamp=t,
                parent_frame_id=parent_frame_id,
                child_frame_id=f"drone_{int(track.track_id)}",
                translation=fgm.Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                rotation=fgm.Quaternion(x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0])),
            )
        )
    return fgm.FrameTransforms(transforms=transforms)
