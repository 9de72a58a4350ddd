"""Camera calibration from images or video of a board, to the intrinsics YAML the daemon reads.

Modules, in the order a run uses them:

``patterns``          the board (kind, size, square) and its detector
``sources``           image globs and evenly sampled video frames
``select_views``      sharp, diverse views from many video frames
``collect``           board views from pictures, with what was left out
``diagnose``          why no board was found (likely wrong sizes, dictionaries)
``calibrate``         pinhole / fisheye calibration with the ``--fix-*`` options, outlier views dropped
``calibration_file``  the OpenCV FileStorage YAML of docs/design.md §5.2
``coverage``          where on the sensor points were seen (figures and PNG)
``report``            --json object, readable summary, advice
``check``             reprojection error of other pictures against a calibration
``cli``               ``dronekey-calib``
"""
