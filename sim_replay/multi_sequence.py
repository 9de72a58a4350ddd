"""Render several drones through one camera of a rig, with each drone's ground truth, per seed.

The scene frame is local North-East-Down at the first camera (``sim_replay.scene`` builds the
drones' paths and the cameras' poses in it). Every frame draws the drones far to near, so a nearer
drone covers a farther one, and a keypoint is flagged hidden when its line of sight passes through
an opaque part of its own drone or of any nearer one (exact segment / convex-part tests, as
``renderer`` does for one drone). Each annotation carries its drone's ``instance_id``.

The first camera draws its background, lighting and noise from the scene seed's main stream as a
single-camera sequence does; camera k from the stream ``(seed, k)``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np

from dronekey.geometry.camera import CameraModel
from dronekey.geometry.drone_spec import DroneSpec
from dronekey.sim_replay.annotations import HIDDEN, DroneAnnotation, DroneInstance, FrameRecord
from dronekey.sim_replay.backgrounds import BackgroundSource
from dronekey.sim_replay.drone_look import DroneLook
from dronekey.sim_replay.effects import sensor_noise
from dronekey.sim_replay.mesh import PROP, DroneMesh, build_mesh, segment_hits
from dronekey.sim_replay.presets import Preset
from dronekey.sim_replay.renderer import Lighting, render_drone
from dronekey.sim_replay.synthetic_sequence import RenderedFrame, SequenceConditions, sequence_info

__all__ = ["MultiDroneSequence", "SceneDrone", "ViewPose"]


@dataclass(frozen=True)
class SceneDrone:
    """One drone of the scene, its look and where it is in every frame (scene NED, metres).

    positions_ned : (N, 3) at the frame times; positions_later_ned : (N, 3) half a frame later
    (the motion-blur streak); R_ned_body : (N, 3, 3) body (FRD) -> NED.
    """

    instance_id: int
    spec: DroneSpec
    look: DroneLook
    style_seed: int
    positions_ned: np.ndarray
    positions_later_ned: np.ndarray
    R_ned_body: np.ndarray


@dataclass(frozen=True)
class ViewPose:
    """A camera of the rig in the scene frame: ``p_cam = R_cam_ned @ (p_ned - position_ned)``."""

    camera_id: str
    R_cam_ned: np.ndarray
    position_ned: np.ndarray

    def to_camera(self, p_ned: np.ndarray) -> np.ndarray:
        """Scene NED points (..., 3) -> this camera's frame (OpenCV), metres."""
        return (np.asarray(p_ned) - self.position_ned) @ self.R_cam_ned.T


def _hidden_behind(
    kp_cam: np.ndarray, mesh: DroneMesh, R: np.ndarray, t: np.ndarray, flags: np.ndarray
) -> np.ndarray:
    """``flags`` with the keypoints (camera frame) whose line of sight crosses ``mesh`` at (R, t) hidden."""
    out = flags.copy()
    eye = -R.T @ t  # the camera centre in the occluder's body frame
    for i, p in enumerate(kp_cam):
        if out[i] == HIDDEN:
            continue
        hub = R.T @ (p - t)
        if any(segment_hits(part, eye, hub) for part in mesh.parts if part.kind != PROP):
            out[i] = HIDDEN
    return out


class MultiDroneSequence:
    """The drones of a scene seen by one camera of the rig; iterate for ``RenderedFrame`` objects.

    Quacks like ``SyntheticSequence`` for ``io.render_output.write_sequence`` (``name``, ``camera``,
    ``spec``, ``fps``, ``n_frames``, ``info``) and adds ``instances`` for the JSON's table.
    """

    def __init__(
        self,
        preset: Preset,
        seed: int,
        camera: CameraModel,
        view: ViewPose,
        view_index: int,
        drones: list[SceneDrone],
        backgrounds: BackgroundSource,
        conditions: SequenceConditions,
    ) -> None:
        if not drones:
            raise ValueError("a scene needs at least one drone")
        self.preset = preset
        self.name = preset.name
        self.seed = seed
        self.camera = camera
        self.view = view
        self.view_index = view_index
        self.drones = sorted(drones, key=lambda d: d.instance_id)
        self.n_frames = len(self.drones[0].positions_ned)
        self.fps = preset.fps
        self.spec = self.drones[0].spec
        self.conditions = conditions
        self._backgrounds = backgrounds

    @property
    def instances(self) -> tuple[DroneInstance, ...]:
        """The JSON's ``instances`` table; empty with one drone (the file stays single-drone)."""
        if len(self.drones) == 1:
            return ()
        return tuple(
            DroneInstance(d.instance_id, d.spec.name, np.asarray(d.spec.keypoints_3d, dtype=np.float64))
            for d in self.drones
        )

    @property
    def info(self) -> dict:
        """The JSON's ``info`` (docs/design.md §5.1): the conditions, the camera and every drone."""
        return {
            **sequence_info(self.name, self.seed, self.preset, self.conditions, self.drones[0].look),
            "camera_id": self.view.camera_id,
            "drones": [
                {
                    "instance_id": d.instance_id,
                    "drone_model": d.spec.name,
                    "style_seed": d.style_seed,
                    "leds_lit": bool(d.look.leds_lit),
                    "led_blink_hz": d.look.blink_hz,
                }
                for d in self.drones
            ],
        }

    def __len__(self) -> int:
        return self.n_frames

    def ground_truth_cam(self, i: int) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """``(instance_id, R body->camera, t metres)`` of every drone in frame ``i``, in or out of view."""
        R_cn = self.view.R_cam_ned
        return [
            (d.instance_id, R_cn @ d.R_ned_body[i], self.view.to_camera(d.positions_ned[i]))
            for d in self.drones
        ]

    def __iter__(self) -> Iterator[RenderedFrame]:
        rng = np.random.default_rng(self.seed if self.view_index == 0 else (self.seed, self.view_index))
        w, h = self.camera.size
        background = self._backgrounds.draw(h, w, rng)
        lighting = Lighting.random(rng)
        noise_sigma = float(rng.uniform(1.0, 3.0))
        meshes = [build_mesh(d.spec, d.look.shape) for d in self.drones]
        for i in range(self.n_frames):
            t_s = i / self.fps
            img = background.copy()
            poses = self.ground_truth_cam(i)
            far_to_near = sorted(range(len(self.drones)), key=lambda k: -poses[k][2][2])
            drawn: list[tuple[int, DroneAnnotation]] = []
            for k in far_to_near:
                drone, (instance_id, R, t) = self.drones[k], poses[k]
                later = self.view.to_camera(drone.positions_later_ned[i])
                c0, c1 = self.camera.project(np.vstack([t, later]))
                ann = render_drone(
                    img, self.camera, meshes[k], R, t, drone.look.style_at(t_s), lighting, tuple(c1 - c0)
                )
                if ann is not None:
                    drawn.append((k, replace(ann, instance_id=instance_id)))
            annotations = []
            for k, ann in drawn:
                kp_cam = meshes[k].keypoints @ ann.rotation.T + ann.translation
                flags = ann.visibility
                for j, (_, R_j, t_j) in enumerate(poses):
                    if j != k and t_j[2] < ann.translation[2]:
                        flags = _hidden_behind(kp_cam, meshes[j], R_j, t_j, flags)
                annotations.append(replace(ann, visibility=flags))
            img = sensor_noise(img, rng, sigma=noise_sigma)
            yield RenderedFrame(img, FrameRecord.with_drones(i, round(t_s * 1e9), "", w, h, annotations))
