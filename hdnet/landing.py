"""Landing outcomes: the chosen site, where the vehicle touches down around it, and whether the ground there is safe.

A map (the ALHAT baseline, the base net, the uncertainty-aware map) chooses an aim point with
``hdnet.sites.select_sites``; the vehicle then lands around it with its navigation dispersion, and
the landing is scored against a **truth label map** (the terrain's, ``hd label --truth terrain``, or
the clean scan's, the paper's), never against the map that chose the site.

The model (docs/evaluation.md, "Landing outcome"):

* **Dispersion**: touchdown = aim + (e_x, e_y), e independent N(0, sigma^2) per horizontal axis,
  sigma in metres (``nav_sigma_m``; 0: the vehicle lands on its aim point).
* **The label at a point** is the label of the DEM cell that contains it: a label says whether a
  lander *centred* in that cell is safe (slope and roughness under its whole footprint), so one
  lookup judges the whole touchdown.
* **Unknown ground is not safe ground.** A touchdown outside the DEM, or in a cell without a label
  (the border band where the footprint leaves the DEM, or a hole of the terrain), counts as not
  safe, and its share is reported (``unknown_fraction``): the rate is a lower bound where the
  dispersion reaches the edge of what was scanned.
* **Per scene** the safe fraction of ``defaults.TOUCHDOWNS`` seeded touchdowns estimates
  P(safe | scene, site); the same draws serve every method of a scene (common random numbers, so
  methods are compared on the same dispersions).
* **Over scenes**, P(safe landing) is the mean of the per-scene fractions over the scenes where the
  method chose a site; its 95 % interval is Wilson's with n = those scenes. Each scene is one
  landing: the per-scene fractions vary less than the 0/1 outcome of one landing with the same mean,
  so the interval is conservative. A scene without a site is an **abstention**, counted apart
  (``abstain_rate``, with its own Wilson interval), never as a safe landing.

``cell_masses`` gives the exact probability of each cell under the same model, for the
dispersion-aware ranking of sites (``dispersion_weighted``) and as the tests' oracle of the
Monte Carlo.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.special import ndtr, ndtri

from hdnet import defaults
from hdnet.results import LandingRow

# hd choice: the Gaussian of the cell masses is cut where a cell's mass falls below 1e-9 of the whole
# (|k| <= 6 sigma + 1 cell).
MASS_CUT_SIGMAS = 6.0
CONFIDENCE = 0.95  # the level of every interval of a landing table
LANDING_STREAM = 0x4C414E44  # "LAND": the purpose key of the touchdown draws


def wilson_interval(successes: float, n: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Wilson score interval of a binomial rate (``successes`` of ``n``; a fraction of a success is
    allowed, for a mean of per-scene rates); (nan, nan) when n = 0."""
    if n <= 0:
        return (math.nan, math.nan)
    z = float(ndtri(0.5 + confidence / 2.0))
    p = min(max(successes / n, 0.0), 1.0)
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1.0 - p) / n + z * z / (4 * n * n)) / denom
    return (max(0.0, centre - half), min(1.0, centre + half))


def touchdown_offsets(n: int, nav_sigma_m: float, seed: int, scene: int) -> np.ndarray:
    """(n, 2) horizontal touchdown offsets (east, north), metres: N(0, nav_sigma_m^2) per axis, drawn
    from the stream keyed by (``seed``, ``scene``, the landing purpose). A given scene gets the same
    standard normals at every sigma (the offsets scale with it)."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(scene), LANDING_STREAM]))
    return rng.standard_normal((n, 2)) * float(nav_sigma_m)


def touchdown_cells(
    row: int, col: int, offsets_m: np.ndarray, spacing_xy_m: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """The (row, col) cells that contain the touchdowns ``offsets_m`` (east, north; metres) around the
    centre of cell (``row``, ``col``) of a north-up grid (rows grow southward)."""
    sx, sy = spacing_xy_m
    cols = np.floor(col + 0.5 + offsets_m[:, 0] / sx).astype(np.int64)
    rows = np.floor(row + 0.5 - offsets_m[:, 1] / sy).astype(np.int64)
    return rows, cols


@dataclass(frozen=True)
class TouchdownScore:
    """The touchdowns of one landing: ``safe`` and ``unknown`` fractions in [0, 1]."""

    safe: float
    unknown: float


def score_touchdowns(
    truth: np.ndarray, row: int, col: int, offsets_m: np.ndarray, spacing_xy_m: tuple[float, float]
) -> TouchdownScore:
    """Touchdowns ``offsets_m`` around cell (``row``, ``col``) scored against the label map ``truth``
    (1 safe, 0 unsafe, anything else unknown; outside the grid unknown)."""
    rows, cols = touchdown_cells(row, col, offsets_m, spacing_xy_m)
    h, w = truth.shape
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    labels = np.full(rows.shape, defaults.IGNORE_INDEX, np.int64)
    labels[inside] = truth[rows[inside], cols[inside]]
    n = max(len(rows), 1)
    return TouchdownScore(
        float(np.count_nonzero(labels == defaults.CLASS_SAFE)) / n,
        float(np.count_nonzero((labels != defaults.CLASS_SAFE) & (labels != defaults.CLASS_UNSAFE))) / n,
    )


def cell_masses(nav_sigma_m: float, spacing_m: float) -> np.ndarray:
    """(2k+1,) probabilities that a touchdown aimed at a cell centre lands k cells away along one axis:
    Phi((k + 1/2) s / sigma) - Phi((k - 1/2) s / sigma). The mass of cell (di, dj) is the product of
    two of them (the axes are independent). ``[1.0]`` for sigma = 0."""
    if nav_sigma_m <= 0.0:
        return np.ones(1)
    k = int(math.ceil(MASS_CUT_SIGMAS * nav_sigma_m / spacing_m)) + 1
    edges = (np.arange(-k, k + 2) - 0.5) * spacing_m / nav_sigma_m
    return np.diff(ndtr(edges))


def exact_safe_probability(
    truth: np.ndarray, row: int, col: int, nav_sigma_m: float, spacing_xy_m: tuple[float, float]
) -> float:
    """P(the touchdown lands on a safe cell) for an aim at the centre of (``row``, ``col``), exactly
    under the model (cell masses; outside the grid not safe)."""
    wy, wx = cell_masses(nav_sigma_m, spacing_xy_m[1]), cell_masses(nav_sigma_m, spacing_xy_m[0])
    ky, kx = len(wy) // 2, len(wx) // 2
    safe = np.pad(truth == defaults.CLASS_SAFE, ((ky, ky), (kx, kx)))
    window = safe[row : row + 2 * ky + 1, col : col + 2 * kx + 1]
    return float(wy @ window @ wx)


def dispersion_weighted(values: np.ndarray, nav_sigma_m: float, spacing_xy_m: tuple[float, float]) -> np.ndarray:
    """Each cell's expectation of ``values`` (0 outside the grid) at the touchdown of an aim at its centre:
    ``values`` correlated with the cell masses along both axes. Unchanged for sigma = 0."""
    out = np.asarray(values, np.float64)
    if nav_sigma_m <= 0.0:
        return out.copy()
    out = ndimage.correlate1d(out, cell_masses(nav_sigma_m, spacing_xy_m[1]), axis=0, mode="constant")
    return ndimage.correlate1d(out, cell_masses(nav_sigma_m, spacing_xy_m[0]), axis=1, mode="constant")


def truth_clearance_map(truth: np.ndarray, spacing_xy_m: tuple[float, float]) -> np.ndarray:
    """Per cell, the distance in metres between cell centres to the nearest cell of ``truth`` that is
    not safe (unsafe or unknown; outside the grid counts as unknown): 0 on ground that is not safe."""
    sx, sy = spacing_xy_m
    safe = np.pad(truth == defaults.CLASS_SAFE, 1)
    return ndimage.distance_transform_edt(safe, sampling=(sy, sx))[1:-1, 1:-1]


class LandingTally:
    """Accumulates the landings of one (method, noise level, dispersion, truth) cell of the table."""

    def __init__(self) -> None:
        self.scenes = 0
        self.safe: list[float] = []
        self.unknown: list[float] = []
        self.clearance: list[float] = []
        self.truth_clearance: list[float] = []

    def abstain(self) -> None:
        """A scene where the method found no site."""
        self.scenes += 1

    def land(self, score: TouchdownScore, clearance_m: float, truth_clearance_m: float) -> None:
        """A scene where the method chose a site and its touchdowns scored ``score``."""
        self.scenes += 1
        self.safe.append(score.safe)
        self.unknown.append(score.unknown)
        self.clearance.append(clearance_m)
        self.truth_clearance.append(truth_clearance_m)

    def row(self, method: str, test_sigma_m: float, nav_sigma_m: float, truth: str) -> LandingRow:
        """The table's row: P(safe landing) and abstentions with their intervals."""
        landed = len(self.safe)
        total = float(np.sum(self.safe)) if landed else 0.0
        lo, hi = wilson_interval(total, landed)
        abstained = self.scenes - landed
        alo, ahi = wilson_interval(abstained, self.scenes)

        def mean(xs: list[float]) -> float:
            return float(np.mean(xs)) if xs else math.nan

        return LandingRow(
            method,
            test_sigma_m,
            nav_sigma_m,
            truth,
            self.scenes,
            landed,
            total / landed if landed else math.nan,
            lo,
            hi,
            abstained / self.scenes if self.scenes else math.nan,
            alo,
            ahi,
            mean(self.unknown),
            mean(self.clearance),
            mean(self.truth_clearance),
        )
