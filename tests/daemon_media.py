"""Test media for the daemon tests: short clips encoded with PyAV (a test-only dependency), damaged
MJPEG and MPEG-TS files, variable-frame-rate clips and an MPEG-TS server over TCP run as a separate
process.

Run ``python tests/daemon_media.py serve PORT`` to serve an endless 320x240 H.264 MPEG-TS stream to
each client that connects to 127.0.0.1:PORT (one at a time), paced at 30 fps.
"""

from __future__ import annotations

import contextlib
import socket
import subprocess
import sys
import time
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

W, H, FPS = 320, 240, 30


def pattern_frame(i: int, width: int = W, height: int = H) -> np.ndarray:
    """A frame that changes with ``i`` (a moving bright square on a tinted background), BGR."""
    img = np.zeros((height, width, 3), np.uint8)
    img[:, :, 1] = (i * 8) % 256
    y = (i * 5) % (height - 20)
    img[y : y + 20, 40:60] = 255
    return img


def encode_clip(
    path: Path,
    codec: str = "libx264",
    frames: int = 30,
    fps: int = FPS,
    *,
    options: dict[str, str] | None = None,
    container_options: dict[str, str] | None = None,
    intervals_ms: tuple[int, ...] | None = None,
) -> Path:
    """Write ``frames`` test-pattern frames with ``codec`` (libx264, mjpeg, mpeg4) to ``path``.

    The container follows the suffix (``.mp4``, ``.avi``, ``.ts``); ``options`` go to the encoder
    (``{"g": "10"}``: a keyframe every 10 frames), ``container_options`` to the muxer
    (``{"movflags": "faststart"}``: the MP4 index first); ``intervals_ms`` (cycled) gives a
    variable frame rate.
    """
    with av.open(str(path), "w", options=container_options or {}) as container:
        stream = container.add_stream(codec, rate=fps, options=options or {})
        stream.width, stream.height = W, H
        stream.pix_fmt = "yuvj420p" if codec == "mjpeg" else "yuv420p"
        if intervals_ms:
            stream.codec_context.time_base = Fraction(1, 1000)
        t_ms = 0
        for i in range(frames):
            frame = av.VideoFrame.from_ndarray(pattern_frame(i), format="bgr24")
            if intervals_ms:
                frame.pts, frame.time_base = t_ms, Fraction(1, 1000)
                t_ms += intervals_ms[i % len(intervals_ms)]
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return path


def damage_mjpeg_frames(src: Path, dst: Path, frame_numbers: list[int]) -> Path:
    """Copy an MJPEG AVI, wiping the entropy-coded data of the given frames (they no longer decode)."""
    data = bytearray(src.read_bytes())
    starts = [i for i in range(len(data) - 1) if data[i] == 0xFF and data[i + 1] == 0xD8]
    for n in frame_numbers:
        s = starts[n]
        data[s + 2 : s + 602] = bytes(600)
    dst.write_bytes(bytes(data))
    return dst


def damage_ts_packets(src: Path, dst: Path, first: int, count: int) -> Path:
    """Copy an MPEG-TS file, zeroing the payload of ``count`` 188-byte packets from packet ``first``
    (as a lossy link does): FFmpeg drops the frames they carried without a decode error."""
    data = bytearray(src.read_bytes())
    for k in range(first, first + count):
        data[188 * k + 4 : 188 * (k + 1)] = bytes(184)
    dst.write_bytes(bytes(data))
    return dst


def serve(port: int) -> None:
    """Serve an endless H.264 MPEG-TS stream to one client at a time on 127.0.0.1:``port``."""
    server = socket.socket()
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("127.0.0.1", port))
    server.listen(4)
    print("listening", flush=True)
    i = 0
    while True:
        conn, _ = server.accept()
        out = conn.makefile("wb")
        try:
            container = av.open(out, "w", format="mpegts")
            stream = container.add_stream(
                "libx264", rate=FPS, options={"preset": "ultrafast", "tune": "zerolatency", "g": "10"}
            )
            stream.width, stream.height, stream.pix_fmt = W, H, "yuv420p"
            t0 = time.monotonic()
            n = 0
            while True:
                frame = av.VideoFrame.from_ndarray(pattern_frame(i), format="bgr24")
                for packet in stream.encode(frame):
                    container.mux(packet)
                out.flush()
                i += 1
                n += 1
                time.sleep(max(0.0, t0 + n / FPS - time.monotonic()))
        except (BrokenPipeError, ConnectionResetError, OSError, av.error.FFmpegError):
            pass
        finally:
            with contextlib.suppress(Exception):
                conn.close()


def write_untrained_model(path: Path, input_size: int = 64) -> Path:
    """An ONNX file with the keypoint model's contract (dronekey.training.export) that never sees a drone.

    The daemon tests that are about the service (signals, sd_notify, sources, exit codes) run the
    real pipeline and ONNX Runtime with it, independently of the trained model: ``presence`` is 0,
    ``keypoints`` a fixed square, ``gate`` uniform.
    """
    import json

    import onnx
    from onnx import TensorProto, helper

    s = int(input_size)
    nodes = [
        helper.make_node("ReduceMean", ["image"], ["mean"], axes=[1, 2, 3], keepdims=0),
        helper.make_node("Mul", ["mean", "zero"], ["nothing"]),  # (batch,) zeros
        helper.make_node("Identity", ["nothing"], ["presence"]),
        helper.make_node("Reshape", ["nothing", "shape_b11"], ["nothing_b11"]),
        helper.make_node("Add", ["nothing_b11", "square"], ["keypoints"]),
        helper.make_node("Reshape", ["nothing", "shape_b1"], ["nothing_b1"]),
        helper.make_node("Add", ["nothing_b1", "uniform"], ["gate"]),
    ]
    square = np.array([[0.6, 0.4], [0.6, 0.6], [0.4, 0.6], [0.4, 0.4]], np.float32)
    inits = [
        helper.make_tensor("zero", TensorProto.FLOAT, [], [0.0]),
        helper.make_tensor("shape_b11", TensorProto.INT64, [3], [-1, 1, 1]),
        helper.make_tensor("shape_b1", TensorProto.INT64, [2], [-1, 1]),
        helper.make_tensor("square", TensorProto.FLOAT, [4, 2], square.ravel().tolist()),
        helper.make_tensor("uniform", TensorProto.FLOAT, [6], [1 / 6] * 6),
    ]
    graph = helper.make_graph(
        nodes,
        "untrained_dronekey",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, ["batch", 3, s, s])],
        [
            helper.make_tensor_value_info("keypoints", TensorProto.FLOAT, ["batch", 4, 2]),
            helper.make_tensor_value_info("presence", TensorProto.FLOAT, ["batch"]),
            helper.make_tensor_value_info("gate", TensorProto.FLOAT, ["batch", 6]),
        ],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    metadata = {
        "input_size": [s, s],
        "normalisation": {
            "color": "RGB",
            "scale": 1 / 255,
            "mean": [0.485, 0.456, 0.406],
            "std": [0.229, 0.224, 0.225],
        },
        "keypoint_names": ["prop1", "prop2", "prop3", "prop4"],
        "crop_policy": {"input_size": s},
        "trained_on": "nothing (test model)",
        "precision": "fp32",
    }
    for key, value in metadata.items():
        model.metadata_props.add(key=key, value=json.dumps(value))
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def daemon_assets(folder: Path, width: int = 640, height: int = 480) -> Path:
    """What a daemon run in a test needs, in ``folder``: a 30-frame H.264 ``clip.mp4``, a matching
    ``camera.yaml`` (60 deg horizontal field of view) and an ``untrained.onnx`` model."""
    from dronekey.geometry.camera import CameraModel

    encode_clip(folder / "clip.mp4", "libx264", frames=30)
    CameraModel.from_fov(width, height, 60).save_yaml(folder / "camera.yaml")
    write_untrained_model(folder / "untrained.onnx")
    return folder


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(port: int) -> subprocess.Popen:
    """The MPEG-TS server in its own process, once it listens."""
    proc = subprocess.Popen(
        [sys.executable, __file__, "serve", str(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    line = proc.stdout.readline()
    if "listening" not in line:
        proc.kill()
        raise RuntimeError(f"stream server did not start: {line!r}")
    return proc


def stop_process(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.wait(10)


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "serve":
        serve(int(sys.argv[2]))
    else:
        sys.exit(f"usage: {sys.argv[0]} serve PORT")
