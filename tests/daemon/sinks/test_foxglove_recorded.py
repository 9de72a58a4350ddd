"""A real recording, checked message by message against Foxglove's published schemas.

``dronekey-daemon`` tracks a rendered sequence (``sim://seq13``, the real pipeline) with the camera
placed on the Earth; every message on the Foxglove topics of the MCAP file it writes, read back with
the ``mcap`` reader, must decode with Foxglove's published protobuf classes (foxglove-schemas-protobuf)
and each channel's schema must be the published one. The map and 3D messages are checked for sense.
"""

from __future__ import annotations

import collections
import json
import subprocess
import sys

import numpy as np
import pytest
from foxglove_checks import decode, schema_matches_published
from mcap.reader import make_reader

from dronekey.daemon.geo import CameraGeo

GEO = "51.5,-0.12,30,90,5,0"  # looking east, 5 degrees up


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    folder = tmp_path_factory.mktemp("mcap")
    command = [sys.executable, "-m", "dronekey.daemon.cli", "--source", "sim://seq13", "--max-frames", "45"]
    command += ["--camera-geo", GEO, "--mcap-dir", str(folder), "--no-zenoh", "--no-mavlink"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=240)
    assert result.returncode == 0, result.stderr[-2000:]
    (path,) = sorted(folder.glob("dronekey_cam0_*.mcap"))
    by_topic = collections.defaultdict(list)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        for schema in summary.schemas.values():
            if schema.encoding == "protobuf":
                assert schema_matches_published(schema.name, schema.data) == [], schema.name
        for schema, channel, message in reader.iter_messages():
            by_topic[channel.topic].append(
                (schema.name, decode(schema.name, channel.message_encoding, message.data))
            )
    return by_topic


def test_every_foxglove_message_is_valid_under_the_published_schemas(recording):
    foxglove_topics = {t: items for t, items in recording.items() if items[0][0].startswith("foxglove.")}
    counts = {topic: len(items) for topic, items in sorted(foxglove_topics.items())}
    total = sum(counts.values())
    print(f"\n{total} messages on the Foxglove topics decoded with the published schemas: {counts}")
    assert set(counts) == {
        "/camera/image", "/camera/calibration", "/dronekey/annotations", "/tf", "/dronekey/scene",
        "/camera/fix", "/camera/fov", "/dronekey/fix",
    }  # fmt: skip
    assert counts["/dronekey/annotations"] == 45 and counts["/dronekey/fix"] > 0 and counts["/tf"] > 0


def test_the_map_shows_the_camera_its_view_and_the_track(recording):
    geo = CameraGeo.parse(GEO)
    (_, camera_fix) = recording["/camera/fix"][0]
    assert (camera_fix.latitude, camera_fix.longitude, camera_fix.altitude) == (51.5, -0.12, 30.0)
    (_, fov) = recording["/camera/fov"][0]
    polygon = json.loads(fov.geojson)["features"][0]["geometry"]
    ring = np.array(polygon["coordinates"][0])
    assert polygon["type"] == "Polygon" and np.allclose(ring[0], ring[-1]) and len(ring) >= 4
    assert np.all(ring[1:-1, 0] > geo.lon_deg)  # looking east: the wedge lies east of the camera
    track_tracks = [m for _, m in recording["/dronekey/tracks"] if m.get("lat") is not None]
    fixes = [m for _, m in recording["/dronekey/fix"]]
    assert len(fixes) == len([m for m in track_tracks if all(np.isfinite(m["position_m"]))])
    fix, message = fixes[-1], track_tracks[-1]
    assert fix.frame_id == f"drone_{message['track_id']}"
    assert (fix.latitude, fix.longitude) == pytest.approx((message["lat"], message["lon"]), abs=1e-9)
    cov = np.array(fix.position_covariance).reshape(3, 3)
    assert fix.position_covariance_type == 3  # KNOWN
    assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) >= -1e-12)
    # ENU: the camera looks east, so its depth (the largest variance) is East's
    cam_cov = np.array(message["position_cov"])
    assert np.trace(cov) == pytest.approx(np.trace(cam_cov), rel=1e-6)
    assert cov[0, 0] == pytest.approx(max(np.diag(cov)))


def test_the_3d_scene_has_the_frustum_the_drone_and_its_path(recording):
    scenes = [m for _, m in recording["/dronekey/scene"]]
    assert len(scenes) == 45
    last = scenes[-1]
    ids = {e.id for e in last.entities}
    assert "camera_frustum" in ids
    drones = [e for e in last.entities if e.id.startswith("drone_")]
    assert drones and all(len(e.lines) == 4 and len(e.cylinders) == 4 for e in drones)
    assert all(e.frame_id == e.id and e.frame_locked for e in drones)  # drawn in /tf's drone frame
    paths = [e for e in last.entities if e.id.startswith("path_")]
    assert paths and len(paths[0].lines[0].points) >= 10
    assert last.deletions[0].type == 1  # ALL: each update replaces the scene
