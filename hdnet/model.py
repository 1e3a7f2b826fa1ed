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

``ModelConfig.depth`` < 5 keeps the first ``depth`` VGG16 blocks, their mirrored decoder units and
the central dropout on the deepest three levels (``drop_pool{k}``, ``drop_dec{k}`` for k from
``depth - 2`` to ``depth``; all levels when ``depth`` < 3). A shallower network sees less context
(pooling halves the grid ``depth`` times) and needs less padding (to a multiple of 2**depth).

Sizes not divisible by 2**depth (32 at depth 5): ``prefix`` pads the input on the bottom and right
with edge replication ("replicate") up to the next multiple, and ``suffix`` crops the logits back to the input size,
so any H, W >= 1 works and the output has the input's size. Replication keeps heights plausible at
the padded border; those pixels never reach the loss (they are cropped away).

The forward pass is split for MC dropout: ``prefix(x)`` is everything before the first dropout
(deterministic, computed once), ``suffix(state)`` the rest (stochastic when the dropout modules are
in training mode). ``forward(x) == suffix(prefix(x))``.
"""

from __future__ import annotations

import itertools
from dataclasses import asdict, dataclass
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from hdcore.bounds import Bound
from hdcore.setting import check, setting
from hdnet import defaults
from hdnet.dropout_masks import fast_dropout, sample_dropout
from hdnet.errors import HdNetError

MODEL_NAME = "bayesian_segnet"


@dataclass(frozen=True)
class ModelConfig:
    """Hyper-parameters that define the architecture (stored in every checkpoint). Each field's
    meaning and range is its metadata (``hdcore.setting``), from which the checks here are made.
    Checkpoints written before ``depth`` existed hold 5-block models and load with the default.
    """

    in_channels: int = setting(defaults.IN_CHANNELS, "Input channels", bound=Bound(1, integer=True), cli=False)
    n_classes: int = setting(defaults.N_CLASSES, "Output classes", bound=Bound(2, integer=True), cli=False)
    width: float = setting(
        1.0, "Scale of every channel count (rounded, at least 1)", bound=Bound(0.0, low_open=True), cli=False
    )
    dropout_p: float = setting(
        defaults.DROPOUT_P,
        "Drop probability of the MC-dropout layers",
        bound=Bound(0.0, 1.0, high_open=True),
        cli=False,
    )
    depth: int = setting(
        len(defaults.ENCODER_CHANNELS),
        "Encoder blocks, each ending in a 2x2 max-pool (5 = the paper's VGG16 SegNet; fewer keeps VGG16's "
        "first blocks and their mirrored decoder units)",
        bound=Bound(1, len(defaults.ENCODER_CHANNELS), integer=True),
        cli=False,
    )

    def __post_init__(self) -> None:
        check(self, HdNetError)

    @property
    def size_multiple(self) -> int:
        """Inputs are padded to a multiple of 2**depth pixels (one halving per pooling stage)."""
        return 2**self.depth

    def to_dict(self) -> dict[str, float | int]:
        """Plain-type dictionary (for checkpoints and config.json)."""
        return asdict(self)


class MCDropout(nn.Dropout):
    """Element-wise dropout that MC-dropout inference switches on alone (BatchNorm stays in eval).

    Two attributes, not parameters (a loaded model has both off):

    * ``sampling`` (set by ``hdnet.infer.mc_dropout_mode`` while it samples): the masks are
      ``hdnet.dropout_masks.sample_dropout``'s, hd's own 16-bit PCG64 draws seeded from PyTorch's
      generator, in the logical (N, C, H, W) order: the same samples on every CPU (whatever its
      vendor or BLAS), in every memory layout and on every device. MC-dropout inference therefore
      draws the same masks whatever the run was trained with;
    * ``fast_masks`` (off unless training turns it on, ``TrainingProfile.fast_dropout``): in training
      mode on a CPU, the masks come from ``hdnet.dropout_masks.fast_dropout`` (the same generator,
      four times faster than ``torch.bernoulli``) instead of ``nn.Dropout``'s.
    """

    def __init__(self, p: float = 0.5) -> None:
        super().__init__(p)
        self.fast_masks = False
        self.sampling = False

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Dropout of ``x`` in training mode: MC sampling's masks, the fast masks (training on a CPU)
        or ``nn.Dropout``'s; ``x`` itself in inference mode."""
        if not self.training:
            return x
        if self.sampling:
            return sample_dropout(x, self.p)
        if self.fast_masks and x.device.type == "cpu":
            return fast_dropout(x, self.p)
        return super().forward(x)


class PrefixState(NamedTuple):
    """Output of ``BayesianSegNet.prefix``: what the stochastic suffix needs.

    ``features``: output of the last pool before the first dropout (pool3, (N, C, H/8, W/8), at
    depth 5); ``indices``/``sizes``: pooling indices and pre-pool sizes of those pools (for
    unpooling); ``input_hw``: the unpadded input size (pixels).
    """

    features: torch.Tensor
    indices: tuple[torch.Tensor, ...]
    sizes: tuple[torch.Size, ...]
    input_hw: tuple[int, int]

    def repeat(self, times: int) -> PrefixState:
        """The same state tiled ``times`` along the batch: sample-major, (times*N, ...)."""
        rep = lambda t: t.repeat(times, *([1] * (t.dim() - 1)))  # noqa: E731
        return PrefixState(rep(self.features), tuple(rep(i) for i in self.indices), self.sizes, self.input_hw)


def _scaled(channels: int, width: float) -> int:
    return max(1, int(round(channels * width)))


def _cbr(c_in: int, c_out: int) -> list[nn.Module]:
    return [nn.Conv2d(c_in, c_out, kernel_size=3, padding=1), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True)]


def _block(channels: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for c_in, c_out in itertools.pairwise(channels):
        layers += _cbr(c_in, c_out)
    return nn.Sequential(*layers)


class BayesianSegNet(nn.Module):
    """Bayesian SegNet; input (N, in_channels, H, W) float, output logits (N, n_classes, H, W)."""

    def __init__(self, config: ModelConfig | None = None, **kwargs: float) -> None:
        super().__init__()
        self.config = config if config is not None else ModelConfig(**kwargs)  # type: ignore[arg-type]  # checked by ModelConfig
        cfg = self.config
        enc = [[_scaled(c, cfg.width) for c in block] for block in defaults.ENCODER_CHANNELS[: cfg.depth]]
        # Encoder: block k maps (previous block's last width) -> its channels.
        c_prev = cfg.in_channels
        for k, block in enumerate(enc, start=1):
            setattr(self, f"enc{k}", _block([c_prev, *block]))
            c_prev = block[-1]
        # Decoder k mirrors encoder k: same widths, the last layer going to the previous block's width.
        # Unit 1 has one conv-BN-ReLU (64 -> 64); its second layer is the classifier conv (64 -> classes).
        self.dec1 = _block(list(reversed(enc[0])))
        for k in range(1, cfg.depth):
            setattr(self, f"dec{k + 1}", _block([*reversed(enc[k]), enc[k - 1][-1]]))
        self.classifier = nn.Conv2d(enc[0][0], cfg.n_classes, kernel_size=3, padding=1)
        self.pool = nn.MaxPool2d(2, 2, return_indices=True)
        self.unpool = nn.MaxUnpool2d(2, 2)
        # Central dropout: after the deepest pools and at the end of the deepest decoder units.
        self.first_dropout_level = cfg.depth - min(defaults.DROPOUT_UNITS, cfg.depth) + 1
        for k in range(self.first_dropout_level, cfg.depth + 1):
            setattr(self, f"drop_pool{k}", MCDropout(cfg.dropout_p))
        for k in range(cfg.depth, self.first_dropout_level - 1, -1):
            setattr(self, f"drop_dec{k}", MCDropout(cfg.dropout_p))

    @property
    def size_multiple(self) -> int:
        """Input sizes are padded internally to a multiple of this (2**depth pixels)."""
        return self.config.size_multiple

    def dropout_modules(self) -> list[MCDropout]:
        """The MC-dropout modules, in forward order."""
        return [m for m in self.modules() if isinstance(m, MCDropout)]

    def _level(self, kind: str, k: int) -> nn.Module:
        return getattr(self, f"{kind}{k}")

    def prefix(self, x: torch.Tensor) -> PrefixState:
        """Deterministic part: pad to a multiple of 2**depth, the encoder blocks up to the first dropout
        (blocks 1-3 and pool3 at depth 5)."""
        if x.dim() != 4 or x.shape[1] != self.config.in_channels:
            raise HdNetError(f"input must have shape (N, {self.config.in_channels}, H, W), got {tuple(x.shape)}.")
        h, w = int(x.shape[-2]), int(x.shape[-1])
        m = self.size_multiple
        pad_h, pad_w = (-h) % m, (-w) % m
        if pad_h or pad_w:
            x = F.pad(x, (0, pad_w, 0, pad_h), mode="replicate")
        indices, sizes = [], []
        for k in range(1, self.first_dropout_level + 1):
            x = self._level("enc", k)(x)
            sizes.append(x.shape)
            x, idx = self.pool(x)
            indices.append(idx)
        return PrefixState(x, tuple(indices), tuple(sizes), (h, w))

    def suffix(self, state: PrefixState) -> torch.Tensor:
        """Stochastic part: the dropout after the prefix's last pool, the remaining encoder blocks, the
        decoder and the classifier; crops back to the input size."""
        indices, sizes = list(state.indices), list(state.sizes)
        first, depth = self.first_dropout_level, self.config.depth
        x = self._level("drop_pool", first)(state.features)
        for k in range(first + 1, depth + 1):
            x = self._level("enc", k)(x)
            sizes.append(x.shape)
            x, idx = self.pool(x)
            indices.append(idx)
            x = self._level("drop_pool", k)(x)
        for k in range(depth, 0, -1):
            x = self._level("dec", k)(self.unpool(x, indices[k - 1], output_size=sizes[k - 1][-2:]))
            if k >= first:
                x = self._level("drop_dec", k)(x)
        x = self.classifier(x)
        h, w = state.input_hw
        return x[..., :h, :w]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits (N, n_classes, H, W) for input (N, in_channels, H, W)."""
        return self.suffix(self.prefix(x))


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
