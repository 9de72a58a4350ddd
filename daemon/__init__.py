"""The DroneKey service: sources, pipeline, sinks (Zenoh, MAVLink, MCAP, SBS-1), config, systemd."""
