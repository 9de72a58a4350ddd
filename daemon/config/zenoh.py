"""The ``zenoh`` section: mode, endpoints, scouting, the TLS identity, the history cache's depth and
the live tracks' expiry (docs/design.md §6.1).

An endpoint is ``PROTOCOL/ADDRESS`` as Zenoh parses it (everything before the first ``/`` is the
protocol): ``tcp/``, ``udp/``, ``tls/``, ``quic/``, ``ws/``, ``unixsock-stream/``, ``unixpipe/``,
``serial/``, ``vsock/``; protocol names are lower-case letters, digits and ``-``. Secure by
default (docs/security.md): a peer listens on ``LOOPBACK_LISTEN`` only, a client nowhere, and
scouting is off.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, FilePath, ValidationInfo, field_validator

from dronekey.daemon.config.section import Section

__all__ = ["ENDPOINT", "LOOPBACK_LISTEN", "ZenohConfig", "ZenohTlsConfig"]

ENDPOINT = re.compile(r"^[a-z0-9\-]+/\S+$")
LOOPBACK_LISTEN = ("tcp/127.0.0.1:0",)  # a peer's listener when none is configured: this machine only


class ZenohTlsConfig(Section):
    """This sensor's TLS identity for ``tls/`` endpoints, with mutual authentication (docs/security.md).

    ``root_ca`` verifies the other end (the router's certificate, or a peer's); ``certificate`` and
    ``private_key`` are presented to it, both when connecting and when listening, so the
    certificate's common name is this sensor's identity in the router's access control.
    """

    root_ca: FilePath = Field(description="PEM certificate of the fleet CA, which signed the other end")
    certificate: FilePath = Field(description="PEM certificate from that CA; its common name is our identity")
    private_key: FilePath = Field(description="PEM private key of the certificate (daemon-only readable)")
    verify_name_on_connect: bool = Field(True, description="the router's certificate must name its host")

    @field_validator("root_ca", "certificate")
    @classmethod
    def _pem_certificate(cls, v: Path) -> Path:
        return _pem_file(v, "-----BEGIN CERTIFICATE-----", "a PEM certificate")

    @field_validator("private_key")
    @classmethod
    def _pem_key(cls, v: Path) -> Path:
        return _pem_file(v, "PRIVATE KEY-----", "a PEM private key")


def _pem_file(path: Path, marker: str, what: str) -> Path:
    try:
        with open(path, "rb") as f:
            head = f.read(65536)
    except OSError as exc:
        raise ValueError(f"cannot read it: {exc.strerror}") from None
    if marker.encode() not in head:
        raise ValueError(f"must be {what} (no {marker!r} in its first 64 KiB)")
    return path


class ZenohConfig(Section):
    """Zenoh session (docs/design.md §6.1); on its defaults reachable from this machine only."""

    enabled: bool = True
    mode: Literal["peer", "client"] = "peer"
    connect: list[str] = Field(default_factory=list, description="endpoints, e.g. tls/192.168.1.10:7447")
    listen: list[str] = Field(
        None,  # resolved by _default_listen
        validate_default=True,
        description="endpoints; null: tcp/127.0.0.1:0 for a peer (this machine only), none for a client; "
        "e.g. tcp/0.0.0.0:7447 opens the session to the network",
    )
    scouting: bool = Field(
        False, description="multicast and gossip scouting: makes the session discoverable on the network"
    )
    tls: ZenohTlsConfig | None = Field(None, description="TLS identity (mutual authentication); null: none")
    history_depth: int = Field(
        1,
        ge=1,
        le=1000,
        description="samples the status key and each live track's key keep for subscribers that join "
        "late (zenoh-ext advanced subscribers with history)",
    )
    track_expiry_s: float = Field(
        5.0,
        gt=0,
        description="seconds without an update after which a track's key is deleted as if lost "
        "(its lost message was dropped on the way, or the source stalled)",
    )

    @field_validator("listen", mode="before")
    @classmethod
    def _default_listen(cls, v: Any, info: ValidationInfo) -> Any:
        if v is None:
            return list(LOOPBACK_LISTEN) if info.data.get("mode", "peer") == "peer" else []
        return v

    @field_validator("connect", "listen")
    @classmethod
    def _endpoints(cls, v: list[str]) -> list[str]:
        for ep in v:
            if not ENDPOINT.match(ep):
                raise ValueError(
                    f"endpoint {ep!r} must look like tcp/HOST:PORT, tls/HOST:PORT, udp/... or "
                    "unixsock-stream/PATH (PROTOCOL/ADDRESS)"
                )
        return v
