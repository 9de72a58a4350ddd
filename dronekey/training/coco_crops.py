"""Training crops from a COCO keypoint dataset: the real 2DroneKey images, or any sequence of ours
written with ``dronekey-sim --images`` (our JSON is a COCO keypoint file).

The crops are cut exactly as the rendered ones (``sim_replay.sampler``) and as the daemon's
localiser cuts them: ``CropPolicy.roi`` around the drone's box, with the policy's jitter, resized
to the network input; drone-free crops come from image regions that touch no drone box. So a model
trained here and one trained on renders read the same kind of input.

Only what training needs is read from the JSON: each image's file and size, and per annotation the
four keypoints (x, y, v) and the box (the keypoints' box when ``bbox`` is missing). No camera and no
6DoF are needed, and the images may differ in size (``sequence_reader.load_sequence`` is the reader
for evaluation, where the camera matters).
"""

from __future__ import annotations

import json
import logging
import math
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from dronekey.geometry.crop import CropPolicy, crop_square, to_normalised
from dronekey.perception.keypoint_model import (  # a mirrored drone has its sides exchanged
    MIRROR,
    mirrored_back,
)
from dronekey.sim_replay.sampler import CropSample

__all__ = ["CocoCropSampler", "CocoDataError", "CocoImage", "find_coco_splits", "load_coco_images"]

log = logging.getLogger(__name__)

N_KEYPOINTS = 4
_TRAIN_WORDS = ("train",)
_VAL_WORDS = ("val", "valid", "validation")


class CocoDataError(ValueError):
    """A COCO keypoint dataset that cannot be used for training (the message names file and key)."""


@dataclass(frozen=True)
class CocoImage:
    """One image and its drones.

    path : the image file. width, height : pixels, from the JSON.
    keypoints : (D, 4, 2) float full-frame pixels of the D drones. visibility : (D, 4) COCO flags.
    boxes : (D, 4) x, y, w, h in pixels.
    """

    path: Path
    width: int
    height: int
    keypoints: np.ndarray
    visibility: np.ndarray
    boxes: np.ndarray


def find_coco_splits(path: str | Path) -> tuple[list[Path], list[Path]]:
    """The training and validation JSON files of ``path``.

    A JSON file is the training set alone (the caller then holds out images for validation). A
    folder is searched recursively: files whose name contains "train" train, those with "val",
    "valid" or "validation" validate (so ``annotations/train.json`` + ``annotations/val.json``,
    or ``person_keypoints_train2017.json`` style names, work); test splits are left alone.

    Raises
    ------
    CocoDataError
        No such path, or a folder without a training JSON.
    """
    path = Path(path)
    if path.is_file():
        return [path], []
    if not path.is_dir():
        raise CocoDataError(f"--coco: no such file or folder: {path}")
    files = sorted(path.rglob("*.json"))

    def named(words: tuple[str, ...]) -> list[Path]:
        return [f for f in files if any(w in part for part in _name_parts(f) for w in words)]

    train = named(_TRAIN_WORDS)
    val = [f for f in named(_VAL_WORDS) if f not in train]
    if not train:
        shown = ", ".join(str(f.relative_to(path)) for f in files[:5]) or "no JSON files"
        raise CocoDataError(f"--coco {path}: no JSON file with 'train' in its name ({shown})")
    return train, val


def _name_parts(f: Path) -> list[str]:
    return [p for p in f.stem.lower().replace("-", "_").split("_") if p] + [f.parent.name.lower()]


def _image_path(json_path: Path, file_name: str) -> Path:
    """Where an image named by a COCO file lies: beside the JSON, or in an images/ folder near it."""
    base = json_path.parent
    candidates = [base / file_name, base / "images" / file_name, base.parent / "images" / file_name]
    candidates += [base.parent / file_name, base / "images" / Path(file_name).name]
    for c in candidates:
        if c.is_file():
            return c
    return candidates[0]


def load_coco_images(json_paths: list[Path]) -> list[CocoImage]:
    """Images with their drones from COCO keypoint files (annotations with 4 labelled keypoints).

    Annotations with an unlabelled keypoint (v = 0: coordinates meaningless) or ``iscrowd`` are
    skipped and counted in the log; images without a usable annotation serve as drone-free images.

    Raises
    ------
    CocoDataError
        Unreadable JSON, missing keys, keypoints that are not 4 (x, y, v) triplets, or image files
        that cannot be found (the first missing one is named).
    """
    images: list[CocoImage] = []
    for json_path in json_paths:
        try:
            doc = json.loads(Path(json_path).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise CocoDataError(f"{json_path}: not a readable JSON file ({exc})") from None
        if not isinstance(doc, dict) or not isinstance(doc.get("images"), list):
            raise CocoDataError(f"{json_path}: not a COCO file (no 'images' list)")
        by_image: dict = {}
        skipped = 0
        for i, ann in enumerate(doc.get("annotations", [])):
            where = f"{json_path}: annotations[{i}]"
            kp = np.asarray(ann.get("keypoints", []), dtype=np.float64) if isinstance(ann, dict) else None
            if kp is None or kp.size != 3 * N_KEYPOINTS or "image_id" not in ann:
                raise CocoDataError(
                    f"{where}: needs 'image_id' and 'keypoints' with {N_KEYPOINTS} (x, y, v) triplets"
                )
            kp = kp.reshape(N_KEYPOINTS, 3)
            if ann.get("iscrowd", 0) or np.any(kp[:, 2] <= 0) or not np.all(np.isfinite(kp)):
                skipped += 1
                continue
            box = ann.get("bbox")
            if box is None or len(box) != 4 or min(box[2], box[3]) <= 0:
                lo, hi = kp[:, :2].min(axis=0), kp[:, :2].max(axis=0)
                box = [lo[0], lo[1], hi[0] - lo[0], hi[1] - lo[1]]
            by_image.setdefault(ann["image_id"], []).append((kp[:, :2], kp[:, 2].astype(np.int64), box))
        for j, img in enumerate(doc["images"]):
            if not isinstance(img, dict) or not {"id", "file_name", "width", "height"} <= img.keys():
                raise CocoDataError(f"{json_path}: images[{j}] needs id, file_name, width and height")
            drones = by_image.get(img["id"], [])
            images.append(
                CocoImage(
                    path=_image_path(Path(json_path), str(img["file_name"])),
                    width=int(img["width"]),
                    height=int(img["height"]),
                    keypoints=np.array([d[0] for d in drones], dtype=np.float64).reshape(-1, N_KEYPOINTS, 2),
                    visibility=np.array([d[1] for d in drones], dtype=np.int64).reshape(-1, N_KEYPOINTS),
                    boxes=np.array([d[2] for d in drones], dtype=np.float64).reshape(-1, 4),
                )
            )
        if skipped:
            log.info("%s: skipped %d annotations (crowd or unlabelled keypoints)", json_path, skipped)
    missing = [im.path for im in images if not im.path.is_file()]
    if missing:
        raise CocoDataError(
            f"{len(missing)} of {len(images)} images not found, e.g. {missing[0]} "
            "(looked beside the JSON and in an images/ folder next to it)"
        )
    if not any(len(im.boxes) for im in images):
        raise CocoDataError(f"{', '.join(map(str, json_paths))}: no annotation with 4 labelled keypoints")
    return images


class CocoCropSampler:
    """Draws ``CropSample`` objects from COCO images forever; reproducible for a given seed.

    Parameters
    ----------
    images : from ``load_coco_images``.
    crop : CropPolicy
        The model's crop policy (input size, scale, jitter).
    seed : int
    negative_fraction : float
        Share of drone-free crops (random squares that touch no drone box).
    mirror : bool
        Mirror half of the crops left/right, exchanging the keypoints' sides (``MIRROR``).
    cache_size : int
        Decoded images kept in memory; each sample reads from a random cached image and a new one
        is decoded every ``refresh_every`` samples (a 1080p JPEG costs about 10 ms to decode).
    """

    def __init__(
        self,
        images: list[CocoImage],
        crop: CropPolicy,
        seed: int = 0,
        negative_fraction: float = 0.1,
        mirror: bool = True,
        cache_size: int = 16,
        refresh_every: int = 2,
    ) -> None:
        if not 0 <= negative_fraction < 1:
            raise ValueError(f"negative_fraction must be in [0, 1), got {negative_fraction}")
        self.images, self.crop = images, crop
        self.rng = np.random.default_rng(seed)
        self.negative_fraction, self.mirror = negative_fraction, mirror
        self._with_drone = [i for i, im in enumerate(images) if len(im.boxes)]
        sides = [crop.scale * max(b[2], b[3]) for im in images for b in im.boxes]
        lo, hi = np.percentile(sides, [5, 95])
        self._side_range = (max(float(crop.min_side), float(lo)), float(hi))
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._cache_size, self._refresh_every, self._count = max(1, cache_size), max(1, refresh_every), 0

    def sample(self) -> CropSample:
        """One sample (a drone with probability 1 - negative_fraction)."""
        self._count += 1
        if (self._count - 1) % self._refresh_every == 0 or len(self._cache) < self._cache_size:
            self._load(int(self.rng.integers(len(self.images))))
        if self.rng.random() < self.negative_fraction:
            out = self._negative()
            if out is not None:
                return out
        return self._positive()

    def _load(self, index: int) -> np.ndarray:
        if index in self._cache:
            self._cache.move_to_end(index)
            return self._cache[index]
        image = self.images[index]
        bgr = cv2.imread(str(image.path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise CocoDataError(f"OpenCV cannot read the image {image.path}")
        self._cache[index] = bgr
        while len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        return bgr

    def _cached(self, with_drone: bool) -> tuple[int, np.ndarray]:
        keys = [k for k in self._cache if len(self.images[k].boxes) or not with_drone]
        if not keys:  # no drone among the cached images: decode one that has one
            k = int(self.rng.choice(self._with_drone))
            return k, self._load(k)
        k = keys[int(self.rng.integers(len(keys)))]
        return k, self._cache[k]

    def _positive(self) -> CropSample:
        k, bgr = self._cached(with_drone=True)
        image = self.images[k]
        d = int(self.rng.integers(len(image.boxes)))
        roi = self.crop.roi(image.boxes[d], self.rng)
        S = self.crop.input_size
        crop = crop_square(bgr, roi, S)
        kp = to_normalised(image.keypoints[d], roi).astype(np.float32)
        vis = image.visibility[d].copy()
        area = float(image.boxes[d][2] * image.boxes[d][3]) / roi[2] ** 2
        if self.mirror and self.rng.random() < 0.5:
            crop = np.ascontiguousarray(crop[:, ::-1])
            kp = mirrored_back(kp[None])[0]  # a mirror's own keypoints, mapped as the runtime maps them
            vis = vis[MIRROR]
        return CropSample(self._photometric(crop), kp, vis, True, area)

    def _negative(self) -> CropSample | None:
        k, bgr = self._cached(with_drone=False)
        roi = self._negative_roi(k, bgr.shape[:2])
        if roi is None:
            return None
        crop = crop_square(bgr, roi, self.crop.input_size)
        empty = np.zeros((4, 2), np.float32)
        return CropSample(self._photometric(crop), empty, np.zeros(4, np.int64), False, 0.0)

    def _negative_roi(self, index: int, shape: tuple[int, int]) -> tuple[int, int, int] | None:
        """A random square inside image ``index`` of a drone crop's size that touches no drone box."""
        h, w = shape
        lo, hi = self._side_range
        boxes = self.images[index].boxes
        for _ in range(10):
            side = min(int(math.exp(self.rng.uniform(math.log(lo), math.log(max(hi, lo + 1))))), w, h)
            x0, y0 = int(self.rng.integers(0, w - side + 1)), int(self.rng.integers(0, h - side + 1))
            touches = (
                (boxes[:, 0] < x0 + side)
                & (boxes[:, 0] + boxes[:, 2] > x0)
                & (boxes[:, 1] < y0 + side)
                & (boxes[:, 1] + boxes[:, 3] > y0)
            )
            if not touches.any():
                return x0, y0, side
        return None

    def _photometric(self, crop: np.ndarray) -> np.ndarray:
        """Brightness and contrast jitter (+-20 %), as the renderer's lighting varies."""
        gain, bias = self.rng.uniform(0.8, 1.2), self.rng.uniform(-20, 20)
        return cv2.convertScaleAbs(crop, alpha=gain, beta=bias)
