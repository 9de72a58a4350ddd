"""Multi-camera fusion: several cameras' tracks of the same drones, associated and triangulated.

Torch-free and service-free: ``dronekey-fuse`` (``dronekey.daemon.fuse``) feeds it tracks received
over Zenoh, ``dronekey-eval fusion`` the tracks of each camera's pipeline run offline.

Modules, one job each:

- ``camera_pose``: a camera's pose in the shared site frame (``p_site = R_site_cam @ p_cam + t``),
- ``config``: the gates and noise figures (``FusionConfig``),
- ``observation``: one camera's track, predicted to a common time, in the site frame,
- ``clock``: per-camera clock offsets estimated from arrival times (unsynchronised clocks),
- ``association``: the gate and cost between observations (ray geometry and Mahalanobis distance),
- ``estimate``: covariance-weighted triangulation and the fused orientation,
- ``fuser``: fused tracks over time, their stable ids and lifecycle (``Fuser``).
"""

from dronekey.fusion.camera_pose import CameraPose
from dronekey.fusion.clock import ClockAlignment
from dronekey.fusion.config import FusionConfig
from dronekey.fusion.fuser import FusedMember, FusedTrack, Fuser
from dronekey.fusion.observation import Observation, observe

__all__ = [
    "CameraPose",
    "ClockAlignment",
    "FusedMember",
    "FusedTrack",
    "Fuser",
    "FusionConfig",
    "Observation",
    "observe",
]
