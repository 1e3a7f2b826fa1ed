"""Metrics: hand-computed counts, ignore masks, the uncertain/false-unsafe convention, accumulation."""

import math

import pytest
import torch

from hdnet.errors import HdNetError
from hdnet.metrics import ConfusionAccumulator, metrics_from_counts

# 0 unsafe, 1 safe, 255 ignored. Eight pixels by hand:
TRUTH = torch.tensor([[1, 1, 1, 0], [0, 0, 1, 255]])
PRED = torch.tensor([[1, 1, 0, 0], [1, 0, 1, 1]])
# valid: 7 pixels. TS = 3 (0,0)(0,1)(1,2); FU = 1 (0,2); TU = 2 (0,3)(1,1); FS = 1 (1,0).


def test_hand_computed_counts() -> None:
    acc = ConfusionAccumulator()
    acc.update(TRUTH, PRED)
    assert acc.confusion.tolist() == [[2, 1], [1, 3]]
    m = acc.compute()
    assert m.pixel_accuracy == pytest.approx(5 / 7)
    # IoU(unsafe) = 2 / (3 + 3 - 2) = 0.5; IoU(safe) = 3 / (4 + 4 - 3) = 0.6
    assert m.miou == pytest.approx(0.55)
    assert m.precision_safe == pytest.approx(3 / 4)
    assert m.sensitivity_safe == pytest.approx(3 / 4)
    assert m.vc_fraction is None


def test_uncertain_safe_pixels_are_false_unsafe_for_sensitivity_only() -> None:
    # Uncertain: (0,0) true safe predicted safe, (1,0) true unsafe predicted safe, and the ignored pixel.
    unc = torch.tensor([[True, False, False, False], [True, False, False, True]])
    acc = ConfusionAccumulator(uncertainty_aware=True)
    acc.update(TRUTH, PRED, uncertain=unc)
    # Certain valid pixels: (0,1) TS, (0,2) FU, (0,3) TU, (1,1) TU, (1,2) TS -> 5 of 7 valid.
    assert acc.confusion.tolist() == [[2, 0], [1, 2]]
    m = acc.compute()
    assert m.pixel_accuracy == pytest.approx(4 / 5)
    assert m.precision_safe == pytest.approx(1.0)
    assert m.sensitivity_safe == pytest.approx(2 / (2 + 1 + 1))  # the uncertain true-safe pixel counts
    assert m.vc_fraction == pytest.approx(5 / 7)
    assert m.miou == pytest.approx((2 / 3 + 2 / 3) / 2)


def test_extra_ignore_mask_and_accumulation_over_batches_equals_one_pass() -> None:
    gen = torch.Generator().manual_seed(0)
    truth = torch.randint(0, 2, (6, 16, 16), generator=gen)
    truth[:, :2] = 255
    pred = torch.randint(0, 2, (6, 16, 16), generator=gen)
    ignore = torch.rand(6, 16, 16, generator=gen) < 0.1
    unc = torch.rand(6, 16, 16, generator=gen) < 0.3
    whole = ConfusionAccumulator(uncertainty_aware=True)
    whole.update(truth, pred, ignore=ignore, uncertain=unc)
    parts = ConfusionAccumulator(uncertainty_aware=True)
    for i in range(6):
        parts.update(truth[i], pred[i], ignore=ignore[i], uncertain=unc[i])
    assert torch.equal(whole.confusion, parts.confusion) and whole.compute() == parts.compute()
    valid = (truth != 255) & ~ignore
    certain = valid & ~unc
    assert whole.confusion.sum() == certain.sum()
    assert whole.compute().vc_fraction == pytest.approx(certain.sum().item() / valid.sum().item())
    ts = ((truth == 1) & (pred == 1) & certain).sum().item()
    safe_valid = ((truth == 1) & valid).sum().item()
    assert whole.compute().sensitivity_safe == pytest.approx(ts / safe_valid)


def test_zero_denominators_are_nan() -> None:
    m = metrics_from_counts(torch.tensor([[5, 0], [0, 0]]), n_valid=5)
    assert m.pixel_accuracy == 1.0 and m.miou == 1.0  # only the unsafe class is present
    assert math.isnan(m.precision_safe) and math.isnan(m.sensitivity_safe)


def test_bad_inputs_raise() -> None:
    acc = ConfusionAccumulator()
    with pytest.raises(HdNetError):
        acc.update(TRUTH, PRED[:, :3])
    with pytest.raises(HdNetError):
        acc.update(TRUTH, PRED, uncertain=torch.zeros_like(TRUTH, dtype=torch.bool))
    with pytest.raises(HdNetError):
        acc.update(torch.tensor([2]), torch.tensor([1]))
    with pytest.raises(HdNetError):
        ConfusionAccumulator(uncertainty_aware=True).update(TRUTH, PRED)


def test_against_torchmetrics_on_random_inputs() -> None:
    tm = pytest.importorskip("torchmetrics.functional.classification")
    gen = torch.Generator().manual_seed(1)
    truth = torch.randint(0, 2, (4, 32, 32), generator=gen)
    pred = torch.randint(0, 2, (4, 32, 32), generator=gen)
    truth[truth.clone().bernoulli_(0.1, generator=gen).bool()] = 255
    acc = ConfusionAccumulator()
    acc.update(truth, pred)
    m = acc.compute()
    assert torch.equal(acc.confusion, tm.multiclass_confusion_matrix(pred, truth, 2, ignore_index=255))
    kw = {"num_classes": 2, "ignore_index": 255, "average": "micro"}
    assert m.pixel_accuracy == pytest.approx(tm.multiclass_accuracy(pred, truth, **kw).item())
    assert m.miou == pytest.approx(
        tm.multiclass_jaccard_index(pred, truth, 2, ignore_index=255, average="macro").item()
    )
    keep = truth != 255
    assert m.precision_safe == pytest.approx(tm.binary_precision(pred[keep], truth[keep]).item())
    assert m.sensitivity_safe == pytest.approx(tm.binary_recall(pred[keep], truth[keep]).item())
