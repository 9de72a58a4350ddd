"""Where in a full frame the keypoint network should look.

A 1080p frame is far larger than the network's 128 px input and a drone may be 30 or 600 px wide,
or absent. Two modes:

- **Acquisition** (the search for drones outside the live tracks): a cheap saliency pass on a
  downscaled frame (local contrast against a blurred background, plus frame-to-frame change for a
  static camera) proposes a few blobs, those on a live track's region left out before the budget
  (``max_candidates``, or the caller's smaller one) is counted, so the live drones never use up the
  search; the network checks them all in one batch, and every one
  above the presence threshold is refined by a second crop framed on its predicted keypoints
  (``dronekey.geometry.crop.CropPolicy``'s framing of the hubs' box; the training crops frame the
  whole drone, body included, so this one sits a little higher), all in a second batch. Each survivor
  becomes its own hypothesis downstream (``acquire_all``).
- **Tracking**: one crop per live track around the box of its predicted pose (propeller discs
  projected through the camera), all in one batch (``track_many``).

Both return ``KeypointDetection`` objects in full-frame pixels.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from dronekey.frame_image import FrameImage, downscaled_bgr
from dronekey.geometry.apparent_size import keypoint_spread
from dronekey.geometry.camera import CameraModel
from dronekey.geometry.crop import CropPolicy, roi_around_box
from dronekey.geometry.drone_spec import DroneSpec
from dronekey.perception.keypoint_model import KeypointModel
from dronekey.types import KeypointDetection

__all__ = [
    "Localizer",
    "LocalizerConfig",
    "Saliency",
    "box_from_keypoints",
    "box_from_pose",
    "box_overlap",
    "keypoint_spread",
    "propose_rois",
    "saliency_pass",
    "select_rois",
]

log = logging.getLogger(__name__)

Box = tuple[float, float, float, float]


@dataclass(frozen=True)
class LocalizerConfig:
    """Acquisition settings.

    presence_threshold : presence probability above which a crop holds a drone.
    work_width : width (px) of the downscaled frame the saliency pass runs on.
    max_candidates : blobs checked by the network per acquisition (one batch): the search's budget
        of candidates per frame (blobs on a live track's region are not counted).
    candidate_scale : crop side over the blob's longer side (blobs often miss faint propellers).
    min_contrast : smallest local contrast (8-bit levels) a blob must reach.
    background_sigma : blur (work-image px) that estimates the local background.
    use_motion : also propose blobs that changed since the previous frame (static cameras).
    motion_frames : frames the motion map compares. 2: this search frame against the last one; a
        moving drone's blob then holds it twice (where it is and where it was), and the crop cut
        from it is 3-4x the drone's framing, where the network sees nothing (a swarm's far drone:
        presence 0.01-0.04). 3: the smaller of its differences with the last two search frames
        (the three-frame difference), which is high only where the drone is now, since where it
        was differs from one earlier frame alone; the two-frame map until two earlier frames exist.
        2 as shipped: 3 found a swarm's far drone sooner but did not raise the tuning swarms'
        IDF1 beyond their noise (docs/evaluation.md).
    tight_blobs : a blob's box (hence its crop) is the box of its pixels above the threshold, not of
        the dilated mask that joins them into one region (which adds 2 map px, 8 frame px at
        ``work_width`` 480 on a 1080p frame, on every side: a far drone's 28 px body came out as a
        76 px blob, and its crop 137 px). Off as shipped: measured with ``motion_frames`` 3, it
        added false tracks on the mixed tuning swarms (docs/evaluation.md).
    recut_shift, recut_scale : in tracking mode, the crop is cut again on the detected keypoints when
        their box's centre is off the crop's centre by more than ``recut_shift`` of the crop side, or
        its size off by more than ``recut_scale`` (relative): the network was trained on crops within
        ``CropPolicy``'s jitter of the drone and degrades outside it, so a lagging prediction is
        corrected the same frame, at the price of a second inference. The network reads a drone's
        size largely from the crop it is given (a drone 66 px across came back 51, 62 and 69 px
        across in crops of 91, 130 and 160 px), so a track whose range drifted feeds its own drift;
        5 % (not 12 %) re-frames it sooner: on the README demo (seq13, default seed) the frames
        holding the drone's track outside the range gate fell from 53 to 27.
    acquire_recut : None (the default): off. When set, a sure refined candidate of a search is cut and
        read once more when the crop its keypoints ask for is off the one it was read in by more than
        this factor either way (0.25: outside 0.8-1.25x). A search crop is sized from a blob, often three
        times the drone, whose rough reading overestimates it; the refined crop cut from that is
        then still too large, and its reading, though right, can fill too little of it for the
        plausibility gate (s9210 of tuning seed 9201: crops of 129-145 px on a drone 47 px across,
        its spread 0.23-0.35 of the side against the gate's 0.38, rejected on every search frame).
        Not on by default: with the shipped model, which reads a drone in a crop too large as too
        large, it added false-track frames; with r10, which reads it right, it found the drone on
        more frames but missed the rule on one tuning set (docs/evaluation.md).
    max_drone_px : longest drone box (full-frame px) a whole salient region is proposed for; a larger
        region (building edges, or wires joining blobs into one) is searched at its strongest
        saliency peaks instead, one candidate per peak sized by the peak's own neighbourhood.
    peaks_per_region : peaks proposed per oversized region.
    wide_look_scale, wide_look_ratio, wide_look_presence : a wide look (``track_looking_wide``)
        reads a track's drone again in a crop ``wide_look_scale`` times the side of its own, same
        centre, when the network's presence on its own crop is below ``wide_look_presence``, and
        takes that reading when the drone comes out more than ``wide_look_ratio`` times wider in it
        (or only in it). The recut above cannot mend a crop cut too small: the network reads a
        drone clipped by its crop with its keypoints crowded together, and the recut then cuts
        tighter still (s8031 of tuning seed 8001: a track read too far, crops of 32-35 px on a
        drone 64-67 px across, keypoints spread 7 px, the range run out to 17-19 m). The network
        also reads a drone's size partly from its crop (a rightly framed drone read 1.06-1.48x its
        spread in a crop twice as large), hence a ratio of 2; and it is sure (presence 1.00) of a
        drone it sees whole at 0.6-1.25x the right framing, less so of a clipped one (0.09-0.97
        at 0.3-0.45x), so a sure crop is not looked at again (the look costs nothing then).
    """

    presence_threshold: float = 0.5
    work_width: int = 480
    max_candidates: int = 6
    candidate_scale: float = 1.8
    min_contrast: float = 12.0
    background_sigma: float = 6.0
    use_motion: bool = True
    motion_frames: int = 2
    tight_blobs: bool = False
    recut_shift: float = 0.04
    recut_scale: float = 0.05
    acquire_recut: float | None = None
    max_drone_px: float = 600.0
    peaks_per_region: int = 3
    wide_look_scale: float = 2.0
    wide_look_ratio: float = 2.0
    wide_look_presence: float = 0.999

    def __post_init__(self) -> None:
        if not 0.0 < self.presence_threshold < 1.0:
            raise ValueError(f"presence_threshold must be in (0, 1), got {self.presence_threshold}")
        if self.work_width < 64:
            raise ValueError(f"work_width must be >= 64, got {self.work_width}")
        if self.max_candidates < 1:
            raise ValueError(f"max_candidates must be >= 1, got {self.max_candidates}")
        if not self.max_drone_px > 0 or self.peaks_per_region < 1:
            raise ValueError(
                "need max_drone_px > 0 and peaks_per_region >= 1, "
                f"got {self.max_drone_px} and {self.peaks_per_region}"
            )
        if not self.wide_look_scale > 1.0 or not self.wide_look_ratio >= 1.0:
            raise ValueError(
                "need wide_look_scale > 1 and wide_look_ratio >= 1, "
                f"got {self.wide_look_scale} and {self.wide_look_ratio}"
            )
        if not 0.0 < self.wide_look_presence <= 1.0:
            raise ValueError(f"wide_look_presence must be in (0, 1], got {self.wide_look_presence}")
        if self.motion_frames not in (2, 3):
            raise ValueError(f"motion_frames must be 2 or 3, got {self.motion_frames}")
        if self.acquire_recut is not None and not self.acquire_recut > 0.0:
            raise ValueError(f"acquire_recut must be > 0, got {self.acquire_recut}")


def box_from_keypoints(keypoints_px: np.ndarray, spec: DroneSpec) -> Box:
    """Approximate box of the whole drone from its four hubs: the hubs' box grown by a propeller
    radius scaled like the hubs' apparent spread."""
    kp = np.asarray(keypoints_px, dtype=np.float64)
    spread = keypoint_spread(kp)
    margin = 0.5 * spec.prop_diameter_m / spec.diagonal_m * spread + 1.0
    lo, hi = kp.min(axis=0) - margin, kp.max(axis=0) + margin
    return float(lo[0]), float(lo[1]), float(hi[0] - lo[0]), float(hi[1] - lo[1])


def box_from_pose(camera: CameraModel, spec: DroneSpec, R: np.ndarray, t: np.ndarray) -> Box | None:
    """Box of the drone at pose (R, t) in full-frame pixels, or None if it is behind the camera."""
    pts = spec.extent_points_m @ np.asarray(R).T + np.asarray(t).reshape(3)
    if pts[:, 2].min() <= 0.05:
        return None
    uv = camera.project(pts)
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    return float(lo[0]), float(lo[1]), float(hi[0] - lo[0]), float(hi[1] - lo[1])


class Localizer:
    """Finds the drone in full frames and runs the keypoint model on the right crops.

    Frames are BGR arrays or ``FrameImage`` s (``dronekey.frame_image``): of a decoder's YUV frame only
    the crops and the search's downscaled copy are converted to colour.

    Parameters
    ----------
    model : KeypointModel
    spec : DroneSpec
        The drone model (for the box around predicted keypoints).
    crop : CropPolicy
        The framing the network was trained on (``input_size`` must match the model).
    config : LocalizerConfig
    """

    def __init__(
        self, model: KeypointModel, spec: DroneSpec, crop: CropPolicy, config: LocalizerConfig | None = None
    ) -> None:
        if crop.input_size != model.input_size:
            raise ValueError(f"crop.input_size {crop.input_size} differs from the model's {model.input_size}")
        self.model = model
        self.spec = spec
        self.crop = crop
        self.config = config or LocalizerConfig()
        self._prev_small: np.ndarray | None = None
        self._earlier_small: np.ndarray | None = None  # the search frame before that (motion_frames 3)

    # ------------------------------------------------------------------ tracking mode
    def detect_in_box(self, frame: np.ndarray | FrameImage, box: Box) -> KeypointDetection:
        """Run the network on the training framing of ``box`` (no jitter)."""
        return self.model.detect(frame, [self.crop.roi(box)])[0]

    def track(self, frame: np.ndarray | FrameImage, box: Box) -> KeypointDetection:
        """Keypoints in the crop of a predicted box, recut once on them when the prediction was off
        (``LocalizerConfig.recut_shift`` / ``recut_scale``)."""
        return self.track_many(frame, [box])[0]

    def track_many(
        self, frame: np.ndarray | FrameImage, boxes: Sequence[Box], verify: Sequence[bool] | None = None
    ) -> list[KeypointDetection]:
        """``track`` for several predicted boxes (one per live track) in one batched inference, and
        one more batch for the crops that need a recut (the patch classifiers run on each crop's
        last cut only). ``verify``: per box, whether the drone verifier looks at its crop (all by
        default; a confirmed track's crop need not: ``KeypointModel.finish``)."""
        return self.track_looking_wide(frame, boxes, verify)[0]

    def track_looking_wide(
        self,
        frame: np.ndarray | FrameImage,
        boxes: Sequence[Box],
        verify: Sequence[bool] | None = None,
        wide: Sequence[bool] | None = None,
    ) -> tuple[list[KeypointDetection], list[bool]]:
        """``track_many``, with a wide look for the boxes ``wide`` flags whose crop the network is
        not sure of (presence below ``LocalizerConfig.wide_look_presence``): their drone is read
        again in a crop ``wide_look_scale`` times larger (one more batch, only when some crop needs
        it), and that reading is taken (then recut on its keypoints like any other) when
        ``_reads_wider`` holds. Returns the detections and, per box, whether its wide reading was
        taken."""
        if not boxes:
            return [], []
        cfg = self.config
        asked = [True] * len(boxes) if verify is None else list(verify)
        reading = self.model.read(frame, [self.crop.roi(box) for box in boxes])
        rough = self.model.rough(reading)
        doubtful = [
            k for k, look in enumerate(wide or ()) if look and rough[k].presence < cfg.wide_look_presence
        ]
        wide_index = {k: len(boxes) + i for i, k in enumerate(doubtful)}  # box -> its wide crop's index
        if doubtful:
            wide_rois = []
            for k in doubtful:
                x0, y0, side = rough[k].roi
                centre_x, centre_y = x0 + side / 2 - 0.5, y0 + side / 2 - 0.5
                wide_rois.append(roi_around_box(centre_x, centre_y, side * cfg.wide_look_scale))
            wide_reading = self.model.read(frame, wide_rois)
            reading = reading.joined(wide_reading)
            rough = rough + self.model.rough(wide_reading)
            asked += [asked[k] for k in doubtful]
        source = list(range(len(boxes)))  # per box, the crop of the reading it keeps
        for k, j in wide_index.items():
            if self._reads_wider(rough[k], rough[j]):
                source[k] = j
        recut = []
        for k, src in enumerate(source):
            off = self._framing_error(rough[src])
            if off is not None and (off[0] > cfg.recut_shift or abs(off[1] - 1.0) > cfg.recut_scale):
                recut.append(k)
        recuts = self.refine_many(frame, [rough[source[k]] for k in recut], [asked[source[k]] for k in recut])
        again = dict(zip(recut, recuts, strict=True))
        held = {k for k, det in again.items() if det.presence >= cfg.presence_threshold}
        first_cut = [k for k in range(len(boxes)) if k not in held]  # no recut, or the recut lost it
        finished = self.model.finish(reading, [source[k] for k in first_cut], asked)
        dets = dict(zip(first_cut, finished, strict=True))
        widened = [source[k] != k for k in range(len(boxes))]
        return [dets[k] if k in dets else again[k] for k in range(len(boxes))], widened

    def _framing_error(self, det: KeypointDetection) -> tuple[float, float] | None:
        """How far the crop a sure reading's keypoints ask for (``refine``'s) is from the one it was
        read in: the centres' largest offset over its side, and the asked side over its side; None
        for a reading without a drone (presence under the threshold, or keypoints not finite)."""
        if det.presence < self.config.presence_threshold or not np.all(np.isfinite(det.keypoints_px)):
            return None
        x0, y0, side = det.roi
        nx, ny, nside = self.crop.roi(box_from_keypoints(det.keypoints_px, self.spec))
        shift = max(abs(nx + nside / 2 - x0 - side / 2), abs(ny + nside / 2 - y0 - side / 2)) / side
        return shift, nside / side

    def _reads_wider(self, narrow: KeypointDetection, wide: KeypointDetection) -> bool:
        """Whether a wide look's reading replaces its narrow crop's: it holds a drone, centred inside
        the narrow crop, and the narrow crop holds none or reads it more than ``wide_look_ratio``
        times smaller (keypoint spread, px): the narrow crop clipped the drone."""
        cfg = self.config
        if wide.presence < cfg.presence_threshold or not np.all(np.isfinite(wide.keypoints_px)):
            return False
        x0, y0, side = narrow.roi
        cx, cy = np.mean(wide.keypoints_px, axis=0)
        if not (x0 <= cx < x0 + side and y0 <= cy < y0 + side):
            return False
        if narrow.presence < cfg.presence_threshold or not np.all(np.isfinite(narrow.keypoints_px)):
            return True
        return keypoint_spread(wide.keypoints_px) > cfg.wide_look_ratio * keypoint_spread(narrow.keypoints_px)

    def refine(self, frame: np.ndarray | FrameImage, detection: KeypointDetection) -> KeypointDetection:
        """Re-crop on the box implied by a detection's keypoints and run the network again."""
        return self.refine_many(frame, [detection])[0]

    def refine_many(
        self,
        frame: np.ndarray | FrameImage,
        detections: Sequence[KeypointDetection],
        verify: Sequence[bool] | None = None,
    ) -> list[KeypointDetection]:
        """``refine`` for several detections in one batch (``verify``: see ``track_many``)."""
        rois = [self.crop.roi(box_from_keypoints(d.keypoints_px, self.spec)) for d in detections]
        return self.model.detect(frame, rois, verify)

    # ------------------------------------------------------------------ acquisition
    def acquire(self, frame: np.ndarray | FrameImage) -> KeypointDetection | None:
        """Search the whole frame; the best refined detection above the presence threshold, or None."""
        found = self.acquire_all(frame)
        return found[0] if found else None

    def acquire_all(
        self,
        frame: np.ndarray | FrameImage,
        exclude: Sequence[Box] = (),
        max_candidates: int | None = None,
        saliency: Saliency | None = None,
    ) -> list[KeypointDetection]:
        """Every candidate of a search outside ``exclude`` that holds a drone, refined, best first.

        Blobs on a box of ``exclude`` (the live tracks' regions, full-frame px) are not proposed,
        and at most ``max_candidates`` (default: the config's) are: the search's budget. All
        candidates are scored in one batch and those above the presence threshold refined in a
        second; detections of the same object (keypoint boxes overlapping by more than a third)
        keep only the best, and those on a box of ``exclude`` are left out. Each becomes its own
        hypothesis downstream, so one false candidate cannot hide the drone. ``saliency``: this
        frame's pass, if already run (``saliency``), else it runs here.
        """
        rois = self.candidate_rois(frame, exclude, max_candidates, saliency)
        if not rois:
            return []
        thr = self.config.presence_threshold
        reading = self.model.read(frame, rois)
        rough = self.model.rough(reading)
        # A candidate on a live track's drone is not refined: the track's own crop measures it.
        hits = [
            k
            for k, d in enumerate(rough)
            if d.presence >= thr and not _on_any(box_from_keypoints(d.keypoints_px, self.spec), exclude)
        ]
        if not hits:
            return []
        refined = self._recut_misframed(frame, self.refine_many(frame, [rough[k] for k in hits]))
        failed = [k for k, r in zip(hits, refined, strict=True) if r.presence < thr]
        first = dict(zip(failed, self.model.finish(reading, failed), strict=True))  # their first cut stands
        found = [first.get(k, r) for k, r in zip(hits, refined, strict=True)]
        found.sort(key=lambda d: -d.presence)
        kept: list[KeypointDetection] = []
        boxes = list(exclude)
        for det in found:
            box = box_from_keypoints(det.keypoints_px, self.spec)
            if _on_any(box, boxes):
                continue
            kept.append(det)
            boxes.append(box)
        return kept

    def _recut_misframed(
        self, frame: np.ndarray | FrameImage, refined: list[KeypointDetection]
    ) -> list[KeypointDetection]:
        """``refined`` with each sure reading whose keypoints ask for a crop off its own by more than
        ``acquire_recut`` read again in that crop (one batch), where the network is sure there too;
        ``refined`` itself while ``acquire_recut`` is None."""
        if self.config.acquire_recut is None:
            return refined
        limit = 1.0 + self.config.acquire_recut
        errors = [self._framing_error(d) for d in refined]
        redo = [k for k, off in enumerate(errors) if off is not None and not 1.0 / limit <= off[1] <= limit]
        if not redo:
            return refined
        out = list(refined)
        for k, det in zip(redo, self.refine_many(frame, [refined[k] for k in redo]), strict=True):
            if det.presence >= self.config.presence_threshold:
                out[k] = det
        return out

    def candidate_rois(
        self,
        frame: np.ndarray | FrameImage,
        exclude: Sequence[Box] = (),
        max_candidates: int | None = None,
        saliency: Saliency | None = None,
    ) -> list[tuple[int, int, int]]:
        """Square crops around the most salient blobs of the frame outside ``exclude``, best first
        (``saliency``: this frame's pass, if already run)."""
        if saliency is None:
            saliency = self.saliency(frame)
        return select_rois(saliency, self.config, self.crop.min_side, exclude, max_candidates)

    def saliency(self, frame: np.ndarray | FrameImage) -> Saliency:
        """This frame's saliency pass against the last searched frame; it becomes the next one's
        motion reference. Safe to run on another thread while the network runs on this one."""
        result = saliency_pass(frame, self.config, self._prev_small, self._earlier_small)
        if self.config.motion_frames == 3:  # only the three-frame map reads it: hold no copy otherwise
            self._earlier_small = self._prev_small
        self._prev_small = result.small
        return result


@dataclass(frozen=True)
class Saliency:
    """The salient blobs of one frame, before any region is left out or the budget counted.

    blobs : boxes (x, y, w, h) in the downscaled map's pixels, the maps' best-first lists taken in
        turn (``_take_in_turn``).
    scale : the map's size over the frame's.
    small : the downscaled frame (float32 BGR), the motion reference of the next pass.
    """

    blobs: tuple[Box, ...]
    scale: float
    small: np.ndarray


def saliency_pass(
    frame: np.ndarray | FrameImage,
    config: LocalizerConfig,
    previous_small: np.ndarray | None = None,
    earlier_small: np.ndarray | None = None,
) -> Saliency:
    """Local contrast on a ``config.work_width`` copy of the frame (a BGR array or a ``FrameImage``,
    whose YUV planes are downscaled before the colour conversion), plus the change since
    ``previous_small`` (that copy of an earlier frame) when ``config.use_motion``: their blobs.
    With ``config.motion_frames`` 3 the change is also taken against ``earlier_small`` (the frame
    before that one), and the smaller of the two kept: where a moving object is now.

    Pure (no state), so the pipeline may run it on another core while the track crops run.
    """
    h, w = frame.shape[:2]
    cfg = config
    scale = min(1.0, cfg.work_width / w)
    small = downscaled_bgr(frame, round(w * scale), round(h * scale)).astype(np.float32)
    background = cv2.GaussianBlur(small, (0, 0), cfg.background_sigma)
    maps = [(_max_abs_difference(small, background), False)]
    if cfg.use_motion and previous_small is not None and previous_small.shape == small.shape:
        # Two 8-bit images' difference: whole grey levels, whose median a histogram finds
        motion = _max_abs_difference(small, previous_small)
        if cfg.motion_frames == 3 and earlier_small is not None and earlier_small.shape == small.shape:
            motion = np.minimum(motion, _max_abs_difference(small, earlier_small))
        maps.append((motion, True))
    max_side = cfg.max_drone_px * scale
    per_map = [
        sorted(
            _blobs(m, cfg.min_contrast, max_side, cfg.peaks_per_region, levels, cfg.tight_blobs),
            key=lambda b: -b[0],
        )
        for m, levels in maps
    ]
    return Saliency(tuple(_take_in_turn(per_map)), scale, small)


def select_rois(
    saliency: Saliency,
    config: LocalizerConfig,
    min_side: float,
    exclude: Sequence[Box] = (),
    max_candidates: int | None = None,
) -> list[tuple[int, int, int]]:
    """Square crops (x0, y0, side) around a pass's blobs, best first: those on a box of ``exclude``
    (full-frame px; more than a third of the smaller box) skipped before the budget,
    ``max_candidates`` (default ``config.max_candidates``), is counted."""
    budget = config.max_candidates if max_candidates is None else int(max_candidates)
    if budget < 1:
        raise ValueError(f"max_candidates must be >= 1, got {max_candidates}")
    cfg, scale = config, saliency.scale
    rois, seen = [], []
    for bx, by, bw, bh in saliency.blobs:
        # Blob centre in edge coordinates of the small map -> full-frame pixel-centre coordinates.
        cx, cy = (bx + bw / 2) / scale - 0.5, (by + bh / 2) / scale - 0.5
        size = max(bw, bh) / scale
        side = max(cfg.candidate_scale * size, float(min_side))
        if exclude and _on_any((bx / scale, by / scale, bw / scale, bh / scale), exclude):
            continue  # a live track's drone: its own crop measures it
        if any(abs(cx - x) < s / 2 and abs(cy - y) < s / 2 and s / 2 < side < 2 * s for x, y, s in seen):
            continue  # the same object seen by both maps (a small blob inside a big one stays)
        rois.append(roi_around_box(cx, cy, side))
        seen.append((cx, cy, side))
        if len(rois) >= budget:
            break
    return rois


def propose_rois(
    frame: np.ndarray | FrameImage,
    config: LocalizerConfig,
    min_side: float,
    previous_small: np.ndarray | None = None,
    exclude: Sequence[Box] = (),
    max_candidates: int | None = None,
) -> tuple[list[tuple[int, int, int]], np.ndarray]:
    """Square crops (x0, y0, side) around the most salient blobs of a frame, best first, and this
    frame's downscaled copy for the next call: ``saliency_pass`` then ``select_rois``. The
    training sampler calls it on drone-free backgrounds to mine the hard negatives the daemon
    would propose."""
    saliency = saliency_pass(frame, config, previous_small)
    return select_rois(saliency, config, min_side, exclude, max_candidates), saliency.small


def _take_in_turn(ranked: list[list[tuple[float, Box]]]) -> list[Box]:
    """The boxes of several best-first blob lists, taken in turn (first of each, then second, ...).

    Each saliency map gets its share of the budget: ranked together by contrast x size, a building
    facade's windows outranked a far drone's small moving blob on every frame (the far preset's
    first camera: a candidate on the drone in 3 of 90 frames), while the motion map alone saw it.
    """
    out: list[Box] = []
    for rank in range(max((len(r) for r in ranked), default=0)):
        out.extend(r[rank][1] for r in ranked if rank < len(r))
    return out


def _on_any(box: Box, others: Sequence[Box]) -> bool:
    """Whether ``box`` overlaps any of ``others`` by more than a third of the smaller one."""
    return any(box_overlap(box, other) > 1 / 3 for other in others)


def box_overlap(a: Box, b: Box) -> float:
    """Intersection over the smaller box's area of two (x, y, w, h) boxes."""
    ix = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    smaller = max(min(a[2] * a[3], b[2] * b[3]), 1e-9)
    return ix * iy / smaller


def _max_abs_difference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.abs(a - b).max(axis=2)`` for (H, W, 3) float32 images, bit for bit, about 20x faster
    (numpy reduces a 3-long last axis slowly)."""
    d = cv2.absdiff(a, b)
    return np.maximum(np.maximum(d[..., 0], d[..., 1]), d[..., 2])


def _median(values: np.ndarray) -> float:
    """``float(np.median(values))`` of a finite float32 array, bit for bit, several times faster
    (one partition instead of np.median's three-point partition and NaN check)."""
    flat = values.ravel()
    k = flat.size // 2
    part = np.partition(flat, k)
    if flat.size % 2:
        return float(part[k])
    return float((part[:k].max() + part[k]) / np.float32(2))  # np.median: float32 mean of the two


def _median_of_levels(values: np.ndarray, step: float) -> float:
    """``_median(values)``, bit for bit, for float32 values that are whole multiples of ``step``
    (>= 0, fewer than 2 ** 16 steps): a histogram instead of a partition, which is slow on the
    many equal values of a motion map (3.0 against 0.3 ms for a 480 x 270 map here)."""
    flat = values.ravel()
    counts = np.cumsum(np.bincount((flat if step == 1.0 else flat * np.float32(1.0 / step)).astype(np.intp)))
    k = flat.size // 2
    upper = np.float32(np.searchsorted(counts, k + 1) * step)  # the value at sorted position k
    if flat.size % 2:
        return float(upper)
    lower = np.float32(np.searchsorted(counts, k) * step)  # at position k - 1
    return float((lower + upper) / np.float32(2))


def _blobs(
    saliency: np.ndarray,
    min_contrast: float,
    max_side: float | None = None,
    peaks: int = 3,
    levels: bool = False,
    tight: bool = False,
) -> list[tuple[float, Box]]:
    """Connected regions of high saliency as (score, box in the map's pixels).

    A region whose box is longer than ``max_side`` is replaced by its ``peaks`` strongest local
    maxima, each with the box of the pixels around it above half its value (``_peak_blobs``).
    ``levels``: the map holds whole grey levels (a difference of two 8-bit images), whose median
    and median deviation come from a histogram, the same to the bit. ``tight``: a region's box is
    that of its pixels above the threshold, not of the dilated mask that joined them (same score).
    """
    if levels:
        med = _median_of_levels(saliency, 1.0)
        mad = _median_of_levels(np.abs(saliency - np.float32(med)), 0.5) + 1e-3
    else:
        med = _median(saliency)
        mad = _median(np.abs(saliency - np.float32(med))) + 1e-3
    thr = max(min_contrast, med + 8.0 * 1.4826 * mad)
    salient = (saliency > thr).astype(np.uint8)
    mask = cv2.dilate(salient, np.ones((3, 3), np.uint8), iterations=2)
    # Label only the box around the salient pixels (usually a small part of the map): same regions.
    x0, y0, w0, h0 = cv2.boundingRect(mask)
    if w0 == 0 or h0 == 0:
        return []
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask[y0 : y0 + h0, x0 : x0 + w0], connectivity=8)
    out = []
    for i in range(1, n):
        x, y, bw, bh, area = stats[i]
        if area < 4:
            continue
        inside = labels[y : y + bh, x : x + bw] == i
        if max_side is not None and max(bw, bh) > max_side:
            out.extend(_peak_blobs(saliency, (x0 + x, y0 + y, bw, bh), inside, thr, max_side, peaks))
            continue
        window = (slice(y0 + y, y0 + y + bh), slice(x0 + x, x0 + x + bw))  # the region's box in the map
        score = float(saliency[window][inside].max()) * np.sqrt(float(area))
        if tight:
            ys, xs = np.nonzero(inside & salient[window].astype(bool))
            x, y, bw, bh = x + xs.min(), y + ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1
        out.append((score, (float(x0 + x), float(y0 + y), float(bw), float(bh))))
    return out


def _peak_blobs(
    saliency: np.ndarray,
    box: tuple[int, int, int, int],
    inside: np.ndarray,
    thr: float,
    max_side: float,
    n: int,
) -> list[tuple[float, Box]]:
    """The ``n`` strongest saliency peaks of an oversized region, each with its own small blob.

    A peak is a local maximum (7 x 7) of the lightly smoothed map above ``thr``; its blob is the
    connected set of pixels above half the peak's value within ``max_side`` of it. Scored like a
    region: peak value x sqrt(blob area).
    """
    x, y, bw, bh = box
    sub = cv2.GaussianBlur(saliency[y : y + bh, x : x + bw], (0, 0), 1.0)
    is_peak = (sub >= cv2.dilate(sub, np.ones((7, 7), np.uint8))) & inside & (sub > thr)
    py, px = np.nonzero(is_peak)
    order = np.argsort(-sub[py, px])[:n]
    out = []
    half = int(max_side // 2)
    for k in order:
        cy, cx = int(py[k]), int(px[k])
        wy0, wx0 = max(cy - half, 0), max(cx - half, 0)
        window = sub[wy0 : cy + half + 1, wx0 : cx + half + 1]
        _, labels = cv2.connectedComponents((window > 0.5 * sub[cy, cx]).astype(np.uint8), connectivity=8)
        ys, xs = np.nonzero(labels == labels[cy - wy0, cx - wx0])
        bx, by = float(x + wx0 + xs.min()), float(y + wy0 + ys.min())
        w, h = float(xs.max() - xs.min() + 1), float(ys.max() - ys.min() + 1)
        out.append((float(sub[cy, cx]) * np.sqrt(float(len(xs))), (bx, by, w, h)))
    return out
