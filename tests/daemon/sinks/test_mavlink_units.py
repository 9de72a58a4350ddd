"""MAVLink output without sockets: the generated dialect, frame mapping, message fields, schedules,
signing key and timestamp files. The tests with real pymavlink peers are in test_mavlink_sink.py."""

from __future__ import annotations

import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from factories import make_track

from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.mavlink import messages
from dronekey.daemon.sinks.mavlink.dialect import load_dialect
from dronekey.daemon.sinks.mavlink.signing import (
    SigningKeyError,
    SigningTimestampStore,
    now_signing_timestamp,
    read_signing_key,
)
from dronekey.daemon.sinks.mavlink.streams import StreamRates
from dronekey.daemon.sinks.target_state import (
    callsign,
    icao_address,
    target_geodetic,
    unix_time_us,
    validate_icao_base,
    validate_statuses,
)
from dronekey.geometry.rotations import quat_wxyz_to_matrix

GEO = CameraGeo.parse("47.3977,8.5456,488.0,30,5,2")


@pytest.fixture(scope="module")
def dialect(tmp_path_factory):
    return load_dialect(tmp_path_factory.mktemp("mavlink-dialect"))


def random_rotation(rng) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


# ---------------------------------------------------------------- dialect


def test_dialect_crc_extras_match_upstream(dialect):
    # Upstream's C headers: MAVLINK_MSG_ID_TARGET_RELATIVE_CRC 28 (len 71), TARGET_ABSOLUTE 245 (len 106).
    assert dialect.MAVLink_target_relative_message.crc_extra == 28
    assert dialect.MAVLink_heartbeat_message.crc_extra == 50
    assert dialect.MAVLink_target_absolute_message.crc_extra == 245
    assert dialect.MAVLink_target_relative_message.unpacker.size == 71
    assert dialect.MAVLink_target_absolute_message.unpacker.size == 106
    assert dialect.WIRE_PROTOCOL_VERSION == "2.0"


def test_dialect_fields_and_enums_as_upstream(dialect):
    assert dialect.MAVLink_target_relative_message.fieldnames == [
        "timestamp", "id", "frame", "x", "y", "z", "pos_std", "yaw_std", "q_target", "q_sensor", "type",
    ]  # fmt: skip
    assert dialect.MAVLink_target_relative_message.id == 511
    assert dialect.MAVLink_target_absolute_message.id == 510
    assert dialect.MAVLink_target_absolute_message.fieldnames[:6] == [
        "timestamp", "id", "sensor_capabilities", "lat", "lon", "alt",
    ]  # fmt: skip
    assert (dialect.TARGET_OBS_FRAME_LOCAL_NED, dialect.TARGET_OBS_FRAME_BODY_FRD) == (0, 1)
    assert (dialect.TARGET_OBS_FRAME_LOCAL_OFFSET_NED, dialect.TARGET_OBS_FRAME_OTHER) == (2, 3)
    assert dialect.TARGET_ABSOLUTE_SENSOR_CAPABILITY_RATES == 16
    assert dialect.ADSB_EMITTER_TYPE_UAV == 14


def test_dialect_generation_is_cached_and_concurrency_safe(tmp_path):
    # Three processes generate into the same empty cache at once, then a fourth finds it there.
    code = (
        "import sys; from dronekey.daemon.sinks.mavlink.dialect import load_dialect; "
        "print(load_dialect(sys.argv[1]).__file__)"
    )
    procs = [
        subprocess.Popen([sys.executable, "-c", code, str(tmp_path)], stdout=subprocess.PIPE, text=True)
        for _ in range(3)
    ]
    paths = {p.communicate(timeout=60)[0].strip() for p in procs}
    assert all(p.returncode == 0 for p in procs)
    assert len(paths) == 1
    generated = Path(paths.pop())
    assert generated.parent == tmp_path and generated.name.startswith("dronekey_mavlink_")
    mtime = generated.stat().st_mtime_ns
    out = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=60
    )
    assert out.stdout.strip() == str(generated) and generated.stat().st_mtime_ns == mtime  # not regenerated
    assert sorted(p.name for p in tmp_path.iterdir() if p.suffix == ".py") == [generated.name]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".gen-")]  # no temporary leftovers


# ---------------------------------------------------------------- frames and message fields


def test_target_relative_frame_mapping(dialect):
    rng = np.random.default_rng(3)
    for _ in range(5):
        R = random_rotation(rng)
        track = make_track(attitude=R, position_m=rng.normal(size=3) * 10)
        msg = messages.target_relative(dialect, track, messages.sensor_quaternion(GEO), 123)
        p_frd = np.array([msg.x, msg.y, msg.z])
        # x forward = camera z, y right = camera x, z down = camera y
        np.testing.assert_allclose(p_frd, track.position_m[[2, 0, 1]], rtol=1e-6)
        # q_target: body -> FRD; q_sensor: FRD -> NED, so together they place the track in NED.
        R_frd_body = quat_wxyz_to_matrix(np.array(msg.q_target))
        np.testing.assert_allclose(R_frd_body, messages.FRD_FROM_CAM @ R, atol=1e-6)
        R_ned_frd = quat_wxyz_to_matrix(np.array(msg.q_sensor))
        np.testing.assert_allclose(R_ned_frd @ p_frd, GEO.ned_from_cam(track.position_m), atol=1e-4)
    assert msg.frame == dialect.TARGET_OBS_FRAME_BODY_FRD
    assert msg.type == dialect.LANDING_TARGET_TYPE_VISION_OTHER
    np.testing.assert_allclose(msg.pos_std, [0.5, 0.1, 0.2], rtol=1e-6)  # sqrt of cov diag z, x, y
    assert msg.yaw_std == pytest.approx(0.02)  # about camera y = FRD down
    assert msg.id == 7 and msg.timestamp == 123


def test_target_relative_without_geo_or_attitude(dialect):
    track = make_track()
    track.quaternion_wxyz = np.full(4, np.nan)
    msg = messages.target_relative(dialect, track, messages.sensor_quaternion(None), 1)
    assert list(msg.q_sensor) == [0, 0, 0, 0] and list(msg.q_target) == [0, 0, 0, 0]
    assert messages.target_relative(dialect, make_track(track_id=300), (0, 0, 0, 0), 1).id == 300 % 256


def _wire(dialect, msg):
    """``msg`` packed into MAVLink 2 bytes by pymavlink and parsed back."""
    mav = dialect.MAVLink(None, srcSystem=42, srcComponent=191)
    buf = msg.pack(mav)
    assert buf[0] == 0xFD  # MAVLink 2
    return dialect.MAVLink(None).decode(bytearray(buf))


def _yaw(R: np.ndarray) -> float:
    """Yaw (ZYX Euler) of a body -> frame rotation: heading of the body's x axis, rad."""
    return math.atan2(R[1, 0], R[0, 0])


def test_heading_flip_yaw_std_is_the_two_point_mixture_std():
    for confidence in (0.0, 0.3, 0.82, 1.0):
        q = 0.5 * (1.0 + confidence)
        yaws, weights = np.array([0.0, math.pi]), np.array([q, 1.0 - q])  # published yaw, its twin
        mean = weights @ yaws
        std = math.sqrt(weights @ (yaws - mean) ** 2)
        assert messages.heading_flip_yaw_std(confidence) == pytest.approx(std, abs=1e-12)
    assert messages.heading_flip_yaw_std(0.0) == pytest.approx(math.pi / 2)  # a coin flip
    assert messages.heading_flip_yaw_std(1.0) == 0.0
    assert messages.heading_flip_yaw_std(float("nan")) == pytest.approx(math.pi / 2)  # unknown: coin flip
    with pytest.raises(ValueError, match=r"heading_confidence .* got 1\.5"):
        messages.heading_flip_yaw_std(1.5)


def test_the_twin_yaw_differs_by_pi_whatever_the_tilt(dialect):
    # The front/back twin is R @ Rz(pi): its yaw in the sensor's FRD frame is yaw + pi for any attitude
    # and any camera tilt, which is what makes the two-point mixture of heading_flip_yaw_std exact.
    rng = np.random.default_rng(11)
    Rz_pi = np.diag([-1.0, -1.0, 1.0])
    for _ in range(20):
        R = random_rotation(rng)
        msg = messages.target_relative(dialect, make_track(attitude=R), (0, 0, 0, 0), 1)
        twin = messages.target_relative(dialect, make_track(attitude=R @ Rz_pi), (0, 0, 0, 0), 1)
        d = _yaw(quat_wxyz_to_matrix(np.array(twin.q_target))) - _yaw(
            quat_wxyz_to_matrix(np.array(msg.q_target))
        )
        assert math.remainder(d - math.pi, 2 * math.pi) == pytest.approx(0.0, abs=1e-5)


@pytest.mark.parametrize(
    ("confidence", "rotation_std", "yaw_std"),
    [
        (1.0, 0.02, 0.02),  # certain: the filter's own std
        (0.0, 0.02, math.pi / 2),  # coin flip: pi / 2 at least
        (float("nan"), 0.02, math.pi / 2),  # no front/back head: as unsure as a coin flip
        (0.82, 0.02, math.pi * math.sqrt(0.91 * 0.09)),
        (0.0, 1.8, 1.8),  # the tracker folded the doubt in already: not added a second time
        (0.82, float("nan"), float("nan")),  # the filter's std unknown stays unknown
    ],
)
def test_target_relative_yaw_std_never_claims_a_surer_heading(dialect, confidence, rotation_std, yaw_std):
    track = make_track(attitude=random_rotation(np.random.default_rng(2)), heading_confidence=confidence)
    track.rotation_std_rad = np.array([0.01, rotation_std, 0.03])
    decoded = _wire(dialect, messages.target_relative(dialect, track, messages.sensor_quaternion(GEO), 123))
    assert decoded.get_type() == "TARGET_RELATIVE" and decoded.id == 7
    if math.isnan(yaw_std):
        assert math.isnan(decoded.yaw_std)
    else:
        assert decoded.yaw_std == pytest.approx(yaw_std, rel=1e-6)  # float32 on the wire
    # The attitude is still the published one: the doubt lives in yaw_std, not in q_target.
    R_frd_body = quat_wxyz_to_matrix(np.array(decoded.q_target))
    np.testing.assert_allclose(
        R_frd_body, messages.FRD_FROM_CAM @ quat_wxyz_to_matrix(track.quaternion_wxyz), atol=1e-6
    )
    with pytest.raises(ValueError, match="heading_confidence"):
        messages.target_relative(dialect, make_track(heading_confidence=-0.2), (0, 0, 0, 0), 1)


def test_target_absolute_and_adsb_vehicle(dialect):
    rng = np.random.default_rng(5)
    R = random_rotation(rng)
    track = make_track(attitude=R, velocity_mps=(0.0, 0.0, 4.0))
    state = target_geodetic(track, GEO)
    lat, lon, alt = GEO.geodetic(track.position_m)
    absolute = messages.target_absolute(dialect, track, state, GEO, 99)
    assert absolute.lat == round(lat * 1e7) and absolute.lon == round(lon * 1e7)
    assert absolute.alt == pytest.approx(alt, abs=1e-3)
    caps = absolute.sensor_capabilities
    assert caps & dialect.TARGET_ABSOLUTE_SENSOR_CAPABILITY_POSITION
    assert caps & dialect.TARGET_ABSOLUTE_SENSOR_CAPABILITY_VELOCITY
    assert caps & dialect.TARGET_ABSOLUTE_SENSOR_CAPABILITY_ATTITUDE
    np.testing.assert_allclose(absolute.vel, R.T @ track.velocity_mps, atol=1e-5)  # body frame
    np.testing.assert_allclose(quat_wxyz_to_matrix(np.array(absolute.q_target)), GEO.R_ned_cam @ R, atol=1e-6)

    adsb = messages.adsb_vehicle(dialect, track, state, 0xF00000)
    v_ned = GEO.ned_from_cam(track.velocity_mps)
    assert adsb.ICAO_address == 0xF00007
    assert adsb.callsign == "DK000007"
    assert adsb.emitter_type == 14
    assert adsb.altitude == round(alt * 1000)
    assert adsb.heading == round(math.degrees(math.atan2(v_ned[1], v_ned[0])) % 360 * 100)
    assert adsb.hor_velocity == round(math.hypot(v_ned[0], v_ned[1]) * 100)
    assert adsb.ver_velocity == round(-v_ned[2] * 100)
    for flag in ("VALID_COORDS", "VALID_ALTITUDE", "VALID_HEADING", "VALID_VELOCITY", "VALID_CALLSIGN"):
        assert adsb.flags & getattr(dialect, "ADSB_FLAGS_" + flag), flag
    assert not adsb.flags & dialect.ADSB_FLAGS_SIMULATED


def test_adsb_hovering_track_has_no_heading(dialect):
    track = make_track(velocity_mps=(0.0, 0.0, 0.0))
    adsb = messages.adsb_vehicle(dialect, track, target_geodetic(track, GEO), 0xF00000, simulated=True)
    assert not adsb.flags & dialect.ADSB_FLAGS_VALID_HEADING
    assert adsb.flags & dialect.ADSB_FLAGS_SIMULATED


def test_ids_versions_and_time():
    # 0x000001..0x003FFF: unallocated by ICAO, drawn as drones by MAVProxy; never 0x000000.
    assert icao_address(7) == 0x000007 and icao_address(16383) == 0x003FFF
    assert icao_address(16383 + 5) == 0x000005 and icao_address(0) == 0x003FFF
    assert icao_address(7, 0xF00000) == 0xF00007
    assert callsign(42) == "DK000042" and len(callsign(123456789)) == 8
    with pytest.raises(ValueError, match="icao_base"):
        validate_icao_base(0xF00001)
    with pytest.raises(ValueError, match="statuses"):
        validate_statuses(["confirmed", "flying"])
    assert messages.encode_version("1.2.3") == (1 << 24) | (2 << 16) | (3 << 8) | 255
    assert messages.encode_version("0.1.0.dev4") & 0xFF == 0
    assert unix_time_us(1_700_000_000_123_456_789) == 1_700_000_000_123_456
    assert abs(unix_time_us(5_000_000) - time.time_ns() // 1000) < 5_000_000  # file PTS -> now


# ---------------------------------------------------------------- stream intervals


def test_stream_rates_keep_the_asked_rate():
    rates = StreamRates([511])
    assert all(rates.should_send(511, 1, t) for t in range(0, 10**9, 10**8))  # default: every update
    rates.set_interval(511, 100_000)  # 10 Hz asked, updates at 30 Hz for 3 s
    frame_ns = 10**9 // 30
    sent = sum(rates.should_send(511, 1, i * frame_ns) for i in range(90))
    assert 29 <= sent <= 31
    assert sum(rates.should_send(511, 2, i * frame_ns) for i in range(90)) == sent  # per track
    rates.set_interval(511, -1)
    assert not any(rates.should_send(511, 1, i * frame_ns) for i in range(90))
    with pytest.raises(ValueError, match="interval_us"):
        rates.set_interval(511, -2)
    with pytest.raises(KeyError):
        rates.set_interval(0, 1000)


# ---------------------------------------------------------------- signing files


def test_signing_key_file_formats(tmp_path):
    raw = bytes(range(32))
    (tmp_path / "raw.key").write_bytes(raw)
    (tmp_path / "hex.key").write_text(raw.hex() + "\n")
    assert read_signing_key(tmp_path / "raw.key") == raw
    assert read_signing_key(tmp_path / "hex.key") == raw
    secret = b"0123456789abcdef0123456789abcd"  # 30 bytes: refused, and never echoed
    (tmp_path / "short.key").write_bytes(secret)
    with pytest.raises(SigningKeyError, match="32 raw bytes or 64 hex digits") as err:
        read_signing_key(tmp_path / "short.key")
    assert secret.decode() not in str(err.value) and "short.key" in str(err.value)
    with pytest.raises(SigningKeyError, match="cannot read"):
        read_signing_key(tmp_path / "missing.key")


def test_signing_timestamp_store(tmp_path):
    store = SigningTimestampStore(tmp_path / "ts")
    assert store.load() is None
    assert abs(store.initial_timestamp() - now_signing_timestamp()) < 100_000 * 5
    future = now_signing_timestamp() + 100_000 * 3600  # saved by a run whose clock was an hour ahead
    assert store.save(future)
    assert store.load() == future
    assert store.initial_timestamp() > future  # never go back
    (tmp_path / "ts").write_text("garbage")
    assert store.load() is None
    assert not SigningTimestampStore(tmp_path / "no-such-dir" / "ts").save(1)
