"""``dronekey-daemon``: track drones in a video source and publish them over Zenoh, MAVLink, MCAP
and SBS-1. Flags override the config file (``--config``); ``--help`` explains sources, defaults
and exit codes; ``docs/daemon.md`` is the user guide.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import Any

import dronekey
from dronekey.daemon.errors import EXIT_CODE_HELP, DaemonError, ExitCode, UsageError
from dronekey.daemon.logs import detect_log_mode, setup_logging
from dronekey.daemon.malloc_arenas import limit_malloc_arenas
from dronekey.daemon.sources import SIM_SOURCES

__all__ = ["build_parser", "main"]

log = logging.getLogger("dronekey.daemon")

_EPILOG = f"""sources (--source or source.uri):
  clip.mp4, clip.avi ...   a video file (H.264 MP4, MJPEG, MPEG-4), read in order; ends with exit 0
  DIR                      a folder of images, natural file-name order (source.image_fps sets time)
  /dev/video0 or 0         a V4L2 camera (source.v4l2: width, height, fps, fourcc)
  rtsp:// http:// tcp:// udp://URL
                           a network stream (reconnected with backoff when lost)
  {SIM_SOURCES}
                           a simulator preset rendered on the fly (its camera is the calibration)

calibration: --calib FILE, else the sequence JSON (same stem) or camera.yaml beside the video,
  else the sim preset's camera; otherwise the daemon stops and says how to make one (dronekey-calib).
  Intrinsics are scaled to the source's resolution (same aspect ratio only).

defaults: Zenoh peer mode listening on 127.0.0.1 only, no scouting; MAVLink 2 to
  udpout:127.0.0.1:14550 as system 42 component 191, unsigned; MCAP into $STATE_DIRECTORY/mcap
  under systemd, else ./mcap; no SBS-1; no CoT. `--print-config` shows every setting.

{EXIT_CODE_HELP}

examples:
  dronekey-daemon --source sim://seq13
  dronekey-daemon --source seq13.mp4 --realtime --no-mavlink
  dronekey-daemon --config /etc/dronekey/config.yaml --validate-config
"""


def build_parser() -> argparse.ArgumentParser:
    """The argument parser; every flag defaults to "not given" so the config file's value stands."""
    p = argparse.ArgumentParser(
        prog="dronekey-daemon",
        description="Track drones in a video source (DroneKey keypoints, PnP 6DoF, Kalman tracks)\n"
        "and publish the tracks over Zenoh, MAVLink and SBS-1 and into an MCAP log.\n"
        "Flags override the config file; docs/daemon.md is the user guide.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        argument_default=argparse.SUPPRESS,
    )
    p.add_argument("--version", action="version", version=f"%(prog)s {dronekey.__version__}")
    g = p.add_argument_group("source and camera")
    g.add_argument(
        "--source", metavar="SRC", help=f"video file, image folder, /dev/videoN, stream URL, {SIM_SOURCES}"
    )
    g.add_argument("--config", metavar="FILE", type=Path, help="YAML config file (flags override it)")
    g.add_argument("--calib", metavar="FILE", help="OpenCV calibration YAML (default: beside the video)")
    g.add_argument("--camera-id", metavar="ID", help="camera id in Zenoh keys and MCAP frames (default cam0)")
    g.add_argument(
        "--camera-geo",
        metavar="LAT,LON,ALT_M,YAW,PITCH,ROLL",
        help="camera's WGS84 position and mount attitude (degrees, metres above the ellipsoid)",
    )
    g.add_argument(
        "--camera-extrinsics",
        metavar="FILE",
        help="site file (docs/fleet.md): this camera id's pose in the site frame, the alternative to "
        "--camera-geo",
    )
    g.add_argument("--model", metavar="FILE", help="ONNX keypoint model (default: the shipped model)")
    g.add_argument("--drone", metavar="NAME", help="drone spec: mini2 (default), air2s, or a spec YAML")
    g.add_argument(
        "--realtime", action="store_const", const=True, help="pace files and sim at their frame rate"
    )
    g.add_argument(
        "--loop", action="store_const", const=True, help="restart a file, folder or sim at its end"
    )
    g.add_argument("--max-frames", metavar="N", help="stop (exit 0) after N processed frames")
    g = p.add_argument_group("Zenoh")
    g.add_argument("--zenoh-mode", metavar="peer|client", help="session mode (default peer)")
    g.add_argument(
        "--zenoh-connect", metavar="EP", action="append", help="endpoint to connect to (repeatable)"
    )
    g.add_argument("--zenoh-listen", metavar="EP", action="append", help="endpoint to listen on (repeatable)")
    scouting = g.add_mutually_exclusive_group()
    scouting.add_argument(
        "--zenoh-scouting",
        action="store_const",
        const=True,
        help="multicast and gossip scouting on: discoverable on the network (default off)",
    )
    scouting.add_argument(
        "--no-zenoh-scouting", action="store_const", const=True, help="scouting off (the default)"
    )
    g.add_argument("--no-zenoh", action="store_const", const=True, help="no Zenoh output")
    g = p.add_argument_group("MAVLink and SBS-1")
    g.add_argument(
        "--mavlink", metavar="URL", help="pymavlink connection string (default udpout:127.0.0.1:14550)"
    )
    g.add_argument("--mavlink-sysid", metavar="N", help="our system id, 1-254 (default 42)")
    g.add_argument("--mavlink-compid", metavar="N", help="our component id, 1-255 (default 191)")
    g.add_argument(
        "--mavlink-signing-key", metavar="FILE", help="32-byte signing key file (default unsigned)"
    )
    g.add_argument("--no-mavlink", action="store_const", const=True, help="no MAVLink output")
    g.add_argument(
        "--sbs1-listen",
        metavar="[HOST:]PORT",
        help="serve SBS-1 (BaseStation) lines on 127.0.0.1:PORT, or on HOST; needs --camera-geo",
    )
    g = p.add_argument_group("SAPIENT (BSI Flex 335 v2.0)")
    g.add_argument(
        "--sapient",
        metavar="[HOST:]PORT",
        help="report tracks as a SAPIENT sensor node to the decision node or middleware at HOST:PORT "
        "(127.0.0.1 given only a port); lat/lon with --camera-geo, else camera range-bearing (default off)",
    )
    g = p.add_argument_group("TAK Cursor-on-Target")
    g.add_argument(
        "--cot",
        metavar="URL",
        help="send tracks to TAK as CoT events: udp+multicast://239.2.3.1:6969 (ATAK/WinTAK multicast), "
        "udp://HOST:PORT, tcp://HOST:PORT or tls://HOST:PORT (TAK Server); needs --camera-geo (default off)",
    )
    g.add_argument("--cot-cert", metavar="FILE", help="PEM client certificate for a tls:// TAK Server")
    g.add_argument("--cot-key", metavar="FILE", help="PEM private key of --cot-cert")
    g.add_argument("--cot-ca", metavar="FILE", help="PEM CA certificate that signed the TAK Server's")
    g = p.add_argument_group("MCAP log")
    mcap = g.add_mutually_exclusive_group()
    mcap.add_argument("--mcap-dir", metavar="DIR", help="folder of the MCAP files")
    mcap.add_argument("--no-mcap", action="store_const", const=True, help="no MCAP log")
    g.add_argument(
        "--foxglove-ws",
        metavar="[HOST:]PORT",
        help="serve the MCAP log's channels live to Foxglove (Open connection > Foxglove WebSocket) on "
        "127.0.0.1:PORT, or on HOST (0.0.0.0: the network); works with --no-mcap too (default off)",
    )
    g = p.add_argument_group("annotated video")
    g.add_argument(
        "--annotated-video",
        metavar="FILE",
        help="write every frame with its tracks drawn on it (keypoints 1-4, body axes, id, range, "
        "heading) as H.264 to FILE (.mp4, .mkv or .mov); frames the encoder cannot keep up with are "
        "dropped and counted (default off)",
    )
    g = p.add_argument_group("checks and logging")
    g.add_argument(
        "--validate-config",
        action="store_const",
        const=True,
        help="check the config and the flags (and that the source, calibration and model load); exit 0 or 2",
    )
    g.add_argument(
        "--print-config", action="store_const", const=True, help="print the effective config as YAML"
    )
    g.add_argument("--log-level", metavar="LEVEL", help="DEBUG, INFO (default), WARNING or ERROR")
    return p


# flag attribute -> (dotted config key, value transform)
_FLAG_KEYS: dict[str, tuple[str, Any]] = {
    "source": ("source.uri", None),
    "calib": ("camera.calibration", None),
    "camera_id": ("camera.id", None),
    "camera_geo": ("camera.geo", None),
    "camera_extrinsics": ("camera.extrinsics", None),
    "model": ("model.path", None),
    "drone": ("model.drone", None),
    "realtime": ("source.realtime", None),
    "loop": ("source.loop", None),
    "max_frames": ("source.max_frames", None),
    "zenoh_mode": ("zenoh.mode", None),
    "zenoh_connect": ("zenoh.connect", None),
    "zenoh_listen": ("zenoh.listen", None),
    "zenoh_scouting": ("zenoh.scouting", None),
    "no_zenoh_scouting": ("zenoh.scouting", lambda v: not v),
    "no_zenoh": ("zenoh.enabled", lambda v: not v),
    "mavlink": ("mavlink.url", None),
    "mavlink_sysid": ("mavlink.sysid", None),
    "mavlink_compid": ("mavlink.compid", None),
    "mavlink_signing_key": ("mavlink.signing_key", None),
    "no_mavlink": ("mavlink.enabled", lambda v: not v),
    "sbs1_listen": ("sbs1.listen", None),
    "sapient": ("sapient.connect", None),
    "cot": ("cot.url", None),
    "cot_cert": ("cot.tls.certificate", None),
    "cot_key": ("cot.tls.private_key", None),
    "cot_ca": ("cot.tls.root_ca", None),
    "mcap_dir": ("mcap.dir", None),
    "no_mcap": ("mcap.enabled", lambda v: not v),
    "foxglove_ws": ("foxglove_ws.listen", None),
    "annotated_video": ("annotated_video.path", None),
    "log_level": ("log.level", None),
}


def collect_overrides(args: argparse.Namespace) -> dict[str, tuple[Any, str]]:
    """Dotted key -> (value, ``--flag``) for every flag given on the command line."""
    overrides = {}
    for attr, (dotted, transform) in _FLAG_KEYS.items():
        if hasattr(args, attr):
            value = getattr(args, attr)
            overrides[dotted] = (transform(value) if transform else value, "--" + attr.replace("_", "-"))
    return overrides


def _validate(config) -> None:
    """--validate-config beyond the schema: the source, its calibration and the model must be usable."""
    from dronekey.daemon.app import build_pipeline
    from dronekey.daemon.calibration import resolve_calibration
    from dronekey.daemon.sources import SourceOpenError, make_reader

    reader = make_reader(config.source)
    if not reader.live:
        try:
            reader.open()
        except SourceOpenError as exc:
            raise UsageError(f"source: {exc}") from None
        finally:
            reader.close()
    elif reader.kind == "v4l2" and not Path(reader.description).exists():
        log.warning("%s does not exist now; the daemon will wait for it", reader.description)
    camera, origin = resolve_calibration(config.camera.calibration, reader)
    log.info("calibration: %s (%dx%d)", origin, camera.width, camera.height)
    build_pipeline(camera, config)  # loads the model and the drone spec as a run would


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``dronekey-daemon``; returns the exit code (see ``errors.ExitCode``)."""
    limit_malloc_arenas()  # before any thread allocates: a hundred MiB less a camera
    args = build_parser().parse_args(argv)
    mode = detect_log_mode()
    status_line = setup_logging("INFO", mode)
    from dronekey.daemon.config.errors import ConfigError
    from dronekey.daemon.config.loading import config_to_yaml, load_config

    try:
        config = load_config(getattr(args, "config", None), collect_overrides(args))
    except ConfigError as exc:
        for line in str(exc).splitlines():
            log.error("%s", line)
        return ExitCode.USAGE
    logging.getLogger().setLevel(config.log.level)
    from dronekey.daemon.sources.opencv_readers import quiet_native_logs

    quiet_native_logs(verbose=config.log.level == "DEBUG")
    if getattr(args, "print_config", False):
        sys.stdout.write(config_to_yaml(config))
        sys.stdout.flush()
    if getattr(args, "validate_config", False):
        try:
            _validate(config)
        except UsageError as exc:
            log.error("%s", exc)
            return ExitCode.USAGE
        log.info("config OK")
        return ExitCode.OK
    if getattr(args, "print_config", False):
        return ExitCode.OK
    code = _run(config, status_line)
    if argv is None:  # the console script: everything is closed, skip interpreter finalisation
        _exit_now(code)
    return int(code)


def _run(config, status_line) -> ExitCode:
    from dronekey.daemon.app import DaemonApp
    from dronekey.daemon.signals import SignalMonitor
    from dronekey.daemon.systemd import SystemdNotifier

    signals = SignalMonitor(deadline_s=5.0)
    signals.install()
    notifier = SystemdNotifier()
    log.info("dronekey-daemon %s starting (camera %s)", dronekey.__version__, config.camera.id)
    try:
        app = DaemonApp(config, signals=signals, notifier=notifier, status_line=status_line)
        code = app.run()
    except DaemonError as exc:
        log.error("%s", exc)
        code = exc.exit_code
    except Exception:
        log.exception("unexpected failure")
        code = ExitCode.RUNTIME_FAILURE
    finally:
        signals.finished()
        notifier.close()
    if signals.exit_code is not None and code == ExitCode.OK:
        code = signals.exit_code
    log.info("exit %d", int(code))
    return code


def _exit_now(code: int) -> None:
    """End the process once the outputs are closed, without interpreter finalisation.

    Library threads still inside native code (a Zenoh session still connecting, a camera read) must
    neither keep the process alive nor crash it while Python tears down (a daemon thread that
    re-enters Python during finalisation is unwound with pthread_exit, which aborts through Rust or
    C++ frames); the exit code must be the daemon's.
    """
    from dronekey.daemon.signals import hard_exit

    logging.shutdown()
    hard_exit(int(code))


if __name__ == "__main__":
    sys.exit(main())
