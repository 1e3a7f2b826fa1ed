"""Dropout masks drawn fast on a CPU: 16-bit integers from NumPy's PCG64, seeded from PyTorch.

``torch.nn.functional.dropout`` draws its keep mask with ``torch.bernoulli``, one Mersenne-Twister
double per element in one thread: at the robust profile's width that is a quarter of a CPU
training step (docs/benchmarks.md, "Training throughput of the robust profile"). Here the mask is
one 16-bit integer per element from NumPy's PCG64 (``Generator.integers``, about four times
faster), keep where the integer is at least ``round(p * 65536)``. The drop probability is therefore
``p`` rounded to a multiple of 1/65536 (0.2 → 13107/65536 = 0.19999695), and the kept elements are
scaled by ``65536 / (65536 - round(p * 65536))`` so that the expectation is exactly the input's,
as inverted dropout's ``1 / (1 - p)`` makes it for the exact ``p``.

Each call draws the PCG64 seed from PyTorch's default generator (one 63-bit integer), so a seeded
run draws the same masks every time and a resumed run continues them from the checkpointed PyTorch
RNG state, as with ``torch.bernoulli``. The masks are not ``torch.bernoulli``'s: training with them
gives other (equally distributed) draws, which is why a profile chooses them
(``TrainingProfile.fast_dropout``) and MC-dropout inference never uses them.
"""

from __future__ import annotations

import numpy as np
import torch

MASK_LEVELS = 65536  # the integers' range: 16 bits per element


def drop_threshold(p: float) -> int:
    """Integers below this (of 0..65535) are dropped: ``round(p * 65536)``, for drop probability ``p``."""
    return int(round(p * MASK_LEVELS))


def keep_scale(p: float) -> float:
    """The factor that scales kept elements, ``65536 / (65536 - threshold)``: E[output] = input."""
    return MASK_LEVELS / (MASK_LEVELS - drop_threshold(p))


def keep_mask(x: torch.Tensor, p: float) -> torch.Tensor:
    """A boolean keep mask of ``x``'s shape and memory layout (channels-last or contiguous), each
    element kept with probability ``1 - threshold / 65536``, drawn from a PCG64 generator seeded
    from PyTorch's default generator. ``x`` must be on the CPU."""
    seed = int(torch.randint(0, 2**63 - 1, (1,), dtype=torch.int64))
    draws = np.random.Generator(np.random.PCG64(seed)).integers(0, MASK_LEVELS, x.numel(), dtype=np.uint16)
    keep = torch.from_numpy(draws >= drop_threshold(p))
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
