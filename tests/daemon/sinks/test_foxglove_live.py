"""The live view (``--foxglove-ws``): foxglove-sdk's WebSocket server fed by the MCAP sink.

A real Foxglove WebSocket client (``websockets``) connects over
127.0.0.1, reads the advertised channels, subscribes, and decodes the message data it is sent with
the advertised schema, checked against Foxglove's published classes. A viewer that never reads must
not slow the sink.
"""

from __future__ import annotations

import asyncio
import base64
import json
import struct
import threading
import time

import pytest
import websockets
from foxglove_checks import decode
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from test_mcap_sink import camera, mcap_files, picture, update

from dronekey.daemon.config.foxglove_ws import FoxgloveWsConfig
from dronekey.daemon.config.mcap import McapConfig
from dronekey.daemon.sinks.foxglove_ws import FoxgloveLiveServer
from dronekey.daemon.sinks.mcap.channels import channel_specs
from dronekey.daemon.sinks.mcap.sink import McapSink

# foxglove-sdk's server speaks foxglove.sdk.v1, the successor of foxglove.websocket.v1 (same ops and
# binary message-data frame); it refuses a client that offers only the old name (HTTP 400).
SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01  # server binary opcode


def advertised_class(channel: dict):
    """The message class built from a protobuf channel's advertised schema (base64 FileDescriptorSet)."""
    pool = descriptor_pool.DescriptorPool()
    for file in descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"])).file:
        pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


async def receive(port: int, topics: list[str], wanted: int, started: threading.Event) -> tuple[dict, list]:
    """Subscribe to ``topics`` and collect ``wanted`` messages: (channels by topic, [(topic, t, data)])."""
    async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL]) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        channels: dict[str, dict] = {}
        while not set(topics) <= set(channels):
            frame = json.loads(await asyncio.wait_for(ws.recv(), 10))
            if frame["op"] == "advertise":
                channels.update({c["topic"]: c for c in frame["channels"]})
        subscriptions = [{"id": i, "channelId": channels[t]["id"]} for i, t in enumerate(topics)]
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
        started.set()
        got = []
        while len(got) < wanted:
            frame = await asyncio.wait_for(ws.recv(), 10)
            if isinstance(frame, bytes) and frame[0] == MESSAGE_DATA:
                subscription, log_time = struct.unpack_from("<IQ", frame, 1)
                got.append((topics[subscription], log_time, frame[13:]))
        return channels, got


def test_a_websocket_client_subscribes_and_decodes_what_it_is_sent(tmp_path):
    live = FoxgloveLiveServer("127.0.0.1", 0, channel_specs(with_geo=False))
    sink = McapSink(McapConfig(dir=tmp_path, image_rate_hz=10.0), camera(), "cam0", live=live)
    topics = ["/dronekey/annotations", "/camera/image", "/dronekey/tracks"]
    started, result = threading.Event(), {}
    client = threading.Thread(
        target=lambda: result.update(out=asyncio.run(receive(live.port, topics, 20, started))), daemon=True
    )
    client.start()
    assert started.wait(10), "the client did not get the advertised channels"
    time.sleep(0.2)  # the subscription reaches the server
    img = picture()
    for i in range(60):
        sink.handle_update(update(i, image=img))
        time.sleep(0.005)
    client.join(15)
    sink.close()
    channels, got = result["out"]
    assert {t for t, _, _ in got} == set(topics)
    for topic, log_time, data in got:
        channel = channels[topic]
        if channel["encoding"] == "protobuf":
            assert channel["schemaEncoding"] == "protobuf"
            message = advertised_class(channel).FromString(data)  # with the schema the server advertised
            published = decode(channel["schemaName"], "protobuf", data)  # and with Foxglove's published one
            assert message.SerializeToString() == published.SerializeToString()
            stamp = message.timestamp
            assert stamp.seconds * 1_000_000_000 + stamp.nanos == log_time
        else:
            assert (channel["encoding"], channel["schemaName"]) == ("json", "dronekey.Track")
            assert decode("dronekey.Track", "json", data)["camera_id"] == "cam0"
    # The same messages went into the file: the live view is one more destination of each write.
    assert mcap_files(tmp_path) and sink.message_counts["/dronekey/annotations"] == 60


async def _stalled_viewer(port: int, connected: threading.Event, stop: threading.Event) -> None:
    """Subscribes to every channel and then never reads."""
    async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], max_size=None) as ws:
        ids = []
        while not ids:
            frame = json.loads(await ws.recv())
            if frame["op"] == "advertise":
                ids = [c["id"] for c in frame["channels"]]
        subscriptions = [{"id": i, "channelId": c} for i, c in enumerate(ids)]
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
        ws.transport.pause_reading()
        connected.set()
        while not stop.is_set():
            await asyncio.sleep(0.05)


def test_a_viewer_that_never_reads_does_not_slow_the_sink():
    live = FoxgloveLiveServer("127.0.0.1", 0, channel_specs(with_geo=False), message_backlog=16)
    sink = McapSink(
        McapConfig(enabled=False, image_rate_hz=30.0, image_max_width=1280), camera(), "cam0", live=live
    )
    connected, stop = threading.Event(), threading.Event()
    viewer = threading.Thread(
        target=asyncio.run, args=(_stalled_viewer(live.port, connected, stop),), daemon=True
    )
    viewer.start()
    assert connected.wait(10)
    img = picture()
    sink.handle_update(update(0, image=img))  # JPEG encoding warm-up
    start = time.monotonic()
    for i in range(1, 151):  # 150 full-size JPEGs (~ 30 MB) to a socket nobody reads
        sink.handle_update(update(i, image=img))
    per_frame_ms = (time.monotonic() - start) / 150 * 1e3
    stop.set()
    sink.close()
    viewer.join(5)
    # JPEG encoding dominates (milliseconds); a sink that waited for this viewer would never finish.
    # The bound is generous so that a loaded machine does not count.
    assert per_frame_ms < 500, per_frame_ms
    assert sink.health()["file"] is None and sink.message_counts["/dronekey/annotations"] == 0


def test_foxglove_ws_listen_defaults_to_loopback_and_names_a_bad_value():
    assert FoxgloveWsConfig(listen=8765).address() == ("127.0.0.1", 8765)
    assert FoxgloveWsConfig(listen="0.0.0.0:8765").address() == ("0.0.0.0", 8765)
    with pytest.raises(ValueError, match="PORT, :PORT"):
        FoxgloveWsConfig(listen="localhost:http")


def test_a_taken_port_is_a_clear_error():
    first = FoxgloveLiveServer("127.0.0.1", 0, channel_specs(with_geo=False))
    try:
        with pytest.raises(OSError, match=rf"foxglove_ws.listen 127.0.0.1:{first.port}: .*in use"):
            FoxgloveLiveServer("127.0.0.1", first.port, channel_specs(with_geo=False))
    finally:
        first.close()
