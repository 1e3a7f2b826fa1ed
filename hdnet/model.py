"""Bayesian SegNet (Kendall et al. 2015) for two-class (unsafe / safe) segmentation of DEMs.

Layout at width 1.0 (29,443,010 parameters with 1 input channel and 2 classes):

* encoder: five VGG16 blocks of conv3x3-BN-ReLU layers (64,64 | 128,128 | 256x3 | 512x3 | 512x3),
  each followed by a 2x2 max-pool that returns its indices;
* decoder: the mirror image, each block starting with ``MaxUnpool2d`` by the matching indices;
  every decoder layer is conv3x3-BN-ReLU and the last decoder layer keeps 64 channels
  (unit 1 = 64->64), followed by a separate conv3x3 classifier 64 -> ``n_classes`` with bias and
  no BN/ReLU (the logits);
* element-wise dropout (p = 0.5) after pool3, pool4, pool5 and at the end of decoder units 5, 4, 3
  (the "central" Bayesian SegNet placement), as ``MCDropout`` modules named ``drop_pool3``,
  ``drop_pool4``, ``drop_pool5``, ``drop_dec5``, ``drop_dec4``, ``drop_dec3``.

Sizes not divisible by 32: ``prefix`` pads the input on the bottom and right with edge replication
("replicate") up to the next multiple of 32, and ``suffix`` crops the logits back to the input size,
so any H, W >= 1 works and the output has the input's size. Replication keeps heights plausible at
the padded border; those pixels never reach the loss (they are cropped away).

The forward pass is split for MC dropout: ``prefix(x)`` is everything before the first dropout
(deterministic, computed once), ``suffix(state)`` the rest (stochastic when the dropout modules are
in training mode). ``forward(x) == suffix(prefix(x))``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from hdnet import defaults
from hdnet.errors import HdNetError

MODEL_NAME = "bayesian_segnet"


@dataclass(frozen=True)
class ModelConfig:
    """Hyper-parameters that define the architecture (stored in every checkpoint).

    ``width`` scales every channel count (rounded, at least 1); ``dropout_p`` is the drop probability.
    """

    in_channels: int = defaults.IN_CHANNELS
    n_classes: int = defaults.N_CLASSES
    width: float = 1.0
    dropout_p: float = defaults.DROPOUT_P

    def __post_init__(self) -> None:
        if self.in_channels < 1 or self.n_classes < 2:
            raise HdNetError(f"in_channels must be >= 1 and n_classes >= 2, got {self.in_channels} and {self.n_classes}.")
        if not self.width > 0:
            raise HdNetError(f"width must be > 0, got {self.width}.")
        if not 0.0 <= self.dropout_p < 1.0:
            raise HdNetError(f"dropout_p must be in [0, 1), got {self.dropout_p}.")

    def to_dict(self) -> dict[str, float | int]:
        """Plain-type dictionary (for checkpoints and config.json)."""
        return asdict(self)


class MCDropout(nn.Dropout):
    """Element-wise dropout that MC-dropout inference switches on alone (BatchNorm stays in eval)."""


class PrefixState(NamedTuple):
    """Output of ``BayesianSegNet.prefix``: what the stochastic suffix needs.

    ``features``: pool3 output (N, C, H/8, W/8); ``indices``/``sizes``: pooling indices and pre-pool
    sizes of pools 1-3 (for unpooling); ``input_hw``: the unpadded input size (pixels).
    """

    features: torch.Tensor
    indices: tuple[torch.Tensor, torch.Tensor, torch.Tensor]
    sizes: tuple[torch.Size, torch.Size, torch.Size]
    input_hw: tuple[int, int]

    def repeat(self, times: int) -> PrefixState:
        """The same state tiled ``times`` along the batch: sample-major, (times*N, ...)."""
        rep = lambda t: t.repeat(times, *([1] * (t.dim() - 1)))  # noqa: E731
        return PrefixState(rep(self.features), tuple(rep(i) for i in self.indices), self.sizes, self.input_hw)  # type: ignore[arg-type]


def _scaled(channels: int, width: float) -> int:
    return max(1, int(round(channels * width)))


def _cbr(c_in: int, c_out: int) -> list[nn.Module]:
    return [nn.Conv2d(c_in, c_out, kernel_size=3, padding=1), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True)]


def _block(channels: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for c_in, c_out in zip(channels[:-1], channels[1:]):
        layers += _cbr(c_in, c_out)
    return nn.Sequential(*layers)


class BayesianSegNet(nn.Module):
    """Bayesian SegNet; input (N, in_channels, H, W) float, output logits (N, n_classes, H, W)."""

    def __init__(self, config: ModelConfig | None = None, **kwargs: float) -> None:
        super().__init__()
        self.config = config if config is not None else ModelConfig(**kwargs)  # type: ignore[arg-type]
        cfg = self.config
        enc = [[_scaled(c, cfg.width) for c in block] for block in defaults.ENCODER_CHANNELS]
        # Encoder: block k maps (previous block's last width) -> its channels.
        c_prev = cfg.in_channels
        encoders = []
        for block in enc:
            encoders.append(_block([c_prev, *block]))
            c_prev = block[-1]
        self.enc1, self.enc2, self.enc3, self.enc4, self.enc5 = encoders
        # Decoder k mirrors encoder k: same widths, the last layer going to the previous block's width.
        # Unit 1 has one conv-BN-ReLU (64 -> 64); its second layer is the classifier conv (64 -> classes).
        decoders = [_block(list(reversed(enc[0])))]
        decoders += [_block([*reversed(block), enc[k - 1][-1]]) for k, block in enumerate(enc) if k > 0]
        self.dec1, self.dec2, self.dec3, self.dec4, self.dec5 = decoders
        self.classifier = nn.Conv2d(enc[0][0], cfg.n_classes, kernel_size=3, padding=1)
        self.pool = nn.MaxPool2d(2, 2, return_indices=True)
        self.unpool = nn.MaxUnpool2d(2, 2)
        p = cfg.dropout_p
        self.drop_pool3, self.drop_pool4, self.drop_pool5 = MCDropout(p), MCDropout(p), MCDropout(p)
        self.drop_dec5, self.drop_dec4, self.drop_dec3 = MCDropout(p), MCDropout(p), MCDropout(p)

    def dropout_modules(self) -> list[MCDropout]:
        """The six MC-dropout modules, in forward order."""
        return [m for m in self.modules() if isinstance(m, MCDropout)]

    def prefix(self, x: torch.Tensor) -> PrefixState:
        """Deterministic part: pad to a multiple of 32, encoder blocks 1-3 and pool3 (before any dropout)."""
        if x.dim() != 4 or x.shape[1] != self.config.in_channels:
            raise HdNetError(f"input must have shape (N, {self.config.in_channels}, H, W), got {tuple(x.shape)}.")
        h, w = int(x.shape[-2]), int(x.shape[-1])
        m = defaults.SIZE_MULTIPLE_PX
        pad_h, pad_w = (-h) % m, (-w) % m
        if pad_h or pad_w:
            x = F.pad(x, (0, pad_w, 0, pad_h), mode="replicate")
        x = self.enc1(x)
        s1 = x.shape
        x, i1 = self.pool(x)
        x = self.enc2(x)
        s2 = x.shape
        x, i2 = self.pool(x)
        x = self.enc3(x)
        s3 = x.shape
        x, i3 = self.pool(x)
        return PrefixState(x, (i1, i2, i3), (s1, s2, s3), (h, w))

    def suffix(self, state: PrefixState) -> torch.Tensor:
        """Stochastic part: dropout after pool3, encoder 4-5, the decoder and the classifier; crops back."""
        (i1, i2, i3), (s1, s2, s3) = state.indices, state.sizes
        x = self.drop_pool3(state.features)
        x = self.enc4(x)
        s4 = x.shape
        x, i4 = self.pool(x)
        x = self.drop_pool4(x)
        x = self.enc5(x)
        s5 = x.shape
        x, i5 = self.pool(x)
        x = self.drop_pool5(x)
        x = self.drop_dec5(self.dec5(self.unpool(x, i5, output_size=s5[-2:])))
        x = self.drop_dec4(self.dec4(self.unpool(x, i4, output_size=s4[-2:])))
        x = self.drop_dec3(self.dec3(self.unpool(x, i3, output_size=s3[-2:])))
        x = self.dec2(self.unpool(x, i2, output_size=s2[-2:]))
        x = self.dec1(self.unpool(x, i1, output_size=s1[-2:]))
        x = self.classifier(x)
        h, w = state.input_hw
        return x[..., :h, :w]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits (N, n_classes, H, W) for input (N, in_channels, H, W)."""
        return self.suffix(self.prefix(x))


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
