"""Bayesian SegNet: parameter count, layout, forward/backward, odd sizes, prefix/suffix split."""

import math
from typing import Any

import pytest
import torch

from hdnet import defaults
from hdnet.errors import HdNetError
from hdnet.model import BayesianSegNet, ModelConfig, count_parameters


def test_full_width_parameter_count() -> None:
    model = BayesianSegNet(ModelConfig(in_channels=1, n_classes=2, width=1.0))
    assert count_parameters(model) == 29_443_010 == defaults.PARAMETER_COUNT_FULL_WIDTH


def test_layout_13_encoder_layers_and_six_named_dropouts() -> None:
    model = BayesianSegNet(width=1 / 16)
    enc_convs = [m for n, m in model.named_modules() if n.startswith("enc") and isinstance(m, torch.nn.Conv2d)]
    dec_convs = [m for n, m in model.named_modules() if n.startswith("dec") and isinstance(m, torch.nn.Conv2d)]
    assert len(enc_convs) == 13 and len(dec_convs) == 12
    names = [n for n, m in model.named_modules() if m in model.dropout_modules()]
    assert names == ["drop_pool3", "drop_pool4", "drop_pool5", "drop_dec5", "drop_dec4", "drop_dec3"]
    assert all(type(m).__name__ == "MCDropout" and m.p == 0.5 for m in model.dropout_modules())


@pytest.mark.parametrize(("in_channels", "n_classes"), [(1, 2), (3, 5)])
def test_forward_backward_tiny(in_channels: int, n_classes: int) -> None:
    torch.manual_seed(0)
    model = BayesianSegNet(in_channels=in_channels, n_classes=n_classes, width=1 / 16)
    x = torch.randn(2, in_channels, 64, 64)
    logits = model(x)
    assert logits.shape == (2, n_classes, 64, 64)
    loss = torch.nn.functional.cross_entropy(logits, torch.randint(0, n_classes, (2, 64, 64)))
    loss.backward()
    assert math.isfinite(loss.item())
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in model.parameters())


@pytest.mark.parametrize("hw", [(100, 100), (33, 70), (7, 5)])
def test_sizes_not_divisible_by_32_are_padded_and_cropped(hw: tuple[int, int]) -> None:
    model = BayesianSegNet(width=1 / 16).eval()
    x = torch.randn(1, 1, *hw)
    assert model(x).shape == (1, 2, *hw)
    # Replicate padding on the bottom/right: the output equals running on the padded input, cropped.
    h, w = hw
    padded = torch.nn.functional.pad(x, (0, (-w) % 32, 0, (-h) % 32), mode="replicate")
    torch.testing.assert_close(model(x), model(padded)[..., :h, :w])


def test_forward_is_prefix_then_suffix() -> None:
    model = BayesianSegNet(width=1 / 16).eval()
    x = torch.randn(2, 1, 32, 32)
    torch.testing.assert_close(model(x), model.suffix(model.prefix(x)))


def test_bad_input_shape_and_config_raise() -> None:
    model = BayesianSegNet(width=1 / 16)
    with pytest.raises(HdNetError):
        model(torch.randn(1, 3, 32, 32))
    with pytest.raises(HdNetError):
        ModelConfig(width=0)
    with pytest.raises(HdNetError):
        ModelConfig(dropout_p=1.0)


def test_state_dict_round_trip(tmp_path) -> None:
    torch.manual_seed(0)
    model = BayesianSegNet(width=1 / 16).eval()
    torch.save(model.state_dict(), tmp_path / "w.pt")
    other = BayesianSegNet(width=1 / 16).eval()
    other.load_state_dict(torch.load(tmp_path / "w.pt", weights_only=True))
    x = torch.randn(1, 1, 32, 32)
    torch.testing.assert_close(model(x), other(x))


@pytest.mark.parametrize(("depth", "multiple"), [(3, 8), (4, 16), (1, 2)])
def test_shallower_networks_keep_the_first_blocks_and_central_dropout(depth: int, multiple: int) -> None:
    model = BayesianSegNet(ModelConfig(width=1 / 16, depth=depth)).eval()
    assert model.size_multiple == multiple
    enc_convs = [n for n, m in model.named_modules() if n.startswith("enc") and isinstance(m, torch.nn.Conv2d)]
    assert len(enc_convs) == sum(len(b) for b in defaults.ENCODER_CHANNELS[:depth])
    levels = range(max(1, depth - 2), depth + 1)
    names = [n for n, m in model.named_modules() if m in model.dropout_modules()]
    assert names == [f"drop_pool{k}" for k in levels] + [f"drop_dec{k}" for k in reversed(levels)]
    x = torch.randn(2, 1, 50, 37)
    assert model(x).shape == (2, 2, 50, 37)
    torch.testing.assert_close(model(x), model.suffix(model.prefix(x)))
    padded = torch.nn.functional.pad(x, (0, (-37) % multiple, 0, (-50) % multiple), mode="replicate")
    torch.testing.assert_close(model(x), model(padded)[..., :50, :37])
    with pytest.raises(HdNetError, match="depth"):
        ModelConfig(depth=6)


def test_configs_saved_before_depth_existed_load_five_blocks() -> None:
    old: dict[str, Any] = {"in_channels": 1, "n_classes": 2, "width": 1 / 16, "dropout_p": 0.5}
    config = ModelConfig(**old)
    assert config.depth == 5 and config == ModelConfig(width=1 / 16)
    torch.manual_seed(0)
    reference = BayesianSegNet(ModelConfig(width=1 / 16))
    loaded = BayesianSegNet(config)
    loaded.load_state_dict(reference.state_dict())  # the same parameter names as before
