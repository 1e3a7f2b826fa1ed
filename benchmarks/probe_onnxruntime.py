"""ONNX Runtime against PyTorch for ``hd detect``'s MC-dropout pass, side by side (an optional engine, probed).

The robust profile's network (width 3/4, depth 2, untrained weights), one batch of ``hd detect``:
8 tiles of 100 x 100, M = 8 samples. Variants, interleaved round by round:

* ``torch nchw`` / ``torch channels-last``: ``hdnet.engine.predict`` (the shared prefix once, the
  suffix on the M x N tiled copies, hd's own dropout draws: ``hdnet.dropout_masks.sample_keep``);
* ``onnxruntime``: the same network exported (``torch.onnx.export``, dynamo) as two graphs, the
  prefix and the suffix with its four dropout masks as **inputs**; the masks are drawn as hd draws them, in
  the order and shapes the suffix applies them (``hdnet.engine.NCHWDrawDropout.draw``), so the
  samples are the same draws and the maps differ only by the arithmetic's round-off (printed:
  max |ΔP(safe)| and |Δentropy| against ``torch nchw``);
* ``onnxruntime, full graph``: the whole deterministic forward (no dropout) in one ORT graph against
  PyTorch's, to see the convolutions' speed alone.

Needs ``onnxruntime``, ``onnx`` and ``onnxscript`` (``pip install onnxruntime onnx onnxscript``);
they are not hd's dependencies. Prints the frames/s of each and the ratio to ``torch nchw``.

Usage::

    python benchmarks/probe_onnxruntime.py [--rounds 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from machine import cpu_model

from hdnet.dropout_masks import keep_scale
from hdnet.engine import NCHWDrawDropout, inference_model, predict
from hdnet.fit import input_spec_for
from hdnet.infer import MCPrediction, predictive_entropy
from hdnet.model import BayesianSegNet
from hdnet.profiles import ROBUST

TILES, SAMPLES = 8, 8


class _Prefix(nn.Module):
    """The deterministic prefix as a graph: features and the pools' indices."""

    def __init__(self, net: BayesianSegNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        state = self.net.prefix(x)
        return (state.features, *state.indices)


class _MaskedSuffix(nn.Module):
    """The depth-2 suffix with its dropout masks as inputs (``x * mask`` where the model drops)."""

    def __init__(self, net: BayesianSegNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, features: torch.Tensor, idx1: torch.Tensor, *masks: torch.Tensor) -> torch.Tensor:
        n = self.net
        enc2, dec2, dec1 = (getattr(n, name) for name in ("enc2", "dec2", "dec1"))  # set by name in the model
        m_pool1, m_pool2, m_dec2, m_dec1 = masks
        x = features * m_pool1
        x = enc2(x)
        size2 = x.shape
        x, idx2 = n.pool(x)
        x = x * m_pool2
        x = dec2(n.unpool(x, idx2, output_size=size2[-2:])) * m_dec2
        x = dec1(n.unpool(x, idx1, output_size=(100, 100))) * m_dec1
        return torch.softmax(n.classifier(x), dim=1)


def _out_channels(net: BayesianSegNet, block: str) -> int:
    """The output channels of a block of the network (its last convolution's)."""
    convs = [m for m in getattr(net, block).modules() if isinstance(m, nn.Conv2d)]
    return int(convs[-1].out_channels)


def _masks(net: BayesianSegNet, state_shape: torch.Size, n: int) -> list[torch.Tensor]:
    """The four masks of one suffix pass on the sample-major batch (float32: 0 or the keep scale), drawn
    as MC-dropout inference draws them, in the order the suffix applies them (the shapes of a depth-2
    network on 100 x 100 tiles)."""
    c1, c2, c0 = state_shape[1], _out_channels(net, "enc2"), _out_channels(net, "dec1")
    shapes = [(n, c1, 50, 50), (n, c2, 25, 25), (n, c1, 50, 50), (n, c0, 100, 100)]
    draw = NCHWDrawDropout(net.config.dropout_p)
    scale = keep_scale(net.config.dropout_p)
    return [draw.draw(s).to(torch.float32).mul_(scale) for s in shapes]


def _summary(probs: torch.Tensor, n: int) -> MCPrediction:
    samples = probs.view(SAMPLES, n, *probs.shape[1:])
    mean = samples.mean(dim=0)
    expected = predictive_entropy(samples, dim=2).mean(dim=0)
    return MCPrediction(mean, mean.argmax(dim=1), predictive_entropy(mean), expected)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    import onnxruntime as ort

    torch.manual_seed(0)
    spec = input_spec_for(ROBUST, 1.0, None)
    net = BayesianSegNet(ROBUST.model_config(spec.n_channels)).eval()
    if net.config.depth != 2 or net.first_dropout_level != 1:
        raise SystemExit("this probe exports the depth-2 suffix of the robust profile")
    x = torch.randn(TILES, spec.n_channels, 100, 100)
    so = ort.SessionOptions()
    so.intra_op_num_threads = torch.get_num_threads()
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    with tempfile.TemporaryDirectory() as tmp, torch.no_grad():
        t0 = time.perf_counter()
        state = net.prefix(x)
        tiled = state.repeat(SAMPLES)
        masks = _masks(net, state.features.shape, SAMPLES * TILES)
        paths = {name: str(Path(tmp) / f"{name}.onnx") for name in ("prefix", "suffix", "full")}
        torch.onnx.export(_Prefix(net), (x,), paths["prefix"], dynamo=True, verbose=False)
        torch.onnx.export(
            _MaskedSuffix(net), (tiled.features, tiled.indices[0], *masks), paths["suffix"], dynamo=True, verbose=False
        )
        torch.onnx.export(net, (x.repeat(SAMPLES, 1, 1, 1),), paths["full"], dynamo=True, verbose=False)
        export_s = time.perf_counter() - t0
        prefix, suffix, full = (ort.InferenceSession(paths[k], so, providers=["CPUExecutionProvider"]) for k in paths)
        s_names = [i.name for i in suffix.get_inputs()]
        x_np, x_full = x.numpy(), x.repeat(SAMPLES, 1, 1, 1).numpy()
        cl = inference_model(net, "channels-last")

        def ort_mc(seed: int) -> MCPrediction:
            torch.manual_seed(seed)
            feats, idx1 = prefix.run(None, {prefix.get_inputs()[0].name: x_np})
            reps = (SAMPLES, 1, 1, 1)
            drawn = _masks(net, torch.Size(feats.shape), SAMPLES * TILES)
            feed = [np.tile(feats, reps), np.tile(idx1, reps), *(m.numpy() for m in drawn)]
            probs = suffix.run(None, dict(zip(s_names, feed, strict=True)))[0]
            return _summary(torch.from_numpy(probs), TILES)

        def torch_mc(model: nn.Module, layout: str, seed: int) -> MCPrediction:
            torch.manual_seed(seed)
            return predict(model, x, SAMPLES, layout)

        ref, other = torch_mc(net, "nchw", 1), ort_mc(1)
        d_p = float((ref.mean_probs[:, 1] - other.mean_probs[:, 1]).abs().max())
        d_h = float((ref.entropy_nats - other.entropy_nats).abs().max())
        variants: dict[str, Any] = {
            "torch nchw": lambda: torch_mc(net, "nchw", 2),
            "torch channels-last": lambda: torch_mc(cl, "channels-last", 2),
            "onnxruntime (masks as inputs)": lambda: ort_mc(2),
            "torch full forward, no dropout": lambda: net(torch.from_numpy(x_full)),
            "onnxruntime full forward": lambda: full.run(None, {full.get_inputs()[0].name: x_full}),
        }
        times: dict[str, list[float]] = {k: [] for k in variants}
        for _ in range(args.rounds):
            for name, run in variants.items():
                t0 = time.perf_counter()
                run()
                times[name].append(time.perf_counter() - t0)
    load = os.getloadavg()
    print(
        f"{cpu_model()}, {os.cpu_count()} cores, torch {torch.__version__} and onnxruntime {ort.__version__} on "
        f"{torch.get_num_threads()} threads, load {load[0]:.1f}; robust network, {TILES} tiles x M = {SAMPLES}; "
        f"export {export_s:.1f} s"
    )
    base = statistics.median(times["torch nchw"])
    full_base = statistics.median(times["torch full forward, no dropout"])
    for name, ts in times.items():
        m = statistics.median(ts)
        ref_s = full_base if "full" in name else base
        print(f"  {name:32s} {m * 1000:7.1f} ms  {TILES * SAMPLES / m:6.1f} frames/s  {ref_s / m:4.2f}x")
    print(f"onnxruntime against torch nchw, the same draws: max |dP(safe)| {d_p:.2e}, max |dentropy| {d_h:.2e}")


if __name__ == "__main__":
    main()
