"""The numbers hdlabels uses by default, each with its source.

Paper: Tomita, Skinner & Ho, "Bayesian Deep Learning for Segmentation for Autonomous Safe
Planetary Landing" ("the paper" in ``docs/references.md``), section "Label generation", which
replicates the ALHAT hazard detection of Ivanov, Huertas & Carson ("Ivanov et al. 2013"). The
lander numbers are the ALHAT defaults used by the paper's authors (``docs/labels.md``, "Lander").
Values marked "hd choice" are not in the paper; ``docs/labels.md`` explains them.
"""

from __future__ import annotations

from typing import Literal

# --- Lander (the ALHAT defaults used by the paper's authors; docs/labels.md) -----------------------
# Lander diameter: the disk of this diameter is the lander body over the terrain, metres.
LANDER_DIAMETER_M: float = 10.0
# Footpad diameter, metres (hd convention: pad centres on a circle of radius (10 - 1) / 2 = 4.5 m,
# the pads inside the body; hdlabels.lander.Lander.pad_centre_radius_m).
PAD_DIAMETER_M: float = 1.0
# Critical slope: a site is unsafe if the lander would rest tilted by this much or more, degrees.
MAX_SLOPE_DEG: float = 10.0
# Critical roughness: unsafe if terrain under the body reaches this far above the lander plane, metres.
MAX_ROUGHNESS_M: float = 0.20
# Lander layout: 4 pads in a square (ALHAT / Morpheus); a 3-pad triangle is the option.
LAYOUTS: tuple[str, ...] = ("square", "triangle")
LAYOUT: Literal["square", "triangle"] = "square"

# --- Label conventions (docs/labels.md "Two conventions") -------------------------------------------
# "paper": the ALHAT replica the paper's numbers rest on (the paper author's public pydem library at
# commit e7734ae, April 2023, docs/references.md); "hd": hd's own geometric convention.
CONVENTIONS: tuple[str, ...] = ("paper", "hd")
CONVENTION: Literal["paper", "hd"] = "paper"
# How the baseline combines the per-node probabilities Phi((r_crit - r) / s) of one lander
# configuration: "product" (Ivanov et al. 2013, Eq. 13; the paper's replica) or "min" (worst node).
BASELINE_COMBINES: tuple[str, ...] = ("product", "min")
BASELINE_COMBINE: dict[str, str] = {"paper": "product", "hd": "min"}
# How points become a DEM: "linear" (the detector's triangulation interpolated at cell centres),
# "mean", "max" or "nearest" (the points falling in each cell, binned). The paper convention's
# choice is the one whose DEM keeps the paper's noise level: the paper's noisy DEMs carry 1-sigma
# noise of 1.67 / 3 / 7 cm and its baseline uses that sigma as the DEM's noise. Measured on flat
# terrain (docs/labels.md, "Gridding"): linear keeps 0.70 sigma, mean 0.89, max 1.01 with a
# +0.25 sigma bias, nearest 1.00 without bias; nearest also brings the baseline closest to the
# paper's Table 1 (with max a near tie).
GRIDDINGS: tuple[str, ...] = ("linear", "mean", "max", "nearest")
GRIDDING: dict[str, str] = {"paper": "nearest", "hd": "linear"}

# --- Paper convention (the replica's rules, docs/labels.md "The paper convention") ------------------
# Lander orientations are evaluated every 10 degrees over a full turn (the replica's default step).
PAPER_ORIENTATION_STEP_DEG: float = 10.0

# --- Evaluation choices of the hd convention (hd choice; docs/labels.md) ---------------------------
# Yaws per symmetry period of the pad layout (90 deg for the square, 120 deg for the triangle):
# 8 gives 11.25 deg steps, i.e. pad centres 0.88 m apart along their 4.5 m circle, one pad per pixel.
N_YAWS: int = 8
# Points on each pad's rim where the bilinear terrain is sampled (plus grid nodes inside the pad).
PAD_RIM_SAMPLES: int = 8
# Holes (terrain below the lander plane) do not count as roughness by default, in both conventions
# (the paper's replica ignores terrain below the plane at the commit above).
COUNT_HOLES: bool = False

# --- DEM (paper, "Dataset preparation": 100x100 at 1 m per pixel) -----------------------------------
DEM_ROWS: int = 100
DEM_COLS: int = 100
DEM_SPACING_M: float = 1.0
# hd choice: largest DEM side accepted (pixels), checked before anything is allocated.
MAX_DEM_SIDE_PX: int = 2048

# --- Labels (the public encoding of label shards, docs/labels-format.md) ---------------------------
LABEL_UNSAFE: int = 0
LABEL_SAFE: int = 1
LABEL_INVALID: int = 255

# --- Baseline (paper, "Label generation": "adopting a safety threshold of 50%") -------------------
SAFE_PROBABILITY_THRESHOLD: float = 0.5

# --- Dead pixels (paper, "Damaged elements", Table 2: ten random pixels dropped from the 100x100 DEM;
# the dead-pixel test of `hd demo` and `hd reproduce`) ----------------------------------------------
N_DEAD_PIXELS: int = 10

# --- Truth of the deterministic labels (docs/labels.md, "Truth") ------------------------------------
# "clean-scan": the labels of the clean scan's DEM, as the paper makes them; "terrain": the labels of
# the DTM itself sampled on each scan's DEM grid (hd choice: the truth once the sensor blurs).
TRUTHS: tuple[str, ...] = ("clean-scan", "terrain")
TRUTH: Literal["clean-scan", "terrain"] = "clean-scan"
# hd choice: the terrain truth samples the DTM's surface at odd n x n points per DEM cell, at least
# two per DTM cell along each axis (n = the smallest odd number >= 2 * DEM spacing / DTM spacing,
# within these bounds), so that the cell centre is one of them and the "mean"/"max" griddings see
# every DTM cell under the DEM cell.
TERRAIN_SAMPLES_MIN: int = 3
TERRAIN_SAMPLES_MAX: int = 15
