"""The ``sapient`` section: where the SAPIENT (BSI Flex 335 v2.0) decision node listens, and the
session's timings. Off unless ``connect`` is set (``--sapient HOST:PORT``)."""

from __future__ import annotations

import uuid
from typing import Any

from pydantic import Field, field_validator, model_validator

from dronekey.daemon.config.listen_address import split_host_port
from dronekey.daemon.config.section import Seconds, Section

__all__ = ["SapientConfig"]

_LOOPBACK = "127.0.0.1"
_CONNECT_HELP = "must be PORT, :PORT (127.0.0.1) or HOST:PORT with a port in 1-65535, e.g. 127.0.0.1:5020"


def _split_host_port(text: str) -> tuple[str, int] | None:
    """(host, port) of ``PORT``, ``:PORT``, ``HOST:PORT`` or ``[IPv6]:PORT``; None when malformed."""
    if text.isdigit():
        text = f":{text}"
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or len(port) > 5 or not 0 < int(port) < 65536:
        return None
    if host.startswith("["):
        if not host.endswith("]") or len(host) < 3:
            return None
    elif ":" in host or any(c.isspace() for c in host):
        return None
    return host or _LOOPBACK, int(port)


class SapientConfig(Section):
    """SAPIENT sensor-node output: a TCP client to a decision node or middleware (docs/sapient.md).

    A port without a host connects to 127.0.0.1 and is stored as ``127.0.0.1:PORT``, so
    ``--print-config`` names the address.
    """

    connect: str | None = Field(
        None, description="decision node to connect to: PORT (127.0.0.1), or HOST:PORT; unset: off"
    )
    node_id: str | None = Field(
        None, description="this node's UUID in every message (default: derived from the camera id)"
    )
    status_interval_s: Seconds = Field(
        5.0, description="StatusReport period, s (declared in the Registration)"
    )
    registration_timeout_s: Seconds = Field(
        10.0, description="reconnect when no RegistrationAck arrives within this long"
    )
    send_timeout_s: Seconds = Field(
        5.0, description="reconnect when the peer takes no bytes for this long while data waits"
    )
    reconnect_min_s: Seconds = Field(0.5, description="first reconnection delay, doubled per failure")
    reconnect_max_s: Seconds = Field(30.0, description="longest reconnection delay")
    max_queue: int = Field(
        256,
        ge=1,
        le=100000,
        description="messages waiting for the peer at most (the oldest report is dropped)",
    )

    @field_validator("connect", mode="before")
    @classmethod
    def _host_port(cls, v: Any) -> Any:
        if v is None:
            return v
        if isinstance(v, bool) or not isinstance(v, int | str):
            raise ValueError(_CONNECT_HELP)
        parsed = _split_host_port(str(v).strip())
        if parsed is None:
            raise ValueError(_CONNECT_HELP)
        host, port = parsed
        return f"{host}:{port}"

    @field_validator("node_id", mode="before")
    @classmethod
    def _uuid(cls, v: Any) -> Any:
        if v is None:
            return v
        try:
            return str(uuid.UUID(str(v)))
        except ValueError:
            raise ValueError("must be a UUID, e.g. 2f1c7a52-6f0e-4b8e-9d55-0c1f1b7f9a10") from None

    @model_validator(mode="after")
    def _backoff_order(self) -> SapientConfig:
        if self.reconnect_max_s < self.reconnect_min_s:
            raise ValueError(
                f"reconnect_max_s ({self.reconnect_max_s}) must be >= "
                f"reconnect_min_s ({self.reconnect_min_s})"
            )
        return self

    def address(self) -> tuple[str, int]:
        """``connect`` as a socket address (host without IPv6 brackets, port).

        Raises
        ------
        ValueError
            If ``connect`` is not set (the SAPIENT output is off).
        """
        if self.connect is None:
            raise ValueError("sapient.connect is not set: the SAPIENT output has no node to connect to")
        return split_host_port(self.connect)

    def resolved_node_id(self, camera_id: str) -> str:
        """``node_id``, or a UUID derived from the camera id (the same node across restarts)."""
        if self.node_id is not None:
            return self.node_id
        return str(uuid.uuid5(uuid.NAMESPACE_URL, f"dronekey://{camera_id}"))
