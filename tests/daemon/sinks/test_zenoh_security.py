"""Zenoh secure by default, and the secure fleet of docs/security.md, with real sessions over 127.0.0.1.

A CA and the certificates are made here with ``cryptography``. The router is an in-process
``zenoh.open`` of ``docs/zenoh-router.json5`` (the file the docs show) pointed at them and at a
free port: TLS only, mutual authentication, access control by certificate common name. The sensor
is the daemon's own ``ZenohSink`` with its TLS identity ``dronekey-cam0``; a reader with the
console's certificate gets its tracks, status, liveliness and info. A peer with another identity
from the same CA can neither publish into ``dronekey/**`` nor read it, the sensor cannot publish
under another camera's id, and a peer without a certificate, or with one from another CA, gets no
link at all.
"""

from __future__ import annotations

import datetime
import ipaddress
import json
import re
import subprocess
import sys
import textwrap
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import paths
import pytest
import zenoh
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID
from test_zenoh_sink import frame, free_port, status, wait_for
from zenoh import ext

from dronekey.daemon.cli import build_parser, collect_overrides
from dronekey.daemon.config.daemon_config import DaemonConfig
from dronekey.daemon.config.errors import ConfigError
from dronekey.daemon.config.loading import load_config
from dronekey.daemon.config.zenoh import ZenohConfig, ZenohTlsConfig
from dronekey.daemon.sinks.zenoh_sink import ZenohSink, describe_exposure, zenoh_config

ROOT = paths.ROOT
ROUTER_JSON5 = ROOT / "docs" / "zenoh-router.json5"
SECURITY_MD = ROOT / "docs" / "security.md"


# ------------------------------------------------------------------------------------ certificates
def _name(cn: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def _write_key(key: ec.EllipticCurvePrivateKey, path: Path) -> None:
    path.write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )
    )
    path.chmod(0o600)


_KEY_USAGES = (
    "digital_signature", "content_commitment", "key_encipherment", "data_encipherment", "key_agreement",
    "key_cert_sign", "crl_sign", "encipher_only", "decipher_only",
)  # fmt: skip


class CertificateAuthority:
    """A CA (as the docs' openssl recipe makes it) that issues certificates into ``folder``."""

    def __init__(self, folder: Path, cn: str) -> None:
        self.folder = folder
        self.key = ec.generate_private_key(ec.SECP256R1())
        now = datetime.datetime.now(datetime.UTC)
        self.cert = (
            x509.CertificateBuilder()
            .subject_name(_name(cn))
            .issuer_name(_name(cn))
            .public_key(self.key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(
                x509.KeyUsage(**{usage: usage in ("key_cert_sign", "crl_sign") for usage in _KEY_USAGES}),
                critical=True,
            )
            .sign(self.key, hashes.SHA256())
        )
        self.pem = folder / f"{cn.replace(' ', '-')}.pem"
        self.pem.write_bytes(self.cert.public_bytes(serialization.Encoding.PEM))

    def issue(self, cn: str, prefix: str = "", server: bool = False) -> ZenohTlsConfig:
        """A certificate with common name ``cn`` (``server``: for 127.0.0.1 too) and its key."""
        key = ec.generate_private_key(ec.SECP256R1())
        now = datetime.datetime.now(datetime.UTC)
        builder = (
            x509.CertificateBuilder()
            .subject_name(_name(cn))
            .issuer_name(self.cert.subject)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(
                x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                critical=False,
            )
        )
        if server:
            names = [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]
            builder = builder.add_extension(x509.SubjectAlternativeName(names), critical=False)
        cert_path = self.folder / f"{prefix}{cn}.pem"
        key_path = self.folder / f"{prefix}{cn}-key.pem"
        cert_path.write_bytes(
            builder.sign(self.key, hashes.SHA256()).public_bytes(serialization.Encoding.PEM)
        )
        _write_key(key, key_path)
        return ZenohTlsConfig(root_ca=self.pem, certificate=cert_path, private_key=key_path)


# ------------------------------------------------------------------------------------ the fleet
@dataclass
class Fleet:
    port: int
    ca: CertificateAuthority
    identities: dict[str, ZenohTlsConfig]

    @property
    def endpoint(self) -> str:
        return f"tls/127.0.0.1:{self.port}"


def router_config(fleet_ca: CertificateAuthority, router: ZenohTlsConfig, port: int) -> zenoh.Config:
    """docs/zenoh-router.json5 with its listener on 127.0.0.1 and its files in the test folder."""
    config = zenoh.Config.from_json5(ROUTER_JSON5.read_text(encoding="utf-8"))
    config.insert_json5("listen/endpoints", json.dumps([f"tls/127.0.0.1:{port}"]))
    config.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(str(fleet_ca.pem)))
    config.insert_json5("transport/link/tls/listen_certificate", json.dumps(str(router.certificate)))
    config.insert_json5("transport/link/tls/listen_private_key", json.dumps(str(router.private_key)))
    return config


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    folder = tmp_path_factory.mktemp("pki")
    ca = CertificateAuthority(folder, "dronekey fleet CA")
    identities = {cn: ca.issue(cn) for cn in ("dronekey-cam0", "dronekey-console", "intruder")}
    rogue = CertificateAuthority(folder, "rogue CA")
    identities["rogue dronekey-cam0"] = rogue.issue("dronekey-cam0", prefix="rogue-")
    port = free_port()
    router = zenoh.open(router_config(ca, ca.issue("zenoh-router", server=True), port))
    try:
        yield Fleet(port, ca, identities)
    finally:
        router.close()


def client_session(fleet: Fleet, tls: ZenohTlsConfig) -> zenoh.Session:
    """A plain client session of the fleet (a reader, an intruder), TLS configured as the daemon does."""
    return zenoh.open(zenoh_config(ZenohConfig(mode="client", connect=[fleet.endpoint], tls=tls)))


class Reader:
    """Subscribes to ``dronekey/**`` (samples and liveliness) on its own session."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self.samples: list[tuple[str, str]] = []
        self.alive: list[str] = []
        self._lock = threading.Lock()
        self._entities = [
            session.declare_subscriber("dronekey/**", self._on_sample),
            session.liveliness().declare_subscriber("dronekey/**", self._on_alive, history=True),
        ]

    def _on_sample(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.samples.append((str(sample.key_expr), sample.payload.to_string()))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            with self._lock:
                self.alive.append(str(sample.key_expr))

    def keys(self) -> list[str]:
        with self._lock:
            return [key for key, _ in self.samples]

    def info(self, camera_id: str) -> list[str]:
        replies = self.session.get(f"dronekey/{camera_id}/info", timeout=2.0)
        return [reply.ok.payload.to_string() for reply in replies if reply.ok is not None]

    def close(self) -> None:
        self.session.close()


def test_a_sensor_identity_publishes_and_only_the_authorised_reader_reads(fleet):
    identity = fleet.identities
    intruder_reader = Reader(client_session(fleet, identity["intruder"]))
    console = Reader(client_session(fleet, identity["dronekey-console"]))
    intruder = client_session(fleet, identity["intruder"])
    sink = ZenohSink(
        ZenohConfig(mode="client", connect=[fleet.endpoint], tls=identity["dronekey-cam0"]), "cam0",
        info={"camera_id": "cam0", "version": "test"},
    )  # fmt: skip
    entities = []
    try:
        assert sink.wait_open(10), sink.health()
        wait_for(lambda: sink.health().get("subscribers"), 10, "the router to tell the sensor of the reader")
        # The intruder, signed by the fleet CA but not a sensor, tries every way into dronekey/**.
        entities += [
            intruder.declare_publisher("dronekey/cam0/tracks"),
            intruder.liveliness().declare_token("dronekey/cam9/alive"),
            intruder.declare_queryable(
                "dronekey/cam9/info", lambda q: q.reply("dronekey/cam9/info", "forged")
            ),
        ]
        for i in range(5):
            sink.handle_update(frame(i))  # 2 tracks each
            sink.handle_status(status(i))
            entities[0].put(b'{"track_id": 666, "forged": true}')
            intruder.put("dronekey/cam0/status", b"forged")
        # 10 track messages on the stream and 10 on the tracks' own keys, and 5 statuses.
        wait_for(lambda: len(console.keys()) >= 25, 10, "the reader to get 20 tracks and 5 statuses")
        wait_for(lambda: console.alive, 10, "the sensor's liveliness token")
        time.sleep(0.5)  # anything that was going to slip through has had its chance
        console_info, intruder_info = console.info("cam0"), intruder_reader.info("cam0")
        forged_info = console.info("cam9")
    finally:
        sink.close()
        for session in (intruder, console, intruder_reader):
            session.close()

    keys = console.keys()
    assert sorted(set(keys)) == [
        "dronekey/cam0/status", "dronekey/cam0/tracks", "dronekey/cam0/tracks/1", "dronekey/cam0/tracks/2",
    ]  # fmt: skip
    assert keys.count("dronekey/cam0/tracks") == 10 and keys.count("dronekey/cam0/status") == 5
    assert not any("forged" in payload for _, payload in console.samples)
    assert console.alive == ["dronekey/cam0/alive"]  # not the intruder's dronekey/cam9/alive
    assert [json.loads(p)["version"] for p in console_info] == ["test"] and forged_info == []
    # The intruder read nothing: no samples, no liveliness, no info (its own puts stay local to
    # its publishing session, which is not this one).
    assert intruder_reader.samples == [] and intruder_reader.alive == [] and intruder_info == []
    assert sink.health()["published"] == 15


def test_a_sensor_cannot_publish_under_another_camera_id(fleet):
    console = Reader(client_session(fleet, fleet.identities["dronekey-console"]))
    sensor = ZenohConfig(mode="client", connect=[fleet.endpoint], tls=fleet.identities["dronekey-cam0"])
    wrong = ZenohSink(sensor, "cam1")
    right = ZenohSink(sensor, "cam0")
    try:
        assert wrong.wait_open(10) and right.wait_open(10)
        wait_for(lambda: right.health().get("subscribers"), 10, "the reader to be matched")
        for i in range(3):
            wrong.handle_update(frame(i))
            right.handle_update(frame(i))
        wait_for(lambda: len(console.keys()) >= 12, 10, "cam0's tracks, on the stream and their own keys")
        time.sleep(0.5)
    finally:
        wrong.close()
        right.close()
        console.close()
    keys = console.keys()
    assert set(keys) == {"dronekey/cam0/tracks", "dronekey/cam0/tracks/1", "dronekey/cam0/tracks/2"}
    assert keys.count("dronekey/cam0/tracks") == 6


def test_a_late_reader_gets_the_history_through_the_router_and_an_intruder_does_not(fleet):
    sink = ZenohSink(
        ZenohConfig(mode="client", connect=[fleet.endpoint], tls=fleet.identities["dronekey-cam0"]), "cam0"
    )
    sessions = []
    try:
        assert sink.wait_open(10), sink.health()
        for i in range(3):
            sink.handle_update(frame(i))  # tracks 1 and 2
            sink.handle_status(status(i))
        history = ext.HistoryConfig(detect_late_publishers=True, max_samples=1)
        received: dict[str, list[str]] = {"dronekey-console": [], "intruder": []}
        for who, keys in received.items():
            session = client_session(fleet, fleet.identities[who])
            sessions.append(session)
            for key in ("dronekey/cam0/tracks/*", "dronekey/cam0/status"):
                ext.declare_advanced_subscriber(
                    session, key, lambda s, k=keys: k.append(str(s.key_expr)), history=history
                )
        wanted = {"dronekey/cam0/tracks/1", "dronekey/cam0/tracks/2", "dronekey/cam0/status"}
        wait_for(lambda: set(received["dronekey-console"]) >= wanted, 10, "the history through the router")
        time.sleep(0.5)
    finally:
        sink.close()
        for session in sessions:
            session.close()
    # (and the deletes of the two live tracks on close)
    assert set(received["dronekey-console"]) == wanted and received["intruder"] == []


@pytest.mark.parametrize("who", ["no certificate", "rogue dronekey-cam0", "plain tcp"])
def test_a_peer_without_a_fleet_certificate_gets_no_link(fleet, who):
    if who == "plain tcp":
        config = zenoh_config(
            ZenohConfig(mode="client", connect=[f"tcp/127.0.0.1:{fleet.port}"]), connect_timeout_s=1.0
        )
    elif who == "no certificate":
        config = zenoh_config(ZenohConfig(mode="client", connect=[fleet.endpoint]), connect_timeout_s=1.0)
        config.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(str(fleet.ca.pem)))
    else:  # a certificate with a sensor's name, signed by another CA
        rogue = ZenohConfig(mode="client", connect=[fleet.endpoint], tls=fleet.identities[who])
        config = zenoh_config(rogue, connect_timeout_s=1.0)
    started = time.monotonic()
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        zenoh.open(config).close()
    assert time.monotonic() - started < 10


def test_the_docs_show_the_router_config_the_tests_run():
    text = SECURITY_MD.read_text(encoding="utf-8")
    blocks = re.findall(r"```json5\n(.*?)```", text, flags=re.S)
    assert ROUTER_JSON5.read_text(encoding="utf-8") in blocks


# ------------------------------------------------------------------------------------ defaults
DEFAULT_SESSION = textwrap.dedent(
    """
    import json, logging, sys, time
    import psutil
    from dronekey.daemon.config.daemon_config import DaemonConfig
    from dronekey.daemon.sinks.zenoh_sink import ZenohSink

    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(message)s")
    sink = ZenohSink(DaemonConfig().zenoh, "cam0")
    assert sink.wait_open(10), sink.health()

    def listed():
        return [
            [c.type.name, c.laddr.ip, c.laddr.port, c.status]
            for c in psutil.Process().net_connections(kind="inet")
        ]

    deadline = time.monotonic() + 10  # on a loaded box the listener may bind after the session opens
    while not any(s[3] == "LISTEN" for s in listed()) and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.5)  # scouting, were it on, has opened its sockets by now
    sockets = listed()
    sink.close()
    print(json.dumps(sockets))
    """
)


def test_the_default_session_listens_on_loopback_only_and_does_not_scout():
    z = DaemonConfig().zenoh
    assert (z.mode, z.listen, z.scouting, z.tls) == ("peer", ["tcp/127.0.0.1:0"], False, None)
    assert DaemonConfig.model_validate({"zenoh": {"mode": "client"}}).zenoh.listen == []  # clients don't

    config = zenoh_config(z)
    for key in ("scouting/multicast/enabled", "scouting/gossip/enabled"):
        assert json.loads(config.get_json(key)) is False, key
    assert json.loads(config.get_json("listen/endpoints")) == ["tcp/127.0.0.1:0"]
    assert ZenohConfig().listen == ["tcp/127.0.0.1:0"]  # the section's own default, the one rule

    result = subprocess.run(
        [sys.executable, "-c", DEFAULT_SESSION], capture_output=True, text=True, timeout=60
    )  # its own process: no other test's sockets
    assert result.returncode == 0, result.stderr
    sockets = json.loads(result.stdout)
    listening = [s for s in sockets if s[3] == "LISTEN"]
    assert listening and all(ip == "127.0.0.1" for _, ip, _, _ in listening), sockets
    assert [s for s in sockets if s[0] == "SOCK_DGRAM"] == [], sockets  # no multicast scouting socket
    assert (
        "zenoh peer session: listens on tcp/127.0.0.1:0 (this machine only), connects to nothing, "
        "scouting off, no TLS"
    ) in result.stderr


def test_what_opens_the_session_is_said_in_one_line(fleet):
    tls = fleet.identities["dronekey-cam0"]
    line = describe_exposure(
        ZenohConfig(
            connect=["tls/10.0.0.1:7447"], listen=["tcp/127.0.0.1:7447", "tls/0.0.0.0:7447"], scouting=True,
            tls=tls,
        )
    )  # fmt: skip
    assert "REACHABLE FROM THE NETWORK: tls/0.0.0.0:7447" in line and "connects to tls/10.0.0.1:7447" in line
    assert "scouting ON" in line and f"TLS with mutual authentication as {tls.certificate}" in line
    for endpoint in ("tcp/[::1]:7447", "tcp/localhost:7447", "unixsock-stream//run/z.sock"):
        assert "this machine only" in describe_exposure(ZenohConfig(listen=[endpoint]))
    assert "listens nowhere" in describe_exposure(ZenohConfig(mode="client", connect=["tls/10.0.0.1:7447"]))


def test_opening_flags_and_tls_config_errors(tmp_path):
    assert collect_overrides(build_parser().parse_args(["--zenoh-scouting"]))["zenoh.scouting"][0] is True
    assert collect_overrides(build_parser().parse_args(["--no-zenoh-scouting"]))["zenoh.scouting"][0] is False
    pem = tmp_path / "ca.pem"
    pem.write_text("-----BEGIN CERTIFICATE-----\nMIIB\n-----END CERTIFICATE-----\n")
    key = tmp_path / "key.pem"
    key.write_text("-----BEGIN PRIVATE KEY-----\nMIIB\n-----END PRIVATE KEY-----\n")
    good = {"root_ca": str(pem), "certificate": str(pem), "private_key": str(key)}
    config = DaemonConfig.model_validate({"zenoh": {"tls": good}})
    assert config.zenoh.tls.certificate == pem and config.zenoh.tls.verify_name_on_connect is True

    def error(tls: dict) -> str:
        path = tmp_path / "config.yaml"
        path.write_text(json.dumps({"source": {"uri": "sim://seq13"}, "zenoh": {"tls": tls}}))
        with pytest.raises(ConfigError) as exc:
            load_config(path)
        return str(exc.value)

    text = error({**good, "certificate": str(tmp_path / "absent.pem")})
    assert "zenoh.tls.certificate" in text and "absent.pem" in text and "not point to a file" in text
    text = error({**good, "private_key": str(pem)})
    assert "zenoh.tls.private_key" in text and "must be a PEM private key" in text
    text = error({"root_ca": str(pem)})
    assert "zenoh.tls.certificate" in text and "zenoh.tls.private_key" in text
    with pytest.raises(ValueError, match="root_ca"):
        ZenohTlsConfig(root_ca=tmp_path / "absent.pem", certificate=pem, private_key=key)
