"""Pixel agreement of a paper-convention labelling with the paper's own ALHAT replica (pydem e7734ae).

For every scan of a labelled dataset (or the first ``--scans``), the stored clean DEM goes through
pydem's ``dhd`` (deterministic labels) and every stored noisy DEM through its ``alhat`` (P(safe)),
in pydem's own environment (see ``benchmarks/reference_pydem.py`` for the throw-away set-up), and
the results are compared with the stored labels and P(safe):

* valid masks: the fraction of all pixels on which both agree (valid or invalid);
* labels: the fraction of pixels valid in both with the same safe/unsafe label;
* baseline: per noise level, the fraction of pixels valid in both with the same P(safe) >= 0.5
  decision, and the largest |P - P_ref|;
* the first differing pixels of each map, with hd's slope and roughness (labels) or both P(safe).

    .venv/bin/python scripts/compare_reference.py DATASET --reference-python /tmp/pydem-venv/bin/python \\
        --reference-src /tmp/pydem [--labels NAME] [--scans 200]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hdlabels.defaults import LABEL_INVALID, LABEL_SAFE, SAFE_PROBABILITY_THRESHOLD
from hdlabels.store import LabelShardReader, find_labeling

RUNNER = Path(__file__).resolve().parents[1] / "benchmarks" / "reference_pydem.py"
MAX_SHOWN = 10  # differing pixels listed per map, with the values that decide them


def stored(dataset: Path, labels: str | None, n_scans: int | None) -> dict[str, np.ndarray]:
    """DEMs, labels, slope, roughness and P(safe) of the labelling, stacked over scans."""
    entry = find_labeling(dataset, labels)
    if entry.convention != "paper":
        raise SystemExit(f"{entry.name} is not a paper-convention labelling")
    keys = ("dem_clean", "dem_noisy", "label", "slope_rad", "roughness_m", "p_safe")
    out: dict[str, list[np.ndarray]] = {k: [] for k in keys}
    sigmas: tuple[float, ...] = ()
    for path in entry.shard_paths(dataset):
        with LabelShardReader(path) as reader:
            sigmas = reader.sigmas_m
            for k in keys:
                out[k].append(reader.h5[k][:])
    arrays = {k: np.concatenate(v)[:n_scans] for k, v in out.items()}
    arrays["sigmas"] = np.asarray(sigmas)
    return arrays


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--reference-python", required=True, help="python of pydem's throw-away environment")
    parser.add_argument("--reference-src", required=True, help="pydem checkout at commit e7734ae")
    parser.add_argument("--labels", default=None, help="labelling name (when the dataset has several)")
    parser.add_argument("--scans", type=int, default=None, help="compare the first N scans only")
    args = parser.parse_args()
    ours = stored(args.dataset, args.labels, args.scans)
    with tempfile.TemporaryDirectory() as tmp:
        inputs, outputs = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        np.savez(inputs, dems=ours["dem_clean"], noisy=ours["dem_noisy"], sigmas=ours["sigmas"])
        subprocess.run(
            [args.reference_python, str(RUNNER), str(inputs), str(outputs), "--src", args.reference_src],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        ref = dict(np.load(outputs))
    valid = ours["label"] != LABEL_INVALID
    both = valid & ref["valid"]
    n = ours["label"].shape[0]
    print(f"{args.dataset}: {n} scans, {both.sum():,} pixels valid in both of {valid.size:,}")
    print(
        f"valid masks agree on {np.mean(valid == ref['valid']) * 100:.3f}% of all pixels "
        f"({(valid != ref['valid']).sum()} differ) "
        f"(hd valid {valid.mean() * 100:.2f}%, reference valid {ref['valid'].mean() * 100:.2f}%)"
    )
    same = (ours["label"] == LABEL_SAFE) == (ref["label"] == 1)
    print(
        f"deterministic labels agree on {same[both].mean() * 100:.3f}% of pixels valid in both "
        f"({(~same[both]).sum()} differ) "
        f"(safe: hd {np.mean(ours['label'][both] == LABEL_SAFE) * 100:.2f}%, "
        f"reference {np.mean(ref['label'][both] == 1) * 100:.2f}%)"
    )
    for k, i, j in np.argwhere(both & ~same)[:MAX_SHOWN]:
        hd_safe, ref_safe = ours["label"][k, i, j] == LABEL_SAFE, ref["label"][k, i, j] == 1
        slope, rough = np.degrees(ours["slope_rad"][k, i, j]), ours["roughness_m"][k, i, j]
        print(
            f"  differs at scan row {k}, pixel ({i}, {j}): hd {'safe' if hd_safe else 'unsafe'} (slope {slope:.6f} "
            f"deg, roughness {rough:.7f} m), reference {'safe' if ref_safe else 'unsafe'}"
        )
    for s, sigma in enumerate(ours["sigmas"]):
        p, pr = ours["p_safe"][:, s], ref["p"][:, s]
        ok = both & np.isfinite(p) & np.isfinite(pr)
        agree = (p >= SAFE_PROBABILITY_THRESHOLD) == (pr >= SAFE_PROBABILITY_THRESHOLD)
        print(
            f"baseline sigma {sigma * 100:g} cm: P >= 0.5 agrees on {agree[ok].mean() * 100:.3f}% of pixels valid "
            f"in both ({(~agree[ok]).sum()} differ; safe: hd {np.mean(p[ok] >= 0.5) * 100:.2f}%, "
            f"reference {np.mean(pr[ok] >= 0.5) * 100:.2f}%); "
            f"max |P - P_ref| = {np.abs(p - pr)[ok].max():.2e}"
        )
        for k, i, j in np.argwhere(ok & ~agree)[:MAX_SHOWN]:
            print(f"  differs at scan row {k}, pixel ({i}, {j}): P hd {p[k, i, j]:.7f}, reference {pr[k, i, j]:.7f}")


if __name__ == "__main__":
    main()
