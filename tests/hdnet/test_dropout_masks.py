"""hdnet.dropout_masks: the keep rate, the scale, the layout, the seeding, the pinned draws of MC-dropout
inference, and MCDropout's three paths."""

import hashlib
import math

import numpy as np
import pytest
import torch

from hdnet.dropout_masks import (
    drop_threshold,
    fast_dropout,
    keep_mask,
    keep_scale,
    sample_dropout,
    sample_keep,
    uint16_draws,
)
from hdnet.infer import mc_dropout_mode
from hdnet.model import BayesianSegNet, MCDropout


def test_threshold_and_scale_by_hand() -> None:
    assert drop_threshold(0.2) == 13107 and drop_threshold(0.5) == 32768 and drop_threshold(0.0) == 0
    assert keep_scale(0.2) == 65536 / 52429  # 1.2499952, not 1.25: p is 13107/65536
    assert keep_scale(0.5) == 2.0


def test_keep_rate_within_its_binomial_interval() -> None:
    torch.manual_seed(0)
    x = torch.zeros(4, 16, 64, 64)
    n = x.numel()
    kept = int(keep_mask(x, 0.2).sum())
    q = 1 - 13107 / 65536
    assert abs(kept - n * q) < 5 * math.sqrt(n * q * (1 - q))  # 5 sigma


def test_masks_follow_pytorchs_seed_and_layout() -> None:
    x = torch.randn(2, 3, 5, 7)
    torch.manual_seed(1)
    a = keep_mask(x, 0.5)
    b = keep_mask(x, 0.5)
    torch.manual_seed(1)
    assert torch.equal(keep_mask(x, 0.5), a) and not torch.equal(a, b)
    cl = x.contiguous(memory_format=torch.channels_last)
    torch.manual_seed(1)
    m = keep_mask(cl, 0.5)
    assert m.shape == x.shape and m.is_contiguous(memory_format=torch.channels_last)
    # The draws are laid out in memory order: the channels-last mask is the contiguous draws of (N, H, W, C).
    torch.manual_seed(1)
    flat = keep_mask(torch.empty(2, 5, 7, 3), 0.5)
    assert torch.equal(m, flat.permute(0, 3, 1, 2))


def test_fast_dropout_values_and_gradient() -> None:
    x = torch.full((1, 2, 8, 8), 3.0, requires_grad=True)
    torch.manual_seed(2)
    y = fast_dropout(x, 0.2)
    torch.manual_seed(2)
    keep = keep_mask(x, 0.2)
    expected = torch.where(keep, torch.tensor(3.0 * keep_scale(0.2)), torch.tensor(0.0))
    assert torch.allclose(y, expected)
    y.sum().backward()
    assert x.grad is not None and torch.allclose(x.grad, keep.float() * keep_scale(0.2))
    assert fast_dropout(x, 0.0) is x and not fast_dropout(x, 1.0).any()


@pytest.mark.parametrize(("fast", "sampling"), [(False, False), (True, False), (False, True), (True, True)])
def test_mcdropout_paths(fast: bool, sampling: bool) -> None:
    """Training: nn.Dropout's masks or the fast ones, as the profile chose; MC sampling: hd's own,
    whatever the training chose."""
    x = torch.randn(2, 4, 6, 6)
    layer, reference = MCDropout(0.3), torch.nn.Dropout(0.3)
    layer.fast_masks, layer.sampling = fast, sampling
    torch.manual_seed(4)
    out = layer(x)
    torch.manual_seed(4)
    expected = sample_dropout(x, 0.3) if sampling else fast_dropout(x, 0.3) if fast else reference(x)
    assert torch.equal(out, expected)
    torch.manual_seed(4)
    assert torch.equal(out, reference(x)) == (not sampling and not fast)  # the paths draw other masks
    layer.eval()
    assert torch.equal(layer(x), x)


@pytest.mark.parametrize("n", [0, 1, 3, 4, 5, 1001])
def test_uint16_draws_are_numpys_integers_bit_for_bit(n: int) -> None:
    """The raw outputs' words are Generator.integers' 16-bit draws (training's masks unchanged),
    for any count, with the seed taken from PyTorch's generator."""
    torch.manual_seed(9)
    seed = int(torch.randint(0, 2**63 - 1, (1,), dtype=torch.int64))
    expected = np.random.Generator(np.random.PCG64(seed)).integers(0, 65536, n, dtype=np.uint16)
    torch.manual_seed(9)
    draws = uint16_draws(n)
    assert draws.dtype == np.uint16 and np.array_equal(draws, expected)


def test_inference_masks_are_pinned() -> None:
    """The masks MC-dropout inference draws for a seed, pinned: they depend on nothing but PyTorch's
    Mersenne Twister (the seed) and PCG64, so they are these bytes on every CPU, whatever its vendor,
    ISA, BLAS or thread count. A change of the draws, the threshold or the order fails here."""
    torch.manual_seed(0)
    assert uint16_draws(6).tolist() == [24263, 15864, 6734, 42788, 6223, 5823]
    torch.manual_seed(0)
    keep = sample_keep((2, 3, 8, 8), 0.2)
    assert keep.dtype == torch.bool and keep.is_contiguous()
    assert keep.flatten()[:6].tolist() == [True, True, False, True, False, False]  # the draws >= 13107
    digest = hashlib.sha256(np.packbits(keep.numpy()).tobytes()).hexdigest()
    assert digest == "a9f66e958ca78310fe718117ca9fc25213c8142b18bed25a0a3b87c385aede56"
    torch.manual_seed(0)
    half = sample_keep((2, 3, 8, 8), 0.5)
    assert half.flatten()[:6].tolist() == [False, False, False, True, False, False]  # the draws >= 32768
    digest = hashlib.sha256(np.packbits(half.numpy()).tobytes()).hexdigest()
    assert digest == "528975d456b8ac8d9325467d99f415f61d932e2c7d6a432045434610475de81b"


def test_sample_keep_rate_and_sample_dropout_values() -> None:
    torch.manual_seed(3)
    n = 4 * 16 * 64 * 64
    kept = int(sample_keep((4, 16, 64, 64), 0.2).sum())
    q = 1 - 13107 / 65536
    assert abs(kept - n * q) < 5 * math.sqrt(n * q * (1 - q))  # 5 sigma
    x = torch.full((2, 3, 4, 5), 3.0).contiguous(memory_format=torch.channels_last)
    torch.manual_seed(5)
    y = sample_dropout(x, 0.5)
    torch.manual_seed(5)
    keep = sample_keep(x.shape, 0.5)
    assert torch.equal(y, torch.where(keep, torch.tensor(6.0), torch.tensor(0.0)))  # p = 0.5: scale exactly 2
    assert y.is_contiguous(memory_format=torch.channels_last)
    assert sample_dropout(x, 0.0) is x and not sample_dropout(x, 1.0).any()


def test_mc_dropout_mode_switches_the_inference_masks_on_and_back() -> None:
    model = BayesianSegNet(width=1 / 16, depth=2)
    model.dropout_modules()[0].sampling = True  # a previous value is restored, not reset
    with mc_dropout_mode(model) as net:
        assert all(m.sampling and m.training for m in net.dropout_modules())
    assert [m.sampling for m in model.dropout_modules()] == [True] + [False] * (len(model.dropout_modules()) - 1)
