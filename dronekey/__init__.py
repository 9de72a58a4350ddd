"""DroneKey: drone propeller keypoints, 6DoF pose and tracking (IROS 2025 method), as a product.

Packages, lowest layer first (each imports only the ones above it in this list; the rules are
import-linter contracts, docs/architecture.md):

``types``        the frame-flow dataclasses: Frame, KeypointDetection, PoseMeasurement, Track
``geometry``     camera model, rotations, drone specs (``geometry/specs``), the crop policy
``perception``   the ONNX keypoint model, localiser, keypoint order, plausibility gate, PnP pose
``tracking``     tracker (lifecycle, front/back evidence), position and orientation filters
``pipeline``     ``TrackingPipeline``: one frame in, track updates out
``sim_replay``   renderer, sequences, training crops, file formats (folder ``sim_replay/``)
``calib``        camera calibration, ``dronekey-calib`` (folder ``calib/``)
``nn``           the DroneKey network and its loss in torch (training and export only)
``evaluation``   metrics, the paper's tables, the robustness matrix, ``dronekey-eval``
``training``     recipes, the training loop, checkpoints, ONNX export (torch)
``bench``        model latency and sampler speed, ``dronekey-bench``
``daemon``       the service, its sources and outputs, end-to-end benchmarks (folder ``daemon/``)

The shipped model is ``models/dronekey_edge.onnx``. Importing this package, or anything but
``nn``, ``training`` and ``bench``, never imports torch.
"""

__version__ = "0.1.0"
