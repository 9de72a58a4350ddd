"""The ``sbs1`` section: where the SBS-1 (BaseStation) TCP output listens, and its client timeout."""

from __future__ import annotations

import re
from typing import Any

from pydantic import Field, field_validator

from dronekey.daemon.config.section import Seconds, Section

__all__ = ["Sbs1Config"]

_HOST_PORT = re.compile(r"^(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]*):(?P<port>\d{1,5})$")
_LOOPBACK = "127.0.0.1"


class Sbs1Config(Section):
    """SBS-1 (BaseStation) TCP output; needs camera.geo.

    A port without a host binds 127.0.0.1 and is stored as ``127.0.0.1:PORT``, so ``--print-config``
    names the address; serving the network takes an explicit host (``0.0.0.0:30003``).
    """

    listen: str | None = Field(
        None, description="PORT or :PORT (127.0.0.1), or HOST:PORT, e.g. 30003; 0.0.0.0:30003: the network"
    )
    idle_timeout_s: Seconds = Field(
        10.0, description="disconnect a client that accepts no data for this long while data waits for it"
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
                "e.g. 30003 or 0.0.0.0:30003"
            )
        return text if m["host"] else f"{_LOOPBACK}:{int(m['port'])}"

    def address(self) -> tuple[str, int]:
        """``listen`` as a socket address (host without IPv6 brackets, port; 0 picks a free one).

        Raises
        ------
        ValueError
            If ``listen`` is not set (the SBS-1 output is off).
        """
        if self.listen is None:
            raise ValueError("sbs1.listen is not set: the SBS-1 output has no address to listen on")
        host, _, port = self.listen.rpartition(":")
        return host.removeprefix("[").removesuffix("]"), int(port)
