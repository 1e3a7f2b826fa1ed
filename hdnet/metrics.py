"""Segmentation metrics from one 2x2 confusion matrix accumulated over a whole split (paper, Eq. 3-6).

Classes: 0 = unsafe, 1 = safe; ``confusion[i, j]`` counts pixels of true class i predicted j, built
with ``torch.bincount(2 * truth + prediction)`` over *valid* pixels (truth != 255 and not in the
optional extra ignore mask, e.g. the dead-pixel neighbourhoods).

Uncertainty-aware method (paper, "Quantitative Comparison"): pixels flagged uncertain
(entropy >= threshold) are removed from the confusion matrix, so pixel accuracy, mIoU and precision
are computed over valid *and certain* pixels; but a truly safe pixel dropped as uncertain counts as a
false unsafe for sensitivity: sensitivity = TS / (TS + FU + uncertain true-safe). The V/C fraction is
(valid and certain pixels) / (valid pixels).

A ratio whose denominator is zero is reported as NaN ("undefined", e.g. precision with no pixel
predicted safe); mIoU averages the IoU of the classes whose union is non-empty.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from hdnet import defaults
from hdnet.errors import HdNetError


@dataclass(frozen=True)
class SegmentationMetrics:
    """Dataset-level scores (fractions in [0, 1]); ``vc_fraction`` is None without uncertainty thresholding."""

    pixel_accuracy: float
    miou: float
    precision_safe: float
    sensitivity_safe: float
    vc_fraction: float | None


def _ratio(num: int, den: int) -> float:
    return float(num) / float(den) if den > 0 else float("nan")


class ConfusionAccumulator:
    """Accumulates the 2x2 confusion matrix (and the uncertain true-safe count) batch by batch.

    ``uncertainty_aware=True`` makes ``update`` require an ``uncertain`` mask (and reports V/C).
    """

    def __init__(self, uncertainty_aware: bool = False, ignore_index: int = defaults.IGNORE_INDEX) -> None:
        self.uncertainty_aware = uncertainty_aware
        self.ignore_index = ignore_index
        self.confusion = torch.zeros(2, 2, dtype=torch.int64)
        self.n_valid = 0
        self.n_uncertain_true_safe = 0

    def update(
        self,
        truth: torch.Tensor,
        prediction: torch.Tensor,
        ignore: torch.Tensor | None = None,
        uncertain: torch.Tensor | None = None,
    ) -> None:
        """Add one batch. ``truth`` (..., H, W) in {0, 1, ignore_index}; ``prediction`` same shape in {0, 1};
        ``ignore`` / ``uncertain``: optional boolean masks of the same shape."""
        if truth.shape != prediction.shape:
            raise HdNetError(
                f"truth shape {tuple(truth.shape)} differs from prediction shape {tuple(prediction.shape)}."
            )
        for name, mask in (("ignore", ignore), ("uncertain", uncertain)):
            if mask is not None and mask.shape != truth.shape:
                raise HdNetError(
                    f"{name} mask shape {tuple(mask.shape)} differs from truth shape {tuple(truth.shape)}."
                )
        if self.uncertainty_aware and uncertain is None:
            raise HdNetError("an uncertainty-aware accumulator needs an uncertain mask for every update.")
        if not self.uncertainty_aware and uncertain is not None:
            raise HdNetError("an uncertain mask was given to an accumulator created with uncertainty_aware=False.")
        truth = truth.detach().cpu().long()
        prediction = prediction.detach().cpu().long()
        valid = truth != self.ignore_index
        if ignore is not None:
            valid &= ~ignore.detach().cpu().bool()
        bad_truth = valid & (truth != 0) & (truth != 1)
        if bad_truth.any() or ((prediction[valid] != 0) & (prediction[valid] != 1)).any():
            raise HdNetError(
                f"labels and predictions must be 0 (unsafe) or 1 (safe) on valid pixels (else {self.ignore_index})."
            )
        self.n_valid += int(valid.sum())
        certain = valid
        if uncertain is not None:
            unc = uncertain.detach().cpu().bool()
            self.n_uncertain_true_safe += int((valid & unc & (truth == defaults.CLASS_SAFE)).sum())
            certain = valid & ~unc
        codes = 2 * truth[certain] + prediction[certain]
        self.confusion += torch.bincount(codes, minlength=4).view(2, 2)

    def compute(self) -> SegmentationMetrics:
        """Scores from the accumulated counts."""
        return metrics_from_counts(
            self.confusion, self.n_valid, self.n_uncertain_true_safe, uncertainty_aware=self.uncertainty_aware
        )


def metrics_from_counts(
    confusion: torch.Tensor, n_valid: int, n_uncertain_true_safe: int = 0, uncertainty_aware: bool = False
) -> SegmentationMetrics:
    """PA, mIoU, precision/sensitivity of "safe" and V/C from a 2x2 confusion matrix of certain valid pixels."""
    c = confusion.to(torch.int64)
    n_certain = int(c.sum())
    ts, fs = int(c[1, 1]), int(c[0, 1])  # true safe, false safe (truly unsafe, predicted safe)
    fu = int(c[1, 0]) + n_uncertain_true_safe  # false unsafe, uncertain safe pixels included
    ious = []
    for k in range(2):
        union = int(c[k, :].sum() + c[:, k].sum() - c[k, k])
        if union > 0:
            ious.append(int(c[k, k]) / union)
    return SegmentationMetrics(
        pixel_accuracy=_ratio(int(c.trace()), n_certain),
        miou=sum(ious) / len(ious) if ious else float("nan"),
        precision_safe=_ratio(ts, ts + fs),
        sensitivity_safe=_ratio(ts, ts + fu),
        vc_fraction=_ratio(n_certain, n_valid) if uncertainty_aware else None,
    )
