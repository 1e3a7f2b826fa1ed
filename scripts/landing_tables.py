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
    """One truth's landing rows of one report."""
    lines = [
        (
            "| run | method | test σ | nav. 1σ | P(safe landing) [95 % CI] | abstain % [95 % CI] | unknown % | "
            "clearance map / truth (m) |"
        ),
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in report.get("landing", []):
        if r["truth"] != truth:
            continue
        p = (
            DASH
            if not r["landed"]
            else f"{_num(r['p_safe'], 4)} [{_num(r['p_safe_low'], 4)}, {_num(r['p_safe_high'], 4)}]"
        )
        lines.append(
            f"| {name} | {METHODS.get(r['method'], r['method'])} | {_cm(r['test_sigma_m'])} | {r['nav_sigma_m']:g} m | "
            f"{p} | {100 * r['abstain_rate']:.1f} [{100 * r['abstain_low']:.1f}, {100 * r['abstain_high']:.1f}] | "
            f"{_num(100 * r['unknown_fraction'] if r['unknown_fraction'] is not None else None, 1)} | "
            f"{_num(r['clearance_m'], 1)} / {_num(r['truth_clearance_m'], 1)} |"
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
        rows = [line for name, rep in reports for line in landing_table(name, rep, truth)[2:]]
        if rows:
            print(f"### Landing against the {truth} truth\n")
            print("\n".join(landing_table("", {}, truth)[:2] + rows) + "\n")
    for name, rep in reports:
        print("\n".join(pixel_table(name, rep)) + "\n")


if __name__ == "__main__":
    main()
