"""MCAP sink: real files written and read back with the ``mcap`` reader.

Covers the channels and Foxglove schemas of docs/design.md §6.3 (Foxglove's types decoded with Foxglove's
published protobuf classes, see foxglove_checks), rotation by size and duration, retention
(our oldest files only), an unwritable or full folder (health says so, the sink recovers), and a
writer killed with SIGKILL (completed chunks stay readable with ``StreamReader``).
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import cv2
import numpy as np
import paths
import pytest
from factories import make_track
from foxglove_checks import decode, schema_matches_published
from json_checks import schema_errors
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Channel, Footer, Message, Schema
from mcap.stream_reader import StreamReader

from dronekey.daemon import messages
from dronekey.daemon.config.mcap import McapConfig
from dronekey.daemon.sinks.base import FrameUpdate
from dronekey.daemon.sinks.mcap import foxglove
from dronekey.daemon.sinks.mcap.channels import GEO_TOPICS, TOPICS, foxglove_compatible
from dronekey.daemon.sinks.mcap.sink import McapSink
from dronekey.geometry.camera import CameraModel
from dronekey.types import KeypointDetection, Track, TrackStatus

# The channels of a recording without --camera-geo.
PLAIN_TOPICS = {topic: schema for topic, schema in TOPICS.items() if topic not in GEO_TOPICS}
FPS = 30
FRAME_NS = 1_000_000_000 // FPS
KEYPOINTS = np.array([[600.0, 300.0], [660.0, 304.0], [658.0, 350.0], [602.0, 346.0]])
# Front/back confidence per track id: 1 fairly sure, 2 unsure (a "heading ?" label), others unknown.
HEADINGS = {1: 0.82, 2: 0.3}


def camera() -> CameraModel:
    return CameraModel.from_fov(1280, 720, 70.0)


def picture(seed: int = 0) -> np.ndarray:
    """A 1280x720 BGR frame that compresses like a real one (gradients and shapes, not noise)."""
    y, x = np.mgrid[0:720, 0:1280]
    img = np.stack([(x // 5) % 256, (y // 3) % 256, ((x + y + 40 * seed) // 7) % 256], axis=-1).astype(
        np.uint8
    )
    cv2.circle(img, (630 + seed % 50, 325), 40, (20, 20, 20), -1)
    return img


def track(track_id: int, t_ns: int, *, z: float = 20.0) -> Track:
    """A measured track of the test frames: keypoints beside the detection's, tilted 45 degrees."""
    return make_track(
        track_id,
        t_ns=t_ns,
        position_m=(0.5 * track_id, -1.0, z),
        velocity_mps=(1.0, 0.0, 0.0),
        position_cov=np.eye(3) * 0.01,
        attitude=(0.9238795, 0.3826834, 0.0, 0.0),
        rotation_std_rad=(np.nan, np.nan, np.nan),
        keypoints_px=KEYPOINTS + 3 * track_id,
        score=0.9,
        reprojection_px=0.6,
        hits=5,
        heading_confidence=HEADINGS.get(track_id, float("nan")),
    )


def update(i: int, *, n_tracks: int = 2, image: np.ndarray | None = None, t0_ns: int = 0) -> FrameUpdate:
    t_ns = t0_ns + i * FRAME_NS
    return FrameUpdate(
        camera_id="cam0",
        frame_index=i,
        t_ns=t_ns,
        t_arrival_mono_ns=time.monotonic_ns(),
        tracks=tuple(track(k + 1, t_ns) for k in range(n_tracks)),
        detection=KeypointDetection(KEYPOINTS, 0.95, (500, 200, 256)),
        image=image,
    )


def status(t_ns: int) -> dict:
    figures = {"healthy": True, "uptime_s": 1.0, "fps": 30.0, "source": {"state": "running"}}
    return messages.status_message("cam0", t_ns, figures)


def mcap_files(directory: Path) -> list[Path]:
    return sorted(directory.glob("dronekey_cam0_*.mcap"))


def read_finalised(path: Path):
    """(summary, {topic: [(log_time, decoded message)]}) of a finalised file."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None, f"{path} has no summary"
        by_topic: dict[str, list] = {c.topic: [] for c in summary.channels.values()}
        for schema, channel, message in reader.iter_messages():
            decoded = decode(schema.name, channel.message_encoding, message.data)
            by_topic[channel.topic].append((message.log_time, decoded))
    return summary, by_topic


def foxglove_parser_errors(schema: dict, path: str = "") -> list[str]:
    """What Foxglove's jsonschema channel parser (parseJsonSchema.ts in Foxglove's MCAP support) rejects."""
    if schema.get("type") != "object" or not isinstance(schema.get("properties"), dict):
        return [f"{path or '<root>'}: needs type object with properties"]
    errors = []
    for name, field in schema["properties"].items():
        where = f"{path}{name}"
        if isinstance(field.get("oneOf"), list):
            if not all(isinstance(alt.get("const"), (int, float)) for alt in field["oneOf"]):
                errors.append(f"{where}: oneOf alternatives must be numbers")
            continue
        kind = field.get("type")
        if kind == "object":
            errors += foxglove_parser_errors(field, f"{where}.")
        elif kind == "array":
            item = field.get("items") or {}
            if item.get("type") == "object":
                errors += foxglove_parser_errors(item, f"{where}[].")
            elif (
                item.get("type") not in ("boolean", "number", "integer", "string")
                or "contentEncoding" in item
            ):
                errors.append(f"{where}: unsupported array item {item.get('type')!r}")
        elif kind == "string":
            if field.get("contentEncoding") not in (None, "base64"):
                errors.append(f"{where}: unsupported contentEncoding")
        elif kind not in ("boolean", "number", "integer"):
            errors.append(f"{where}: unsupported type {kind!r}")
    return errors


# ----------------------------------------------------------------------------- the normal path
def test_close_finalises_a_file_with_every_channel_schema_and_count(tmp_path):
    sink = McapSink(McapConfig(dir=tmp_path, image_rate_hz=2.0, image_max_width=960), camera(), "cam0")
    img = picture()
    for i in range(30):  # 1 s of frames
        sink.handle_update(update(i, image=img))
        if i in (10, 20):
            sink.handle_status(status(time.time_ns()))
    assert sink.health()["writable"] is True and sink.health()["compression"] == "zstd"
    sink.close()

    (path,) = mcap_files(tmp_path)
    summary, by_topic = read_finalised(path)
    channels = {c.topic: c for c in summary.channels.values()}
    assert set(channels) == set(PLAIN_TOPICS)
    for topic, schema_name in PLAIN_TOPICS.items():
        schema = summary.schemas[channels[topic].schema_id]
        encoding = "json" if schema_name.startswith("dronekey.") else "protobuf"
        assert (schema.name, schema.encoding, channels[topic].message_encoding) == (
            schema_name,
            "jsonschema" if encoding == "json" else "protobuf",
            encoding,
        )
        if encoding == "json":
            assert foxglove_parser_errors(json.loads(schema.data)) == [], topic
        else:
            assert schema_matches_published(schema.name, schema.data) == [], topic
    counts = {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()}
    expected = {
        "/dronekey/tracks": 60,  # 2 tracks x 30 frames
        "/dronekey/annotations": 30,
        "/tf": 30,
        "/camera/image": 2,  # 2 Hz over frames t = 0 .. 0.967 s: slots at 0 and 0.5 s
        "/camera/calibration": 1,  # at the first frame, then once per second of frame time
        "/dronekey/scene": 30,
        "/dronekey/status": 2,
    }
    assert counts == expected == sink.message_counts
    assert all(ci.compression == "zstd" for ci in summary.chunk_indexes)

    # Foxglove messages decoded with the published classes (read_finalised); ours validate against the
    # contract schemas (the channel carries a Foxglove-typed rendition of them: foxglove_compatible).
    for _, message in by_topic["/dronekey/tracks"]:
        assert schema_errors(message, messages.load_schema("track")) == []
    for _, message in by_topic["/dronekey/status"]:
        assert schema_errors(message, messages.load_schema("status")) == []

    # Log times are the frame times; the same JSON as on Zenoh.
    log_time, first = by_topic["/dronekey/tracks"][0]
    assert log_time == 0 and first == messages.track_message(track(1, 0), "cam0")
    assert [t for t, _ in by_topic["/dronekey/annotations"]] == [i * FRAME_NS for i in range(30)]

    # The image is a 960x540 JPEG at frame time; the calibration describes that size.
    t_img, image_msg = by_topic["/camera/image"][1]
    assert t_img == 16 * FRAME_NS  # first >= 0.5 s
    assert (image_msg.timestamp.seconds, image_msg.timestamp.nanos) == (0, 16 * FRAME_NS)
    assert image_msg.format == "jpeg" and image_msg.frame_id == "cam0"
    jpeg = cv2.imdecode(np.frombuffer(image_msg.data, np.uint8), cv2.IMREAD_COLOR)  # bytes, not base64
    assert jpeg.shape == (540, 960, 3)
    _, calib = by_topic["/camera/calibration"][0]
    assert (calib.width, calib.height, calib.distortion_model) == (960, 540, "plumb_bob")
    assert calib.K[0] == pytest.approx(camera().fx * 0.75)
    assert calib.K[2] == pytest.approx((camera().cx + 0.5) * 0.75 - 0.5)
    assert calib.P[:3] == calib.K[:3] and len(calib.P) == 12

    # Annotations: 4 keypoints with labels 1-4 (corner origin, scaled to 960 wide) and the ROI box.
    _, ann = by_topic["/dronekey/annotations"][0]
    points = {p.type: p for p in ann.points}
    kp = points[int(foxglove.POINTS)].points
    expected_kp = (KEYPOINTS + 0.5) * 0.75
    assert np.allclose([[p.x, p.y] for p in kp], expected_kp)
    assert [t.text for t in ann.texts[:4]] == ["1", "2", "3", "4"]
    box = points[int(foxglove.LINE_LOOP)].points
    assert (box[0].x, box[0].y) == (500 * 0.75, 200 * 0.75) and (box[2].x, box[2].y) == (
        756 * 0.75,
        456 * 0.75,
    )
    labels = [t.text for t in ann.texts[4:] if t.text.startswith("#")]
    assert labels == ["#1 confirmed 20.0 m  heading 0.82", "#2 confirmed 20.0 m  heading ?"]
    # The track messages carry the confidence too, typed for Foxglove's plots.
    assert [m["heading_confidence"] for _, m in by_topic["/dronekey/tracks"][:2]] == [0.82, 0.3]
    track_schema = json.loads(summary.schemas[channels["/dronekey/tracks"].schema_id].data)
    assert track_schema["properties"]["heading_confidence"]["type"] == "number"
    assert "heading_confidence" in track_schema["required"]

    # Transforms camera -> drone_<id>, quaternion in Foxglove's x, y, z, w order.
    _, tf = by_topic["/tf"][0]
    first_tf = tf.transforms[0]
    assert (first_tf.parent_frame_id, first_tf.child_frame_id) == ("cam0", "drone_1")
    assert (first_tf.translation.x, first_tf.translation.y, first_tf.translation.z) == (0.5, -1.0, 20.0)
    rotation = first_tf.rotation
    assert [rotation.x, rotation.y, rotation.z, rotation.w] == pytest.approx([0.3826834, 0.0, 0.0, 0.9238795])


def test_track_label_shows_the_heading_confidence():
    t = track(3, 0)
    t.position_m = np.array([0.0, 0.0, 12.4])
    for confidence, heading in [(0.82, "0.82"), (0.5, "0.50"), (1.0, "1.00"), (0.49, "?"), (0.0, "?")]:
        t.heading_confidence = confidence
        assert foxglove.track_label(t) == f"#3 confirmed 12.4 m  heading {heading}"
    t.heading_confidence = float("nan")  # a model without a front/back head: the front is not known
    assert foxglove.track_label(t) == "#3 confirmed 12.4 m  heading ?"
    t.position_m = np.array([np.nan, 0.0, 1.0])
    t.status = TrackStatus.COASTING
    assert foxglove.track_label(t) == "#3 coasting  heading ?"
    t.heading_confidence = 2.0
    with pytest.raises(ValueError, match=r"heading_confidence must be .* got 2\.0"):
        foxglove.track_label(t)


def test_worker_queues_the_frame_only_for_the_images_written(tmp_path):
    """Behind its SinkWorker the sink gets the frame only on the image grid (a backlog holds no full
    frames) and writes the same images as when it gets every frame."""
    from dronekey.daemon.sinks.base import SinkWorker

    times = [i * FRAME_NS for i in range(75)] + [10 * FRAME_NS + i * 7_000_000 for i in range(40)]
    img = picture()

    def image_times(sink) -> list[int]:
        sink.close()
        (path,) = mcap_files(sink._directory)
        return [t for t, _ in read_finalised(path)[1]["/camera/image"]]

    direct = McapSink(McapConfig(dir=tmp_path / "direct", image_rate_hz=2.0), camera(), "cam0")
    for i, t in enumerate(times):
        direct.handle_update(update(i, image=img, t0_ns=t - i * FRAME_NS))
    queued = McapSink(McapConfig(dir=tmp_path / "queued", image_rate_hz=2.0), camera(), "cam0")
    carried = []
    original = queued.handle_update

    def spy(u):
        carried.append(u.image is not None)
        original(u)

    queued.handle_update = spy
    worker = SinkWorker(queued, max_queue=1000)
    for i, t in enumerate(times):
        worker.submit_update(update(i, image=img, t0_ns=t - i * FRAME_NS))
    worker.close(timeout_s=10.0)
    written = image_times(direct)
    assert len(written) >= 4  # 2.5 s of frames, then time goes back
    assert image_times(queued) == written
    assert sum(carried) == len(written)


def test_json_schemas_are_what_foxglove_can_parse():
    contract = messages.load_schema("track")
    assert foxglove_parser_errors(contract)  # nullable types and 3x3 lists: Foxglove would refuse it
    reduced = foxglove_compatible(contract)
    assert foxglove_parser_errors(reduced) == []
    assert "position_cov" not in reduced["properties"] and "position_cov" in reduced["$comment"]
    assert reduced["properties"]["reprojection_px"]["type"] == "number"
    assert foxglove_parser_errors(foxglove_compatible(messages.load_schema("status"))) == []


def test_status_log_time_follows_the_frame_clock(tmp_path):
    sink = McapSink(McapConfig(dir=tmp_path, image_rate_hz=0), camera(), "cam0")
    t0 = 5_000_000_000  # a file source: stream PTS, far from the wall clock
    sink.handle_status(status(time.time_ns()))  # before any frame: waits for the first one
    for i in range(3):
        sink.handle_update(update(i, t0_ns=t0))
    sink.handle_status(status(time.time_ns()))
    sink.close()
    _, by_topic = read_finalised(mcap_files(tmp_path)[0])
    (t_first, _), (t_second, _) = by_topic["/dronekey/status"]
    assert t_first == t0
    assert t0 + 2 * FRAME_NS <= t_second < t0 + 60_000_000_000  # last frame + the wall time since
    assert by_topic["/camera/image"] == []


def test_bad_arguments_name_themselves(tmp_path):
    with pytest.raises(ValueError, match="compression"):
        McapSink(McapConfig(dir=tmp_path, compression="brotli"), camera(), "cam0")
    with pytest.raises(ValueError, match="jpeg_quality"):
        McapSink(McapConfig(dir=tmp_path, jpeg_quality=0), camera(), "cam0")
    with pytest.raises(ValueError, match="camera_id"):
        McapSink(McapConfig(dir=tmp_path), camera(), "cam 0")
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- rotation and retention
def test_rotation_by_size_finalises_each_file_with_all_channels_and_calibration(tmp_path):
    sink = McapSink(
        McapConfig(dir=tmp_path, image_rate_hz=30.0, rotate_size_mb=0.1),
        camera(),
        "cam0",
        chunk_size=64 * 1024,
    )
    pictures = [picture(k) for k in range(4)]
    for i in range(40):
        sink.handle_update(update(i, image=pictures[i % 4]))
    sink.close()
    files = mcap_files(tmp_path)
    assert len(files) >= 3
    total: dict[str, int] = dict.fromkeys(PLAIN_TOPICS, 0)
    for path in files:
        summary, by_topic = read_finalised(path)
        assert {c.topic for c in summary.channels.values()} == set(PLAIN_TOPICS)
        assert len(summary.schemas) == len(PLAIN_TOPICS)
        assert by_topic["/camera/calibration"], f"{path.name} has no calibration"
        assert by_topic["/camera/calibration"][0][0] == by_topic["/dronekey/annotations"][0][0]
        for topic, items in by_topic.items():
            total[topic] += len(items)
    assert total == sink.message_counts
    assert total["/dronekey/annotations"] == 40 and total["/camera/image"] == 40


def test_rotation_by_duration(tmp_path):
    sink = McapSink(McapConfig(dir=tmp_path, image_rate_hz=0, rotate_duration_s=0.2), camera(), "cam0")
    for i in range(6):
        sink.handle_update(update(i))
        time.sleep(0.1)
    sink.close()
    files = mcap_files(tmp_path)
    assert len(files) >= 2
    assert sum(len(read_finalised(p)[1]["/dronekey/annotations"]) for p in files) == 6


def test_retention_deletes_only_our_oldest_recordings(tmp_path):
    foreign = [
        tmp_path / "notes.txt",
        tmp_path / "dronekey_cam1_20200101T000000.000Z.mcap",  # another camera's
        tmp_path / "dronekey_cam0_backup.mcap",  # not one of our names
    ]
    for path in foreign:
        path.write_bytes(b"x" * 200_000)
    ours_old = tmp_path / "dronekey_cam0_20200101T000000.000Z.mcap"
    ours_old.write_bytes(b"x" * 400_000)
    os.utime(ours_old, (1_577_836_800, 1_577_836_800))

    sink = McapSink(
        McapConfig(dir=tmp_path, image_rate_hz=30.0, rotate_size_mb=0.1, retention_total_mb=0.25),
        camera(),
        "cam0",
        chunk_size=64 * 1024,
    )
    pictures = [picture(k) for k in range(4)]
    for i in range(60):  # JPEG bytes: about 25 kB a frame
        sink.handle_update(update(i, image=pictures[i % 4]))
    sink.close()
    assert not ours_old.exists()
    assert all(path.exists() for path in foreign)
    health = sink.health()
    assert health["files_deleted"] >= 2 and health["files_opened"] >= 4
    ours = [p for p in mcap_files(tmp_path) if p not in foreign]
    assert len(ours) < health["files_opened"]
    # What is left: at most the bound, counting the newest file as it was when the check ran.
    assert sum(p.stat().st_size for p in ours[:-1]) <= 250_000
    for path in ours:
        read_finalised(path)


# ----------------------------------------------------------------------------- faults
def test_unwritable_folder_is_reported_and_recovered(tmp_path):
    blocker = tmp_path / "blocker"
    blocker.write_text("a file where the folder should be")
    folder = blocker / "recordings"
    sink = McapSink(McapConfig(dir=folder, image_rate_hz=0), camera(), "cam0", retry_interval_s=0.2)
    for i in range(5):
        sink.handle_update(update(i))  # must not raise
    sink.handle_status(status(1))
    health = sink.health()
    assert health["writable"] is False and str(blocker) in health["error"]
    assert health["frames_not_recorded"] == 5 and health["file"] is None

    blocker.unlink()
    time.sleep(0.25)
    sink.handle_update(update(5))
    health = sink.health()
    assert health["writable"] is True and health["error"] is None and health["file"]
    sink.handle_update(update(6))
    sink.close()
    (path,) = mcap_files(folder)
    _, by_topic = read_finalised(path)
    assert len(by_topic["/dronekey/annotations"]) == 2


def test_full_disk_stops_recording_but_not_tracking(tmp_path):
    sink = McapSink(
        McapConfig(dir=tmp_path, min_free_mb=1e12), camera(), "cam0", retry_interval_s=0.05
    )  # "needs" 1 EB free
    for i in range(3):
        sink.handle_update(update(i, image=picture()))
        time.sleep(0.06)
    health = sink.health()
    assert health["writable"] is False and "min_free_mb" in health["error"]
    assert health["frames_not_recorded"] == 3
    assert sink.failing().startswith("not recording: free disk space") and str(tmp_path) in sink.failing()
    assert sink.fault_counts() == {"not recorded": 3}
    sink.close()
    assert mcap_files(tmp_path) == []


def test_default_min_free_is_the_lesser_of_500_mb_and_5_percent_said_once(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="dronekey.daemon.sinks.mcap.retention")
    sink = McapSink(
        McapConfig(dir=tmp_path / "not" / "yet", image_rate_hz=0), camera(), "cam0"
    )  # measured on its parent
    expected_mb = min(500.0, 0.05 * shutil.disk_usage(tmp_path).total / 1e6)
    assert sink.health()["min_free_mb"] == pytest.approx(expected_mb, abs=0.1)
    for i in range(3):
        sink.handle_update(update(i))
    sink.close()
    said = [r.getMessage() for r in caplog.records if "MB free" in r.getMessage()]
    assert len(said) == 1 and "the lesser of 500 MB and 5 % of the disk" in said[0], said
    assert McapSink(McapConfig(dir=tmp_path, min_free_mb=0), camera(), "cam0").health()["min_free_mb"] == 0


# A child that imports this module (and the helpers it imports from tests/).
_WITH_TEST_HELPERS = {
    **os.environ,
    "PYTHONPATH": os.pathsep.join(
        [str(Path(__file__).parent), str(paths.TESTS), os.environ.get("PYTHONPATH", "")]
    ),
}

_REFUSED_WRITER = textwrap.dedent(
    """
    import json, resource, signal, sys, time
    from test_mcap_sink import camera, picture, update
    from dronekey.daemon.config.mcap import McapConfig
    from dronekey.daemon.sinks.mcap.sink import McapSink

    # Writes past RLIMIT_FSIZE fail with EFBIG once SIGXFSZ is ignored: a disk that is full (ENOSPC)
    # for this process only. min_free_mb 0: the free-space check does not stop the attempts first.
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[2]), resource.RLIM_INFINITY))
    config = McapConfig(dir=sys.argv[1], min_free_mb=0)
    sink = McapSink(config, camera(), "cam0", chunk_size=1024, retry_interval_s=0.01)
    for i in range(20):
        sink.handle_update(update(i, image=picture()))
        time.sleep(0.02)
    sink.close()
    print(json.dumps({"health": sink.health(), "failing": sink.failing(), "faults": sink.fault_counts()}))
    """
)


@pytest.mark.parametrize("file_limit", [0, 4096])  # the header fails; the header fits, the first chunk fails
def test_a_full_disk_leaves_no_empty_files(tmp_path, file_limit):
    result = subprocess.run(
        [sys.executable, "-c", _REFUSED_WRITER, str(tmp_path), str(file_limit)],
        capture_output=True, text=True, timeout=60, env=_WITH_TEST_HELPERS,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert list(tmp_path.iterdir()) == []
    assert report["failing"].startswith("not recording: ") and "File too large" in report["failing"]
    assert report["faults"] == {"not recorded": 20}
    if file_limit:
        assert report["health"]["files_opened"] >= 2  # each retry made a file, and removed it


_KILLED_WRITER = textwrap.dedent(
    """
    import sys, time
    from test_mcap_sink import camera, picture, update
    from dronekey.daemon.config.mcap import McapConfig
    from dronekey.daemon.sinks.mcap.sink import McapSink

    sink = McapSink(McapConfig(dir=sys.argv[1], image_rate_hz=10.0), camera(), "cam0", chunk_max_age_s=0.2)
    img = picture()
    i = 0
    while True:
        sink.handle_update(update(i, image=img))
        i += 1
        if i % 10 == 0:
            print(i, flush=True)
        time.sleep(0.01)
    """
)


def read_salvaged(path: Path) -> tuple[list, Exception | None]:
    """Records of a file with no summary or footer, up to where it was cut, and what stopped the reader."""
    records = []
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f).records:
                records.append(record)
        except Exception as exc:  # the cut: EndOfFile, or a truncated record
            return records, exc
    return records, None


def test_sigkill_leaves_completed_chunks_readable(tmp_path):
    child = subprocess.Popen(
        [sys.executable, "-c", _KILLED_WRITER, str(tmp_path)],
        env=_WITH_TEST_HELPERS,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        written = 0
        while written < 60:  # about a second of frames: several chunks closed by age
            line = child.stdout.readline()
            assert line, "the writer died early"
            written = int(line)
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.wait(timeout=10)
    assert child.returncode == -signal.SIGKILL

    (path,) = mcap_files(tmp_path)
    with open(path, "rb") as f, pytest.raises(Exception):  # noqa: B017 - no footer: the seeking reader fails
        make_reader(f).get_summary()
    records, stopped_by = read_salvaged(path)
    assert not any(isinstance(r, Footer) for r in records)
    assert stopped_by is not None
    schemas = {r.name for r in records if isinstance(r, Schema)}
    channels = {r.id: r.topic for r in records if isinstance(r, Channel)}
    assert schemas == set(PLAIN_TOPICS.values()) and set(channels.values()) == set(PLAIN_TOPICS)
    found = [r for r in records if isinstance(r, Message)]
    topics = [channels[m.channel_id] for m in found]
    assert topics.count("/dronekey/annotations") >= 20
    assert topics.count("/dronekey/tracks") == 2 * topics.count("/dronekey/annotations")
    assert topics.count("/camera/image") >= 2
    times = [m.log_time for m in found if channels[m.channel_id] == "/dronekey/annotations"]
    assert times == [i * FRAME_NS for i in range(len(times))]  # a gap-free prefix of what was written
    schema_of = {r.id: r.name for r in records if isinstance(r, Schema)}
    channel_records = {r.id: r for r in records if isinstance(r, Channel)}
    for m in found:
        channel = channel_records[m.channel_id]
        decode(schema_of[channel.schema_id], channel.message_encoding, m.data)

    # The mcap reader for streams gives the same messages when asked not to sort (sorting reads to the
    # end first, and the end is the cut).
    decoded = []
    with open(path, "rb") as f:
        try:
            for _schema, channel, message in NonSeekingReader(f).iter_messages(log_time_order=False):
                decoded.append((channel.topic, message.log_time))
        except Exception as exc:  # EndOfFile, unless the kill cut a chunk being written
            assert type(exc) is type(stopped_by)
    assert decoded == [(channels[m.channel_id], m.log_time) for m in found]
