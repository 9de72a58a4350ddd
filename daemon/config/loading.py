"""The daemon's configuration: one YAML file validated by pydantic, overridden by command-line flags.

Every section forbids unknown keys, so a typo is an error, not a silently ignored setting. A
problem is reported as one line naming the dotted key, the bad value and what is allowed::

    config error: zenoh.mode = 'router' (from --zenoh-mode): input should be 'peer' or 'client'

The file is read so that it cannot exhaust the machine: at most ``MAX_CONFIG_BYTES``, no YAML
anchors or aliases (a 1 KB "billion laughs" file expands to gigabytes), nesting at most
``_MAX_DEPTH`` deep, no duplicate keys (YAML keeps the last one silently), and values are cut to a
few dozen characters before an error message is built from them.

``load_config`` is the only entry point the CLI needs; ``DaemonConfig`` documents every key (see
also ``daemon/config.example.yaml`` and ``docs/daemon.md``).
"""

from __future__ import annotations

import os
import re
import reprlib
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    FilePath,
    ValidationError,
    ValidationInfo,
    field_validator,
)

from dronekey.daemon.errors import UsageError
from dronekey.daemon.geo import CameraGeo, GeoError

__all__ = ["ConfigError", "DaemonConfig", "config_to_yaml", "format_validation_error", "load_config"]

_CAMERA_ID = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
_ZENOH_ENDPOINT = re.compile(r"^[a-z0-9]+/\S+$")
_HOST_PORT = re.compile(r"^(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]*):(?P<port>\d{1,5})$")

MAX_CONFIG_BYTES = 1_000_000  # a complete config is about 3 KB; a file this big is not a config
_MAX_DEPTH = 16  # nesting of YAML collections; the deepest key (source.v4l2.width) is 3 levels down
_MAX_ERROR_LINES = 20  # problems listed; the rest are counted


class ConfigError(UsageError):
    """The config file or the flags that override it are invalid; one line per problem."""


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


Seconds = Annotated[float, Field(gt=0, le=3600)]


class V4l2Settings(_Section):
    """Capture settings applied to ``/dev/videoN`` sources (ignored by other sources)."""

    width: int | None = Field(None, gt=0, le=16384, description="requested frame width, px")
    height: int | None = Field(None, gt=0, le=16384, description="requested frame height, px")
    fps: float | None = Field(None, gt=0, le=1000, description="requested frame rate")
    fourcc: str | None = Field(None, description="pixel format, e.g. MJPG, YUYV, H264")

    @field_validator("fourcc")
    @classmethod
    def _four_chars(cls, v: str | None) -> str | None:
        if v is not None and (len(v) != 4 or not v.isascii()):
            raise ValueError("must be 4 ASCII characters such as MJPG, YUYV or H264")
        return v


class NetworkSettings(_Section):
    """Settings of rtsp/http/tcp/udp sources (OpenCV's FFmpeg backend)."""

    open_timeout_s: Seconds = Field(10.0, description="give up one connection attempt after this")
    rtsp_transport: Literal["tcp", "udp"] = Field("tcp", description="RTSP over TCP survives lossy links")


class SimSettings(_Section):
    """Settings of ``sim://<preset>`` sources."""

    seed: int | None = Field(None, ge=0, description="random seed; null: the preset's own (11, 12, 13)")
    frames: int | None = Field(None, gt=0, description="frames to render; null: the preset's length")


class SourceConfig(_Section):
    """Where frames come from and how the capture thread treats them."""

    uri: str | None = Field(
        None, description="video file, image folder, /dev/videoN, rtsp|http|tcp|udp URL or sim://preset"
    )
    realtime: bool = Field(False, description="pace files, image folders and sim at their frame rate")
    loop: bool = Field(False, description="restart a file, image folder or sim at its end")
    queue_size: int = Field(2, ge=1, le=256, description="frames buffered from live sources (drop oldest)")
    stall_timeout_s: Seconds = Field(
        5.0, description="live source with no frame for this long is stalled; reconnected after twice that"
    )
    reconnect_initial_s: Seconds = Field(0.5, description="first reconnection delay (doubles each try)")
    reconnect_max_s: Seconds = Field(30.0, description="longest reconnection delay")
    max_reconnects: int | None = Field(
        None, ge=0, description="failed attempts in a row before exit 3; null: retry forever"
    )
    image_fps: float = Field(30.0, gt=0, le=1000, description="frame rate of image folders (timestamps)")
    max_frames: int | None = Field(None, gt=0, description="stop (exit 0) after this many frames")
    decode_threads: int | None = Field(
        None, ge=1, le=64, description="FFmpeg decoder threads (files, network); null: all cores but one"
    )
    v4l2: V4l2Settings = Field(default_factory=V4l2Settings)
    network: NetworkSettings = Field(default_factory=NetworkSettings)
    sim: SimSettings = Field(default_factory=SimSettings)

    @field_validator("uri")
    @classmethod
    def _not_blank(cls, v: str | None) -> str | None:
        if v is not None and not v.strip():
            raise ValueError("must not be empty")
        return v


class CameraConfig(_Section):
    """Identity, intrinsics and (optional) geodetic pose of the camera."""

    id: str = Field("cam0", description="camera id: Zenoh key segment and MCAP frame ids")
    calibration: FilePath | None = Field(
        None, description="OpenCV calibration YAML; null: the file's sidecar, the sim preset's camera"
    )
    geo: str | None = Field(None, description="LAT,LON,ALT_M[,YAW,PITCH,ROLL] (degrees, metres)")

    @field_validator("id")
    @classmethod
    def _id_chars(cls, v: str) -> str:
        if not _CAMERA_ID.match(v):
            raise ValueError("must be 1-64 characters of A-Z a-z 0-9 _ - . (it is a Zenoh key segment)")
        return v

    @field_validator("geo")
    @classmethod
    def _geo_parses(cls, v: str | None) -> str | None:
        if v is not None:
            try:
                CameraGeo.parse(v)
            except GeoError as exc:
                raise ValueError(str(exc)) from None
        return v

    def camera_geo(self) -> CameraGeo | None:
        """The parsed geodetic pose, or None when not configured."""
        return CameraGeo.parse(self.geo) if self.geo is not None else None


class ModelConfig(_Section):
    """The keypoint network and the drone it looks for."""

    path: FilePath | None = Field(None, description="ONNX model; null: the model shipped with the package")
    drone: str = Field("mini2", description="drone spec name (mini2, air2s) or a spec YAML path")
    threads: int = Field(
        1, ge=1, le=256, description="ONNX Runtime intra-op threads; 1 leaves the other cores to decoding"
    )
    mirror_average: bool = Field(
        True,
        description="also run each crop mirrored and average (a fifth less keypoint error, ~1.6x inference)",
    )

    @field_validator("drone")
    @classmethod
    def _known_drone(cls, v: str) -> str:
        from dronekey.geometry.drone_spec import available_specs

        if v.endswith((".yaml", ".yml")):
            if not Path(v).is_file():
                raise ValueError("drone spec file not found")
            return v
        names = available_specs()
        if v not in names:
            raise ValueError(f"unknown drone; allowed: {', '.join(names)} or a spec .yaml path")
        return v


class ZenohTlsConfig(_Section):
    """This sensor's TLS identity for ``tls/`` endpoints, with mutual authentication (docs/security.md)."""

    root_ca: FilePath = Field(description="PEM certificate of the fleet CA, which signed the other end")
    certificate: FilePath = Field(description="PEM certificate from that CA; its common name is our identity")
    private_key: FilePath = Field(description="PEM private key of the certificate (daemon-only readable)")
    verify_name_on_connect: bool = Field(True, description="the router's certificate must name its host")

    @field_validator("root_ca", "certificate")
    @classmethod
    def _pem_certificate(cls, v: Path) -> Path:
        return _pem_file(v, "-----BEGIN CERTIFICATE-----", "a PEM certificate")

    @field_validator("private_key")
    @classmethod
    def _pem_key(cls, v: Path) -> Path:
        return _pem_file(v, "PRIVATE KEY-----", "a PEM private key")


def _pem_file(path: Path, marker: str, what: str) -> Path:
    try:
        with open(path, "rb") as f:
            head = f.read(65536)
    except OSError as exc:
        raise ValueError(f"cannot read it: {exc.strerror}") from None
    if marker.encode() not in head:
        raise ValueError(f"must be {what} (no {marker!r} in its first 64 KiB)")
    return path


class ZenohConfig(_Section):
    """Zenoh session (docs/design.md §6.1); on its defaults reachable from this machine only."""

    enabled: bool = True
    mode: Literal["peer", "client"] = "peer"
    connect: list[str] = Field(default_factory=list, description="endpoints, e.g. tls/192.168.1.10:7447")
    listen: list[str] = Field(
        None,  # resolved by _default_listen
        validate_default=True,
        description="endpoints; null: tcp/127.0.0.1:0 for a peer (this machine only), none for a client; "
        "e.g. tcp/0.0.0.0:7447 opens the session to the network",
    )
    scouting: bool = Field(
        False, description="multicast and gossip scouting: makes the session discoverable on the network"
    )
    tls: ZenohTlsConfig | None = Field(None, description="TLS identity (mutual authentication); null: none")

    @field_validator("listen", mode="before")
    @classmethod
    def _default_listen(cls, v: Any, info: ValidationInfo) -> Any:
        if v is None:
            return ["tcp/127.0.0.1:0"] if info.data.get("mode", "peer") == "peer" else []
        return v

    @field_validator("connect", "listen")
    @classmethod
    def _endpoints(cls, v: list[str]) -> list[str]:
        for ep in v:
            if not _ZENOH_ENDPOINT.match(ep):
                raise ValueError(f"endpoint {ep!r} must look like tcp/HOST:PORT, tls/HOST:PORT or udp/...")
        return v


class MavlinkConfig(_Section):
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
        from dronekey.daemon.sinks.mavlink.link import validate_url  # no pymavlink import

        return validate_url(v)  # also spells out 127.0.0.1 for a listening URL without a host

    @field_validator("allow")
    @classmethod
    def _allow(cls, v: list[str]) -> list[str]:
        from dronekey.daemon.sinks.mavlink.peers import parse_allow_entry

        for entry in v:
            parse_allow_entry(entry)
        return v


class Sbs1Config(_Section):
    """SBS-1 (BaseStation) TCP output; needs camera.geo.

    A port without a host binds 127.0.0.1 and is stored as ``127.0.0.1:PORT``, so ``--print-config``
    names the address; serving the network takes an explicit host (``0.0.0.0:30003``).
    """

    listen: str | None = Field(
        None, description="PORT or :PORT (127.0.0.1), or HOST:PORT, e.g. 30003; 0.0.0.0:30003: the network"
    )
    idle_timeout_s: Seconds = Field(
        10.0, description="disconnect a client that accepts no data for this long while data waits for it"
    )

    @field_validator("listen", mode="before")
    @classmethod
    def _host_port(cls, v: Any) -> Any:
        if v is None:
            return v
        text = str(v).strip() if isinstance(v, int | str) and not isinstance(v, bool) else v
        if isinstance(text, str) and text.isdigit():
            text = f":{text}"
        m = _HOST_PORT.match(text) if isinstance(text, str) else None
        if not m or not 0 <= int(m["port"]) < 65536:
            raise ValueError(
                "must be PORT, :PORT (127.0.0.1) or HOST:PORT with a port in 0-65535 (0: any free port), "
                "e.g. 30003 or 0.0.0.0:30003"
            )
        return text if m["host"] else f"127.0.0.1:{int(m['port'])}"


class McapConfig(_Section):
    """MCAP log (docs/design.md §6.3); the keys are ``McapSink``'s parameters."""

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


class SinksConfig(_Section):
    """Settings shared by every output."""

    queue_size: int = Field(64, ge=1, le=100000, description="updates queued per output (drop oldest)")


class LogConfig(_Section):
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


class DaemonConfig(_Section):
    """Everything ``dronekey-daemon`` can be told; each section is documented in ``docs/daemon.md``."""

    source: SourceConfig = Field(default_factory=SourceConfig)
    camera: CameraConfig = Field(default_factory=CameraConfig)
    model: ModelConfig = Field(default_factory=ModelConfig)
    zenoh: ZenohConfig = Field(default_factory=ZenohConfig)
    mavlink: MavlinkConfig = Field(default_factory=MavlinkConfig)
    sbs1: Sbs1Config = Field(default_factory=Sbs1Config)
    mcap: McapConfig = Field(default_factory=McapConfig)
    sinks: SinksConfig = Field(default_factory=SinksConfig)
    log: LogConfig = Field(default_factory=LogConfig)


# ---------------------------------------------------------------------------------------- loading
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
    if config.sbs1.listen is not None and config.camera.geo is None:
        flag = overrides.get("sbs1.listen", (None, None))[1]
        source = f" (from {flag})" if flag else ""
        raise ConfigError(
            f"config error: sbs1.listen = {_short_repr(config.sbs1.listen)}{source}: the SBS-1 output needs "
            "camera.geo (--camera-geo LAT,LON,ALT_M,YAW,PITCH,ROLL)"
        )
    if config.mcap.dir is None:
        config.mcap.dir = _default_mcap_dir()
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
        raise ConfigError(f"config error: cannot read {path}: {_clip(str(exc))}") from None
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
        raise ConfigError(f"config error: {path}{where}: invalid YAML: {_clip(problem)}") from None
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
                problem=f"YAML anchors and aliases ({mark}{_clip(anchor, 20)}) are not allowed in a "
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
                    f"config error: {_dotted((*loc, key))}: duplicate key (in {path} line {line}; "
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
    "zenoh.tls.root_ca",
    "zenoh.tls.certificate",
    "zenoh.tls.private_key",
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


def _default_mcap_dir() -> Path:
    state = os.environ.get("STATE_DIRECTORY")  # set by systemd's StateDirectory=
    if state:
        return Path(state.split(":")[0]) / "mcap"
    return Path("mcap").absolute()


# ---------------------------------------------------------------------------------------- errors
def format_validation_error(
    exc: ValidationError, origin: dict[str, str] | None = None, path: Path | None = None
) -> str:
    """One line per problem: ``config error: <key> = <value> (from <flag or file>): <what is allowed>``.

    Values are cut before they are formatted (``_short_repr``), so a huge value costs nothing; at
    most ``_MAX_ERROR_LINES`` problems are listed and the rest counted.
    """
    origin = origin or {}
    lines = []
    errors = exc.errors(include_url=False)
    for err in errors[:_MAX_ERROR_LINES]:
        loc = tuple(str(p) for p in err["loc"])
        dotted = _dotted(loc)
        field_key = ".".join(p for p in loc if not p.isdigit())
        source = f" (from {origin[field_key]})" if field_key in origin else (f" (in {path})" if path else "")
        if err["type"] == "extra_forbidden":
            allowed = ", ".join(_allowed_keys(loc[:-1]))
            lines.append(f"config error: {dotted}: unknown key{source}; allowed keys here: {allowed}")
            continue
        msg = err["msg"]
        if err["type"] == "value_error":
            msg = msg.removeprefix("Value error, ")
        msg = _clip(msg[:1].lower() + msg[1:], 200)
        lines.append(f"config error: {dotted} = {_short_repr(err.get('input'))}{source}: {msg}")
    if len(errors) > _MAX_ERROR_LINES:
        lines.append(f"config error: and {len(errors) - _MAX_ERROR_LINES} more problems")
    return "\n".join(lines)


def _dotted(loc: tuple[str, ...]) -> str:
    out = ""
    for part in loc:
        part = _clip(part, 40)
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


def _short_repr(value: Any, limit: int = 60) -> str:
    """``repr(value)`` in at most ``limit`` characters, bounded while it is built."""
    return _clip(_REPR.repr(value), limit)


def _clip(text: str, limit: int = 200) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def config_to_yaml(config: DaemonConfig) -> str:
    """The effective configuration as YAML (what ``--print-config`` prints); loads back unchanged."""
    return yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False, default_flow_style=False)
