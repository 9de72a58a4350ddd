"""The ``mavlink`` section: link URL, our MAVLink identity, signing and who may command (§6.2)."""

from __future__ import annotations

from pydantic import Field, FilePath, field_validator

from dronekey.daemon.config.section import Section
from dronekey.daemon.sinks.mavlink.link import validate_url
from dronekey.daemon.sinks.mavlink.peers import parse_allow_entry

__all__ = ["MavlinkConfig"]


class MavlinkConfig(Section):
    """MAVLink 2 output (docs/design.md §6.2)."""

    enabled: bool = True
    url: str = Field(
        "udpout:127.0.0.1:14550",
        description="pymavlink connection string; udpin:PORT listens on 127.0.0.1, "
        "udpin:0.0.0.0:PORT on every interface",
    )
    sysid: int = Field(42, ge=1, le=254, description="our MAVLink system id (255 is for ground stations)")
    compid: int = Field(191, ge=1, le=255, description="our component id (191: onboard computer)")
    signing_key: FilePath | None = Field(None, description="32-byte key file; null: unsigned")
    allow: list[str] = Field(
        default_factory=list,
        description='who else may command: "HOST" (any port), "HOST:PORT" or a network "10.0.0.0/24"; '
        "[]: only the udpout target (or the first peer heard on udpin)",
    )

    @field_validator("url")
    @classmethod
    def _url(cls, v: str) -> str:
        return validate_url(v)  # also spells out 127.0.0.1 for a listening URL without a host

    @field_validator("allow")
    @classmethod
    def _allow(cls, v: list[str]) -> list[str]:
        for entry in v:
            parse_allow_entry(entry)
        return v
