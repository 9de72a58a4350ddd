"""Reading the config file and the flags into a validated ``DaemonConfig`` (``load_config``).

A problem is reported as one line naming the dotted key, the bad value and what is allowed
(``errors``)::

    config error: zenoh.mode = 'router' (from --zenoh-mode): input should be 'peer' or 'client'

The file is read so that it cannot exhaust the machine: at most ``MAX_CONFIG_BYTES``, no YAML
anchors or aliases (a 1 KB "billion laughs" file expands to gigabytes), nesting at most
``_MAX_DEPTH`` deep, no duplicate keys (YAML keeps the last one silently), and values are cut to a
few dozen characters before an error message is built from them.

``load_config`` and ``config_to_yaml`` are what the CLI needs; ``DaemonConfig`` documents every key
(see also ``daemon/config.example.yaml`` and ``docs/daemon.md``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from dronekey.daemon.config.daemon_config import DaemonConfig
from dronekey.daemon.config.errors import ConfigError, clip, dotted_key, format_validation_error, short_repr
from dronekey.daemon.config.mcap import default_mcap_dir

__all__ = ["MAX_CONFIG_BYTES", "config_to_yaml", "load_config"]

MAX_CONFIG_BYTES = 1_000_000  # a complete config is about 3 KB; a file this big is not a config
_MAX_DEPTH = 16  # nesting of YAML collections; the deepest key (source.v4l2.width) is 3 levels down


def load_config(path: Path | None, overrides: dict[str, tuple[Any, str]] | None = None) -> DaemonConfig:
    """Read ``path`` (if given), apply the flag overrides, validate, and resolve environment defaults.

    Parameters
    ----------
    path : Path or None
        YAML file; None for defaults only.
    overrides : dict
        Dotted key -> (value, flag that set it), e.g. ``{"zenoh.mode": ("client", "--zenoh-mode")}``.

    Raises
    ------
    ConfigError
        One line per problem, each naming the key, the bad value and what is allowed.
    """
    overrides = overrides or {}
    data = {}
    if path is not None:
        data = _read_yaml(path)
        _resolve_relative_paths(data, Path(path).parent)
    for dotted, (value, _flag) in overrides.items():
        _set_dotted(data, dotted, value)
    try:
        config = DaemonConfig.model_validate(data)
    except ValidationError as exc:
        origin = {dotted: flag for dotted, (_value, flag) in overrides.items()}
        raise ConfigError(format_validation_error(exc, origin, path)) from None
    # outputs whose messages are points on the Earth
    for dotted, value, output in (
        ("sbs1.listen", config.sbs1.listen, "SBS-1"),
        ("cot.url", config.cot.url, "CoT"),
    ):
        if value is not None and config.camera.geo is None and config.camera.extrinsics is None:
            flag = overrides.get(dotted, (None, None))[1]
            source = f" (from {flag})" if flag else ""
            raise ConfigError(
                f"config error: {dotted} = {short_repr(value)}{source}: the {output} output needs "
                "camera.geo (--camera-geo LAT,LON,ALT_M,YAW,PITCH,ROLL) or camera.extrinsics "
                "(--camera-extrinsics FILE)"
            )
    if config.mcap.dir is None:
        config.mcap.dir = default_mcap_dir()
    return config


def _read_yaml(path: Path) -> dict:
    """The file's top-level mapping, read within the bounds of the module docstring."""
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_CONFIG_BYTES + 1)  # never more, whatever the file is (/dev/zero, a FIFO)
        text = raw.decode("utf-8")
    except FileNotFoundError:
        raise ConfigError(f"config error: file not found: {path}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"config error: cannot read {path}: {clip(str(exc))}") from None
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(
            f"config error: {path}: larger than {MAX_CONFIG_BYTES // 1000} KB; a config file is a few KB"
        )
    try:
        data = _parse_yaml(text, path)
    except _Refused as exc:
        raise ConfigError(f"config error: {path}{_where(exc.problem_mark)}: {exc.problem}") from None
    except yaml.YAMLError as exc:
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        where = _where(getattr(exc, "problem_mark", None))
        raise ConfigError(f"config error: {path}{where}: invalid YAML: {clip(problem)}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(
            f"config error: {path}: the top level must be a mapping of sections "
            f"({', '.join(DaemonConfig.model_fields)}), got {type(data).__name__}"
        )
    return data


class _Refused(yaml.MarkedYAMLError):
    """Valid YAML that a config file may not use (anchors, aliases, deep nesting)."""


class _ConfigLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses anchors and aliases and nesting beyond ``_MAX_DEPTH``.

    Both are refused while the document is composed, before anything is expanded: an alias is
    cheap to parse but every later walk over the data (validation, ``repr``) pays for each copy.
    """

    def __init__(self, stream) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        event = self.peek_event()
        anchor = getattr(event, "anchor", None)
        if anchor is not None:
            mark = "*" if isinstance(event, yaml.AliasEvent) else "&"
            raise _Refused(
                problem=f"YAML anchors and aliases ({mark}{clip(anchor, 20)}) are not allowed in a "
                "config file; write each value out",
                problem_mark=event.start_mark,
            )
        self._depth += 1
        try:
            if self._depth > _MAX_DEPTH:
                raise _Refused(
                    problem=f"nested deeper than {_MAX_DEPTH} levels", problem_mark=event.start_mark
                )
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def _parse_yaml(text: str, path: Path) -> Any:
    """Compose (refusing anchors, aliases, deep nesting), reject duplicate keys, then construct."""
    loader = _ConfigLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _reject_duplicate_keys(node, (), path)
        return loader.construct_document(node)
    finally:
        loader.dispose()


def _reject_duplicate_keys(node: yaml.Node, loc: tuple[str, ...], path: Path) -> None:
    """YAML keeps the last of two equal keys without a word; a config must not hide a setting."""
    if isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _reject_duplicate_keys(item, (*loc, str(i)), path)
    elif isinstance(node, yaml.MappingNode):
        first_line: dict[str, int] = {}
        for key_node, value_node in node.value:
            if not isinstance(key_node, yaml.ScalarNode):
                continue  # a complex key: the constructor rejects it if it cannot be a key
            key = key_node.value
            line = key_node.start_mark.line + 1
            if key in first_line:
                raise ConfigError(
                    f"config error: {dotted_key((*loc, key))}: duplicate key (in {path} line {line}; "
                    f"first on line {first_line[key]})"
                )
            first_line[key] = line
            _reject_duplicate_keys(value_node, (*loc, key), path)


def _where(mark: yaml.Mark | None) -> str:
    return f" line {mark.line + 1} column {mark.column + 1}" if mark is not None else ""


# Keys holding local paths: relative values in a config file are relative to the file's folder.
_PATH_KEYS = (
    "source.uri",
    "camera.calibration",
    "model.path",
    "mavlink.signing_key",
    "mcap.dir",
    "annotated_video.path",
    "zenoh.tls.root_ca",
    "zenoh.tls.certificate",
    "zenoh.tls.private_key",
    "cot.tls.root_ca",
    "cot.tls.certificate",
    "cot.tls.private_key",
)


def _resolve_relative_paths(data: dict, base: Path) -> None:
    for dotted in _PATH_KEYS:
        *parents, leaf = dotted.split(".")
        node = data
        for key in parents:
            node = node.get(key) if isinstance(node, dict) else None
        if not isinstance(node, dict) or not isinstance(node.get(leaf), str):
            continue
        value = node[leaf]
        if "://" in value or Path(value).is_absolute() or not value.strip() or value.isdigit():
            continue  # URLs, absolute paths and V4L2 device numbers stay as they are
        node[leaf] = str(base / value)


def _set_dotted(data: dict, dotted: str, value: Any) -> None:
    *parents, leaf = dotted.split(".")
    node = data
    for key in parents:
        child = node.setdefault(key, {})
        if not isinstance(child, dict):  # the file's own type error is reported by validation
            return
        node = child
    node[leaf] = value


def config_to_yaml(config: DaemonConfig) -> str:
    """The effective configuration as YAML (what ``--print-config`` prints); loads back unchanged."""
    return yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False, default_flow_style=False)
