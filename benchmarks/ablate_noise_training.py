"""Ablation of training across noise levels: each lever trained in full, judged on the validation split.

Every variant is the cpu profile trained across 0 to 10 cm of range noise (``--train-sigma-range
0:0.10``) with one or more fields changed (``VARIANTS``), trained with ``hdnet.fit`` for the
profile's 40 epochs. Each is scored on the validation split of the dataset at the levels of
``SIGMAS_M`` (stored levels read, others made from the clean points) with MC dropout (M = 8):

* base net pixel accuracy;
* the uncertainty-aware map's precision where its sensitivity reaches 0.6 (the best precision any
  entropy threshold gives at that sensitivity: the quality of the network's ranking);
* precision / sensitivity / V/C at the rule's threshold (``ROBUST_THRESHOLD_SPEC``, a quantile of
  the validation entropies at the same level: ``--calibrate each``; in-sample here).

The test split is never read. Outputs in ``--out``: ``runs/<variant>/`` (normal run directories)
and ``ablation.md`` (the table).

Usage::

    python benchmarks/ablate_noise_training.py DATASET --out noise-ablation [--variants a,b] [--threads 2]
    python benchmarks/ablate_noise_training.py DATASET --out noise-ablation --report
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hdcore.storage import OutputTransaction, write_json_atomic, write_text_atomic
from hdnet.evaluate import checkpoint_path, infer_split, score, split_dataset
from hdnet.fit import FitConfig, fit
from hdnet.noise_levels import TrainingNoise
from hdnet.profiles import CPU, ROBUST_THRESHOLD_SPEC
from hdnet.results import SplitInference
from hdnet.run_record import checkpoint_data
from hdnet.thresholds import EntropyCalibration, select_threshold
from hdnet.train import load_trained_model, median_images_per_s

RANGE_M = (0.0, 0.10)
SIGMAS_M = (0.0167, 0.03, 0.07, 0.10, 0.12)
TARGET_SENSITIVITY = 0.6

# name -> (what changes, overrides of the cpu profile)
VARIANTS: dict[str, tuple[str, dict[str, Any]]] = {
    "range": ("the cpu profile trained across 0-10 cm", {}),
    "range_sigma": ("+ the noise level as an input channel", {"extra_channels": ("slope", "highpass", "sigma")}),
    "width075_sigma": (
        "+ width 3/4 (the robust profile)",
        {"extra_channels": ("slope", "highpass", "sigma"), "width": 0.75},
    ),
    "width075_sigma_bf16_fastmasks": (
        "the robust profile with bfloat16 autocast and fast dropout masks (its training speed-up)",
        {
            "extra_channels": ("slope", "highpass", "sigma"),
            "width": 0.75,
            "precision": "bfloat16",
            "fast_dropout": True,
        },
    ),
    "width1_sigma": ("+ width 1", {"extra_channels": ("slope", "highpass", "sigma"), "width": 1.0}),
    "depth3_sigma": ("+ three pooling stages", {"extra_channels": ("slope", "highpass", "sigma"), "depth": 3}),
}


def precision_at_sensitivity(inf: SplitInference, sensitivity: float) -> float:
    """The precision of the certain predicted-safe pixels at the loosest entropy threshold whose
    sensitivity reaches ``sensitivity`` (the network's ranking quality, independent of the rule)."""
    v = inf.valid
    truth, pred, ent = inf.label[v], inf.prediction[v], inf.entropy_nats[v]
    order = np.argsort(ent, kind="stable")
    safe_pred = pred[order] == 1
    tp = np.cumsum(safe_pred & (truth[order] == 1))
    fp = np.cumsum(safe_pred & (truth[order] == 0))
    k = int(np.searchsorted(tp, sensitivity * (truth == 1).sum()))
    if k >= tp.size:
        return float("nan")
    return float(tp[k] / max(tp[k] + fp[k], 1))


def summarise(run: Path, dataset: Path) -> dict[str, float]:
    """The validation numbers of one run (see the module docstring)."""
    path = checkpoint_path(run)
    model, ckpt = load_trained_model(path, map_location="cpu")
    data = checkpoint_data(ckpt, path)
    spec, labels = data.input, data.labels
    out: dict[str, float] = {"val_loss": float(ckpt["history"][-1]["val_loss"])}
    out["images_per_s"] = float(median_images_per_s(ckpt.get("timing", [])) or float("nan"))
    for sigma in SIGMAS_M:
        inf = infer_split(
            model, split_dataset(dataset, "val", sigma, labels=labels, input_spec=spec), 8, 8, 0, torch.device("cpu")
        )
        cal = EntropyCalibration()
        cal.update(torch.from_numpy(inf.entropy_nats), torch.from_numpy(inf.prediction), torch.from_numpy(inf.label))
        h = select_threshold(ROBUST_THRESHOLD_SPEC, cal)
        base = score(inf.label, inf.prediction, inf.ignore)
        ua = score(inf.label, inf.prediction, inf.ignore, inf.entropy_nats >= h)
        tag = f"@{sigma * 100:.3g}cm"
        out[f"base_pa{tag}"] = base.pixel_accuracy
        out[f"precision_at_sens{tag}"] = precision_at_sensitivity(inf, TARGET_SENSITIVITY)
        out[f"rule_precision{tag}"] = ua.precision_safe
        out[f"rule_sensitivity{tag}"] = ua.sensitivity_safe
        out[f"rule_vc{tag}"] = float(ua.vc_fraction or 0.0)
    return out


def write_report(out: Path) -> None:
    results = json.loads((out / "results.json").read_text())
    intro = (
        f"Validation split, M = 8; every variant trained across {RANGE_M[0] * 100:g}-{RANGE_M[1] * 100:g} cm "
        f"for 40 epochs. Precision at sensitivity {TARGET_SENSITIVITY}: the best any entropy threshold gives. "
        f"Rule: {ROBUST_THRESHOLD_SPEC} of the validation entropies at the same level."
    )
    header = (
        "| variant | what | val loss | base PA 1.67 / 3 / 7 cm | prec. at sens. 0.6, 7 cm | "
        "rule at 7 cm: V/C / prec. / sens. | prec. at sens. 0.6, 10 / 12 cm | images/s |"
    )
    lines = [intro, "", header, "|---|---|---|---|---|---|---|---|"]
    for name, r in results.items():
        lines.append(
            f"| {name} | {VARIANTS.get(name, ('?', {}))[0]} | {r['val_loss']:.4f} | "
            f"{r['base_pa@1.67cm']:.3f} / {r['base_pa@3cm']:.3f} / {r['base_pa@7cm']:.3f} | "
            f"{r['precision_at_sens@7cm']:.3f} | {r['rule_vc@7cm'] * 100:.0f} % / {r['rule_precision@7cm']:.3f} / "
            f"{r['rule_sensitivity@7cm']:.3f} | {r['precision_at_sens@10cm']:.3f} / "
            f"{r['precision_at_sens@12cm']:.3f} | {r['images_per_s']:.0f} |"
        )
    with OutputTransaction(out, "ablation"):
        write_text_atomic(out / "ablation.md", "\n".join(lines) + "\n")
    print("\n".join(lines))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--labels", default=None, help="the labelling to train on (when the dataset has several)")
    parser.add_argument("--report", action="store_true", help="only rewrite ablation.md from results.json")
    args = parser.parse_args()
    if args.report:
        write_report(args.out)
        return
    torch.set_num_threads(args.threads)
    path = args.out / "results.json"
    results = json.loads(path.read_text()) if path.exists() else {}
    noise = TrainingNoise(range_m=RANGE_M)
    for name in args.variants.split(","):
        profile = replace(CPU, name=f"noise-{name}", **VARIANTS[name][1])
        run = args.out / "runs" / name
        fit(
            args.dataset,
            run,
            FitConfig(profile=profile, train_noise=noise, resume=True, progress=False, labels=args.labels),
        )
        results[name] = summarise(run, args.dataset)
        with OutputTransaction(args.out, "ablation"):
            write_json_atomic(path, results)
        print(name, json.dumps({k: round(v, 4) for k, v in results[name].items()}), flush=True)
    write_report(args.out)


if __name__ == "__main__":
    main()
