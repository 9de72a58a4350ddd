"""The DroneKey keypoint network (paper §III-A and §III-B, equations 1-6) plus a presence head.

Data flow for an image batch ``x`` of shape (B, 3, S, S), normalised RGB:

1. CNN backbone -> (B, C, S/32, S/32) (``dronekey.nn.backbones``), 1x1 convolution to ``d_model``.
2. Flatten to P = (S/32)^2 tokens, add a fixed 2D sine positional encoding (eq. before 1).
3. N post-norm ``nn.TransformerEncoderLayer`` (eq. 1); after each layer l:
   IR_l = mean of its P output tokens (eq. 2), CR_l = W IR_l + b (eq. 3, one W shared by all layers:
   the paper writes W without a layer index, and only this reading gives its 76.02 M parameters).
4. gate = softmax(W_g IR_N + b_g) (eq. 4); keypoints = ReLU(sum_l gate_l CR_l) (eqs. 5-6), reshaped
   to (B, K, 2) in normalised crop units (0 = the crop's left/top edge, 1 = its right/bottom edge;
   see ``dronekey.geometry.crop``).
5. Presence (ours, the paper has none): one logit from IR_N, so the daemon can tell an empty crop.

Dead-ReLU trap (docs/design.md §7): with a default init the gated sum can be negative for every
output, the final ReLU then passes no gradient and nothing trains. Here W starts small and b at 0.5,
so every prediction starts near the crop centre (> 0) and gradients reach every parameter at
initialisation (tested).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import torch
from torch import nn

from dronekey.nn.backbones import EdgeBackbone, ResNet50Trunk
from dronekey.perception.keypoint_order import HEADING_TWIN

__all__ = [
    "HEADING_TWIN",
    "DroneKeyConfig",
    "DroneKeyNet",
    "DroneKeyOutput",
    "count_parameters",
    "sine_positional_encoding_2d",
]

BACKBONES = ("resnet50", "edge")
ACTIVATIONS = ("relu", "gelu")
PRESENCE_INPUTS = ("last_ir", "tokens")
# Initial scale of the shared CR projection: the CR deviation from its 0.5 bias is at most about this
# (IR is a mean of LayerNorm outputs, so |IR| <= sqrt(d)); small enough that no output starts <= 0.
_CR_INIT_SCALE = 0.1


HEADING_HIDDEN = 128


@dataclass(frozen=True)
class DroneKeyConfig:
    """Architecture of a DroneKey network; stored in checkpoints and ONNX metadata.

    Parameters
    ----------
    backbone : {"resnet50", "edge"}
        CNN trunk: the paper's ResNet-50 or our depthwise-separable edge network.
    input_size : int
        Side of the square input in pixels; a multiple of the token stride.
    d_model : int
        Token dimension d (multiple of 4 for the 2D sine encoding, and of ``num_heads``).
    num_layers : int
        Transformer encoder layers N.
    num_heads : int
        Attention heads per layer.
    ff_dim : int
        Hidden size of each layer's feed-forward network.
    dropout : float
        Dropout inside the encoder layers (training only).
    activation : {"relu", "gelu"}
        Feed-forward activation (the paper / PyTorch default is ReLU).
    num_keypoints : int
        K; the propellers of a quadcopter, 4.
    token_stride : {32, 16}
        Backbone output stride. 32 is the paper's H/32 grid; 16 (edge backbone only) is a documented
        deviation that gives four times as many tokens.
    token_norm : bool
        LayerNorm the projected tokens before the positional encoding is added (not in the paper;
        see ``pe_scale``).
    pe_scale : float
        Amplitude of the sine encoding (the paper's PE has amplitude 1). Trained from scratch, the
        network has to learn where the propellers are from the encoding alone (the IR is a mean over
        tokens); when the projected tokens are much larger than the encoding, the position signal
        is drowned and training sits on the "predict the mean keypoints" plateau. Normalised tokens
        plus a stronger encoding escape it sooner (docs/model.md).
    presence_input : {"last_ir", "tokens"}
        What the presence head reads: the last layer's IR (the gate's input), or the mean of the
        projected CNN tokens before the encoding is added. The edge preset uses "tokens": with
        ``pe_scale`` 10 the deeper layers' IRs become nearly image-independent (in a trained edge
        network the last IR varied across crops by 2e-6 of its size), which leaves a head on them
        blind, while the token mean separates drone from empty crops (linear probe AUC 0.97).
    edge_widths : tuple of 5 ints
        Edge backbone channels: stem and four stages.
    edge_depths : tuple of 4 ints
        Edge backbone separable residual blocks per stage.
    heading_head : bool
        Add the front/back head (not in the paper). It regresses, from the normalised CNN token grid
        (where the nose, gimbal and battery are), the drone's nose direction in the crop: the unit
        vector from the rear propellers' midpoint to the front ones' (``DroneKeyOutput.nose``).
        Trained by squared error, it predicts the mean of that vector given the crop, which shrinks
        to zero when the front cannot be told; against the predicted keypoints' own front axis v,
        p = (1 + nose . v) / 2 is then the probability that the keypoints are in the spec's order
        and not its 180-degree twin (``HEADING_TWIN``), calibrated by construction for the
        squared-error optimum. ``heading_logit`` is logit(p). Trained with it, the keypoint losses
        take whichever of the two orders the prediction is closer to (plus a weaker pull towards
        the labelled one), so a crop whose front cannot be told does not pull the four keypoints
        onto their mean.
    """

    backbone: str = "edge"
    input_size: int = 128
    d_model: int = 192
    num_layers: int = 4
    num_heads: int = 4
    ff_dim: int = 384
    dropout: float = 0.0
    activation: str = "relu"
    num_keypoints: int = 4
    token_stride: int = 32
    token_norm: bool = False
    pe_scale: float = 1.0
    presence_input: str = "last_ir"
    edge_widths: tuple[int, ...] = field(default=(32, 64, 96, 160, 256))
    edge_depths: tuple[int, ...] = field(default=(1, 2, 2, 2))
    heading_head: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "edge_widths", tuple(int(w) for w in self.edge_widths))
        object.__setattr__(self, "edge_depths", tuple(int(d) for d in self.edge_depths))
        if self.backbone not in BACKBONES:
            raise ValueError(f"backbone must be one of {BACKBONES}, got {self.backbone!r}")
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {ACTIVATIONS}, got {self.activation!r}")
        if self.token_stride not in (16, 32):
            raise ValueError(f"token_stride must be 16 or 32, got {self.token_stride}")
        if self.backbone == "resnet50" and self.token_stride != 32:
            raise ValueError(f"token_stride must be 32 with the resnet50 backbone, got {self.token_stride}")
        if self.input_size < self.token_stride or self.input_size % self.token_stride:
            raise ValueError(
                f"input_size must be a positive multiple of token_stride={self.token_stride}, "
                f"got {self.input_size}"
            )
        for name in ("d_model", "num_layers", "num_heads", "ff_dim", "num_keypoints"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.d_model % 4 or self.d_model % self.num_heads:
            raise ValueError(
                f"d_model must be a multiple of 4 and of num_heads={self.num_heads}, got {self.d_model}"
            )
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout}")
        if self.presence_input not in PRESENCE_INPUTS:
            raise ValueError(f"presence_input must be one of {PRESENCE_INPUTS}, got {self.presence_input!r}")
        if not self.pe_scale > 0:
            raise ValueError(f"pe_scale must be > 0, got {self.pe_scale}")

    @property
    def grid_size(self) -> int:
        """Tokens per side of the token grid (S / stride)."""
        return self.input_size // self.token_stride

    @classmethod
    def paper(cls) -> DroneKeyConfig:
        """The paper's configuration (§V-A): ResNet-50, d = 1024, N = 6, 8 heads, feed-forward 2048,
        224 px input, dropout 0.1 (PyTorch's default, as the reference code)."""
        return cls(
            backbone="resnet50",
            input_size=224,
            d_model=1024,
            num_layers=6,
            num_heads=8,
            ff_dim=2048,
            dropout=0.1,
        )

    @classmethod
    def edge(cls) -> DroneKeyConfig:
        """Our 2-core CPU configuration: edge backbone, 128 px input (4 x 4 tokens), d = 192,
        N = 4, 4 heads, feed-forward 384; dropout 0 (trained on an endless stream of rendered crops);
        normalised tokens and a sine encoding of amplitude 10 (``token_norm``, ``pe_scale``), and a
        presence head on the projected tokens (``presence_input``). The dataclass defaults are the
        paper's choices, so older checkpoints load unchanged."""
        return cls(token_norm=True, pe_scale=10.0, presence_input="tokens", heading_head=True)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (tuples as lists)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> DroneKeyConfig:
        """Inverse of ``to_dict``; unknown keys are an error (they would be silently ignored)."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown DroneKeyConfig keys {unknown}; known: {sorted(known)}")
        return cls(**dict(data))


class DroneKeyOutput(NamedTuple):
    """What ``DroneKeyNet.forward`` returns.

    keypoints : (B, K, 2) in normalised crop units, x then y, keypoint order of the drone spec.
    presence_logit : (B,) logit of 'this crop holds a drone' (sigmoid gives the probability).
    gate : (B, N) softmax weights of the layers' compact representations (paper Fig. 8).
    heading_logit : (B,) logit of 'keypoints are in the spec's order, not the 180-degree twin', or
        None without ``DroneKeyConfig.heading_head``.
    nose : (B, 2) the regressed nose direction in the crop (x right, y down; length <= 1 about,
        shorter when the front is uncertain), or None without the head.
    """

    keypoints: torch.Tensor
    presence_logit: torch.Tensor
    gate: torch.Tensor
    heading_logit: torch.Tensor | None = None
    nose: torch.Tensor | None = None


def front_axis(keypoints: torch.Tensor) -> torch.Tensor:
    """Unit vector (B, 2) from the rear propellers' midpoint to the front ones' (order 1 FR, 2 RR,
    3 RL, 4 FL), in crop units; the 180-degree twin order gives its opposite."""
    v = 0.5 * (keypoints[:, 0] + keypoints[:, 3]) - 0.5 * (keypoints[:, 1] + keypoints[:, 2])
    return v / (v.norm(dim=1, keepdim=True) + 1e-6)


def sine_positional_encoding_2d(grid: int, d_model: int) -> torch.Tensor:
    """Fixed 2D sine encoding of a ``grid`` x ``grid`` token grid, (grid * grid, d_model), row-major.

    The first d/2 channels encode the row, the last d/2 the column, each as the Transformer's 1D
    encoding [sin(i w_k), cos(i w_k)] with w_k = 10000^(-4k/d). Parameter-free (so the paper
    configuration keeps its 76.02 M parameters), deterministic from the config (so it is not
    stored in checkpoints), and unlike the reference code's 1D index encoding it tells the
    encoder the 2D position of each token.
    """
    if d_model % 4:
        raise ValueError(f"d_model must be a multiple of 4, got {d_model}")
    quarter = d_model // 4
    omega = torch.exp(-math.log(10000.0) * torch.arange(quarter, dtype=torch.float64) / quarter)
    index = torch.arange(grid, dtype=torch.float64)[:, None] * omega[None, :]
    axis = torch.cat([torch.sin(index), torch.cos(index)], dim=1)  # (grid, d/2)
    rows = axis[:, None, :].expand(grid, grid, d_model // 2)
    cols = axis[None, :, :].expand(grid, grid, d_model // 2)
    return torch.cat([rows, cols], dim=2).reshape(grid * grid, d_model).float()


class DroneKeyNet(nn.Module):
    """DroneKey: CNN backbone, transformer encoder, gated multi-layer keypoint head, presence head.

    Parameters
    ----------
    config : DroneKeyConfig
        Architecture; ``DroneKeyConfig.paper()`` or ``DroneKeyConfig.edge()`` for the presets.
    """

    def __init__(self, config: DroneKeyConfig) -> None:
        super().__init__()
        if not isinstance(config, DroneKeyConfig):
            raise TypeError(f"config must be a DroneKeyConfig, got {type(config).__name__}")
        self.config = config
        d, n, k = config.d_model, config.num_layers, config.num_keypoints
        if config.backbone == "resnet50":
            self.backbone: nn.Module = ResNet50Trunk()
        else:
            self.backbone = EdgeBackbone(config.edge_widths, config.edge_depths, config.token_stride)
        self.projection = nn.Conv2d(self.backbone.out_channels, d, kernel_size=1)
        self.token_norm = nn.LayerNorm(d) if config.token_norm else nn.Identity()
        self.register_buffer(
            "positional_encoding",
            config.pe_scale * sine_positional_encoding_2d(config.grid_size, d),
            persistent=False,
        )
        # A ModuleList of N layers, not nn.TransformerEncoder: we need every layer's output, and the
        # reference's extra template layer (the paper's 84.41 M) would be dead weight.
        self.layers = nn.ModuleList(
            nn.TransformerEncoderLayer(
                d,
                config.num_heads,
                config.ff_dim,
                config.dropout,
                activation=config.activation,
                batch_first=True,
            )
            for _ in range(n)
        )
        self.compact = nn.Linear(d, 2 * k)  # eq. 3, shared by all layers
        self.gate = nn.Linear(d, n)  # eq. 4
        self.presence = nn.Linear(d, 1)
        if config.heading_head:
            # GELU, not ReLU: on a target that is noise early in training, ReLU units all died
            # (a constant output) within eight epochs of the first run.
            self.heading = nn.Sequential(
                nn.Linear(config.grid_size**2 * d, HEADING_HIDDEN), nn.GELU(), nn.Linear(HEADING_HIDDEN, 2)
            )
        self._init_heads()

    def _init_heads(self) -> None:
        d = self.config.d_model
        nn.init.normal_(self.compact.weight, std=_CR_INIT_SCALE / math.sqrt(d))
        nn.init.constant_(self.compact.bias, 0.5)  # predictions start at the crop centre, ReLU alive
        nn.init.normal_(self.gate.weight, std=_CR_INIT_SCALE / math.sqrt(d))  # near-uniform gate
        nn.init.zeros_(self.gate.bias)
        nn.init.zeros_(self.presence.bias)

    def project(self, x: torch.Tensor) -> torch.Tensor:
        """The CNN's tokens projected to d, before normalisation and encoding: (B, P, d)."""
        return self.projection(self.backbone(x)).flatten(2).transpose(1, 2)

    def forward(self, x: torch.Tensor) -> DroneKeyOutput:
        """Keypoints, presence logit and gate for a batch (B, 3, S, S) of normalised RGB crops."""
        s = self.config.input_size
        if x.dim() != 4 or tuple(x.shape[1:]) != (3, s, s):
            raise ValueError(f"x must have shape (B, 3, {s}, {s}), got {tuple(x.shape)}")
        projected = self.project(x)  # (B, P, d)
        tokens = self.token_norm(projected) + self.positional_encoding
        representations = []
        for layer in self.layers:
            tokens = _encoder_layer_forward(layer, tokens)
            representations.append(tokens.mean(dim=1))  # IR_l, eq. 2
        ir = torch.stack(representations, dim=1)  # (B, N, d)
        compact = self.compact(ir)  # CR_l, (B, N, 2K)
        last = representations[-1]
        gate = torch.softmax(self.gate(last), dim=-1)  # (B, N)
        gated_sum = (gate.unsqueeze(-1) * compact).sum(dim=1)  # X_G, (B, 2K)
        keypoints = torch.relu(gated_sum).reshape(-1, self.config.num_keypoints, 2)
        presence_features = projected.mean(dim=1) if self.config.presence_input == "tokens" else last
        presence_logit = self.presence(presence_features).squeeze(-1)
        heading_logit = nose = None
        if self.config.heading_head:
            grid = self.token_norm(projected).flatten(1)  # (B, P d): the token grid keeps where things are
            nose = self.heading(grid)
            axis = front_axis(keypoints.detach())  # the head judges the order, it does not move points
            p = (0.5 * (1.0 + (nose * axis).sum(dim=1))).clamp(1e-4, 1.0 - 1e-4)
            heading_logit = torch.log(p) - torch.log1p(-p)
        return DroneKeyOutput(keypoints, presence_logit, gate, heading_logit, nose)


def _encoder_layer_forward(layer: nn.TransformerEncoderLayer, x: torch.Tensor) -> torch.Tensor:
    """``layer(x)`` for a post-norm, batch-first ``nn.TransformerEncoderLayer`` without masks, written
    out so that the ONNX graph stays small.

    Same parameters, same maths and same dropout sites as PyTorch's implementation (tested to agree),
    but the exported graph has ~25 nodes per layer instead of ~70: at 16 tokens the encoder is
    bound by ONNX Runtime's per-node overhead, not by arithmetic.
    """
    attn = layer.self_attn
    d, heads = attn.embed_dim, attn.num_heads
    tokens, head_dim = x.shape[1], d // heads
    w, b = attn.in_proj_weight, attn.in_proj_bias

    def split_heads(t: torch.Tensor) -> torch.Tensor:  # (B, P, d) -> (B, heads, P, head_dim)
        return t.reshape(-1, tokens, heads, head_dim).transpose(1, 2)

    q = split_heads(nn.functional.linear(x, w[:d], b[:d]))
    k = split_heads(nn.functional.linear(x, w[d : 2 * d], b[d : 2 * d]))
    v = split_heads(nn.functional.linear(x, w[2 * d :], b[2 * d :]))
    weights = torch.softmax((q * head_dim**-0.5) @ k.transpose(2, 3), dim=-1)
    weights = nn.functional.dropout(weights, attn.dropout, layer.training)
    context = (weights @ v).transpose(1, 2).reshape(-1, tokens, d)
    x = layer.norm1(x + layer.dropout1(attn.out_proj(context)))
    feed_forward = layer.linear2(layer.dropout(layer.activation(layer.linear1(x))))
    return layer.norm2(x + layer.dropout2(feed_forward))


def count_parameters(module: nn.Module) -> int:
    """Number of trainable parameters (the figure of the paper's Tables III and IV)."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)
