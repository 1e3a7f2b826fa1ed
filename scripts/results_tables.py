"""Markdown tables of docs/results.md from the reports of a reproduction.

Reads ``report.json`` files written by ``hd eval`` (``hd reproduce`` writes ``report/`` with the mean
threshold and 10 dropped pixels, and ``report-risk/`` with ``risk:0.05``) and prints, next to the
paper's numbers (``hdnet.paper_results``): Table 1 (noise), Table 2 (dead pixels), the threshold
sweep, the risk-controlled rows and, for reports with ``--sigma-sweep``, the noise sweep. Nothing
is typed by hand: regenerate the tables whenever the science changes.

Usage::

    python scripts/results_tables.py REPORT_DIR [--risk RISK_REPORT_DIR] [--title "paper convention"]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hdnet.paper_results import paper_row

DASH = "\u2013"  # an en dash: the tables' "no value"
METHODS = {"alhat_baseline": "ALHAT baseline", "base_net": "base net", "uncertainty_aware": "uncertainty-aware"}


def _num(x: float | None, digits: int = 4) -> str:
    return DASH if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def _cm(sigma_m: float) -> str:
    return f"{sigma_m * 100:.3g} cm"


def _vc(row: dict[str, Any], paper: Any) -> str:
    if row["vc_fraction"] is None:
        return DASH
    ours = f"{100 * row['vc_fraction']:.0f}"
    return ours if paper is None or paper.vc_fraction is None else f"{ours} (paper {100 * paper.vc_fraction:.0f})"


def table(report: dict[str, Any], which: str) -> list[str]:
    """Rows of ``which`` (``noise`` = Table 1, ``dead_pixels`` = Table 2) beside the paper's."""
    columns = ["method", "test σ", "V/C %", "PA", "mIoU", "precision", "sensitivity"]
    columns += ["paper PA", "paper mIoU", "paper prec.", "paper sens."]
    lines = ["| " + " | ".join(columns) + " |", "|---" * len(columns) + "|"]
    for r in report["rows"]:
        if r["table"] != which:
            continue
        p = paper_row(which, r["method"], r["test_sigma_m"])
        theirs = (
            [DASH] * 4 if p is None else [_num(p.pixel_accuracy), _num(p.miou), _num(p.precision), _num(p.sensitivity)]
        )
        lines.append(
            f"| {METHODS.get(r['method'], r['method'])} | {_cm(r['test_sigma_m'])} | {_vc(r, p)} | "
            f"{_num(r['pixel_accuracy'])} | {_num(r['miou'])} | {_num(r['precision'])} | "
            f"{_num(r['sensitivity'])} | " + " | ".join(theirs) + " |"
        )
    return lines


def sweep(report: dict[str, Any]) -> list[str]:
    """The threshold sweep: precision / sensitivity per quantile and test sigma."""
    points = report.get("sweep") or []
    sigmas = sorted({p["test_sigma_m"] for p in points})
    quantiles = sorted({p["quantile"] for p in points})
    by = {(p["quantile"], p["test_sigma_m"]): p for p in points}
    lines = [
        "| quantile | " + " | ".join(f"{_cm(s)} V/C % / prec. / sens." for s in sigmas) + " |",
        "|---" * (len(sigmas) + 1) + "|",
    ]
    for q in quantiles:
        cells = []
        for s in sigmas:
            p = by.get((q, s))
            cells.append(
                DASH
                if p is None
                else f"{100 * (p.get('vc_fraction') or 0):.0f} / {_num(p['precision'], 3)} / "
                f"{_num(p['sensitivity'], 3)}"
            )
        lines.append(f"| {q:g} | " + " | ".join(cells) + " |")
    return lines


def risk(report: dict[str, Any]) -> list[str]:
    """The uncertainty-aware rows at the risk-controlled threshold, with the false-safe rate achieved on test.

    The false-safe rate is ``hdnet.thresholds``' loss: certain pixels predicted safe that are unsafe,
    over the valid pixels of a DEM, averaged over the test DEMs.
    """
    achieved = {
        (a["table"], a["test_sigma_m"]): a["false_safe_rate"] for a in report["threshold"].get("achieved_risk", [])
    }
    lines = [
        "| test σ | V/C % | PA | mIoU | precision | sensitivity | false-safe rate |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in report["rows"]:
        if r["table"] == "noise" and r["method"] == "uncertainty_aware":
            fs = achieved.get(("noise", r["test_sigma_m"]))
            lines.append(
                f"| {_cm(r['test_sigma_m'])} | {100 * r['vc_fraction']:.0f} | {_num(r['pixel_accuracy'])} | "
                f"{_num(r['miou'])} | {_num(r['precision'])} | {_num(r['sensitivity'])} | {_num(fs, 3)} |"
            )
    return lines


def noise_sweep(report: dict[str, Any], risk_report: dict[str, Any] | None = None) -> list[str]:
    """The noise sweep (``sigma_sweep`` rows): per test sigma, the baseline, the base net, the
    uncertainty-aware map at the report's threshold and, with ``risk_report``, at ``risk:ALPHA``
    with the false-safe rate achieved."""
    noise = report["run"].get("train_noise") or {}
    lo, hi = (noise.get("range_m") or [None, None])[:2]
    rows: dict[float, dict[str, dict[str, Any]]] = {}
    for r in report["rows"]:
        if r["table"] == "sigma_sweep":
            rows.setdefault(r["test_sigma_m"], {})[r["method"]] = r
    risk_rows: dict[float, dict[str, Any]] = {}
    achieved: dict[float, float] = {}
    if risk_report is not None:
        risk_rows = {
            r["test_sigma_m"]: r
            for r in risk_report["rows"]
            if r["table"] == "sigma_sweep" and r["method"] == "uncertainty_aware"
        }
        achieved = {
            a["test_sigma_m"]: a["false_safe_rate"]
            for a in risk_report["threshold"].get("achieved_risk", [])
            if a["table"] == "sigma_sweep"
        }
    header = ["test σ", "training", "ALHAT PA / prec. / sens.", "base net PA / prec. / sens."]
    header += [f"{report['threshold']['spec']}: V/C % / prec. / sens."]
    if risk_report is not None:
        header += [f"{risk_report['threshold']['spec']}: V/C % / prec. / sens. / false-safe"]
    lines = ["| " + " | ".join(header) + " |", "|---" * len(header) + "|"]

    def three(r: dict[str, Any] | None) -> str:
        if r is None:
            return DASH
        return f"{_num(r['pixel_accuracy'], 3)} / {_num(r['precision'], 3)} / {_num(r['sensitivity'], 3)}"

    def vc(r: dict[str, Any] | None) -> str:
        if r is None:
            return DASH
        return f"{100 * (r['vc_fraction'] or 0):.0f} / {_num(r['precision'], 3)} / {_num(r['sensitivity'], 3)}"

    for sigma in sorted(rows):
        m = rows[sigma]
        where = DASH if lo is None else ("in range" if lo - 1e-9 <= sigma <= hi + 1e-9 else "**above**")
        cells = [_cm(sigma), where, three(m.get("alhat_baseline")), three(m.get("base_net"))]
        cells.append(vc(m.get("uncertainty_aware")))
        if risk_report is not None:
            fs = achieved.get(sigma)
            cells.append(f"{vc(risk_rows.get(sigma))} / {_num(fs, 3) if fs is not None else DASH}")
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("report", type=Path, help="report directory of the mean threshold (hd reproduce: report/)")
    parser.add_argument("--risk", type=Path, default=None, help="report directory of risk:ALPHA (report-risk/)")
    parser.add_argument("--title", default="", help="words after each table's heading")
    args = parser.parse_args()
    rep = json.loads((args.report / "report.json").read_text())
    th = rep["threshold"]
    suffix = f" — {args.title}" if args.title else ""
    print(f"### Table 1{suffix} (threshold {th['spec']}: {th['value_nats']:.3f} nats)\n")
    print("\n".join(table(rep, "noise")) + "\n")
    print(f"### Table 2{suffix} (10 dropped pixels)\n")
    print("\n".join(table(rep, "dead_pixels")) + "\n")
    print(f"### Threshold sweep{suffix}\n")
    print("\n".join(sweep(rep)) + "\n")
    cal = rep.get("calibration", {}).get("per_sigma") or []
    if cal:
        print("ECE: " + ", ".join(f"{c.get('ece', float('nan')):.3f} ({_cm(c['test_sigma_m'])})" for c in cal) + "\n")
    if any(r["table"] == "sigma_sweep" for r in rep["rows"]):
        rr_sweep = json.loads((args.risk / "report.json").read_text()) if args.risk is not None else None
        print(f"### Noise sweep{suffix}\n")
        print("\n".join(noise_sweep(rep, rr_sweep)) + "\n")
    if args.risk is not None:
        rr = json.loads((args.risk / "report.json").read_text())
        t = rr["threshold"]
        value = "+inf nats: no pixel is discarded" if t["value_nats"] is None else f"{t['value_nats']:.3f} nats"
        print(f"### Risk-controlled threshold{suffix} ({t['spec']}: {value})\n")
        print("\n".join(risk(rr)) + "\n")


if __name__ == "__main__":
    main()
