"""Synthetic 3DronePose-style sequences, dataset readers and the training sampler."""
