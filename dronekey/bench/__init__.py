"""Benchmarks of the method's parts: the network's latency and the training sampler's speed.

The end-to-end pipeline and soak benchmarks run the daemon, so they live in
``dronekey.daemon.bench``; ``dronekey-bench`` joins both.
"""
