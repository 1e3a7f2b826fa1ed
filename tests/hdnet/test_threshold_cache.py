"""The threshold cache (``RUN/thresholds.json``) trusts nothing it reads: every forged field is ignored
with a warning and the threshold calibrated again."""

from __future__ import annotations

import json
import math
import os
import signal
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

import pytest

from hdcore.errors import HdWarning
from hdnet.report_json import ThresholdJson
from hdnet.threshold_cache import (
    CACHE_FILE,
    MAX_FILE_BYTES,
    CachedThreshold,
    ThresholdKey,
    entry_digest,
)

KEY = ThresholdKey(
    checkpoint_sha256="a" * 64,
    manifest_sha256="b" * 64,
    labels="paper-square",
    sigma_m=0.0167,
    spec="mean",
    calibrate="reference",
    mc_samples=8,
    batch_size=4,
    seed=0,
)
INFO = cast(ThresholdJson, {"spec": "mean", "kind": "mean", "value_nats": 0.4321, "n_pixels": 1000})  # any JSON record


def stored(tmp_path: Path, value: float | None = 0.4321, info: dict[str, Any] | None = None) -> CachedThreshold:
    cache = CachedThreshold(tmp_path)
    assert cache.put(
        KEY, math.inf if value is None else value, cast(ThresholdJson, dict(INFO if info is None else info))
    )
    return cache


def edit(cache: CachedThreshold, change: Callable[[dict[str, Any]], None]) -> None:
    record = json.loads(cache.path.read_text())
    change(record["entries"][0])
    cache.path.write_text(json.dumps(record))  # NaN and Infinity written as JSON's extensions


def test_an_entry_round_trips_with_its_digest(tmp_path):
    cache = stored(tmp_path)
    entry = json.loads(cache.path.read_text())["entries"][0]
    assert entry["sha256"] == entry_digest(KEY.to_dict(), 0.4321, entry["info"])
    assert cache.get(KEY) == (0.4321, INFO)
    (tmp_path / "u").mkdir()
    unbounded = stored(tmp_path / "u", None, dict(INFO, value_nats=None))
    assert unbounded.get(KEY) == (math.inf, dict(INFO, value_nats=None))


def _value(v: Any) -> Callable[[dict[str, Any]], None]:
    return lambda e: e.update(value_nats=v)


def _value_and_record(v: Any) -> Callable[[dict[str, Any]], None]:
    """The value edited in both places, so only the digest (or the range) can tell."""

    def change(e: dict[str, Any]) -> None:
        e.update(value_nats=v)
        e["info"].update(value_nats=v)

    return change


FORGERIES: dict[str, tuple[Callable[[dict[str, Any]], None], str]] = {
    "value 5.0": (_value(5.0), "outside the score's range"),
    "value NaN": (_value(float("nan")), "outside the score's range"),
    "value -1": (_value(-1), "outside the score's range"),
    "value true": (_value(True), "is not a number"),
    "value 1e308": (_value(1e308), "outside the score's range"),
    "value Infinity": (_value(float("inf")), "outside the score's range"),
    "value a string": (_value("0.2"), "is not a number"),
    "value unbounded (null)": (_value(None), "record states 0.4321"),
    "value and record both edited": (_value_and_record(0.05), "sha256 does not match"),
    "value and record both unbounded": (_value_and_record(None), "sha256 does not match"),
    "record's spec": (lambda e: e["info"].update(spec="quantile:0.9"), "of the rule 'quantile:0.9'"),
    "record not an object": (lambda e: e.update(info=[1, 2]), "not an object"),
    "record edited": (lambda e: e["info"].update(n_pixels=7), "sha256 does not match"),
    "digest missing": (lambda e: e.pop("sha256"), "not {key, value_nats, info, sha256}"),
    "digest wrong": (lambda e: e.update(sha256="0" * 64), "sha256 does not match"),
    "digest not a string": (lambda e: e.update(sha256=12), "sha256 does not match"),
    "an extra field": (lambda e: e.update(trusted=True), "not {key, value_nats, info, sha256}"),
}


@pytest.mark.parametrize("forgery", sorted(FORGERIES))
def test_every_forged_field_is_ignored_with_a_warning(tmp_path, forgery):
    change, why = FORGERIES[forgery]
    cache = stored(tmp_path)
    edit(cache, change)
    with pytest.warns(HdWarning, match=why) as caught:
        assert cache.get(KEY) is None
    assert "calibrated again" in str(caught[0].message)


def test_an_entry_of_another_key_is_never_used(tmp_path):
    cache = stored(tmp_path)
    edit(cache, lambda e: e["key"].update(checkpoint_sha256="c" * 64))
    assert cache.get(KEY) is None


@pytest.mark.parametrize(
    ("damage", "why"),
    [
        ("not json", "unreadable threshold cache"),
        ("huge integer", "unreadable threshold cache"),  # past Python's 4300 digits: a ValueError, not JSON's
        ("another schema", "not a threshold cache"),
        ("version 7", "unknown version 7"),
        ("too large", "more than the"),
        ("fifo", "is a FIFO"),
        ("directory", "is a directory"),
    ],
)
def test_a_damaged_or_odd_cache_file_is_ignored_with_a_warning_and_never_blocks(tmp_path, damage, why):
    cache = CachedThreshold(tmp_path)
    path = tmp_path / CACHE_FILE
    if damage == "not json":
        path.write_text("{not json")
    elif damage == "huge integer":
        path.write_text('{"schema": "hd.threshold-cache", "schema_version": 2, "n": 1' + "0" * 5000 + "}")
    elif damage == "another schema":
        path.write_text(json.dumps({"schema": "hd.other", "entries": []}))
    elif damage == "version 7":
        path.write_text(json.dumps({"schema": "hd.threshold-cache", "schema_version": 7, "entries": []}))
    elif damage == "too large":
        with path.open("wb") as f:
            f.truncate(MAX_FILE_BYTES + 1)
    elif damage == "fifo":
        os.mkfifo(path)
    else:
        path.mkdir()
    signal.alarm(20)  # a FIFO opened for reading would wait for a writer
    try:
        with pytest.warns(HdWarning, match=why):
            assert cache.get(KEY) is None
    finally:
        signal.alarm(0)


def test_a_cache_of_version_1_is_replaced_without_a_warning(tmp_path, recwarn):
    path = tmp_path / CACHE_FILE
    path.write_text(
        json.dumps(
            {
                "schema": "hd.threshold-cache",
                "schema_version": 1,
                "entries": [{"key": KEY.to_dict(), "value_nats": 0.1, "info": {}}],
            }
        )
    )
    cache = CachedThreshold(tmp_path)
    assert cache.get(KEY) is None and not [w for w in recwarn if issubclass(w.category, HdWarning)]
    assert cache.put(KEY, 0.4321, INFO) and cache.get(KEY) == (0.4321, INFO)


@pytest.mark.parametrize("value", [float("nan"), -0.5, 3.0, -math.inf])
def test_a_value_outside_the_score_range_is_never_stored(tmp_path, value):
    cache = CachedThreshold(tmp_path)
    assert not cache.put(KEY, value, INFO)
    assert not (tmp_path / CACHE_FILE).exists()
