"""``hd compare``: the key rows of several ``hd eval`` reports side by side, and the settings that differ.

Each report is read from its ``report.json`` (``hdnet.report``: ``rows``, ``threshold``, ``run`` and,
when the evaluation scored landings, ``landing`` and ``landing_settings``). The comparison shows, per
report (a column named after its directory), Table 1's rows (PA, mIoU, precision, sensitivity and, for
the uncertainty-aware map, V/C; fractions in [0, 1]), Table 2's (dead pixels) when a report has one (a
report without it is named in one note), the threshold (its rule and H_t in nats) and the
landing table's P(safe landing) per truth, method, noise level and navigation dispersion, each with its
95 % Wilson interval and its scenes (landed on / scored: ``0.9500 [0.8412, 0.9862] n=38/40``). A row whose
shown values are not all equal is marked (``differs``), and each report after the first has a difference
column: its number minus the first report's (fractions, nats or P(safe); ``--`` where either is missing
or not a number). Then every
setting of the reports' ``run``, ``threshold`` and ``landing_settings`` records whose values are not
all equal, with each report's value; the equal ones are counted. Nothing is written.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

from hdcore.storage import read_json
from hdnet.errors import HdNetError
from hdnet.report import METHOD_WORDS, ROW_KEYS, json_plain
from hdnet.report_json import ReportJson
from hdnet.run_files import CONFIG, LAST
from hdnet.uncertainty import RECORD_KEY, recorded_score

REPORT = "report.json"
FORMATS = ("table", "markdown", "json")

# Table 1's metrics, in the paper's column order: (report.json row key, label).
METRICS: tuple[tuple[str, str], ...] = (
    ("vc_fraction", "V/C"),
    ("pixel_accuracy", "PA"),
    ("miou", "mIoU"),
    ("precision", "precision"),
    ("sensitivity", "sensitivity"),
)
# Entries of a threshold record that are what the calibration found, not how it was asked for: they
# are compared as the threshold's rows (H_t), or not at all (the risk achieved, the quantiles).
THRESHOLD_RESULTS = frozenset(
    {
        "value_nats",
        "mean_nats",
        "mean_quantile",
        "value_quantile",
        "calibration_pixels",
        "achieved_risk",
        "per_sigma",
        "guarded",
        "guard_nats",
        "unreachable",
        "needs_images",
    }
)
ABSENT = "(absent)"  # a setting one report records and another does not
DIGITS = 4  # decimals of the fractions and of H_t shown (the report's own, hdnet.report.DECIMALS)

Value = float | int | str | None


@dataclass(frozen=True)
class LoadedReport:
    """One report: its column name, the directory it was read from and the content of ``report.json``."""

    name: str
    directory: Path
    content: ReportJson


@dataclass(frozen=True)
class LandingCell:
    """How sure one report's P(safe landing) is: its 95 % Wilson interval (``low``, ``high``; None
    where the method never landed), the scenes it landed on (the interval's n) and the scenes scored."""

    low: float | None
    high: float | None
    landed: int | None
    scenes: int | None

    def text(self, p_safe: Value) -> str:
        """The cell as shown: ``0.9500 [0.8412, 0.9862] n=38/40`` (n: scenes landed on / scored), or
        ``-- n=0/40`` where the method never landed."""
        n = f"n={'?' if self.landed is None else self.landed}/{'?' if self.scenes is None else self.scenes}"
        if not isinstance(p_safe, float):
            return f"-- {n}"
        return f"{p_safe:.{DIGITS}f} [{_cell(self.low)}, {_cell(self.high)}] {n}"

    def to_dict(self) -> dict[str, object]:
        """The cell's record in ``hd --json compare`` (its row's value is the rate)."""
        return {"p_safe_low": self.low, "p_safe_high": self.high, "landed": self.landed, "scenes": self.scenes}


@dataclass(frozen=True)
class Row:
    """One compared quantity: its section (``Table 1``, ``Threshold``, ``Landing``), label and each
    report's value (None where undefined or missing; fractions in [0, 1], H_t in nats); a landing
    row also each report's interval and scene counts (``landing``; None where the report lacks the row)."""

    section: str
    label: str
    values: tuple[Value, ...]
    landing: tuple[LandingCell | None, ...] | None = None

    def cells(self) -> list[str]:
        """Each report's value as shown (a landing rate with its interval and scene counts)."""
        if self.landing is None:
            return [_cell(v) for v in self.values]
        return [_cell(v) if c is None else c.text(v) for v, c in zip(self.values, self.landing, strict=True)]

    @property
    def differs(self) -> bool:
        """Whether the reports' values, as shown (``DIGITS`` decimals, interval and scene counts
        included), are not all equal: a difference below the last decimal shown is no mark."""
        shown = self.cells()
        return any(c != shown[0] for c in shown[1:])

    def differences(self) -> tuple[float | None, ...]:
        """Each report after the first: its value minus the first report's (None where either is not
        a number, a rule say, or missing)."""
        first = self.values[0]
        return tuple(
            v - first if isinstance(v, (int, float)) and isinstance(first, (int, float)) else None
            for v in self.values[1:]
        )


@dataclass(frozen=True)
class Setting:
    """One setting (a dotted path into ``report.json``: ``run.mc_samples``) and each report's value
    (``ABSENT`` where a report does not record it)."""

    name: str
    values: tuple[Any, ...]


@dataclass(frozen=True)
class Comparison:
    """What ``hd compare`` shows: the reports, the rows, the settings that differ and those equal."""

    reports: tuple[LoadedReport, ...]
    rows: tuple[Row, ...]
    differing: tuple[Setting, ...]
    equal: dict[str, object] = field(default_factory=dict)
    notes: tuple[str, ...] = ()  # one line per section a report lacks (``table_notes``)

    @property
    def names(self) -> tuple[str, ...]:
        """The columns: each report's name."""
        return tuple(r.name for r in self.reports)


# ------------------------------------------------------------------------------------------- reading
def read_report(path: str | os.PathLike) -> tuple[Path, ReportJson]:
    """The report directory of ``path`` (a report directory or its ``report.json``) and its content.

    Raises:
        HdNetError: a run directory (runs do not record their reports: ``hd eval`` it first), a
            directory without ``report.json``, or a ``report.json`` that is not an ``hd eval`` report.
        StorageError: an unreadable, damaged or non-regular ``report.json`` (``hdcore.storage.read_json``).
    """
    p = Path(path)
    if p.name == REPORT and not p.is_dir():
        directory, file = p.parent, p
    else:
        directory, file = p, p / REPORT
    if not directory.is_dir():
        raise HdNetError(f"{directory}: no such report directory; give the --out directory of an hd eval")
    if not file.exists() and not file.is_symlink():
        if (directory / LAST).exists() or (directory / CONFIG).exists():
            raise HdNetError(
                f"{directory} is a run, and runs do not record their reports: run `hd eval {directory} --data "
                "DATASET --out REPORT` first and compare REPORT"
            )
        raise HdNetError(f"{directory} holds no {REPORT}: give the --out directory of an hd eval (run `hd eval` first)")
    content = read_json(file, "report")
    _check_schema(file, content)
    return directory, cast("ReportJson", content)  # its structure checked


def _check_schema(file: Path, content: Any) -> None:
    """Refuse a ``report.json`` whose structure is not that of this hd's reports (``hdnet.report``)."""
    fix = "re-run hd eval with this hd to write it again"
    if not isinstance(content, dict):
        raise HdNetError(f"{file}: not an hd eval report (a JSON {type(content).__name__}, not an object); {fix}")
    for key, kind in (("rows", list), ("threshold", dict), ("run", dict)):
        if not isinstance(content.get(key), kind):
            raise HdNetError(f"{file}: not an hd eval report of this schema (no {key!r} {kind.__name__}); {fix}")
    for i, row in enumerate(content["rows"]):
        if not isinstance(row, dict) or set(row) != set(ROW_KEYS):
            raise HdNetError(f"{file}: row {i} has other keys than this hd's reports ({', '.join(ROW_KEYS)}); {fix}")
    for key in ("landing", "landing_settings"):
        if key in content and not isinstance(content[key], list if key == "landing" else dict):
            raise HdNetError(f"{file}: {key!r} is not of this hd's report schema; {fix}")


def column_names(directories: list[Path]) -> list[str]:
    """Each report's column name: its directory's name, with as many parent directories as make the
    names distinct (``a/report``, ``b/report``); the same directory twice is numbered (``report (2)``)."""
    paths = [d.resolve() for d in directories]
    depth = 1
    while True:
        names = [str(Path(*p.parts[-depth:])) for p in paths]
        if len(set(names)) == len(set(paths)) or all(depth >= len(p.parts) for p in paths):
            break
        depth += 1
    seen: dict[str, int] = {}
    out = []
    for n in names:
        seen[n] = seen.get(n, 0) + 1
        out.append(n if seen[n] == 1 else f"{n} ({seen[n]})")
    return out


def load_reports(paths: list[str | os.PathLike]) -> list[LoadedReport]:
    """The reports of ``paths`` (each a report directory or its ``report.json``), named for their columns.

    Raises:
        HdNetError: fewer than two paths, or a path that is not a report (``read_report``).
        StorageError: an unreadable or damaged ``report.json``.
    """
    if len(paths) < 2:
        raise HdNetError(
            f"hd compare needs at least two reports (got {len(paths)}): give two or more hd eval --out directories"
        )
    read = [read_report(p) for p in paths]
    names = column_names([d for d, _ in read])
    return [LoadedReport(n, d, c) for n, (d, c) in zip(names, read, strict=True)]


# ----------------------------------------------------------------------------------------- comparing
def _cm(sigma_m: Any) -> str:
    return f"{sigma_m * 100:.3g} cm" if isinstance(sigma_m, (int, float)) else str(sigma_m)


def _number(x: Any) -> float | None:
    """A finite number of a report, else None (report.json writes an undefined ratio as null)."""
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) else None


def _ordered(keys: list[Any]) -> list[Any]:
    """``keys`` once each, in their first order."""
    return list(dict.fromkeys(keys))


# The tables of report.json compared as rows: (its ``table`` value, section name, what it is, the
# hd eval setting that makes it).
TABLES: tuple[tuple[str, str, str, str], ...] = (
    ("noise", "Table 1", "noise levels", ""),
    ("dead_pixels", "Table 2", "dead pixels", " (evaluated without --drop-pixels)"),
)


def table1_rows(
    reports: list[LoadedReport], table: str = "noise", section: str = "Table 1", suffix: str = ""
) -> list[Row]:
    """Table 1 (``table == "noise"``), or another table of report rows (``table``, shown as ``section``,
    each label ending in ``suffix`` so that no two rows of a comparison share a label): per method and
    test noise level, V/C (uncertainty-aware only), PA, mIoU, precision and sensitivity of each report."""
    index: list[dict[tuple[str, float], Mapping[str, object]]] = [
        {(r["method"], r["test_sigma_m"]): r for r in rep.content["rows"] if r.get("table") == table} for rep in reports
    ]
    keys = _ordered([k for rows in index for k in rows])
    out = []
    for method, sigma in keys:
        for key, label in METRICS:
            if key == "vc_fraction" and method != "uncertainty_aware":
                continue
            values = tuple(_number(rows[(method, sigma)][key]) if (method, sigma) in rows else None for rows in index)
            out.append(Row(section, f"{METHOD_WORDS.get(method, method)} {_cm(sigma)} {label}{suffix}", values))
    return out


def table_notes(reports: list[LoadedReport]) -> list[str]:
    """One line per table that some reports have and others do not, naming those without it (their
    column shows ``--``): ``Table 2 (dead pixels): not in report b (evaluated without --drop-pixels)``."""
    out = []
    for table, section, words, why in TABLES:
        has = [any(r.get("table") == table for r in rep.content["rows"]) for rep in reports]
        if any(has) and not all(has):
            missing = [rep.name for rep, h in zip(reports, has, strict=True) if not h]
            which = f"report{'s' if len(missing) > 1 else ''} {', '.join(missing)}"
            out.append(f"{section} ({words}): not in {which}{why}")
    return out


def threshold_rows(reports: list[LoadedReport]) -> list[Row]:
    """The threshold: its rule (``mean``, ``quantile:Q``, ``risk:ALPHA``, ``nats:H``, with the score when
    it is not the entropy) and H_t in nats (None: unbounded)."""
    rules = []
    for rep in reports:
        th = rep.content["threshold"]
        rules.append(f"{th.get('spec', '')}{recorded_score(th).qualifier}" if "spec" in th else None)
    return [
        Row("Threshold", "rule", tuple(rules)),
        Row("Threshold", "H_t (nats)", tuple(_number(rep.content["threshold"].get("value_nats")) for rep in reports)),
    ]


def _count(x: Any) -> int | None:
    """A scene count of a report, else None."""
    return x if isinstance(x, int) and not isinstance(x, bool) else None


def landing_rows(reports: list[LoadedReport]) -> list[Row]:
    """The landing table's P(safe landing) per truth, method, test noise level and navigation dispersion
    (None where the method chose no site), with its 95 % Wilson interval and the scenes landed on and
    scored, so that 2 scenes do not look as sure as 500; no rows when no report scored landings."""
    index: list[dict[tuple[Any, ...], tuple[float | None, LandingCell]]] = []
    for rep in reports:
        rows = {}
        for r in rep.content.get("landing") or []:
            if isinstance(r, dict):
                key = (r.get("truth"), r.get("method"), r.get("test_sigma_m"), r.get("nav_sigma_m"))
                landed = _count(r.get("landed"))
                cell = LandingCell(
                    _number(r.get("p_safe_low")), _number(r.get("p_safe_high")), landed, _count(r.get("scenes"))
                )
                rows[key] = (None if landed == 0 else _number(r.get("p_safe")), cell)
        index.append(rows)
    out = []
    for key in _ordered([k for rows in index for k in rows]):
        truth, method, sigma, nav = key
        nav_words = f"{nav:g} m" if isinstance(nav, (int, float)) else str(nav)
        label = f"P(safe landing) {truth} truth, {METHOD_WORDS.get(method, method)} {_cm(sigma)}, nav {nav_words}"
        found = [rows.get(key) for rows in index]
        values = tuple(None if f is None else f[0] for f in found)
        out.append(Row("Landing", label, values, tuple(None if f is None else f[1] for f in found)))
    return out


def _flatten(prefix: str, value: object, out: dict[str, object]) -> None:
    """Nested objects as dotted names (``run.train_noise.kind``); lists and scalars are values."""
    if isinstance(value, dict) and value:
        for k, v in value.items():
            _flatten(f"{prefix}.{k}", v, out)
    else:
        out[prefix] = value


def settings(content: ReportJson) -> dict[str, object]:
    """A report's settings by dotted name: its ``run`` record, its threshold's settings (not what the
    calibration found) and its ``landing_settings``; the uncertainty score always named."""
    out: dict[str, object] = {}
    _flatten("run", content["run"], out)
    th = {k: v for k, v in content["threshold"].items() if k not in THRESHOLD_RESULTS}
    th[RECORD_KEY] = recorded_score(content["threshold"]).name
    _flatten("threshold", th, out)
    if content.get("landing_settings"):
        _flatten("landing_settings", content["landing_settings"], out)
    return out


def compare_settings(reports: list[LoadedReport]) -> tuple[list[Setting], dict[str, object]]:
    """The settings whose values are not all equal (each report's value, ``ABSENT`` where it has none)
    and the equal ones (name -> value)."""
    each = [settings(rep.content) for rep in reports]
    names = _ordered([k for s in each for k in s])
    differing, equal = [], {}
    for name in names:
        values = tuple(s.get(name, ABSENT) for s in each)
        if all(json.dumps(v, sort_keys=True) == json.dumps(values[0], sort_keys=True) for v in values):
            equal[name] = values[0]
        else:
            differing.append(Setting(name, values))
    return differing, equal


def compare(paths: list[str | os.PathLike]) -> Comparison:
    """Read the reports of ``paths`` and compare them (see the module's docstring).

    Raises:
        HdNetError: fewer than two reports, a path that is not a report, a report of another schema.
        StorageError: an unreadable or damaged ``report.json``.
    """
    reports = load_reports(paths)
    tables = [
        row
        for k, (table, section, words, _) in enumerate(TABLES)
        for row in table1_rows(reports, table, section, f", {words}" if k else "")
    ]
    rows = [*tables, *threshold_rows(reports), *landing_rows(reports)]
    differing, equal = compare_settings(reports)
    return Comparison(tuple(reports), tuple(rows), tuple(differing), equal, tuple(table_notes(reports)))


# --------------------------------------------------------------------------------------------- output
def _cell(value: Value) -> str:
    """A row's value as shown: numbers with ``DIGITS`` decimals, ``--`` where undefined or missing."""
    if value is None:
        return "--"
    if isinstance(value, float):
        return f"{value:.{DIGITS}f}"
    return str(value)


def _setting_cell(value: Any) -> str:
    """A setting's value as shown: strings as they are, anything else as compact JSON."""
    if isinstance(value, str):
        return value
    return json.dumps(json_plain(value))


def _equal_line(c: Comparison) -> str:
    n = len(c.equal)
    return f"{n} other setting{'' if n == 1 else 's'} equal in every report"


MARK = "*"  # the mark of a row whose reports differ


def _difference(d: float | None) -> str:
    """A difference as shown: signed, ``DIGITS`` decimals; ``--`` where there is none."""
    return "--" if d is None else f"{d:+.{DIGITS}f}"


def difference_names(c: Comparison) -> list[str]:
    """The difference columns' headers: ``b - a`` for each report after the first (``a``)."""
    return [f"{n} - {c.names[0]}" for n in c.names[1:]]


def _legend(c: Comparison) -> str:
    """The line that says what the mark and the difference columns mean."""
    return f"{MARK} the reports differ on this row; {difference_names(c)[0]}: that report's value minus {c.names[0]}'s"


def to_table(c: Comparison) -> str:
    """The comparison as aligned text for a terminal: each differing row marked ``*``, then a
    difference column per report after the first, the notes, the settings that differ."""
    header = ["", *c.names, *difference_names(c)]
    body = [
        [f"{MARK if r.differs else ' '} {r.section}: {r.label}", *r.cells(), *map(_difference, r.differences())]
        for r in c.rows
    ]
    widths = [max(len(line[i]) for line in [header, *body]) for i in range(len(header))]

    def line(cells: list[str]) -> str:
        return "  ".join(
            cell.ljust(w) if i == 0 else cell.rjust(w) for i, (cell, w) in enumerate(zip(cells, widths, strict=True))
        ).rstrip()

    out = [line(header), *(line(b) for b in body), _legend(c), *c.notes, ""]
    if c.differing:
        out.append(f"Settings that differ ({len(c.differing)}):")
        width = max(len(n) for n in c.names)
        for s in c.differing:
            out.append(f"  {s.name}")
            out += [f"    {n.ljust(width)}  {_setting_cell(v)}" for n, v in zip(c.names, s.values, strict=True)]
    else:
        out.append("Settings that differ: none")
    out.append(_equal_line(c))
    return "\n".join(out)


def _md(text: str) -> str:
    return text.replace("|", "\\|")


def to_markdown(c: Comparison) -> str:
    """The comparison as Markdown: one table of the rows, one of the settings that differ."""
    columns = [*c.names, *difference_names(c)]
    out = [
        f"| {MARK} | Section | Row | " + " | ".join(_md(n) for n in columns) + " |",
        "|---|---|---|" + "---|" * len(columns),
        *(
            f"| {MARK if r.differs else ''} | {r.section} | {_md(r.label)} | "
            + " | ".join(_md(v) for v in [*r.cells(), *map(_difference, r.differences())])
            + " |"
            for r in c.rows
        ),
        "",
        _md(_legend(c)) + ".",
        *(f"{_md(n)}." for n in c.notes),
        "",
    ]
    if c.differing:
        out += [
            "Settings that differ:",
            "",
            "| Setting | " + " | ".join(_md(n) for n in c.names) + " |",
            "|---|" + "---|" * len(c.names),
            *(f"| `{s.name}` | " + " | ".join(_md(_setting_cell(v)) for v in s.values) + " |" for s in c.differing),
            "",
        ]
    else:
        out += ["Settings that differ: none", ""]
    out.append(_equal_line(c) + ".")
    return "\n".join(out)


def to_record(c: Comparison) -> dict[str, object]:
    """The comparison as one JSON-ready object: the reports (name, directory), each row's values by
    report name (the reports' own numbers), whether they differ and each later report's difference
    from the first, the notes (a table some reports lack), the settings that differ and those equal."""

    def by_name(values: tuple[object, ...]) -> dict[str, object]:
        return dict(zip(c.names, values, strict=True))

    return json_plain(
        {
            "command": "compare",
            "reports": [{"name": r.name, "directory": str(r.directory)} for r in c.reports],
            "rows": [_row_record(r, by_name) for r in c.rows],
            "notes": list(c.notes),
            "settings_differ": {s.name: by_name(s.values) for s in c.differing},
            "settings_equal": c.equal,
        }
    )


def _row_record(r: Row, by_name: Callable[[tuple[object, ...]], dict[str, object]]) -> dict[str, object]:
    """A row of ``to_record``: its section, label, values by report, ``differs`` (its values as shown
    are not all equal) and ``differences`` (each later report's value minus the first's, by report);
    a landing row also its ``landing`` (interval and scene counts, ``LandingCell.to_dict``) by report."""
    out: dict[str, object] = {
        "section": r.section,
        "row": r.label,
        "values": by_name(r.values),
        "differs": r.differs,
        "differences": dict(zip(list(by_name(r.values))[1:], r.differences(), strict=True)),
    }
    if r.landing is not None:
        out["landing"] = by_name(tuple(None if c is None else c.to_dict() for c in r.landing))
    return out


def render(c: Comparison, fmt: str) -> str:
    """The comparison in ``fmt`` (one of ``FORMATS``)."""
    if fmt == "markdown":
        return to_markdown(c)
    if fmt == "json":
        return json.dumps(to_record(c))
    return to_table(c)
