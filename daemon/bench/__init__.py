"""``dronekey-bench pipeline`` and ``dronekey-bench soak``: the daemon's own pipeline, end to end.

Both run ``dronekey.daemon.app.DaemonApp``, the service's runner (capture thread, ``TrackingPipeline``,
one ``SinkWorker`` per output), on a video file with every output on, so they measure the product:

- Zenoh: a peer listening on 127.0.0.1 only, multicast scouting off;
- MAVLink: ``udpout`` to a UDP port on 127.0.0.1 that the benchmark reads and discards;
- MCAP: into a temporary folder (deleted afterwards), images at the configured default rate.

SIGINT / SIGTERM stop either command the daemon's way (outputs closed, temporary folder removed,
exit status 130 / 143); an interrupted soak still prints its figures up to the last 100 frames.
``dronekey-bench`` finds the two commands through the ``dronekey.bench`` entry points.

``errors``       ``BenchError`` (bad input, failed run) and ``BenchInterruptedError`` (a signal)
``bench_setup``  ``BenchSetup``: the source, calibration, model and threads, as a daemon config
``meter``        the daemon's pipeline behind a frame counter that stamps time, CPU and memory
``daemon_run``   one daemon run with local endpoints and the daemon's signal handling
``pipeline``     the four passes of ``pipeline``: decode, flat out, paced, model
``soak``         ``soak``: the daemon looping over a video, resident memory over time
``commands``     the two subcommands' parsers, tables and exit statuses
"""
