"""Thresholds: spec parsing, mean/quantile, the conformal risk-control rule by hand and its guarantee."""

import math

import numpy as np
import pytest
import torch

from hdnet.errors import HdNetError
from hdnet.thresholds import (
    EntropyCalibration,
    ThresholdSpec,
    parse_threshold_spec,
    precision_threshold,
    select_threshold,
    uncertain_mask,
)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("mean", ThresholdSpec("mean")),
        ("quantile:0.4", ThresholdSpec("quantile", 0.4)),
        ("risk:0.05", ThresholdSpec("risk", 0.05)),
        (" Quantile:1 ", ThresholdSpec("quantile", 1.0)),
    ],
)
def test_parse_good_specs(text: str, expected: ThresholdSpec) -> None:
    assert parse_threshold_spec(text) == expected


@pytest.mark.parametrize(
    "text",
    ["", "median", "mean:1", "quantile", "quantile:1.5", "quantile:-0.1", "risk:0", "risk:1", "risk:abc", "risk:"],
)
def test_parse_bad_specs_raise(text: str) -> None:
    with pytest.raises(HdNetError):
        parse_threshold_spec(text)


def _calibration() -> EntropyCalibration:
    # Image 0: 4 valid pixels (one ignored); image 1: 2 valid pixels.
    h = torch.tensor([[[0.1, 0.2, 0.3, 0.4, 0.6]], [[0.05, 0.5, 0.0, 0.0, 0.0]]])
    truth = torch.tensor([[[0, 0, 1, 0, 255]], [[0, 1, 255, 255, 255]]])
    pred = torch.tensor([[[1, 0, 1, 1, 1]], [[1, 1, 0, 0, 0]]])
    cal = EntropyCalibration()
    cal.update(h, pred, truth)
    return cal


def test_mean_quantile_and_risk_by_hand() -> None:
    cal = _calibration()
    valid = [0.1, 0.2, 0.3, 0.4, 0.05, 0.5]
    assert cal.mean() == pytest.approx(np.mean(valid))
    assert cal.quantile(0.5) == pytest.approx(np.quantile(valid, 0.5))
    assert select_threshold("quantile:0", cal) == pytest.approx(0.05)
    # False-safe pixels: image 0 at H = 0.1 and 0.4 (weight 1/4 each), image 1 at H = 0.05 (weight 1/2).
    assert cal.risk(0.05) == 0.0
    assert cal.risk(0.06) == pytest.approx(0.5 / 2)
    assert cal.risk(0.2) == pytest.approx((0.5 + 0.25) / 2)
    assert cal.risk(math.inf) == pytest.approx((0.5 + 0.5) / 2)


def test_risk_control_rule_by_hand() -> None:
    cal = _calibration()  # n = 2: n/(n+1) Rhat + 1/3 <= alpha
    # alpha 0.5: Rhat <= 0.25 -> the pixel at 0.05 may be certain, the one at 0.1 not -> t = 0.1.
    assert select_threshold("risk:0.5", cal) == pytest.approx(0.1)
    # alpha 0.4: Rhat <= 0.1 -> not even the first false-safe pixel -> t = 0.05.
    assert select_threshold("risk:0.4", cal) == pytest.approx(0.05)
    # alpha 0.99: Rhat <= 0.985 always -> every pixel certain.
    assert select_threshold("risk:0.99", cal) == math.inf
    # alpha < 1/(n+1): only t = 0 (everything uncertain) keeps the guarantee.
    assert select_threshold("risk:0.3", cal) == 0.0
    assert not uncertain_mask(torch.tensor([0.3]), math.inf).any() and uncertain_mask(torch.tensor([0.0]), 0.0).all()


def _synthetic_images(gen: torch.Generator, n: int, pixels: int = 256) -> tuple[torch.Tensor, ...]:
    """Exchangeable images: uncertain pixels are more often wrong; per-image difficulty varies."""
    difficulty = torch.rand(n, 1, 1, generator=gen)
    h = torch.rand(n, 1, pixels, generator=gen) * math.log(2)
    truth = (torch.rand(n, 1, pixels, generator=gen) < 0.5).long()
    wrong = torch.rand(n, 1, pixels, generator=gen) < difficulty * h / math.log(2)
    pred = torch.where(wrong, 1 - truth, truth)
    truth[:, :, :16] = 255  # a border of ignored pixels
    return h, pred, truth


def test_risk_control_meets_alpha_on_exchangeable_data() -> None:
    alpha, n_cal, n_test, reps = 0.05, 100, 40, 100
    gen = torch.Generator().manual_seed(7)
    achieved = []
    for _ in range(reps):
        cal, test = EntropyCalibration(), EntropyCalibration()
        cal.update(*_synthetic_images(gen, n_cal))
        test.update(*_synthetic_images(gen, n_test))
        achieved.append(test.risk(select_threshold(f"risk:{alpha}", cal)))
    mean, se = float(np.mean(achieved)), float(np.std(achieved) / math.sqrt(reps))
    assert mean <= alpha + 3 * se
    # Not vacuous: CRC is tight to within B/(n+1), and the data's risk without thresholding exceeds alpha.
    assert mean >= alpha - 2 / (n_cal + 1)
    assert test.risk(math.inf) > 2 * alpha


def test_empty_calibration_raises() -> None:
    with pytest.raises(HdNetError):
        EntropyCalibration().mean()
    with pytest.raises(HdNetError):
        EntropyCalibration().update(torch.zeros(2, 3), torch.zeros(2, 3), torch.zeros(2, 3))


def test_precision_guard_by_hand() -> None:
    """Predicted-safe pixels sorted by entropy: right, right, wrong, right, wrong (plus unsafe predictions)."""
    cal = EntropyCalibration()
    h = torch.tensor([[[0.1, 0.2, 0.3, 0.4, 0.5, 0.05]]])
    pred = torch.tensor([[[1, 1, 1, 1, 1, 0]]])
    truth = torch.tensor([[[1, 1, 0, 1, 0, 0]]])
    cal.update(h, pred, truth)
    # Precision of the k most certain predicted-safe pixels: 1, 1, 2/3, 3/4, 3/5.
    assert precision_threshold(cal, 1.0) == pytest.approx(0.3)  # the two most certain: H < 0.3
    assert precision_threshold(cal, 0.75) == pytest.approx(0.5)  # four: precision 3/4
    assert precision_threshold(cal, 0.6) == math.inf  # all five reach it
    dip = EntropyCalibration()  # right, wrong, right, right: 1, 1/2, 2/3, 3/4
    dip.update(
        torch.tensor([[[0.1, 0.2, 0.3, 0.4]]]), torch.ones(1, 1, 4, dtype=torch.long), torch.tensor([[[1, 0, 1, 1]]])
    )
    assert precision_threshold(dip, 0.7) == math.inf  # only all four reach 0.7: every pixel certain
    empty = EntropyCalibration()
    empty.update(h, torch.zeros_like(pred), truth)
    assert precision_threshold(empty, 0.95) == math.inf  # nothing predicted safe: nothing to guard
    wrong = EntropyCalibration()
    wrong.update(h, pred, torch.zeros_like(truth))
    assert precision_threshold(wrong, 0.5) == 0.0  # never right: nothing certain
    with pytest.raises(HdNetError, match="precision guard"):
        precision_threshold(cal, 0.0)


def test_a_fixed_threshold_in_nats_is_a_spec_like_the_others():
    from hdnet.thresholds import SPEC_FORMS, EntropyCalibration, parse_threshold_spec, select_threshold

    spec = parse_threshold_spec("nats:0.25")
    assert (spec.kind, spec.value, str(spec)) == ("nats", 0.25, "nats:0.25")
    assert select_threshold(spec, EntropyCalibration()) == 0.25  # no calibration needed
    assert parse_threshold_spec("NATS:inf").value == float("inf")
    for bad in ("nats:-0.1", "nats:nan", "nats"):
        with pytest.raises(HdNetError):
            parse_threshold_spec(bad)
    with pytest.raises(HdNetError, match="nats:H"):
        parse_threshold_spec("entropy:0.2")
    assert "nats:H" in SPEC_FORMS


@pytest.mark.parametrize(("alpha", "needed"), [(0.05, 19), (0.01, 99), (0.1, 9), (0.3, 3), (1 / 3, 2), (0.5, 1)])
def test_a_risk_level_below_one_over_n_plus_one_is_unreachable_and_says_how_many_images_it_needs(alpha, needed):
    """With n calibration images, risk:ALPHA keeps every pixel uncertain whatever the network when
    ALPHA < 1/(n+1): the images it needs are counted as the rule counts them (images, not pixels)."""
    from hdnet.thresholds import risk_images_needed, risk_reach, unreachable_risk_words

    assert risk_images_needed(alpha) == needed

    def perfect(n: int) -> EntropyCalibration:  # n images of 4 pixels, never false-safe
        cal = EntropyCalibration()
        cal.update(
            torch.full((n, 1, 4), 0.2), torch.ones(n, 1, 4, dtype=torch.long), torch.ones(n, 1, 4, dtype=torch.long)
        )
        return cal

    assert select_threshold(f"risk:{alpha}", perfect(needed)) == math.inf  # reachable: every pixel certain
    if needed > 1:
        assert select_threshold(f"risk:{alpha}", perfect(needed - 1)) == 0.0  # one image short: nothing certain
        assert risk_reach(alpha, needed - 1) == {"unreachable": True, "needs_images": needed}
    assert risk_reach(alpha, needed) == {"unreachable": False, "needs_images": needed}
    words = unreachable_risk_words("risk:0.05", 6, 19)
    assert "6 validation image(s)" in words and "at least 19 validation images" in words and "0.143" in words


def test_each_registered_rule_parses_selects_and_is_in_the_help() -> None:
    from hdnet.shared_settings import THRESHOLD_FORMS
    from hdnet.threshold_spec import RULES, SPEC_FORMS, ThresholdRule, parse_threshold_spec

    assert list(RULES) == ["mean", "quantile", "risk", "nats"]
    assert SPEC_FORMS == "'mean', 'quantile:Q', 'risk:ALPHA' or 'nats:H'"
    cal = EntropyCalibration()
    h = torch.tensor([[[0.1, 0.2], [0.3, 0.4]]])
    cal.update(h, torch.ones(1, 2, 2, dtype=torch.long), torch.ones(1, 2, 2, dtype=torch.long))
    by_hand = {"mean": 0.25, "quantile": 0.1 + 0.3 * 0.5, "risk": math.inf, "nats": 0.5}  # no false-safe pixel
    for name, rule in RULES.items():
        assert isinstance(rule, ThresholdRule) and rule.name == name
        assert rule.form in THRESHOLD_FORMS and rule.words in THRESHOLD_FORMS
        spec = parse_threshold_spec(name if not rule.takes_value else f"{name}:0.5")
        assert spec.rule is rule
        assert spec.select(cal) == pytest.approx(by_hand[name])
    assert [n for n, r in RULES.items() if not r.calibrated] == ["nats"]
    assert [n for n, r in RULES.items() if r.is_mean] == ["mean"]
    assert [n for n, r in RULES.items() if r.certifies_risk] == ["risk"]
    assert parse_threshold_spec("mean").rule.quantile_entry(cal, 0.25) == {}
    assert parse_threshold_spec("quantile:0.5").rule.quantile_entry(cal, 0.25) == {"value_quantile": 0.5}
    assert parse_threshold_spec("risk:0.05").reach(18) == {"unreachable": True, "needs_images": 19}
    assert parse_threshold_spec("nats:0.3").reach(18) == {}
