"""The import rules of docs/architecture.md hold: ``lint-imports`` with pyproject's contracts.

import-linter builds its graph by walking a package's folder, but ``dronekey`` spans four folders
(pyproject's ``package-dir``: ``daemon/``, ``calib/`` and ``sim_replay/`` are mapped under it). The
test therefore lays the sources out as the wheel installs them, in a temporary folder, and runs
``lint-imports`` there; a broken contract fails with import-linter's own report of the chain.
"""

import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import paths


def _installed_layout(dest: Path) -> Path:
    """Copy every package's ``.py`` files to where the wheel puts them; returns ``dest``."""
    setuptools_cfg = tomllib.loads((paths.ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    mapped = setuptools_cfg["package-dir"]
    for package in setuptools_cfg["packages"]:
        root = max((p for p in mapped if package == p or package.startswith(p + ".")), key=len)
        folder = paths.ROOT / mapped[root] / Path(*package.split(".")[root.count(".") + 1 :])
        target = dest.joinpath(*package.split("."))
        target.mkdir(parents=True, exist_ok=True)
        for source in folder.glob("*.py"):
            shutil.copy2(source, target / source.name)
    return dest


def test_import_contracts_hold(tmp_path):
    tree = _installed_layout(tmp_path / "site")
    lint_imports = shutil.which("lint-imports") or str(Path(sys.executable).with_name("lint-imports"))
    result = subprocess.run(
        [lint_imports, str(paths.ROOT / "pyproject.toml"), "--no-cache"],
        cwd=tree,
        env={"PYTHONPATH": str(tree), "PATH": str(Path(sys.executable).parent)},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout, result.stdout
