"""Bayesian SegNet speed: training throughput / achieved GFLOP/s, and shared-prefix MC dropout vs naive.

Prints, measured side by side in one run:
* forward+backward (+ SGD step) images/s at the given width (default full width) on 128x128, batch 8,
  and the achieved GFLOP/s (FLOPs counted by torch.utils.flop_counter for one step);
* MC-dropout inference with M samples: the shared-prefix batched path vs M naive full passes,
  seconds per call and the ratio (target >= 1.3x at M = 8).

Usage: python benchmarks/bench_model.py [--width 1.0] [--size 128] [--batch 8] [--samples 8] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch
from torch.utils.flop_counter import FlopCounterMode

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hdnet.infer import mc_dropout_predict, mc_dropout_predict_naive
from hdnet.model import BayesianSegNet, count_parameters


def _train_step(model: BayesianSegNet, opt: torch.optim.Optimizer, x: torch.Tensor, y: torch.Tensor) -> None:
    opt.zero_grad(set_to_none=True)
    torch.nn.functional.cross_entropy(model(x), y, ignore_index=255).backward()
    opt.step()


def _timed(fn: Callable[[], object], repeats: int) -> float:
    """Median seconds of ``repeats`` calls after one warm-up call."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=float, default=1.0)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--samples", type=int, default=8)
    parser.add_argument("--mc-batch", type=int, default=1, help="DEMs per MC-dropout call")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    args = parser.parse_args()
    device = torch.device(args.device)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    torch.manual_seed(0)

    model = BayesianSegNet(width=args.width).to(device)
    print(
        f"device {device}, torch {torch.__version__}, threads {torch.get_num_threads()}, "
        f"width {args.width}, {count_parameters(model):,} parameters"
    )

    # --- training throughput ------------------------------------------------------------------
    opt = torch.optim.SGD(model.parameters(), lr=1e-4, momentum=0.9)
    x = torch.randn(args.batch, 1, args.size, args.size, device=device)
    y = torch.randint(0, 2, (args.batch, args.size, args.size), device=device)
    model.train()
    with FlopCounterMode(display=False) as counter:
        _train_step(model, opt, x, y)
    flops = counter.get_total_flops()

    def step() -> None:
        _train_step(model, opt, x, y)
        sync()

    t = _timed(step, args.repeats)
    print(
        f"train fwd+bwd  {args.size}x{args.size} batch {args.batch}: {t:.3f} s/step, "
        f"{args.batch / t:.2f} images/s, {flops / 1e9:.1f} GFLOP/step, {flops / t / 1e9:.1f} GFLOP/s achieved"
    )

    # --- MC dropout: shared prefix vs naive ----------------------------------------------------
    xm = torch.randn(args.mc_batch, 1, args.size, args.size, device=device)
    shared_t, naive_t = [], []

    def shared() -> None:
        mc_dropout_predict(model, xm, n_samples=args.samples)
        sync()

    def naive() -> None:
        mc_dropout_predict_naive(model, xm, n_samples=args.samples)
        sync()

    shared()  # warm-up both
    naive()
    for _ in range(args.repeats):  # interleaved, so load changes hit both alike
        shared_t.append(_once(shared))
        naive_t.append(_once(naive))
    s, n = statistics.median(shared_t), statistics.median(naive_t)
    print(
        f"MC dropout M={args.samples}, {args.mc_batch} x {args.size}x{args.size}: shared prefix {s:.3f} s, "
        f"naive {n:.3f} s, speed-up {n / s:.2f}x (target >= 1.3x)"
    )


def _once(fn: Callable[[], object]) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


if __name__ == "__main__":
    main()
