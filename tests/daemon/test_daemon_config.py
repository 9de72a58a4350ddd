"""dronekey-daemon's config: YAML + flags validated by pydantic, one-line errors naming the key, the
value and what is allowed, --validate-config / --print-config, and exit code 2 for bad usage.

The CLI runs as a real process (exit codes, stderr); the loader is also called in-process.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import typing
from pathlib import Path

import paths
import pytest
import yaml
from daemon_media import encode_clip
from site_files import write_site

from dronekey.daemon.config.daemon_config import DaemonConfig
from dronekey.daemon.config.errors import ConfigError
from dronekey.daemon.config.loading import config_to_yaml, load_config
from dronekey.daemon.errors import ExitCode
from dronekey.geometry.camera import CameraModel


def run_cli(*args: str, cwd: Path | None = None, timeout: float = 60) -> subprocess.CompletedProcess:
    env = {
        k: v for k, v in os.environ.items() if k not in ("NOTIFY_SOCKET", "JOURNAL_STREAM", "STATE_DIRECTORY")
    }
    return subprocess.run(
        [sys.executable, "-m", "dronekey.daemon.cli", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if "config error" in line]


@pytest.fixture(scope="module")
def h264_clip(tmp_path_factory) -> Path:
    return encode_clip(tmp_path_factory.mktemp("clip") / "clip.mp4", frames=10)


@pytest.fixture
def write_config(tmp_path):
    def write(text: str) -> Path:
        path = tmp_path / "config.yaml"
        path.write_text(text)
        return path

    return write


# ------------------------------------------------------------------------------------ errors
def test_unknown_key_names_the_dotted_key_and_the_allowed_keys(write_config):
    cfg = write_config("source: {uri: sim://seq13}\nzenoh:\n  mod: client\n")
    result = run_cli("--config", str(cfg), "--validate-config")
    assert result.returncode == ExitCode.USAGE
    (line,) = error_lines(result.stderr)
    assert "zenoh.mod: unknown key" in line
    assert "mode" in line and "connect" in line and "scouting" in line
    assert "Traceback" not in result.stderr


def test_bad_type_names_key_value_and_what_is_allowed(write_config):
    cfg = write_config("source: {uri: sim://seq13}\nmavlink:\n  sysid: abc\n")
    result = run_cli("--config", str(cfg), "--validate-config")
    assert result.returncode == ExitCode.USAGE
    (line,) = error_lines(result.stderr)
    assert "mavlink.sysid = 'abc'" in line
    assert "valid integer" in line
    assert "Traceback" not in result.stderr


def test_bad_enum_lists_the_choices(write_config):
    cfg = write_config("source: {uri: sim://seq13}\nzenoh: {mode: router}\n")
    result = run_cli("--config", str(cfg), "--validate-config")
    assert result.returncode == ExitCode.USAGE
    (line,) = error_lines(result.stderr)
    assert "zenoh.mode = 'router'" in line and "'peer' or 'client'" in line


def test_one_line_per_problem_and_the_flag_is_named(write_config):
    cfg = write_config("source: {uri: sim://seq13, queue_size: 0}\nlog: {level: loud}\n")
    result = run_cli("--config", str(cfg), "--mavlink-sysid", "255", "--validate-config")
    assert result.returncode == ExitCode.USAGE
    lines = error_lines(result.stderr)
    assert len(lines) == 3, result.stderr
    joined = "\n".join(lines)
    assert "source.queue_size = 0" in joined and "greater than or equal to 1" in joined
    assert "log.level = 'loud'" in joined
    assert "mavlink.sysid = '255' (from --mavlink-sysid)" in joined and "less than or equal to 254" in joined


def test_yaml_syntax_error_gives_the_line(write_config):
    cfg = write_config("source:\n  uri: [unclosed\n")
    result = run_cli("--config", str(cfg), "--validate-config")
    assert result.returncode == ExitCode.USAGE
    (line,) = error_lines(result.stderr)
    assert "invalid YAML" in line and "line" in line


def test_missing_config_file_is_usage_error(tmp_path):
    result = run_cli("--config", str(tmp_path / "absent.yaml"), "--validate-config")
    assert result.returncode == ExitCode.USAGE
    assert "file not found" in result.stderr


def test_sbs1_without_camera_geo_is_refused():
    result = run_cli("--source", "sim://seq13", "--sbs1-listen", "127.0.0.1:30003", "--validate-config")
    assert result.returncode == ExitCode.USAGE
    assert "sbs1.listen" in result.stderr and "--camera-geo" in result.stderr


def test_bad_camera_geo_and_zenoh_endpoint():
    result = run_cli(
        "--source", "sim://seq13", "--camera-geo", "91,0,10", "--zenoh-connect", "localhost:7447",
        "--validate-config",
    )  # fmt: skip
    assert result.returncode == ExitCode.USAGE
    joined = "\n".join(error_lines(result.stderr))
    assert "camera.geo = '91,0,10' (from --camera-geo)" in joined and "latitude" in joined
    assert "zenoh.connect" in joined and "tcp/HOST:PORT" in joined


def test_camera_extrinsics_give_the_pose_and_its_errors_name_the_file(tmp_path):
    site = write_site(
        tmp_path / "site.json", [("cam0", 0.0, 0.0, (0, 0, 2)), ("cam1", 90.0, 0.0, (20, 0, 2))]
    )
    config = load_config(None, {"camera.id": ("cam1", "--camera-id"), "camera.extrinsics": (str(site), "-")})
    placement = config.camera.placement()
    assert placement.source == "extrinsics" and placement.site.t_site_cam_m.tolist() == [20.0, 0.0, 2.0]
    assert abs(config.camera.camera_geo().yaw_deg - 90.0) < 1e-3  # the geodetic outputs get it too
    result = run_cli(
        "--source", "sim://seq13", "--camera-id", "mast", "--camera-extrinsics", str(site),
        "--validate-config",
    )  # fmt: skip
    assert result.returncode == ExitCode.USAGE
    (line,) = error_lines(result.stderr)
    assert str(site) in line and "'mast'" in line and "cam0" in line
    result = run_cli(
        "--source", "sim://seq13", "--camera-extrinsics", str(site), "--camera-geo", "47,8,400",
        "--validate-config",
    )  # fmt: skip
    assert result.returncode == ExitCode.USAGE and "set one" in result.stderr
    (tmp_path / "bad.json").write_text('{"format": "other"}')
    result = run_cli(
        "--source", "sim://seq13", "--camera-extrinsics", str(tmp_path / "bad.json"), "--validate-config"
    )
    assert result.returncode == ExitCode.USAGE and "bad.json" in result.stderr
    assert "Traceback" not in result.stderr


# ------------------------------------------------------------------------------------ exhaustion
_ALIAS_BOMB = (
    "source: {uri: sim://seq13}\nmavlink:\n  sysid: [&a [lol,lol,lol,lol,lol,lol,lol,lol,lol], "
    + ", ".join(f"&{b} [{', '.join([f'*{a}'] * 9)}]" for a, b in zip("abcdefgh", "bcdefghi", strict=True))
    + "]\n"
)  # under 1 KB; 9^9 strings once expanded


def _bounded() -> None:
    """The child's limits: 10 s of CPU and 1 GiB of address space (the bomb once took 55 s and 3 GB)."""
    resource.setrlimit(resource.RLIMIT_CPU, (10, 10))
    resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))


def test_yaml_alias_bomb_is_one_line_and_exit_2(write_config):
    cfg = write_config(_ALIAS_BOMB)
    assert cfg.stat().st_size < 1024
    result = subprocess.run(
        [sys.executable, "-m", "dronekey.daemon.cli", "--config", str(cfg), "--validate-config"],
        capture_output=True, text=True, timeout=60, preexec_fn=_bounded,
    )  # fmt: skip
    assert result.returncode == ExitCode.USAGE, result.stderr
    (line,) = error_lines(result.stderr)
    assert "line 3 column" in line and "anchors and aliases (&a) are not allowed" in line
    assert "Traceback" not in result.stderr


def test_duplicate_key_is_named_with_both_lines(write_config):
    cfg = write_config("source: {uri: sim://seq13}\nzenoh:\n  mode: client\n  connect: []\n  mode: peer\n")
    with pytest.raises(ConfigError) as err:
        load_config(cfg)
    assert str(err.value) == f"config error: zenoh.mode: duplicate key (in {cfg} line 5; first on line 3)"
    cfg = write_config("source: {uri: sim://seq13}\nsource: {uri: sim://seq12}\n")
    with pytest.raises(
        ConfigError, match=r"^config error: source: duplicate key .* line 2; first on line 1\)$"
    ):
        load_config(cfg)


def test_oversized_and_deeply_nested_files_are_refused(write_config):
    cfg = write_config("# padding\n" * 200_000)  # 2 MB of comments
    with pytest.raises(ConfigError, match=r"larger than 1000 KB; a config file is a few KB$"):
        load_config(cfg)
    cfg = write_config("source: " + "[" * 5000 + "]" * 5000 + "\n")  # would overflow the recursive composer
    with pytest.raises(ConfigError, match=r"line 1 column \d+: nested deeper than 16 levels$"):
        load_config(cfg)


def test_values_are_cut_before_the_error_is_formatted():
    """A value with 10^13 leaves (shared, so it costs nothing to hold) and a megabyte string: each
    error line is short, and is built without walking the value."""
    bomb: list = ["lol"] * 10
    for _ in range(12):
        bomb = [bomb] * 10
    with pytest.raises(ConfigError) as err:
        load_config(
            None, {"mavlink.sysid": (bomb, "--mavlink-sysid"), "camera.id": ("b" * 10**6, "--camera-id")}
        )
    lines = str(err.value).splitlines()
    assert len(lines) == 2 and all(len(line) < 250 for line in lines), lines
    assert any(line.startswith("config error: mavlink.sysid = [[[[") for line in lines)
    assert any(line.startswith("config error: camera.id = 'bbbb") and "..." in line for line in lines)


# ------------------------------------------------------------------------------------ checks
def test_validate_config_accepts_a_good_config(tmp_path):
    example = paths.ROOT / "daemon" / "config.example.yaml"
    text = (
        example.read_text()
        .replace("uri: /dev/video0", "uri: sim://seq13")
        .replace("calibration: camera.yaml", "calibration: null")
    )
    cfg = tmp_path / "config.yaml"
    cfg.write_text(text)
    result = run_cli("--config", str(cfg), "--validate-config")
    assert result.returncode == ExitCode.OK, result.stderr
    assert "config OK" in result.stderr


def test_validate_config_needs_a_source():
    result = run_cli("--validate-config")
    assert result.returncode == ExitCode.USAGE
    assert "no source" in result.stderr and "--source" in result.stderr


def test_missing_video_is_one_line_and_exit_2(tmp_path):
    result = run_cli("--source", str(tmp_path / "absent.mp4"), "--no-zenoh", "--no-mavlink", "--no-mcap")
    assert result.returncode == ExitCode.USAGE
    errors = [line for line in result.stderr.splitlines() if "ERROR" in line]
    assert len(errors) == 1 and "video file not found" in errors[0], result.stderr
    assert "Traceback" not in result.stderr


def test_video_without_calibration_says_how_to_get_one(tmp_path, h264_clip):
    result = run_cli("--source", str(h264_clip), "--no-zenoh", "--no-mavlink", "--no-mcap")
    assert result.returncode == ExitCode.USAGE
    errors = [line for line in result.stderr.splitlines() if "ERROR" in line]
    assert len(errors) == 1, result.stderr
    assert "no calibration" in errors[0] and "--calib" in errors[0] and "dronekey-calib" in errors[0]


def test_unreadable_calibration_and_wrong_aspect_are_exit_2(tmp_path, h264_clip):
    bad = tmp_path / "bad.yaml"
    bad.write_text("%YAML:1.0\nfoo: 1\n")
    result = run_cli("--source", str(h264_clip), "--calib", str(bad), "--validate-config")
    assert result.returncode == ExitCode.USAGE
    assert "camera_matrix" in result.stderr and "Traceback" not in result.stderr
    wide = tmp_path / "wide.yaml"
    CameraModel.from_fov(640, 360, 70).save_yaml(wide)  # 16:9 for a 4:3 clip
    result = run_cli(
        "--source", str(h264_clip), "--calib", str(wide), "--no-zenoh", "--no-mavlink", "--no-mcap"
    )
    assert result.returncode == ExitCode.USAGE
    assert "aspect ratio differs" in result.stderr and "Traceback" not in result.stderr


def test_missing_model_and_unknown_source_scheme():
    result = run_cli("--source", "sim://seq13", "--model", "/nonexistent/model.onnx", "--validate-config")
    assert result.returncode == ExitCode.USAGE
    assert "model.path = '/nonexistent/model.onnx' (from --model)" in result.stderr
    result = run_cli("--source", "ftp://host/clip.mp4", "--validate-config")
    assert result.returncode == ExitCode.USAGE
    assert "unknown scheme 'ftp'" in result.stderr


def test_validate_config_loads_the_model(tmp_path):
    """A file that exists but is no DroneKey model fails --validate-config, not the first real run."""
    not_a_model = tmp_path / "model.onnx"
    not_a_model.write_bytes(b"not an ONNX file")
    result = run_cli("--source", "sim://seq13", "--model", str(not_a_model), "--validate-config")
    assert result.returncode == ExitCode.USAGE, result.stderr
    assert f"model: {not_a_model} is not a loadable ONNX model" in result.stderr
    assert "Traceback" not in result.stderr


def test_print_config_is_the_effective_config_and_loads_back(tmp_path, write_config):
    cfg = write_config("source: {uri: sim://seq12}\nzenoh: {mode: client, connect: [tcp/10.0.0.1:7447]}\n")
    result = run_cli("--config", str(cfg), "--zenoh-mode", "peer", "--no-mcap", "--print-config")
    assert result.returncode == ExitCode.OK, result.stderr
    printed = yaml.safe_load(result.stdout)
    assert printed["source"]["uri"] == "sim://seq12"  # from the file
    assert printed["zenoh"]["mode"] == "peer"  # the flag wins
    assert printed["zenoh"]["connect"] == ["tcp/10.0.0.1:7447"]
    assert printed["mcap"]["enabled"] is False
    assert printed["mavlink"]["sysid"] == 42  # a default
    again = tmp_path / "printed.yaml"
    again.write_text(result.stdout)
    assert config_to_yaml(load_config(again)) == result.stdout


def test_help_explains_sources_and_exit_codes():
    result = run_cli("--help")
    assert result.returncode == 0
    for text in ("sim://seq11", "/dev/video0", "rtsp://", "exit codes", "143", "--mcap-dir", "--camera-geo"):
        assert text in result.stdout


# ------------------------------------------------------------------------------------ in-process
def test_flags_override_the_file_and_relative_paths_follow_the_file(tmp_path):
    (tmp_path / "etc").mkdir()
    CameraModel.from_fov(640, 480, 60).save_yaml(tmp_path / "etc" / "camera.yaml")
    cfg = tmp_path / "etc" / "config.yaml"
    cfg.write_text(
        "source: {uri: clip.mp4}\ncamera: {calibration: camera.yaml, id: roof}\nmcap: {dir: logs}\n"
    )
    config = load_config(cfg, {"camera.id": ("mast", "--camera-id")})
    assert config.camera.id == "mast"
    assert config.camera.calibration == tmp_path / "etc" / "camera.yaml"
    assert config.source.uri == str(tmp_path / "etc" / "clip.mp4")
    assert config.mcap.dir == tmp_path / "etc" / "logs"


def test_device_numbers_and_urls_are_not_paths(tmp_path):
    cfg = tmp_path / "config.yaml"
    cfg.write_text("source: {uri: '0'}\n")
    assert load_config(cfg).source.uri == "0"
    cfg.write_text("source: {uri: 'rtsp://cam/stream'}\n")
    assert load_config(cfg).source.uri == "rtsp://cam/stream"


def test_mcap_dir_defaults_to_the_systemd_state_directory(monkeypatch, tmp_path):
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path / "state"))
    assert load_config(None).mcap.dir == tmp_path / "state" / "mcap"
    monkeypatch.delenv("STATE_DIRECTORY")
    assert load_config(None).mcap.dir == Path("mcap").absolute()


def test_every_section_forbids_extra_keys():
    def models(model):
        yield model
        for field in model.model_fields.values():
            annotation = field.annotation
            if isinstance(annotation, type) and hasattr(annotation, "model_fields"):
                yield from models(annotation)

    for model in models(DaemonConfig):
        assert model.model_config.get("extra") == "forbid", model.__name__


def test_nested_list_errors_are_indexed(tmp_path):
    with pytest.raises(ConfigError) as info:
        load_config(
            None, {"source.v4l2.fourcc": ("MJPEG", "--x"), "zenoh.listen": (["tcp/0.0.0.0:1", 5], "--y")}
        )
    text = str(info.value)
    assert "source.v4l2.fourcc = 'MJPEG' (from --x): must be 4 ASCII characters" in text
    assert "zenoh.listen[1] = 5" in text


# ------------------------------------------------------------------------------------ tracking
def test_the_tracking_section_reaches_the_pipeline(write_config):
    from dronekey.daemon.app import default_pipeline_factory

    cfg = write_config(
        "source: {uri: sim://seq13}\n"
        "tracking: {max_tracks: 1, search_more_every: 12, search_every: 0, confirm_min_change: 0,"
        " confirm_drone_p: 0.7, wide_look_every: 0, heading_full_spread_px: 43.5, measure_every: 2}\n"
    )
    config = load_config(cfg, {})
    pipeline = default_pipeline_factory(CameraModel.from_fov(1920, 1080, 70), config)
    assert pipeline.poses.tracker.config.max_tracks == 1
    assert pipeline.poses.tracker.config.confirm_min_change == 0.0
    assert pipeline.poses.tracker.config.confirm_drone_p == 0.7
    assert pipeline.poses.tracker.config.heading_full_spread_px == 43.5
    assert (pipeline.search_more_every, pipeline.search_every, pipeline.max_search_candidates) == (12, 0, 2)
    assert pipeline.wide_look_every == 0
    assert pipeline.measure_every == 2


def test_the_model_section_chooses_the_shipped_front_back_classifier(write_config):
    from dronekey.daemon.app import default_pipeline_factory
    from dronekey.daemon.config.model import ModelConfig
    from dronekey.perception.heading_model import HEADING_MODEL_ALIASES, SHIPPED_HEADING_MODELS

    allowed = typing.get_args(ModelConfig.model_fields["front_back_net"].annotation)
    assert set(allowed) == set(SHIPPED_HEADING_MODELS) | set(HEADING_MODEL_ALIASES)  # nothing else
    assert ModelConfig().front_back_net == "gated"
    camera = CameraModel.from_fov(1920, 1080, 70)
    for net, name in (
        ("gated", "dronekey_heading.onnx"),
        ("small", "dronekey_heading.onnx"),  # its former name, in configs written before
        ("deep", "dronekey_heading_deep.onnx"),
    ):
        cfg = write_config(f"source: {{uri: sim://seq13}}\nmodel: {{front_back_net: {net}}}\n")
        config = load_config(cfg, {})
        assert default_pipeline_factory(camera, config).model.heading_model.path.name == name
    result = run_cli("--config", str(write_config("model: {front_back_net: huge}\n")), "--validate-config")
    assert result.returncode == ExitCode.USAGE
    (line,) = error_lines(result.stderr)
    assert "model.front_back_net = 'huge'" in line


def test_other_airframes_widen_every_published_range_doubt(write_config):
    """model.drone_alternatives reaches the pipeline: the published range doubt is kept at least the
    airframes' size difference (Air 2S beside Mini 2: 302 / 213 mm diagonals), the info says so,
    and an unknown airframe is one line naming it."""
    from dronekey.daemon.app import default_pipeline_factory
    from dronekey.geometry.drone_spec import load_spec
    from dronekey.pipeline import airframe_range_span

    camera = CameraModel.from_fov(1920, 1080, 70)
    mini2, air2s = load_spec("mini2"), load_spec("air2s")
    span = airframe_range_span(mini2, (air2s,))
    assert span == pytest.approx(air2s.diagonal_m / mini2.diagonal_m - 1) and 0.41 < span < 0.42
    assert airframe_range_span(air2s, (mini2,)) == pytest.approx(1 - mini2.diagonal_m / air2s.diagonal_m)
    assert airframe_range_span(mini2, ()) == 0.0
    one = default_pipeline_factory(camera, load_config(write_config("source: {uri: sim://seq13}\n"), {}))
    assert one.info()["drone_alternatives"] == [] and one.info()["range_std_floor"] == 0.07  # as before
    cfg = write_config("source: {uri: sim://seq13}\nmodel: {drone_alternatives: [air2s]}\n")
    mixed = default_pipeline_factory(camera, load_config(cfg, {}))
    assert mixed.poses.tracker.config.range_std_floor == pytest.approx(span)
    assert mixed.info()["drone_alternatives"] == ["air2s"] and mixed.spec.name == "mini2"
    bad = write_config("model: {drone_alternatives: [air2s, phantom4]}\n")
    result = run_cli("--config", str(bad), "--validate-config")
    assert result.returncode == ExitCode.USAGE
    (line,) = error_lines(result.stderr)
    assert "model.drone_alternatives = ['air2s', 'phantom4']" in line and "unknown drone 'phantom4'" in line


def test_a_bad_tracking_value_is_one_line(write_config):
    cfg = write_config("source: {uri: sim://seq13}\ntracking: {search_more_every: 0}\n")
    result = run_cli("--config", str(cfg), "--validate-config")
    assert result.returncode == ExitCode.USAGE
    (line,) = error_lines(result.stderr)
    assert "tracking.search_more_every = 0" in line and "greater than or equal to 1" in line
