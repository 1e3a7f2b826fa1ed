"""hdnet.dropout_masks: the keep rate, the scale, the layout, the seeding, and MCDropout's two paths."""

import math

import pytest
import torch

from hdnet.dropout_masks import drop_threshold, fast_dropout, keep_mask, keep_scale
from hdnet.model import MCDropout


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


@pytest.mark.parametrize("fast", [False, True])
def test_mcdropout_paths(fast: bool) -> None:
    x = torch.randn(2, 4, 6, 6)
    layer, reference = MCDropout(0.3), torch.nn.Dropout(0.3)
    layer.fast_masks = fast
    torch.manual_seed(4)
    out = layer(x)
    torch.manual_seed(4)
    assert torch.equal(out, fast_dropout(x, 0.3) if fast else reference(x))
    layer.eval()
    assert torch.equal(layer(x), x)
