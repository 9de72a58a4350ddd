"""Camera calibration from images or video of a board, to the intrinsics YAML the daemon reads."""
