"""DroneKey's MAVLink dialect: ``dronekey.xml`` generated into a Python module with pymavlink's mavgen.

pymavlink's published ``development`` dialect lacks TARGET_ABSOLUTE (510) and TARGET_RELATIVE (511),
so the project ships ``dronekey.xml`` (common.xml plus those two messages, copied from upstream's
development.xml) and generates it here (docs/design.md §6.2).

When: lazily, on the first ``load_dialect()`` of a process. The module is written into a cache
folder under a name keyed by the SHA-256 of every input (our XML, the wheel's common.xml,
standard.xml and minimal.xml, pymavlink's version), so a changed XML or a pymavlink upgrade makes a
new module and an unchanged one is generated once per machine (about 0.2 s) and then only imported.
Generation runs in a private temporary folder inside the cache and the result is moved into place
with ``os.replace``, so concurrent daemons never see a half-written file.

mavgen resolves ``<include>`` relative to the including file, so the temporary folder holds our XML
next to copies of the wheel's ``pymavlink/dialects/v20/{common,standard,minimal}.xml``.

Cache folder, first usable of: ``$DRONEKEY_MAVLINK_CACHE``, ``$CACHE_DIRECTORY`` (systemd's
``CacheDirectory=``), ``$XDG_CACHE_HOME/dronekey/mavlink`` or ``~/.cache/dronekey/mavlink``, and
``<tempdir>/dronekey-mavlink-<uid>``.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.resources
import importlib.util
import io
import logging
import os
import shutil
import sys
import tempfile
import threading
from pathlib import Path
from types import ModuleType

__all__ = ["DialectError", "cache_directory", "dialect_xml", "load_dialect", "write_message_definitions"]

log = logging.getLogger(__name__)

DIALECT_XML_NAME = "dronekey.xml"
_INCLUDED_XML = ("common.xml", "standard.xml", "minimal.xml")
_MODULE_PREFIX = "dronekey_mavlink_"

_lock = threading.Lock()
_loaded: dict[str, ModuleType] = {}


class DialectError(RuntimeError):
    """The dialect could not be generated or imported; the message says which file and why."""


def dialect_xml() -> bytes:
    """The shipped dialect XML (``dronekey.xml`` beside this module)."""
    return importlib.resources.files(__package__).joinpath(DIALECT_XML_NAME).read_bytes()


def _wheel_xml_dir() -> Path:
    import pymavlink

    return Path(pymavlink.__file__).resolve().parent / "dialects" / "v20"


def _input_digest(our_xml: bytes, wheel_dir: Path) -> str:
    import pymavlink

    h = hashlib.sha256()
    h.update(getattr(pymavlink, "__version__", "unknown").encode())
    h.update(b"\0" + our_xml)
    for name in _INCLUDED_XML:
        h.update(b"\0" + (wheel_dir / name).read_bytes())
    return h.hexdigest()


def write_message_definitions(folder: str | os.PathLike) -> str:
    """Lay out the dialect for tools that generate it themselves (MAVProxy, ``mavutil.set_dialect``):
    ``<folder>/v1.0/<name>.xml`` with the XML files it includes, where pymavlink looks when the
    ``MDEF`` environment variable is ``folder``. Returns ``name`` (``dronekey_`` and a hash of the
    inputs), the ``--dialect`` to give: a new name for new XML, so pymavlink, which writes the module
    it generates into its own ``dialects/v20`` folder and reuses it from then on, never uses a stale one.
    """
    wheel_dir = _wheel_xml_dir()
    our_xml = dialect_xml()
    name = "dronekey_" + _input_digest(our_xml, wheel_dir)[:12]
    target = Path(folder) / "v1.0"
    target.mkdir(parents=True, exist_ok=True)
    (target / f"{name}.xml").write_bytes(our_xml)
    for included in _INCLUDED_XML:
        shutil.copyfile(wheel_dir / included, target / included)
    return name


def _writable_dir(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    return os.access(path, os.W_OK | os.X_OK)


def cache_directory() -> Path:
    """First writable folder of the list in the module docstring (created if missing)."""
    candidates: list[Path] = []
    if os.environ.get("DRONEKEY_MAVLINK_CACHE"):
        candidates.append(Path(os.environ["DRONEKEY_MAVLINK_CACHE"]))
    if os.environ.get("CACHE_DIRECTORY"):  # systemd may list several folders separated by ':'
        candidates.append(Path(os.environ["CACHE_DIRECTORY"].split(":")[0]) / "mavlink")
    xdg = os.environ.get("XDG_CACHE_HOME")
    candidates.append(
        Path(xdg) / "dronekey" / "mavlink" if xdg else Path.home() / ".cache" / "dronekey" / "mavlink"
    )
    candidates.append(Path(tempfile.gettempdir()) / f"dronekey-mavlink-{os.getuid()}")
    for path in candidates:
        if _writable_dir(path):
            return path
    raise DialectError(f"no writable cache folder for the generated MAVLink dialect; tried {candidates}")


def _generate(our_xml: bytes, wheel_dir: Path, target: Path) -> None:
    """Run mavgen in a private temporary folder and move the module to ``target`` atomically."""
    from pymavlink.generator import mavgen
    from pymavlink.generator.mavparse import PROTOCOL_2_0

    work = Path(tempfile.mkdtemp(prefix=".gen-", dir=target.parent))
    try:
        (work / DIALECT_XML_NAME).write_bytes(our_xml)
        for name in _INCLUDED_XML:
            shutil.copyfile(wheel_dir / name, work / name)
        out = work / target.name
        opts = mavgen.Opts(str(out), wire_protocol=PROTOCOL_2_0, language="Python3", validate=False)
        chatter = io.StringIO()  # mavgen prints its progress; keep it out of the daemon's log
        try:
            with contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter):
                ok = mavgen.mavgen(opts, [str(work / DIALECT_XML_NAME)])
        except (Exception, SystemExit) as exc:
            raise DialectError(f"mavgen failed on {DIALECT_XML_NAME}: {exc!r}\n{chatter.getvalue()}") from exc
        if not ok or not out.is_file():
            raise DialectError(f"mavgen failed on {DIALECT_XML_NAME}:\n{chatter.getvalue()}")
        os.replace(out, target)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _import(path: Path, name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise DialectError(f"cannot import the generated dialect {path}")
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except Exception as exc:
        raise DialectError(f"cannot import the generated dialect {path}: {exc!r}") from exc
    if getattr(module, "WIRE_PROTOCOL_VERSION", None) != "2.0":
        raise DialectError(f"{path} is not a MAVLink 2 module")
    # The generated parser logs "new stream", "sig mismatch", "old timestamp" at INFO for every such
    # packet it sees: input anyone can send, so a flood of forged packets became a flood of log
    # lines. The sink counts refusals and reports them at a bounded rate instead (``refusals``).
    logging.getLogger(module.__name__).setLevel(logging.WARNING)
    sys.modules[name] = module
    return module


def load_dialect(cache_dir: str | os.PathLike | None = None) -> ModuleType:
    """The generated pymavlink module of ``dronekey.xml`` (MAVLink 2), generating it if needed.

    Parameters
    ----------
    cache_dir : folder for the generated module; default ``cache_directory()``.

    Returns
    -------
    The module, with pymavlink's usual API (``MAVLink``, ``MAVLink_target_relative_message``, enums).
    Loaded once per process and input digest; thread-safe.
    """
    our_xml = dialect_xml()
    wheel_dir = _wheel_xml_dir()
    missing = [n for n in _INCLUDED_XML if not (wheel_dir / n).is_file()]
    if missing:
        raise DialectError(f"pymavlink's wheel lacks {missing} in {wheel_dir}; reinstall pymavlink")
    digest = _input_digest(our_xml, wheel_dir)
    name = _MODULE_PREFIX + digest[:16]
    with _lock:
        if name in _loaded:
            return _loaded[name]
        folder = Path(cache_dir) if cache_dir is not None else cache_directory()
        if not _writable_dir(folder) and not (folder / f"{name}.py").is_file():
            raise DialectError(f"cache_dir {str(folder)!r} is not a writable folder")
        path = folder / f"{name}.py"
        if not path.is_file():
            log.info("generating the MAVLink dialect %s into %s", DIALECT_XML_NAME, path)
            _generate(our_xml, wheel_dir, path)
        module = _import(path, name)
        _loaded[name] = module
        return module
