"""ONNX Runtime inference of the exported DroneKey network (the daemon's KeypointModel, docs/design.md §3).

rtmlib style: one class, ``KeypointModel``, with separate ``preprocess`` (BGR uint8 crops ->
normalised RGB tensor), ``inference`` (ONNX Runtime) and ``postprocess`` (normalised crop units ->
full-frame pixels), and ``detect`` / ``__call__`` chaining them for a frame and its crops.

Front and back. A model with a front/back head (``DroneKeyConfig.heading_head``) has a fourth
output, ``heading``: the probability that its keypoints are in the spec's order rather than the
180-degree twin (``HEADING_TWIN``). ``postprocess`` applies that decision (a probability below 0.5
swaps the keypoints to the twin order) and hands the pipeline the probability of the order it
returns (``KeypointDetection.heading_p`` in [0.5, 1]), so that the tracker can weigh it. A model
without the output gives NaN: the order is the network's, its doubt unknown.
With a ``HeadingModel`` (the shipped front/back classifier, which reads the nose from a patch turned
front-up around the keypoints) its probability replaces the head's before that decision. With a
``DroneVerifier`` (the second look at whether the patch is a drone at all) each detection also
carries its probability (``KeypointDetection.drone_p``); the same patch feeds both.

The input size and normalisation are read from the model's metadata (written by
``dronekey.training.export``), so a model carries its own contract. torch is never imported here: the
daemon runs without it. ``preprocess_crops`` is also what training uses, so training and serving
see the same pixels.
"""

from __future__ import annotations

import functools
import json
import logging
import os
import time
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import onnxruntime as ort
import psutil

from dronekey.frame_image import FrameImage
from dronekey.geometry.crop import ROI, crop_square, from_normalised
from dronekey.perception.drone_verifier import DroneVerifier
from dronekey.perception.heading_model import HeadingModel
from dronekey.perception.keypoint_order import HEADING_TWIN
from dronekey.perception.onnx_session import session_options
from dronekey.perception.patch_classifier import canonical_patches, patches_to_tensor
from dronekey.perception.spread_calibration import SpreadCalibration
from dronekey.types import KeypointDetection

__all__ = [
    "HEADING_OUTPUT",
    "HEADING_TWIN",
    "IMAGENET_MEAN",
    "IMAGENET_STD",
    "INPUT_NAME",
    "OUTPUT_NAMES",
    "KeypointModel",
    "KeypointReading",
    "ModelFormatError",
    "RawOutputs",
    "default_model_path",
    "physical_cores",
    "preprocess_crops",
]

LOG = logging.getLogger(__name__)

# The ONNX contract written by dronekey.training.export.
INPUT_NAME = "image"
OUTPUT_NAMES = ("keypoints", "presence", "gate")
HEADING_OUTPUT = "heading"  # optional fourth output: sigmoid of the front/back head
# ImageNet statistics on RGB in [0, 1], as the paper's reference preprocessing.
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
SHIPPED_MODEL = "dronekey_edge.onnx"
# The patch classifiers (front/back, verifier) run only on crops at least this likely to hold a drone
# (the localiser's presence threshold, 0.5 by default, is above it), which keeps them off most of
# the search's crops.
HEADING_MIN_PRESENCE = 0.3


class ModelFormatError(ValueError):
    """The ONNX file is not a DroneKey export (missing metadata, wrong inputs); the message says what."""


class RawOutputs(NamedTuple):
    """The network's outputs for a batch of B crops.

    keypoints : (B, K, 2) float32, normalised crop units (0 = left/top edge, 1 = right/bottom edge).
    presence : (B,) float32, probability that the crop holds a drone.
    gate : (B, N) float32, per-layer gate weights.
    heading : (B,) float32, probability that ``keypoints`` are in the spec's order and not the
        180-degree twin, or None for a model without a front/back head.
    """

    keypoints: np.ndarray
    presence: np.ndarray
    gate: np.ndarray
    heading: np.ndarray | None = None


def default_model_path() -> Path:
    """Where the shipped edge model lives: ``dronekey/models/dronekey_edge.onnx`` (package data)."""
    return Path(str(resources.files("dronekey") / "models" / SHIPPED_MODEL))


def physical_cores() -> int:
    """Physical CPU cores (ORT's best intra-op thread count); logical cores if psutil cannot tell."""
    return psutil.cpu_count(logical=False) or os.cpu_count() or 1


def preprocess_crops(
    crops_bgr: np.ndarray,
    input_size: int,
    mean: Sequence[float] = IMAGENET_MEAN,
    std: Sequence[float] = IMAGENET_STD,
) -> np.ndarray:
    """BGR uint8 crops (S, S, 3) or (B, S, S, 3) -> normalised RGB float32 tensor (B, 3, S, S).

    x = (rgb / 255 - mean) / std, the normalisation of the paper's reference code (ImageNet).
    """
    crops = np.asarray(crops_bgr)
    if crops.dtype != np.uint8:
        raise ValueError(f"crops_bgr must be uint8, got dtype {crops.dtype}")
    if crops.ndim == 3:
        crops = crops[None]
    if crops.ndim != 4 or crops.shape[1:] != (input_size, input_size, 3):
        raise ValueError(
            f"crops_bgr must have shape (S, S, 3) or (B, S, S, 3) with S = {input_size}, "
            f"got {np.asarray(crops_bgr).shape}"
        )
    b, s = crops.shape[0], input_size
    planes = np.ascontiguousarray(crops.transpose(0, 3, 1, 2))  # (B, 3, S, S) uint8, BGR
    tables = _normalisation_tables(tuple(float(m) for m in mean), tuple(float(v) for v in std))
    tensor = np.empty((b, 3, s, s), dtype=np.float32)
    for c in range(3):  # RGB channel c is BGR plane 2 - c
        tensor[:, c] = cv2.LUT(planes[:, 2 - c].reshape(b * s, s), tables[c]).reshape(b, s, s)
    return tensor


@functools.lru_cache(maxsize=8)
def _normalisation_tables(mean: tuple[float, ...], std: tuple[float, ...]) -> tuple[np.ndarray, ...]:
    """``preprocess_crops``' normalisation of each grey level, one (1, 256) float32 table per RGB
    channel: the same float32 operations on the same values as normalising every pixel, so the
    tensor is the same to the bit, at a tenth of the CPU (a look-up per pixel instead of a
    conversion, a multiply and a subtraction over the batch, then a transpose of floats)."""
    scale = np.float32(1.0 / 255.0) / np.asarray(std, dtype=np.float32)
    offset = np.asarray(mean, dtype=np.float32) / np.asarray(std, dtype=np.float32)
    levels = np.arange(256, dtype=np.float32)[:, None] * scale - offset  # (256, 3) RGB
    return tuple(np.ascontiguousarray(levels[:, c].reshape(1, 256)) for c in range(3))


def _metadata_json(metadata: dict[str, str], key: str, path: Path):
    if key not in metadata:
        raise ModelFormatError(
            f"{path}: metadata key {key!r} missing; export the model with dronekey-export "
            f"(present keys: {sorted(metadata)})"
        )
    try:
        return json.loads(metadata[key])
    except json.JSONDecodeError as exc:
        raise ModelFormatError(f"{path}: metadata {key!r} is not JSON ({exc})") from None


# Keypoint order of a left/right mirrored drone (1 FR <-> 4 FL, 2 RR <-> 3 RL).
MIRROR = [3, 2, 1, 0]


def mirrored_back(keypoints: np.ndarray) -> np.ndarray:
    """Keypoints (B, 4, 2) predicted on mirrored crops, in normalised units, mapped to the crops."""
    out = keypoints[:, MIRROR].copy()
    out[..., 0] = 1.0 - out[..., 0]
    return out


class KeypointReading(NamedTuple):
    """The keypoint network's outputs on a batch of crops, before the patch classifiers.

    crops : (B, S, S, 3) uint8 BGR, the network's input.
    raw : the network's outputs (mirror-averaged when the model averages), or None when B = 0.
    rois : the crops' (x0, y0, side), full-frame pixels.
    """

    crops: np.ndarray
    raw: RawOutputs | None
    rois: list[ROI]

    @property
    def presence(self) -> np.ndarray:
        """(B,) float32, the network's presence per crop."""
        return self.raw.presence if self.raw is not None else np.zeros(0, np.float32)

    def joined(self, other: KeypointReading) -> KeypointReading:
        """This reading's crops followed by ``other``'s (two batches read as one)."""
        if not other.rois:
            return self
        if not self.rois:
            return other
        raw = RawOutputs(
            *(None if a is None else np.concatenate([a, b]) for a, b in zip(self.raw, other.raw, strict=True))
        )
        return KeypointReading(np.concatenate([self.crops, other.crops]), raw, self.rois + other.rois)

    def subset(self, select: Sequence[int]) -> KeypointReading:
        """The reading of crops ``select`` only, in that order."""
        idx = np.asarray(select, dtype=np.intp)
        raw = RawOutputs(*(None if a is None else a[idx] for a in self.raw)) if len(idx) else None
        return KeypointReading(self.crops[idx], raw, [self.rois[i] for i in idx])


def mirror_averaged(raw: RawOutputs, n: int) -> RawOutputs:
    """Average the outputs of ``n`` crops (first half of ``raw``) and their mirrors (second half).

    With a front/back head the two answers may come out in twin orders (the network may give any
    order when it also says which one it gave): the mirrored answer is first put in whichever of
    its order and its twin is closer to the direct one, its heading probability flipped with it.
    """
    direct, mirrored = raw.keypoints[:n], mirrored_back(raw.keypoints[n:])
    heading = None
    if raw.heading is not None:
        twin = mirrored[:, HEADING_TWIN]
        use_twin = np.abs(twin - direct).mean(axis=(1, 2)) < np.abs(mirrored - direct).mean(axis=(1, 2))
        mirrored = np.where(use_twin[:, None, None], twin, mirrored)
        h_mirror = np.where(use_twin, 1.0 - raw.heading[n:], raw.heading[n:])
        heading = (0.5 * (raw.heading[:n] + h_mirror)).astype(np.float32)
    kp = 0.5 * (direct + mirrored)
    presence = 0.5 * (raw.presence[:n] + raw.presence[n:])
    return RawOutputs(kp.astype(np.float32), presence, raw.gate[:n], heading)


def in_heading_order(raw: RawOutputs) -> RawOutputs:
    """Apply the front/back head's decision: crops it scores below 0.5 get the twin order, and
    ``heading`` becomes the probability of the order returned (>= 0.5). Unchanged without a head."""
    if raw.heading is None:
        return raw
    flip = raw.heading < 0.5
    kp = np.where(flip[:, None, None], raw.keypoints[:, HEADING_TWIN], raw.keypoints)
    heading = np.where(flip, 1.0 - raw.heading, raw.heading).astype(np.float32)
    return RawOutputs(kp.astype(np.float32), raw.presence, raw.gate, heading)


class KeypointModel:
    """The DroneKey keypoint network in ONNX Runtime.

    Parameters
    ----------
    path : str or Path, optional
        ONNX file written by ``dronekey-export``; default ``default_model_path()`` (the shipped
        edge model).
    providers : sequence of str, optional
        ONNX Runtime execution providers in priority order; default ``["CPUExecutionProvider"]``.
        A provider this onnxruntime build lacks, or one that fails to load, is an error (no silent
        fallback to the CPU).
    threads : int, optional
        Intra-op threads; default the number of physical cores.
    mirror_average : bool
        ``detect`` also runs every crop mirrored left/right (in the same batch) and averages the
        two answers, the mirrored one with its keypoints' sides exchanged back (1 <-> 4, 2 <-> 3).
        On 1,500 validation crops this cut the median keypoint error by a fifth (4.94 -> 3.90 px
        of 128) for about 1.6x the inference time (docs/model.md).
    spread_calibration : SpreadCalibration, optional
        How the keypoints' spread is de-compressed (``dronekey.perception.spread_calibration``);
        default: the one in the model's metadata, none if it has none. ``SpreadCalibration()``
        turns it off.
    heading_model : HeadingModel, optional
        The front/back classifier (``dronekey.perception.heading_model``): when given, its
        probability decides each crop's keypoint order in place of the network's own head.
    verifier : DroneVerifier, optional
        The drone verifier (``dronekey.perception.drone_verifier``): when given, each detection
        carries its probability that the crop is a drone (``drone_p``; NaN without one).

    Attributes
    ----------
    input_size : int
        Side of the square network input, pixels.
    keypoint_names : list of str
    metadata : dict
        The model's metadata, JSON values decoded.
    providers : list of str
        Execution providers in use.
    inference_cpu_s : float
        CPU seconds the calling threads have spent in this network's ``session.run`` (``network_cpu_s``
        adds the patch classifiers').
    """

    def __init__(
        self,
        path: str | Path | None = None,
        providers: Sequence[str] | None = None,
        threads: int | None = None,
        mirror_average: bool = False,
        spread_calibration: SpreadCalibration | None = None,
        heading_model: HeadingModel | None = None,
        verifier: DroneVerifier | None = None,
    ) -> None:
        self.mirror_average = bool(mirror_average)
        self.inference_cpu_s = 0.0  # the calling threads' CPU seconds in this network's session.run
        self.heading_model = heading_model
        self.verifier = verifier
        sizes = {c.patch_size for c in (heading_model, verifier) if c is not None}
        if len(sizes) > 1:
            raise ValueError(
                f"heading_model and verifier read patches of different sizes ({sorted(sizes)} px): "
                "train them with the same patch size"
            )
        self._patch_size = sizes.pop() if sizes else 0
        self.path = Path(path) if path is not None else default_model_path()
        if not self.path.is_file():
            hint = (
                "the shipped model is not built yet: train with `dronekey-train`, then "
                f"`dronekey-export --checkpoint CKPT --out {self.path}`"
                if path is None
                else "pass the path of an ONNX file written by dronekey-export"
            )
            raise FileNotFoundError(f"keypoint model not found: {self.path} ({hint})")
        requested = list(providers) if providers is not None else ["CPUExecutionProvider"]
        available = ort.get_available_providers()
        missing = [p for p in requested if p not in available]
        if not requested or missing:
            raise ValueError(
                f"providers={requested!r}: {missing or 'empty list'} not available in this onnxruntime "
                f"(available: {available})"
            )
        threads = physical_cores() if threads is None else int(threads)
        if threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        self.threads = threads
        try:
            options = session_options(threads)
            self.session = ort.InferenceSession(str(self.path), options, providers=requested)
        except Exception as exc:  # onnxruntime raises its own Fail / InvalidProtobuf / InvalidGraph types
            if type(exc).__module__.startswith("onnxruntime"):
                raise ModelFormatError(f"{self.path} is not a loadable ONNX model ({exc})") from None
            raise
        self.providers = self.session.get_providers()
        failed = [p for p in requested if p not in self.providers]
        if failed:
            raise RuntimeError(
                f"{self.path}: execution providers {failed} failed to load (in use: {self.providers})"
            )
        self._check_io()
        self.has_heading = HEADING_OUTPUT in [o.name for o in self.session.get_outputs()]
        self._outputs = list(OUTPUT_NAMES) + ([HEADING_OUTPUT] if self.has_heading else [])
        self.metadata = self._read_metadata()
        size = self.metadata["input_size"]
        if not (isinstance(size, list) and len(size) == 2 and size[0] == size[1] and int(size[0]) > 0):
            raise ModelFormatError(f"{self.path}: input_size metadata must be [S, S], got {size!r}")
        self.input_size = int(size[0])
        norm = self.metadata["normalisation"]
        if norm.get("color") != "RGB" or len(norm.get("mean", ())) != 3 or len(norm.get("std", ())) != 3:
            raise ModelFormatError(
                f"{self.path}: normalisation metadata must give RGB mean and std, got {norm!r}"
            )
        self.mean = tuple(float(v) for v in norm["mean"])
        self.std = tuple(float(v) for v in norm["std"])
        self.keypoint_names = list(self.metadata["keypoint_names"])
        if spread_calibration is None:
            try:
                spread_calibration = SpreadCalibration.from_metadata(self.metadata)
            except ValueError as exc:
                raise ModelFormatError(f"{self.path}: {exc}") from None
        self.spread_calibration = spread_calibration
        LOG.info(
            "keypoint model %s (%s, %d px input) on execution providers %s, %d threads",
            self.path.name,
            self.metadata.get("precision", "fp32"),
            self.input_size,
            ", ".join(self.providers),
            threads,
        )

    def _check_io(self) -> None:
        inputs = [i.name for i in self.session.get_inputs()]
        outputs = [o.name for o in self.session.get_outputs()]
        if inputs != [INPUT_NAME] or not set(OUTPUT_NAMES) <= set(outputs):
            raise ModelFormatError(
                f"{self.path}: expected input {INPUT_NAME!r} and outputs {list(OUTPUT_NAMES)}, "
                f"got inputs {inputs} and outputs {outputs}"
            )

    def _read_metadata(self) -> dict:
        raw = dict(self.session.get_modelmeta().custom_metadata_map)
        metadata = {}
        for key in ("input_size", "normalisation", "keypoint_names"):
            metadata[key] = _metadata_json(raw, key, self.path)
        for key, value in raw.items():
            if key not in metadata:
                try:
                    metadata[key] = json.loads(value)
                except json.JSONDecodeError:
                    metadata[key] = value
        return metadata

    def preprocess(self, crops_bgr: np.ndarray) -> np.ndarray:
        """BGR uint8 crop(s) of ``input_size`` -> the network input (B, 3, S, S) float32."""
        return preprocess_crops(crops_bgr, self.input_size, self.mean, self.std)

    def inference(self, tensor: np.ndarray) -> RawOutputs:
        """Run the network on a preprocessed batch (B, 3, S, S) float32."""
        tensor = np.asarray(tensor)
        s = self.input_size
        if tensor.dtype != np.float32 or tensor.ndim != 4 or tensor.shape[1:] != (3, s, s):
            raise ValueError(f"tensor must be float32 (B, 3, {s}, {s}), got {tensor.dtype} {tensor.shape}")
        started = time.thread_time()
        outputs = self.session.run(self._outputs, {INPUT_NAME: tensor})
        self.inference_cpu_s += time.thread_time() - started
        return RawOutputs(*outputs) if self.has_heading else RawOutputs(*outputs, None)

    @property
    def network_cpu_s(self) -> float:
        """CPU seconds the calling threads have spent in ONNX Runtime, this network's and its
        patch classifiers', since the model was loaded. ONNX Runtime computes on the calling thread
        at one intra-op thread (the default for one camera); with more, its pool threads' share is
        not in it. ``dronekey-bench pipeline`` reads it as the networks' floor of a frame's cost."""
        classifiers = (c for c in (self.heading_model, self.verifier) if c is not None)
        return self.inference_cpu_s + sum(c.inference_cpu_s for c in classifiers)

    def postprocess(
        self, raw: RawOutputs, rois: Sequence[ROI], drone_p: np.ndarray | None = None
    ) -> list[KeypointDetection]:
        """Map each crop's keypoints back to full-frame pixels through its ``roi`` (x0, y0, side), in
        the front/back head's order (``in_heading_order``), their spread calibrated
        (``spread_calibration``); ``drone_p`` (B,) is the verifier's probability per crop (NaN
        without a verifier)."""
        if len(rois) != raw.keypoints.shape[0]:
            raise ValueError(f"rois must hold one roi per crop ({raw.keypoints.shape[0]}), got {len(rois)}")
        raw = in_heading_order(raw)
        keypoints, scales = self.spread_calibration.apply(raw.keypoints)
        heading = raw.heading if raw.heading is not None else np.full(len(rois), np.nan)
        drone_p = drone_p if drone_p is not None else np.full(len(rois), np.nan)
        detections = []
        for kp_n, presence, p, scale, roi, verified in zip(
            keypoints, raw.presence, heading, scales, rois, drone_p, strict=True
        ):
            roi = tuple(int(v) for v in roi)
            kp = from_normalised(kp_n, roi)
            detections.append(
                KeypointDetection(kp, float(presence), roi, float(p), float(scale), float(verified))
            )
        return detections

    def detect(
        self, frame: np.ndarray | FrameImage, rois: Sequence[ROI], verify: Sequence[bool] | None = None
    ) -> list[KeypointDetection]:
        """Crop ``rois`` out of a frame (a BGR array, or a ``FrameImage`` of which only the crops
        are converted to colour), run the network and the patch classifiers, return one detection
        per roi: ``finish(read(frame, rois), verify=verify)``."""
        return self.finish(self.read(frame, rois), verify=verify)

    __call__ = detect

    def read(self, frame: np.ndarray | FrameImage, rois: Sequence[ROI]) -> KeypointReading:
        """The keypoint network alone on the crops of ``rois`` (mirror-averaged when set): a
        reading to ``finish``, or to look at first (``rough``) when some crops may be cut again."""
        rois = [tuple(int(v) for v in roi) for roi in rois]
        if not rois:
            s = self.input_size
            return KeypointReading(np.zeros((0, s, s, 3), np.uint8), None, [])
        crops = np.stack([crop_square(frame, roi, self.input_size) for roi in rois])
        if not self.mirror_average:
            raw = self.inference(self.preprocess(crops))
        else:
            n, s = len(rois), self.input_size
            tensor = np.empty((2 * n, 3, s, s), dtype=np.float32)
            tensor[:n] = self.preprocess(crops)
            tensor[n:] = tensor[:n, ..., ::-1]  # the mirrors, flipped after normalising: half the work
            raw = mirror_averaged(self.inference(tensor), n)
        return KeypointReading(crops, raw, rois)

    def rough(self, reading: KeypointReading) -> list[KeypointDetection]:
        """A reading's detections before the patch classifiers: the keypoints in the network's own
        order, no ``drone_p``. Enough to decide where to cut again (boxes do not depend on the
        order); ``finish`` gives the detections to use."""
        return self.postprocess(reading.raw, reading.rois) if reading.rois else []

    def finish(
        self,
        reading: KeypointReading,
        select: Sequence[int] | None = None,
        verify: Sequence[bool] | None = None,
    ) -> list[KeypointDetection]:
        """The detections of a reading (of its crops ``select`` only, in that order, when given):
        the patch classifiers on the crops that hold a drone, then ``postprocess``. Crops cut again
        need not pay for the classifiers on their first cut. ``verify`` (one flag per crop of the
        reading, all by default): the crops the drone verifier looks at; the others get ``drone_p``
        NaN (a confirmed track's crop: the verdict is confirmation evidence only)."""
        if select is not None:
            if verify is not None:
                verify = [verify[k] for k in select]
            reading = reading.subset(select)
        if not reading.rois:
            return []
        raw, drone_p = reading.raw, None
        if self.heading_model is not None or self.verifier is not None:
            raw, drone_p = self._read_patches(reading.crops, raw, verify)
        return self.postprocess(raw, reading.rois, drone_p)

    def _read_patches(
        self, crops: np.ndarray, raw: RawOutputs, verify: Sequence[bool] | None = None
    ) -> tuple[RawOutputs, np.ndarray | None]:
        """The patch classifiers on the crops the network finds a drone in (presence at least
        ``HEADING_MIN_PRESENCE``; the others, which no later stage keeps, get heading 0.5 and
        ``drone_p`` 0 without running them): the front/back classifier's probability replaces the
        network's head (``raw.heading``), the verifier's is returned (None without a verifier; NaN
        for the crops ``verify`` leaves out). The front-up patch is built once for both."""
        keep = np.flatnonzero(raw.presence >= HEADING_MIN_PRESENCE)
        tensor = ratios = None
        if len(keep):
            patches, ratios = canonical_patches(crops[keep], raw.keypoints[keep], self._patch_size)
            tensor = patches_to_tensor(patches)
        if self.heading_model is not None:  # the front/back classifier decides the order, not the head
            heading = np.full(len(crops), 0.5, dtype=np.float32)
            if tensor is not None:
                heading[keep] = self.heading_model.postprocess(self.heading_model.inference(tensor), ratios)
            raw = raw._replace(heading=heading)
        drone_p = None
        if self.verifier is not None:
            drone_p = np.zeros(len(crops), dtype=np.float32)
            asked = np.ones(len(crops), bool) if verify is None else np.asarray(verify, bool)
            drone_p[~asked] = np.nan
            run = asked[keep]  # empty when no crop holds a drone (and ``tensor`` is None)
            if run.any():
                p = self.verifier.postprocess(self.verifier.inference(tensor[run]), ratios[run])
                drone_p[keep[run]] = p
        return raw, drone_p
