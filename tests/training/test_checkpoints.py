"""The run's files: network checkpoints round-trip, their errors name the file, the run state keeps
the keys --resume reads, and a resumed run's recipe is its saved one with the new overrides."""

from dataclasses import asdict, replace

import pytest
import torch

from dronekey.nn.model import DroneKeyConfig, DroneKeyNet
from dronekey.training.checkpoints import (
    CheckpointError,
    RunFolder,
    load_checkpoint,
    load_run_state,
    save_checkpoint,
    save_run_state,
)
from dronekey.training.recipe import presets, resumed_recipe, with_overrides

TINY = DroneKeyConfig.from_dict(presets()["tiny"].model)


def test_checkpoint_round_trip(tmp_path):
    torch.manual_seed(0)
    net = DroneKeyNet(TINY).eval()
    path = save_checkpoint(tmp_path / "ckpt.pt", net, {"epochs": 3, "drone_spec": "mini2"})
    loaded, meta = load_checkpoint(path)
    assert meta == {"epochs": 3, "drone_spec": "mini2"}
    assert loaded.config == TINY
    x = torch.randn(2, 3, TINY.input_size, TINY.input_size)
    with torch.no_grad():
        assert torch.equal(loaded(x).keypoints, net(x).keypoints)
    payload = torch.load(path, weights_only=True)
    assert sorted(payload) == ["config", "meta", "model"]


def test_checkpoint_errors_name_the_file(tmp_path):
    with pytest.raises(CheckpointError, match="checkpoint not found"):
        load_checkpoint(tmp_path / "missing.pt")
    bad = tmp_path / "bad.pt"
    torch.save({"weights": {}}, bad)
    with pytest.raises(CheckpointError, match=r"bad\.pt"):
        load_checkpoint(bad)


def test_run_state_holds_what_resume_reads(tmp_path):
    recipe = presets()["tiny"]
    net = torch.nn.Linear(2, 1)
    opt = torch.optim.AdamW(net.parameters())
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda step: 1.0)
    folder = RunFolder(tmp_path)
    save_run_state(folder.state, recipe, 4, [{"epoch": 5}], 12.5, opt, sched)
    state = load_run_state(folder.state)
    assert sorted(state) == ["best_ap", "epoch", "history", "optimizer", "recipe", "scheduler"]
    assert state["recipe"] == asdict(recipe) and state["epoch"] == 4 and state["best_ap"] == 12.5
    assert state["scheduler"]["lr_lambdas"] == [None]  # a plain function leaves nothing behind
    assert not folder.resumable()  # no last.pt yet
    save_run_state(folder.state, recipe, 4, [], 0.0, opt, sched, heatmaps=torch.nn.Linear(1, 1))
    assert "heatmaps" in load_run_state(folder.state)
    assert [p.name for p in (folder.last, folder.best, folder.history)] == [
        "last.pt",
        "best.pt",
        "history.json",
    ]
    assert folder.validation_cache(64, 128, coco=True).name == "val_coco_64_128.npz"


def test_resumed_recipe_is_the_saved_one_with_new_overrides():
    preset = presets()["tiny"]
    saved = asdict(replace(preset, lr=1e-4, frozen_batchnorm=True, epochs=5))
    del saved["heading_weight"]  # a field an older version did not save
    resumed = resumed_recipe(saved, with_overrides(preset, {"epochs": 8}), {"epochs": 8, "patience": None})
    assert resumed.lr == 1e-4 and resumed.frozen_batchnorm  # saved fields win over the preset
    assert resumed.epochs == 8  # overrides win over the saved recipe
    assert resumed.heading_weight == preset.heading_weight  # missing fields come from the preset
    assert resumed.patience == preset.patience  # None is no override
