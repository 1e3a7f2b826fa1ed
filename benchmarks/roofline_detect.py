"""How fast ``hd detect`` of the whole Jezero floor could be on this machine: a roofline of the network pass.

Prints, measured in one run on torch's threads:

* the arithmetic of one ``hd detect`` batch (8 tiles of 100 x 100, M MC-dropout samples) of the robust
  profile's network (width 3/4, depth 2, 4 input channels), counted by ``torch.utils.flop_counter``
  on the path ``hd detect`` runs (``hdnet.engine``, channels-last, the shared prefix once per tile),
  per tile and for the 2209 tiles of the 14.29 km^2 Jezero floor (docs/benchmarks.md);
* the machine's sustained float32 rates: a 2048 x 2048 matrix product, and the network's heaviest
  convolution (96 -> 96 channels, 3 x 3, 50 x 50, batch 64, channels-last), median of five;
* the network pass itself (median of three batches), the rate it achieves, and the part of it spent
  drawing the MC-dropout masks, side by side for the masks drawn before (PyTorch's ``bernoulli_`` over
  the batch's mask elements in NCHW order, divided by 1 - p, as ``hdnet.engine`` drew them until
  MC-dropout inference took hd's own masks) and now (``hdnet.dropout_masks.sample_keep``: 16-bit PCG64
  draws compared with a threshold), the two passes alternated batch by batch;
* the floor's lower bound in seconds at each rate against issue 30's 60 s target, and the rate the
  target needs.

Usage: python benchmarks/roofline_detect.py [--samples 8] [--tiles 2209]
"""

from __future__ import annotations

import argparse
import copy
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch
import torch.nn.functional as F
from torch.utils.flop_counter import FlopCounterMode

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_detect import median_seconds
from machine import cpu_model

from hdnet.dropout_masks import sample_keep
from hdnet.engine import NCHWDrawDropout, inference_model, predict
from hdnet.model import BayesianSegNet, ModelConfig
from hdnet.profiles import ROBUST

FLOOR_TILES = 2209  # the 14.29 km^2 Jezero floor at 1 m (docs/benchmarks.md, "Detection at area scale")
TARGET_S = 60.0  # issue 30: the floor with the robust run in at most 60 s
BATCH_TILES = 8  # hd detect's default batch (DetectSettings.batch_size)


def _gemm_gflops() -> float:
    a, b = torch.randn(2048, 2048), torch.randn(2048, 2048)
    return 2 * 2048**3 / median_seconds(lambda: torch.mm(a, b), 5, warmups=1) / 1e9


def _conv_gflops() -> float:
    x = torch.randn(64, 96, 50, 50).contiguous(memory_format=torch.channels_last)
    w = torch.randn(96, 96, 3, 3).contiguous(memory_format=torch.channels_last)
    with torch.no_grad():
        seconds = median_seconds(lambda: F.conv2d(x, w, padding=1), 5, warmups=1)
    return 2 * 64 * 50 * 50 * 96 * 96 * 9 / seconds / 1e9


class BernoulliDropout(NCHWDrawDropout):
    """The masks MC-dropout inference drew before hd's own: PyTorch's ``bernoulli_(1 - p)`` over the
    logical NCHW order (MKL's generator on Intel CPUs, the Mersenne Twister elsewhere), over 1 - p."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``x`` times the noise while sampling (``x`` channels-last: the noise made so too)."""
        if self.shapes is not None or not self.training:
            return super().forward(x)
        noise = bernoulli_noise(x.shape, self.p)
        if x.is_contiguous(memory_format=torch.channels_last):
            noise = noise.contiguous(memory_format=torch.channels_last)
        return x * noise


def bernoulli_noise(shape: torch.Size, p: float) -> torch.Tensor:
    """The former draw: float32 Bernoulli(1 - p) over 1 - p, in NCHW order."""
    return torch.empty(shape).bernoulli_(1.0 - p).div_(1.0 - p)


def _with_bernoulli_masks(model: torch.nn.Module) -> torch.nn.Module:
    """A copy of the inference model whose dropouts draw the former masks."""
    old = copy.deepcopy(model)
    for module in list(old.modules()):
        for name, child in module.named_children():
            if isinstance(child, NCHWDrawDropout):
                setattr(module, name, BernoulliDropout(child.p))
    return old


def _alternated(fns: list[Callable[[], object]], repeats: int) -> list[float]:
    """Median seconds of each of ``fns``, called in turn ``repeats`` times after one warm-up round."""
    times: list[list[float]] = [[] for _ in fns]
    for round_ in range(repeats + 1):
        for fn, kept in zip(fns, times, strict=True):
            t0 = time.perf_counter()
            fn()
            if round_:
                kept.append(time.perf_counter() - t0)
    return [statistics.median(t) for t in times]


def _mask_shapes(model: torch.nn.Module, x: torch.Tensor, samples: int) -> list[torch.Size]:
    """The shapes of the masks one pass draws, in draw order."""
    masks: list[tuple[NCHWDrawDropout, torch.Size]] = []
    drops = [m for m in model.modules() if isinstance(m, NCHWDrawDropout)]
    for drop in drops:
        drop.shapes = masks
    with torch.no_grad():
        predict(model, x, samples, "channels-last")
    for drop in drops:
        drop.shapes = None
    return [shape for _, shape in masks]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=8, help="MC-dropout samples M")
    parser.add_argument("--tiles", type=int, default=FLOOR_TILES, help="tiles of the area mapped")
    args = parser.parse_args()
    torch.manual_seed(0)
    config = ModelConfig(in_channels=4, width=ROBUST.width, depth=ROBUST.depth, dropout_p=ROBUST.dropout_p)
    model = inference_model(BayesianSegNet(config).eval(), "channels-last")
    x = torch.randn(BATCH_TILES, 4, 100, 100)
    load = os.getloadavg()
    print(
        f"{cpu_model()}, {os.cpu_count()} cores, torch {torch.__version__} on {torch.get_num_threads()} threads, "
        f"load average {load[0]:.1f} / {load[1]:.1f} (1 / 5 min); robust network, M = {args.samples}"
    )
    with torch.no_grad():
        with FlopCounterMode(display=False) as counter:
            predict(model, x, args.samples, "channels-last")
        flops = counter.get_total_flops()
    old_model = _with_bernoulli_masks(model)
    with torch.no_grad():
        old_s, network_s = _alternated(
            [
                lambda: predict(old_model, x, args.samples, "channels-last"),
                lambda: predict(model, x, args.samples, "channels-last"),
            ],
            3,
        )
    shapes = _mask_shapes(model, x, args.samples)
    draws = sum(shape.numel() for shape in shapes)
    p = config.dropout_p
    old_mask_s, mask_s = _alternated(
        [lambda: [bernoulli_noise(shape, p) for shape in shapes], lambda: [sample_keep(shape, p) for shape in shapes]],
        3,
    )
    gemm, conv = _gemm_gflops(), _conv_gflops()
    per_tile = flops / BATCH_TILES
    total = per_tile * args.tiles
    achieved = flops / network_s / 1e9
    print(f"\none batch ({BATCH_TILES} tiles x M = {args.samples}): {flops / 1e9:.1f} GFLOP, {draws / 1e6:.1f} M draws")
    print(f"{'MC-dropout masks':40s} {'draws, s':>9s} {'pass, s':>8s} {'of pass':>8s} {'GFLOP/s':>8s}")
    for name, drawn, passed in (
        ("PyTorch bernoulli_ (before)", old_mask_s, old_s),
        ("hd's 16-bit PCG64 (sample_keep, now)", mask_s, network_s),
    ):
        print(f"{name:40s} {drawn:9.3f} {passed:8.3f} {100 * drawn / passed:7.0f}% {flops / passed / 1e9:8.1f}")
    print(f"draws {old_mask_s / mask_s:.1f}x faster, the pass {old_s / network_s:.2f}x")
    print(f"per tile {per_tile / 1e9:.2f} GFLOP; {args.tiles} tiles: {total / 1e12:.2f} TFLOP")
    print(f"\nsustained float32: matrix product {gemm:.1f} GFLOP/s, the net's heaviest convolution {conv:.1f} GFLOP/s")
    print(f"{'rate':44s} {'floor, s':>9s} {'vs 60 s':>8s}")
    for name, rate in (
        ("the network as it runs", achieved),
        ("every FLOP at the heaviest convolution's rate", conv),
        ("every FLOP at the matrix product's rate", gemm),
    ):
        seconds = total / (rate * 1e9)
        print(f"{name:44s} {seconds:9.1f} {seconds / TARGET_S:7.1f}x")
    print(f"the 60 s target needs {total / TARGET_S / 1e9:.0f} GFLOP/s sustained over the whole pass")


if __name__ == "__main__":
    main()
