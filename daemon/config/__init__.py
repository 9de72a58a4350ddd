"""The daemon's configuration: one YAML file validated by pydantic, overridden by command-line flags.

One module per section of the file, each a pydantic model that forbids unknown keys and holds the
section's rules once: ``source``, ``camera``, ``model``, ``tracking``, ``zenoh``, ``mavlink``,
``sbs1``, ``mcap``; ``daemon_config`` joins them (with the small ``sinks`` and ``log`` sections)
into ``DaemonConfig``. ``loading`` reads the file within bounds and applies the flags
(``load_config``); ``errors`` turns a validation error into one line per problem (``ConfigError``).
``daemon/config.example.yaml`` and ``docs/daemon.md`` document every key.
"""
