"""dronekey-train, dronekey-train-heading, dronekey-train-verifier and dronekey-export in a runtime
install (no torch): one line naming the extra."""

import subprocess
import sys

import pytest

# Blocks the torch import the way a runtime install lacks it (find_spec then returns None).
WITHOUT_TORCH = (
    "import sys; sys.modules['torch'] = None\n"
    "from dronekey.training.entry_points import {main}\n"
    "sys.exit({main}(['--help']))\n"
)


@pytest.mark.parametrize(
    ("main", "command"),
    [
        ("train_main", "dronekey-train"),
        ("export_main", "dronekey-export"),
        ("train_heading_main", "dronekey-train-heading"),
        ("train_verifier_main", "dronekey-train-verifier"),
    ],
)
def test_without_torch_one_line_and_the_extra(main, command):
    result = subprocess.run(
        [sys.executable, "-c", WITHOUT_TORCH.format(main=main)], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert (
        len(lines) == 1 and lines[0].startswith(f"{command}: needs torch") and "dronekey[train]" in lines[0]
    )


@pytest.mark.parametrize("main", ["train_main", "export_main", "train_heading_main", "train_verifier_main"])
def test_with_torch_the_command_runs(main, capsys):
    from dronekey.training import entry_points

    with pytest.raises(SystemExit) as stop:  # argparse's --help
        getattr(entry_points, main)(["--help"])
    assert stop.value.code == 0
    assert "usage:" in capsys.readouterr().out
