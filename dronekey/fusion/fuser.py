"""Fused tracks over time: several cameras' tracks of one drone under one stable fused id.

``Fuser.update`` keeps each camera's latest track state (a ``lost`` track is forgotten);
``Fuser.fuse(t_ns)`` predicts every camera's track to ``t_ns`` (``observation``), keeps the
bindings of the existing fused tracks that still pass the gates (with hysteresis, so an id does not
flap), binds the free tracks camera by camera with the Hungarian algorithm
(``scipy.optimize.linear_sum_assignment``) on the gated cost (``association``), merges fused tracks
that turn out to be one drone (the older id stays), and estimates each fused track
(``estimate``). A fused track lives while one of its cameras' tracks does; its last message has
status ``lost``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import linear_sum_assignment

from dronekey.fusion.association import pair_cost
from dronekey.fusion.camera_pose import CameraPose
from dronekey.fusion.config import FusionConfig
from dronekey.fusion.estimate import fuse_observations
from dronekey.fusion.observation import Observation, observe
from dronekey.types import PUBLISHED_STATUSES, Track, TrackStatus

__all__ = ["FusedMember", "FusedTrack", "Fuser"]

_NO_MATCH = 1e12  # the cost matrix's stand-in for a gated-out pair


@dataclass(frozen=True)
class FusedMember:
    """One camera's track in a fused track: its time on the fusion's clock and range (m)."""

    camera_id: str
    track_id: int
    t_ns: int
    status: TrackStatus
    range_m: float


@dataclass(frozen=True)
class FusedTrack:
    """A fused track at ``t_ns``, site frame (metres, seconds; quaternion body FRD -> site).

    method : ``triangulated`` (two or more cameras) or ``single`` (one camera's position; its depth
        leans on the last triangulated one for ``FusionConfig.depth_memory_s``).
    members : the cameras' tracks fused this time (empty on the ``lost`` message).
    """

    fused_id: int
    t_ns: int
    status: TrackStatus
    position_m: np.ndarray
    velocity_mps: np.ndarray
    position_cov: np.ndarray
    quaternion_wxyz: np.ndarray
    rotation_std_rad: np.ndarray
    heading_confidence: float
    score: float
    hits: int
    age_s: float
    method: str
    members: tuple[FusedMember, ...]


@dataclass
class _Cluster:
    fused_id: int
    first_t_ns: int
    bound: list[tuple[str, int]] = field(default_factory=list)  # oldest binding first
    hits: int = 0
    last: FusedTrack | None = None
    last_triangulated: FusedTrack | None = None

    def cameras(self) -> set[str]:
        return {camera for camera, _ in self.bound}


class Fuser:
    """Fuses the tracks of several cameras whose poses in one site frame are known.

    Parameters
    ----------
    poses : mapping camera id -> CameraPose, optional (``set_pose`` adds or replaces one).
    config : FusionConfig, optional.
    """

    def __init__(self, poses: Mapping[str, CameraPose] | None = None, config: FusionConfig | None = None):
        self.config = config if config is not None else FusionConfig()
        self._poses: dict[str, CameraPose] = dict(poses or {})
        self._latest: dict[tuple[str, int], tuple[Track, int]] = {}
        self._clusters: list[_Cluster] = []
        self._next_id = 1

    # ------------------------------------------------------------------ inputs
    def set_pose(self, camera_id: str, pose: CameraPose) -> None:
        """The pose of ``camera_id`` in the site frame."""
        self._poses[camera_id] = pose

    @property
    def cameras(self) -> tuple[str, ...]:
        """The cameras whose poses are known."""
        return tuple(sorted(self._poses))

    def update(self, camera_id: str, track: Track, t_ns: int | None = None) -> None:
        """Record the latest state of one camera's track; ``t_ns`` is its time on the fusion's clock
        (default ``track.t_ns``). A ``lost`` track is forgotten."""
        key = (camera_id, int(track.track_id))
        if TrackStatus(track.status) == TrackStatus.LOST:
            self._latest.pop(key, None)
            return
        self._latest[key] = (track, int(track.t_ns if t_ns is None else t_ns))

    def latest_t_ns(self) -> int | None:
        """The newest track time received (fusion clock), or None before any."""
        return max((t for _, t in self._latest.values()), default=None)

    # ------------------------------------------------------------------ one fusion step
    def fuse(self, t_ns: int) -> list[FusedTrack]:
        """The fused tracks at ``t_ns`` (fusion clock), plus a ``lost`` message for each fused track
        that ended since the last call."""
        t_ns = int(t_ns)
        self._forget_expired(t_ns)
        observations = self._observations(t_ns)
        ended = self._drop_gone_members()
        self._validate_bindings(observations)
        self._bind_free(observations, t_ns)
        ended += self._merge(observations)
        out = [replace(c.last, status=TrackStatus.LOST, t_ns=t_ns, members=()) for c in ended if c.last]
        for cluster in self._clusters:
            current = [observations[k] for k in cluster.bound if k in observations]
            if current:
                out.append(self._estimate(cluster, current, t_ns))
        return out

    def _forget_expired(self, t_ns: int) -> None:
        expiry_ns = self.config.track_expiry_s * 1e9
        for key, (_, own_t) in list(self._latest.items()):
            if t_ns - own_t > expiry_ns:
                del self._latest[key]

    def _observations(self, t_ns: int) -> dict[tuple[str, int], Observation]:
        allowed = set(PUBLISHED_STATUSES)
        if self.config.include_tentative:
            allowed.add(TrackStatus.TENTATIVE)
        out = {}
        for (camera_id, _), (track, own_t) in self._latest.items():
            pose = self._poses.get(camera_id)
            if pose is None or TrackStatus(track.status) not in allowed:
                continue
            o = observe(track, camera_id, pose, t_ns, self.config, track_t_ns=own_t)
            if o is not None:
                out[o.key] = o
        return out

    def _drop_gone_members(self) -> list[_Cluster]:
        ended = []
        for cluster in self._clusters:
            cluster.bound = [k for k in cluster.bound if k in self._latest]
            if not cluster.bound:
                ended.append(cluster)
        self._clusters = [c for c in self._clusters if c.bound]
        return ended

    def _validate_bindings(self, observations: Mapping[tuple[str, int], Observation]) -> None:
        """Release, newest binding first, members that no longer match the others."""
        scale = self.config.keep_scale
        for cluster in self._clusters:
            for key in reversed(list(cluster.bound)):
                others = [observations[k] for k in cluster.bound if k != key and k in observations]
                if key not in observations or not others:
                    continue
                if any(math.isinf(pair_cost(observations[key], o, self.config, scale)) for o in others):
                    cluster.bound.remove(key)
        self._clusters = [c for c in self._clusters if c.bound]

    def _cost(self, o: Observation, cluster: _Cluster, observations: Mapping) -> float:
        current = [observations[k] for k in cluster.bound if k in observations]
        if not current or o.camera_id in cluster.cameras():
            return math.inf
        costs = [pair_cost(o, c, self.config) for c in current]
        return math.inf if any(math.isinf(c) for c in costs) else float(np.mean(costs))

    def _bind_free(self, observations: Mapping[tuple[str, int], Observation], t_ns: int) -> None:
        bound = {k for c in self._clusters for k in c.bound}
        free = [k for k in observations if k not in bound]
        for camera_id in sorted({camera for camera, _ in free}):
            mine = sorted(k for k in free if k[0] == camera_id)
            clusters = list(self._clusters)
            matched: set[tuple[str, int]] = set()
            if clusters:
                cost = np.array(
                    [[self._cost(observations[k], c, observations) for c in clusters] for k in mine]
                )
                rows, cols = linear_sum_assignment(np.where(np.isinf(cost), _NO_MATCH, cost))
                for r, c in zip(rows, cols, strict=True):
                    if np.isfinite(cost[r, c]):
                        clusters[c].bound.append(mine[r])
                        matched.add(mine[r])
            for key in mine:
                if key not in matched:
                    self._clusters.append(_Cluster(self._next_id, t_ns, [key]))
                    self._next_id += 1

    def _merge(self, observations: Mapping[tuple[str, int], Observation]) -> list[_Cluster]:
        """Merge fused tracks of disjoint cameras whose observations all match (the older id stays)."""
        ended = []
        merged = True
        while merged:
            merged = False
            for a, b in itertools.combinations(sorted(self._clusters, key=lambda c: c.fused_id), 2):
                if a.cameras() & b.cameras():
                    continue
                obs_a = [observations[k] for k in a.bound if k in observations]
                obs_b = [observations[k] for k in b.bound if k in observations]
                if not obs_a or not obs_b:
                    continue
                if all(math.isfinite(pair_cost(x, y, self.config)) for x in obs_a for y in obs_b):
                    a.bound += b.bound
                    a.hits = max(a.hits, b.hits)
                    self._clusters.remove(b)
                    ended.append(b)
                    merged = True
                    break
        return ended

    def _depth_memory(self, cluster: _Cluster, t_ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The cluster's last triangulated position predicted to ``t_ns`` with its covariance
        grown by the velocity's uncertainty, while it is at most ``depth_memory_s`` old."""
        last = cluster.last_triangulated
        if last is None:
            return None
        dt = (t_ns - last.t_ns) * 1e-9
        if not 0 <= dt <= self.config.depth_memory_s:
            return None
        grown = last.position_cov + np.eye(3) * (self.config.velocity_std_mps * dt) ** 2
        return last.position_m + last.velocity_mps * dt, grown

    def _estimate(self, cluster: _Cluster, current: list[Observation], t_ns: int) -> FusedTrack:
        prior = self._depth_memory(cluster, t_ns) if len(current) == 1 else None
        state = fuse_observations(current, prior)
        statuses = {o.status for o in current}
        if TrackStatus.CONFIRMED in statuses:
            status = TrackStatus.CONFIRMED
        elif TrackStatus.COASTING in statuses:
            status = TrackStatus.COASTING
        else:
            status = TrackStatus.TENTATIVE
        cluster.hits += 1
        members = tuple(
            FusedMember(o.camera_id, o.track_id, o.track_t_ns, o.status, o.range_m)
            for o in sorted(current, key=lambda o: o.key)
        )
        fused = FusedTrack(
            fused_id=cluster.fused_id,
            t_ns=t_ns,
            status=status,
            position_m=state.position_m,
            velocity_mps=state.velocity_mps,
            position_cov=state.position_cov,
            quaternion_wxyz=state.quaternion_wxyz,
            rotation_std_rad=state.rotation_std_rad,
            heading_confidence=state.heading_confidence,
            score=max(o.score for o in current),
            hits=cluster.hits,
            age_s=(t_ns - cluster.first_t_ns) * 1e-9,
            method="triangulated" if len(current) > 1 else "single",
            members=members,
        )
        cluster.last = fused
        if fused.method == "triangulated":
            cluster.last_triangulated = fused
        return fused
