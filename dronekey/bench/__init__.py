"""Benchmarks of the method's parts: the network's latency and the training sampler's speed.

``cli``            ``dronekey-bench``: one subcommand per ``dronekey.bench`` entry point
``arguments``      argument types shared by the subcommands
``model``          ``dronekey-bench model``: the network in ONNX Runtime, batch 1, fp32 and int8
``model_latency``  one ONNX model's latency (no torch; the daemon's pipeline bench reuses it)
``model_files``    the random-weight exports and int8 files ``model`` times (torch; a child process)
``sampler``        ``dronekey-bench sampler``: training crops rendered per second

The end-to-end ``pipeline`` and ``soak`` benchmarks run the daemon, so they live in
``dronekey.daemon.bench`` and join ``dronekey-bench`` through the same entry points.
"""
