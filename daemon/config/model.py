"""The ``model`` section: the keypoint network, its threads and the drone it looks for."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, FilePath, field_validator

from dronekey.daemon.config.section import Section
from dronekey.geometry.drone_spec import available_specs

__all__ = ["ModelConfig"]


class ModelConfig(Section):
    """The keypoint network, the front/back classifier and the drone it looks for."""

    path: FilePath | None = Field(None, description="ONNX model; null: the model shipped with the package")
    drone: str = Field("mini2", description="drone spec name (mini2, air2s) or a spec YAML path")
    drone_alternatives: list[str] = Field(
        default_factory=list,
        description="other airframes the site may see (names or spec YAML paths): one camera cannot "
        "tell airframes of one shape apart, so every track's published range doubt is kept at least "
        "their largest size difference from drone's (air2s beside mini2: 42 % of the range); the range "
        "stays drone's. Empty: one airframe",
    )
    threads: int = Field(
        1,
        ge=1,
        le=256,
        description="ONNX Runtime intra-op threads; 1 leaves the other cores to decoding and other cameras; "
        "2 lowers the latency of one camera watching several drones (docs/performance.md)",
    )
    mirror_average: bool = Field(
        True,
        description="also run each crop mirrored and average (a fifth less keypoint error, ~1.6x inference)",
    )
    front_back: bool = Field(
        True,
        description="decide each crop's front and back with the front/back classifier "
        "(dronekey.perception.heading_model); false: the keypoint network's own head (a coin flip)",
    )
    front_back_net: Literal["gated", "deep", "small"] = Field(
        "gated",
        description="which shipped front/back classifier: gated (0.5 ms a crop; it answers 0.5 on a "
        "body that shows no front) or deep (1.2 ms a crop, no gate, a pipeline 13-15 % slower; "
        "docs/model.md); small is the gated one's former name; unused with front_back_path",
    )
    front_back_path: FilePath | None = Field(
        None, description="ONNX front/back classifier; null: the shipped one that front_back_net names"
    )
    verifier: bool = Field(
        True,
        description="confirm a track only when the drone verifier (dronekey.perception.drone_verifier) "
        "calls its hits a drone (tracker.confirm_drone_p); no effect when the package ships no verifier "
        "and verifier_path is null",
    )
    verifier_path: FilePath | None = Field(
        None, description="ONNX drone verifier; null: the one shipped with the package, if any"
    )

    @field_validator("drone")
    @classmethod
    def _known_drone(cls, v: str) -> str:
        return _known_spec(v)

    @field_validator("drone_alternatives")
    @classmethod
    def _known_alternatives(cls, v: list[str]) -> list[str]:
        return [_known_spec(name) for name in v]


def _known_spec(v: str) -> str:
    """A drone spec name or an existing spec YAML path; else the error pydantic shows."""
    if v.endswith((".yaml", ".yml")):
        if not Path(v).is_file():
            raise ValueError(f"drone spec file not found: {v}")
        return v
    names = available_specs()
    if v not in names:
        raise ValueError(f"unknown drone {v!r}; allowed: {', '.join(names)} or a spec .yaml path")
    return v
