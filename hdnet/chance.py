"""Has a run learnt anything? The signs of a network at chance, and the warning each command gives.

A two-class network that learnt nothing predicts P(safe) ≈ 0.5 everywhere: its cross-entropy on
the validation split is ln 2 ≈ 0.693 nats (the loss of a coin), and its predictive entropy is at the
top of its scale, ln 2, in every cell, so every threshold calibrated on it lies there too and no
site is certain. ``hd train`` (the best validation loss), ``hd eval`` (H_t), ``hd detect`` (H_t and
no site) and ``hd view`` (the same, from the files) say so in one line instead of passing such a
run on without a word.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

CHANCE_NATS = math.log(2.0)  # the cross-entropy and the predictive entropy of P(safe) = 0.5
# hd choice: a loss or an H_t within 2 % of ln 2 is taken for chance (a run that learnt a little has
# a validation loss of 0.5 or less on hd's datasets; one epoch of the tiny profile reaches ~0.6).
NEAR = 0.98
ADVICE = "train longer or on more scans, or check the labels (hd inspect DATASET)"


def at_chance(nats: float | None) -> bool:
    """True when a loss or an entropy threshold (nats) is within 2 % of ln 2, or above it."""
    return nats is not None and math.isfinite(nats) and nats >= NEAR * CHANCE_NATS


def loss_warning(val_losses: Iterable[float]) -> str | None:
    """The warning for a run whose best validation loss (nats) is at chance; None when it learnt."""
    finite = [v for v in val_losses if math.isfinite(v)]
    if not finite or not at_chance(min(finite)):
        return None
    return (
        f"Warning: the best validation loss, {min(finite):.3f}, is that of a coin (ln 2 = {CHANCE_NATS:.3f}): the "
        f"network predicts P(safe) ≈ 0.5 everywhere and has learnt nothing; {ADVICE}."
    )


def threshold_warning(h_t_nats: float | None, n_sites: int | None = None) -> str | None:
    """The warning for an H_t (nats) at the top of the entropy scale, with the number of sites found
    (``None``: not a detection); None when H_t is below it."""
    if not at_chance(h_t_nats):
        return None
    sites = "" if n_sites is None else f" and {n_sites} site(s) found"
    return (
        f"Warning: H_t = {h_t_nats:.3f} nats is at the top of the entropy scale (ln 2 = {CHANCE_NATS:.3f}){sites}: "
        f"the network is as uncertain as a coin everywhere, as a run that learnt nothing is; {ADVICE}."
    )
