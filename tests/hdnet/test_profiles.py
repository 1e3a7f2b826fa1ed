"""Training profiles: the paper's numbers, lookup and round trip."""

import pytest

from hdnet.errors import HdNetError
from hdnet.profiles import CPU, PAPER, TINY, get_profile, profile_from_dict


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
