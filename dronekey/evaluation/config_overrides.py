"""``KEY=VALUE`` settings for a config dataclass, from the command line (``dronekey-eval robustness``
and ``mot``, ``--tracker KEY=VALUE --localizer KEY=VALUE``): any setting of ``TrackerConfig`` or
``LocalizerConfig`` measured before it is shipped, without a script of one's own; and how a report
names what was changed (``pipeline_changes``, ``describe_pipeline_changes``).

A value is read as the field's type (the annotation names it: ``bool`` true / false, ``int``,
``float``, ``null`` where the field may be None); the dataclass's own checks then run, so a
setting out of range is refused as the library refuses it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

from dronekey.perception.localizer import LocalizerConfig
from dronekey.tracking.tracker_config import TrackerConfig

__all__ = [
    "OverrideError",
    "changed_settings",
    "config_with_overrides",
    "describe_pipeline_changes",
    "parse_overrides",
    "pipeline_changes",
]

_TRUE, _FALSE, _NULL = ("true", "yes", "on", "1"), ("false", "no", "off", "0"), ("null", "none")


class OverrideError(ValueError):
    """A ``KEY=VALUE`` the config cannot take; the message names the flag, the key and the value."""


def parse_overrides(pairs: Sequence[str], config_type: type, flag: str) -> dict[str, Any]:
    """``pairs`` (``"KEY=VALUE"`` strings) as keyword arguments of the dataclass ``config_type``.

    Parameters
    ----------
    pairs : the strings as given, e.g. ``["confirm_min_presence=0.9", "max_tracks=2"]``.
    config_type : a dataclass whose fields are the keys.
    flag : the option the pairs came with (``--tracker``), for the messages.

    Raises
    ------
    OverrideError
        A pair without ``=``, an unknown key (the message lists the known ones), a key given twice,
        or a value that is not of the field's type.
    """
    fields = {f.name: f for f in dataclasses.fields(config_type)}
    out: dict[str, Any] = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        key, text = key.strip(), text.strip()
        if not sep or not key:
            raise OverrideError(f"{flag} takes KEY=VALUE, got {pair!r}")
        if key not in fields:
            known = ", ".join(fields)
            raise OverrideError(f"{flag}: {config_type.__name__} has no setting {key!r}; known: {known}")
        if key in out:
            raise OverrideError(f"{flag}: {key} given twice")
        out[key] = _value(text, _annotation(fields[key].type), f"{flag} {key}")
    return out


def config_with_overrides(config_type: type, overrides: dict[str, Any], flag: str, **base: Any):
    """``config_type(**base, **overrides)``; the overrides win over ``base``. The dataclass's own
    ``ValueError`` (a value out of its range) comes back as an ``OverrideError`` naming ``flag``."""
    try:
        return config_type(**{**base, **overrides})
    except ValueError as exc:
        raise OverrideError(f"{flag}: {exc}") from None


def changed_settings(config: Any, config_type: type) -> dict[str, Any]:
    """The fields of ``config`` (an instance of the dataclass ``config_type``, or None: the defaults)
    whose values differ from the defaults', in field order: what a measurement changed."""
    if config is None:
        return {}
    shipped = config_type()
    return {
        f.name: getattr(config, f.name)
        for f in dataclasses.fields(config_type)
        if getattr(config, f.name) != getattr(shipped, f.name)
    }


def pipeline_changes(
    localizer: LocalizerConfig | None, tracker: TrackerConfig | None
) -> dict[str, dict[str, Any]]:
    """What a measurement changed of the localiser's and the tracker's settings (``changed_settings``
    of each; None: shipped), under the keys an evaluation's ``settings`` report them by."""
    return {
        "localizer_changed": changed_settings(localizer, LocalizerConfig),
        "tracker_changed": changed_settings(tracker, TrackerConfig),
    }


def describe_pipeline_changes(settings: dict) -> list[str]:
    """``pipeline_changes``' entries of ``settings`` as text, one per part that changed:
    ``["localizer max_candidates=4", "tracker max_tracks=1"]``."""
    return [
        f"{part} {', '.join(f'{k}={v}' for k, v in settings[key].items())}"
        for part, key in (("localizer", "localizer_changed"), ("tracker", "tracker_changed"))
        if settings.get(key)
    ]


def _annotation(field_type: Any) -> str:
    """A field's annotation as text (``"float | None"``), whether postponed (a string) or a type."""
    if isinstance(field_type, str):
        return field_type
    return getattr(field_type, "__name__", None) or str(field_type)


def _value(text: str, annotation: str, name: str) -> Any:
    """``text`` as the type ``annotation`` (a dataclass field's annotation string) names."""
    kinds = {part.strip() for part in annotation.split("|")}
    lowered = text.lower()
    if "None" in kinds and lowered in _NULL:
        return None
    if "bool" in kinds:
        if lowered in _TRUE:
            return True
        if lowered in _FALSE:
            return False
        raise OverrideError(f"{name} must be true or false, got {text!r}")
    if "int" in kinds:
        try:
            return int(text)
        except ValueError:
            raise OverrideError(f"{name} must be an integer, got {text!r}") from None
    if "float" in kinds:
        try:
            value = float(text)
        except ValueError:
            raise OverrideError(f"{name} must be a number, got {text!r}") from None
        if math.isnan(value):
            raise OverrideError(f"{name} must be a number, got {text!r}")
        return value
    return text
