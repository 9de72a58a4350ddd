"""``dronekey-fuse``: fuse the tracks of several ``dronekey-daemon`` cameras (docs/fleet.md).

    dronekey-fuse --zenoh-mode client --zenoh-connect tcp/ROUTER:7447
    dronekey-fuse --cameras north,east --origin 47.3977,8.5456,488
    dronekey-fuse --origin 47.3977,8.5456,488 --sbs1-listen 30004 --mavlink udpout:127.0.0.1:14550

Exit codes: 0 never (it runs until stopped), 2 bad usage (one line names the flag and value),
3 the Zenoh session could not be opened, 130 / 143 stopped by SIGINT / SIGTERM.
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading

import zenoh
from pydantic import ValidationError

import dronekey
from dronekey.daemon.config.camera import check_camera_id
from dronekey.daemon.config.mavlink import MavlinkConfig
from dronekey.daemon.config.sbs1 import Sbs1Config
from dronekey.daemon.config.zenoh import ZenohConfig
from dronekey.daemon.errors import ExitCode
from dronekey.daemon.fuse.fused_message import FUSED_KEY
from dronekey.daemon.fuse.local_frame import LocalFrame
from dronekey.daemon.fuse.outputs import FusedOutputs
from dronekey.daemon.fuse.service import FuseService
from dronekey.daemon.geo import CameraGeo, GeoError
from dronekey.daemon.signals import SignalMonitor
from dronekey.fusion import FusionConfig
from dronekey.fusion.clock import CLOCK_MODES

__all__ = ["build_parser", "main"]

log = logging.getLogger("dronekey.fuse")

_EPILOG = f"""Publishes one JSON message per fused track on {FUSED_KEY} (schema fused_track:
the track's fields in ENU at the fused frame's origin, lat/lon/alt, and the contributing cameras),
and with --sbs1-listen / --mavlink the same tracks as the daemon's SBS-1 lines and MAVLink
ADSB_VEHICLE / TARGET_ABSOLUTE messages (fused id = track id).
Each daemon must publish its camera pose: start it with --camera-extrinsics FILE or --camera-geo.

exit codes:
  2    bad usage (one line on stderr says which flag)
  3    the Zenoh session could not be opened (a client with no reachable router)
  130  stopped by SIGINT, 143 by SIGTERM"""


class _UsageError(Exception):
    """Bad input the user can fix; printed as one line."""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="dronekey-fuse",
        description="Fuse the drone tracks of several dronekey-daemon cameras over Zenoh: associate them\n"
        "across cameras, triangulate, and publish fused tracks. docs/fleet.md is the guide.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--version", action="version", version=f"%(prog)s {dronekey.__version__}")
    p.add_argument(
        "--cameras",
        metavar="ID[,ID...]",
        help="camera ids to fuse (default: every daemon publishing on dronekey/*/tracks)",
    )
    p.add_argument(
        "--origin",
        metavar="LAT,LON,ALT_M",
        help="origin of the fused ENU frame, WGS84 (default: the cameras' site origin, else the first "
        "camera)",
    )
    p.add_argument("--rate-hz", type=float, default=30.0, metavar="HZ", help="fused updates per second (30)")
    p.add_argument(
        "--clock",
        choices=CLOCK_MODES,
        default="auto",
        help="camera clocks: trust their t_ns, align them by arrival time, or auto: trust epoch clocks "
        "within 2 s of ours and align the others (default)",
    )
    p.add_argument(
        "--max-age-s", type=float, default=0.5, metavar="S", help="leave out camera tracks older than S (0.5)"
    )
    g = p.add_argument_group("Zenoh (the daemon's settings and defaults)")
    g.add_argument("--zenoh-mode", choices=("peer", "client"), default="peer", help="session mode (peer)")
    g.add_argument("--zenoh-connect", metavar="EP", action="append", default=[], help="endpoint (repeatable)")
    g.add_argument(
        "--zenoh-listen",
        metavar="EP",
        action="append",
        help="endpoint to listen on (repeatable; default: tcp/127.0.0.1:0 for a peer, none for a client)",
    )
    g.add_argument(
        "--zenoh-scouting", action="store_true", help="multicast and gossip scouting on (default off)"
    )
    g.add_argument(
        "--zenoh-tls-ca", metavar="PEM", help="fleet CA certificate (tls/ endpoints, docs/security.md)"
    )
    g.add_argument("--zenoh-tls-cert", metavar="PEM", help="this fuser's certificate from that CA")
    g.add_argument("--zenoh-tls-key", metavar="PEM", help="its private key")
    g = p.add_argument_group(
        "air-picture outputs of the fused tracks (off by default; both need --origin: they carry lat/lon)"
    )
    g.add_argument(
        "--sbs1-listen",
        metavar="[HOST:]PORT",
        help="serve SBS-1 (BaseStation) lines on TCP, e.g. 30004 (127.0.0.1); 0.0.0.0:30004 serves "
        "the network",
    )
    g.add_argument(
        "--mavlink",
        metavar="URL",
        help="send ADSB_VEHICLE / TARGET_ABSOLUTE over MAVLink 2, e.g. udpout:127.0.0.1:14550",
    )
    g.add_argument(
        "--mavlink-sysid",
        type=int,
        default=FUSER_SYSID,
        metavar="N",
        help=f"the fuser's MAVLink system id, 1-254 (default {FUSER_SYSID}: the daemons default to 42)",
    )
    p.add_argument("--log-level", default="INFO", choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    return p


FUSER_SYSID = 43  # apart from the daemons' default 42, so a ground station sees two systems


def _air_picture(args: argparse.Namespace) -> tuple[Sbs1Config | None, MavlinkConfig | None]:
    """The SBS-1 and MAVLink sections the flags ask for (None: off)."""
    sbs1 = mavlink = None
    if args.sbs1_listen is not None:
        try:
            sbs1 = Sbs1Config(listen=args.sbs1_listen)
        except ValidationError as exc:
            raise _UsageError(f"--sbs1-listen {args.sbs1_listen!r}: {exc.errors()[0]['msg']}") from None
    if args.mavlink is not None:
        try:
            mavlink = MavlinkConfig(url=args.mavlink, sysid=args.mavlink_sysid)
        except ValidationError as exc:
            error = exc.errors()[0]
            flag = "--mavlink-sysid" if error["loc"] == ("sysid",) else "--mavlink"
            raise _UsageError(f"{flag}: {error['msg']}") from None
    if (sbs1 or mavlink) and args.origin is None:
        raise _UsageError(
            "--sbs1-listen and --mavlink report latitude and longitude: give the fused frame's origin, "
            "--origin LAT,LON,ALT_M"
        )
    return sbs1, mavlink


# the zenoh section's fields -> this command's flags, for error messages
_FLAGS = {
    ("tls", "root_ca"): "--zenoh-tls-ca",
    ("tls", "certificate"): "--zenoh-tls-cert",
    ("tls", "private_key"): "--zenoh-tls-key",
}


def _settings(args: argparse.Namespace) -> tuple[ZenohConfig, list[str], LocalFrame | None, FusionConfig]:
    tls_files = (args.zenoh_tls_ca, args.zenoh_tls_cert, args.zenoh_tls_key)
    if any(tls_files) and not all(tls_files):
        raise _UsageError("--zenoh-tls-ca, --zenoh-tls-cert and --zenoh-tls-key go together")
    tls = None
    if all(tls_files):
        tls = {"root_ca": tls_files[0], "certificate": tls_files[1], "private_key": tls_files[2]}
    try:
        zenoh_settings = ZenohConfig(
            mode=args.zenoh_mode,
            connect=args.zenoh_connect,
            listen=args.zenoh_listen,
            scouting=args.zenoh_scouting,
            tls=tls,
        )
    except ValidationError as exc:
        error = exc.errors()[0]
        loc = tuple(str(part) for part in error["loc"] if not isinstance(part, int))
        field = _FLAGS.get(loc, "--zenoh-" + "-".join(loc))
        raise _UsageError(f"{field}: {error['msg']}") from None
    if args.zenoh_mode == "client" and not args.zenoh_connect:
        raise _UsageError(
            "--zenoh-mode client needs --zenoh-connect ENDPOINT (the router, e.g. tcp/127.0.0.1:7447)"
        )
    cameras = []
    for camera_id in (args.cameras or "").split(","):
        if camera_id.strip():
            try:
                cameras.append(check_camera_id(camera_id.strip()))
            except ValueError as exc:
                raise _UsageError(f"--cameras {args.cameras!r}: {exc}") from None
    origin = None
    if args.origin is not None:
        try:
            geo = CameraGeo.parse(args.origin)
        except GeoError as exc:
            raise _UsageError(f"--origin {args.origin!r}: {exc}") from None
        origin = LocalFrame(geo.lat_deg, geo.lon_deg, geo.alt_m)
    if not args.rate_hz > 0:
        raise _UsageError(f"--rate-hz must be > 0, got {args.rate_hz}")
    try:
        fusion = FusionConfig(max_age_s=args.max_age_s)
    except ValueError as exc:
        raise _UsageError(f"--max-age-s: {exc}") from None
    return zenoh_settings, cameras, origin, fusion


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``dronekey-fuse``; returns the exit code."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=args.log_level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        zenoh_settings, cameras, origin, fusion = _settings(args)
        sbs1, mavlink = _air_picture(args)
    except _UsageError as exc:
        log.error("%s", exc)
        return ExitCode.USAGE
    outputs = None
    if sbs1 is not None or mavlink is not None:
        try:
            outputs = FusedOutputs(origin, sbs1=sbs1, mavlink=mavlink)
        except (ValueError, OSError) as exc:
            log.error("%s", exc)
            return ExitCode.USAGE
    service = FuseService(
        zenoh_settings, cameras, origin, fusion, clock=args.clock, rate_hz=args.rate_hz, outputs=outputs
    )
    signals = SignalMonitor()
    signals.install()
    threading.Thread(target=lambda: (signals.stop.wait(), service.stop()), name="stop", daemon=True).start()
    try:
        service.run()
    except zenoh.ZError as exc:
        log.error("zenoh session could not be opened: %s", str(exc).split(" at ", 1)[0])
        return ExitCode.SOURCE_FAILED
    finally:
        signals.finished()
    return signals.exit_code or ExitCode.OK


if __name__ == "__main__":
    sys.exit(main())
