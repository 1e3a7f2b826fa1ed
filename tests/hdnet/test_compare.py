"""hd compare: the key rows of several report.json side by side, the settings that differ, bad input.

The reports are written by hd's own writer (``hdnet.report.report_dict`` of a hand-made
``EvaluationResult``), so that they have exactly the schema ``hd eval`` writes, without training.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner, Result

from hdcli.cli import main
from hdcore.errors import StorageError
from hdcore.storage import write_json_atomic
from hdnet.compare import ABSENT, column_names, compare
from hdnet.errors import HdNetError
from hdnet.landing import LandingTally, TouchdownScore
from hdnet.report import METHOD_WORDS, report_dict
from hdnet.report_json import ReportRunJson, ThresholdJson
from hdnet.results import METHODS, EvaluationResult, LandingRecord, LandingRow, LandingSettings, ReportRow

SIGMAS = (0.0167, 0.07)
ROOT = Path(__file__).resolve().parents[2]


def rows(shift: float) -> list[ReportRow]:
    """Table 1 (and one Table 2 row) with distinct numbers per method, sigma and ``shift``."""
    out = []
    for s, sigma in enumerate(SIGMAS):
        for m, method in enumerate(METHODS):
            base = 0.5 + 0.1 * m + 0.01 * s + shift
            out.append(
                ReportRow(
                    table="noise",
                    method=method,
                    train_sigma_m=None if method == "alhat_baseline" else 0.0167,
                    test_sigma_m=sigma,
                    vc_fraction=0.8 + shift if method == "uncertainty_aware" else None,
                    pixel_accuracy=base,
                    miou=base - 0.05,
                    precision=base + 0.02,
                    sensitivity=float("nan") if (method, s) == ("base_net", 1) else base + 0.03,
                )
            )
    out.append(replace(out[0], table="dead_pixels", pixel_accuracy=0.123456))
    return out


def landing(p_safe: float) -> list[LandingRow]:
    """A landing table against the terrain: P(safe) = ``p_safe`` + nav / 100; the base net never lands."""
    interval = {"p_safe_low": 0.1, "p_safe_high": 1.0, "abstain_rate": 0.0, "abstain_low": 0.0, "abstain_high": 0.5}
    return [
        LandingRow(
            method=method,
            test_sigma_m=0.0167,
            nav_sigma_m=nav,
            truth="terrain",
            scenes=4,
            landed=0 if method == "base_net" else 4,
            p_safe=p_safe + nav / 100,
            unknown_fraction=0.0,
            clearance_m=5.0,
            truth_clearance_m=float("nan"),
            **interval,
        )
        for method in METHODS
        for nav in (0.0, 3.0)
    ]


def write_report(directory: Path, shift: float = 0.0, **changes: Any) -> Path:
    """A report directory holding the report.json hd eval would write for these numbers and settings.

    ``changes``: ``mc_samples=``, ``spec=``, ``value_nats=``, ``landing=`` (P(safe), or None for no
    landing table), ``landing_rows=`` (the landing table itself), ``uncertainty=``, ``table2=False`` (no
    dead-pixel rows)."""
    run: ReportRunJson = {
        "checkpoint": "/runs/a/last.pt",
        "checkpoint_sha256": "a" * 64,
        "epoch": 10,
        "profile": "cpu",
        "train_noise": {"kind": "single", "levels_m": [0.0167], "range_m": None},
        "dataset": "/data/mars",
        "labels": "paper-square",
        "sigmas_m": list(SIGMAS),
        "mc_samples": changes.get("mc_samples", 20),
        "seed": 0,
    }
    threshold: ThresholdJson = {
        "spec": changes.get("spec", "mean"),
        "kind": "mean",
        "value_nats": changes.get("value_nats", 0.4321),
        "mean_nats": changes.get("value_nats", 0.4321),
        "mean_quantile": 0.61 + shift,
        "calibration_split": "val",
        "calibration_sigma_m": 0.0167,
        "calibrate": "reference",
    }
    if "uncertainty" in changes:
        threshold["uncertainty"] = changes["uncertainty"]
    p_safe = changes.get("landing", 0.9)
    result = EvaluationResult(
        rows=[r for r in rows(shift) if changes.get("table2", True) or r.table != "dead_pixels"],
        threshold=threshold,
        sweep=[],
        calibration={"bins": 10, "per_sigma": []},
        run=run,
        landing=changes.get("landing_rows") or ([] if p_safe is None else landing(p_safe)),
        landing_settings=None if p_safe is None else LandingRecord(LandingSettings(nav_sigmas_m=(0.0, 3.0))),
    )
    directory.mkdir(parents=True)
    write_json_atomic(directory / "report.json", report_dict(result))
    return directory


def hd(*args: Any) -> Result:
    return CliRunner().invoke(main, [str(a) for a in args])


def row_values(record: dict[str, Any], label: str) -> dict[str, Any]:
    return next(r["values"] for r in record["rows"] if r["row"] == label)


def test_json_shows_the_reports_own_numbers(tmp_path):
    a = write_report(tmp_path / "a")
    b = write_report(tmp_path / "b", shift=0.1, mc_samples=50, value_nats=0.25, landing=0.7)
    result = hd("--json", "compare", a, b)
    assert result.exit_code == 0, result.output
    record = json.loads(result.output)
    assert [r["name"] for r in record["reports"]] == ["a", "b"]
    for name, directory in (("a", a), ("b", b)):
        report = json.loads((directory / "report.json").read_text())
        for r in report["rows"]:
            if r["table"] != "noise":
                continue
            prefix = f"{METHOD_WORDS[r['method']]} {r['test_sigma_m'] * 100:.3g} cm"
            assert row_values(record, f"{prefix} PA")[name] == r["pixel_accuracy"]
            assert row_values(record, f"{prefix} mIoU")[name] == r["miou"]
            assert row_values(record, f"{prefix} precision")[name] == r["precision"]
            assert row_values(record, f"{prefix} sensitivity")[name] == r["sensitivity"]  # null stays null
            if r["method"] == "uncertainty_aware":
                assert row_values(record, f"{prefix} V/C")[name] == r["vc_fraction"]
        assert row_values(record, "H_t (nats)")[name] == report["threshold"]["value_nats"]
        assert row_values(record, "rule")[name] == "mean"
        for land in report["landing"]:
            label = (
                f"P(safe landing) terrain truth, {METHOD_WORDS[land['method']]} 1.67 cm, nav {land['nav_sigma_m']:g} m"
            )
            expected = None if land["landed"] == 0 else land["p_safe"]
            assert row_values(record, label)[name] == expected
    assert not any(r["row"].endswith("V/C") and "base net" in r["row"] for r in record["rows"])
    assert row_values(record, "ALHAT baseline 1.67 cm PA, dead pixels") == {"a": 0.123456, "b": 0.123456}
    labels = [r["row"] for r in record["rows"]]
    assert len(labels) == len(set(labels))  # a row's label names it alone
    assert record["notes"] == []  # both reports have Table 2


def test_differing_settings_are_named_and_equal_ones_only_counted(tmp_path):
    a = write_report(tmp_path / "a")
    b = write_report(tmp_path / "b", mc_samples=50, spec="quantile:0.7", uncertainty="mutual-information")
    c = compare([a, b])
    differing = {s.name: s.values for s in c.differing}
    assert differing == {
        "run.mc_samples": (20, 50),
        "threshold.spec": ("mean", "quantile:0.7"),
        "threshold.uncertainty": ("entropy", "mutual-information"),
    }
    assert "run.checkpoint_sha256" in c.equal and "threshold.value_nats" not in c.equal
    text = hd("compare", a, b)
    assert text.exit_code == 0, text.output
    out = text.output
    assert "Settings that differ (3):" in out and "run.mc_samples" in out and "quantile:0.7" in out
    assert "run.checkpoint_sha256" not in out and "run.epoch" not in out
    assert f"{len(c.equal)} other settings equal in every report" in out
    assert "mean on the mutual information" not in out and "quantile:0.7 on the mutual information" in out
    ua = next(line for line in out.splitlines() if line.startswith("  Table 1: uncertainty-aware 1.67 cm PA"))
    assert ua.split()[-3:] == ["0.7000", "0.7000", "+0.0000"]  # equal: no mark


def test_markdown_is_a_table_with_the_differing_settings(tmp_path):
    a = write_report(tmp_path / "x" / "report")
    b = write_report(tmp_path / "y" / "report", shift=0.05, landing=None)
    result = hd("compare", a, b, "--format", "markdown")
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0] == "| * | Section | Row | x/report | y/report | y/report - x/report |"
    assert "| * | Table 1 | ALHAT baseline 1.67 cm PA | 0.5000 | 0.5500 | +0.0500 |" in lines
    assert "|  | Threshold | rule | mean | mean | -- |" in lines
    label = "P(safe landing) terrain truth, ALHAT baseline 1.67 cm, nav 3 m"
    assert f"| * | Landing | {label} | 0.9300 [0.1000, 1.0000] n=4/4 | -- | -- |" in lines
    assert "| * | Landing | P(safe landing) terrain truth, base net 1.67 cm, nav 3 m | -- n=0/4 | -- | -- |" in lines
    assert any(line.startswith("| `landing_settings.touchdowns` | 1000 | " + ABSENT) for line in lines)


def wilson_row(safe: int, scenes: int) -> LandingRow:
    """The base net's row at no dispersion: ``safe`` of ``scenes`` scenes landed safely (each one
    touchdown), none abstained, with the Wilson interval of hd's landing tally."""
    tally = LandingTally()
    for k in range(scenes):
        tally.land(TouchdownScore(1.0 if k < safe else 0.0, 0.0), 5.0, 4.0)
    return tally.row("base_net", 0.0167, 0.0, "terrain")


def test_landing_rows_show_their_interval_and_scenes(tmp_path):
    """A rate of 1 over 2 scenes and over 500 scenes: the same P(safe landing), told apart by the Wilson
    interval and n shown beside it, in every format."""
    z2 = 1.959963984540054**2
    two = write_report(tmp_path / "two", landing_rows=[wilson_row(2, 2)])
    many = write_report(tmp_path / "many", landing_rows=[wilson_row(500, 500)])
    label = "P(safe landing) terrain truth, base net 1.67 cm, nav 0 m"
    row = next(r for r in compare([two, many]).rows if r.label == label)
    assert row.values == (1.0, 1.0)
    lo2, lo500 = 2 / (2 + z2), 500 / (500 + z2)  # Wilson's lower end at p = 1: n / (n + z^2)
    assert row.cells() == [f"1.0000 [{lo2:.4f}, 1.0000] n=2/2", f"1.0000 [{lo500:.4f}, 1.0000] n=500/500"]
    assert row.cells() == ["1.0000 [0.3424, 1.0000] n=2/2", "1.0000 [0.9924, 1.0000] n=500/500"]
    text = hd("compare", two, many)
    assert text.exit_code == 0, text.output
    line = next(x for x in text.output.splitlines() if x.startswith(f"* Landing: {label}"))  # its n differs
    cells = [x.strip() for x in line.split("  ") if x.strip()]
    assert cells[-2:] == ["1.0000 [0.9924, 1.0000] n=500/500", "+0.0000"] and "[0.3424, 1.0000] n=2/2" in line
    record = json.loads(hd("--json", "compare", two, many).output)
    entry = next(r for r in record["rows"] if r["row"] == label)
    assert entry["values"] == {"two": 1.0, "many": 1.0}  # the rate, as before
    assert entry["landing"]["two"] == {"p_safe_low": pytest.approx(lo2), "p_safe_high": 1.0, "landed": 2, "scenes": 2}
    assert entry["landing"]["many"]["landed"] == 500


def test_names_are_the_directories_made_distinct():
    assert column_names([Path("/r/a"), Path("/r/b")]) == ["a", "b"]
    assert column_names([Path("/x/report"), Path("/y/report")]) == ["x/report", "y/report"]
    assert column_names([Path("/x/report"), Path("/x/report")]) == ["report", "report (2)"]


def test_a_report_json_path_is_its_report(tmp_path):
    a = write_report(tmp_path / "a")
    b = write_report(tmp_path / "b")
    c = compare([a / "report.json", b])
    assert c.names == ("a", "b") and not c.differing


def test_hd_json_and_another_format_is_a_usage_error(tmp_path):
    a, b = write_report(tmp_path / "a"), write_report(tmp_path / "b")
    result = hd("--json", "compare", a, b, "--format", "markdown")
    assert result.exit_code == 2 and "drop --format markdown" in result.output
    assert json.loads(hd("compare", a, b, "--format", "json").output)["command"] == "compare"


def one_line_error(result: Result, *needles: str) -> None:
    assert result.exit_code == 1, result.output
    assert "Traceback" not in result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.output
    for n in needles:
        assert n in lines[0], (n, lines[0])


def test_fewer_than_two_reports_is_one_line(tmp_path):
    one_line_error(hd("compare"), "at least two reports (got 0)")
    one_line_error(hd("compare", write_report(tmp_path / "a")), "at least two reports (got 1)")


def test_a_run_directory_asks_for_hd_eval_first(tmp_path):
    a = write_report(tmp_path / "a")
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text("{}")
    one_line_error(hd("compare", a, run), f"{run} is a run", "hd eval", "first")


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        (None, "holds no report.json"),
        (b"{not json", "unreadable report"),
        (b"\xff\xfe", "not UTF-8"),
        (b"[1, 2]", "not an hd eval report"),
        (b'{"rows": [], "run": {}}', "no 'threshold' dict"),
        (b'{"rows": [{"table": "noise"}], "threshold": {}, "run": {}}', "row 0 has other keys"),
    ],
)
def test_a_missing_damaged_or_other_schema_report_is_one_line(tmp_path, content, needle):
    a = write_report(tmp_path / "a")
    bad = tmp_path / "bad"
    bad.mkdir()
    if content is not None:
        (bad / "report.json").write_bytes(content)
    before = sorted(p.name for p in tmp_path.rglob("*"))
    one_line_error(hd("compare", a, bad), needle)
    assert sorted(p.name for p in tmp_path.rglob("*")) == before  # read-only


def test_a_missing_directory_and_a_fifo_report_are_refused(tmp_path):
    a = write_report(tmp_path / "a")
    one_line_error(hd("compare", a, tmp_path / "nope"), "no such report directory")
    fifo = tmp_path / "f"
    fifo.mkdir()
    os.mkfifo(fifo / "report.json")
    with pytest.raises(StorageError, match=r"report\.json"):
        compare([a, fifo])
    with pytest.raises(HdNetError, match="at least two"):
        compare([a])


def test_hd_compare_does_not_import_torch(tmp_path):
    a, b = write_report(tmp_path / "a"), write_report(tmp_path / "b")
    code = "import sys; sys.modules['torch'] = None; from hdcli.cli import main; main(sys.argv[1:], prog_name='hd')"
    done = subprocess.run(
        [sys.executable, "-c", code, "compare", str(a), str(b)], cwd=ROOT, capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stderr
    assert "Settings that differ: none" in done.stdout


def test_differing_rows_are_marked_with_each_reports_difference_from_the_first(tmp_path):
    a = write_report(tmp_path / "a")
    b = write_report(tmp_path / "b", shift=0.25, landing=0.5)
    c = write_report(tmp_path / "c", value_nats=0.5)  # a's numbers but H_t
    record = json.loads(hd("--json", "compare", a, b, c).output)
    by_label = {r["row"]: r for r in record["rows"] if r["section"] != "Table 2"}
    pa = by_label["ALHAT baseline 1.67 cm PA"]  # 0.5 + shift
    assert pa["differs"] is True
    assert pa["differences"]["b"] == pytest.approx(0.25) and pa["differences"]["c"] == 0.0
    assert list(pa["differences"]) == ["b", "c"]  # none for the first report
    ht = by_label["H_t (nats)"]
    assert ht["differs"] is True and ht["differences"] == {"b": 0.0, "c": pytest.approx(0.5 - 0.4321)}
    rule = by_label["rule"]
    assert rule["differs"] is False and rule["differences"] == {"b": None, "c": None}  # not a number
    never = by_label["P(safe landing) terrain truth, base net 1.67 cm, nav 0 m"]
    assert never["differs"] is False and never["differences"] == {"b": None, "c": None}
    land = by_label["P(safe landing) terrain truth, ALHAT baseline 1.67 cm, nav 3 m"]  # 0.9 + 0.03 vs 0.5 + 0.03
    assert land["differs"] is True and land["differences"]["b"] == pytest.approx(-0.4)
    text = hd("compare", a, b, c).output.splitlines()
    assert text[0].split()[-6:] == ["b", "-", "a", "c", "-", "a"]
    assert next(x for x in text if "ALHAT baseline 1.67 cm PA" in x).split() == [
        "*", "Table", "1:", "ALHAT", "baseline", "1.67", "cm", "PA", "0.5000", "0.7500", "0.5000", "+0.2500", "+0.0000"
    ]  # fmt: skip
    assert next(x for x in text if "Threshold: rule" in x).startswith("  Threshold: rule")
    assert "* the reports differ on this row; b - a: that report's value minus a's" in text


def test_a_report_without_table2_is_named_in_one_line(tmp_path):
    a = write_report(tmp_path / "a")
    b = write_report(tmp_path / "b", table2=False)
    note = "Table 2 (dead pixels): not in report b (evaluated without --drop-pixels)"
    result = hd("compare", a, b)
    assert result.exit_code == 0, result.output
    assert result.output.splitlines().count(note) == 1
    markdown = hd("compare", a, b, "--format", "markdown").output.splitlines()
    assert "| * | Table 2 | ALHAT baseline 1.67 cm PA, dead pixels | 0.1235 | -- | -- |" in markdown
    assert note + "." in markdown
    assert json.loads(hd("--json", "compare", a, b).output)["notes"] == [note]
    none = write_report(tmp_path / "c", table2=False)
    record = json.loads(hd("--json", "compare", b, none).output)
    assert record["notes"] == [] and not any(r["section"] == "Table 2" for r in record["rows"])
