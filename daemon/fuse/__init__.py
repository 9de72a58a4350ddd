"""``dronekey-fuse``: the fusion service of a fleet of cameras (docs/fleet.md).

It subscribes over Zenoh to the tracks of N daemons, asks each daemon's ``info`` queryable for its
camera pose, fuses the tracks with ``dronekey.fusion.Fuser`` and publishes the fused tracks on
``dronekey/fused/tracks`` (schema ``fused_track``).

Modules, one job each:

- ``cli``: the command line, logging, exit codes, signals;
- ``service``: the Zenoh session, subscriptions, pose queries and the publishing loop (``FuseService``);
- ``local_frame``: the fuser's ENU frame at its reference origin, cameras' ECEF poses into it;
- ``track_input``: a daemon's track message (JSON) back into a ``Track``;
- ``fused_message``: a ``FusedTrack`` into its JSON message.
"""
