"""Ablation of the cpu training profile: each lever at a fixed epoch budget, judged on the validation split.

Every variant is the reference profile (``cpu-v1``: the cpu profile as shipped before this study)
with one or more fields changed (``VARIANTS``). Each is trained with ``hdnet.fit`` for the same
number of epochs (its learning-rate schedule compressed to that budget), then scored on the
validation split at the training noise level with MC dropout (M = 8; ``validation_summary``): base
net PA / mIoU, uncertainty-aware V/C / PA / mIoU / precision / sensitivity at the mean validation
entropy, and precision / sensitivity at the median validation entropy (V/C = 50 % by construction).
The test split is never read.

Training throughput is measured apart (``--throughput``): every variant's training step (forward,
backward, optimiser step on a batch at the variant's input size, plus reading and preparing its
samples from the dataset) timed in short rounds, the variants interleaved round by round so that
load from other jobs hits them alike; the median images/s over the rounds is reported and gives
the seconds the epoch budget takes (800 training DEMs per epoch, validation excluded).

Outputs in ``--out``: ``runs/<variant>/`` (each a normal run directory), ``results.json``,
``ablation.md`` (the table) and ``learning_curves.png`` (validation PA and mIoU per epoch).

Usage::

    python benchmarks/ablate_cpu_profile.py DATASET --out ablation --epochs 20 [--variants a,b] [--threads 2]
    python benchmarks/ablate_cpu_profile.py DATASET --out ablation --throughput [--rounds 5]
    python benchmarks/ablate_cpu_profile.py DATASET --out ablation --report
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hdcore.storage import OutputTransaction, atomic_path, write_json_atomic, write_text_atomic
from hdnet import defaults
from hdnet.data import HazardDataset, open_labeling
from hdnet.evaluate import validation_summary
from hdnet.fit import FitConfig, fit, input_spec_for
from hdnet.inputs import Normalisation
from hdnet.model import BayesianSegNet
from hdnet.profiles import CPU, TrainingProfile
from hdnet.train import load_checkpoint, median_images_per_s

# The cpu profile as shipped before this study (hd 0.1.0): the reference every lever is measured against.
# Parallel instances share --out: each waits up to this long (seconds) for another's short write.
LOCK_WAIT_S = 60.0
REFERENCE = replace(
    CPU,
    name="cpu-v1",
    input_size=None,
    width=0.25,
    batch_size=8,
    lr=1e-3,
    epochs=80,
    optimizer="adam",
    lr_schedule="cosine",
    depth=5,
    dropout_p=0.5,
    heights="minmax",
    height_scale_m=1.0,
    extra_channels=(),
    augment="none",
    class_weighting="none",
    channels_last=False,
)

OTHER_SIGMAS_M = (0.07,)  # the validation split is also scored at 7 cm with the 1.67 cm thresholds

# name -> (what changes, overrides of REFERENCE)
VARIANTS: dict[str, tuple[str, dict[str, Any]]] = {
    "reference": ("cpu profile before this study: width 1/4, depth 5, min-max heights, cosine Adam 1e-3, batch 8", {}),
    "median": ("heights relative to each DEM's median, metres", {"heights": "median"}),
    "plane_slope": (
        "heights relative to each DEM's plane + slope channel",
        {"heights": "plane", "extra_channels": ("slope",)},
    ),
    "median_slope_hp": (
        "median heights + slope + high-pass channels",
        {"heights": "median", "extra_channels": ("slope", "highpass")},
    ),
    "d4": ("D4 augmentation", {"augment": "d4"}),
    "balanced": ("class-balanced cross-entropy", {"class_weighting": "balanced"}),
    "onecycle": ("one-cycle learning rate (peak 1e-3)", {"lr_schedule": "onecycle"}),
    "onecycle-3e-3": ("one-cycle learning rate (peak 3e-3)", {"lr_schedule": "onecycle", "lr": 3e-3}),
    "batch16": ("batch 16", {"batch_size": 16}),
    "dropout0.2": ("dropout p = 0.2", {"dropout_p": 0.2}),
    "depth4": ("4 pooling stages (pad to 112 px)", {"depth": 4}),
    "depth3": ("3 pooling stages (pad to 104 px)", {"depth": 3}),
    "depth2": ("2 pooling stages (100 px, no padding)", {"depth": 2}),
    "depth1": ("1 pooling stage (100 px, no padding)", {"depth": 1}),
    "width0.5": ("width 1/2", {"width": 0.5}),
    "width0.375": ("width 3/8", {"width": 0.375}),
    "width0.75": ("width 3/4", {"width": 0.75}),
    "minmax": ("the paper's dataset min-max heights", {"heights": "minmax", "extra_channels": ()}),
    "channels_last": ("channels-last memory format", {"channels_last": True}),
}


def profile_of(name: str, epochs: int) -> TrainingProfile:
    """The variant's profile at the epoch budget (combined variants: names joined by '+')."""
    overrides: dict[str, Any] = {}
    for part in _parts(name):
        overrides.update(VARIANTS[part][1])
    return replace(REFERENCE, name=f"ablation-{name}", epochs=epochs, **overrides)


def _parts(name: str) -> list[str]:
    """The levers of a variant: one name of VARIANTS, or several joined by '+' (later ones win)."""
    parts = name.split("+")
    unknown = [p for p in parts if p not in VARIANTS]
    if unknown:
        raise SystemExit(f"Error: unknown variant(s) {unknown}; known: {', '.join(VARIANTS)}")
    return parts


def train_and_score(dataset: Path, out: Path, name: str, epochs: int, labels: str | None) -> dict[str, Any]:
    run = out / "runs" / name
    profile = profile_of(name, epochs)
    last = fit(dataset, run, FitConfig(profile=profile, epochs=epochs, resume=True, labels=labels, progress=False))
    ckpt = load_checkpoint(last)
    timing = ckpt.get("timing", [])
    summary = validation_summary(run, dataset, labels=labels, other_sigmas_m=OTHER_SIGMAS_M)
    return {
        "variant": name,
        "epochs": epochs,
        "profile": profile.to_dict(),
        "history": ckpt["history"],
        "train_seconds_measured": sum(t["train_seconds"] for t in timing),
        "images_per_s_measured": median_images_per_s(timing),
        "validation": summary,
    }


def throughput(dataset: Path, names: list[str], rounds: int, steps: int, labels: str | None) -> dict[str, float]:
    """Median images/s of each variant's training step (data preparation included), interleaved rounds."""
    entry, _ = open_labeling(dataset, labels)
    rates: dict[str, list[float]] = {n: [] for n in names}
    data_share: dict[str, list[float]] = {n: [] for n in names}
    setups = {}
    for n in names:
        p = profile_of(n, 1)
        spec = input_spec_for(p, entry.spacing_m, Normalisation(-10.0, 10.0) if p.heights == "minmax" else None)
        ds = HazardDataset(dataset, "train", defaults.TRAIN_SIGMA_M, labels=labels, input_spec=spec, augment=p.augment)
        model = BayesianSegNet(p.model_config(spec.n_channels))
        fmt = torch.channels_last if p.channels_last else torch.contiguous_format
        model = model.to(memory_format=fmt).train()  # type: ignore[call-overload]  # the stubs omit memory_format
        opt = torch.optim.Adam(model.parameters(), lr=p.lr)
        setups[n] = (p, ds, model, opt, fmt)
    for r in range(rounds + 1):  # round 0 warms up
        for n in names:
            p, ds, model, opt, fmt = setups[n]
            t0 = time.perf_counter()
            t_data = 0.0
            for s in range(steps):
                t1 = time.perf_counter()
                batch = [ds[(s * p.batch_size + j) % len(ds)] for j in range(p.batch_size)]
                x = torch.stack([b["image"] for b in batch]).contiguous(memory_format=fmt)
                y = torch.stack([b["mask"] for b in batch])
                t_data += time.perf_counter() - t1
                opt.zero_grad(set_to_none=True)
                torch.nn.functional.cross_entropy(model(x), y, ignore_index=defaults.IGNORE_INDEX).backward()
                opt.step()
            if r:
                elapsed = time.perf_counter() - t0
                rates[n].append(steps * p.batch_size / elapsed)
                data_share[n].append(t_data / elapsed)
        if r:
            print(f"round {r}: " + ", ".join(f"{n} {rates[n][-1]:.1f}" for n in names), flush=True)
    for n in names:
        print(
            f"{n}: median {statistics.median(rates[n]):.1f} images/s, reading and preparing the samples "
            f"{100 * statistics.median(data_share[n]):.0f} % of a step"
        )
    return {n: statistics.median(v) for n, v in rates.items()}


def write_report(out: Path, n_train: int) -> None:
    results = json.loads((out / "results.json").read_text()) if (out / "results.json").exists() else {}
    rates = json.loads((out / "throughput.json").read_text()) if (out / "throughput.json").exists() else {}
    lines = [
        (
            "| variant | change | epochs | val PA | val mIoU | UA V/C % | UA PA | UA mIoU | UA precision "
            "| UA sensitivity "
            "| precision @ V/C 50 % | sensitivity @ V/C 50 % | UA precision 7 cm (V/C %) "
            "| risk:0.05 sensitivity (in-sample) "
            "| images/s | s for the budget |"
        ),
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        v = r["validation"]
        change = " + ".join(VARIANTS[p][0] for p in _parts(name)) if name != "reference" else VARIANTS["reference"][0]
        rate = rates.get(name)
        secs = f"{r['epochs'] * n_train / rate:.0f}" if rate else "-"
        lines.append(
            f"| {name} | {change} | {r['epochs']} | {v['base_pa']:.4f} | {v['base_miou']:.4f} | "
            f"{100 * v['ua_vc']:.0f} | "
            f"{v['ua_pa']:.4f} | {v['ua_miou']:.4f} | {v['ua_precision']:.4f} | {v['ua_sensitivity']:.4f} | "
            f"{v['q_precision']:.4f} | {v['q_sensitivity']:.4f} | {_at7(v)} | {_get(v, 'risk_sensitivity')} | "
            f"{f'{rate:.1f}' if rate else '-'} | {secs} |"
        )
    with OutputTransaction(out, "ablation", wait_s=LOCK_WAIT_S):
        write_text_atomic(out / "ablation.md", "\n".join(lines) + "\n")
        if results:
            _figure(out, results)
    print("\n".join(lines))


def _get(v: dict[str, float], key: str) -> str:
    return f"{v[key]:.4f}" if key in v else "-"


def _at7(v: dict[str, float]) -> str:
    if "ua_precision@7cm" not in v:
        return "-"
    return f"{v['ua_precision@7cm']:.4f} ({100 * v['ua_vc@7cm']:.0f})"


def _figure(out: Path, results: dict[str, Any]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), sharex=True)
    for name, r in results.items():
        epochs = [h["epoch"] for h in r["history"]]
        style = "-" if name != "reference" else "k--"
        axes[0].plot(epochs, [h["val_pixel_accuracy"] for h in r["history"]], style, label=name, lw=1.2)
        axes[1].plot(epochs, [h.get("val_miou", float("nan")) for h in r["history"]], style, label=name, lw=1.2)
    axes[0].set_ylabel("validation pixel accuracy (dropout off)")
    axes[1].set_ylabel("validation mIoU (dropout off)")
    for ax in axes:
        ax.set_xlabel("epoch")
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=7, loc="lower right", ncol=2)
    fig.tight_layout()
    with atomic_path(out / "learning_curves.png") as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--epochs", type=int, default=20)
    parser.add_argument(
        "--variants",
        default=",".join(VARIANTS),
        help="comma-separated variants; a combination of levers is written with '+' between names, e.g. median+d4",
    )
    parser.add_argument("--labels", default=None, help="labelling to train on (when the dataset has several)")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    parser.add_argument(
        "--throughput", action="store_true", help="measure images/s of the variants instead of training"
    )
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--steps", type=int, default=4, help="training steps per variant and round (--throughput)")
    parser.add_argument("--report", action="store_true", help="only rewrite the table and the figure")
    parser.add_argument("--rescore", action="store_true", help="score the variants' finished runs again (no training)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    names = [n for n in args.variants.split(",") if n]
    for n in names:
        _parts(n)
    n_train = len(
        HazardDataset(
            args.dataset,
            "train",
            defaults.TRAIN_SIGMA_M,
            labels=args.labels,
            input_spec=input_spec_for(REFERENCE, 1.0, Normalisation(0.0, 1.0)),
        )
    )
    if args.report:
        write_report(args.out, n_train)
        return
    if args.throughput:
        rates = throughput(args.dataset, names, args.rounds, args.steps, args.labels)
        path = args.out / "throughput.json"
        with OutputTransaction(args.out, "ablation", wait_s=LOCK_WAIT_S):
            previous = json.loads(path.read_text()) if path.exists() else {}
            write_json_atomic(path, {**previous, **rates})
        write_report(args.out, n_train)
        return
    for name in names:
        t0 = time.perf_counter()
        path = args.out / "results.json"
        if args.rescore:
            result = json.loads(path.read_text())[name]
            result["validation"] = validation_summary(
                args.out / "runs" / name, args.dataset, labels=args.labels, other_sigmas_m=OTHER_SIGMAS_M
            )
        else:
            result = train_and_score(args.dataset, args.out, name, args.epochs, args.labels)
        with OutputTransaction(args.out, "ablation", wait_s=LOCK_WAIT_S):  # parallel instances share the file
            previous = json.loads(path.read_text()) if path.exists() else {}
            previous[name] = result
            write_json_atomic(path, previous, indent=1)
        v = result["validation"]
        print(
            f"{name}: {time.perf_counter() - t0:.0f} s; val PA {v['base_pa']:.4f} mIoU {v['base_miou']:.4f} | "
            f"UA V/C {v['ua_vc']:.2f} prec {v['ua_precision']:.4f} sens {v['ua_sensitivity']:.4f} | "
            f"@50% prec {v['q_precision']:.4f} sens {v['q_sensitivity']:.4f}",
            flush=True,
        )
    write_report(args.out, n_train)


if __name__ == "__main__":
    main()
