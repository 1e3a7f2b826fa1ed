"""Markdown tables of docs/results.md, "Landing safety", from the reports of ``hd eval``.

Each ``NAME=REPORT_DIR`` is one evaluated run (its ``report.json``). Printed, for every report:
the landing table (method x test sigma x navigation dispersion, per truth: P(safe landing) with its
95 % interval, abstentions with theirs, touchdowns on unknown ground, clearance in the map and in the
truth) and the pixel rows of Table 1 (scored against the labelling the report was made with).
Nothing is typed by hand: regenerate the tables whenever the science changes.

Usage::

    python scripts/landing_tables.py "terrain-trained=eval-terrain" "clean-trained=eval-clean"
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

DASH = "\u2013"
METHODS = {"alhat_baseline": "ALHAT baseline", "base_net": "base net", "uncertainty_aware": "uncertainty-aware"}


def _num(x: float | None, digits: int = 3) -> str:
    return DASH if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def _cm(sigma_m: float) -> str:
    return f"{sigma_m * 100:.3g} cm"


def landing_table(name: str, report: dict[str, Any], truth: str) -> list[str]:
    """One truth's landing rows of one report, one line per method and test sigma, one column per
    navigation dispersion: P(safe landing) [its 95 % lower bound] and the abstain rate."""
    rows = [r for r in report.get("landing", []) if r["truth"] == truth]
    navs = sorted({r["nav_sigma_m"] for r in rows})
    lines = [
        "| run | method | test σ | scenes | "
        + " | ".join(f"nav. {n:g} m: P(safe landing) [95 % low] · abstain %" for n in navs)
        + " |",
        "|---|---|---|---|" + "---|" * len(navs),
    ]
    keys = list(dict.fromkeys((r["method"], r["test_sigma_m"]) for r in rows))
    for method, sigma in keys:
        cells = []
        scenes = 0
        for n in navs:
            r = next(x for x in rows if (x["method"], x["test_sigma_m"], x["nav_sigma_m"]) == (method, sigma, n))
            scenes = r["scenes"]
            p = DASH if not r["landed"] else f"{_num(r['p_safe'], 4)} [{_num(r['p_safe_low'], 4)}]"
            cells.append(f"{p} · {100 * r['abstain_rate']:.1f}")
        lines.append(
            f"| {name} | {METHODS.get(method, method)} | {_cm(sigma)} | {scenes} | " + " | ".join(cells) + " |"
        )
    return lines


def pixel_table(name: str, report: dict[str, Any]) -> list[str]:
    """Table 1's rows of one report (against the labelling it was evaluated with)."""
    truth = report["run"].get("truth", "clean-scan")
    lines = [
        f"Pixels against the {truth} truth:",
        "",
        "| run | method | test σ | V/C % | PA | mIoU | precision | sensitivity |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in report["rows"]:
        if r["table"] != "noise":
            continue
        vc = DASH if r["vc_fraction"] is None else f"{100 * r['vc_fraction']:.0f}"
        lines.append(
            f"| {name} | {METHODS.get(r['method'], r['method'])} | {_cm(r['test_sigma_m'])} | {vc} | "
            f"{_num(r['pixel_accuracy'])} | {_num(r['miou'])} | {_num(r['precision'])} | {_num(r['sensitivity'])} |"
        )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("reports", nargs="+", help="NAME=REPORT_DIR")
    args = parser.parse_args()
    reports = []
    for item in args.reports:
        name, _, path = item.partition("=")
        reports.append((name, json.loads((Path(path) / "report.json").read_text())))
    for truth in ("terrain", "clean-scan"):
        tables = [landing_table(name, rep, truth) for name, rep in reports]
        rows = [line for t in tables for line in t[2:]]
        if rows:
            print(f"### Landing against the {truth} truth\n")
            print("\n".join(tables[0][:2] + rows) + "\n")
    for name, rep in reports:
        print("\n".join(pixel_table(name, rep)) + "\n")


if __name__ == "__main__":
    main()
