"""One DEM sample on the DEM grid: the record that ``hdnet.data`` reads and ``hdnet.augment`` transforms.

A leaf module (it imports only NumPy), so the dataset and the augmentation both depend on it and
not on each other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DemSample:
    """One scan on the DEM grid after dead-pixel repair, before normalisation (metres, north-up).

    ``dem_noisy_m``: the (repaired) noisy DEM with NaN holes; ``dem_filled_m``: the same with holes
    filled; ``label``: int64 with 255 on invalid cells and holes; ``p_safe``: the stored ALHAT
    baseline P(safe), or None for a DEM made on the fly (see ``HazardDataset.baseline_p_safe``);
    ``ignore``: dead-pixel neighbourhoods (all False without dead pixels); ``dead_pixels``: (K, 2)
    (row, col); ``sigma_m``: the DEM's noise level, metres.
    """

    scan_index: int
    dem_clean_m: np.ndarray
    dem_noisy_m: np.ndarray
    dem_filled_m: np.ndarray
    label: np.ndarray
    p_safe: np.ndarray | None
    ignore: np.ndarray
    dead_pixels: np.ndarray
    sigma_m: float = math.nan
