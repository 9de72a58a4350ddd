"""The drone verifier's recipe end to end on a few rendered crops: shards of the keypoint network's
own detections labelled drone / drone-free, a short training run, the ONNX export, the runtime
loading it, and KeypointModel handing its verdict on."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dronekey.nn.heading_net import HeadingNet, Symmetric
from dronekey.perception.drone_verifier import DroneVerifier, load_verifier
from dronekey.perception.heading_model import HeadingModel, default_heading_model_path
from dronekey.perception.keypoint_model import HEADING_MIN_PRESENCE, KeypointModel
from dronekey.sim_replay.sampler import CropSampler, SamplerConfig
from dronekey.training.patch_train import PatchRecipe
from dronekey.training.verifier_cli import main as verifier_main
from dronekey.training.verifier_data import load_verifier_shards, write_verifier_shards
from dronekey.training.verifier_train import evaluate_verifier, export_verifier, train_verifier


def test_symmetric_wrapper_gives_the_turned_patch_the_same_logit():
    torch.manual_seed(0)
    model = Symmetric(HeadingNet()).eval()
    x = torch.randn(3, 3, 64, 64)
    with torch.no_grad():
        np.testing.assert_allclose(model(torch.flip(x, dims=(2, 3))), model(x), atol=1e-5)


def test_shards_keep_what_the_network_calls_a_drone_and_say_whether_it_is(tmp_path):
    paths = write_verifier_shards(tmp_path, seed=5, shards=1, shard_size=40)
    with np.load(paths[0]) as d:
        assert d["patch"].shape[1:] == (64, 64, 3) and d["patch"].dtype == np.uint8
        assert len(d["y"]) == len(d["presence"]) == len(d["patch"]) > 0
        assert d["presence"].min() >= HEADING_MIN_PRESENCE  # only what the verifier sees at run time
    assert write_verifier_shards(tmp_path, seed=5, shards=1, shard_size=40) == paths  # kept
    patches, labels, presence = load_verifier_shards(paths)
    assert len(patches) == len(labels) == len(presence)
    with pytest.raises(ValueError, match="no shards"):
        load_verifier_shards([])


def toy_patches(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Drones: a bright cross through the centre (four arms); clutter: one bright blob off centre."""
    rng = np.random.default_rng(seed)
    patches = np.full((n, 64, 64, 3), 90, np.uint8)
    labels = (np.arange(n) % 3 == 0).astype(np.float32)  # a third drones
    for p, y in zip(patches, labels, strict=True):
        if y:
            p[30:34, 10:54] = 230
            p[10:54, 30:34] = 230
        else:
            r, c = rng.integers(4, 44, 2)
            p[r : r + 14, c : c + 14] = 230
    return patches, labels, np.ones(n, np.float32)


def test_train_export_and_load(tmp_path):
    train, val = toy_patches(300, 0), toy_patches(90, 1)
    model, history = train_verifier(train, val, tmp_path, PatchRecipe(epochs=8, batch=64))
    assert (tmp_path / "last.pt").is_file() and (tmp_path / "history.json").is_file()
    assert history[-1]["drones_kept"] > 0.9 and history[-1]["drone_free_rejected"] > 0.9
    path = export_verifier(model, tmp_path / "verifier.onnx", {"trained_on": {"toy": True}})
    runtime = DroneVerifier(path)
    assert runtime.metadata["trained_on"] == {"toy": True}
    tensor = np.random.default_rng(2).normal(size=(2, 3, 64, 64)).astype(np.float32)
    logits = runtime.inference(np.concatenate([tensor, np.ascontiguousarray(tensor[..., ::-1, ::-1])]))
    np.testing.assert_allclose(logits[:2], logits[2:], atol=1e-5)  # symmetric by construction
    figures = evaluate_verifier(model, *val)
    assert figures["auc"] > 0.95 and figures["drones"] == 30

    # KeypointModel runs it beside the front/back classifier on the same patches
    crops = CropSampler(SamplerConfig(negative_fraction=0.5), seed=3).batch(6)["image"]
    keypoints = KeypointModel(threads=1, heading_model=HeadingModel(), verifier=runtime)
    raw = keypoints.inference(keypoints.preprocess(crops))
    _, drone_p = keypoints._read_patches(crops, raw)
    assert drone_p.shape == (6,) and np.all((drone_p >= 0) & (drone_p <= 1))
    assert np.all(drone_p[raw.presence < HEADING_MIN_PRESENCE] == 0.0)  # not run on empty crops
    # A confirmed track's crop is not verified (NaN); the others' verdicts are as before.
    verify = [k % 2 == 0 for k in range(6)]
    _, some = keypoints._read_patches(crops, raw, verify)
    assert np.all(np.isnan(some[1::2]))
    np.testing.assert_allclose(some[0::2], drone_p[0::2], rtol=1e-5, atol=1e-6)


def test_errors_name_what_is_wrong(tmp_path, capsys):
    with pytest.raises(FileNotFoundError, match="dronekey-train-verifier"):
        DroneVerifier(tmp_path / "missing.onnx")
    with pytest.raises(ValueError, match="not a drone verifier"):
        DroneVerifier(default_heading_model_path())  # a front/back classifier has no drone_logit
    with pytest.raises(TypeError, match="verifier must be"):
        load_verifier(3)
    assert load_verifier(False) is None
    with pytest.raises(ValueError, match="drone and drone-free"):
        train_verifier(toy_patches(10, 0)[:1] + (np.ones(10, np.float32),) * 2, toy_patches(6, 1), tmp_path)
    assert verifier_main(["--seeds", "3", "--val-seed", "3"]) == 2
    assert "also a training seed" in capsys.readouterr().err
    assert verifier_main(["--shards", "0"]) == 2
    assert verifier_main(["--epochs", "0"]) == 2
