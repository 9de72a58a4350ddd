"""Test media for the daemon tests: short clips encoded with PyAV (a test-only dependency), damaged
MJPEG files and an MPEG-TS server over TCP run as a separate process.

Run ``python tests/daemon_media.py serve PORT`` to serve an endless 320x240 H.264 MPEG-TS stream to
each client that connects to 127.0.0.1:PORT (one at a time), paced at 30 fps.
"""

from __future__ import annotations

import contextlib
import socket
import subprocess
import sys
import time
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


def encode_clip(path: Path, codec: str = "libx264", frames: int = 30, fps: int = FPS) -> Path:
    """Write ``frames`` test-pattern frames with ``codec`` (libx264, mjpeg, mpeg4) to ``path``."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream(codec, rate=fps)
        stream.width, stream.height = W, H
        stream.pix_fmt = "yuvj420p" if codec == "mjpeg" else "yuv420p"
        for i in range(frames):
            for packet in stream.encode(av.VideoFrame.from_ndarray(pattern_frame(i), format="bgr24")):
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
    """An ONNX file with the keypoint model's contract (dronekey.export) that never sees a drone.

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
