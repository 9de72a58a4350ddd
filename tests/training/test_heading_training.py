"""The front/back classifier's recipe end to end on a few rendered crops: shards labelled with the
keypoint network's own keypoints, a short training run, the ONNX export, and the runtime loading it."""

from __future__ import annotations

import json
import logging
from dataclasses import replace

import numpy as np
import pytest
import torch

import dronekey.training.patch_train as patch_train
from dronekey.nn.heading_net import Antisymmetric, GatedAntisymmetric, HeadingNet
from dronekey.perception.heading_model import HeadingModel
from dronekey.sim_replay.sampler import CropSampler, SamplerConfig
from dronekey.training.heading_cli import main as heading_main
from dronekey.training.heading_data import NO_ANSWER, load_shards, write_shards
from dronekey.training.heading_train import (
    HEADING_RECIPE,
    HEADING_RECIPES,
    evaluate,
    export_heading_model,
    gated_objective,
    train_heading,
)


def test_antisymmetric_wrapper_gives_the_turned_patch_the_opposite_logit():
    torch.manual_seed(0)
    model = Antisymmetric(HeadingNet()).eval()
    x = torch.randn(3, 3, 64, 64)
    with torch.no_grad():
        np.testing.assert_allclose(model(torch.flip(x, dims=(2, 3))), -model(x), atol=1e-5)


def test_gated_wrapper_is_antisymmetric_and_reads_a_closed_gate_as_no_answer():
    torch.manual_seed(0)
    net = HeadingNet(outputs=2)
    model = GatedAntisymmetric(net).eval()
    x = torch.randn(3, 3, 64, 64)
    with torch.no_grad():
        np.testing.assert_allclose(model(torch.flip(x, dims=(2, 3))), -model(x), atol=1e-5)
        net.head[-1].bias[1] = -30.0  # the gate says no front: the order is a coin flip, however sure
        net.head[-1].bias[0] = 30.0
        np.testing.assert_allclose(model(x), 0.0, atol=1e-5)
        net.head[-1].bias[1] = 30.0  # gate open: the order logit's own answer
        order = net(x)[:, 0] - net(torch.flip(x, dims=(2, 3)))[:, 0]
        np.testing.assert_allclose(model(x), order / 2, atol=1e-4)
    with pytest.raises(ValueError, match="outputs must be 1 or 2, got 3"):
        HeadingNet(outputs=3)


def test_gated_objective_trains_the_gate_on_whether_there_is_an_answer():
    labels = torch.tensor([1.0, 0.0, NO_ANSWER])
    right = torch.tensor([[9.0, 9.0], [-9.0, 9.0], [0.0, -9.0]])  # sure orders, gate open, closed
    wrong_gate = right * torch.tensor([1.0, -1.0])
    best = np.log(2) / 3  # the no-answer patch's order at 0.5 is as low as its cross-entropy goes
    assert gated_objective(right, labels, 0.0) == pytest.approx(best, abs=1e-3)
    assert gated_objective(wrong_gate, labels, 0.0) > best + 5


def test_heading_net_repeats_the_convs_of_its_two_last_stages():
    convs = [m for m in HeadingNet(repeats=2).modules() if isinstance(m, torch.nn.Conv2d)]
    assert len(convs) == 6 and len([m for m in HeadingNet().modules() if isinstance(m, torch.nn.Conv2d)]) == 4
    deep = HEADING_RECIPES["deep"]
    assert sum(p.numel() for p in HeadingNet(deep.channels, 64, deep.repeats).parameters()) == 413_585
    assert sum(p.numel() for p in HeadingNet().parameters()) == 177_617  # the default classifier's
    with pytest.raises(ValueError, match="repeats"):
        HeadingNet(repeats=0)


def test_shards_label_the_networks_order_against_the_truth(tmp_path):
    paths = write_shards(tmp_path, seed=5, shards=1, shard_size=24)
    with np.load(paths[0]) as d:
        assert d["patch"].shape[1:] == (64, 64, 3) and d["patch"].dtype == np.uint8
        assert len(d["y"]) == len(d["err"]) == len(d["ratio"]) > 10
        np.testing.assert_array_equal(d["y"], d["err"] < d["err_twin"])
    again = write_shards(tmp_path, seed=5, shards=1, shard_size=24)  # kept, not rendered again
    assert again == paths
    patches, labels = load_shards(paths, decided=1.0, min_axis_ratio=0.0)
    assert len(patches) == len(labels) > 10


def test_a_body_that_shows_no_front_is_labelled_no_answer(tmp_path):
    paths = write_shards(tmp_path, seed=5, shards=1, shard_size=40)
    with np.load(paths[0]) as d:
        cue, kept = d["cue"], d["err"] != d["err_twin"]
    assert cue.any() and not cue.all()  # CUE_FREE_FRACTION of the drones, and top-only cues from below
    _, labels = load_shards(paths, decided=1.0, min_axis_ratio=0.0)
    np.testing.assert_array_equal(labels == NO_ANSWER, ~cue[kept])
    with np.load(paths[0]) as d:  # a shard written before "cue" existed: every body shows its front
        np.savez(tmp_path / "old.npz", **{k: d[k] for k in d.files if k != "cue"})
    _, old_labels = load_shards([tmp_path / "old.npz"], decided=1.0, min_axis_ratio=0.0)
    assert set(np.unique(old_labels)) <= {0.0, 1.0}


def test_sampler_draws_cue_free_drones_on_request():
    sampler = CropSampler(SamplerConfig(negative_fraction=0.0, cue_free_fraction=1.0), seed=3)
    assert not any(sampler.sample().front_visible for _ in range(6))
    with pytest.raises(ValueError, match="cue_free_fraction must be in"):
        SamplerConfig(cue_free_fraction=1.5)


def test_evaluate_scores_answerable_patches_and_the_doubt_on_the_others():
    patches, labels = _toy_task(256)
    labels[:64] = NO_ANSWER
    torch.manual_seed(0)
    model = Antisymmetric(HeadingNet()).eval()
    scores = evaluate(model, patches, labels)
    assert scores["samples"] == 192 and scores["no_answer_samples"] == 64
    assert 0 <= scores["no_answer_certainty"] <= 1 and 0 <= scores["no_answer_confident"] <= 1
    assert evaluate(model, patches[64:], labels[64:])["no_answer_certainty"] is None  # strict JSON: null


def _refuse_constant(name: str):
    raise AssertionError(f"{name} in JSON: not strict JSON")


def _toy_task(n: int = 512) -> tuple[np.ndarray, np.ndarray]:
    """A toy task with the real shapes: a bright blob at the top (label 1) or at the bottom (0)."""
    rng = np.random.default_rng(0)
    patches = np.full((n, 64, 64, 3), 90, np.uint8)
    labels = rng.integers(0, 2, n).astype(np.float32)
    for p, y in zip(patches, labels, strict=True):
        row = 12 if y else 44
        p[row : row + 8, 28:36] = 230
    return patches, labels


def test_train_export_and_load(tmp_path):
    patches, labels = _toy_task()
    model, history = train_heading(
        (patches, labels),
        (patches[:128], labels[:128]),
        tmp_path,
        replace(HEADING_RECIPES["deep"], epochs=3, batch=64),
    )
    assert (tmp_path / "last.pt").is_file() and (tmp_path / "history.json").is_file()
    assert history[-1]["accuracy"] > 0.9
    # no no-answer patch to average over: null, not the NaN token strict JSON readers refuse
    strict = json.loads((tmp_path / "history.json").read_text(), parse_constant=_refuse_constant)
    assert strict[-1]["no_answer_certainty"] is None
    assert sum(p.numel() for p in model.f.parameters()) == 413_585  # the deep recipe's net
    path = export_heading_model(model, tmp_path / "heading.onnx", {"trained_on": {"toy": True}})
    runtime = HeadingModel(path)
    assert runtime.metadata["trained_on"] == {"toy": True}
    logits = runtime.inference(np.zeros((2, 3, 64, 64), np.float32))
    assert logits.shape == (2,)


def test_the_gated_recipe_trains_exports_and_loads(tmp_path):
    patches, labels = _toy_task()
    labels[:128] = NO_ANSWER  # a quarter with no answer: the gate must close on them
    model, history = train_heading(
        (patches, labels), (patches, labels), tmp_path, replace(HEADING_RECIPES["gated"], epochs=3, batch=64)
    )
    assert isinstance(model, GatedAntisymmetric) and history[-1]["accuracy"] > 0.9
    runtime = HeadingModel(export_heading_model(model, tmp_path / "gated.onnx"))
    assert runtime.inference(np.zeros((2, 3, 64, 64), np.float32)).shape == (2,)


def test_cli_refuses_a_validation_seed_it_trains_on(capsys):
    assert heading_main(["--seeds", "3", "--val-seed", "3"]) == 2
    assert "also a training seed" in capsys.readouterr().err
    assert heading_main(["--shards", "0"]) == 2


def test_a_stopped_run_goes_on_to_the_weights_an_uninterrupted_run_has(tmp_path, monkeypatch, caplog):
    patches, labels = _toy_task(256)
    data, val = (patches, labels), (patches[:64], labels[:64])
    recipe = replace(HEADING_RECIPE, epochs=2, batch=64, validate_every=3)  # 8 steps, checkpoints at 3 and 6
    whole, whole_history = train_heading(data, val, tmp_path / "whole", recipe)

    augment, calls = patch_train.augment, []

    def stop_in_step_5(*args, **kwargs):
        calls.append(1)
        if len(calls) == 5:
            raise KeyboardInterrupt
        return augment(*args, **kwargs)

    monkeypatch.setattr(patch_train, "augment", stop_in_step_5)
    with pytest.raises(KeyboardInterrupt):
        train_heading(data, val, tmp_path / "stopped", recipe)
    monkeypatch.setattr(patch_train, "augment", augment)
    with caplog.at_level(logging.INFO, logger="dronekey.training.patch_train"):
        resumed, history = train_heading(data, val, tmp_path / "stopped", recipe, resume=True)
    assert "at step 3 of 8" in caplog.text
    assert [h["step"] for h in history] == [h["step"] for h in whole_history] == [3, 6, 8]
    for name, tensor in whole.state_dict().items():
        torch.testing.assert_close(resumed.state_dict()[name], tensor, rtol=0, atol=0)

    # Another recipe (here twice the epochs) is another run: it starts anew and says why.
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="dronekey.training.patch_train"):
        _, longer = train_heading(
            data, val, tmp_path / "stopped", replace(HEADING_RECIPE, epochs=4, batch=64), resume=True
        )
    assert "starting a new run" in caplog.text and longer[-1]["step"] == 16
