"""MC-dropout inference (Kendall et al. 2015; paper Eq. 1-2): mean softmax, prediction, predictive entropy.

While sampling, every BatchNorm (and every other module) is in inference mode and only the
``MCDropout`` modules are in training mode; the previous modes are restored afterwards, so running
statistics are never touched. The M samples are batched: the deterministic prefix (everything before
the first dropout) is computed once, tiled M times along the batch (sample-major) and passed through
the stochastic suffix in one pass (or in chunks of ``samples_per_pass`` samples to bound memory).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass

import torch
from torch import nn

from hdnet import defaults
from hdnet.errors import HdNetError
from hdnet.model import BayesianSegNet, MCDropout


@dataclass(frozen=True)
class MCPrediction:
    """MC-dropout output for a batch of N inputs of H x W pixels.

    ``mean_probs``: mean softmax (N, n_classes, H, W); ``prediction``: argmax class (N, H, W) int64
    (1 = safe, 0 = unsafe); ``entropy_nats``: predictive entropy of the mean softmax (N, H, W), in nats
    (0 = certain, ln 2 = maximal for two classes).
    """

    mean_probs: torch.Tensor
    prediction: torch.Tensor
    entropy_nats: torch.Tensor


def _unwrap(model: nn.Module) -> BayesianSegNet:
    inner = getattr(model, "module", model)  # DistributedDataParallel / DataParallel wrappers
    if not isinstance(inner, BayesianSegNet):
        raise HdNetError(f"MC-dropout inference needs a BayesianSegNet, got {type(inner).__name__}.")
    return inner


@contextlib.contextmanager
def mc_dropout_mode(model: nn.Module) -> Iterator[BayesianSegNet]:
    """Context: whole model in eval mode, only the dropout modules sampling; modes restored on exit."""
    net = _unwrap(model)
    saved = [(m, m.training) for m in net.modules()]
    try:
        net.eval()
        for m in net.dropout_modules():
            m.train()
        yield net
    finally:
        for module, mode in saved:
            module.training = mode


def predictive_entropy(mean_probs: torch.Tensor, dim: int = 1) -> torch.Tensor:
    """Entropy -sum_c p_c ln p_c of a probability tensor along ``dim``, in nats (0 ln 0 = 0)."""
    return -torch.special.xlogy(mean_probs, mean_probs).sum(dim=dim)


def _summarise(mean_probs: torch.Tensor) -> MCPrediction:
    return MCPrediction(mean_probs, mean_probs.argmax(dim=1), predictive_entropy(mean_probs))


def _check_samples(n_samples: int) -> None:
    if not isinstance(n_samples, int) or n_samples < 1:
        raise HdNetError(f"the number of MC samples must be an integer >= 1, got {n_samples!r}.")


@torch.no_grad()
def mc_dropout_predict(
    model: nn.Module, x: torch.Tensor, n_samples: int = defaults.MC_SAMPLES, samples_per_pass: int | None = None
) -> MCPrediction:
    """MC dropout with a shared prefix: one prefix pass, the suffix on M tiled copies.

    ``x``: (N, in_channels, H, W) normalised input. ``samples_per_pass`` (default: all M) bounds how
    many samples go through the suffix at once (memory).
    """
    _check_samples(n_samples)
    chunk = n_samples if samples_per_pass is None else max(1, min(samples_per_pass, n_samples))
    with mc_dropout_mode(model) as net:
        state = net.prefix(x)
        n = x.shape[0]
        total: torch.Tensor | None = None
        done = 0
        while done < n_samples:
            m = min(chunk, n_samples - done)
            probs = torch.softmax(net.suffix(state.repeat(m) if m > 1 else state), dim=1)
            part = probs.view(m, n, *probs.shape[1:]).sum(dim=0)
            total = part if total is None else total + part
            done += m
        assert total is not None
        return _summarise(total / n_samples)


@torch.no_grad()
def mc_dropout_predict_naive(model: nn.Module, x: torch.Tensor, n_samples: int = defaults.MC_SAMPLES) -> MCPrediction:
    """Reference MC dropout: M independent full forward passes (for tests and benchmarks)."""
    _check_samples(n_samples)
    with mc_dropout_mode(model) as net:
        total = sum(torch.softmax(net(x), dim=1) for _ in range(n_samples))
        return _summarise(total / n_samples)  # type: ignore[arg-type]  # a sum of tensors is a tensor


def dropout_modules(model: nn.Module) -> list[MCDropout]:
    """The MC-dropout modules of a (possibly DDP-wrapped) Bayesian SegNet."""
    return _unwrap(model).dropout_modules()
