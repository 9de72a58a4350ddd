"""ONNX export, int8 quantisation, the ONNX Runtime KeypointModel and the export / bench CLIs, on a
tiny configuration (CI never trains)."""

import json
import subprocess
import sys

import numpy as np
import onnx
import pytest
import torch

from dronekey.bench import cli as bench
from dronekey.geometry.crop import crop_square, from_normalised, to_normalised
from dronekey.nn.model import DroneKeyConfig, DroneKeyNet
from dronekey.perception.keypoint_model import (
    IMAGENET_MEAN,
    IMAGENET_STD,
    KeypointModel,
    ModelFormatError,
    RawOutputs,
    default_model_path,
    mirror_averaged,
    preprocess_crops,
)
from dronekey.training import export_cli
from dronekey.training.checkpoints import save_checkpoint
from dronekey.training.quantize import quantize_int8

TINY = DroneKeyConfig(
    input_size=64, d_model=32, num_layers=2, num_heads=4, ff_dim=64, edge_widths=(8, 8, 16, 16, 32)
)
META = {
    "drone_spec": "mini2",
    "crop_policy": {"input_size": 64, "scale": 1.3},
    "trained_on": "unit test: random weights",
    "figures": {"ap_kp": 0.0},
    "epochs": 0,
}


@pytest.fixture(scope="module")
def trained_like():
    """A tiny network whose BatchNorm statistics are not the identity (as after training)."""
    torch.manual_seed(0)
    net = DroneKeyNet(TINY).train()
    with torch.no_grad():
        for _ in range(3):
            net(torch.randn(8, 3, 64, 64) * 0.5)
    return net.eval()


@pytest.fixture(scope="module")
def onnx_path(trained_like, tmp_path_factory):
    """Exported through the CLI, from a checkpoint as dronekey-train writes it."""
    folder = tmp_path_factory.mktemp("export")
    checkpoint = save_checkpoint(folder / "tiny.pt", trained_like, META)
    out = folder / "tiny.onnx"
    assert export_cli.main(["--checkpoint", str(checkpoint), "--out", str(out)]) == 0
    return out


def test_onnx_contract(onnx_path):
    model = onnx.load(str(onnx_path))
    assert max(o.version for o in model.opset_import if o.domain in ("", "ai.onnx")) >= 17
    (image,) = model.graph.input
    dims = [d.dim_param or d.dim_value for d in image.type.tensor_type.shape.dim]
    assert (image.name, dims) == ("image", ["batch", 3, 64, 64])
    outputs = {
        o.name: [d.dim_param or d.dim_value for d in o.type.tensor_type.shape.dim] for o in model.graph.output
    }
    assert outputs == {"keypoints": ["batch", 4, 2], "presence": ["batch"], "gate": ["batch", 2]}


def test_metadata(onnx_path):
    meta = {p.key: json.loads(p.value) for p in onnx.load(str(onnx_path)).metadata_props}
    assert meta["input_size"] == [64, 64]
    assert meta["normalisation"]["color"] == "RGB"
    assert meta["normalisation"]["mean"] == list(IMAGENET_MEAN)
    assert meta["normalisation"]["std"] == list(IMAGENET_STD)
    assert meta["keypoint_names"] == meta["drone_spec"]["keypoint_names"] and len(meta["keypoint_names"]) == 4
    assert meta["drone_spec"]["name"] == "mini2" and len(meta["drone_spec"]["keypoints_3d"]) == 4
    assert meta["crop_policy"] == META["crop_policy"]
    assert meta["trained_on"] == META["trained_on"] and meta["figures"] == META["figures"]
    assert meta["config"] == TINY.to_dict() and meta["meta"] == {"epochs": 0}
    assert meta["precision"] == "fp32" and meta["params"] > 0


@pytest.mark.parametrize("batch", [1, 3])
def test_onnx_runtime_agrees_with_torch(trained_like, onnx_path, batch):
    x = torch.randn(batch, 3, 64, 64, generator=torch.Generator().manual_seed(batch))
    with torch.no_grad():
        expected = trained_like(x)
    raw = KeypointModel(onnx_path).inference(x.numpy())
    np.testing.assert_allclose(raw.keypoints, expected.keypoints.numpy(), atol=1e-4)
    np.testing.assert_allclose(raw.presence, torch.sigmoid(expected.presence_logit).numpy(), atol=1e-4)
    np.testing.assert_allclose(raw.gate, expected.gate.numpy(), atol=1e-4)


def test_preprocess_is_rgb_imagenet_normalisation(onnx_path):
    crop = np.random.default_rng(0).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    tensor = KeypointModel(onnx_path).preprocess(crop)
    rgb = crop[..., ::-1].astype(np.float64) / 255.0
    expected = ((rgb - IMAGENET_MEAN) / IMAGENET_STD).transpose(2, 0, 1)[None]
    assert tensor.dtype == np.float32 and tensor.shape == (1, 3, 64, 64)
    np.testing.assert_allclose(tensor, expected, atol=1e-5)
    with pytest.raises(ValueError, match="uint8"):
        preprocess_crops(crop.astype(np.float32), 64)
    with pytest.raises(ValueError, match="S = 64"):
        preprocess_crops(crop[:32], 64)


def test_preprocess_by_look_up_is_the_float32_formula_to_the_bit():
    """The normalisation is a look-up per grey level (the serving path's CPU): it must give the
    float32 arithmetic of normalising every pixel, bit for bit, so training and serving agree."""
    crops = np.random.default_rng(1).integers(0, 256, (5, 64, 64, 3), dtype=np.uint8)
    scale = np.float32(1.0 / 255.0) / np.asarray(IMAGENET_STD, dtype=np.float32)
    offset = np.asarray(IMAGENET_MEAN, dtype=np.float32) / np.asarray(IMAGENET_STD, dtype=np.float32)
    formula = (crops[..., ::-1].astype(np.float32) * scale - offset).transpose(0, 3, 1, 2)
    tensor = preprocess_crops(crops, 64)
    assert tensor.dtype == np.float32 and tensor.flags.c_contiguous
    assert np.array_equal(tensor, formula)
    assert np.array_equal(preprocess_crops(crops[2], 64), formula[2:3])


def test_mirror_averaged_read_runs_each_crop_and_its_mirror(onnx_path):
    """``read`` with mirror averaging runs the crops and their left/right mirrors in one batch:
    the same outputs as running that batch by hand."""
    model = KeypointModel(onnx_path, mirror_average=True)
    frame = np.random.default_rng(2).integers(0, 256, (200, 300, 3), dtype=np.uint8)
    rois = [(10, 20, 64), (100, 50, 90)]
    reading = model.read(frame, rois)
    tensor = preprocess_crops(reading.crops, 64)
    by_hand = mirror_averaged(model.inference(np.concatenate([tensor, tensor[..., ::-1]])), len(rois))
    for got, expected in zip(reading.raw, by_hand, strict=True):
        assert np.array_equal(got, expected)


def test_postprocess_maps_keypoints_back_exactly(onnx_path):
    model = KeypointModel(onnx_path)
    rois = [(100, 50, 64), (-20, 300, 257)]
    truth = [np.array([[110.0, 60.0], [150.5, 70.25], [140.0, 100.0], [101.0, 99.0]]), np.full((4, 2), 350.0)]
    keypoints = np.stack([to_normalised(uv, roi) for uv, roi in zip(truth, rois, strict=True)]).astype(
        np.float64
    )
    raw = RawOutputs(keypoints, np.array([0.9, 0.1]), np.full((2, 2), 0.5))
    detections = model.postprocess(raw, rois)
    for det, uv, roi in zip(detections, truth, rois, strict=True):
        np.testing.assert_allclose(det.keypoints_px, uv, atol=1e-9)
        assert det.roi == roi
    assert [d.presence for d in detections] == [0.9, 0.1]


def test_detect_crops_runs_and_maps_back(onnx_path):
    model = KeypointModel(onnx_path)
    frame = np.random.default_rng(1).integers(0, 256, (240, 320, 3), dtype=np.uint8)
    rois = [(10, 20, 100), (250, 200, 128)]  # the second runs off the frame: black padding
    detections = model.detect(frame, rois)
    crops = np.stack([crop_square(frame, roi, 64) for roi in rois])
    raw = model.inference(model.preprocess(crops))
    for det, kp, roi in zip(detections, raw.keypoints, rois, strict=True):
        np.testing.assert_allclose(det.keypoints_px, from_normalised(kp, roi))
    assert model.detect(frame, []) == []


def test_runtime_errors_are_clear(onnx_path, tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nope\.onnx"):
        KeypointModel(tmp_path / "nope.onnx")
    with pytest.raises(ValueError, match="NoSuchExecutionProvider"):
        KeypointModel(onnx_path, providers=["NoSuchExecutionProvider"])
    bare = onnx.load(str(onnx_path))
    del bare.metadata_props[:]
    onnx.save(bare, str(tmp_path / "bare.onnx"))
    with pytest.raises(ModelFormatError, match="input_size"):
        KeypointModel(tmp_path / "bare.onnx")
    assert default_model_path().parts[-2:] == ("models", "dronekey_edge.onnx")
    if not default_model_path().is_file():
        with pytest.raises(FileNotFoundError, match="dronekey-export"):
            KeypointModel()


def test_runtime_does_not_import_torch():
    code = "import sys, dronekey.perception.keypoint_model; sys.exit('torch' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


def test_int8_quantisation(onnx_path, tmp_path):
    crops = np.random.default_rng(2).integers(0, 256, (8, 64, 64, 3), dtype=np.uint8)
    path = quantize_int8(onnx_path, tmp_path / "int8.onnx", crops, num_crops=8)
    model = KeypointModel(path)
    assert model.metadata["precision"] == "int8" and model.input_size == 64
    ops = {node.op_type for node in onnx.load(str(path)).graph.node}
    assert "QuantizeLinear" in ops
    fp32 = KeypointModel(onnx_path).inference(model.preprocess(crops))
    int8 = model.inference(model.preprocess(crops))
    assert np.abs(int8.keypoints - fp32.keypoints).max() < 0.1  # normalised crop units
    with pytest.raises(ValueError, match="uint8"):
        quantize_int8(onnx_path, tmp_path / "bad.onnx", crops.astype(np.float32), num_crops=8)


def test_int8_calibrates_on_the_training_sampler_by_default(onnx_path, tmp_path):
    path = quantize_int8(onnx_path, tmp_path / "int8.onnx", crops=None, num_crops=4)
    assert KeypointModel(path).metadata["precision"] == "int8"


def _one_line_error(capsys, argv, main):
    assert main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    return err


def test_export_cli_errors_are_one_line(capsys, tmp_path):
    err = _one_line_error(
        capsys, ["--checkpoint", str(tmp_path / "missing.pt"), "--out", "x.onnx"], export_cli.main
    )
    assert "checkpoint not found" in err and "missing.pt" in err
    (tmp_path / "junk.pt").write_text("not a checkpoint")
    err = _one_line_error(
        capsys, ["--checkpoint", str(tmp_path / "junk.pt"), "--out", "x.onnx"], export_cli.main
    )
    assert "junk.pt" in err


def test_bench_model_json(capsys, onnx_path):
    argv = ["model", "--models", "edge", "--edge-model", str(onnx_path), "--precisions", "fp32"]
    assert bench.main([*argv, "--runs", "3", "--warmup", "1", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    (entry,) = report["models"]
    assert entry["name"] == "edge" and entry["precision"] == "fp32" and entry["weights"] == "file"
    assert entry["input"] == [64, 64] and entry["params"] > 0
    assert entry["latency_ms_p99"] >= entry["latency_ms_p50"] > 0 and entry["fps"] > 0


def test_bench_missing_edge_model_is_one_line(capsys, tmp_path):
    err = _one_line_error(capsys, ["model", "--edge-model", str(tmp_path / "none.onnx")], bench.main)
    assert "none.onnx" in err


def test_mirror_average_equals_the_mean_of_a_crop_and_its_mirror(onnx_path):
    """detect(mirror_average=True) = mean of the plain answer and the mirrored crop's answer mapped
    back (x -> 1 - x, sides exchanged), computed here by hand with two separate runs."""
    from dronekey.geometry.crop import crop_square, from_normalised
    from dronekey.perception.keypoint_model import MIRROR, KeypointModel

    rng = np.random.default_rng(3)
    frame = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    rois = [(40, 30, 100), (150, 60, 140)]
    plain = KeypointModel(onnx_path, threads=1)
    both = KeypointModel(onnx_path, threads=1, mirror_average=True)
    S = plain.input_size
    crops = np.stack([crop_square(frame, roi, S) for roi in rois])
    a = plain.inference(plain.preprocess(crops))
    b = plain.inference(plain.preprocess(np.ascontiguousarray(crops[:, :, ::-1])))
    kb = b.keypoints[:, MIRROR].copy()
    kb[..., 0] = 1.0 - kb[..., 0]
    detections = both.detect(frame, rois)
    for i, (det, roi) in enumerate(zip(detections, rois, strict=True)):
        expected = from_normalised((a.keypoints[i] + kb[i]) / 2, roi)
        np.testing.assert_allclose(det.keypoints_px, expected, atol=1e-3)
        assert det.presence == pytest.approx((a.presence[i] + b.presence[i]) / 2, abs=1e-5)


def test_weights_read_back_from_the_export_reproduce_the_network(trained_like, onnx_path):
    """dronekey-train --init-from MODEL.onnx: the rebuilt network (BatchNorm folded, then frozen)
    computes what the export computes, and what the checkpoint it came from computed."""
    from dronekey.training.onnx_weights import OnnxWeightsError, frozen_batchnorm, weights_from_onnx

    torch.manual_seed(1)
    fresh = DroneKeyNet(TINY)
    weights = weights_from_onnx(onnx_path, fresh)  # checks itself against ONNX Runtime
    fresh.load_state_dict(weights, strict=False)
    fresh.train()
    assert frozen_batchnorm(fresh) > 0
    x = torch.randn(3, 3, 64, 64)
    with torch.no_grad():
        got, expected = fresh(x), trained_like(x)
    # train mode with frozen BatchNorm: the same function as the trained network in eval mode
    assert torch.allclose(got.keypoints, expected.keypoints, atol=1e-4)
    assert torch.allclose(got.presence_logit, expected.presence_logit, atol=1e-3)
    with pytest.raises(OnnxWeightsError, match="model not found"):
        weights_from_onnx(onnx_path.parent / "missing.onnx", fresh)


def test_extra_threads_sleep_between_calls_and_answer_as_one(onnx_path):
    """With 2 intra-op threads the session's threads do not spin between calls (they would burn the
    decoder's core), and the answers are the single-threaded session's."""
    from dronekey.perception.keypoint_model import KeypointModel

    one, two = KeypointModel(onnx_path, threads=1), KeypointModel(onnx_path, threads=2)
    options = two.session.get_session_options()
    assert options.get_session_config_entry("session.intra_op.allow_spinning") == "0"
    crops = np.random.default_rng(5).integers(0, 256, (6, one.input_size, one.input_size, 3), dtype=np.uint8)
    a, b = one.inference(one.preprocess(crops)), two.inference(two.preprocess(crops))
    np.testing.assert_allclose(b.keypoints, a.keypoints, atol=1e-5)
    np.testing.assert_allclose(b.presence, a.presence, atol=1e-5)
