"""The DroneKey network: paper parameter count, gradients at initialisation, the written-out encoder
layer and configuration."""

import pytest
import torch
from torch import nn

from dronekey.nn.backbones import ResNet50Trunk
from dronekey.nn.loss import build_loss
from dronekey.nn.model import (
    DroneKeyConfig,
    DroneKeyNet,
    _encoder_layer_forward,
    count_parameters,
    sine_positional_encoding_2d,
)

TINY = DroneKeyConfig(
    backbone="edge",
    input_size=64,
    d_model=32,
    num_layers=3,
    num_heads=4,
    ff_dim=64,
    edge_widths=(8, 8, 16, 16, 32),
    edge_depths=(1, 1, 1, 1),
)
# The paper's head and trunk on a small input, so a backward pass through ResNet-50 stays fast.
TINY_NORMED = DroneKeyConfig(**{**TINY.to_dict(), "token_norm": True, "pe_scale": 10.0})  # as edge()
TINY_RESNET = DroneKeyConfig(
    backbone="resnet50", input_size=64, d_model=64, num_layers=2, num_heads=4, ff_dim=64
)


def test_paper_configuration_has_the_papers_76_02_million_parameters():
    net = DroneKeyNet(DroneKeyConfig.paper())
    assert count_parameters(net.backbone) == 23_508_032  # torchvision resnet50 without fc
    total = count_parameters(net)
    assert abs(total - 76.02e6) <= 0.01e6, total
    # docs/design.md §7: the paper's 84.42 M (Tab. III; 84.41 M in Tab. IV) also counts the reference
    # code's unused template encoder layer, and not our presence head.
    papers_count = total - count_parameters(net.presence) + count_parameters(net.layers[0])
    assert round(papers_count / 1e6, 2) == 84.42


def test_resnet50_trunk_reaches_stride_32_with_2048_channels():
    assert ResNet50Trunk()(torch.zeros(1, 3, 64, 64)).shape == (1, 2048, 2, 2)


@pytest.mark.parametrize("config", [TINY, TINY_RESNET, DroneKeyConfig.edge()], ids=["tiny", "resnet", "edge"])
def test_output_shapes_and_predictions_start_inside_the_crop(config):
    torch.manual_seed(0)
    net = DroneKeyNet(config)
    out = net(torch.randn(3, 3, config.input_size, config.input_size))
    assert out.keypoints.shape == (3, 4, 2)
    assert out.presence_logit.shape == (3,)
    assert out.gate.shape == (3, config.num_layers)
    assert torch.allclose(out.gate.sum(dim=1), torch.ones(3))
    # Dead-ReLU guard: every output starts well inside (0, 1), none is clipped by the final ReLU.
    assert out.keypoints.min() > 0.2 and out.keypoints.max() < 0.8


@pytest.mark.parametrize("config", [TINY, TINY_NORMED, TINY_RESNET], ids=["edge", "edge-normed", "resnet"])
def test_gradients_reach_every_parameter_at_initialisation(config):
    torch.manual_seed(0)
    net = DroneKeyNet(config).train()
    x = torch.randn(4, 3, config.input_size, config.input_size)
    gt = torch.rand(4, 4, 2) * 0.6 + 0.2
    present = torch.tensor([True, True, True, False])
    out = net(x)
    loss = build_loss("pose")(out.keypoints, gt, 0, present)
    loss = loss + nn.functional.binary_cross_entropy_with_logits(out.presence_logit, present.float())
    loss.backward()
    dead = [name for name, p in net.named_parameters() if p.grad is None or not torch.any(p.grad != 0)]
    assert not dead, f"no gradient at initialisation: {dead}"


def test_written_out_encoder_layer_equals_pytorchs():
    torch.manual_seed(0)
    layer = nn.TransformerEncoderLayer(32, 4, 64, dropout=0.0, batch_first=True)
    x = torch.randn(3, 16, 32) * 2
    assert torch.allclose(_encoder_layer_forward(layer, x), layer(x), atol=1e-5)
    layer.eval()
    with torch.no_grad():
        assert torch.allclose(_encoder_layer_forward(layer, x), layer(x), atol=1e-5)


def test_sine_positional_encoding_is_distinct_per_token():
    pe = sine_positional_encoding_2d(4, 32)
    assert pe.shape == (16, 32)
    assert torch.cdist(pe, pe).add(torch.eye(16) * 1e3).min() > 0.1


def test_config_round_trip_and_presets():
    for config in (DroneKeyConfig.paper(), DroneKeyConfig.edge(), TINY):
        assert DroneKeyConfig.from_dict(config.to_dict()) == config
    paper = DroneKeyConfig.paper()
    assert (
        paper.backbone,
        paper.d_model,
        paper.num_layers,
        paper.num_heads,
        paper.ff_dim,
        paper.input_size,
    ) == (
        "resnet50",
        1024,
        6,
        8,
        2048,
        224,
    )


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"backbone": "vgg"}, "backbone"),
        ({"input_size": 100}, "input_size"),
        ({"d_model": 30}, "d_model"),
        ({"token_stride": 8}, "token_stride"),
        ({"backbone": "resnet50", "token_stride": 16}, "token_stride"),
        ({"dropout": 1.5}, "dropout"),
        ({"pe_scale": 0.0}, "pe_scale"),
    ],
)
def test_bad_config_errors_name_the_field(changes, message):
    with pytest.raises(ValueError, match=message):
        DroneKeyConfig(**{**TINY.to_dict(), **changes})


def test_unknown_config_key_is_an_error():
    with pytest.raises(ValueError, match="unknown DroneKeyConfig keys"):
        DroneKeyConfig.from_dict({**TINY.to_dict(), "depth": 3})


def test_wrong_input_size_is_an_error():
    with pytest.raises(ValueError, match="x must have shape"):
        DroneKeyNet(TINY)(torch.zeros(1, 3, 32, 32))
