"""A decoder's YUV frame converted to colour only where a stage asks: the same pixels as converting
the whole frame, on real decoded H.264."""

from __future__ import annotations

import av
import cv2
import numpy as np
import pytest

from dronekey.frame_image import BgrImage, I420Image, as_frame_image
from dronekey.geometry.crop import crop_square
from dronekey.perception.frame_change import frame_change
from dronekey.perception.localizer import LocalizerConfig, saliency_pass
from dronekey.types import Frame

W, H = 320, 240


@pytest.fixture(scope="module")
def decoded(tmp_path_factory) -> list[np.ndarray]:
    """I420 planes of a real H.264 clip: a moving colour bar on noise, decoded by PyAV."""
    path = tmp_path_factory.mktemp("clip") / "bars.mp4"
    rng = np.random.default_rng(3)
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=30)
        stream.width, stream.height, stream.pix_fmt = W, H, "yuv420p"
        for i in range(4):
            img = rng.integers(100, 140, (H, W, 3), dtype=np.uint8)  # in gamut: no clipping
            img[:, (40 * i) % W : (40 * i) % W + 60] = (20, 200, 250)
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="bgr24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    with av.open(str(path)) as container:
        return [f.to_ndarray() for f in container.decode(video=0)]


def test_regions_are_the_whole_frames_conversion_bit_for_bit(decoded):
    image = I420Image(decoded[1])
    whole = cv2.cvtColor(decoded[1], cv2.COLOR_YUV2BGR_I420)
    assert image.size == (W, H) and image.shape == (H, W, 3)
    for x0, y0, x1, y1 in [
        (0, 0, W, H),
        (1, 1, 2, 2),
        (7, 3, 100, 61),
        (W - 5, H - 3, W, H),
        (10, 20, 11, 200),
    ]:
        assert np.array_equal(image.region_bgr(x0, y0, x1, y1), whole[y0:y1, x0:x1])
    assert np.array_equal(image.bgr(), whole) and not image.bgr().flags.writeable
    assert image.bgr() is image.bgr()  # converted once, then kept


def test_crops_and_change_match_the_bgr_path(decoded):
    planes, bgr = I420Image(decoded[2]), BgrImage(cv2.cvtColor(decoded[2], cv2.COLOR_YUV2BGR_I420))
    previous = I420Image(decoded[1])
    for roi in [
        (50, 40, 64),
        (-20, -10, 90),
        (W - 30, H - 30, 128),
        (400, 10, 20),
    ]:  # inside, past edges, off
        assert np.array_equal(crop_square(planes, roi, 32), crop_square(bgr, roi, 32))
    kp = np.array([[100.0, 100.0], [140.0, 100.0], [140.0, 130.0], [100.0, 130.0]])
    assert frame_change(planes, previous, kp) == frame_change(bgr, previous.bgr(), kp)


def test_the_search_copy_is_downscaled_before_the_conversion(decoded):
    planes = I420Image(decoded[0])
    whole = cv2.cvtColor(decoded[0], cv2.COLOR_YUV2BGR_I420)
    small = planes.downscaled_bgr(160, 120)
    reference = cv2.resize(whole, (160, 120), interpolation=cv2.INTER_AREA)
    assert small.shape == (120, 160, 3)
    assert np.abs(small.astype(int) - reference).mean() < 2.0  # the same picture, up to chroma rounding
    config = LocalizerConfig(work_width=160, use_motion=False)
    assert saliency_pass(planes, config).small.shape == saliency_pass(whole, config).small.shape


def test_frames_wrap_bgr_arrays_and_reject_malformed_planes():
    bgr = np.zeros((H, W, 3), np.uint8)
    frame = Frame(0, 0, bgr)
    assert isinstance(frame.image, BgrImage) and frame.size == (W, H) and frame.bgr.base is bgr
    assert bgr.flags.writeable  # the caller's array is left writable; the frame's view is not
    assert as_frame_image(frame.image) is frame.image
    with pytest.raises(ValueError, match=r"i420 must be an \(H \* 3 / 2, W\) uint8 array"):
        I420Image(np.zeros((241, 320), np.uint8))
    with pytest.raises(ValueError, match="bgr must be an"):
        BgrImage(np.zeros((H, W), np.uint8))
