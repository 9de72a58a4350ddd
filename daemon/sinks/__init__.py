"""Outputs of the daemon. Every sink implements ``Sink`` and runs behind a ``SinkWorker`` thread."""
