"""Which uncertainty score sees a new terrain: predictive entropy or mutual information, chosen on a held-out terrain.

The choice between the two scores of ``hdnet.uncertainty`` is made on the **validation split of a
terrain the run never saw** (never on held-out scans of its training terrain, which share its
ground). One MC-dropout pass per split gives both scores (``hdnet.evaluate.infer_split``):

1. per noise level, the threshold of each score is calibrated as the run's rule does (the
   ``--quantile`` of the score over the valid pixels of the run's own validation split at that level,
   ``hd eval --threshold quantile:Q --calibrate each``);
2. on the held-out terrain's validation split at the same level, the uncertainty-aware map of each
   score is scored against the held-out labelling (V/C, precision and sensitivity of "safe"), with
   the base net beside it, and the score's AUROC for telling the base net's wrong pixels from its
   right ones (how well the score ranks errors, whatever the threshold).

The score with the higher held-out precision at a V/C of at least ``--min-vc`` is chosen; the table
says by how much. Prints a markdown table (docs/results.md, "Landing safety").

Usage::

    python benchmarks/ablate_novelty.py RUN --home DATASET --heldout DATASET --labels NAME [--sigma 0.0167 ...]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hdnet import defaults
from hdnet.evaluate import checkpoint_path, infer_split, run_data, score, split_dataset
from hdnet.results import SplitInference
from hdnet.train import load_trained_model
from hdnet.uncertainty import SCORES

DASH = "\u2013"  # the tables' "no value"


def auroc(scores: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve of ``scores`` for ``positive`` (ties counted half): the probability that
    a random positive scores above a random negative."""
    s, p = np.asarray(scores, np.float64), np.asarray(positive, bool)
    n_pos, n_neg = int(p.sum()), int((~p).sum())
    if not n_pos or not n_neg:
        return float("nan")
    order = np.argsort(s, kind="mergesort")
    ranks = np.empty(len(s))
    sorted_s = s[order]
    # average ranks of ties
    _, first, counts = np.unique(sorted_s, return_index=True, return_counts=True)
    avg = first + (counts - 1) / 2.0 + 1.0
    ranks[order] = np.repeat(avg, counts)
    return float((ranks[p].sum() - n_pos * (n_pos + 1) / 2.0) / (n_pos * n_neg))


def rows_for(inf: SplitInference, thresholds: dict[str, float]) -> list[tuple[str, float, float, float, float]]:
    """(score, V/C, precision, sensitivity, AUROC) of each score's uncertainty-aware map, and the base net."""
    v = inf.valid
    wrong = (inf.prediction != inf.label)[v]
    out = []
    base = score(inf.label, inf.prediction, inf.ignore)
    out.append(("base net", 1.0, base.precision_safe, base.sensitivity_safe, float("nan")))
    for name, h_t in thresholds.items():
        values = SCORES[name].of(inf)
        m = score(inf.label, inf.prediction, inf.ignore, values >= h_t)
        out.append((name, float(m.vc_fraction or 0.0), m.precision_safe, m.sensitivity_safe, auroc(values[v], wrong)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("run", type=Path)
    parser.add_argument(
        "--home", type=Path, required=True, help="the run's own dataset (its validation split calibrates)"
    )
    parser.add_argument("--heldout", type=Path, required=True, help="a dataset of a terrain the run never saw")
    parser.add_argument("--labels", required=True, help="the labelling (same name in both datasets)")
    parser.add_argument("--sigma", type=float, action="append", help="noise levels, metres (default: 1.67, 3, 7 cm)")
    parser.add_argument("--quantile", type=float, default=0.68, help="the rule's quantile (robust profile: 0.68)")
    parser.add_argument("--mc-samples", type=int, default=defaults.MC_SAMPLES)
    parser.add_argument("--min-vc", type=float, default=0.5)
    args = parser.parse_args()
    sigmas = args.sigma or [0.0167, 0.03, 0.07]
    device = torch.device("cpu")
    ckpt = checkpoint_path(args.run)
    model, data = load_trained_model(ckpt, map_location=device)
    _, spec, _ = run_data(data, ckpt)
    print(f"run {args.run} ({data.get('profile', {}).get('name')}), home {args.home}, held-out {args.heldout}")
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, M = {args.mc_samples}\n")
    print("| test σ | split | score | V/C % | precision | sensitivity | AUROC of errors |")
    print("|---|---|---|---|---|---|---|")
    chosen: dict[str, list[float]] = {name: [] for name in SCORES}
    for sigma in sigmas:
        t0 = time.perf_counter()
        home = infer_split(
            model,
            split_dataset(args.home, "val", sigma, labels=args.labels, input_spec=spec),
            args.mc_samples,
            8,
            0,
            device,
        )
        v = home.valid
        thresholds = {name: float(np.quantile(SCORES[name].of(home)[v], args.quantile)) for name in SCORES}
        held = infer_split(
            model,
            split_dataset(args.heldout, "val", sigma, labels=args.labels, input_spec=spec),
            args.mc_samples,
            8,
            0,
            device,
        )
        for split, inf in (("home val (calibration)", home), ("held-out val", held)):
            for name, vc, prec, sens, auc in rows_for(inf, thresholds):
                print(
                    f"| {sigma * 100:.3g} cm | {split} | {name} | {100 * vc:.0f} | {prec:.3f} | {sens:.3f} | "
                    f"{DASH if np.isnan(auc) else f'{auc:.3f}'} |"
                )
                if split == "held-out val" and name in chosen:
                    chosen[name].append(prec if vc >= args.min_vc else float("nan"))
        print(f"<!-- {sigma * 100:.3g} cm: {time.perf_counter() - t0:.0f} s -->")
    means = {name: float(np.nanmean(v)) if v else float("nan") for name, v in chosen.items()}
    best = max(means, key=lambda k: -np.inf if np.isnan(means[k]) else means[k])
    print(
        f"\nmean held-out precision at V/C >= {args.min_vc:.0%}: "
        + ", ".join(f"{k} {v:.4f}" for k, v in means.items())
        + f"; chosen: {best}"
    )


if __name__ == "__main__":
    main()
