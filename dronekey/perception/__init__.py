"""Perception: from a frame to per-drone 6DoF measurements (no torch: ONNX Runtime only).

``keypoint_model``  the exported network: preprocess, ONNX Runtime inference, postprocess
``onnx_session``    ONNX Runtime session options both models share
``heading_model``   the front/back classifier: the crop turned front-up around the keypoints, its answer
``localizer``       where to look: search proposals over the frame, crops per prior
``keypoint_order``  the keypoint <-> network order (mirror, 180-degree twin) and its fixes
``plausibility``    the gate every detection passes before it becomes a measurement
``pose``            the pose estimator: checks the keypoints, picks an IPPE solution, the output pose
``planar_pnp``      PnP (IPPE) from four keypoints and the spec, refined, with covariance
``paper_frame``     the paper's rotation construction and its axes in the body frame
"""
