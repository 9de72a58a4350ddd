"""The camera images of the MCAP log: which frames get one, at what size, with which calibration.

Images are written at ``image_rate_hz`` of frame time (``ImageSchedule``) and downscaled to at most
``image_max_width`` pixels; their calibration and annotations follow the downscaled size
(``ImageSize``).
"""

from __future__ import annotations

import logging

from dronekey.geometry.camera import CameraModel

__all__ = ["ImageSchedule", "ImageSize", "resized_camera"]

log = logging.getLogger(__name__)


class ImageSchedule:
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


class ImageSize:
    """The size and calibration of the published images for frames of a given size.

    Parameters
    ----------
    camera : CameraModel
        Intrinsics at the source resolution.
    max_width : int
        Wider frames are downscaled to this width (the height follows, rounded), pixels.
    """

    def __init__(self, camera: CameraModel, max_width: int) -> None:
        self._camera = camera
        self._max_width = int(max_width)
        self._warned = False
        self.set_source(camera.width, camera.height)

    def set_source(self, width: int, height: int) -> None:
        """Frames are now ``width`` x ``height``: set ``image_size``, ``image_camera`` and ``scale``."""
        camera = self._camera
        if (width, height) != (camera.width, camera.height):
            if not self._warned:
                log.warning(
                    "frames are %dx%d but the calibration is %dx%d: scaling the calibration",
                    width,
                    height,
                    camera.width,
                    camera.height,
                )
                self._warned = True
            camera = resized_camera(camera, width, height)
        if width > self._max_width:
            out_w, out_h = self._max_width, max(1, round(height * self._max_width / width))
        else:
            out_w, out_h = width, height
        self.source_size = (width, height)
        self.image_size = (out_w, out_h)
        self.image_camera = resized_camera(camera, out_w, out_h)

    @property
    def scale(self) -> tuple[float, float]:
        """(sx, sy): the published image's size over the frame's."""
        (src_w, src_h), (out_w, out_h) = self.source_size, self.image_size
        return out_w / src_w, out_h / src_h


def resized_camera(camera: CameraModel, width: int, height: int) -> CameraModel:
    """``camera`` for an image resized to ``width`` x ``height`` (as cv2.resize maps pixel centres).

    ``CameraModel.scaled_to`` is the same mapping behind a check that the aspect ratio stays within
    half a pixel, right for a calibration file against a source but not here: a downscaled image's
    rounded height can change the aspect ratio by up to half a pixel times width / height (1024x600
    to 960 wide: 0.85 px), and a source whose resolution changed may differ more. So x and y scale
    separately, exactly as the resize does.
    """
    sx, sy = width / camera.width, height / camera.height
    K = camera.K.copy()
    K[0, 0] *= sx
    K[0, 1] *= sx
    K[1, 1] *= sy
    K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return CameraModel(width, height, K, camera.dist.copy(), camera.rms_px)
