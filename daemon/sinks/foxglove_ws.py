"""Live Foxglove view: foxglove-sdk's WebSocket server (protocol ``foxglove.websocket.v1``) carrying
the Foxglove log's channels with the same schemas and the same encoded bytes as the MCAP file.

The MCAP sink hands each message to ``FoxgloveLiveServer.log`` as it writes it. ``log`` never
blocks: the SDK queues up to ``message_backlog`` messages per connected viewer and drops that
viewer's oldest when it falls behind, so a slow viewer never stalls the sink (nor the pipeline).
"""

from __future__ import annotations

import logging

import foxglove

from dronekey.daemon.sinks.mcap.channels import ChannelSpec

__all__ = ["FoxgloveLiveServer"]

log = logging.getLogger(__name__)


class FoxgloveLiveServer:
    """A WebSocket server advertising one channel per ``ChannelSpec``.

    Parameters
    ----------
    host, port : str, int
        Where to listen (port 0: a free one, see ``port``).
    specs : list of ChannelSpec
        The channels (topic, schema, encoding).
    message_backlog : int
        Messages queued per viewer before its oldest are dropped.

    Raises
    ------
    OSError
        Naming ``foxglove_ws.listen`` when the address cannot be bound.
    """

    def __init__(self, host: str, port: int, specs: list[ChannelSpec], *, message_backlog: int = 256) -> None:
        self._context = foxglove.Context()
        self._channels = {
            spec.topic: foxglove.Channel(
                spec.topic,
                schema=foxglove.Schema(
                    name=spec.schema_name, encoding=spec.schema_encoding, data=spec.schema_data
                ),
                message_encoding=spec.message_encoding,
                context=self._context,
            )
            for spec in specs
        }
        try:
            self._server = foxglove.start_server(
                name="dronekey",
                host=host,
                port=port,
                context=self._context,
                message_backlog_size=message_backlog,
            )
        except RuntimeError as exc:
            raise OSError(f"foxglove_ws.listen {host}:{port}: {exc}") from None
        self.host = host
        self.port = int(self._server.port)
        log.info("Foxglove live view on ws://%s:%d (open it in Foxglove: Open connection)", host, self.port)

    def log(self, topic: str, t_ns: int, data: bytes) -> None:
        """Send one encoded message to the viewers subscribed to ``topic`` (never blocks)."""
        channel = self._channels.get(topic)
        if channel is not None and channel.has_sinks():
            channel.log(data, log_time=max(int(t_ns), 0))

    def close(self) -> None:
        """Stop the server and close the channels."""
        self._server.stop()
        for channel in self._channels.values():
            channel.close()
