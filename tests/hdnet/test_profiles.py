"""Training profiles: the paper's numbers, lookup and round trip."""

from typing import Any

import pytest

from hdnet.errors import HdNetError
from hdnet.profiles import CPU, PAPER, ROBUST, TINY, get_profile, profile_from_dict


def test_paper_profile_matches_the_paper() -> None:
    assert (PAPER.input_size, PAPER.width, PAPER.batch_size) == (512, 1.0, 8)
    assert (PAPER.optimizer, PAPER.lr, PAPER.momentum, PAPER.epochs) == ("sgd", 1e-4, 0.9, 10_000)


def test_small_profiles_use_native_size_and_reduced_width() -> None:
    for p in (CPU, TINY):
        assert p.input_size is None and p.width < 1.0 and p.epochs >= 1
    assert TINY.width < CPU.width


def test_lookup_and_round_trip() -> None:
    assert get_profile("cpu") is CPU
    assert profile_from_dict(TINY.to_dict()) == TINY
    with pytest.raises(HdNetError, match="unknown training profile"):
        get_profile("gpu")
    with pytest.raises(HdNetError):
        profile_from_dict({"name": "x"})


def test_new_fields_default_to_the_papers_choices_and_old_profiles_load() -> None:
    old_cpu = {
        "name": "cpu",
        "input_size": None,
        "width": 0.25,
        "batch_size": 8,
        "lr": 1e-3,
        "momentum": 0.9,
        "epochs": 80,
        "optimizer": "adam",
        "lr_schedule": "cosine",
    }  # as saved by hd 0.1.0
    p = profile_from_dict(old_cpu)
    assert (p.depth, p.dropout_p, p.heights, p.extra_channels, p.augment, p.class_weighting, p.channels_last) == (
        5,
        0.5,
        "minmax",
        (),
        "none",
        "none",
        False,
    )
    assert (PAPER.depth, PAPER.heights, PAPER.augment, PAPER.lr_schedule, PAPER.dropout_p) == (
        5,
        "minmax",
        "none",
        "constant",
        0.5,
    )


def test_every_profile_round_trips_through_json() -> None:
    import json

    for p in (PAPER, CPU, ROBUST, TINY):
        back = profile_from_dict(json.loads(json.dumps(p.to_dict())))
        assert back == p and isinstance(back.extra_channels, tuple)


def test_training_arithmetic_fields_are_saved_only_off_their_defaults() -> None:
    # A profile saved before precision and fast_dropout existed reads back as float32 with torch's masks,
    # and the profiles that keep those defaults save the same dictionary as before.
    assert "precision" not in CPU.to_dict() and "fast_dropout" not in PAPER.to_dict()
    assert (CPU.precision, CPU.fast_dropout) == ("float32", False)
    assert ROBUST.to_dict()["precision"] == "bfloat16" and ROBUST.to_dict()["fast_dropout"] is True


def test_invalid_fields_are_refused() -> None:
    from dataclasses import replace

    for field, value in (
        ("precision", "float16"),
        ("lr_schedule", "step"),
        ("augment", "mixup"),
        ("class_weighting", "focal"),
        ("heights", "zscore"),
        ("extra_channels", ("curvature",)),
        ("batch_size", 0),
    ):
        changed: dict[str, Any] = {field: value}
        with pytest.raises(HdNetError, match=field):
            replace(CPU, **changed)


def test_learning_rate_schedules_by_hand() -> None:
    import math
    from dataclasses import replace

    const = replace(CPU, lr_schedule="constant", lr=2e-3)
    assert const.learning_rate(0, 10) == const.learning_rate(7.5, 10) == 2e-3
    cos = replace(CPU, lr_schedule="cosine", lr=2e-3)
    assert cos.learning_rate(0, 10) == 2e-3 and math.isclose(cos.learning_rate(5, 10), 1e-3)
    assert math.isclose(cos.learning_rate(2.5, 10), 1e-3 * (1 + math.cos(math.pi / 4)))
    one = replace(CPU, lr_schedule="onecycle", lr=2e-3)
    start, end = 2e-3 / 25, 2e-3 / 25 / 1e4
    assert math.isclose(one.learning_rate(0, 10), start)
    assert math.isclose(one.learning_rate(1.5, 10), (start + 2e-3) / 2)  # half-way up the warm-up cosine
    assert math.isclose(one.learning_rate(3, 10), 2e-3)  # the peak at 30 %
    assert math.isclose(one.learning_rate(6.5, 10), (2e-3 + end) / 2)  # half-way down
    assert math.isclose(one.learning_rate(10, 10), end)
