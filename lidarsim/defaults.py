"""The sensor, scene and build numbers lidarsim uses by default, each with its source, in one place.

Source of the paper's numbers: Tomita, Skinner & Ho, "Bayesian Deep Learning for Segmentation for
Autonomous Safe Planetary Landing" ("the paper" in ``docs/references.md``), section "Dataset
Preparation" and Table "Sensor parameters". Values marked "hd choice" are not in the paper.
"""

from __future__ import annotations

# Table "Sensor parameters": detector size 128x128.
DETECTOR_ROWS: int = 128
DETECTOR_COLS: int = 128
# Table "Sensor parameters": horizontal and vertical field of view, 12 degrees each.
FOV_DEG: float = 12.0
# Table "Sensor parameters": focal length 25 cm (informational: only the FOV shapes the rays).
FOCAL_LENGTH_M: float = 0.25
# "the sensor is moved across the terrain at a fixed altitude of 500 m".
ALTITUDE_M: float = 500.0
# Noise levels, 1-sigma along each ray: S-167, S-300 and S-700 ("1-sigma noise level of 1.67 cm",
# "3 cm", "7 cm"). 1.67 cm is the paper's rounding of 5 cm / 3; hd uses the paper's 0.0167 m
# everywhere (datasets, --sigma and --train-sigma defaults) so that the levels match exactly.
SIGMA_S167_M: float = 0.0167
SIGMA_S300_M: float = 0.03
SIGMA_S700_M: float = 0.07
PAPER_SIGMAS_M: tuple[float, float, float] = (SIGMA_S167_M, SIGMA_S300_M, SIGMA_S700_M)
# The CLI default for --sigma and --train-sigma (metres): S-167.
DEFAULT_SIGMA_M: float = SIGMA_S167_M
# "We generated simulated datasets of 1000 DEMs" (800 train / 100 val / 100 test).
N_SCANS: int = 1000
SPLIT_FRACTIONS: tuple[float, float, float] = (0.8, 0.1, 0.1)
# "Due to memory limitations, we load the DTM at 25% of the full resolution"; hd reads
# windows instead, so its default is full resolution (DTM_SCALE). The paper's value is quoted in
# the help of --dtm-scale.
PAPER_DTM_SCALE: float = 0.25
# HiRISE DTM NULL value (PDS3 label MISSING_CONSTANT); mask with <=, never ==.
HIRISE_NULL: float = -3.4028227e38

# --- Build settings that are not in the paper (hd choices; docs/lidarsim.md) ------------------------
# Master seed of every random stream of a build.
SEED: int = 0
# DTM resampling factor: full resolution (hd reads windows, so memory does not force 0.25).
DTM_SCALE: float = 1.0
# Scans per shard file (50 scans of 128 x 128 px at 3 noise levels: ~40 MB in memory per worker).
SHARD_SIZE: int = 50
# Off-nadir tilt of the boresight and 1-sigma attitude jitter per axis, degrees: the paper's nadir
# sensor with perfect pointing.
TILT_DEG: float = 0.0
JITTER_DEG: float = 0.0
# Detector elements that never return, or return with a large range error: none by default.
DEAD_ELEMENTS: int = 0
DAMAGED_ELEMENTS: int = 0
# HDF5 compression of the point arrays (docs/shard-format.md): deflate level 1 + shuffle by default.
COMPRESSIONS: tuple[str, ...] = ("gzip", "lzf", "none")
COMPRESSION: str = "gzip"

# --- Sensor realism (hd choices; docs/lidarsim.md, "Pixel footprint" and "Signal-dependent noise") ---
# Sub-rays per pixel side: 1 casts one ray through each pixel centre (the paper's sensor).
FOOTPRINT_SAMPLES: int = 1
# Spot profile over a pixel's field of view: "gaussian" (1/e^2 radius = half the pixel's side) or
# "uniform" (every sub-ray the same weight).
SPOT_PROFILES: tuple[str, ...] = ("gaussian", "uniform")
SPOT_PROFILE: str = "gaussian"
# How a pixel's range is formed from its returned pulse: the energy-weighted centroid, or the first
# crossing of a constant fraction of the waveform's peak (a constant-fraction discriminator).
RANGE_ESTIMATORS: tuple[str, ...] = ("centroid", "first")
RANGE_ESTIMATOR: str = "centroid"
# Full width at half maximum of the returned pulse, in range (c * tau / 2), metres: a 5 ns pulse.
PULSE_WIDTH_M: float = 0.75
# Fraction of the waveform's peak at which the "first" estimator fires.
RETURN_FRACTION: float = 0.5
# The range-noise model (lidarsim.noise.NOISE_KINDS): "constant" (one sigma everywhere, the paper's).
NOISE_MODEL: str = "constant"
# The "snr" model's reference: the --sigma levels are the 1-sigma at this range and normal
# incidence (the paper's altitude), where the signal-to-noise ratio is SNR_REF.
SNR_REF_RANGE_M: float = ALTITUDE_M
SNR_REF: float = 100.0
# A pixel whose signal-to-noise ratio is below this comes back with no return (status "weak").
SNR_MIN: float = 5.0

# --- Descents (hd choices; docs/lidarsim.md, "Descents") -------------------------------------------
# Frames per descent: 0 builds single frames (the paper's scans).
DESCENT_FRAMES: int = 0
# Altitudes of a descent's first and last frames above the target's terrain, metres: from twice the
# paper's 500 m down to half of it.
DESCENT_ALTITUDE_START_M: float = 1000.0
DESCENT_ALTITUDE_END_M: float = 250.0
# Angle of the approach path from the vertical, degrees: a vertical descent.
APPROACH_DEG: float = 0.0
# Navigation error, 1-sigma per axis: none (perfect navigation).
NAV_POSITION_SIGMA_M: float = 0.0
NAV_POSITION_WALK_M: float = 0.0
NAV_ATTITUDE_SIGMA_DEG: float = 0.0
NAV_ATTITUDE_WALK_DEG: float = 0.0
