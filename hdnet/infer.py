"""MC-dropout inference (Kendall et al. 2015; paper Eq. 1-2): mean softmax, prediction, predictive entropy,
expected entropy and mutual information.

While sampling, every BatchNorm (and every other module) is in inference mode and only the
``MCDropout`` modules are in training mode; the previous modes are restored afterwards, so running
statistics are never touched. The dropout masks are hd's own (``hdnet.dropout_masks.sample_keep``:
16-bit PCG64 draws seeded from PyTorch's default generator, in the logical N, C, H, W order), not
``torch.bernoulli``'s, whose CPU kernel has a path through MKL's generator for Intel CPUs and the
Mersenne Twister elsewhere: a seed gives the same samples on every CPU, in every memory layout and on
every device.
The M samples are batched: the deterministic prefix (everything before the first dropout) is
computed once, tiled M times along the batch (sample-major) and passed through the stochastic
suffix in one pass (or in chunks of ``samples_per_pass`` samples to bound memory). The samples'
softmaxes and their entropies are summed chunk by chunk; no sample is kept.

On a GPU the samples are computed in float32 proper: TF32 (PyTorch's default for cuDNN
convolutions on Ampere and later) is switched off while sampling (``exact_float32``). Measured on an
NVIDIA H200 with the cpu profile's network, 48 test DEMs at 1.67 and 7 cm, M = 8, one seed, against
this project's AMD EPYC CPU: with TF32, P(safe) differed by up to 0.107 and entropy by 0.161, the
safe/unsafe/uncertain class of 0.025 % of cells and the best site of 1 scene in 48 moved; without it,
at most 7.1e-4, no class and no site (docs/results.md, "What is the same on every machine").
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
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
    (1 = safe, 0 = unsafe); ``entropy_nats``: predictive entropy H[mean_m p_m] of the mean softmax
    (N, H, W), in nats (0 = certain, ln 2 = maximal for two classes); ``expected_entropy_nats``: the
    mean over the M samples of each sample's softmax entropy, mean_m H[p_m] (N, H, W), nats.
    """

    mean_probs: torch.Tensor
    prediction: torch.Tensor
    entropy_nats: torch.Tensor
    expected_entropy_nats: torch.Tensor

    @property
    def mutual_information_nats(self) -> torch.Tensor:
        """H[mean_m p_m] - mean_m H[p_m] (N, H, W), nats: the samples' disagreement (``mutual_information``)."""
        return mutual_information(self.entropy_nats, self.expected_entropy_nats)

    def on_grid(self, to_grid: Callable[[torch.Tensor], torch.Tensor]) -> MCPrediction:
        """The prediction on another grid: ``to_grid`` maps (N, C, H, W) to (N, C, h, w) (e.g. the
        DEM grid, ``hdnet.inputs.to_dem_grid``) and is applied to the mean softmax (float32) and to
        the expected entropy; the prediction and the predictive entropy are made again on the new grid."""
        probs = to_grid(self.mean_probs.float())
        expected = to_grid(self.expected_entropy_nats.float()[:, None])[:, 0]
        return MCPrediction(probs, probs.argmax(dim=1), predictive_entropy(probs), expected)


def _unwrap(model: nn.Module) -> BayesianSegNet:
    inner = getattr(model, "module", model)  # DistributedDataParallel / DataParallel wrappers
    if not isinstance(inner, BayesianSegNet):
        raise HdNetError(f"MC-dropout inference needs a BayesianSegNet, got {type(inner).__name__}.")
    return inner


@contextlib.contextmanager
def exact_float32() -> Iterator[None]:
    """Context: CUDA's convolutions and matrix products in float32 proper, not TF32 (10-bit
    mantissas), so that a GPU makes the CPU's decisions (module docstring); the flags restored on exit.
    No effect on a CPU."""
    saved = (torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32)
    try:
        torch.backends.cudnn.allow_tf32 = False
        torch.backends.cuda.matmul.allow_tf32 = False
        yield
    finally:
        torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32 = saved


@contextlib.contextmanager
def mc_dropout_mode(model: nn.Module) -> Iterator[BayesianSegNet]:
    """Context: whole model in eval mode, only the dropout modules sampling, with hd's own masks
    (``MCDropout.sampling``: ``hdnet.dropout_masks.sample_dropout``), in float32 proper on a GPU
    (``exact_float32``); modes and flags restored on exit."""
    net = _unwrap(model)
    saved = [(m, m.training) for m in net.modules()]
    drops = net.dropout_modules()
    sampling = [m.sampling for m in drops]
    try:
        net.eval()
        for m in drops:
            m.train()
            m.sampling = True
        with exact_float32():
            yield net
    finally:
        for module, mode in saved:
            module.training = mode
        for m, was in zip(drops, sampling, strict=True):
            m.sampling = was


def predictive_entropy(mean_probs: torch.Tensor, dim: int = 1) -> torch.Tensor:
    """Entropy -sum_c p_c ln p_c of a probability tensor along ``dim``, in nats (0 ln 0 = 0)."""
    return -torch.special.xlogy(mean_probs, mean_probs).sum(dim=dim)


def mutual_information(entropy_nats: torch.Tensor, expected_entropy_nats: torch.Tensor) -> torch.Tensor:
    """MI = H[mean_m p_m] - mean_m H[p_m] (nats; Gal et al. 2017, the BALD score), clipped
    at 0: it is >= 0 by the concavity of the entropy, and only round-off makes it negative."""
    return (entropy_nats - expected_entropy_nats).clamp_min(0.0)


def _summarise(prob_sum: torch.Tensor, entropy_sum: torch.Tensor, n_samples: int) -> MCPrediction:
    """The prediction from the sums over the M samples of their softmaxes and of their entropies."""
    mean_probs = prob_sum / n_samples
    return MCPrediction(mean_probs, mean_probs.argmax(dim=1), predictive_entropy(mean_probs), entropy_sum / n_samples)


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
        entropy_total: torch.Tensor | None = None
        done = 0
        while done < n_samples:
            m = min(chunk, n_samples - done)
            probs = torch.softmax(net.suffix(state.repeat(m) if m > 1 else state), dim=1)
            samples = probs.view(m, n, *probs.shape[1:])
            part = samples.sum(dim=0)
            entropy_part = predictive_entropy(samples.float(), dim=2).sum(dim=0)
            total = part if total is None else total + part
            entropy_total = entropy_part if entropy_total is None else entropy_total + entropy_part
            done += m
        assert total is not None and entropy_total is not None
        return _summarise(total, entropy_total, n_samples)


@torch.no_grad()
def mc_dropout_predict_naive(model: nn.Module, x: torch.Tensor, n_samples: int = defaults.MC_SAMPLES) -> MCPrediction:
    """Reference MC dropout: M independent full forward passes (for tests and benchmarks)."""
    _check_samples(n_samples)
    with mc_dropout_mode(model) as net:
        samples = [torch.softmax(net(x), dim=1) for _ in range(n_samples)]
        total = sum(samples)
        entropy_total = sum(predictive_entropy(p.float()) for p in samples)
        return _summarise(total, entropy_total, n_samples)  # type: ignore[arg-type]  # sums of tensors are tensors


def dropout_modules(model: nn.Module) -> list[MCDropout]:
    """The MC-dropout modules of a (possibly DDP-wrapped) Bayesian SegNet."""
    return _unwrap(model).dropout_modules()
