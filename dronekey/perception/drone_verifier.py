"""Drone or not: a second look at what the keypoint network calls a drone, on the front-up patch.

The keypoint network's presence score is trained on random and mined drone-free crops, yet birds,
wires and photographs it was not drawn from still score 0.94-0.99 (docs/evaluation.md), so the
tracker's presence rule cannot tell them from drones. The verifier is a cascade stage trained on
exactly those: the network's own confident detections on drone-free crops against its detections
of drones, each warped front-up around the keypoints the network found
(``dronekey.perception.patch_classifier.canonical_patches``). A drone's four arms then sit where
the patch expects them; clutter's do not.

- preprocess: the front-up patch (the same one the front/back classifier reads; ``KeypointModel``
  builds it once for both).
- ``DroneVerifier.inference``: the ONNX classifier, symmetric by construction
  (``logit(x) = (f(x) + f(x turned 180 deg)) / 2``), so the verdict does not depend on which of the
  two orders the keypoints came in.
- postprocess (``PatchClassifier.postprocess``): the probability that the patch is a drone.

The tracker uses it as confirmation evidence (``TrackerConfig.confirm_drone_p``): a hypothesis
whose hits the verifier rejects is never confirmed, so it never reaches an output.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from dronekey.perception.patch_classifier import PatchClassifier

__all__ = ["DroneVerifier", "default_verifier_path", "load_verifier"]

SHIPPED_VERIFIER = "dronekey_verifier.onnx"
OUTPUT_NAME = "drone_logit"


def default_verifier_path() -> Path:
    """The shipped drone verifier, inside the installed package."""
    return Path(str(resources.files("dronekey.models").joinpath(SHIPPED_VERIFIER)))


class DroneVerifier(PatchClassifier):
    """The drone verifier in ONNX Runtime.

    Parameters
    ----------
    path : str or Path, optional
        ONNX file written by ``dronekey-train-verifier``; default the shipped one.
    threads : int
        Intra-op threads (the classifier is small: one is enough).
    """

    def __init__(self, path: str | Path | None = None, threads: int = 1) -> None:
        super().__init__(
            Path(path) if path is not None else default_verifier_path(),
            OUTPUT_NAME,
            "drone verifier",
            "dronekey-train-verifier",
            threads,
        )


def load_verifier(choice: bool | str | Path | None) -> DroneVerifier | None:
    """The verifier a pipeline asked for: True the shipped one (None when none is shipped), a path
    that file, False or None none."""
    if choice is False or choice is None:
        return None
    if choice is True:
        return DroneVerifier() if default_verifier_path().is_file() else None
    if isinstance(choice, (str, Path)):
        return DroneVerifier(choice)
    raise TypeError(f"verifier must be True, False or a path, got {choice!r}")
