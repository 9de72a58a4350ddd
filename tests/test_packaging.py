"""The wheel ships every package and data file the runtime needs."""

import tomllib

import paths

ROOT = paths.ROOT
FOLDERS = {
    "dronekey": "dronekey",
    "daemon": "dronekey.daemon",
    "calib": "dronekey.calib",
    "sim_replay": "dronekey.sim_replay",
}


def test_every_package_is_listed():
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(cfg["packages"])
    found = set()
    for folder, namespace in FOLDERS.items():
        for init in (ROOT / folder).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / folder)
            found.add(".".join([namespace, *rel.parts]))
    assert found == listed, (
        f"missing from pyproject: {sorted(found - listed)}; stale: {sorted(listed - found)}"
    )
