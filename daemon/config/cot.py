"""The ``cot`` section: where the TAK Cursor-on-Target output sends, and what its events say.

``url`` (``--cot URL``, off while null) is one of::

    udp+multicast://239.2.3.1:6969   TAK's default situational-awareness multicast group (ATAK, WinTAK)
    udp://HOST:PORT                  unicast UDP, e.g. an ATAK device's input on 4242
    tcp://HOST:PORT                  a TAK Server's plain streaming input (8087)
    tls://HOST:PORT                  a TAK Server's TLS streaming input (8089), with ``tls`` set

A missing port takes the default in brackets (6969, 4242, 8087, 8089); a missing host is
127.0.0.1 (``tcp://:8087``), so sending off this machine takes an explicit host.
"""

from __future__ import annotations

import ipaddress
import re
from typing import Any
from urllib.parse import urlsplit

from pydantic import Field, field_validator, model_validator

from dronekey.daemon.config.section import Seconds, Section
from dronekey.daemon.config.zenoh import ZenohTlsConfig

__all__ = ["DEFAULT_PORTS", "CotConfig", "CotTlsConfig", "CotUrl"]

DEFAULT_PORTS = {"udp+multicast": 6969, "udp": 4242, "tcp": 8087, "tls": 8089}
_LOOPBACK = "127.0.0.1"
_COT_TYPE = re.compile(r"^[a-z](-[A-Za-z0-9]+)+$")
_URL_RULE = "udp+multicast://GROUP[:PORT], udp://HOST[:PORT], tcp://HOST[:PORT] or tls://HOST[:PORT]"


class CotTlsConfig(ZenohTlsConfig):
    """The client certificate a TAK Server's TLS input (8089) asks for, and the CA that signed the server.

    ``root_ca`` is the TAK Server's CA (``truststore-root`` in its certificate tooling, as PEM);
    ``certificate`` and ``private_key`` are this sensor's client certificate, signed by a CA the
    server trusts; ``verify_name_on_connect``: the server's certificate must name the URL's host.
    """


class CotUrl(tuple):
    """A parsed ``cot.url``: ``(scheme, host, port)``, scheme one of ``DEFAULT_PORTS``."""

    __slots__ = ()

    def __new__(cls, scheme: str, host: str, port: int) -> CotUrl:
        return super().__new__(cls, (scheme, host, port))

    @property
    def scheme(self) -> str:
        return self[0]

    @property
    def host(self) -> str:
        return self[1]

    @property
    def port(self) -> int:
        return self[2]

    @property
    def multicast(self) -> bool:
        try:
            return ipaddress.ip_address(self.host).is_multicast
        except ValueError:
            return False

    @classmethod
    def parse(cls, text: str) -> CotUrl:
        """Parse and check a URL (module docstring); ValueError says what is allowed."""
        try:
            parts = urlsplit(text.strip())
            port = parts.port
        except ValueError as exc:
            raise ValueError(f"must be {_URL_RULE} ({exc})") from None
        scheme = parts.scheme.lower()
        if scheme not in DEFAULT_PORTS or parts.path not in ("", "/") or parts.query or parts.username:
            raise ValueError(f"must be {_URL_RULE}, e.g. udp+multicast://239.2.3.1:6969")
        host = parts.hostname or _LOOPBACK
        if ":" in host:
            raise ValueError(
                f"IPv6 addresses are not supported (pytak's URLs), got {host!r}: use a host name"
            )
        url = cls(scheme, host, DEFAULT_PORTS[scheme] if port is None else port)
        if not 0 < url.port < 65536:
            raise ValueError(f"port must be in 1-65535, got {url.port}")
        if scheme == "udp+multicast" and not (url.multicast and ipaddress.ip_address(host).version == 4):
            raise ValueError(f"udp+multicast needs an IPv4 multicast group (224.0.0.0/4), got {host!r}")
        return url

    def __str__(self) -> str:
        return f"{self.scheme}://{self.host}:{self.port}"


class CotConfig(Section):
    """TAK Cursor-on-Target output (docs/outputs.md "TAK Cursor-on-Target"); needs camera.geo."""

    url: str | None = Field(None, description=f"null: off; {_URL_RULE}")
    tls: CotTlsConfig | None = Field(None, description="client certificate and CA for a tls:// URL")
    stale_s: Seconds = Field(5.0, description="a track's marker goes stale this long after its last event")
    min_interval_s: float = Field(
        0.2, ge=0.0, le=60.0, description="at most one event per track this often (0: every frame)"
    )
    sensor_interval_s: Seconds = Field(10.0, description="the sensor's own point, every this often")
    track_type: str = Field("a-u-A-M-H-Q", description="CoT type of a track: unknown air, rotary-wing UAV")
    sensor_type: str = Field("a-f-G-E-S-E", description="CoT type of the sensor: friendly ground sensor")
    send_delete: bool = Field(
        True, description="after a lost track's stale event, a t-x-d-d delete (ATAK/WinTAK/iTAK remove it)"
    )
    multicast_interface: str | None = Field(
        None, description="IPv4 address of the interface multicast leaves by; null: the routing table's"
    )
    multicast_ttl: int = Field(1, ge=0, le=127, description="multicast hops: 1 stays on the local network")
    connect_timeout_s: Seconds = Field(5.0, description="one TCP/TLS connection attempt at most")
    write_timeout_s: Seconds = Field(5.0, description="a peer that takes no data this long is reconnected")

    @field_validator("url", mode="before")
    @classmethod
    def _url(cls, v: Any) -> Any:
        if v is None:
            return v
        if not isinstance(v, str):
            raise ValueError(f"must be a string: {_URL_RULE}")
        return str(CotUrl.parse(v))

    @field_validator("track_type", "sensor_type")
    @classmethod
    def _cot_type(cls, v: str) -> str:
        if not _COT_TYPE.match(v):
            raise ValueError("must be a CoT type such as a-u-A-M-H-Q (letters and digits joined by -)")
        return v

    @field_validator("multicast_interface")
    @classmethod
    def _ipv4(cls, v: str | None) -> str | None:
        if v is not None:
            try:
                ipaddress.IPv4Address(v)
            except ValueError:
                raise ValueError("must be an IPv4 address of this machine, e.g. 192.168.1.20") from None
        return v

    @model_validator(mode="after")
    def _tls_matches_scheme(self) -> CotConfig:
        if self.url is not None and self.parsed_url().scheme == "tls" and self.tls is None:
            raise ValueError(
                "a tls:// URL needs cot.tls (root_ca, certificate, private_key: --cot-ca, --cot-cert, "
                "--cot-key): a TAK Server's TLS input asks for a client certificate"
            )
        return self

    def parsed_url(self) -> CotUrl:
        """``url`` parsed; ValueError if the output is off."""
        if self.url is None:
            raise ValueError("cot.url is not set: the CoT output is off")
        return CotUrl.parse(self.url)
