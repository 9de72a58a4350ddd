"""The ``foxglove_ws`` section: where the live Foxglove WebSocket view listens (``--foxglove-ws``).
Off unless ``listen`` is set; a port without a host binds 127.0.0.1."""

from __future__ import annotations

from typing import Any

from pydantic import Field, field_validator

from dronekey.daemon.config.listen_address import normalise_listen, split_host_port
from dronekey.daemon.config.section import Section

__all__ = ["FoxgloveWsConfig"]


class FoxgloveWsConfig(Section):
    """Live view: foxglove-sdk's WebSocket server (Foxglove WebSocket protocol) serving the MCAP
    log's channels as they are written (docs/outputs.md)."""

    listen: str | None = Field(
        None, description="PORT or :PORT (127.0.0.1), or HOST:PORT, e.g. 8765; 0.0.0.0:8765: the network"
    )
    message_backlog: int = Field(
        256, ge=1, le=65536, description="messages queued per viewer; a slow viewer loses the oldest"
    )

    @field_validator("listen", mode="before")
    @classmethod
    def _host_port(cls, v: Any) -> Any:
        return normalise_listen(v, example_port=8765)

    def address(self) -> tuple[str, int]:
        """``listen`` as (host without IPv6 brackets, port; 0 picks a free one).

        Raises
        ------
        ValueError
            If ``listen`` is not set (the live view is off).
        """
        if self.listen is None:
            raise ValueError("foxglove_ws.listen is not set: the live view has no address to listen on")
        return split_host_port(self.listen)
