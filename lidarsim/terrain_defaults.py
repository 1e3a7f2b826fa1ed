"""Constants of the procedural Mars terrain, each with its source.

These are the defaults of :class:`lidarsim.procedural.MarsTerrainParams`; ``docs/terrain.md``
explains each one and how to tune it. Where a value was *chosen* (not taken from a paper) the
comment says so and why.
"""

from __future__ import annotations

# --- Grid -------------------------------------------------------------------------------------
# Side of the square tile (metres). Chosen: ~10 footprints of a 500 m, 12 deg scan (105 m) across,
# and a power of two in cells at 0.5 m so the spectral synthesis uses a fast FFT size (2048).
SIZE_M: float = 1024.0
# Grid spacing (metres/pixel). Chosen: twice finer than the 1 m/px DEM of the paper, so boulders
# of about one metre (the ones that exceed the 0.20 m roughness limit) are represented.
SPACING_M: float = 0.5
# Coarsest spacing accepted (metres/pixel): beyond this, rocks near the hazard size vanish.
MAX_SPACING_M: float = 0.5

# --- Fractal relief (spectral synthesis, power-law spectrum) -----------------------------------
# Hurst exponent H (dimensionless): the height-difference RMS grows as baseline**H. Mars
# topography is self-affine with H ~ 0.7-0.9 at hectometre to kilometre baselines
# (Orosei et al. 2003, JGR 108(E4) 8023, "Self-affine behavior of Martian topography at
# kilometer scale from Mars Orbiter Laser Altimeter data"; Kreslavsky & Head 1999, JGR 104(E9)).
RELIEF_HURST: float = 0.8
# RMS slope (degrees) of the relief at the reference baseline below. Landing-site candidates
# mapped with HiRISE stereo show metre-baseline RMS slopes of a few degrees (Kirk et al. 2008,
# JGR 113, E00A24, Phoenix sites; Golombek et al. 2012, Space Sci. Rev. 170, MSL sites).
# Chosen inside that range.
RELIEF_RMS_SLOPE_DEG: float = 3.0
# Baseline (metres) at which RELIEF_RMS_SLOPE_DEG is measured: 1 m, as in Kirk et al. 2008.
RELIEF_BASELINE_M: float = 1.0

# --- Craters (cumulative size-frequency distribution + fresh simple-crater profile) -------------
# Cumulative SFD N(>D) = N10 * (D / 10 m)**(-b) per km^2. Small craters on Mars landing sites are
# near empirical equilibrium, whose cumulative slope is b ~ 2 (Gault 1970, Radio Sci. 5(2);
# Hartmann 1984, Icarus 60, "Does crater 'saturation equilibrium' occur in the solar system?").
CRATER_SFD_EXPONENT: float = 2.0
# N(>10 m) per km^2. Geometric saturation is 1.54 D**-2 per km^2 (D in km; Gault 1970), i.e.
# 1.54e4 per km^2 for D > 10 m; empirical equilibrium is a few percent of it (Hartmann 1984).
# Chosen: 1.3 % of geometric saturation, tuned so the default terrain gives a real safe/unsafe mix.
CRATER_N_GT_10M_PER_KM2: float = 200.0
# Crater diameter range (metres). Lower bound chosen: 4 grid cells, the smallest bowl the grid
# resolves. Upper bound chosen: a fifth of the tile, so a tile holds many footprints off craters.
CRATER_D_MIN_M: float = 2.0
CRATER_D_MAX_M: float = 200.0
# Fresh simple crater: depth rim-crest-to-floor ~ 0.2 D and rim height ~ 0.04 D above the
# surroundings (Pike 1977, "Size-dependence in the shape of fresh impact craters on the Moon",
# in Impact and Explosion Cratering, 489-509: d = 0.196 D, h = 0.036 D; Melosh 1989, ch. 8).
CRATER_DEPTH_RATIO: float = 0.2
CRATER_RIM_RATIO: float = 0.04
# Ejecta blanket: thickness falls as (r/R)**-3 outside the rim (McGetchin, Settle & Head 1973,
# EPSL 20, 226-236), tapered to zero at this many crater radii from the centre; continuous ejecta
# reaches about one crater radius beyond the rim (Moore et al. 1974), chosen 3 R to let it fade.
CRATER_EJECTA_FALLOFF_EXPONENT: float = 3.0
CRATER_EJECTA_EXTENT_RADII: float = 3.0

# --- Rocks (Golombek & Rapp 1997 model) --------------------------------------------------------
# Cumulative fractional area covered by rocks of diameter >= D: F_k(D) = k exp(-q(k) D),
# q(k) = 1.79 + 0.152 / k (D in metres; Golombek & Rapp 1997, JGR 102(E2), 4117-4129).
ROCK_Q_A_PER_M: float = 1.79
ROCK_Q_B_PER_M: float = 0.152
# Model validity range of the total rock abundance k (Golombek & Rapp 1997: 5 % to 40 %, the
# range seen at the Viking and Pathfinder sites and in IRTM thermal inertia).
ROCK_K_MIN: float = 0.05
ROCK_K_MAX: float = 0.40
# Default total rock abundance k. Chosen: Viking Lander 1 ~ 0.07, Pathfinder ~ 0.16-0.2; the
# modal Mars value from thermal inertia is ~ 0.06-0.08 (Golombek & Rapp 1997; Golombek et al. 2003,
# JGR 108(E12) 8086). Tuned with the default craters for a real safe/unsafe mix.
ROCK_K: float = 0.08
# Smallest sampled rock (metres). Chosen: with height 0.5 D, a rock below 0.4 m cannot reach the
# 0.20 m roughness limit of the default lander, and it is below one grid cell.
ROCK_D_MIN_M: float = 0.4
# Largest sampled rock (metres). The largest rocks at the Viking/Pathfinder sites are 2-3 m
# (Golombek & Rapp 1997); the exponential makes larger ones negligible.
ROCK_D_MAX_M: float = 3.0
# Rock height over diameter: rocks at the landing sites are about half as high as wide
# (Golombek & Rapp 1997; Golombek et al. 2003). Shape: half-ellipsoid of revolution.
ROCK_HEIGHT_RATIO: float = 0.5

# --- Random streams ---------------------------------------------------------------------------
# Purpose codes mixed into np.random.SeedSequence([seed, PURPOSE]): one stream per component,
# so changing one component's parameters leaves the others' draws unchanged.
PURPOSE_RELIEF: int = 1
PURPOSE_CRATERS: int = 2
PURPOSE_ROCKS: int = 3
