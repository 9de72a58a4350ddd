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
