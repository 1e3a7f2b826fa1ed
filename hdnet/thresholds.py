"""Uncertainty thresholds H_t from validation entropies: mean (paper), quantile, conformal risk control.

A pixel is *uncertain* (invalid) when its predictive entropy H >= H_t (paper, "Uncertainty-aware
Safety Map Generation"); all entropies are in nats. Every rule here applies as it stands to the other
uncertainty score, the mutual information (``hdnet.uncertainty``): "entropy" below is then the
pixel's mutual information, and H_t a threshold on it.

Specs (``parse_threshold_spec``):

* ``mean``: mean entropy over the valid validation pixels (paper default, after Mukhoti & Gal 2018);
* ``quantile:Q``: the Q-quantile (Q in [0, 1]) of those entropies (paper, "Effect of Varying the
  Uncertainty Threshold");
* ``risk:ALPHA``: conformal risk control (Angelopoulos et al. 2022, "Conformal Risk Control"), beyond
  the paper. Per image i the loss at threshold t is the **false-safe rate**

      L_i(t) = #{valid pixels: truly unsafe, predicted safe, H < t} / #{valid pixels of image i},

  i.e. certain false-safe pixels over valid pixels. It is bounded by B = 1 and non-decreasing in t,
  which is what CRC needs for its guarantee. (The other candidate, the fraction of *certain
  predicted-safe* pixels that are truly unsafe, is not monotone in t, so CRC would not apply to it.)
  With n validation images and Rhat(t) = mean_i L_i(t), we return the largest t with

      n/(n+1) * Rhat(t) + B/(n+1) <= alpha,

  which guarantees E[L_{n+1}(t)] <= alpha for a new image exchangeable with the validation images.
  If even t = 0 (every pixel uncertain, loss 0) fails, i.e. alpha < 1/(n+1), t = 0 is returned (the
  only choice that keeps the guarantee): such an alpha is *unreachable* with n images, whatever the
  network, and needs at least ``risk_images_needed(alpha)`` = ceil(1/alpha) - 1 of them (19 for
  alpha = 0.05). n counts images, not pixels. ``risk_reach`` gives the threshold record's
  ``unreachable`` and ``needs_images``; ``hd eval`` and ``hd detect`` warn. If no false-safe pixel
  ever limits it, t = +inf (every pixel certain).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import torch

from hdcore.errors import HdWarning
from hdnet import defaults
from hdnet.errors import HdNetError
from hdnet.report_json import ThresholdJson
from hdnet.threshold_spec import (
    LOSS_BOUND,
    RULES,
    SPEC_FORMS,
    ThresholdRule,
    ThresholdSpec,
    parse_threshold_spec,
    risk_images_needed,
    risk_reach,
    unreachable_risk_words,
)

__all__ = [
    "LOSS_BOUND",
    "RULES",
    "SPEC_FORMS",
    "EntropyCalibration",
    "ThresholdRule",
    "ThresholdSpec",
    "parse_threshold_spec",
    "precision_threshold",
    "risk_images_needed",
    "risk_reach",
    "select_threshold",
    "uncertain_mask",
    "unreachable_risk_words",
    "warn_if_unreachable",
]


def warn_if_unreachable(record: ThresholdJson) -> None:
    """A one-line ``HdWarning`` when the threshold record ``record`` (``report.json``'s and
    ``detect.json``'s ``threshold``) is a risk level its calibration images cannot reach
    (``unreachable``, from :func:`risk_reach`)."""
    if record.get("unreachable"):
        words = unreachable_risk_words(
            str(record.get("spec")), int(record["calibration_images"]), int(record["needs_images"])
        )
        warnings.warn(words, HdWarning, stacklevel=2)


class EntropyCalibration:
    """Per-pixel entropies of a split (usually validation), added one batch of images at a time.

    Keeps the valid entropies (float32, for mean/quantile) and, per false-safe pixel, its entropy and
    weight 1 / (valid pixels of its image) (for the false-safe-rate risk). Memory: 4 bytes per valid
    pixel (100 images of 512x512: about 100 MB).
    """

    def __init__(self, ignore_index: int = defaults.IGNORE_INDEX) -> None:
        self.ignore_index = ignore_index
        self._entropies: list[np.ndarray] = []
        self._fs_entropies: list[np.ndarray] = []
        self._fs_weights: list[np.ndarray] = []
        self._ps_entropies: list[np.ndarray] = []  # pixels predicted safe: entropy, and whether truly safe
        self._ps_correct: list[np.ndarray] = []
        self.n_images = 0

    def update(
        self,
        entropy_nats: torch.Tensor,
        prediction: torch.Tensor,
        truth: torch.Tensor,
        ignore: torch.Tensor | None = None,
    ) -> None:
        """Add a batch: all tensors (N, H, W); ``truth`` 0/1/ignore_index, ``prediction`` 0/1, ``ignore`` bool."""
        if entropy_nats.dim() != 3 or entropy_nats.shape != prediction.shape or entropy_nats.shape != truth.shape:
            raise HdNetError(
                f"entropy, prediction and truth must share one (N, H, W) shape, got {tuple(entropy_nats.shape)}, "
                f"{tuple(prediction.shape)}, {tuple(truth.shape)}."
            )
        h = entropy_nats.detach().cpu().float()
        t = truth.detach().cpu().long()
        p = prediction.detach().cpu().long()
        valid = t != self.ignore_index
        if ignore is not None:
            valid &= ~ignore.detach().cpu().bool()
        for i in range(h.shape[0]):
            v = valid[i]
            n_valid = int(v.sum())
            self.n_images += 1
            if n_valid == 0:
                continue  # loss 0 for every t; the image still counts in n
            self._entropies.append(h[i][v].numpy())
            fs = v & (t[i] == defaults.CLASS_UNSAFE) & (p[i] == defaults.CLASS_SAFE)
            e = h[i][fs].numpy()
            self._fs_entropies.append(e)
            self._fs_weights.append(np.full(e.shape, 1.0 / n_valid))
            ps = v & (p[i] == defaults.CLASS_SAFE)
            self._ps_entropies.append(h[i][ps].numpy())
            self._ps_correct.append((t[i][ps] == defaults.CLASS_SAFE).numpy())

    def _all(self) -> np.ndarray:
        if not self._entropies:
            raise HdNetError("no valid pixel was added to the entropy calibration set.")
        return np.concatenate(self._entropies)

    def mean(self) -> float:
        """Mean entropy over all valid pixels (nats)."""
        return float(np.mean(self._all(), dtype=np.float64))

    def quantile(self, q: float) -> float:
        """The q-quantile of the valid-pixel entropies (nats; linear interpolation)."""
        return float(np.quantile(self._all(), q))

    def fraction_below(self, threshold_nats: float) -> float:
        """The validation quantile of a threshold: the fraction of valid pixels with entropy < H_t
        (the pixels it leaves certain; 1 for an unbounded H_t)."""
        return float(np.mean(self._all() < threshold_nats))

    def _false_safe(self) -> tuple[np.ndarray, np.ndarray]:
        if self.n_images == 0:
            raise HdNetError("no image was added to the entropy calibration set.")
        e = np.concatenate(self._fs_entropies) if self._fs_entropies else np.zeros(0, np.float32)
        w = np.concatenate(self._fs_weights) if self._fs_weights else np.zeros(0)
        return e, w

    def risk(self, threshold_nats: float) -> float:
        """Mean over images of the false-safe rate at H_t (certain = H < H_t)."""
        e, w = self._false_safe()
        return float(w[e < threshold_nats].sum() / self.n_images)

    def risk_control_threshold(self, alpha: float) -> float:
        """Largest H_t with n/(n+1) Rhat(H_t) + B/(n+1) <= alpha (see the module docstring)."""
        if not 0.0 < alpha < 1.0:
            raise HdNetError(f"the risk level alpha must be in (0, 1), got {alpha}.")
        e, w = self._false_safe()
        n = self.n_images
        order = np.argsort(e, kind="stable")
        e, w = e[order], w[order]
        # cum[k] = Rhat just above the k-th smallest false-safe entropy (k+1 pixels certain).
        cum = np.cumsum(w) / n
        if n < risk_images_needed(alpha):  # LOSS_BOUND / (n + 1) > alpha: even t = 0 is all it allows
            return 0.0
        feasible = n / (n + 1) * cum + LOSS_BOUND / (n + 1) <= alpha
        # Number of leading false-safe pixels that can be certain: first infeasible index.
        k = int(np.argmin(feasible)) if not feasible.all() else len(e)
        return math.inf if k == len(e) else float(e[k])


def precision_threshold(calibration: EntropyCalibration, precision: float) -> float:
    """The loosest H_t (nats) at which the certain predicted-safe pixels of the calibration set are
    truly safe in at least a fraction ``precision`` of cases; 0 (nothing certain) when no threshold
    reaches it, +inf when every threshold does.

    Used as the guard of ``hd eval --calibrate each`` above a run's training noise range
    (``hdnet.evaluate``): there the network's own ranking is not trusted, only what the validation
    split at that noise level shows.
    """
    if not 0.0 < precision <= 1.0:
        raise HdNetError(f"the precision guard must be in (0, 1], got {precision}.")
    e = np.concatenate(calibration._ps_entropies) if calibration._ps_entropies else np.zeros(0, np.float32)
    ok = np.concatenate(calibration._ps_correct) if calibration._ps_correct else np.zeros(0, bool)
    if e.size == 0:
        return math.inf
    order = np.argsort(e, kind="stable")
    e, ok = e[order], ok[order]
    tp = np.cumsum(ok)
    reached = tp >= precision * np.arange(1, e.size + 1)  # precision of the k+1 most certain >= target
    if reached.all():
        return math.inf
    hits = np.flatnonzero(reached)
    if hits.size == 0:
        return 0.0
    k = int(hits[-1])  # the k+1 most certain pixels are certain: H_t just above e[k]
    if k == e.size - 1:  # all of them together reach it (some shorter prefix did not)
        return math.inf
    return float(e[k + 1]) if e[k + 1] > e[k] else float(e[k])  # a tie at e[k]: leave the tied pixels out


def select_threshold(spec: ThresholdSpec | str, calibration: EntropyCalibration) -> float:
    """H_t (nats) for ``spec`` from a calibration (validation) set, by its rule (``ThresholdSpec.rule``)."""
    if isinstance(spec, str):
        spec = parse_threshold_spec(spec)
    return spec.select(calibration)


def uncertain_mask(entropy_nats: torch.Tensor, threshold_nats: float) -> torch.Tensor:
    """Boolean mask of uncertain (invalid) pixels: H >= H_t (paper, "Uncertainty-aware Safety Map")."""
    return entropy_nats >= threshold_nats
