"""The front-up patch and the ONNX classifiers that read it (rtmlib style: preprocess, inference,
postprocess).

Each crop the keypoint network found a drone in is warped by a similarity transform so that its
keypoints' centre is the patch centre, their front axis (rear hubs' midpoint -> front hubs'
midpoint, in the order the keypoints come in) points up, and the farthest hub lies ``HUB_RADIUS``
of the patch side from the centre (``canonical_patches``). Rotation and scale are taken out, so a
classifier only has to read the body. Two read it: the front/back classifier
(``dronekey.perception.heading_model``) and the drone verifier
(``dronekey.perception.drone_verifier``); ``PatchClassifier`` is what they share: the ONNX session,
its contract check, metadata and the patch tensor.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

from dronekey.perception.onnx_session import session_options

__all__ = [
    "HUB_RADIUS",
    "INPUT_NAME",
    "PATCH_SIZE",
    "PatchClassifier",
    "canonical_patch",
    "canonical_patches",
    "patches_to_tensor",
]

PATCH_SIZE = 64  # px, side of the classifiers' square input
HUB_RADIUS = 0.34  # the farthest hub's distance from the patch centre, in patch sides
INPUT_NAME = "patch"
# Normalisation of the BGR patch (grey statistics: the classifiers are trained with their colour
# channels permuted, so no channel is special).
PATCH_MEAN = 0.45
PATCH_STD = 0.25


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


class PatchClassifier:
    """An ONNX classifier of front-up patches: input ``patch`` (B, 3, P, P) float32, one logit per
    patch on output ``output_name``.

    Parameters
    ----------
    path : Path
        The ONNX file.
    output_name : str
        The logit output this kind of classifier must have.
    kind : str
        What it is, for error messages ("front/back classifier", "drone verifier").
    trainer : str
        The command that writes one, for the error when the file is missing.
    threads : int
        Intra-op threads (the classifiers are small: one is enough).

    Attributes
    ----------
    inference_cpu_s : float
        CPU seconds the calling threads have spent in ``session.run`` (``KeypointModel.network_cpu_s``).
    """

    def __init__(self, path: Path, output_name: str, kind: str, trainer: str, threads: int = 1) -> None:
        self.path = Path(path)
        self.output_name = output_name
        self.inference_cpu_s = 0.0  # the calling threads' CPU seconds in session.run
        if not self.path.is_file():
            raise FileNotFoundError(f"{kind} not found: {self.path} (train one with `{trainer}`)")
        if threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        try:
            self.session = ort.InferenceSession(
                str(self.path), session_options(int(threads)), providers=["CPUExecutionProvider"]
            )
        except Exception as exc:  # onnxruntime's own Fail / InvalidProtobuf types
            raise ValueError(f"{self.path}: not an ONNX model onnxruntime can load ({exc})") from None
        inputs = [i.name for i in self.session.get_inputs()]
        outputs = [o.name for o in self.session.get_outputs()]
        if inputs != [INPUT_NAME] or output_name not in outputs:
            raise ValueError(
                f"{self.path}: not a {kind} (inputs {inputs}, outputs {outputs}; "
                f"expected input {INPUT_NAME!r} and output {output_name!r})"
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
        """Logits (B,) of the patches in ``tensor`` (``preprocess``'s first output)."""
        started = time.thread_time()
        out = self.session.run([self.output_name], {INPUT_NAME: tensor})[0]
        self.inference_cpu_s += time.thread_time() - started
        return np.asarray(out, dtype=np.float32).reshape(-1)

    def postprocess(self, logits: np.ndarray, axis_ratios: np.ndarray) -> np.ndarray:
        """Probabilities (B,) from the logits; ``axis_ratios`` (``preprocess``'s second output)
        for the classifiers whose answer depends on them."""
        return sigmoid(logits)

    def __call__(self, crops_bgr: np.ndarray, keypoints_norm: np.ndarray) -> np.ndarray:
        """Crops (B, S, S, 3) and their keypoints (B, 4, 2, normalised) -> probabilities (B,)."""
        if len(crops_bgr) == 0:
            return np.zeros(0, dtype=np.float32)
        tensor, ratios = self.preprocess(crops_bgr, keypoints_norm)
        return self.postprocess(self.inference(tensor), ratios)


def sigmoid(logits: np.ndarray) -> np.ndarray:
    """Probabilities of logits, float32, overflow-safe."""
    return (1.0 / (1.0 + np.exp(-np.clip(logits, -30.0, 30.0)))).astype(np.float32)


def _json_or_text(value: str):
    try:
        return json.loads(value)
    except json.JSONDecodeError:
        return value
