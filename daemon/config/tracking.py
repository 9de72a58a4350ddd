"""The ``tracking`` section: how many drones the pipeline follows and how often it looks for more."""

from __future__ import annotations

from pydantic import Field

from dronekey.daemon.config.section import Section

__all__ = ["TrackingConfig"]


class TrackingConfig(Section):
    """How many drones are tracked at once and the search for new ones (``TrackingPipeline``)."""

    max_tracks: int = Field(
        4,
        ge=1,
        le=64,
        description="live tracks at most; the search for more drones stops once this many are confirmed",
    )
    search_every: int = Field(
        30, ge=0, le=100000, description="frames between whole-frame searches while tracking (0: never)"
    )
    search_more_every: int = Field(
        6, ge=1, le=100000, description="frames between searches for more drones while tracking"
    )
    wide_look_every: int = Field(
        1,
        ge=0,
        le=100000,
        description="frames between the frames on which a track whose crop the network is unsure of "
        "(presence below 0.999) reads its drone again in a crop twice as large, so that a crop cut too "
        "small from a range read too far cannot clip the drone (1: any frame; 0: never)",
    )
    measure_every: int = Field(
        1,
        ge=1,
        le=100,
        description="the measurement stride: while every live track is confirmed, the network sure of its "
        "last crop and no search due, the drones are measured on every this-many-th frame only and the "
        "tracks predicted and published on the frames between (1: every frame, as shipped; 2 lets three "
        "cameras share the 2-core box at 30 FPS, at the accuracy cost docs/evaluation.md gives)",
    )
    late_after_ms: float | None = Field(
        None,
        gt=0,
        le=10000,
        description="a frame the pipeline takes this long after it arrived (ms) is predicted instead of "
        "measured, as a frame between two measured ones is (the tracks confirmed and sure, no search due, "
        "never more than max(1, measure_every) frames unmeasured in a row), so that after a slow frame "
        "the pipeline catches up instead of passing its lateness on to the next frames; null: never",
    )
    max_search_candidates: int = Field(
        2, ge=0, le=16, description="crops a search for more drones may check (0: no such search)"
    )
    confirm_min_change: float = Field(
        4.0,
        ge=0,
        le=255,
        description="grey levels a detection's propellers must change above their surroundings, frame to "
        "frame, to confirm a track (0: off, e.g. to report drones hovering with stopped propellers)",
    )
    confirm_drone_p: float = Field(
        0.9,
        ge=0,
        le=1,
        description="mean drone probability the drone verifier must give a track's confirming hits "
        "(0: off; no effect without a verifier, see model.verifier); lower confirms far drones sooner "
        "and more clutter (docs/evaluation.md)",
    )
    heading_full_spread_px: float = Field(
        0.0,
        ge=0,
        le=10000,
        description="bound the published heading confidence by the drone's size: none while its hubs are "
        "less than half this many px apart, sure allowed from this many on (43.5: the front/back "
        "classifier's patch; 0: off, as shipped). Only what the outputs are told changes, at the price "
        "of sure headings on far drones (docs/evaluation.md)",
    )
