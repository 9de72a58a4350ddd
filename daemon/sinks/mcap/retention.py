"""Retention of the MCAP log: delete this camera's oldest recordings to bound their total size and
keep the disk's free space, and never touch any other file.

Free space: by default the lesser of 500 MB and 5 % of the disk is kept free (a fixed 500 MB
would leave nothing to record on an 8 GB card), and the figure is said once at start.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
from pathlib import Path

__all__ = ["MB", "Retention", "min_free_bytes"]

log = logging.getLogger(__name__)

MB = 1_000_000
_MIN_FREE_FLOOR_MB = 500.0  # the default free-space reserve on big disks ...
_MIN_FREE_SHARE = 0.05  # ... and on small ones this share of the disk, whichever is less


class Retention:
    """The recordings of one camera in one folder, and the bounds they are kept within.

    Parameters
    ----------
    directory : Path
        Folder of the recordings.
    file_prefix, camera_id : str
        Recordings are named ``<file_prefix>_<camera_id>_<YYYYmmddTHHMMSS.mmm>Z[-N].mcap``; only
        files named so are counted and deleted.
    total_bytes : int
        Delete the oldest recordings while all of them together exceed this.
    min_free_bytes : int
        Delete the oldest recordings while the disk has less free space than this.
    """

    def __init__(
        self, directory: Path, file_prefix: str, camera_id: str, total_bytes: int, min_free_bytes: int
    ) -> None:
        self.directory = directory
        self.total_bytes = int(total_bytes)
        self.min_free_bytes = int(min_free_bytes)
        self.files_deleted = 0
        self._our_name = re.compile(
            rf"^{re.escape(file_prefix)}_{re.escape(camera_id)}_\d{{8}}T\d{{6}}\.\d{{3}}Z(-\d+)?\.mcap$"
        )

    def enforce(self, current: Path | None, current_size: int) -> int:
        """Delete the oldest finished recordings beyond the bounds, never ``current`` (the file being
        written, ``current_size`` bytes so far); returns the free bytes left on the disk."""
        name = current.name if current is not None else None
        older = [f for f in self._our_files() if f[1] != name]
        total = current_size + sum(size for _, _, size in older)
        free = shutil.disk_usage(self.directory).free
        while older and (total > self.total_bytes or free < self.min_free_bytes):
            _, old, size = older.pop(0)
            with contextlib.suppress(FileNotFoundError):
                (self.directory / old).unlink()
            self.files_deleted += 1
            total -= size
            free = shutil.disk_usage(self.directory).free
            log.info("MCAP retention deleted %s (%.1f MB)", old, size / MB)
        return free

    def low_space_text(self, free: int) -> str:
        """Why recording stops when ``free`` bytes are below the bound and nothing is left to delete."""
        return (
            f"free disk space {free / MB:.0f} MB is below min_free_mb={self.min_free_bytes / MB:.0f} "
            "and no older recording is left to delete"
        )

    def _our_files(self) -> list[tuple[float, str, int]]:
        """(mtime, name, size) of this camera's recordings, oldest first."""
        files = []
        with os.scandir(self.directory) as entries:
            for entry in entries:
                if self._our_name.match(entry.name) and entry.is_file(follow_symlinks=False):
                    st = entry.stat(follow_symlinks=False)
                    files.append((st.st_mtime, entry.name, st.st_size))
        files.sort()
        return files


def min_free_bytes(directory: Path, min_free_mb: float | None) -> int:
    """The free space to keep, in bytes: ``min_free_mb``, or by default the lesser of 500 MB and
    5 % of the disk that holds ``directory`` (its nearest existing parent); logged once."""
    if min_free_mb is not None:
        log.info("MCAP keeps %.0f MB free on the disk of %s (mcap.min_free_mb)", min_free_mb, directory)
        return int(min_free_mb * MB)
    probe = directory.absolute()
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    try:
        total = shutil.disk_usage(probe).total
    except OSError as exc:
        log.warning("MCAP cannot measure the disk of %s (%s): keeping 500 MB free", directory, exc)
        return int(_MIN_FREE_FLOOR_MB * MB)
    keep = min(_MIN_FREE_FLOOR_MB * MB, _MIN_FREE_SHARE * total)
    log.info(
        "MCAP keeps %.0f MB free on the %.1f GB disk of %s (mcap.min_free_mb null: the lesser of "
        "%.0f MB and %.0f %% of the disk)",
        keep / MB,
        total / 1e9,
        directory,
        _MIN_FREE_FLOOR_MB,
        _MIN_FREE_SHARE * 100,
    )
    return int(keep)
