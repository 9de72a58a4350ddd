"""``sim://<preset>``: a simulator sequence rendered on the fly: ``sim_replay.synthetic_sequence`` for
the single-drone presets, the first camera of ``sim_replay.scene.build_scene`` for the multi-drone
ones (``sim://swarm``: its default three drones, crossing, one passing in front of another)."""

from __future__ import annotations

import logging

from dronekey.daemon.config.source import SimSettings
from dronekey.daemon.sources.base import FrameReader, ReadResult, SourceOpenError, valid_bgr
from dronekey.geometry.camera import CameraModel

__all__ = ["SimReader"]

log = logging.getLogger(__name__)


class SimReader(FrameReader):
    """Renders the preset's frames in order; its camera is the preset's camera."""

    live = False
    kind = "sim"

    def __init__(self, preset: str, settings: SimSettings) -> None:
        self.preset = preset
        self.description = f"sim://{preset}"
        self._settings = settings
        self._sequence = None
        self._frames = None

    def _build(self):
        try:
            from dronekey.sim_replay.presets import PRESETS
            from dronekey.sim_replay.scene import build_scene
            from dronekey.sim_replay.synthetic_sequence import build_sequence
        except ImportError as exc:
            raise SourceOpenError(f"sim:// sources need dronekey.sim_replay: {exc}") from None
        seed, frames = self._settings.seed, self._settings.frames
        try:
            preset = PRESETS.get(self.preset)
            if preset is not None and preset.multi_drone:
                return build_scene(self.preset, seed=seed, frames=frames).views[0]
            return build_sequence(self.preset, seed=seed, frames=frames)
        except (KeyError, ValueError) as exc:
            message = exc.args[0] if exc.args else str(exc)
            raise SourceOpenError(f"sim://{self.preset}: {message}") from None

    def open(self) -> None:
        if self._sequence is None:
            self._sequence = self._build()
        self._frames = iter(self._sequence)

    @property
    def frame_rate(self) -> float | None:
        fps = getattr(self._sequence, "fps", None)
        return float(fps) if fps else None

    @property
    def resolution(self) -> tuple[int, int] | None:
        if self._sequence is None:
            return None
        camera = self._sequence.camera
        return camera.width, camera.height

    def read(self) -> ReadResult:
        if self._frames is None:
            raise RuntimeError("read() before open()")
        corrupt = 0
        for rendered in self._frames:
            if valid_bgr(rendered.image):
                return ReadResult(rendered.image, int(rendered.record.t_ns), corrupt=corrupt)
            corrupt += 1
        return ReadResult(corrupt=corrupt, ended=True)

    def close(self) -> None:
        self._frames = None

    def bundled_camera(self) -> tuple[CameraModel, str] | None:
        if self._sequence is None:
            self._sequence = self._build()
        return self._sequence.camera, f"the camera of the sim://{self.preset} preset"
