"""The ``mcap`` section: where the MCAP log goes, what it holds, and its rotation and retention (§6.3)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

from pydantic import Field

from dronekey.daemon.config.section import Section

__all__ = ["McapConfig", "default_mcap_dir"]


class McapConfig(Section):
    """MCAP log (docs/design.md §6.3); ``McapSink`` takes this section as it is."""

    enabled: bool = True
    dir: Path | None = Field(None, description="log folder; null: $STATE_DIRECTORY/mcap or ./mcap")
    image_rate_hz: float = Field(2.0, ge=0, le=120, description="camera images logged per second (0: none)")
    image_max_width: int = Field(960, ge=16, le=16384, description="logged images are downscaled to this")
    jpeg_quality: int = Field(80, ge=1, le=100)
    rotate_size_mb: float = Field(1024.0, gt=0, description="start a new file at this size")
    rotate_duration_s: float = Field(3600.0, gt=0, description="start a new file after this long")
    retention_total_mb: float = Field(10240.0, gt=0, description="delete the oldest files beyond this total")
    min_free_mb: float | None = Field(
        None,
        ge=0,
        description="delete the oldest files to keep this much disk free, else stop writing; "
        "null: the lesser of 500 MB and 5 % of the disk",
    )
    compression: Literal["zstd", "lz4", "none"] = "zstd"


def default_mcap_dir() -> Path:
    """The log folder when ``mcap.dir`` is null: ``$STATE_DIRECTORY/mcap`` under systemd, else ``./mcap``."""
    state = os.environ.get("STATE_DIRECTORY")  # set by systemd's StateDirectory=
    if state:
        return Path(state.split(":")[0]) / "mcap"
    return Path("mcap").absolute()
