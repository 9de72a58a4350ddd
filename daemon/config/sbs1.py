"""The ``sbs1`` section: where the SBS-1 (BaseStation) TCP output listens, and its client timeout."""

from __future__ import annotations

from typing import Any

from pydantic import Field, field_validator

from dronekey.daemon.config.listen_address import normalise_listen, split_host_port
from dronekey.daemon.config.section import Seconds, Section

__all__ = ["Sbs1Config"]


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
        return normalise_listen(v, example_port=30003)

    def address(self) -> tuple[str, int]:
        """``listen`` as a socket address (host without IPv6 brackets, port; 0 picks a free one).

        Raises
        ------
        ValueError
            If ``listen`` is not set (the SBS-1 output is off).
        """
        if self.listen is None:
            raise ValueError("sbs1.listen is not set: the SBS-1 output has no address to listen on")
        return split_host_port(self.listen)
