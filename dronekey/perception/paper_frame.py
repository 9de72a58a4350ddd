"""The paper's rotation from four 3D keypoints (paper §III-D), and its axes in the FRD body frame.

``PoseEstimator(method="paper")`` forms its rotation this way instead of taking IPPE's; see
docs/pose-and-tracking.md, "The paper's construction".
"""

from __future__ import annotations

import numpy as np

from dronekey.geometry.drone_spec import DroneSpec

__all__ = ["paper_basis_in_body", "paper_frame"]


def _polar(M: np.ndarray) -> np.ndarray:
    """The rotation nearest to M in the Frobenius norm (orthogonal polar factor, det +1)."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def paper_frame(Y: np.ndarray) -> np.ndarray:
    """The paper's rotation R_pose = orth([v1/|v1|, v2/|v2|, v3/|v3|]) of four 3D keypoints (4, 3).

    v1 = Y2 - YO, v2 = Y3 - YO (YO the centroid), v3 = v1 x v2. v1 and v2 are not orthogonal (they
    are two half-diagonals of the hub rectangle), so the unit vectors are orthonormalised with the
    SVD polar factor: the nearest rotation, which treats v1 and v2 symmetrically (Gram-Schmidt would
    keep v1 exact and bend v2 only). The polar factor commutes with rotations,
    ``polar(Q M) = Q polar(M)``, which is what makes the body-frame correction
    (:func:`paper_basis_in_body`) a constant.
    """
    centre = Y.mean(axis=0)
    v1 = Y[1] - centre
    v2 = Y[2] - centre
    v3 = np.cross(v1, v2)
    M = np.column_stack([v / np.linalg.norm(v) for v in (v1, v2, v3)])
    return _polar(M)


def paper_basis_in_body(spec: DroneSpec) -> np.ndarray:
    """The paper's axes [v1 v2 v3] (orthonormalised) expressed in the FRD body frame, (3, 3).

    The paper's R_pose maps the paper's own drone axes to the camera, ``R_pose = R @ B``, where B is
    this matrix. Our body -> camera rotation is therefore ``R = R_pose @ B.T``. For the shipped
    specs (hubs on a rectangle, keypoint 2 rear-right, 3 rear-left) v1 and v2 are the rear-right
    and rear-left half-diagonals, v3 points down, and B is a yaw of 135 deg about the body z axis.
    """
    return paper_frame(np.asarray(spec.keypoints_3d, dtype=np.float64))
