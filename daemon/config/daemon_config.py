"""The whole config file: every section, plus the ``sinks`` and ``log`` settings."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, field_validator

from dronekey.daemon.config.annotated_video import AnnotatedVideoConfig
from dronekey.daemon.config.camera import CameraConfig
from dronekey.daemon.config.cot import CotConfig
from dronekey.daemon.config.foxglove_ws import FoxgloveWsConfig
from dronekey.daemon.config.mavlink import MavlinkConfig
from dronekey.daemon.config.mcap import McapConfig
from dronekey.daemon.config.model import ModelConfig
from dronekey.daemon.config.sapient import SapientConfig
from dronekey.daemon.config.sbs1 import Sbs1Config
from dronekey.daemon.config.section import Seconds, Section
from dronekey.daemon.config.source import SourceConfig
from dronekey.daemon.config.tracking import TrackingConfig
from dronekey.daemon.config.zenoh import ZenohConfig

__all__ = ["DaemonConfig", "LogConfig", "SinksConfig"]


class SinksConfig(Section):
    """Settings shared by every output."""

    queue_size: int = Field(64, ge=1, le=100000, description="updates queued per output (drop oldest)")


class LogConfig(Section):
    """Logging and the status messages."""

    level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = "INFO"
    status_interval_s: Seconds = Field(1.0, description="status message to the outputs and the terminal")
    journal_status_interval_s: Seconds = Field(
        60.0, description="status as a plain log line when stderr is not a terminal (journald)"
    )

    @field_validator("level", mode="before")
    @classmethod
    def _upper(cls, v: Any) -> Any:
        if isinstance(v, str) and v.upper() in ("DEBUG", "INFO", "WARNING", "ERROR"):
            return v.upper()
        return v


class DaemonConfig(Section):
    """Everything ``dronekey-daemon`` can be told; each section is documented in ``docs/daemon.md``."""

    source: SourceConfig = Field(default_factory=SourceConfig)
    camera: CameraConfig = Field(default_factory=CameraConfig)
    model: ModelConfig = Field(default_factory=ModelConfig)
    tracking: TrackingConfig = Field(default_factory=TrackingConfig)
    zenoh: ZenohConfig = Field(default_factory=ZenohConfig)
    mavlink: MavlinkConfig = Field(default_factory=MavlinkConfig)
    sbs1: Sbs1Config = Field(default_factory=Sbs1Config)
    sapient: SapientConfig = Field(default_factory=SapientConfig)
    cot: CotConfig = Field(default_factory=CotConfig)
    mcap: McapConfig = Field(default_factory=McapConfig)
    foxglove_ws: FoxgloveWsConfig = Field(default_factory=FoxgloveWsConfig)
    annotated_video: AnnotatedVideoConfig = Field(default_factory=AnnotatedVideoConfig)
    sinks: SinksConfig = Field(default_factory=SinksConfig)
    log: LogConfig = Field(default_factory=LogConfig)
