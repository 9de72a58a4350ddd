"""MAVLink 2 message signing: the secret key file and the persisted signing timestamp.

The key file holds the 32-byte secret either as 32 raw bytes or as 64 hexadecimal digits (what
``openssl rand -hex 32`` writes; surrounding whitespace ignored). The key is never logged nor put in
an exception message.

The signing timestamp counts 10 µs units since 2015-01-01 00:00 UTC and must never go backwards
for a given (link, system, component), or receivers reject our messages as replays. An edge box
without a real-time clock can boot with its clock in the past, so the last timestamp is saved to a
small state file (every ``SAVE_INTERVAL_S`` and at close) and the next start begins after it.
"""

from __future__ import annotations

import logging
import os
import stat
import tempfile
import time
from pathlib import Path

__all__ = [
    "KEY_LEN",
    "SigningKeyError",
    "SigningTimestampStore",
    "default_state_dir",
    "now_signing_timestamp",
    "read_signing_key",
    "write_atomically",
]

log = logging.getLogger(__name__)

KEY_LEN = 32
SAVE_INTERVAL_S = 10.0
_EPOCH_2015_S = 1420070400
_UNITS_PER_S = 100_000
# After a restart, start this far past the saved value: covers what was sent between the last
# save and the stop, with margin (a forward jump is harmless, a backward one is fatal).
_RESTART_MARGIN = int(2 * SAVE_INTERVAL_S * _UNITS_PER_S)


class SigningKeyError(ValueError):
    """The signing key file is missing, unreadable or not 32 bytes; the key itself is never shown."""


def read_signing_key(path: str | os.PathLike) -> bytes:
    """Read a 32-byte MAVLink signing key from ``path`` (raw bytes or 64 hex digits)."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise SigningKeyError(f"cannot read MAVLink signing key file {str(p)!r}: {exc.strerror}") from None
    key = data
    if len(data) != KEY_LEN:
        text = data.strip()
        try:
            key = bytes.fromhex(text.decode("ascii")) if len(text) == 2 * KEY_LEN else b""
        except (UnicodeDecodeError, ValueError):
            key = b""
        if len(key) != KEY_LEN:
            raise SigningKeyError(
                f"MAVLink signing key file {str(p)!r} must hold 32 raw bytes or 64 hex digits, "
                f"got {len(data)} bytes (e.g. create one with: openssl rand -hex 32 > {p.name})"
            )
    try:
        mode = p.stat().st_mode
        if mode & (stat.S_IRWXG | stat.S_IRWXO):
            log.warning("MAVLink signing key file %s is readable by others; chmod 600 it", p)
    except OSError:
        pass
    return key


def now_signing_timestamp(unix_s: float | None = None) -> int:
    """The signing timestamp of ``unix_s`` (default: now), in 10 µs units since 2015-01-01."""
    t = time.time() if unix_s is None else unix_s
    return max(0, int((t - _EPOCH_2015_S) * _UNITS_PER_S))


class SigningTimestampStore:
    """The last signing timestamp of one (system, component), kept in a small text file.

    Parameters
    ----------
    path : the state file (created on the first save; its folder must exist and be writable).
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self._warned = False

    def initial_timestamp(self) -> int:
        """Where signing starts: now, or past the saved value if the clock is behind it."""
        now = now_signing_timestamp()
        saved = self.load()
        if saved is None:
            return now
        start = saved + _RESTART_MARGIN
        if start > now:
            log.warning(
                "system clock is behind the saved MAVLink signing timestamp; continuing from the saved one"
            )
        return max(now, start)

    def load(self) -> int | None:
        """The saved timestamp, or None if there is none (or it is unreadable)."""
        try:
            text = self.path.read_text().strip()
        except FileNotFoundError:
            return None
        except OSError as exc:
            log.warning("cannot read the MAVLink signing timestamp %s: %s", self.path, exc.strerror)
            return None
        try:
            value = int(text)
        except ValueError:
            log.warning("ignoring a corrupt MAVLink signing timestamp file %s", self.path)
            return None
        return value if value >= 0 else None

    def save(self, timestamp: int) -> bool:
        """Write ``timestamp`` atomically (temporary file, fsync, rename); False if it failed."""
        try:
            write_atomically(self.path, f"{int(timestamp)}\n")
        except OSError as exc:
            if not self._warned:
                log.warning(
                    "cannot save the MAVLink signing timestamp to %s (%s); after a restart with a clock "
                    "set back, receivers may reject our messages",
                    self.path,
                    exc.strerror,
                )
                self._warned = True
            return False
        return True


def write_atomically(path: Path, text: str) -> None:
    """Replace ``path`` with ``text`` so a crash leaves the old or the new file, never half of one.

    Temporary file in the same folder, fsync, rename. Raises OSError.
    """
    fd, tmp = tempfile.mkstemp(prefix=".signing-", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def default_state_dir(key_file: str | os.PathLike) -> Path:
    """``$STATE_DIRECTORY`` (systemd's ``StateDirectory=``) if set, else the key file's folder."""
    state = os.environ.get("STATE_DIRECTORY")
    if state:
        return Path(state.split(":")[0])
    return Path(key_file).resolve().parent
