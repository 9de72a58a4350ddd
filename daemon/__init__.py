"""The DroneKey service (``dronekey-daemon``): a frame from a source, through the pipeline, to every output.

``cli``          the command line: flags over the config file, ``--validate-config``, ``--print-config``
``config/``      the pydantic settings, one module per section, and the bounded YAML loader
``sources/``     video files, V4L2, network streams, image folders, ``sim://``; the capture thread
``calibration``  the intrinsics for the source's resolution
``app``          ``DaemonApp``: capture -> ``TrackingPipeline`` -> one ``SinkWorker`` per output
``outputs``      builds the configured sinks
``sinks/``       Zenoh, MAVLink, SBS-1, MCAP (Foxglove); the shared ``target_state``
``messages``     the JSON track / status / info messages (``schemas/``)
``status``       the status line, status message and totals
``geo``          the camera's geodetic pose, camera frame -> WGS-84
``signals``, ``systemd``, ``logs``, ``errors``   stop signals, sd_notify and the unit, log setup, exit codes
``bench/``       ``dronekey-bench pipeline`` and ``soak``: the daemon run end to end
"""
