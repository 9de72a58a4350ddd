"""DroneKey: drone propeller keypoints, 6DoF pose and tracking (IROS 2025 method), as a product.

Sub-packages: ``dronekey.sim_replay`` (synthetic sequences), ``dronekey.calib`` (camera
calibration), ``dronekey.daemon`` (the service). Importing this package never imports torch.
"""

__version__ = "0.1.0"
