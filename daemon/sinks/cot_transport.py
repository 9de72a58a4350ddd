"""Sending CoT events to a TAK peer through pytak, on an asyncio loop of the transport's own thread.

pytak is asyncio throughout: ``pytak.protocol_factory`` opens what a ``COT_URL`` names (UDP
unicast and multicast with TTL and outgoing interface, TCP, TLS with a client certificate from its
``PYTAK_TLS_*`` settings), the way every pytak gateway (DroneCOT, ADSBCOT, ...) does, so a TAK
user's URLs and certificates work unchanged. Its ``CLITool`` owns the process (its own
``asyncio.run``, its argument parser, its reconnect loop), which does not fit a sink: the sink's
thread must return at once. So the transport runs pytak's connection factory on an event loop in a
thread of its own, and the sink hands it bytes with ``send`` (thread-safe, never blocks).

Never stalls: events wait in a bounded queue (the oldest dropped and counted when full); a TCP/TLS
write that a peer does not take within ``write_timeout_s`` (a peer that never reads) drops the
connection; a failed or closed connection is opened again with backoff (0.5 s doubling to 30 s).
The socket's send buffer is kept small, so a peer that stops reading is noticed within seconds
instead of after megabytes of stale positions. Data the peer sends (TAK Server's pings) is read
and discarded.
"""

from __future__ import annotations

import asyncio
import collections
import configparser
import contextlib
import logging
import socket
import threading
import warnings

with warnings.catch_warnings():  # pytak warns at import that its optional aiohttp is missing; unused here
    warnings.simplefilter("ignore")
    import pytak
    from pytak.client_functions import get_ssl_ctx, get_tls_config

from dronekey.daemon.config.cot import CotConfig, CotUrl

__all__ = ["CotTransport"]

log = logging.getLogger(__name__)

_BACKOFF_S = (0.5, 30.0)
_SEND_BUFFER_BYTES = 64 * 1024
_STREAM_SCHEMES = ("tcp", "tls")


def pytak_settings(config: CotConfig) -> configparser.SectionProxy:
    """The ``COT_URL`` and ``PYTAK_*`` settings that make pytak open ``config.url``."""
    url = config.parsed_url()
    scheme = "udp+wo" if url.scheme.startswith("udp") else url.scheme  # write-only: no UDP listener
    values = {
        "COT_URL": f"{scheme}://{url.host}:{url.port}",
        "PYTAK_MULTICAST_TTL": str(config.multicast_ttl),
    }
    if config.multicast_interface is not None:
        values["PYTAK_MULTICAST_LOCAL_ADDR"] = config.multicast_interface
    if config.tls is not None:
        values |= {
            "PYTAK_TLS_CLIENT_CERT": str(config.tls.certificate),
            "PYTAK_TLS_CLIENT_KEY": str(config.tls.private_key),
            "PYTAK_TLS_CLIENT_CAFILE": str(config.tls.root_ca),
            "PYTAK_TLS_CLIENT_CIPHERS": "DEFAULT",  # OpenSSL's, not pytak's "ALL"
            "PYTAK_TLS_DONT_CHECK_HOSTNAME": "0" if config.tls.verify_name_on_connect else "1",
        }
    parser = configparser.ConfigParser(interpolation=None)
    parser["cot"] = values
    return parser["cot"]


def check_tls(settings: configparser.SectionProxy) -> None:
    """Load the client certificate, key and CA as pytak will; ValueError naming the problem."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            get_ssl_ctx(get_tls_config(settings))
    except Exception as exc:  # pytak raises SyntaxError, ValueError, ssl.SSLError, OSError
        cause = exc.__cause__ or exc
        raise ValueError(f"cot.tls: {exc} ({cause})" if cause is not exc else f"cot.tls: {exc}") from None


class CotTransport:
    """One connection (or UDP socket) to a TAK peer, kept open in the background.

    Parameters
    ----------
    config : the ``cot`` section (``url``, ``tls``, multicast, timeouts).
    max_queue : events waiting to be sent at most; the oldest are dropped beyond.
    """

    def __init__(self, config: CotConfig, *, max_queue: int = 64) -> None:
        self.url: CotUrl = config.parsed_url()
        self._settings = pytak_settings(config)
        if self.url.scheme == "tls":
            check_tls(self._settings)
        self._stream = self.url.scheme in _STREAM_SCHEMES
        self._connect_timeout_s = config.connect_timeout_s
        self._write_timeout_s = config.write_timeout_s
        self._max_queue = max_queue
        self._queue: collections.deque[bytes] = collections.deque()
        self._wakeup = asyncio.Event()
        self._closing = False
        self.state = "connecting"
        self.error: str | None = None
        self.counts = {"sent": 0, "not_sent": 0, "dropped": 0, "connects": 0}
        self._loop = asyncio.new_event_loop()
        self._task: asyncio.Task | None = None
        self._thread = threading.Thread(target=self._run, name="cot-transport", daemon=True)
        self._thread.start()

    def send(self, payload: bytes) -> None:
        """Queue one event for the peer; thread-safe, never blocks."""
        try:
            self._loop.call_soon_threadsafe(self._push, payload)
        except RuntimeError:  # the loop is closed: the transport is closed
            self.counts["not_sent"] += 1

    def health(self) -> dict:
        """State (``connecting``, ``open``, ``closed``), the URL, counters and the last error."""
        return {
            "url": str(self.url),
            "state": self.state,
            "error": self.error,
            "queued": len(self._queue),
        } | dict(self.counts)

    def close(self, timeout_s: float = 1.5) -> None:
        """Send what is queued (within about ``timeout_s``), then close. Idempotent."""
        try:
            self._loop.call_soon_threadsafe(self._begin_close)
        except RuntimeError:
            return
        self._thread.join(timeout_s * 0.7)
        if self._thread.is_alive() and self._task is not None:
            with contextlib.suppress(RuntimeError):
                self._loop.call_soon_threadsafe(self._task.cancel)
            self._thread.join(timeout_s * 0.3)

    # -- on the transport's loop -------------------------------------------------------------

    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)
        self._task = self._loop.create_task(self._main())
        try:
            self._loop.run_until_complete(self._task)
        except asyncio.CancelledError:
            pass
        finally:
            self.state = "closed"
            self._loop.close()

    def _push(self, payload: bytes) -> None:
        if self._closing:
            self.counts["not_sent"] += 1
            return
        if len(self._queue) >= self._max_queue:
            self._queue.popleft()
            self.counts["dropped"] += 1
        self._queue.append(payload)
        self._wakeup.set()

    def _begin_close(self) -> None:
        self._closing = True
        self._wakeup.set()

    async def _main(self) -> None:
        delay = _BACKOFF_S[0]
        while not self._closing:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # pytak's notes on disabled name checks; logged below
                    reader, writer = await asyncio.wait_for(
                        pytak.protocol_factory(self._settings), self._connect_timeout_s
                    )
            except Exception as exc:  # refused, unreachable, TLS handshake, timeout: try again later
                self._failed(exc, f"cannot reach {self.url}")
            else:
                delay = _BACKOFF_S[0]
                await self._serve(reader, writer)
            if self._closing:
                break
            self.state = "connecting"
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wait_closing(), delay)
            delay = min(delay * 2.0, _BACKOFF_S[1])
        self.counts["not_sent"] += len(self._queue)
        self._queue.clear()

    async def _wait_closing(self) -> None:
        while not self._closing:
            self._wakeup.clear()
            await self._wakeup.wait()

    async def _serve(self, reader, writer) -> None:
        self.counts["connects"] += 1
        self.state, self.error = "open", None
        log.info("CoT output: sending to %s", self.url)
        eof = None
        if self._stream:
            sock = writer.get_extra_info("socket")
            if sock is not None:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, _SEND_BUFFER_BYTES)
            eof = asyncio.ensure_future(self._discard_incoming(reader))
        try:
            await self._pump(writer, eof)
        except Exception as exc:  # a stream that failed or stalled: reconnect
            self._failed(exc, f"connection to {self.url} lost")
        finally:
            if eof is not None:
                eof.cancel()
            transport = getattr(writer, "transport", None)
            if transport is not None:
                transport.abort()  # drop what the peer did not take; never wait for it
            elif hasattr(writer, "close"):
                writer.close()

    async def _pump(self, writer, eof: asyncio.Future | None) -> None:
        while True:
            while not self._queue:
                if self._closing:
                    return
                self._wakeup.clear()
                waiting = asyncio.ensure_future(self._wakeup.wait())
                await asyncio.wait({waiting} | ({eof} if eof else set()), return_when=asyncio.FIRST_COMPLETED)
                waiting.cancel()
                if eof is not None and eof.done():
                    raise ConnectionError("the peer closed the connection")
            payload = self._queue.popleft()
            try:
                await asyncio.wait_for(self._write(writer, payload), self._write_timeout_s)
            except TimeoutError:
                self.counts["not_sent"] += 1
                raise TimeoutError(f"the peer took no data for {self._write_timeout_s:g} s") from None
            except OSError as exc:
                self.counts["not_sent"] += 1
                if self._stream:
                    raise
                self._failed(exc, f"UDP send to {self.url} failed")  # e.g. ICMP port unreachable
                self.state = "open"
                continue
            self.counts["sent"] += 1

    async def _write(self, writer, payload: bytes) -> None:
        if self._stream:
            writer.write(payload)
            await writer.drain()
        else:
            await writer.send(payload)

    @staticmethod
    async def _discard_incoming(reader) -> None:
        """Read and drop what the peer sends; returns when it closes the connection."""
        while await reader.read(65536):
            pass

    def _failed(self, exc: BaseException, what: str) -> None:
        text = f"{what}: {type(exc).__name__}: {exc}".rstrip(": ")
        if text != self.error:
            log.warning("CoT output: %s", text)
        self.error = text
