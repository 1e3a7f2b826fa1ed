"""The network as ``hd detect`` runs it on a CPU: the same weights and the same MC-dropout draws,
laid out for speed (``DetectSettings.layout``).

``inference_model(model, "channels-last")`` returns a copy of a Bayesian SegNet whose weights and
activations are stored channels-last (NHWC), the layout oneDNN's CPU convolutions are fastest in
(benchmarks/bench_detect_area.py). MC-dropout masks are hd's own in every layout
(``hdnet.dropout_masks.sample_keep``: 16-bit PCG64 draws seeded from PyTorch's generator, drawn in
the logical NCHW order and applied to the features in their own layout), so for a seed the
channels-last network draws the NCHW network's samples bit for bit, and the maps differ only by the
convolutions' round-off (float32; pinned within 1e-3 by tests/hdnet/test_engine.py).

``"channels-last-per-tile"`` also runs each tile's M samples through the network alone
(``predict_tile_by_tile``) with its rows of the masks drawn for the whole batch: the same draws
again, M maps per pass instead of M * N. ``"nchw"`` is the model itself: the reference path.
"""

from __future__ import annotations

import copy

import torch
from torch import nn

from hdnet.detect_settings import LAYOUTS
from hdnet.dropout_masks import sample_dropout, sample_keep
from hdnet.errors import HdNetError
from hdnet.infer import MCPrediction, mc_dropout_mode, mc_dropout_predict, predictive_entropy
from hdnet.model import MCDropout, PrefixState


class NCHWDrawDropout(MCDropout):
    """An ``MCDropout`` that ``predict_tile_by_tile`` can drive: its masks, drawn or given, are in
    the logical NCHW order whatever the input's memory layout (``hdnet.dropout_masks.sample_keep``).

    Two more ways besides ``MCDropout``'s: ``shapes`` (a list) records the module and its input's
    shape, in the order they are applied, without drawing or dropping; ``mask`` (a boolean keep mask
    of the input's shape, any strides) is applied instead of a fresh draw while sampling."""

    def __init__(self, p: float) -> None:
        super().__init__(p)
        self.shapes: list[tuple[NCHWDrawDropout, torch.Size]] | None = None
        self.mask: torch.Tensor | None = None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``x`` times the mask times ``keep_scale(p)`` while sampling; ``x`` itself in inference mode."""
        if self.shapes is not None:
            self.shapes.append((self, x.shape))
            return x
        if self.mask is not None and self.training:
            return sample_dropout(x, self.p, self.mask)
        return super().forward(x)

    def draw(self, shape: torch.Size | tuple[int, ...], device: torch.device | None = None) -> torch.Tensor:
        """The keep mask (boolean, contiguous) MC sampling draws for features of ``shape``."""
        return sample_keep(shape, self.p, device)


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
    itself; ``"channels-last"`` (and ``"channels-last-per-tile"``) a channels-last copy whose dropouts
    ``predict_tile_by_tile`` can drive; the same draws in every layout (module docstring).

    Raises:
        HdNetError: an unknown layout.
    """
    if layout == "nchw":
        return model
    if layout not in LAYOUTS:
        raise HdNetError(f"unknown network layout {layout!r}: one of {', '.join(LAYOUTS)}.")
    net = copy.deepcopy(model)
    _swap_dropouts(net)
    return net.to(memory_format=torch.channels_last)  # type: ignore[call-overload]  # the stubs omit memory_format


def laid_out(x: torch.Tensor, layout: str) -> torch.Tensor:
    """The network input ``x`` (N, C, H, W) in ``layout``'s memory format (values unchanged)."""
    return x if layout == "nchw" else x.contiguous(memory_format=torch.channels_last)


def predict(model: nn.Module, x: torch.Tensor, n_samples: int, layout: str) -> MCPrediction:
    """MC dropout of ``x`` (N, in_channels, H, W) with ``inference_model(..., layout)``'s ``model``:
    ``predict_tile_by_tile`` for ``channels-last-per-tile``, else ``hdnet.infer.mc_dropout_predict``."""
    x = laid_out(x, layout)
    if layout == "channels-last-per-tile":
        return predict_tile_by_tile(model, x, n_samples)
    return mc_dropout_predict(model, x, n_samples=n_samples)


def _dropouts(net: nn.Module) -> list[NCHWDrawDropout]:
    drops = [m for m in net.modules() if isinstance(m, NCHWDrawDropout)]
    if not drops:
        raise HdNetError("tile-by-tile MC dropout needs a model made by inference_model(model, 'channels-last').")
    return drops


def _tiles(state: PrefixState, lo: int, hi: int) -> PrefixState:
    return PrefixState(state.features[lo:hi], tuple(i[lo:hi] for i in state.indices), state.sizes, state.input_hw)


@torch.no_grad()
def predict_tile_by_tile(model: nn.Module, x: torch.Tensor, n_samples: int) -> MCPrediction:
    """``hdnet.infer.mc_dropout_predict(model, x, n_samples)``'s samples, computed one input at a time.

    The batch's masks are drawn first, layer by layer in the order the suffix applies them and with
    the shapes of the whole sample-major batch (M * N, C, H, W): the draws ``mc_dropout_predict``
    makes, so the same samples. Then each input's M samples go through the suffix alone, with its
    rows of the masks: M maps per pass instead of M * N, the batch shape "Detection" in
    docs/benchmarks.md found cheaper per frame at width 1/2 (at width 3/4 it measured slower:
    "Detection at area scale"). ``model``: from
    ``inference_model(model, "channels-last")``; ``x``: (N, in_channels, H, W).
    """
    with mc_dropout_mode(model) as net:
        drops = _dropouts(net)
        state = net.prefix(x)
        n = x.shape[0]
        recorded: list[tuple[NCHWDrawDropout, torch.Size]] = []
        try:
            for drop in drops:
                drop.shapes = recorded
            net.suffix(_tiles(state, 0, 1))  # the dropouts' input shapes, nothing drawn
        finally:
            for drop in drops:
                drop.shapes = None
        applied = [drop for drop, _ in recorded]
        masks = [drop.draw((n_samples * n, *shape[1:]), x.device) for drop, shape in recorded]
        parts = []
        try:
            for k in range(n):
                for drop, mask in zip(applied, masks, strict=True):
                    drop.mask = mask.view(n_samples, n, *mask.shape[1:])[:, k]
                probs = torch.softmax(net.suffix(_tiles(state, k, k + 1).repeat(n_samples)), dim=1)
                parts.append((probs.sum(dim=0), predictive_entropy(probs.float(), dim=1).sum(dim=0)))
        finally:
            for drop in drops:
                drop.mask = None
        mean_probs = torch.stack([p for p, _ in parts]) / n_samples
        entropy = torch.stack([e for _, e in parts]) / n_samples
        return MCPrediction(mean_probs, mean_probs.argmax(dim=1), predictive_entropy(mean_probs), entropy)
