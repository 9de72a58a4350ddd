"""What every section of the config file shares: unknown keys are errors, assignments are validated."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["Seconds", "Section"]


class Section(BaseModel):
    """A section of the config file: a typo is an error, not a silently ignored setting."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)


Seconds = Annotated[float, Field(gt=0, le=3600)]
