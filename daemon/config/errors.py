"""Config problems, one line each: ``config error: <key> = <value> (from <flag>): <what is allowed>``.

Values are cut to a few dozen characters before a message is built from them (``short_repr``), so
a huge or deeply nested value costs nothing to report.
"""

from __future__ import annotations

import reprlib
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError

from dronekey.daemon.config.daemon_config import DaemonConfig
from dronekey.daemon.errors import UsageError

__all__ = ["ConfigError", "clip", "dotted_key", "format_validation_error", "short_repr"]

_MAX_ERROR_LINES = 20  # problems listed; the rest are counted


class ConfigError(UsageError):
    """The config file or the flags that override it are invalid; one line per problem."""


def format_validation_error(
    exc: ValidationError, origin: dict[str, str] | None = None, path: Path | None = None
) -> str:
    """One line per problem: ``config error: <key> = <value> (from <flag or file>): <what is allowed>``.

    Values are cut before they are formatted (``short_repr``), so a huge value costs nothing; at
    most ``_MAX_ERROR_LINES`` problems are listed and the rest counted.
    """
    origin = origin or {}
    lines = []
    errors = exc.errors(include_url=False)
    for err in errors[:_MAX_ERROR_LINES]:
        loc = tuple(str(p) for p in err["loc"])
        key = dotted_key(loc)
        field_key = ".".join(p for p in loc if not p.isdigit())
        source = f" (from {origin[field_key]})" if field_key in origin else (f" (in {path})" if path else "")
        if err["type"] == "extra_forbidden":
            allowed = ", ".join(_allowed_keys(loc[:-1]))
            lines.append(f"config error: {key}: unknown key{source}; allowed keys here: {allowed}")
            continue
        msg = err["msg"]
        if err["type"] == "value_error":
            msg = msg.removeprefix("Value error, ")
        msg = clip(msg[:1].lower() + msg[1:], 200)
        lines.append(f"config error: {key} = {short_repr(err.get('input'))}{source}: {msg}")
    if len(errors) > _MAX_ERROR_LINES:
        lines.append(f"config error: and {len(errors) - _MAX_ERROR_LINES} more problems")
    return "\n".join(lines)


def dotted_key(loc: tuple[str, ...]) -> str:
    """A location as the config file spells it: ``zenoh.connect[0]``, each part cut to 40 characters."""
    out = ""
    for part in loc:
        part = clip(part, 40)
        out += f"[{part}]" if part.isdigit() else (f".{part}" if out else part)
    return out


def _allowed_keys(loc: tuple[str, ...]) -> list[str]:
    model: type[BaseModel] = DaemonConfig
    for part in loc:
        field = model.model_fields.get(part)
        annotation = getattr(field, "annotation", None)
        if not (isinstance(annotation, type) and issubclass(annotation, BaseModel)):
            return []
        model = annotation
    return list(model.model_fields)


# Bounded repr: each level shows a few items and a few dozen characters, so the cost does not
# depend on the size of the value (repr() of a 1 KB YAML alias bomb took 55 s and 3 GB).
_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxdict, _REPR.maxlist, _REPR.maxtuple, _REPR.maxset = 3, 4, 4, 4, 4
_REPR.maxstring = _REPR.maxother = _REPR.maxlong = 60


def short_repr(value: Any, limit: int = 60) -> str:
    """``repr(value)`` in at most ``limit`` characters, bounded while it is built."""
    return clip(_REPR.repr(value), limit)


def clip(text: str, limit: int = 200) -> str:
    """``text`` cut to ``limit`` characters, ``...`` marking the cut."""
    return text if len(text) <= limit else text[: limit - 3] + "..."
