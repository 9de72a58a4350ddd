"""The wheel ships every package and data file the runtime needs."""

import ast
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


def test_every_command_line_module_runs_with_python_m():
    """A module with a top-level ``main()`` that reads its arguments (a command) also runs as
    ``python -m package.module`` (a training run from a separate worktree is started that way),
    rather than importing and exiting silently."""
    silent = []
    for folder in FOLDERS:
        for path in (ROOT / folder).rglob("*.py"):
            tree = ast.parse(path.read_text())
            mains = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "main"]
            if not mains or not mains[0].args.args:
                continue
            guarded = any(isinstance(n, ast.If) and "__main__" in ast.unparse(n.test) for n in tree.body)
            if not guarded:
                silent.append(str(path.relative_to(ROOT)))
    assert not silent, f"no `if __name__ == '__main__'` in {silent}"
