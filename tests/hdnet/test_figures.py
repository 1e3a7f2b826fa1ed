"""The evaluation's figures: the qualitative panel explains its colours with a legend."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Patch

from hdnet import defaults
from hdnet.figures import SAFETY_HEX, SAFETY_NAMES, _safety_codes, qualitative_figure, qualitative_panel
from hdnet.results import SplitInference


def _inference(n: int = 2, size: int = 8) -> SplitInference:
    rng = np.random.default_rng(0)
    label = rng.integers(0, 2, (n, size, size)).astype(np.int64)
    label[:, 0, :] = defaults.IGNORE_INDEX
    heights = rng.normal(0.0, 0.1, (n, size, size)).astype(np.float32)
    return SplitInference(
        sigma_m=0.0167,
        scan_index=np.arange(n),
        label=label,
        ignore=np.zeros((n, size, size), bool),
        prob_safe=rng.random((n, size, size)).astype(np.float32),
        prediction=rng.integers(0, 2, (n, size, size)).astype(np.int64),
        entropy_nats=rng.random((n, size, size)).astype(np.float32) * 0.69,
        baseline_safe=rng.random((n, size, size)) > 0.5,
        dem_clean_m=heights,
        dem_noisy_m=heights + 0.01,
    )


def test_the_safety_maps_are_explained_by_a_legend_not_by_the_title(tmp_path):
    fig = qualitative_figure(_inference(), 1, threshold_nats=0.3)
    try:
        (legend,) = fig.legends
        assert [t.get_text() for t in legend.get_texts()] == list(SAFETY_NAMES)
        faces = [matplotlib.colors.to_hex(h.get_facecolor()) for h in legend.legend_handles if isinstance(h, Patch)]
        assert faces == list(SAFETY_HEX)
        title = fig.get_suptitle()
        assert "scan 1" in title and "1.67cm" in title and "green" not in title
    finally:
        plt.close(fig)
    qualitative_panel(_inference(), 0, None, tmp_path / "p.png")
    assert (tmp_path / "p.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_safety_codes_put_uncertain_over_the_prediction_and_invalid_over_both():
    label = np.array([[0, 1, 255]], np.int64)
    safe = np.array([[True, True, True]])
    uncertain = np.array([[False, True, True]])
    assert _safety_codes(safe, label, uncertain).tolist() == [[1, 2, 3]]
    assert _safety_codes(~safe, label).tolist() == [[0, 0, 3]]
