"""Which renderer drew a sequence: a fingerprint of the simulator's code and the libraries it draws with.

A sequence's pixels follow from its seed and from the code and libraries that rendered it: the
renderer's own source, PyAV's H.264 encoder (libavcodec), OpenCV's rasterising, NumPy's random
streams and the packaged photographs (scikit-image, scikit-learn). The fingerprint names all of
them, so a cache of renders (``dronekey-eval robustness``) can tell a render from other code from
this code's, where the seed alone cannot: until it did, the reporting matrix was scored for
sessions on renders an older encoder had made (docs/evaluation.md, forty-fourth session).
"""

from __future__ import annotations

import functools
import hashlib
from importlib import metadata
from pathlib import Path

__all__ = ["renderer_fingerprint"]

_SOURCE_ROOT = Path(__file__).resolve().parent
# The distributions whose versions can change the pixels (absent ones are named so).
_LIBRARIES = ("av", "opencv-python-headless", "numpy", "scikit-image", "scikit-learn")


def _source_digest() -> str:
    """SHA-256 of every Python file of the simulator (path and bytes, in path order), 12 hex digits."""
    digest = hashlib.sha256()
    for path in sorted(_SOURCE_ROOT.rglob("*.py")):
        digest.update(path.relative_to(_SOURCE_ROOT).as_posix().encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


def _version(distribution: str) -> str:
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return "absent"


@functools.cache
def renderer_fingerprint() -> str:
    """``"source <12 hex>; av 18.1.0; libavcodec 62.28.102; ..."``: the same string for the same
    simulator source and libraries, another one when any of them changes (computed once a process)."""
    parts = [f"source {_source_digest()}"]
    for name in _LIBRARIES:
        parts.append(f"{name} {_version(name)}")
        if name == "av" and parts[-1] != "av absent":
            import av  # the encoder's own version, which a PyAV wheel bundles

            parts.append("libavcodec " + ".".join(map(str, av.library_versions["libavcodec"])))
    return "; ".join(parts)
