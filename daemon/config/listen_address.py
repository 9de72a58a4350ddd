"""``[HOST:]PORT`` settings of the outputs that listen: one rule, loopback unless a host is named.

``sbs1.listen`` and ``foxglove_ws.listen`` take ``PORT``, ``:PORT`` or ``HOST:PORT`` (IPv6 in
brackets). A port without a host is stored as ``127.0.0.1:PORT``, so ``--print-config`` names the
address and serving the network always takes an explicit host such as ``0.0.0.0``.
"""

from __future__ import annotations

import re
from typing import Any

__all__ = ["LOOPBACK", "normalise_listen", "split_host_port"]

LOOPBACK = "127.0.0.1"
_HOST_PORT = re.compile(r"^(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]*):(?P<port>\d{1,5})$")


def normalise_listen(value: Any, example_port: int) -> Any:
    """A ``listen`` value as ``HOST:PORT`` (``127.0.0.1`` for a bare port); None stays None.

    Raises ValueError (pydantic names the setting) for anything else; the message shows
    ``example_port``. Values that are not text or a number are left to pydantic's type check.
    """
    if value is None:
        return value
    text = str(value).strip() if isinstance(value, int | str) and not isinstance(value, bool) else value
    if isinstance(text, str) and text.isdigit():
        text = f":{text}"
    match = _HOST_PORT.match(text) if isinstance(text, str) else None
    if not match or not 0 <= int(match["port"]) < 65536:
        raise ValueError(
            "must be PORT, :PORT (127.0.0.1) or HOST:PORT with a port in 0-65535 (0: any free port), "
            f"e.g. {example_port} or 0.0.0.0:{example_port}"
        )
    return text if match["host"] else f"{LOOPBACK}:{int(match['port'])}"


def split_host_port(address: str) -> tuple[str, int]:
    """``HOST:PORT`` as a socket address: the host without IPv6 brackets, and the port."""
    host, _, port = address.rpartition(":")
    return host.removeprefix("[").removesuffix("]"), int(port)
