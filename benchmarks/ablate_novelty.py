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

With ``--density-quantile Q`` a third candidate joins them: the density of the pixels' features
(class-conditional Gaussians fitted on the run's training split at that level, DDU's density,
Mukhoti et al. 2023; read at ``--feature-layer``: the classifier's input or the first or second
encoder block, as the Mahalanobis detector of Lee et al. 2018), alone (a pixel novel when its
-log p is at or above the quantile Q of the home validation split's) and added to each score (a pixel
uncertain when either says so).

The score with the higher held-out precision at a V/C of at least ``--min-vc`` is chosen; the table
says by how much. Prints a markdown table (docs/results.md, "Landing safety").

Usage::

    python benchmarks/ablate_novelty.py RUN --home DATASET --heldout DATASET --labels NAME [--sigma 0.0167 ...]
        [--density-quantile 0.99 --feature-layer enc1]
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
from hdnet.data import HazardDataset
from hdnet.evaluate import checkpoint_path, infer_split, score, split_dataset
from hdnet.model import BayesianSegNet
from hdnet.results import SplitInference
from hdnet.trained_run import TrainedRun
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


# Where the density reads the network's features: the classifier's input (the last decoder unit, as
# DDU), or the output of the first / second encoder block (the Mahalanobis detector of Lee et al. 2018
# reads several depths; early blocks describe the local relief itself).
FEATURE_LAYERS = ("classifier-input", "enc1", "enc2")


@torch.no_grad()
def pixel_features(model: BayesianSegNet, ds: HazardDataset, layer: str, batch_size: int = 8) -> np.ndarray:
    """The features of every DEM pixel of ``ds`` at ``layer`` (one of FEATURE_LAYERS), deterministic
    (dropout off), a coarser block's brought to the input grid by nearest neighbour: (N, H, W, C)
    float32, on the DEM grid."""
    feats: list[torch.Tensor] = []
    if layer == "classifier-input":
        hook = model.classifier.register_forward_hook(lambda _m, args, _o: feats.append(args[0]))
    else:
        hook = getattr(model, layer).register_forward_hook(lambda _m, _a, output: feats.append(output))
    was = model.training
    model.eval()
    out = []
    try:
        for start in range(0, len(ds), batch_size):
            idx = range(start, min(len(ds), start + batch_size))
            x = torch.stack([ds.prepare(ds.dem_sample(i))["image"] for i in idx])
            feats.clear()
            model(x)
            f = feats[0]
            size = model.size_multiple * -(-x.shape[-1] // model.size_multiple)
            if f.shape[-1] != size:
                f = torch.nn.functional.interpolate(f, scale_factor=size // f.shape[-1], mode="nearest")
            f = ds.to_dem_grid(f[..., : x.shape[-2], : x.shape[-1]])
            out.append(f.permute(0, 2, 3, 1).numpy().astype(np.float32))
    finally:
        hook.remove()
        model.train(was)
    return np.concatenate(out)


class FeatureDensity:
    """Class-conditional Gaussians of the pixels' features on the training split (Gaussian
    discriminant analysis, the density of DDU: Mukhoti et al. 2023); ``score`` = -log p(feature), nats
    (high: a pixel unlike the training pixels)."""

    def __init__(self, features: np.ndarray, labels: np.ndarray, valid: np.ndarray, per_image: int, seed: int) -> None:
        rng = np.random.default_rng(seed)
        xs, ys = [], []
        for f, lab, v in zip(features, labels, valid, strict=True):
            rows, cols = np.nonzero(v)
            pick = rng.choice(len(rows), size=min(per_image, len(rows)), replace=False)
            xs.append(f[rows[pick], cols[pick]])
            ys.append(lab[rows[pick], cols[pick]])
        x, y = np.concatenate(xs).astype(np.float64), np.concatenate(ys)
        self.parts = []
        dim = x.shape[1]
        for c in np.unique(y):
            xc = x[y == c]
            mu = xc.mean(axis=0)
            cov = np.cov(xc, rowvar=False) + 1e-6 * np.trace(np.cov(xc, rowvar=False)) / dim * np.eye(dim)
            chol = np.linalg.cholesky(cov)
            log_det = 2.0 * np.log(np.diag(chol)).sum()
            self.parts.append((np.log(len(xc) / len(x)), mu, chol, log_det))

    def score(self, features: np.ndarray) -> np.ndarray:
        """-log p(f) per pixel (nats, up to a constant) of features (..., C)."""
        shape, dim = features.shape[:-1], features.shape[-1]
        f = features.reshape(-1, dim).astype(np.float64)
        logs = []
        for log_prior, mu, chol, log_det in self.parts:
            z = np.linalg.solve(chol, (f - mu).T)
            logs.append(log_prior - 0.5 * (np.sum(z * z, axis=0) + log_det + dim * np.log(2 * np.pi)))
        return (-np.logaddexp.reduce(np.stack(logs), axis=0)).reshape(shape).astype(np.float32)


def rows_for(
    inf: SplitInference, thresholds: dict[str, float], density: np.ndarray | None = None, density_t: float = np.inf
) -> list[tuple[str, float, float, float, float]]:
    """(score, V/C, precision, sensitivity, AUROC) of each score's uncertainty-aware map, and the base net;
    with ``density`` (-log p of the pixels' features) also the density alone and each score with it (a
    pixel uncertain when either is at or above its threshold)."""
    v = inf.valid
    wrong = (inf.prediction != inf.label)[v]
    out = []
    base = score(inf.label, inf.prediction, inf.ignore)
    out.append(("base net", 1.0, base.precision_safe, base.sensitivity_safe, float("nan")))
    masks: list[tuple[str, np.ndarray, np.ndarray | None]] = []
    for name, h_t in thresholds.items():
        of_score = SCORES[name].of(inf)
        masks.append((name, of_score >= h_t, of_score))
    if density is not None:
        novel = density >= density_t
        masks.append(("density", novel, density))
        masks += [(f"{name} + density", m | novel, None) for name, m, _ in masks[:-1]]
    for name, mask, values in masks:
        m = score(inf.label, inf.prediction, inf.ignore, mask)
        auc = auroc(values[v], wrong) if values is not None else float("nan")
        out.append((name, float(m.vc_fraction or 0.0), m.precision_safe, m.sensitivity_safe, auc))
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
    parser.add_argument(
        "--density-quantile",
        type=float,
        default=0.0,
        help="also the feature density: its threshold the quantile Q of -log p on the home validation split "
        "(0: not computed)",
    )
    parser.add_argument("--feature-layer", choices=FEATURE_LAYERS, default=FEATURE_LAYERS[0])
    args = parser.parse_args()
    sigmas = args.sigma or [0.0167, 0.03, 0.07]
    device = torch.device("cpu")
    ckpt = checkpoint_path(args.run)
    run = TrainedRun.load(ckpt, device)
    model, spec = run.model, run.data.input
    print(f"run {args.run} ({run.header.profile}), home {args.home}, held-out {args.heldout}")
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, M = {args.mc_samples}\n")
    print("| test σ | split | score | V/C % | precision | sensitivity | AUROC of errors |")
    print("|---|---|---|---|---|---|---|")
    chosen: dict[str, list[float]] = {}
    for sigma in sigmas:
        t0 = time.perf_counter()
        home_ds = split_dataset(args.home, "val", sigma, labels=args.labels, input_spec=spec)
        held_ds = split_dataset(args.heldout, "val", sigma, labels=args.labels, input_spec=spec)
        home = infer_split(model, home_ds, args.mc_samples, 8, 0, device)
        v = home.valid
        thresholds = {name: float(np.quantile(SCORES[name].of(home)[v], args.quantile)) for name in SCORES}
        held = infer_split(model, held_ds, args.mc_samples, 8, 0, device)
        densities: dict[str, np.ndarray | None] = {"home": None, "held": None}
        density_t = float("inf")
        if args.density_quantile > 0:
            train_ds = split_dataset(args.home, "train", sigma, labels=args.labels, input_spec=spec)
            train_samples = [train_ds.dem_sample(i) for i in range(len(train_ds))]
            train_inf_valid = np.stack([~s.ignore for s in train_samples])
            train_labels = np.stack([s.label for s in train_samples])
            fitted = FeatureDensity(
                pixel_features(model, train_ds, args.feature_layer), train_labels, train_inf_valid, 64, 0
            )
            home_density = fitted.score(pixel_features(model, home_ds, args.feature_layer))
            densities = {"home": home_density, "held": fitted.score(pixel_features(model, held_ds, args.feature_layer))}
            density_t = float(np.quantile(home_density[v], args.density_quantile))
        for split, key, inf in (("home val (calibration)", "home", home), ("held-out val", "held", held)):
            for name, vc, prec, sens, auc in rows_for(inf, thresholds, densities[key], density_t):
                print(
                    f"| {sigma * 100:.3g} cm | {split} | {name} | {100 * vc:.0f} | {prec:.3f} | {sens:.3f} | "
                    f"{DASH if np.isnan(auc) else f'{auc:.3f}'} |"
                )
                if split == "held-out val" and name != "base net":
                    chosen.setdefault(name, []).append(prec if vc >= args.min_vc else float("nan"))
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
