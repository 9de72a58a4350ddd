"""Write a multi-camera scene: ``OUT/camK/`` per camera (video or frames, §5.1 JSON, camera.yaml, as a
single-camera render writes them) and ``OUT/site.json`` (docs/design.md §5.4), the site file last.

A failure or Ctrl-C removes every camera folder this call created, so no half rig is left behind.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

from dronekey.sim_replay.io.render_output import RenderedSequenceLike, WrittenSequence, write_sequence
from dronekey.sim_replay.io.site import SITE_FILE, SiteDocument, save_site

__all__ = ["write_rig"]


def write_rig(
    views: list[RenderedSequenceLike],
    site: SiteDocument,
    out_dir: str | Path,
    *,
    images: bool = False,
    on_frame: Callable[[], object] | None = None,
    codec: str = "mp4v",
    bitrate_bps: int | None = None,
) -> tuple[list[WrittenSequence], Path]:
    """Render every camera's view into ``out_dir/<camera folder>`` and write the site file.

    ``views[k]`` is the camera ``site.cameras[k]``. Returns what each camera wrote and the site
    file's path. ``codec`` and ``bitrate_bps`` as ``write_sequence`` takes them; raises OSError or
    ValueError as it does.
    """
    out_dir = Path(out_dir)
    if len(views) != len(site.cameras):
        raise ValueError(f"{len(views)} views for the site's {len(site.cameras)} cameras")
    created: list[Path] = []
    written: list[WrittenSequence] = []
    try:
        for view, camera in zip(views, site.cameras, strict=True):
            folder = out_dir / camera.folder
            if not folder.exists():
                folder.mkdir(parents=True)
                created.append(folder)
            written.append(
                write_sequence(
                    view, folder, images=images, on_frame=on_frame, codec=codec, bitrate_bps=bitrate_bps
                )
            )
        site_path = out_dir / SITE_FILE
        save_site(site, site_path)
    except BaseException:
        for folder in created:
            shutil.rmtree(folder, ignore_errors=True)
        raise
    return written, site_path
