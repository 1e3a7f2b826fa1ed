"""The paper's Tables 1 and 2, to print next to measured numbers.

Source: Tomita, Skinner & Ho, "Bayesian Deep Learning for Segmentation for Autonomous Safe
Planetary Landing" ("the paper" in docs/references.md), Table "results" (Table 1:
trained at 1.67 cm, tested at 1.67 / 3 / 7 cm) and Table "results_hole" (Table 2: ten dropped
pixels, tested at 1.67 cm). V/C is printed in the paper as a percentage; here it is a fraction.
"""

from __future__ import annotations

from dataclasses import dataclass

from lidarsim.defaults import SIGMA_S167_M as S167
from lidarsim.defaults import SIGMA_S300_M as S300
from lidarsim.defaults import SIGMA_S700_M as S700

PAPER_SIGMA_TOLERANCE_M = 0.5e-4  # a measured sigma matches a paper column within 0.05 mm (0.0167 ~ 0.05/3)


@dataclass(frozen=True)
class PaperRow:
    """One row of the paper's tables (fractions; ``vc_fraction`` None where the paper prints "--")."""

    table: str
    method: str
    test_sigma_m: float
    vc_fraction: float | None
    pixel_accuracy: float
    miou: float
    precision: float
    sensitivity: float


PAPER_ROWS: tuple[PaperRow, ...] = (
    # Table 1 (paper, Table "results")
    PaperRow("noise", "alhat_baseline", S167, None, 0.9345, 0.8294, 0.9798, 0.7506),
    PaperRow("noise", "base_net", S167, None, 0.8687, 0.7347, 0.6639, 0.9488),
    PaperRow("noise", "uncertainty_aware", S167, 0.64, 0.9839, 0.9615, 0.9493, 0.7182),
    PaperRow("noise", "alhat_baseline", S300, None, 0.8702, 0.6663, 0.9795, 0.4849),
    PaperRow("noise", "base_net", S300, None, 0.8516, 0.7095, 0.6330, 0.9510),
    PaperRow("noise", "uncertainty_aware", S300, 0.63, 0.9712, 0.9343, 0.9228, 0.7375),
    PaperRow("noise", "alhat_baseline", S700, None, 0.7539, 0.3790, 0.9723, 0.0044),
    PaperRow("noise", "base_net", S700, None, 0.8487, 0.7032, 0.6321, 0.9284),
    PaperRow("noise", "uncertainty_aware", S700, 0.58, 0.9722, 0.9320, 0.9092, 0.5934),
    # Table 2 (paper, Table "results_hole"): ten dropped pixels, lander-size neighbourhoods ignored
    PaperRow("dead_pixels", "alhat_baseline", S167, None, 0.9350, 0.8299, 0.9796, 0.7511),
    PaperRow("dead_pixels", "base_net", S167, None, 0.8687, 0.7308, 0.6715, 0.9122),
    PaperRow("dead_pixels", "uncertainty_aware", S167, 0.63, 0.9828, 0.9567, 0.9488, 0.6517),
)


def paper_row(table: str, method: str, test_sigma_m: float) -> PaperRow | None:
    """The paper's row for (table, method, test sigma in metres), or None if the paper has none."""
    for row in PAPER_ROWS:
        if (
            row.table == table
            and row.method == method
            and abs(row.test_sigma_m - test_sigma_m) <= PAPER_SIGMA_TOLERANCE_M
        ):
            return row
    return None
