"""Ranges of hdnet's numeric settings (the options of ``hd train``, ``hd eval`` and ``hd detect``).

Each is declared once here, as a :class:`hdcore.bounds.Bound`, and used by hdnet's own checks
(``hdnet.evaluate``, ``hdnet.detect``) and by the command line (shown in ``--help``; a value outside
is a usage error before any work). Sizes that depend on several settings and on the data (dropped
pixels within a DEM, memory of a batch) are checked where the data is known.
"""

from __future__ import annotations

from hdcore.bounds import Bound
from hdlabels.defaults import MAX_DEM_SIDE_PX
from lidarsim import limits as lidar_limits

# MC-dropout samples per DEM: the tiled suffix of one batch holds M copies in memory (hd choice;
# the paper's M is 8).
MAX_MC_SAMPLES: int = 1024
# DEMs (or detect tiles) per inference batch (hd choice).
MAX_BATCH_SIZE: int = 1024
# Training epochs: the paper's SGD needs 10^4 (hdnet.profiles); ten times that bounds a typo.
MAX_EPOCHS: int = 100_000
# Noise levels of one sweep (hd eval --sigma-sweep; hd choice): each level is one inference over the
# whole test split (with the paper's M = 8 and 100 test DEMs, 200 levels are 160,000 network passes),
# and 200 levels already step 0.5 mm from 0 to 10 cm, finer than any sensor's noise is known.
MAX_SWEEP_LEVELS: int = 200
# The finest step of a sweep, metres (hd choice): a micrometre, below the float32 resolution of heights
# hundreds of metres from the sensor (3e-5 m at 500 m), so finer levels are not different noise; the
# levels are kept to 1e-12 m, and a finer step would repeat levels.
MIN_SWEEP_STEP_M: float = 1e-6

MC_SAMPLES = Bound(1, MAX_MC_SAMPLES, integer=True)
BATCH_SIZE = Bound(1, MAX_BATCH_SIZE, integer=True)
EPOCHS = Bound(1, MAX_EPOCHS, integer=True)
SWEEP_LEVELS = Bound(1, MAX_SWEEP_LEVELS, integer=True, hint="each level is an inference over the whole test split")
# Dead pixels dropped from each DEM (also fewer than the DEM's pixels, checked with the data).
DROP_PIXELS = Bound(0, MAX_DEM_SIDE_PX * MAX_DEM_SIDE_PX - 1, integer=True)
# Landing sites hd detect proposes, at most.
SITES = Bound(1, integer=True)
# Index of a scan in a dataset.
SCAN_INDEX = Bound(0, lidar_limits.MAX_SCANS - 1, integer=True)
# A sensor's or a training input's range noise 1-sigma, metres (0: noise-free; one bound for every command).
NOISE_SIGMA_M = lidar_limits.NOISE_SIGMA_M
# Navigation dispersion of the touchdown around the aim point, metres 1-sigma per horizontal axis
# (hd choice: 100 m is ten landers' diameters, far past any terrain-relative navigation).
NAV_SIGMA_M = Bound(0.0, 100.0)
# Safety margin around the lander body a site must keep safe and certain, metres (hd choice: 50 m, ten
# landers' radii; a wider ring leaves no site in any map a lander would be given).
SITE_MARGIN_M = Bound(0.0, 50.0)
# Longest side of a map image of hd view, pixels (hd choice): below 64 a map says nothing; above
# 8192 one RGBA layer is 256 MiB before compression and browsers slow to a crawl.
VIEW_PX = Bound(64, 8192, integer=True)
# Rows or columns of the DEM an exported network takes (hd export-model): the largest DEM side hd grids.
DEM_SIDE = Bound(1, MAX_DEM_SIDE_PX, integer=True)
