"""Front or back: a small classifier that reads the drone's nose from a patch turned front-up.

Four propeller hubs fit a pose and its 180-degree twin equally well (``HEADING_TWIN``), and the
keypoint network's own front/back head answers 0.5 on every crop (docs/model.md). This model is
the second stage that decides it from the body, rtmlib style:

- preprocess: the crop turned front-up around its keypoints
  (``dronekey.perception.patch_classifier.canonical_patches``), so the classifier only has to tell
  "nose at the top" from "nose at the bottom".
- ``HeadingModel.inference``: the ONNX classifier, whose graph is antisymmetric by construction
  (the patch turned 180 degrees gets exactly ``-logit``), so the twin order always gets exactly
  ``1 - p``. The shipped default is gated: a second, symmetric output of its net says whether the
  body shows a front at all and pulls ``p`` to 0.5 where it does not (``dronekey.nn.heading_net``).
- ``HeadingModel.postprocess``: ``p``, the probability that the keypoints' order is the spec's
  (the front hubs are 1 and 4), 0.5 where the front axis is too short to point anywhere (a drone
  seen nose-on or from the side: ``min_axis_ratio``).

``KeypointModel`` calls it on every crop after the keypoint network and hands ``p`` to
``in_heading_order`` in place of the network's head; the tracker weighs it over frames.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from dronekey.perception.patch_classifier import (
    HUB_RADIUS,
    INPUT_NAME,
    PATCH_SIZE,
    PatchClassifier,
    canonical_patch,
    canonical_patches,
    patches_to_tensor,
    sigmoid,
)

__all__ = [
    "HEADING_MODEL_ALIASES",
    "HUB_RADIUS",
    "INPUT_NAME",
    "OUTPUT_NAME",
    "PATCH_SIZE",
    "SHIPPED_HEADING_MODELS",
    "HeadingModel",
    "canonical_patch",
    "canonical_patches",
    "default_heading_model_path",
    "heading_model_path",
    "load_heading_model",
    "patches_to_tensor",
]

# The shipped front/back classifiers by name, the training recipe that made each
# (``dronekey-train-heading --net``): "gated", the default (four convs and the gate that answers 0.5
# on a body showing no front, 0.5 ms a crop on one core of the 2-core box), and "deep" (six convs, no
# gate, 1.2 ms a crop, right on 81 % of held-out crops against 79 %; a pipeline 13-15 % slower;
# docs/model.md).
SHIPPED_HEADING_MODELS = {"gated": "dronekey_heading.onnx", "deep": "dronekey_heading_deep.onnx"}
# Former names still accepted: "small" named the gated classifier until 2026-12-05, although the
# training recipe of that name is the net without the gate.
HEADING_MODEL_ALIASES = {"small": "gated"}
OUTPUT_NAME = "logit"


def default_heading_model_path(net: str = "gated") -> Path:
    """The shipped front/back classifier ``net`` (a key of ``SHIPPED_HEADING_MODELS`` or a former name
    in ``HEADING_MODEL_ALIASES``), inside the installed package."""
    net = HEADING_MODEL_ALIASES.get(net, net)
    if net not in SHIPPED_HEADING_MODELS:
        raise ValueError(f"net must be one of {', '.join(SHIPPED_HEADING_MODELS)}, got {net!r}")
    return Path(str(resources.files("dronekey.models").joinpath(SHIPPED_HEADING_MODELS[net])))


def heading_model_path(choice: str | Path) -> Path:
    """The file a front/back classifier choice names: a key of ``SHIPPED_HEADING_MODELS`` (``"deep"``)
    or of ``HEADING_MODEL_ALIASES`` the shipped one, anything else a path (``./deep`` for a file so
    named)."""
    if isinstance(choice, str) and HEADING_MODEL_ALIASES.get(choice, choice) in SHIPPED_HEADING_MODELS:
        return default_heading_model_path(choice)
    return Path(choice)


class HeadingModel(PatchClassifier):
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
        if not 0.0 <= min_axis_ratio < 2.0:
            raise ValueError(f"min_axis_ratio must be in [0, 2), got {min_axis_ratio}")
        self.min_axis_ratio = float(min_axis_ratio)
        super().__init__(
            Path(path) if path is not None else default_heading_model_path(),
            OUTPUT_NAME,
            "front/back classifier",
            "dronekey-train-heading",
            threads,
        )

    def postprocess(self, logits: np.ndarray, axis_ratios: np.ndarray) -> np.ndarray:
        """Probabilities (B,) that the keypoints are in the spec's order; 0.5 where the front axis is
        too short to say."""
        return np.where(axis_ratios < self.min_axis_ratio, 0.5, sigmoid(logits)).astype(np.float32)


def load_heading_model(choice: bool | str | Path) -> HeadingModel | None:
    """The classifier a pipeline asked for: True the shipped default, a shipped name or a path the
    file ``heading_model_path`` names, False none."""
    if choice is False or choice is None:
        return None
    if choice is True:
        return HeadingModel()
    if isinstance(choice, (str, Path)):
        return HeadingModel(heading_model_path(choice))
    raise TypeError(f"heading_model must be True, False, a shipped name or a path, got {choice!r}")
