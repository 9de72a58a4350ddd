"""dronekey-train end to end on the tiny recipe: epochs, checkpoints, plots, resume, bad input."""

import json

import pytest

from dronekey.geometry.crop import CropPolicy
from dronekey.training import trainer as trainer_module
from dronekey.training.checkpoints import load_checkpoint
from dronekey.training.crop_stream import crop_sources
from dronekey.training.train_cli import main


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


def test_presence_stage_is_kept_only_when_it_helps(tmp_path, caplog):
    out = tmp_path / "run"
    args = ["--preset", "tiny", "--out", str(out), "--workers", "0", "--threads", "1", "--epochs", "1"]
    with caplog.at_level("INFO", logger="dronekey.training"):
        assert main([*args, "--presence-steps", "5"]) == 0
    (line,) = [r.getMessage() for r in caplog.records if "presence head refit" in r.getMessage()]
    _, meta = load_checkpoint(out / "best.pt")
    if line.endswith(": kept"):
        assert meta["presence_steps"] == 5
    else:
        assert "discarded" in line and "presence_steps" not in meta


@pytest.mark.parametrize(
    "args",
    [
        ["--epochs", "0"],
        ["--batch", "-1"],
        ["--backgrounds", "/nonexistent/dir"],
        ["--presence-steps", "-1"],
        ["--crop-jitter-scale", "1.0"],
        ["--side-view-boost", "1.0"],
        ["--side-view-boost", "0.5", "--coco", "/nonexistent/dir"],
    ],
)
def test_bad_arguments_are_one_line_errors(args, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--preset", "tiny", "--out", str(tmp_path), *args])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("dronekey-train: error:")


def test_crop_jitter_scale_reaches_the_recipe_and_the_checkpoint_and_a_resume(tmp_path, monkeypatch):
    out = tmp_path / "run"
    args = ["--preset", "tiny", "--workers", "0", "--threads", "1", "--epochs", "1", "--presence-steps", "0"]
    assert main([*args, "--out", str(out), "--crop-jitter-scale", "0.45"]) == 0
    _, meta = load_checkpoint(out / "last.pt")
    assert meta["crop_policy"]["jitter_scale"] == 0.45
    assert meta["crop_policy"]["scale"] == 1.3  # the rest of the policy is the preset's

    # Resumed without the option, the run keeps cutting its crops as it started.
    used = []
    real_sources = trainer_module.crop_sources
    monkeypatch.setattr(
        trainer_module, "crop_sources", lambda crop, *a: used.append(crop) or real_sources(crop, *a)
    )
    assert main([*args[:-4], "--out", str(out), "--resume", "--epochs", "2", "--presence-steps", "0"]) == 0
    assert [c.jitter_scale for c in used] == [0.45]


def test_side_view_boost_weights_the_training_stream_only_and_survives_a_resume(tmp_path, monkeypatch):
    train, validation = crop_sources(CropPolicy(), side_view_boost=0.5)
    assert train.sampler(0).config.side_view_boost == 0.5
    assert validation.sampler(0).config.side_view_boost == 0.0  # validation figures stay comparable

    out = tmp_path / "run"
    args = ["--preset", "tiny", "--workers", "0", "--threads", "1", "--presence-steps", "0"]
    args += ["--out", str(out)]
    assert main([*args, "--epochs", "1", "--side-view-boost", "0.5"]) == 0
    used = []
    real_sources = trainer_module.crop_sources
    monkeypatch.setattr(
        trainer_module, "crop_sources", lambda crop, *a: used.append(a[-1]) or real_sources(crop, *a)
    )
    assert main([*args, "--resume", "--epochs", "2"]) == 0
    assert used == [0.5]


def test_presence_head_refit_changes_only_the_head_and_switches_its_input():
    """The presence stage: the head learns drone vs empty crops from the projected tokens; every
    other weight stays as it was, and the config says what the head now reads."""
    import itertools

    import numpy as np
    import torch

    from dronekey.nn.model import DroneKeyConfig, DroneKeyNet
    from dronekey.perception.keypoint_model import IMAGENET_MEAN, IMAGENET_STD, preprocess_crops
    from dronekey.training.presence_refit import fit_presence_head

    torch.manual_seed(0)
    config = DroneKeyConfig(d_model=32, num_layers=2, num_heads=2, ff_dim=64, edge_widths=(8, 16, 16, 24, 32))
    net = DroneKeyNet(config)
    before = {k: v.clone() for k, v in net.state_dict().items()}
    rng = np.random.default_rng(0)
    # Separable toy data: "drone" crops are bright, empty ones dark.
    present = np.arange(16) % 2 == 0
    images = np.where(present[:, None, None, None], 200, 40) + rng.integers(0, 30, (16, 128, 128, 3))
    x = torch.from_numpy(preprocess_crops(images.astype(np.uint8), 128, IMAGENET_MEAN, IMAGENET_STD))
    batch = (x, torch.zeros(16, 4, 2), torch.from_numpy(present), torch.zeros(16))
    fit_presence_head(net, itertools.repeat(batch), steps=60, lr=5e-2)
    assert net.config.presence_input == "tokens"
    with torch.no_grad():
        p = torch.sigmoid(net(x).presence_logit).numpy()
    assert p[present].min() > p[~present].max()
    after = net.state_dict()
    changed = sorted(k for k in before if not torch.equal(before[k], after[k]))
    assert changed == ["presence.bias", "presence.weight"]


def test_init_from_copies_matching_weights_and_names_a_bad_file(tmp_path, capsys, caplog):
    first = tmp_path / "first"
    args = ["--preset", "tiny", "--workers", "0", "--threads", "1", "--epochs", "1", "--presence-steps", "0"]
    assert main([*args, "--out", str(first)]) == 0
    with caplog.at_level("INFO", logger="dronekey.training"):
        assert main([*args, "--out", str(tmp_path / "second"), "--init-from", str(first / "last.pt")]) == 0
    (line,) = [r.getMessage() for r in caplog.records if r.getMessage().startswith("initialised")]
    assert "fresh: none" in line
    assert main([*args, "--out", str(tmp_path / "third"), "--init-from", str(tmp_path / "missing.pt")]) == 2
    assert "--init-from: checkpoint not found" in capsys.readouterr().err


def test_heatmap_targets_mark_every_and_front_propellers():
    import torch

    from dronekey.nn.heatmap_aux import propeller_targets

    hi, lo = 11.5 / 16, 3.5 / 16  # centres of cells 11 and 3 of a 16 x 16 map
    kp = torch.tensor([[[hi, lo], [hi, hi], [lo, hi], [lo, lo]]])  # FR RR RL FL
    both = torch.cat([kp, kp])
    maps = propeller_targets(both, torch.tensor([True, False]), grid=16, input_size=128)
    assert maps.shape == (2, 2, 16, 16)
    every, front = maps[0]
    # FR peaks in cell (row 3, col 11) of both maps; the rear propellers are not "front"
    assert every[3, 11] > 0.99 and front[3, 11] > 0.99
    assert every[11, 11] > 0.99 and front[11, 11] < 1e-3
    assert maps[1].abs().max() == 0  # a drone-free crop has no propellers


def test_trainer_errors_name_the_argument(tmp_path):
    from dronekey.training.recipe import presets
    from dronekey.training.trainer import Trainer

    with pytest.raises(ValueError, match=r"precision must be one of .* got 'fp16'"):
        Trainer(presets()["tiny"], tmp_path, recipe_name="tiny", precision="fp16")
    with pytest.raises(ValueError, match="workers must be >= 0, got -1"):
        Trainer(presets()["tiny"], tmp_path, recipe_name="tiny", workers=-1)
