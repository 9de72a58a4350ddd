"""dronekey-train end to end on the tiny recipe: epochs, checkpoints, plots, resume, bad input."""

import json

import pytest

from dronekey.model import load_checkpoint
from dronekey.train import main


def test_tiny_run_writes_checkpoints_and_plots_then_resumes(tmp_path):
    out = tmp_path / "run"
    assert main(["--preset", "tiny", "--out", str(out), "--workers", "0", "--threads", "1"]) == 0
    history = json.loads((out / "history.json").read_text())
    assert [h["epoch"] for h in history] == [1, 2]
    for key in ("sr90", "sr95", "ap_kp", "presence_auc", "median_err_px", "swap_rate", "gate"):
        assert key in history[-1]["val"]
    assert history[-1]["scale"] == pytest.approx(10 * 2.718281828**-5, rel=1e-3)  # S(100) = D e^(-0.05*100)
    for name in ("best.pt", "last.pt", "state.pt", "loss_scale.png", "gate_weights.png", "validation.png"):
        assert (out / name).is_file(), name
    _, meta = load_checkpoint(out / "last.pt")
    assert meta["epochs"] == 2 and "crop_policy" in meta and "figures" in meta

    assert (
        main(
            [
                "--preset",
                "tiny",
                "--out",
                str(out),
                "--workers",
                "0",
                "--threads",
                "1",
                "--resume",
                "--epochs",
                "3",
            ]
        )
        == 0
    )
    history = json.loads((out / "history.json").read_text())
    assert [h["epoch"] for h in history] == [1, 2, 3]


@pytest.mark.parametrize(
    "args", [["--epochs", "0"], ["--batch", "-1"], ["--backgrounds", "/nonexistent/dir"]]
)
def test_bad_arguments_are_one_line_errors(args, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--preset", "tiny", "--out", str(tmp_path), *args])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("dronekey-train: error:")
