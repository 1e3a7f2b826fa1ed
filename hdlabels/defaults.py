"""The numbers hdlabels uses by default, each with its source.

Paper: Tomita, Skinner & Ho, "Bayesian Deep Learning for Segmentation for Autonomous Safe
Planetary Landing" (``shared/seed/bayesian-segnet-hazard-detection.tex``), section "Label
generation", which replicates the ALHAT hazard detection of Ivanov, Huertas & Carson (2013).
The lander numbers are the ALHAT defaults used by the paper's authors (``shared/DESIGN.md``,
"Lander and labels"). Values marked "hd choice" are not in the paper; ``docs/labels.md`` explains them.
"""

from __future__ import annotations

# --- Lander (DESIGN.md "Lander and labels": ALHAT defaults used by the paper's authors) -------------
# Lander diameter: the disk of this diameter is the lander body over the terrain, metres.
LANDER_DIAMETER_M: float = 10.0
# Footpad diameter, metres.
PAD_DIAMETER_M: float = 1.0
# Pad centres lie on a circle of radius (lander diameter - pad diameter) / 2 = 4.5 m (pads inside the body).
PAD_CENTRE_RADIUS_M: float = (LANDER_DIAMETER_M - PAD_DIAMETER_M) / 2.0
# Critical slope: a site is unsafe if the lander would rest tilted by this much or more, degrees.
MAX_SLOPE_DEG: float = 10.0
# Critical roughness: unsafe if terrain under the body reaches this far above the lander plane, metres.
MAX_ROUGHNESS_M: float = 0.20
# Lander layout: 4 pads in a square (ALHAT / Morpheus); a 3-pad triangle is the option.
LAYOUT: str = "square"

# --- Evaluation choices (hd choice; docs/labels.md) -------------------------------------------------
# Yaws per symmetry period of the pad layout (90 deg for the square, 120 deg for the triangle):
# 8 gives 11.25 deg steps, i.e. pad centres 0.88 m apart along their 4.5 m circle, one pad per pixel.
N_YAWS: int = 8
# Points on each pad's rim where the bilinear terrain is sampled (plus grid nodes inside the pad).
PAD_RIM_SAMPLES: int = 8
# Holes (terrain below the lander plane) do not count as roughness by default.
COUNT_HOLES: bool = False

# --- DEM (paper, "Dataset preparation": 100x100 at 1 m per pixel) -----------------------------------
DEM_ROWS: int = 100
DEM_COLS: int = 100
DEM_SPACING_M: float = 1.0

# --- Labels (public encoding, issue 3) --------------------------------------------------------------
LABEL_UNSAFE: int = 0
LABEL_SAFE: int = 1
LABEL_INVALID: int = 255

# --- Baseline (paper, "Label generation": "adopting a safety threshold of 50%") -------------------
SAFE_PROBABILITY_THRESHOLD: float = 0.5

# --- Dead elements (paper, "Damaged elements": ten random pixels dropped from the 100x100 DEM) -----
N_DEAD_PIXELS: int = 10
