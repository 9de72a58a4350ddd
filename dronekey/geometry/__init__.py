"""Geometry: the camera model, rotations, the drone specs' keypoints and the crop policy.

The lowest layer: numpy and OpenCV only, no other ``dronekey`` package.

``camera``      pinhole / fisheye intrinsics, projection, the calibration YAML
``rotations``   quaternion (w, x, y, z) <-> rotation matrix, angle between rotations
``drone_spec``  a drone's four propeller hubs in its FRD body frame (``specs/*.yaml``)
``crop``        the square crop around a drone that the network sees, and back to frame pixels
``apparent_size`` a drone's size in the image from its keypoints
"""
