"""How fast ``hd detect`` of the whole Jezero floor could be on this machine: a roofline of the network pass.

Prints, measured in one run on torch's threads:

* the arithmetic of one ``hd detect`` batch (8 tiles of 100 x 100, M MC-dropout samples) of the robust
  profile's network (width 3/4, depth 2, 4 input channels), counted by ``torch.utils.flop_counter``
  on the path ``hd detect`` runs (``hdnet.engine``, channels-last, the shared prefix once per tile),
  per tile and for the 2209 tiles of the 14.29 km^2 Jezero floor (docs/benchmarks.md);
* the machine's sustained float32 rates: a 2048 x 2048 matrix product, and the network's heaviest
  convolution (96 -> 96 channels, 3 x 3, 50 x 50, batch 64, channels-last), median of five;
* the network pass itself (median of three batches), the rate it achieves, and the part of it spent
  drawing the MC-dropout masks (``bernoulli_`` over the batch's mask elements, as ``hdnet.engine`` draws
  them);
* the floor's lower bound in seconds at each rate against issue 30's 60 s target, and the rate the
  target needs.

Usage: python benchmarks/roofline_detect.py [--samples 8] [--tiles 2209]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import torch
import torch.nn.functional as F
from torch.utils.flop_counter import FlopCounterMode

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_detect import median_seconds
from machine import cpu_model

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
        network_s = median_seconds(lambda: predict(model, x, args.samples, "channels-last"), 3, warmups=1)
    masks: list[tuple[NCHWDrawDropout, torch.Size]] = []  # each mask's module and shape, in draw order
    drops = [m for m in model.modules() if isinstance(m, NCHWDrawDropout)]
    for drop in drops:
        drop.shapes = masks
    with torch.no_grad():
        predict(model, x, args.samples, "channels-last")
    for drop in drops:
        drop.shapes = None
    draws = sum(shape.numel() for _, shape in masks)
    mask_s = median_seconds(
        lambda: [drop.draw(shape, torch.float32, torch.device("cpu")) for drop, shape in masks], 3, warmups=0
    )
    gemm, conv = _gemm_gflops(), _conv_gflops()
    per_tile = flops / BATCH_TILES
    total = per_tile * args.tiles
    achieved = flops / network_s / 1e9
    print(f"\none batch ({BATCH_TILES} tiles x M = {args.samples}): {flops / 1e9:.1f} GFLOP, {network_s:.3f} s")
    print(f"  the network achieves {achieved:.1f} GFLOP/s; its {draws / 1e6:.1f} M mask draws take {mask_s:.3f} s")
    print(f"  ({100 * mask_s / network_s:.0f} % of the pass, done serially by PyTorch's generator)")
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
