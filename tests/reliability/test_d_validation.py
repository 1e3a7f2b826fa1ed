"""Class D: bad paths and values are refused with one ``Error:`` line before any work starts.

Every case runs a command with one bad option and checks: exit status 1, no traceback, a last
line ``Error: ...`` naming the problem, nothing created at the output path, and no work done
(the first function of each command's real work is replaced by one that fails the test).
"""

from __future__ import annotations

import importlib
import math
import re

import click
import pytest
from click.types import FloatParamType, IntParamType, _NumberRangeBase
from reliability_kit import BUILD_ARGS, assert_one_line_error, invoke

BIG = str(10**9)

BUILD = [
    ("out-under-proc", ["--out", "/proc/hd-test-x"], "/proc"),
    ("out-proc-itself", ["--out", "/proc"], "cannot create files"),
    ("out-under-sys", ["--out", "/sys/hd-test-x"], "/sys"),
    ("out-under-a-file", ["--out", "{file}/sub"], "not a directory"),
    ("out-is-a-file", ["--out", "{file}"], "not a directory|is a file"),
    ("out-dev-null", ["--out", "/dev/null"], "not a directory"),
    ("out-empty", ["--out", ""], "must not be empty"),
    ("out-name-too-long", ["--out", "{tmp}/" + "x" * 300], "longer than 255"),
    ("out-broken-link", ["--out", "{broken}"], "broken symbolic link"),
    ("seed-negative", ["--seed", "-1"], "--seed"),
    ("workers-zero", ["--workers", "0"], "--workers"),
    ("workers-negative", ["--workers", "-1"], "--workers"),
    ("workers-absurd", ["--workers", "100000"], "--workers"),
    ("scans-zero", ["--scans", "0"], "--scans"),
    ("scans-absurd", ["--scans", BIG], "--scans"),
    ("resolution-one", ["--resolution", "1"], "--resolution"),
    ("resolution-absurd", ["--resolution", "100000"], "--resolution"),
    ("shard-memory-absurd", ["--resolution", "1024", "--shard-size", "5000", "--scans", "5000"], "--shard-size"),
    ("shard-size-zero", ["--shard-size", "0"], "--shard-size"),
    ("altitude-inf", ["--altitude", "inf"], "--altitude"),
    ("altitude-nan", ["--altitude", "nan"], "--altitude"),
    ("altitude-negative", ["--altitude", "-5"], "altitude"),
    ("tilt-nan", ["--tilt", "nan"], "--tilt"),
    ("jitter-inf", ["--jitter", "inf"], "--jitter"),
    ("jitter-range-beyond", ["--jitter", "0:9"], "--jitter"),
    ("altitude-range-backwards", ["--altitude", "1000:250"], "--altitude"),
    ("footprint-samples-zero", ["--footprint-samples", "0"], "--footprint-samples"),
    ("footprint-samples-absurd", ["--footprint-samples", BIG], "--footprint-samples"),
    ("pulse-width-nan", ["--pulse-width", "nan"], "--pulse-width"),
    ("return-fraction-inf", ["--return-fraction", "inf"], "--return-fraction"),
    ("snr-ref-inf", ["--snr-ref", "inf"], "--snr-ref"),
    ("snr-min-nan", ["--snr-min", "nan"], "--snr-min"),
    ("descent-frames-one", ["--descent-frames", "1"], "--descent-frames"),
    ("descent-frames-absurd", ["--descent-frames", BIG], "--descent-frames"),
    ("descent-altitudes-ascending", ["--descent-frames", "3", "--descent-altitudes", "250:900"], "does not descend"),
    ("descent-altitudes-nan", ["--descent-frames", "3", "--descent-altitudes", "nan:250"], "--descent-altitudes"),
    ("descents-too-many", ["--descent-frames", "64", "--scans", "100000"], "6,400,000 scans"),
    ("approach-nan", ["--descent-frames", "3", "--approach-deg", "nan"], "--approach-deg"),
    ("approach-without-descent", ["--approach-deg", "10"], "--descent-frames"),
    ("nav-position-sigma-inf", ["--descent-frames", "3", "--nav-position-sigma", "inf"], "--nav-position-sigma"),
    ("nav-position-walk-negative", ["--descent-frames", "3", "--nav-position-walk", "-1"], "--nav-position-walk"),
    ("nav-attitude-sigma-nan", ["--descent-frames", "3", "--nav-attitude-sigma", "nan"], "--nav-attitude-sigma"),
    ("nav-attitude-walk-inf", ["--descent-frames", "3", "--nav-attitude-walk", "inf"], "--nav-attitude-walk"),
    ("fov-nan", ["--fov", "nan"], "--fov"),
    ("fov-zero", ["--fov", "0"], "fov"),
    ("sigma-inf", ["--sigma", "inf"], "--sigma"),
    ("sigma-nan", ["--sigma", "nan"], "--sigma"),
    ("sigma-negative", ["--sigma", "-0.01"], "sigma"),
    ("dtm-scale-nan", ["--dtm-scale", "nan"], "--dtm-scale"),
    ("dtm-scale-two", ["--dtm-scale", "2"], "--dtm-scale"),
    ("dead-elements-negative", ["--dead-elements", "-1"], "element"),
    ("damaged-elements-absurd", ["--damaged-elements", BIG], "elements"),
    ("scheduler-garbage", ["--scheduler", "garbage"], "scheduler"),
    ("scheduler-no-port", ["--scheduler", "tcp://host"], "scheduler"),
    ("scheduler-port-range", ["--scheduler", "tcp://host:99999"], "port"),
    ("scheduler-protocol", ["--scheduler", "ftp://host:21"], "protocol"),
    ("scheduler-port-superscript", ["--scheduler", "tcp://host:\u00b2"], "digits 0-9"),  # was a ValueError traceback
    # Integers are ASCII digits: click's int() took these as 3, 8, 1000, 8 and 2.
    ("scans-arabic-indic-digit", ["--scans", "\u0663"], "'--scans': '\u0663' is not"),
    ("scans-fullwidth-digit", ["--scans", "\uff18"], "'--scans': '\uff18' is not"),
    ("shard-size-underscore", ["--shard-size", "1_000"], "'--shard-size': '1_000' is not"),
    ("scans-blanks", ["--scans", " 8 "], "'--scans': ' 8 ' is not"),
    ("seed-plus", ["--seed", "+2"], "'--seed': '+2' is not"),
    ("workers-devanagari-digit", ["--workers", "\u0968"], "'--workers': '\u0968' is not"),
    # More shard files than the stated bound (lidarsim.limits.MAX_SHARD_FILES) without --max-shards.
    ("shard-files-beyond-bound", ["--scans", "200000", "--shard-size", "1"], "200,000 shard files"),
    ("shard-files-beyond-max-shards", ["--scans", "8", "--shard-size", "2", "--max-shards", "3"], "4 shard files"),
    ("dtm-missing", ["--dtm", "{tmp}/missing.tif"], "missing.tif"),
    ("dtm-directory", ["--dtm", "{tmp}"], "directory"),
    ("dtm-not-a-raster", ["--dtm", "{file}"], "not a raster"),
]


@pytest.fixture
def places(tmp_path):
    file = tmp_path / "regular-file"
    file.write_text("a user's file\n")
    broken = tmp_path / "broken-link"
    broken.symlink_to(tmp_path / "nowhere")
    return {"tmp": str(tmp_path), "file": str(file), "broken": str(broken)}


def _fill(args, places, **more):
    return [a.format(**places, **more) for a in args]


def _no_work(monkeypatch, *targets):
    def refuse(*args, **kwargs):
        raise AssertionError("work started before the options were checked")

    for module, name in targets:  # the module itself: hdnet.fit, the package's attribute, is the function
        monkeypatch.setattr(importlib.import_module(module), name, refuse)


def _snapshot(tmp):
    from pathlib import Path

    return sorted(str(p) for p in Path(tmp).rglob("*"))


@pytest.mark.parametrize(("case", "args", "needle"), BUILD, ids=[c[0] for c in BUILD])
def test_build_dataset_refuses(case, args, needle, places, dtm, monkeypatch):
    _no_work(monkeypatch, ("lidarsim.build", "plan_scans"), ("lidarsim.build", "_procedural_terrain_bytes"))
    argv = _fill(args, places)
    if "--out" not in argv:
        argv = ["--out", f"{places['tmp']}/never", *argv]
    if "--dtm" not in argv:
        argv += ["--dtm", str(dtm)]
    if "--scans" not in argv:
        argv += ["--scans", "8"]
    before = _snapshot(places["tmp"])
    assert_one_line_error(invoke("build-dataset", *argv), needle)
    assert _snapshot(places["tmp"]) == before


LABEL = [
    ("dem-size-one", ["--dem-size", "1"], "dem"),
    ("dem-size-absurd", ["--dem-size", "100000"], "dem"),
    ("dem-spacing-inf", ["--dem-spacing", "inf"], "--dem-spacing"),
    ("dem-spacing-nan", ["--dem-spacing", "nan"], "--dem-spacing"),
    ("dem-spacing-zero", ["--dem-spacing", "0"], "dem"),
    ("lander-nan", ["--lander-diameter", "nan"], "--lander-diameter"),
    ("lander-inf", ["--lander-diameter", "inf"], "--lander-diameter"),
    ("lander-negative", ["--lander-diameter", "-10"], "diameter"),
    ("lander-larger-than-dem", ["--lander-diameter", "150"], "larger than the DEM"),
    ("lander-far-larger-than-dem", ["--lander-diameter", "1000"], "larger than the DEM"),  # was "internal: ..."
    ("pad-nan", ["--pad-diameter", "nan"], "--pad-diameter"),
    ("slope-nan", ["--max-slope-deg", "nan"], "--max-slope-deg"),
    ("slope-ninety", ["--max-slope-deg", "90"], "slope"),
    ("roughness-inf", ["--max-roughness", "inf"], "--max-roughness"),
    ("yaws-zero", ["--yaws", "0"], "yaws"),
    ("workers-negative", ["--workers", "-1"], "--workers"),
    ("scheduler-garbage", ["--scheduler", "not a scheduler"], "scheduler"),
]


@pytest.mark.parametrize(("case", "args", "needle"), LABEL, ids=[c[0] for c in LABEL])
def test_label_refuses(case, args, needle, data_copy, monkeypatch):
    _no_work(monkeypatch, ("hdlabels.labeling", "run_label_task"))
    before = _snapshot(data_copy)
    assert_one_line_error(invoke("label", data_copy, *args), needle)
    assert _snapshot(data_copy) == before


@pytest.mark.parametrize(
    ("target", "needle"),
    [
        ("/proc", "not an hd dataset"),
        ("{file}", "not a directory|is a file"),
        ("{tmp}/missing", "no such"),
        ("{tmp}", "not an hd dataset"),
    ],
    ids=["proc", "a-file", "missing", "empty-dir"],
)
def test_label_refuses_what_is_not_a_dataset(target, needle, places):
    before = _snapshot(places["tmp"])
    assert_one_line_error(invoke("label", target.format(**places)), needle)
    assert _snapshot(places["tmp"]) == before


MAKE_DTM = [
    ("under-proc", ["/proc/hd-test.tif"], "/proc"),
    ("under-a-file", ["{file}/x.tif"], "not a directory"),
    ("is-a-directory", ["{tmp}"], "is a directory"),
    ("missing-parent", ["{tmp}/no/x.tif"], "does not exist"),
    ("empty", [""], "must not be empty"),
    ("seed-negative", ["{tmp}/x.tif", "--seed", "-1"], "--seed"),
    ("size-inf", ["{tmp}/x.tif", "--size", "inf"], "--size"),
    ("spacing-nan", ["{tmp}/x.tif", "--spacing", "nan"], "--spacing"),
    ("spacing-too-coarse", ["{tmp}/x.tif", "--spacing", "5"], "spacing"),
    ("size-absurd", ["{tmp}/x.tif", "--size", "1e9"], "cells per side"),
    ("rock-k-out-of-range", ["{tmp}/x.tif", "--rock-k", "2"], "--rock-k"),
    ("craters-below-nan", ["{tmp}/x.tif", "--craters-below", "nan"], "--craters-below"),
]


@pytest.mark.parametrize(("case", "args", "needle"), MAKE_DTM, ids=[c[0] for c in MAKE_DTM])
def test_make_dtm_refuses(case, args, needle, places, monkeypatch):
    _no_work(monkeypatch, ("lidarsim.procedural", "generate_mars_terrain"))
    before = _snapshot(places["tmp"])
    assert_one_line_error(invoke("make-dtm", *_fill(args, places)), needle)
    assert _snapshot(places["tmp"]) == before


TRAIN = [
    ("out-under-proc", ["--out", "/proc/hd-run"], "/proc"),
    ("out-under-a-file", ["--out", "{file}/run"], "not a directory"),
    ("out-is-a-file", ["--out", "{file}"], "not a directory|is a file"),
    ("out-empty", ["--out", ""], "must not be empty"),
    ("num-workers-negative", ["--num-workers", "-1"], "--num-workers"),
    ("num-workers-absurd", ["--num-workers", "100000"], "--num-workers"),
    ("seed-negative", ["--seed", "-1"], "--seed"),
    ("sigma-nan", ["--train-sigma", "nan"], "--train-sigma"),
    ("sigma-inf", ["--train-sigma", "inf"], "--train-sigma"),
    ("epochs-zero", ["--epochs", "0"], "--epochs"),
    ("epochs-negative", ["--epochs", "-3"], "--epochs"),
    ("resume-and-overwrite", ["--resume", "--overwrite"], "exclude"),
]


@pytest.mark.parametrize(("case", "args", "needle"), TRAIN, ids=[c[0] for c in TRAIN])
def test_train_refuses(case, args, needle, places, labelled, monkeypatch):
    _no_work(monkeypatch, ("hdnet.fit", "compute_normalisation"))
    argv = _fill(args, places)
    if "--out" not in argv:
        argv = ["--out", f"{places['tmp']}/run", *argv]
    before = _snapshot(places["tmp"])
    assert_one_line_error(invoke("train", labelled, *argv, "--profile", "tiny"), needle)
    assert _snapshot(places["tmp"]) == before


def _other_data(labelled, place):
    """A dataset of other data for the mix checks: a copy of ``labelled`` with its manifest written
    in another layout (another sha256; the same scans, which these checks do not look at)."""
    import json
    import shutil

    shutil.copytree(labelled, place)
    manifest = place / "manifest.json"
    manifest.write_text(json.dumps(json.loads(manifest.read_text()), indent=1))
    return place


MIXES = [
    # (case, the --also arguments, the two arguments the error names)
    ("dataset-again", ["{data}"], ("DATASET {data}", "--also {data}")),
    ("link-to-dataset", ["{link}"], ("DATASET {data}", "--also {link}")),
    ("copy-of-dataset", ["{copy}"], ("DATASET {data}", "--also {copy}")),
    ("dataset-as-second-also", ["{other}", "{data}"], ("DATASET {data}", "--also {data}")),
    ("same-also-twice", ["{other}", "{other}"], ("--also {other}", "--also {other}")),
    ("link-to-an-also", ["{other}", "{other_link}"], ("--also {other}", "--also {other_link}")),
]


@pytest.mark.parametrize(("case", "also", "names"), MIXES, ids=[c[0] for c in MIXES])
def test_train_refuses_a_mix_that_names_the_same_data_twice(case, also, names, labelled, tmp_path, monkeypatch):
    """hd train DATASET --also DATASET (or a link to it, a byte-identical copy, the same --also twice)
    trained on the same scans twice per epoch and recorded a mix of two datasets."""
    import shutil

    places = {"data": str(labelled), "link": str(tmp_path / "link"), "copy": str(tmp_path / "copy")}
    places |= {"other": str(tmp_path / "other"), "other_link": str(tmp_path / "other-link")}
    (tmp_path / "link").symlink_to(labelled)
    shutil.copytree(labelled, tmp_path / "copy")
    _other_data(labelled, tmp_path / "other")
    (tmp_path / "other-link").symlink_to(tmp_path / "other")
    _no_work(monkeypatch, ("hdnet.fit", "compute_normalisation"), ("hdnet.fit", "already_trained"))
    argv = [x for a in also for x in ("--also", a.format(**places))]
    before = _snapshot(tmp_path)
    line = assert_one_line_error(
        invoke("train", labelled, "--out", tmp_path / "run", "--profile", "tiny", *argv), "same data", "once"
    )
    for name in names:
        assert name.format(**places) in line, (name, line)
    assert _snapshot(tmp_path) == before


EVAL = [
    ("out-under-proc", ["--out", "/proc/hd-report"], "/proc"),
    ("out-under-a-file", ["--out", "{file}/report"], "not a directory"),
    ("out-is-a-file", ["--out", "{file}"], "not a directory|is a file"),
    ("mc-samples-zero", ["--mc-samples", "0"], "--mc-samples"),
    ("mc-samples-absurd", ["--mc-samples", BIG], "--mc-samples"),
    ("batch-size-zero", ["--batch-size", "0"], "--batch-size"),
    ("batch-size-absurd", ["--batch-size", BIG], "--batch-size"),
    ("drop-pixels-negative", ["--drop-pixels", "-1"], "drop-pixels"),
    ("drop-pixels-absurd", ["--drop-pixels", BIG], "drop-pixels"),
    ("seed-negative", ["--seed", "-1"], "--seed"),
    ("threshold-garbage", ["--threshold", "garbage"], "threshold"),
    ("threshold-quantile-nan", ["--threshold", "quantile:nan"], "quantile"),
    ("threshold-quantile-two", ["--threshold", "quantile:2"], "quantile"),
    ("threshold-risk-inf", ["--threshold", "risk:inf"], "alpha"),
    ("nav-sigma-nan", ["--nav-sigma", "nan"], "--nav-sigma"),
    ("nav-sigma-inf", ["--nav-sigma", "inf"], "--nav-sigma"),
    ("nav-sigma-negative", ["--nav-sigma", "-1"], "--nav-sigma"),
    ("site-margin-nan", ["--site-margin", "nan"], "--site-margin"),
    ("site-margin-inf", ["--site-margin", "inf"], "--site-margin"),
    ("site-margin-absurd", ["--site-margin", "51"], "--site-margin"),
    # Sweeps are checked, and their number of levels bounded, before anything is expanded or loaded.
    ("sigma-sweep-no-step", ["--sigma-sweep", "0:0.1"], "e.g. 0:0.1:0.01"),
    ("sigma-sweep-subnormal-step", ["--sigma-sweep", "0:0.12:5e-324"], "finer than noise levels"),  # OverflowError
    ("sigma-sweep-tiny-step", ["--sigma-sweep", "0:0.12:5e-32"], "finer than noise levels"),
    ("sigma-sweep-repeated-levels", ["--sigma-sweep", "0:1e-12:1e-13"], "finer than noise levels"),  # 2 distinct
    ("sigma-sweep-too-many-levels", ["--sigma-sweep", "0:0.12:0.0001"], "a STEP of at least 0.000603"),
    ("mc-samples-arabic-indic-digit", ["--mc-samples", "\u0668"], "'--mc-samples': '\u0668' is not"),
]


@pytest.mark.parametrize(("case", "args", "needle"), EVAL, ids=[c[0] for c in EVAL])
def test_eval_refuses(case, args, needle, places, labelled, trained, monkeypatch):
    if case.startswith(("out-", "mc-", "batch-", "seed-", "threshold-", "nav-", "sigma-sweep-")):
        _no_work(monkeypatch, ("hdnet.trained_run", "load_trained_model"))  # checked before the model is loaded
    else:
        _no_work(monkeypatch, ("hdnet.evaluate", "infer_split"))  # needs the labelling's DEM size first
    argv = _fill(args, places)
    if "--out" not in argv:
        argv = ["--out", f"{places['tmp']}/report", *argv]
    before = _snapshot(places["tmp"])
    assert_one_line_error(invoke("eval", trained, "--data", labelled, *argv), needle)
    assert _snapshot(places["tmp"]) == before


@pytest.mark.parametrize(
    ("command", "args", "needle"),
    [
        ("demo", ["--epochs", "0"], "--epochs"),
        ("demo", ["--scans", "0"], "--scans"),
        ("demo", ["--scans", "2"], "--scans"),
        ("demo", ["--workers", "0"], "--workers"),
        ("demo", ["--out", "/proc/hd-demo"], "/proc"),
        ("demo", ["--out", "{file}/demo"], "not a directory"),
        ("reproduce", ["--epochs", "0"], "--epochs"),
        ("reproduce", ["--out", "/proc/hd-repro"], "/proc"),
        ("reproduce", ["--dtm", "{tmp}/missing.tif"], "missing.tif"),
    ],
    ids=[
        "demo-epochs-0",
        "demo-scans-0",
        "demo-scans-2",
        "demo-workers-0",
        "demo-proc",
        "demo-under-file",
        "reproduce-epochs-0",
        "reproduce-proc",
        "reproduce-dtm-missing",
    ],
)
def test_multi_stage_commands_check_every_stage_first(command, args, needle, places, monkeypatch):
    _no_work(monkeypatch, ("hdcli.pipeline", "_build_unless_done"))
    argv = _fill(args, places)
    if "--out" not in argv:
        argv = ["--out", f"{places['tmp']}/chain", *argv]
    before = _snapshot(places["tmp"])
    assert_one_line_error(invoke(command, *argv), needle)
    assert _snapshot(places["tmp"]) == before


def test_read_only_file_system_is_refused_before_work(tmp_path, dtm, monkeypatch):
    from reliability_kit import tmpfs

    _no_work(monkeypatch, ("lidarsim.build", "plan_scans"))
    with tmpfs(tmp_path / "ro", "1m", "ro") as ro:
        assert_one_line_error(invoke("build-dataset", "--out", ro / "data", "--dtm", dtm), "read-only")
        assert_one_line_error(invoke("make-dtm", ro / "x.tif"), "read-only")


def test_every_float_option_rejects_nan_and_inf():
    """Guard for new options: each float option of every command is covered by a case above."""
    from click.types import FloatParamType

    from hdcli.cli import main

    covered = {
        a for rows in (BUILD, LABEL, MAKE_DTM, TRAIN, EVAL) for _, args, _ in rows for a in args if a.startswith("--")
    }  # detect's --nav-sigma and --site-margin are eval's settings (one Bound each): covered by eval's cases
    floats = {
        f"{c}:{o}"
        for c, cmd in main.commands.items()
        for p in cmd.params
        if isinstance(p.type, FloatParamType)
        for o in p.opts
    }
    assert len(floats) >= 15  # every float option of every command, FloatRange ones included
    missing = sorted(f for f in floats if f.split(":")[1] not in covered)
    assert missing == [], f"float options without a non-finite case: {missing}"
    assert math.isnan(float("nan"))


def _numeric_options() -> list[tuple[str, click.Command, click.Option]]:
    """(command name, command, option) for every int or float option of every command."""
    from hdcli.cli import main

    return [
        (c, cmd, p)
        for c, cmd in sorted(main.commands.items())
        for p in cmd.params
        if isinstance(p, click.Option) and not p.is_flag and isinstance(p.type, IntParamType | FloatParamType)
    ]


NUMERIC = _numeric_options()


def test_every_numeric_option_has_a_bound_shown_in_its_help():
    """Guard for new options: every numeric option of every command has a declared range (from the
    packages' limits modules), shown by --help, and no range written by hand into its help text."""
    assert len(NUMERIC) >= 40
    unbounded, hidden, by_hand = [], [], []
    for c, cmd, p in NUMERIC:
        name = f"{c} {p.opts[0]}"
        if not isinstance(p.type, _NumberRangeBase) or (p.type.min is None and p.type.max is None):
            unbounded.append(name)
            continue
        record = p.get_help_record(click.Context(cmd, info_name=c))
        assert record is not None
        if p.type._describe_range() not in record[1]:
            hidden.append(name)
        if re.search(r"\d\s*\.\.\s*\d|\(\s*[<>]=?\s*\d", p.help or ""):
            by_hand.append(name)
    assert unbounded == [], f"numeric options without a range: {unbounded}"
    assert hidden == [], f"ranges not shown in --help: {hidden}"
    assert by_hand == [], f"ranges written into the help text instead of declared: {by_hand}"


def _outside(t: _NumberRangeBase) -> str:
    """A value just outside the range of ``t``."""
    integer = isinstance(t, click.IntRange)
    if t.min is not None:
        value = t.min if t.min_open else t.min - (1 if integer else 0.5)
    elif t.max is not None:
        value = t.max if t.max_open else t.max + (1 if integer else 0.5)
    else:
        pytest.fail(f"no range: {t!r}")
    return str(int(value)) if integer else repr(float(value))


@pytest.mark.parametrize(
    ("command", "option"), [(c, p) for c, _, p in NUMERIC], ids=[f"{c}{p.opts[0]}" for c, _, p in NUMERIC]
)
def test_a_value_outside_its_range_is_a_usage_error_before_work(command, option, tmp_path):
    """One line naming the option and its range; nothing created (click refuses it before the command runs)."""
    from hdcli.cli import main

    cmd = main.commands[command]
    argv = [command]
    for p in cmd.params:
        if p.required and p is not option and p.name != option.name:
            argv += [str(tmp_path / "x")] if isinstance(p, click.Argument) else [p.opts[0], str(tmp_path / "x")]
    if not isinstance(option.type, _NumberRangeBase):
        pytest.fail(f"{command} {option.opts[0]} has no range")
    result = invoke(*argv, option.opts[0], _outside(option.type))
    last = assert_one_line_error(result, f"'{option.opts[0]}'")
    assert result.exit_code == 2 and option.type._describe_range() in last, result.output
    assert list(tmp_path.iterdir()) == []


# Scan lists are ASCII digits and ranges, and the number of scans they name is bounded
# (lidarsim.limits.SCANS) before the list is expanded.
EXPORT = [
    ("superscript", "\u00b2", "'\u00b2' is not"),  # was a ValueError traceback
    ("superscript-in-a-range", "1-\u00b3", "'\u00b3' is not"),  # was a ValueError traceback
    ("arabic-indic", "\u0663", "'\u0663' is not"),  # was scan 3
    ("too-many-digits", "9" * 5000, "digits"),  # was a ValueError traceback (int() refuses 4301+ digits)
    ("beyond-the-bound", "0-1000000", "1,000,001 scans"),  # was a list of a million scans, then the export
]


@pytest.mark.parametrize(("case", "text", "needle"), EXPORT, ids=[c[0] for c in EXPORT])
def test_export_refuses_scan_lists(case, text, needle, reference, tmp_path, monkeypatch):
    _no_work(monkeypatch, ("lidarsim.export", "export_scans"))
    last = assert_one_line_error(invoke("export", reference, "--out", tmp_path / "laz", "--scans", text), needle)
    assert "--scans" in last and len(last) < 300, last
    assert list(tmp_path.iterdir()) == []


def _refusal(t: click.ParamType, text: str, p: click.Parameter, ctx: click.Context) -> str | None:
    """click's message refusing ``text`` for ``p``, or None when it takes it."""
    try:
        t.convert(text, p, ctx)
    except click.BadParameter as exc:
        return exc.message
    return None


def test_every_integer_option_takes_ascii_digits_only():
    """Guard for new options: every integer option of every command refuses a value inside its range
    written with other digits (Arabic-Indic, fullwidth), with underscores, blanks or a '+', naming
    the text; the ASCII digits of the same value are taken (click's own int() took all of them)."""
    others = {
        "arabic-indic": str.maketrans("0123456789", "\u0660\u0661\u0662\u0663\u0664\u0665\u0666\u0667\u0668\u0669")
    }
    others["fullwidth"] = str.maketrans("0123456789", "\uff10\uff11\uff12\uff13\uff14\uff15\uff16\uff17\uff18\uff19")
    integers = [(c, cmd, p) for c, cmd, p in NUMERIC if isinstance(p.type, IntParamType)]
    assert len(integers) >= 25
    taken = []
    for c, cmd, p in integers:
        t = p.type
        assert isinstance(t, _NumberRangeBase)
        low = 0 if t.min is None else int(t.min) + (1 if t.min_open else 0)
        value = low + 1 if t.max is None or low + 1 <= t.max else low  # two digits where the range allows
        ctx = click.Context(cmd, info_name=c)
        assert t.convert(str(value), p, ctx) == value
        texts = [str(value).translate(table) for table in others.values()]
        texts += [f" {value}", f"{value} ", f"+{value}", f"0_{value}"]
        for text in texts:
            refusal = _refusal(t, text, p, ctx)
            if refusal is None:
                taken.append(f"{c} {p.opts[0]} {text!r}")
            else:
                assert repr(text) in refusal and "digits 0-9" in refusal, refusal
    assert taken == [], f"integer options that take more than ASCII digits: {taken}"


def test_a_build_may_make_more_shard_files_when_told_and_records_nothing_of_it(reference, dtm, tmp_path):
    """--max-shards allows a build beyond the bound (here: lowered to the build's own 4 shards) and
    leaves no trace in the dataset: every file is byte-identical to the build without it."""
    import hashlib

    out = tmp_path / "data"
    result = invoke("build-dataset", "--out", out, "--dtm", dtm, "--workers", "1", "--max-shards", "4", *BUILD_ARGS)
    assert result.exit_code == 0, result.output

    def sums(root):
        return {
            str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*"))
            if p.is_file()
        }

    assert sums(out) == sums(reference)


def test_a_recipe_beyond_the_shard_file_bound_needs_max_shards(tmp_path, monkeypatch):
    _no_work(monkeypatch, ("lidarsim.build", "plan_scans"), ("lidarsim.build", "_procedural_terrain_bytes"))
    recipe = tmp_path / "many"
    recipe.mkdir()
    (recipe / "recipe.toml").write_text("[build]\nscans = 20000\nshard_size = 1\n")
    before = _snapshot(tmp_path)
    result = invoke("build-dataset", "--recipe", recipe, "--out", tmp_path / "data")
    assert_one_line_error(result, "20,000 shard files", "--max-shards 20000")
    assert _snapshot(tmp_path) == before


def test_partial_names_that_are_not_ascii_pids_are_not_hds(tmp_path):
    """A file named like a partial write whose "PID" is not written in ASCII digits is not hd's:
    it is left alone (a superscript made the clean-up raise ValueError; Arabic-Indic digits read as
    PID 3, long dead, and the file was deleted)."""
    import subprocess

    from hdcore.storage import write_bytes_atomic

    final = tmp_path / "manifest.json"
    strangers = [tmp_path / ".manifest.json.partial-\u00b2", tmp_path / ".manifest.json.partial-\u0663"]
    for p in strangers:
        p.write_text("a user's file\n")
    dead = subprocess.Popen(["true"])
    dead.wait()
    leftover = tmp_path / f".manifest.json.partial-{dead.pid}"  # a killed writer's: still removed
    leftover.write_text("{")
    write_bytes_atomic(final, b"{}")
    assert final.read_bytes() == b"{}" and all(p.exists() for p in strangers) and not leftover.exists()


@pytest.mark.parametrize(
    "args",
    [
        ["verify", "{data}", "--recipe", "no\rsuch"],  # a name in an hd error
        ["verify", "{data}", "--recipe", "no\nsuch\x1b[2J"],
        ["label", "{data}", "--lander", "x\ry"],  # a value in click's usage error
    ],
)
def test_user_text_in_an_error_never_breaks_its_one_line(labelled, args):
    result = invoke(*[str(labelled) if a == "{data}" else a for a in args])
    last = assert_one_line_error(result)
    assert "\r" not in result.output and "\x1b" not in result.output
    assert "x\\ry" in last or "no\\rsuch" in last or "no such\\x1b[2J" in last, last
