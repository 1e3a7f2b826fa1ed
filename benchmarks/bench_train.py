"""Training throughput of the robust profile: bfloat16 autocast and fast dropout masks, side by side.

Measured in one run, variants interleaved round by round on the same batches: the robust profile's
training step (forward, loss, backward, Adam step; batch 8 read and prepared by
``hdnet.data.HazardDataset`` with noise levels drawn on the fly, as ``hd train --profile robust``
does) with

* ``float32, torch masks`` — the profile before these two settings (``precision="float32"``,
  ``fast_dropout=False``);
* ``float32, fast masks`` — ``fast_dropout`` only (``hdnet.dropout_masks``);
* ``bfloat16, torch masks`` — ``precision="bfloat16"`` only;
* ``bfloat16, fast masks`` — the robust profile now.

Prints images/s per variant (median over rounds, the sample preparation included, as an epoch
pays it) and the ratio to the first. The numbers a run trains to are compared in docs/benchmarks.md
(two full robust runs, the validation figures side by side), not here.

Usage::

    python benchmarks/bench_train.py [DATASET] [--steps 6] [--rounds 5]

Without DATASET a 60-scan dataset of the procedural terrain is built (and labelled) in a temporary
directory first (``bench_noise_data``'s).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_noise_data import _small_dataset
from machine import cpu_model

from hdnet.data import HazardDataset
from hdnet.fit import input_spec_for
from hdnet.model import BayesianSegNet
from hdnet.noise_levels import TrainingNoise
from hdnet.profiles import ROBUST, TrainingProfile

VARIANTS: dict[str, TrainingProfile] = {
    "float32, torch masks": replace(ROBUST, precision="float32", fast_dropout=False),
    "float32, fast masks": replace(ROBUST, precision="float32", fast_dropout=True),
    "bfloat16, torch masks": replace(ROBUST, precision="bfloat16", fast_dropout=False),
    "bfloat16, fast masks": ROBUST,
}


def _model(profile: TrainingProfile, in_channels: int) -> tuple[BayesianSegNet, torch.optim.Optimizer]:
    torch.manual_seed(0)
    model = BayesianSegNet(profile.model_config(in_channels)).to(memory_format=torch.channels_last)  # type: ignore[call-overload]  # the stubs omit memory_format
    for module in model.dropout_modules():
        module.fast_masks = profile.fast_dropout
    model.train()
    return model, torch.optim.Adam(model.parameters(), lr=profile.lr)


def _steps_images_per_s(
    ds: HazardDataset,
    model: BayesianSegNet,
    opt: torch.optim.Optimizer,
    profile: TrainingProfile,
    start: int,
    steps: int,
) -> float:
    """Images/s of ``steps`` training steps on batches read from ``ds`` (preparation included)."""
    batch = profile.batch_size
    t0 = time.perf_counter()
    for s in range(steps):
        samples = [ds[(start + s * batch + i) % len(ds)] for i in range(batch)]
        x = torch.stack([x["image"] for x in samples]).contiguous(memory_format=torch.channels_last)
        y = torch.stack([x["mask"] for x in samples]).long()
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=profile.precision == "bfloat16"):
            logits = model(x)
        loss = torch.nn.functional.cross_entropy(logits.float(), y, ignore_index=255)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    return steps * batch / (time.perf_counter() - t0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", nargs="?", type=Path, default=None)
    parser.add_argument("--steps", type=int, default=6, help="training steps per variant and round")
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        dataset = args.dataset if args.dataset is not None else _small_dataset(Path(tmp))
        spec = input_spec_for(ROBUST, 1.0, None)
        ds = HazardDataset(
            dataset,
            "train",
            None,
            input_spec=spec,
            augment="d4",
            noise=TrainingNoise(range_m=ROBUST.train_sigma_range_m),
        )
        in_channels = ds[0]["image"].shape[0]
        models = {name: _model(profile, in_channels) for name, profile in VARIANTS.items()}
        for name, (model, opt) in models.items():  # warm-up: oneDNN's kernels for each dtype
            _steps_images_per_s(ds, model, opt, VARIANTS[name], 0, 1)
        rates: dict[str, list[float]] = {name: [] for name in VARIANTS}
        for r in range(args.rounds):
            for name, (model, opt) in models.items():
                rates[name].append(_steps_images_per_s(ds, model, opt, VARIANTS[name], r * args.steps * 8, args.steps))
    med = {name: statistics.median(v) for name, v in rates.items()}
    base = med["float32, torch masks"]
    print(f"CPU: {cpu_model()}; torch {torch.__version__}, {torch.get_num_threads()} threads")
    print(
        f"robust profile training step, batch {ROBUST.batch_size}, median of {args.rounds} rounds x {args.steps} steps"
    )
    for name, value in med.items():
        print(f"  {name:24s} {value:6.1f} images/s   {value / base:4.2f}x")


if __name__ == "__main__":
    main()
