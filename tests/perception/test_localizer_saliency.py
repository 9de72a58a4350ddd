"""The localiser's fast saliency helpers give exactly what the plain numpy formulas give (they are
speed-ups, not approximations), so acquisition picks the same candidates as before."""

import cv2
import numpy as np
import pytest

from dronekey.perception.localizer import (
    LocalizerConfig,
    _blobs,
    _max_abs_difference,
    _median,
    _median_of_levels,
    propose_rois,
    saliency_pass,
)


def reference_blobs(saliency, min_contrast):
    """The original formulation: np.median, the whole map labelled."""
    med = float(np.median(saliency))
    mad = float(np.median(np.abs(saliency - med))) + 1e-3
    thr = max(min_contrast, med + 8.0 * 1.4826 * mad)
    mask = cv2.dilate((saliency > thr).astype(np.uint8), np.ones((3, 3), np.uint8), iterations=2)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    out = []
    for i in range(1, n):
        x, y, bw, bh, area = stats[i]
        if area < 4:
            continue
        region = saliency[y : y + bh, x : x + bw][labels[y : y + bh, x : x + bw] == i]
        out.append((float(region.max()) * np.sqrt(float(area)), (float(x), float(y), float(bw), float(bh))))
    return out


@pytest.mark.parametrize("n", [1, 2, 7, 8, 129_600, 129_601])
def test_median_is_numpys(n):
    rng = np.random.default_rng(n)
    for scale in (1e-3, 1.0, 255.0):
        values = (rng.random(n) * scale).astype(np.float32)
        assert _median(values) == float(np.median(values))
        rounded = np.round(values)  # many ties
        assert _median(rounded) == float(np.median(rounded))


@pytest.mark.parametrize("n", [1, 2, 7, 8, 129_600, 129_601])
def test_the_median_of_whole_grey_levels_is_the_partitions_to_the_bit(n):
    """A motion map (two 8-bit images' difference, mostly still: many zeros) and its deviations
    from its median, in half levels: the histogram's median is ``_median``'s."""
    rng = np.random.default_rng(n)
    for top in (1, 3, 60, 256):
        levels = rng.integers(0, top, n).astype(np.float32)
        levels[rng.random(n) < 0.4] = 0.0
        med = _median(levels)
        assert _median_of_levels(levels, 1.0) == med
        deviations = np.abs(levels - np.float32(med))  # multiples of 0.5 when med is a half level
        assert _median_of_levels(deviations, 0.5) == _median(deviations)


def test_motion_blobs_from_the_histogram_are_the_reference_blobs():
    rng = np.random.default_rng(2)
    for k in range(20):
        motion = np.round(rng.random((270, 480)) ** (4 + k % 8) * 120).astype(np.float32)
        assert _blobs(motion, 12.0, levels=True) == reference_blobs(motion, 12.0)


def test_max_abs_difference_is_numpys():
    rng = np.random.default_rng(0)
    a = (rng.random((270, 480, 3)) * 255).astype(np.float32)
    b = cv2.GaussianBlur(a, (0, 0), 6.0)
    assert np.array_equal(_max_abs_difference(a, b), np.abs(a - b).max(axis=2))


def test_blobs_are_the_reference_blobs():
    rng = np.random.default_rng(1)
    for k in range(50):
        saliency = (rng.random((270, 480)) ** (4 + k % 8) * 120).astype(np.float32)
        assert _blobs(saliency, 12.0) == reference_blobs(saliency, 12.0)
    assert _blobs(np.zeros((64, 64), np.float32), 12.0) == []
    corners = np.zeros((64, 64), np.float32)
    corners[:3, :3] = corners[-3:, -3:] = 50.0
    assert _blobs(corners, 12.0) == reference_blobs(corners, 12.0)


def test_a_small_moving_blob_gets_a_share_of_the_budget_among_big_static_windows():
    """Ranked together by contrast x size, a facade's windows took every candidate; the motion map
    (a static camera) now gets every other one, so a far drone's small moving blob is proposed."""
    frame = np.full((1080, 1920, 3), 170, np.uint8)
    for i in range(12):  # dark windows, 80 px, strongly contrasted
        x, y = 100 + 150 * i, 200 + 300 * (i % 3)
        frame[y : y + 80, x : x + 80] = 60
    previous = frame.copy()
    cv2.rectangle(previous, (930, 640), (960, 648), (110, 110, 110), -1)  # the drone a frame earlier
    cv2.rectangle(frame, (950, 640), (980, 648), (110, 110, 110), -1)  # a 30 x 8 px grey drone
    config = LocalizerConfig()
    _, small = propose_rois(previous, config, 64.0)
    rois, _ = propose_rois(frame, config, 64.0, small)
    assert len(rois) == config.max_candidates
    centres = [(x + s / 2, y + s / 2, s) for x, y, s in rois]
    assert any(abs(cx - 965) < s / 2 and abs(cy - 644) < s / 2 and s < 300 for cx, cy, s in centres), rois
    without_motion, _ = propose_rois(frame, config, 64.0)
    assert not any(
        abs(x + s / 2 - 965) < s / 2 and abs(y + s / 2 - 644) < s / 2 for x, y, s in without_motion
    )


def test_the_three_frame_difference_proposes_the_drone_where_it_is_now_not_where_it_was():
    """Against one earlier frame, a moving drone's motion blob spans both its places, and the crop
    cut from it is twice too large; against the two earlier search frames (``motion_frames`` 3) the
    blob is the drone where it is now."""
    sky = np.full((1080, 1920, 3), 200, np.uint8)
    frames = []
    for x in (800, 860, 920):  # a 40 x 16 px dark drone moving 60 px a search frame
        frame = sky.copy()
        cv2.rectangle(frame, (x, 500), (x + 40, 516), (60, 60, 60), -1)
        frames.append(frame)
    config = LocalizerConfig(motion_frames=3)
    earlier = saliency_pass(frames[0], config).small
    previous = saliency_pass(frames[1], config, earlier).small

    def motion_boxes(three: bool):
        """The blobs of the motion map alone (the contrast map's removed by a flat reference)."""
        cfg = LocalizerConfig(motion_frames=3 if three else 2)
        small = saliency_pass(frames[2], cfg).small
        motion = _max_abs_difference(small, previous)
        if three:
            motion = np.minimum(motion, _max_abs_difference(small, earlier))
        return [box for _, box in _blobs(motion, cfg.min_contrast, levels=True)], small.shape[1] / 1920

    two, scale = motion_boxes(False)
    three, _ = motion_boxes(True)
    assert len(two) == 1 and len(three) == 1
    assert two[0][2] / scale >= 110  # both places: 860-960 px
    x, _, w, _ = (v / scale for v in three[0])
    assert 900 <= x <= 925 and w <= 64  # the drone now (920-960 px), grown by the blob dilation
    # and the pass itself: its motion blob is the three-frame one
    blobs = saliency_pass(frames[2], config, previous, earlier).blobs
    assert three[0] in blobs and two[0] not in blobs


def test_motion_frames_is_two_or_three():
    with pytest.raises(ValueError, match="motion_frames must be 2 or 3, got 4"):
        LocalizerConfig(motion_frames=4)


def test_a_tight_blob_is_the_box_of_its_salient_pixels_with_the_same_score():
    """The dilation joins pixels into regions; with ``tight`` the box is the pixels' own, so a
    small blob's crop is not 16 frame px wider than the object on every side."""
    rng = np.random.default_rng(3)
    for k in range(20):
        saliency = (rng.random((270, 480)) ** (4 + k % 8) * 120).astype(np.float32)
        wide, tight = _blobs(saliency, 12.0), _blobs(saliency, 12.0, tight=True)
        assert [score for score, _ in wide] == [score for score, _ in tight]
        for (_, (x, y, w, h)), (_, (tx, ty, tw, th)) in zip(wide, tight, strict=True):
            assert x <= tx and y <= ty and tx + tw <= x + w and ty + th <= y + h
    spot = np.zeros((64, 64), np.float32)
    spot[30:33, 20:26] = 50.0  # 6 x 3 px above the threshold
    spot[31, 29] = 50.0  # a lone pixel the dilation joins to it
    ((_, wide),) = _blobs(spot, 12.0)
    ((_, tight),) = _blobs(spot, 12.0, tight=True)
    assert wide == (18.0, 28.0, 14.0, 7.0) and tight == (20.0, 30.0, 10.0, 3.0)
