"""Data preparation of training across noise levels: DEMs made on the fly against stored DEMs.

Measured side by side in one run, interleaved round by round: a training sample of the robust
profile (noise level drawn, noisy DEM made from the clean points, input channels, D4) against the
same profile's sample read from the stored DEMs at one level, and the robust profile's training
step (forward, backward, optimiser step of a batch of 8). Prints the milliseconds per sample, the
ratio, and the share of a training step that making the DEMs takes.

Usage::

    python benchmarks/bench_noise_data.py [DATASET] [--samples 200] [--rounds 3]

Without DATASET a 60-scan dataset of the procedural terrain is built (and labelled) in a temporary
directory first.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from machine import cpu_model

from hdnet.data import HazardDataset
from hdnet.fit import input_spec_for
from hdnet.model import BayesianSegNet
from hdnet.noise_levels import TrainingNoise
from hdnet.profiles import ROBUST


def _small_dataset(root: Path) -> Path:
    from hdlabels.labeling import label_dataset
    from lidarsim.build import BuildConfig, build_dataset
    from lidarsim.trajectory import TrajectoryConfig

    out = root / "data"
    build_dataset(out, BuildConfig(sigmas_m=(0.0167, 0.07), trajectory=TrajectoryConfig(n_scans=60)), workers=1)
    label_dataset(out, workers=1)
    return out


def _per_sample_ms(ds: HazardDataset, n: int) -> float:
    t0 = time.perf_counter()
    for i in range(n):
        ds[i % len(ds)]
    return (time.perf_counter() - t0) / n * 1e3


def _step_ms(model: BayesianSegNet, batch: torch.Tensor, target: torch.Tensor) -> float:
    optimiser = torch.optim.Adam(model.parameters(), lr=ROBUST.lr)  # the robust profile's optimiser
    model.train()
    t0 = time.perf_counter()
    loss = torch.nn.functional.cross_entropy(model(batch), target, ignore_index=255)
    optimiser.zero_grad()
    loss.backward()
    optimiser.step()
    return (time.perf_counter() - t0) / batch.shape[0] * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", nargs="?", type=Path, default=None)
    parser.add_argument("--samples", type=int, default=200)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        dataset = args.dataset if args.dataset is not None else _small_dataset(Path(tmp))
        spec = input_spec_for(ROBUST, 1.0, None)
        stored = HazardDataset(dataset, "train", 0.0167, input_spec=spec, augment="d4")
        made = HazardDataset(
            dataset, "train", None, input_spec=spec, augment="d4", noise=TrainingNoise(range_m=(0.0, 0.1))
        )
        first = made[0]
        model = BayesianSegNet(ROBUST.model_config(first["image"].shape[0]))
        model = model.to(memory_format=torch.channels_last)  # type: ignore[call-overload]  # the stubs omit memory_format
        batch = torch.stack([made[i % len(made)]["image"] for i in range(8)]).contiguous(
            memory_format=torch.channels_last
        )
        target = torch.stack([made[i % len(made)]["mask"] for i in range(8)])
        rounds: dict[str, list[float]] = {"stored": [], "made": [], "step": []}
        for _ in range(args.rounds):
            rounds["stored"].append(_per_sample_ms(stored, args.samples))
            rounds["made"].append(_per_sample_ms(made, args.samples))
            rounds["step"].append(_step_ms(model, batch, target))
        med = {k: statistics.median(v) for k, v in rounds.items()}
    print(f"CPU: {cpu_model()}; torch {torch.__version__}, {torch.get_num_threads()} threads")
    print(f"stored DEM sample: {med['stored']:.2f} ms; made on the fly: {med['made']:.2f} ms")
    print(f"ratio made / stored: {med['made'] / med['stored']:.2f}x")
    print(
        f"robust training step: {med['step']:.1f} ms per image; making the DEMs on the fly adds "
        f"{med['made'] - med['stored']:.2f} ms ({(med['made'] - med['stored']) / med['step'] * 100:.1f} % of a step), "
        f"the whole sample preparation is {med['made'] / (med['made'] + med['step']) * 100:.1f} % of a sample's time"
    )


if __name__ == "__main__":
    main()
