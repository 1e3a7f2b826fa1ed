"""A run that learnt nothing is said to have learnt nothing: validation loss and H_t at ln 2."""

from __future__ import annotations

import math

from hdnet.chance import CHANCE_NATS, at_chance, loss_warning, threshold_warning


def test_chance_is_ln_2_within_2_percent():
    assert math.log(2.0) == CHANCE_NATS
    assert at_chance(0.693) and at_chance(0.68) and at_chance(0.70)
    assert not at_chance(0.67) and not at_chance(None) and not at_chance(math.inf) and not at_chance(math.nan)


def test_the_best_validation_loss_decides():
    said = loss_warning([0.6931, 0.6929, 0.6932])
    assert said is not None and said.startswith("Warning: the best validation loss, 0.693, is that of a coin")
    assert loss_warning([0.6931, 0.41]) is None  # it learnt, in the end
    assert loss_warning([]) is None and loss_warning([math.nan]) is None


def test_an_h_t_at_the_top_of_the_scale_is_one_line_with_the_sites():
    said = threshold_warning(0.6925, 0)
    assert said is not None and "\n" not in said
    assert "H_t = 0.693 nats is at the top of the entropy scale" in said and "and 0 site(s) found" in said
    assert "site" not in (threshold_warning(0.6925) or "")
    assert threshold_warning(0.3, 0) is None and threshold_warning(None, 0) is None
