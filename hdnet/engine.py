"""The network as ``hd detect`` runs it on a CPU: the same weights and the same MC-dropout draws,
laid out for speed (``DetectSettings.layout``).

``inference_model(model, "channels-last")`` returns a copy of a Bayesian SegNet whose weights and
activations are stored channels-last (NHWC), the layout oneDNN's CPU convolutions are fastest in
(benchmarks/bench_detect_area.py), with each MC-dropout module drawing its mask as PyTorch's own
dropout does for a contiguous (NCHW) tensor of the same shape: one ``bernoulli_(1 - p)`` over the
logical NCHW order, divided by ``1 - p``. ``torch.dropout`` on a channels-last tensor draws in memory
order instead, which would give other masks, so other samples and other maps; with the masks drawn
in NCHW order the samples are today's draws and the maps differ from the NCHW network's only by the
convolutions' round-off (float32: of order 1e-6 in P(safe) and entropy; pinned within 1e-3 by
tests/hdnet/test_engine.py). ``"nchw"`` returns the model itself: the reference path.
"""

from __future__ import annotations

import copy

import torch
from torch import nn

from hdnet.detect_settings import LAYOUTS
from hdnet.errors import HdNetError
from hdnet.model import MCDropout


class NCHWDrawDropout(MCDropout):
    """Element-wise dropout whose mask is drawn in the logical NCHW order whatever the input's memory
    layout: the same draws as ``torch.dropout`` on a contiguous tensor of the input's shape."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``x`` times the mask over ``1 - p`` while sampling; ``x`` itself in inference mode."""
        if not self.training or self.p == 0.0:
            return x
        keep = 1.0 - self.p
        noise = torch.empty(x.shape, dtype=x.dtype, device=x.device).bernoulli_(keep)
        noise.div_(keep)
        if x.is_contiguous(memory_format=torch.channels_last):
            noise = noise.contiguous(memory_format=torch.channels_last)  # the product stays channels-last
        return x * noise


def _swap_dropouts(module: nn.Module) -> None:
    for name, child in module.named_children():
        if isinstance(child, MCDropout):
            swapped = NCHWDrawDropout(child.p)
            swapped.train(child.training)
            setattr(module, name, swapped)
        else:
            _swap_dropouts(child)


def inference_model(model: nn.Module, layout: str) -> nn.Module:
    """``model`` laid out as ``layout`` (``LAYOUTS``) for MC-dropout inference: ``"nchw"`` the model
    itself; ``"channels-last"`` a channels-last copy with NCHW-order dropout draws (module docstring).

    Raises:
        HdNetError: an unknown layout.
    """
    if layout == "nchw":
        return model
    if layout != "channels-last":
        raise HdNetError(f"unknown network layout {layout!r}: one of {', '.join(LAYOUTS)}.")
    net = copy.deepcopy(model)
    _swap_dropouts(net)
    return net.to(memory_format=torch.channels_last)  # type: ignore[call-overload]  # the stubs omit memory_format


def laid_out(x: torch.Tensor, layout: str) -> torch.Tensor:
    """The network input ``x`` (N, C, H, W) in ``layout``'s memory format (values unchanged)."""
    return x.contiguous(memory_format=torch.channels_last) if layout == "channels-last" else x
