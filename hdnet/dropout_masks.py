"""Dropout masks drawn fast and the same on every machine: 16-bit integers from NumPy's PCG64,
seeded from PyTorch.

``torch.nn.functional.dropout`` draws its keep mask with ``torch.bernoulli``: on a CPU one
Mersenne-Twister double per element in one thread, and PyTorch's Bernoulli kernel has a path
through MKL's generator for Intel CPUs (it checks the CPU's vendor), so its masks are PyTorch's
implementation's choice, machine by machine and version by version. Here the
mask is one 16-bit integer per element from NumPy's PCG64 (``uint16_draws``: the generator's raw
64-bit outputs cut into four), keep where the integer is at least ``round(p * 65536)``. The drop
probability is therefore ``p`` rounded to a multiple of 1/65536 (0.2 → 13107/65536 = 0.19999695;
0.5 exactly), and the kept elements are scaled by ``65536 / (65536 - round(p * 65536))`` so that
the expectation is exactly the input's, as inverted dropout's ``1 / (1 - p)`` makes it for the
exact ``p``.

Each draw takes its PCG64 seed from PyTorch's default generator (one 63-bit integer, from its
Mersenne Twister: the same on every CPU), so a seeded run draws the same masks every time and
everywhere, and a resumed run continues them from the checkpointed PyTorch RNG state. Two uses:

* training, when the profile chooses it (``TrainingProfile.fast_dropout``): ``fast_dropout``, the
  mask laid out in the features' memory order (``keep_mask``);
* MC-dropout inference, always (``hdnet.infer.mc_dropout_mode``): ``sample_dropout``, the mask
  drawn in the logical (N, C, H, W) order whatever the features' memory layout (``sample_keep``),
  so channels-last and NCHW networks, and ``hdnet.engine``'s paths, draw the same samples.
"""

from __future__ import annotations

import math

import numpy as np
import torch

MASK_LEVELS = 65536  # the integers' range: 16 bits per element
_WORDS_PER_DRAW = 4  # 16-bit integers in one 64-bit output of PCG64


def drop_threshold(p: float) -> int:
    """Integers below this (of 0..65535) are dropped: ``round(p * 65536)``, for drop probability ``p``."""
    return int(round(p * MASK_LEVELS))


def keep_scale(p: float) -> float:
    """The factor that scales kept elements, ``65536 / (65536 - threshold)``: E[output] = input."""
    return MASK_LEVELS / (MASK_LEVELS - drop_threshold(p))


def uint16_draws(n: int) -> np.ndarray:
    """``n`` integers uniform on 0..65535 (uint16) from a PCG64 generator seeded from PyTorch's
    default generator (one 63-bit seed per call).

    Bit for bit ``Generator(PCG64(seed)).integers(0, 65536, n, dtype=np.uint16)`` (whose 16-bit
    draws are each 64-bit output's four words, lowest first), taken as the raw outputs' words in
    one vectorised step: about twice as fast, and the same masks as before for training."""
    seed = int(torch.randint(0, 2**63 - 1, (1,), dtype=torch.int64))
    raw = np.random.PCG64(seed).random_raw(-(-n // _WORDS_PER_DRAW))
    words: np.ndarray = raw.astype("<u8", copy=False).view("<u2")
    return words[:n]


def keep_mask(x: torch.Tensor, p: float) -> torch.Tensor:
    """A boolean keep mask of ``x``'s shape and memory layout (channels-last or contiguous), each
    element kept with probability ``1 - threshold / 65536`` (training's draws, in memory order).
    ``x`` must be on the CPU."""
    keep = torch.from_numpy(uint16_draws(x.numel()) >= drop_threshold(p))
    if x.dim() == 4 and not x.is_contiguous() and x.is_contiguous(memory_format=torch.channels_last):
        n, c, h, w = x.shape
        return keep.view(n, h, w, c).permute(0, 3, 1, 2)  # the mask's layout follows the features'
    return keep.view(x.shape)


def fast_dropout(x: torch.Tensor, p: float) -> torch.Tensor:
    """Inverted dropout of ``x`` (training) with the masks of ``keep_mask``; differentiable in ``x``."""
    if p <= 0.0:
        return x
    if p >= 1.0:
        return x * 0.0
    return x * keep_mask(x, p) * keep_scale(p)


def sample_keep(shape: torch.Size | tuple[int, ...], p: float, device: torch.device | None = None) -> torch.Tensor:
    """MC-dropout inference's keep mask for features of logical shape ``shape``: a contiguous boolean
    tensor drawn in row-major order of ``shape`` (N, C, H, W), so the same for any memory layout and
    any device (drawn on the CPU, then moved to ``device``)."""
    keep = torch.from_numpy(uint16_draws(math.prod(shape)) >= drop_threshold(p)).view(shape)
    return keep if device is None or device.type == "cpu" else keep.to(device)


def sample_dropout(x: torch.Tensor, p: float, keep: torch.Tensor | None = None) -> torch.Tensor:
    """One MC-dropout sample of ``x``: ``x`` times ``keep`` (``sample_keep``'s mask, drawn now when
    ``None``; any strides) times ``keep_scale(p)``, in ``x``'s memory layout and dtype."""
    if p <= 0.0:
        return x
    if drop_threshold(p) >= MASK_LEVELS:
        return x * 0.0
    keep = sample_keep(x.shape, p, x.device) if keep is None else keep
    return x.mul(keep).mul_(keep_scale(p))
