"""Front or back: a small classifier that reads the drone's nose from a patch turned front-up.

Four propeller hubs fit a pose and its 180-degree twin equally well (``HEADING_TWIN``), and the
keypoint network's own front/back head answers 0.5 on every crop (docs/model.md). This model is
the second stage that decides it from the body, rtmlib style:

- ``canonical_patches`` (preprocess): each crop is warped by a similarity transform so that its
  keypoints' centre is the patch centre, their front axis (rear hubs' midpoint -> front hubs'
  midpoint, in the order the keypoints come in) points up, and the farthest hub lies
  ``HUB_RADIUS`` of the patch side from the centre. Rotation and scale are taken out, so the
  classifier only has to tell "nose at the top" from "nose at the bottom".
- ``HeadingModel.inference``: the ONNX classifier, whose graph is antisymmetric by construction
  (``logit(x) = (f(x) - f(x turned 180 deg)) / 2``), so the twin order always gets exactly
  ``1 - p``.
- ``HeadingModel.postprocess``: ``p``, the probability that the keypoints' order is the spec's
  (the front hubs are 1 and 4), 0.5 where the front axis is too short to point anywhere (a drone
  seen nose-on or from the side: ``min_axis_ratio``).

``KeypointModel`` calls it on every crop after the keypoint network and hands ``p`` to
``in_heading_order`` in place of the network's head; the tracker weighs it over frames.
"""

from __future__ import annotations

import json
import logging
import math
from importlib import resources
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

from dronekey.perception.onnx_session import session_options

__all__ = [
    "HUB_RADIUS",
    "PATCH_SIZE",
    "HeadingModel",
    "canonical_patch",
    "canonical_patches",
    "default_heading_model_path",
    "load_heading_model",
    "patches_to_tensor",
]

LOG = logging.getLogger(__name__)

PATCH_SIZE = 64  # px, side of the classifier's square input
HUB_RADIUS = 0.34  # the farthest hub's distance from the patch centre, in patch sides
SHIPPED_HEADING_MODEL = "dronekey_heading.onnx"
INPUT_NAME = "patch"
OUTPUT_NAME = "logit"
# Normalisation of the BGR patch (grey statistics: the classifier is trained with its colour
# channels permuted, so no channel is special).
PATCH_MEAN = 0.45
PATCH_STD = 0.25


def default_heading_model_path() -> Path:
    """The shipped front/back classifier, inside the installed package."""
    return Path(str(resources.files("dronekey.models").joinpath(SHIPPED_HEADING_MODEL)))


def canonical_patch(
    crop_bgr: np.ndarray, keypoints_px: np.ndarray, size: int = PATCH_SIZE
) -> tuple[np.ndarray, float]:
    """Warp one crop front-up around its keypoints.

    Parameters
    ----------
    crop_bgr : (S, S, 3) uint8
        The crop the keypoint network saw.
    keypoints_px : (4, 2)
        Its keypoints in the crop's pixels, in the spec's order (1 FR, 2 RR, 3 RL, 4 FL): normalised
        crop units times the side. The warp maps their centre to (size / 2, size / 2) in
        ``cv2.warpAffine``'s coordinates: the convention the shipped classifier was trained with.
    size : int
        Side of the patch, px.

    Returns
    -------
    patch : (size, size, 3) uint8
    axis_ratio : float
        Length of the front axis over the farthest hub's distance from the centre (about 1 seen
        from above, 0 nose-on).
    """
    P = np.asarray(keypoints_px, dtype=np.float64)
    centre = P.mean(axis=0)
    axis = (P[0] + P[3]) / 2 - (P[1] + P[2]) / 2
    radius = max(float(np.linalg.norm(P - centre, axis=1).max()), 1.0)
    turn = -math.pi / 2 - math.atan2(axis[1], axis[0])  # the front axis onto image "up" (-y)
    k = HUB_RADIUS * size / radius
    c, s = k * math.cos(turn), k * math.sin(turn)
    M = np.array([[c, -s, 0.0], [s, c, 0.0]])
    M[:, 2] = np.array([size / 2, size / 2]) - M[:, :2] @ centre
    patch = cv2.warpAffine(crop_bgr, M, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return patch, float(np.linalg.norm(axis) / radius)


def canonical_patches(
    crops_bgr: np.ndarray, keypoints_norm: np.ndarray, size: int = PATCH_SIZE
) -> tuple[np.ndarray, np.ndarray]:
    """``canonical_patch`` for a batch: crops (B, S, S, 3) uint8 and keypoints (B, 4, 2) in
    normalised crop units -> patches (B, size, size, 3) uint8 and axis ratios (B,)."""
    crops_bgr = np.asarray(crops_bgr)
    S = crops_bgr.shape[1]
    out = np.empty((len(crops_bgr), size, size, 3), dtype=np.uint8)
    ratios = np.empty(len(crops_bgr), dtype=np.float32)
    for i, (crop, kp) in enumerate(zip(crops_bgr, np.asarray(keypoints_norm), strict=True)):
        out[i], ratios[i] = canonical_patch(crop, kp * S, size)
    return out, ratios


def patches_to_tensor(patches_bgr: np.ndarray) -> np.ndarray:
    """uint8 (B, H, W, 3) BGR patches -> the classifier's float32 (B, 3, H, W) input."""
    x = np.asarray(patches_bgr, dtype=np.float32).transpose(0, 3, 1, 2) / 255.0
    return np.ascontiguousarray((x - PATCH_MEAN) / PATCH_STD, dtype=np.float32)


class HeadingModel:
    """The front/back classifier in ONNX Runtime.

    Parameters
    ----------
    path : str or Path, optional
        ONNX file written by ``dronekey-train-heading``; default the shipped one.
    threads : int
        Intra-op threads (the classifier is small: one is enough).
    min_axis_ratio : float
        Below this front-axis length (over the hubs' radius) the order is a coin flip: ``p`` = 0.5.
    """

    def __init__(
        self, path: str | Path | None = None, threads: int = 1, min_axis_ratio: float = 0.15
    ) -> None:
        self.path = Path(path) if path is not None else default_heading_model_path()
        if not self.path.is_file():
            raise FileNotFoundError(
                f"front/back model not found: {self.path} (train one with `dronekey-train-heading`)"
            )
        if threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        if not 0.0 <= min_axis_ratio < 2.0:
            raise ValueError(f"min_axis_ratio must be in [0, 2), got {min_axis_ratio}")
        self.min_axis_ratio = float(min_axis_ratio)
        try:
            self.session = ort.InferenceSession(
                str(self.path), session_options(int(threads)), providers=["CPUExecutionProvider"]
            )
        except Exception as exc:  # onnxruntime's own Fail / InvalidProtobuf types
            raise ValueError(f"{self.path}: not an ONNX model onnxruntime can load ({exc})") from None
        inputs = [i.name for i in self.session.get_inputs()]
        outputs = [o.name for o in self.session.get_outputs()]
        if inputs != [INPUT_NAME] or OUTPUT_NAME not in outputs:
            raise ValueError(
                f"{self.path}: not a front/back classifier (inputs {inputs}, outputs {outputs}; "
                f"expected input {INPUT_NAME!r} and output {OUTPUT_NAME!r})"
            )
        meta = self.session.get_modelmeta().custom_metadata_map
        self.metadata = {k: _json_or_text(v) for k, v in meta.items()}
        self.patch_size = int(self.session.get_inputs()[0].shape[2])

    def preprocess(self, crops_bgr: np.ndarray, keypoints_norm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Crops (B, S, S, 3) and their keypoints (B, 4, 2, normalised crop units) -> the input
        tensor (B, 3, P, P) and the front-axis ratios (B,)."""
        patches, ratios = canonical_patches(crops_bgr, keypoints_norm, self.patch_size)
        return patches_to_tensor(patches), ratios

    def inference(self, tensor: np.ndarray) -> np.ndarray:
        """Logits (B,) that the nose is at the top of each patch."""
        return np.asarray(self.session.run([OUTPUT_NAME], {INPUT_NAME: tensor})[0], dtype=np.float32).reshape(
            -1
        )

    def postprocess(self, logits: np.ndarray, axis_ratios: np.ndarray) -> np.ndarray:
        """Probabilities (B,) that the keypoints are in the spec's order; 0.5 where the front axis is
        too short to say."""
        p = 1.0 / (1.0 + np.exp(-np.clip(logits, -30.0, 30.0)))
        return np.where(axis_ratios < self.min_axis_ratio, 0.5, p).astype(np.float32)

    def __call__(self, crops_bgr: np.ndarray, keypoints_norm: np.ndarray) -> np.ndarray:
        if len(crops_bgr) == 0:
            return np.zeros(0, dtype=np.float32)
        tensor, ratios = self.preprocess(crops_bgr, keypoints_norm)
        return self.postprocess(self.inference(tensor), ratios)


def _json_or_text(value: str):
    try:
        return json.loads(value)
    except json.JSONDecodeError:
        return value


def load_heading_model(choice: bool | str | Path) -> HeadingModel | None:
    """The classifier a pipeline asked for: True the shipped one, a path that file, False none."""
    if choice is False or choice is None:
        return None
    if choice is True:
        return HeadingModel()
    if isinstance(choice, (str, Path)):
        return HeadingModel(choice)
    raise TypeError(f"heading_model must be True, False or a path, got {choice!r}")
