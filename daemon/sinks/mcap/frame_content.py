"""What one frame puts on the Foxglove channels, as encoded messages ready for the file and the
live view alike: ``(topic, log time ns, bytes)``.

Every frame: the track messages (JSON, as on Zenoh), the image annotations, ``/tf`` and the 3D
scene; a JPEG on the image grid (``image_rate_hz`` of frame time); with the camera's geodetic pose,
a LocationFix per track. About once a second per destination (``periodic``): the calibration of the
published image size and, with the geodetic pose, the camera's LocationFix and field of view.
"""

from __future__ import annotations

import cv2
import numpy as np

from dronekey.daemon import messages
from dronekey.daemon.config.mcap import McapConfig
from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.base import FrameUpdate
from dronekey.daemon.sinks.mcap import foxglove, geo_scene
from dronekey.daemon.sinks.mcap.images import ImageSchedule, ImageSize
from dronekey.geometry.camera import CameraModel

__all__ = ["PERIODIC_NS", "FrameContent", "Message", "periodic_due"]

Message = tuple[str, int, bytes]
PERIODIC_NS = 1_000_000_000  # calibration and camera map messages, so a reader seeking anywhere finds one


def periodic_due(last_t_ns: int | None, t_ns: int) -> bool:
    """True when the periodic messages are due at ``t_ns`` for a destination that last got them at
    ``last_t_ns`` (None: never; time going back makes them due too)."""
    return last_t_ns is None or not 0 <= t_ns - last_t_ns < PERIODIC_NS


class FrameContent:
    """Builds the encoded Foxglove messages of each frame (see the module docstring).

    Parameters
    ----------
    config : McapConfig
        ``image_rate_hz``, ``image_max_width`` and ``jpeg_quality`` are used.
    camera : CameraModel
        Intrinsics at the source resolution.
    camera_id : str
        Frame id of the images, calibration, scene and ``/tf`` parent.
    camera_geo : CameraGeo, optional
        The camera's geodetic pose: adds WGS84 fields to the tracks and the map messages.
    """

    def __init__(
        self, config: McapConfig, camera: CameraModel, camera_id: str, camera_geo: CameraGeo | None = None
    ) -> None:
        self._camera_id = camera_id
        self._camera_geo = camera_geo
        self._jpeg_params = [cv2.IMWRITE_JPEG_QUALITY, config.jpeg_quality]
        period_ns = int(1e9 / config.image_rate_hz) if config.image_rate_hz > 0 else None
        self._images = ImageSchedule(period_ns)  # the sink thread's: images built
        self.offers = ImageSchedule(period_ns)  # the pipeline thread's: images queued
        self._image_size = ImageSize(camera, config.image_max_width)
        self._paths = geo_scene.TrackPaths()
        self.image_size_changed = False  # set when the published size changed: re-send the calibration

    def frame(self, update: FrameUpdate) -> list[Message]:
        """The messages of one frame, in log order."""
        t_ns = int(update.t_ns)
        out: list[Message] = []
        for track in update.tracks:
            message = messages.track_message(track, self._camera_id, self._camera_geo)
            out.append(("/dronekey/tracks", t_ns, messages.to_json_bytes(message)))
        if update.image is not None and self._images.due(t_ns):
            out.append(("/camera/image", t_ns, self._jpeg(t_ns, update.image.bgr())))
            self._images.taken(t_ns)
        annotations = foxglove.image_annotations(
            t_ns, update.detection, update.tracks, self._image_size.scale
        )
        out.append(("/dronekey/annotations", t_ns, annotations.encode()))
        transforms = foxglove.frame_transforms(t_ns, self._camera_id, update.tracks)
        if len(transforms.encode()):
            out.append(("/tf", t_ns, transforms.encode()))
        self._paths.update(t_ns, update.tracks)
        scene = geo_scene.scene_update(
            t_ns, self._camera_id, self._image_size.image_camera, update.tracks, self._paths
        )
        out.append(("/dronekey/scene", t_ns, scene.encode()))
        if self._camera_geo is not None:
            for track in update.tracks:
                fix = geo_scene.track_fix(t_ns, track, self._camera_geo)
                if fix is not None:
                    out.append(("/dronekey/fix", t_ns, fix.encode()))
        return out

    def periodic(self, t_ns: int) -> list[Message]:
        """The calibration of the published images, and the camera's fix and field of view."""
        camera = self._image_size.image_camera
        out = [
            ("/camera/calibration", t_ns, foxglove.camera_calibration(t_ns, self._camera_id, camera).encode())
        ]
        if self._camera_geo is not None:
            fix = geo_scene.camera_fix(t_ns, self._camera_id, self._camera_geo)
            fov = geo_scene.fov_geojson(self._camera_id, camera, self._camera_geo)
            out += [("/camera/fix", t_ns, fix.encode()), ("/camera/fov", t_ns, fov.encode())]
        return out

    def _jpeg(self, t_ns: int, image: np.ndarray) -> bytes:
        height, width = image.shape[:2]
        if self._image_size.source_size != (width, height):
            self._image_size.set_source(width, height)
            self.image_size_changed = True
        out_w, out_h = self._image_size.image_size
        small = (
            image
            if (out_w, out_h) == (width, height)
            else cv2.resize(image, (out_w, out_h), interpolation=cv2.INTER_AREA)
        )
        ok, jpeg = cv2.imencode(".jpg", small, self._jpeg_params)
        if not ok:
            raise ValueError(f"JPEG encoding failed for an image of shape {image.shape}")
        return foxglove.compressed_image(t_ns, self._camera_id, jpeg.tobytes()).encode()
