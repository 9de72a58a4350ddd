"""The ``foxglove_ws`` section: where the live Foxglove WebSocket view listens (``--foxglove-ws``).
Off unless ``listen`` is set; a port without a host binds 127.0.0.1."""

from __future__ import annotations

import re
from typing import Any

from pydantic import Field, field_validator

from dronekey.daemon.config.section import Section

__all__ = ["FoxgloveWsConfig"]

_HOST_PORT = re.compile(r"^(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]*):(?P<port>\d{1,5})$")
_LOOPBACK = "127.0.0.1"


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
        if v is None:
            return v
        text = str(v).strip() if isinstance(v, int | str) and not isinstance(v, bool) else v
        if isinstance(text, str) and text.isdigit():
            text = f":{text}"
        m = _HOST_PORT.match(text) if isinstance(text, str) else None
        if not m or not 0 <= int(m["port"]) < 65536:
            raise ValueError(
                "must be PORT, :PORT (127.0.0.1) or HOST:PORT with a port in 0-65535 (0: any free port), "
                "e.g. 8765 or 0.0.0.0:8765"
            )
        return text if m["host"] else f"{_LOOPBACK}:{int(m['port'])}"

    def address(self) -> tuple[str, int]:
        """``listen`` as (host without IPv6 brackets, port; 0 picks a free one).

        Raises
        ------
        ValueError
            If ``listen`` is not set (the live view is off).
        """
        if self.listen is None:
            raise ValueError("foxglove_ws.listen is not set: the live view has no address to listen on")
        host, _, port = self.listen.rpartition(":")
        return host.removeprefix("[").removesuffix("]"), int(port)
