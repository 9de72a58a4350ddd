"""JSON messages of the daemon: track, status and info messages against their shipped JSON schemas
(checked with ``json_checks.schema_errors``)."""

from __future__ import annotations

import functools
import math
import re
import time

import numpy as np
import pytest
from factories import make_track
from json_checks import schema_errors, strict_json
from site_files import ORIGIN, write_site

from dronekey.daemon import messages
from dronekey.daemon.camera_pose import CameraPlacement, load_extrinsics
from dronekey.daemon.geo import CameraGeo, ecef_from_lla, lla_from_ecef
from dronekey.daemon.sinks.base import FrameUpdate, Sink, SinkWorker
from dronekey.daemon.sources import CaptureStats, SourceState
from dronekey.daemon.status import PipelineCounters, status_figures, status_summary
from dronekey.geometry.camera import CameraModel

# The track of these tests: measured (keypoints, score, reprojection), about 17 m away, yawed 45 degrees.
measured_track = functools.partial(
    make_track,
    3,
    t_ns=1_700_000_000_123_456_789,
    position_m=(10.0, -10.0, 10.0),
    velocity_mps=(0.5, 0.0, -1.0),
    position_cov=np.diag([0.04, 0.04, 0.25]),
    attitude=(0.9238795, 0.0, 0.3826834, 0.0),
    keypoints_px=np.array([[900.0, 500.0], [950.0, 505.0], [948.0, 540.0], [902.0, 538.0]]),
    score=0.93,
    reprojection_px=0.7,
    hits=12,
    age_s=0.4,
    heading_confidence=0.82,
)


# ----------------------------------------------------------------------------- schemas
@pytest.mark.parametrize("name", messages.SCHEMA_NAMES)
def test_schemas_ship_as_package_data_and_declare_draft_2020_12(name):
    schema = messages.load_schema(name)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert schema["type"] == "object" and schema["required"]
    assert set(schema["required"]) <= set(schema["properties"])


def test_validator_rejects_what_it_should():
    schema = messages.load_schema("track")
    good = messages.track_message(measured_track(), "cam0")
    assert schema_errors(good, schema) == []
    assert schema_errors({**good, "track_id": "3"}, schema)
    assert schema_errors({**good, "position_m": [1.0, 2.0]}, schema)
    assert schema_errors({**good, "status": "alive"}, schema)
    assert schema_errors({**good, "surprise": 1}, schema)
    assert schema_errors({k: v for k, v in good.items() if k != "score"}, schema)
    assert schema_errors({**good, "lat": 1.0}, schema)  # lat without lon, alt_m, ...
    assert schema_errors({**good, "heading_confidence": 1.5}, schema)
    assert schema_errors({**good, "heading_confidence": -0.1}, schema)
    assert schema_errors({k: v for k, v in good.items() if k != "heading_confidence"}, schema)


# ----------------------------------------------------------------------------- track
def test_track_message_carries_the_contract_fields_and_validates():
    message = messages.track_message(measured_track(), "cam0")
    for key in ("camera_id", "track_id", "t_ns", "status", "position_m", "quaternion_wxyz", "velocity_mps",
                "position_cov", "keypoints_px", "score", "reprojection_px",
                "heading_confidence"):  # fmt: skip
        assert key in message
    assert message["camera_id"] == "cam0" and message["track_id"] == 3 and message["status"] == "confirmed"
    assert message["t_ns"] == 1_700_000_000_123_456_789  # integer ns survive JSON exactly
    assert message["position_cov"] == [[0.04, 0.0, 0.0], [0.0, 0.04, 0.0], [0.0, 0.0, 0.25]]
    assert message["keypoints_px"][2] == [948.0, 540.0]
    assert "lat" not in message
    # range and bearing: x = right 10, y = up 10 (y is down), z = forward 10
    assert message["range_m"] == pytest.approx(math.sqrt(300.0))
    assert message["bearing"]["azimuth_deg"] == pytest.approx(45.0)
    assert message["bearing"]["elevation_deg"] == pytest.approx(
        math.degrees(math.atan2(10.0, math.sqrt(200.0)))
    )
    decoded = strict_json(messages.to_json_bytes(message))
    assert decoded == message
    assert schema_errors(decoded, messages.load_schema("track")) == []


def test_nan_becomes_null_and_the_bytes_are_strict_json():
    track = measured_track(
        rotation_std_rad=np.full(3, np.nan),
        reprojection_px=float("nan"),
        heading_confidence=float("nan"),
        keypoints_px=None,
    )
    track.velocity_mps = np.array([np.nan, np.inf, 0.0])
    payload = messages.to_json_bytes(messages.track_message(track, "cam0"))
    assert b"NaN" not in payload and b"Infinity" not in payload
    decoded = strict_json(payload)
    assert decoded["reprojection_px"] is None
    assert decoded["rotation_std_rad"] == [None, None, None]
    assert decoded["velocity_mps"] == [None, None, 0.0]
    assert decoded["keypoints_px"] is None
    assert decoded["heading_confidence"] is None  # a model without a front/back head
    assert schema_errors(decoded, messages.load_schema("track")) == []


@pytest.mark.parametrize(
    ("confidence", "sent"),
    [(0.82, 0.82), (0.0, 0.0), (1.0, 1.0), (1.0 + 1e-9, 1.0), (-1e-9, 0.0), (np.float32(0.25), 0.25),
     (float("nan"), None), (None, None)],
)  # fmt: skip
def test_heading_confidence_is_sent_in_0_1_or_null(confidence, sent):
    track = measured_track(heading_confidence=confidence)
    decoded = strict_json(messages.to_json_bytes(messages.track_message(track, "cam0")))
    assert decoded["heading_confidence"] == (None if sent is None else pytest.approx(sent))
    assert schema_errors(decoded, messages.load_schema("track")) == []
    schema = messages.load_schema("track")["properties"]["heading_confidence"]
    assert (schema["minimum"], schema["maximum"]) == (0, 1)


@pytest.mark.parametrize("confidence", [1.2, -0.5, "sure"])
def test_heading_confidence_out_of_range_names_itself(confidence):
    with pytest.raises(ValueError, match=f"heading_confidence must be .* got {re.escape(repr(confidence))}"):
        messages.track_message(measured_track(heading_confidence=confidence), "cam0")


def test_geodetic_fields_with_a_camera_pose():
    # Camera at the equator looking north, level: camera z is north, x east, y down.
    geo = CameraGeo(0.0, 10.0, 100.0)
    track = measured_track()
    track.position_m = np.array([0.0, -50.0, 1000.0])  # 1 km north, 50 m up
    track.velocity_mps = np.array([2.0, 0.0, 0.0])  # eastwards
    message = messages.track_message(track, "cam0", camera_geo=geo)
    assert message["lat"] == pytest.approx(
        1000.0 / 110574.0, rel=1e-3
    )  # ~110.57 km per degree at the equator
    assert message["lon"] == pytest.approx(10.0, abs=1e-9)
    assert message["alt_m"] == pytest.approx(150.0, abs=0.2)  # + Earth curvature over 1 km (~0.08 m)
    assert message["bearing_true"]["azimuth_deg"] == pytest.approx(0.0, abs=1e-9)
    assert message["bearing_true"]["elevation_deg"] == pytest.approx(math.degrees(math.atan2(50.0, 1000.0)))
    assert message["velocity_ned_mps"] == pytest.approx([0.0, 2.0, 0.0])
    assert schema_errors(strict_json(messages.to_json_bytes(message)), messages.load_schema("track")) == []
    west = measured_track()
    west.position_m = np.array([-100.0, 0.0, 0.0])  # straight left = west
    assert messages.track_message(west, "cam0", geo)["bearing_true"]["azimuth_deg"] == pytest.approx(270.0)


def test_bad_inputs_name_the_argument():
    track = measured_track()
    track.position_cov = np.eye(2)
    with pytest.raises(ValueError, match="position_cov"):
        messages.track_message(track, "cam0")
    with pytest.raises(ValueError, match="camera_id"):
        messages.track_message(measured_track(), "cam/0")
    with pytest.raises(ValueError, match="camera_id"):
        messages.key_expressions("*")
    assert messages.key_expressions("north-1")["tracks"] == "dronekey/north-1/tracks"


# ----------------------------------------------------------------------------- status
class _CountingSink(Sink):
    name = "counting"

    def __init__(self) -> None:
        self.updates = 0

    def handle_update(self, update: FrameUpdate) -> None:
        self.updates += 1

    def health(self) -> dict:
        return {"writable": True, "ratio": float("nan")}

    def close(self) -> None:
        pass


def _figures(**overrides):
    figures = {
        "healthy": True,
        "uptime_s": 12.5,
        "fps": 29.7,
        "latency_ms": (14.0, float("nan")),
        "frames": {"processed": 371, "dropped": 2},
        "source": {"state": "running", "uri": "clip.mp4"},
        "model": {"name": "dronekey-small", "path": "/opt/m.onnx", "sha256": None, "input_px": 224},
        "tracks_active": 1,
    }
    figures.update(overrides)
    return figures


def test_status_message_from_figures_and_real_workers_validates():
    sink = _CountingSink()
    worker = SinkWorker(sink)
    for i in range(5):
        worker.submit_update(FrameUpdate("cam0", i, i, time.monotonic_ns()))
    worker.close()
    assert sink.updates == 5
    status = messages.status_message(
        "cam0", time.time_ns(), _figures(sinks=[messages.sink_entry("counting", worker)])
    )
    decoded = strict_json(messages.to_json_bytes(status))
    assert schema_errors(decoded, messages.load_schema("status")) == []
    assert decoded["latency_ms"] == {"p50": 14.0, "p99": None}
    assert decoded["source"] == {"state": "running", "uri": "clip.mp4", "reconnects": 0, "error": None}
    assert decoded["model"]["input_px"] == 224  # extra model facts pass through
    (entry,) = decoded["sinks"]
    assert entry["name"] == "counting" and entry["published"] == 5 and entry["queue_depth"] == 0
    assert entry["health"] == {"writable": True, "ratio": None}
    assert entry["latency_ms"]["p50"] is not None


class _LosingSink(_CountingSink):
    """Takes every update and delivers none, as an MCAP output on a full disk does."""

    name = "losing"

    def failing(self) -> str | None:
        return "not recording: No space left on device (/var/lib/dronekey/mcap)"

    def fault_counts(self) -> dict[str, int]:
        return {"not recorded": self.updates}


def test_a_failing_sink_is_named_in_the_status_message_and_line():
    worker = SinkWorker(_LosingSink())
    for i in range(3):
        worker.submit_update(FrameUpdate("cam0", i, i, time.monotonic_ns()))
    worker.close()
    capture = CaptureStats(SourceState.STREAMING, 3, 0, 0, 0, None, 0.03)
    figures = status_figures(
        healthy=True, started_mono=time.monotonic(), pipeline_fps=30.0, capture=capture,
        source_uri="clip.mp4", counters=PipelineCounters(),
        model_info={"name": None, "path": None, "sha256": None}, workers={"mcap": worker},
    )  # fmt: skip
    decoded = strict_json(messages.to_json_bytes(messages.status_message("cam0", time.time_ns(), figures)))
    assert schema_errors(decoded, messages.load_schema("status")) == []
    (entry,) = decoded["sinks"]
    assert entry["published"] == 3 and entry["faults"] == {"not recorded": 3}
    assert entry["failing"].startswith("not recording: No space left")
    line = status_summary(figures, capture, ())
    assert (
        "| mcap q0 3 not recorded, FAILING: not recording: No space left on device (/var/lib/dronekey/m… |"
        in line
    )


def test_status_sinks_may_be_a_mapping_and_figures_are_checked():
    status = messages.status_message("cam0", 1, _figures(sinks={"mcap": {"health": {"writable": False}}}))
    assert status["sinks"][0]["name"] == "mcap" and status["sinks"][0]["health"] == {"writable": False}
    assert schema_errors(status, messages.load_schema("status")) == []
    minimal = messages.status_message(
        "cam0", 1, {"healthy": False, "uptime_s": 0, "fps": None, "source": {"state": "starting"}}
    )
    assert schema_errors(minimal, messages.load_schema("status")) == []
    with pytest.raises(ValueError, match="uptime_s"):
        messages.status_message("cam0", 1, {"healthy": True, "fps": 1.0, "source": {"state": "running"}})
    with pytest.raises(ValueError, match="temperature"):
        messages.status_message("cam0", 1, _figures(temperature=40))
    with pytest.raises(ValueError, match="source"):
        messages.status_message("cam0", 1, _figures(source={"state": "running", "colour": "red"}))
    with pytest.raises(ValueError, match="latency_ms"):
        messages.status_message("cam0", 1, _figures(latency_ms=5.0))


# ----------------------------------------------------------------------------- info
def test_info_message_validates_and_carries_the_schemas():
    camera = CameraModel.from_fov(1920, 1080, 70.0)
    info = messages.info_message(
        "cam0", camera, model={"name": "m", "path": "m.onnx", "sha256": "ab"}, camera_geo=CameraGeo(1, 2, 3)
    )
    decoded = strict_json(messages.to_json_bytes(info))
    assert schema_errors(decoded, messages.load_schema("info")) == []
    assert decoded["calibration"]["width"] == 1920 and len(decoded["calibration"]["K"]) == 3
    assert decoded["camera_geo"]["alt_m"] == 3.0
    assert decoded["schemas"]["track"]["title"] == "dronekey.Track"
    assert decoded["key_expressions"]["info"] == "dronekey/cam0/info"
    assert decoded["version"]


def test_info_message_publishes_the_camera_pose_from_extrinsics(tmp_path):
    """The pose from a site file, in ECEF and in the site frame; the derived geodetic pose puts a
    camera-frame point where the site frame does."""
    site = write_site(tmp_path / "site.json", [("east", 80.0, 5.0, (30.0, -4.0, 2.5))])
    placement = load_extrinsics(site, "east")
    camera = CameraModel.from_fov(1920, 1080, 70.0)
    assert messages.info_message("east", camera)["camera_pose"] is None
    full = CameraPlacement(placement.camera_geo(), placement)
    info = strict_json(
        messages.to_json_bytes(messages.info_message("east", camera, camera_geo=full.geo, placement=full))
    )
    assert schema_errors(info, messages.load_schema("info")) == []
    pose = info["camera_pose"]
    assert pose["source"] == "extrinsics" and pose["site"]["origin"] == ORIGIN
    np.testing.assert_allclose(pose["site"]["t_site_cam_m"], [30.0, -4.0, 2.5])
    assert (
        abs(info["camera_geo"]["yaw_deg"] - 80.0) < 1e-3 and abs(info["camera_geo"]["pitch_deg"] - 5.0) < 1e-3
    )
    p_cam = np.array([3.0, -1.0, 120.0])
    R, t = np.array(pose["ecef"]["R_ecef_cam"]), np.array(pose["ecef"]["position_m"])
    lat, lon, alt = lla_from_ecef(R @ p_cam + t)
    site_lla = lla_from_ecef(
        ecef_from_lla(ORIGIN["lat"], ORIGIN["lon"], ORIGIN["alt_m"])
        + placement.R_ecef_site @ (placement.R_site_cam @ p_cam + placement.t_site_cam_m)
    )
    geo_lla = full.geo.geodetic(p_cam)
    np.testing.assert_allclose((lat, lon), site_lla[:2], atol=1e-9)
    np.testing.assert_allclose((lat, lon), geo_lla[:2], atol=1e-9)
    assert abs(alt - site_lla[2]) < 1e-4 and abs(alt - geo_lla[2]) < 1e-4


def test_info_message_publishes_the_camera_pose_from_geo():
    geo = CameraGeo(47.0, 8.0, 500.0, 90.0, 0.0, 0.0)
    camera = CameraModel.from_fov(640, 480, 60.0)
    info = messages.info_message("cam0", camera, camera_geo=geo, placement=CameraPlacement(geo))
    decoded = strict_json(messages.to_json_bytes(info))
    assert schema_errors(decoded, messages.load_schema("info")) == []
    assert decoded["camera_pose"]["source"] == "geo" and decoded["camera_pose"]["site"] is None
    # optical axis east: camera z in ECEF is the local east
    R = np.array(decoded["camera_pose"]["ecef"]["R_ecef_cam"])
    east = np.array([-np.sin(np.radians(8.0)), np.cos(np.radians(8.0)), 0.0])
    np.testing.assert_allclose(R[:, 2], east, atol=1e-9)
