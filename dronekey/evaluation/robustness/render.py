"""Rendering the matrix of ``dronekey-eval robustness``, reusing what an earlier run left on disk.

Rendered sequences are kept in ``out_dir`` and reused on a rerun when their JSON ``info``, frame
count and image size match what the matrix asks for.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from dronekey.evaluation.robustness.matrix import MatrixEntry
from dronekey.sim_replay.io.frames import resolve_source
from dronekey.sim_replay.io.render_output import write_sequence
from dronekey.sim_replay.io.sequence_reader import load_sequence

__all__ = ["Rendered", "render_matrix"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Rendered:
    """A matrix entry on disk: its JSON, whether an earlier run's render was reused, render time (s)."""

    entry: MatrixEntry
    json_path: Path
    reused: bool
    render_s: float


def _matches(json_path: Path, entry: MatrixEntry, expected_info: dict) -> bool:
    """Whether ``json_path`` (and its media) is the sequence ``entry`` asks for."""
    if not json_path.is_file():
        return False
    try:
        seq = load_sequence(json_path)
        resolve_source(seq)
    except (ValueError, OSError, RuntimeError) as exc:  # SequenceFormatError, FrameSourceError
        log.info("%s is not reusable (%s); rendering it again", json_path, exc)
        return False
    size = (entry.width, entry.height)
    if seq.info != expected_info or len(seq.frames) != entry.frames or seq.camera.size != size:
        log.info("%s was rendered with other settings; rendering it again", json_path)
        return False
    return True


def render_matrix(
    entries: Sequence[MatrixEntry], out_dir: str | Path, *, progress: bool = False
) -> list[Rendered]:
    """Render every entry into ``entry.folder(out_dir)``, reusing the ones already there.

    Parameters
    ----------
    entries : the matrix (``plan_matrix``).
    out_dir : root folder (created if missing).
    progress : show a tqdm bar (frames rendered) on stderr.

    Returns
    -------
    One ``Rendered`` per entry, in order.

    Raises
    ------
    ImportError
        ``background="photos"`` without scikit-image and scikit-learn (before anything is rendered).
    OSError
        A file cannot be written.
    """
    built = [(e, e.build()) for e in entries]  # every entry checked before the first render
    todo = []
    out: dict[int, Rendered] = {}
    for i, (entry, seq) in enumerate(built):
        json_path = entry.folder(out_dir) / f"{seq.name}.json"
        if _matches(json_path, entry, seq.info):
            out[i] = Rendered(entry, json_path, True, 0.0)
        else:
            todo.append((i, entry, seq))
    log.info("%d of %d sequences reused, %d to render", len(out), len(entries), len(todo))
    with tqdm(
        total=sum(e.frames for _, e, _ in todo),
        desc="render",
        unit="frame",
        disable=not progress or not todo,
        file=sys.stderr,
    ) as bar:
        for i, entry, seq in todo:
            folder = entry.folder(out_dir)
            folder.mkdir(parents=True, exist_ok=True)
            bar.set_postfix_str(entry.name)
            written = write_sequence(seq, folder, on_frame=bar.update)
            log.info("rendered %s: %d frames in %.1f s", entry.name, written.n_frames, written.seconds)
            out[i] = Rendered(entry, written.json_path, False, written.seconds)
    return [out[i] for i in range(len(entries))]
