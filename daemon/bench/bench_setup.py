"""What a benchmark run is about: the video, and the daemon settings a benchmark may override."""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

from dronekey.daemon.bench.errors import BenchError
from dronekey.daemon.config.daemon_config import DaemonConfig
from dronekey.daemon.config.errors import ConfigError
from dronekey.daemon.config.loading import load_config
from dronekey.perception.keypoint_model import default_model_path

__all__ = ["BenchSetup"]


@dataclass(frozen=True)
class BenchSetup:
    """What a benchmark run is about: the source and the daemon settings it may override.

    source : video file (looped). calib, model : files (default: beside the video, the shipped
    model). decode_threads, model_threads : override ``source.decode_threads`` and ``model.threads``.
    front_back : False turns ``model.front_back`` off (the front/back classifier's cost, measured).
    mirror_average : False turns ``model.mirror_average`` off (each crop once, not with its mirror:
        what the averaging costs on a box, measured).
    front_back_path : another front/back classifier (``model.front_back_path``): what it costs.
    measure_every : overrides ``tracking.measure_every`` (the measurement stride) when set.
    late_after_ms : overrides ``tracking.late_after_ms`` (frames taken late are predicted) when set.
    decode_ahead : True sets ``source.realtime_decode_ahead``: paced frames decoded before they are
        due, their decode not in the latency (every paced figure before the thirty-third session).
    """

    source: Path
    calib: Path | None = None
    model: Path | None = None
    decode_threads: int | None = None
    model_threads: int | None = None
    front_back: bool = True
    mirror_average: bool = True
    front_back_path: Path | None = None
    measure_every: int | None = None
    decode_ahead: bool = False
    late_after_ms: float | None = None

    def to_json(self) -> dict:
        """Every field as a JSON value (paths as strings), for a worker process (``from_json``)."""
        return {f.name: _json_value(getattr(self, f.name)) for f in fields(self)}

    @classmethod
    def from_json(cls, data: dict) -> BenchSetup:
        """The setup ``to_json`` wrote."""
        paths = {f.name for f in fields(cls) if "Path" in str(f.type)}
        return cls(**{k: Path(v) if k in paths and v is not None else v for k, v in data.items()})

    def check(self) -> None:
        """Raise ``BenchError`` naming the first missing input file."""
        if not self.source.is_file():
            raise BenchError(f"--source: no such file: {self.source}")
        if self.calib is not None and not self.calib.is_file():
            raise BenchError(f"--calib: no such file: {self.calib}")
        if self.model is not None and not self.model.is_file():
            raise BenchError(f"--model: no such file: {self.model}")
        if self.front_back_path is not None and not self.front_back_path.is_file():
            raise BenchError(f"--front-back: no such file: {self.front_back_path}")
        if self.model is None and not default_model_path().is_file():
            raise BenchError(
                f"the shipped model {default_model_path()} is not built yet; pass --model FILE "
                "(an ONNX file written by dronekey-export)"
            )

    def config(
        self,
        frames: int,
        outputs: tuple[Path, int] | None = None,
        realtime: bool = False,
        realtime_phase: float | None = None,
    ) -> DaemonConfig:
        """The daemon configuration: defaults, the source looping and stopping after ``frames``
        (paced at its frame rate with ``realtime``, in ``source.realtime_phase``) and, with
        ``outputs = (mcap_dir, udp_port)``, every output on with local endpoints (else every output
        off)."""
        overrides = {
            "source.uri": (str(self.source), "--source"),
            "source.loop": (True, "loop"),
            "source.realtime": (realtime, "realtime"),
            "source.realtime_phase": (realtime_phase, "--phase"),
            "source.max_frames": (frames, "--frames"),
            "log.level": ("WARNING", "log"),
        }
        optional = {
            "camera.calibration": (self.calib, "--calib"),
            "model.path": (self.model, "--model"),
            "source.decode_threads": (self.decode_threads, "--decode-threads"),
            "model.threads": (self.model_threads, "--model-threads"),
            "model.front_back_path": (self.front_back_path, "--front-back"),
            "tracking.measure_every": (self.measure_every, "--measure-every"),
            "tracking.late_after_ms": (self.late_after_ms, "--late-after"),
        }
        overrides.update(
            {key: (str(v) if isinstance(v, Path) else v, flag) for key, (v, flag) in optional.items() if v}
        )
        if not self.front_back:
            overrides["model.front_back"] = (False, "--no-front-back")
        if not self.mirror_average:
            overrides["model.mirror_average"] = (False, "--no-mirror-average")
        if self.decode_ahead:
            overrides["source.realtime_decode_ahead"] = (True, "--decode-ahead")
        if outputs is not None:
            mcap_dir, udp_port = outputs
            overrides.update(
                {
                    "zenoh.mode": ("peer", "zenoh"),
                    "zenoh.scouting": (False, "zenoh"),
                    "zenoh.listen": (["tcp/127.0.0.1:0"], "zenoh"),
                    "mavlink.url": (f"udpout:127.0.0.1:{udp_port}", "mavlink"),
                    "mcap.dir": (str(mcap_dir), "mcap"),
                }
            )
        for output in ("zenoh", "mavlink", "mcap"):
            overrides[f"{output}.enabled"] = (outputs is not None, output)
        try:
            return load_config(None, overrides)
        except ConfigError as exc:
            raise BenchError(str(exc).splitlines()[0]) from None


def _json_value(value: object) -> object:
    return str(value) if isinstance(value, Path) else value
