"""hd's documented maxima: values beyond them are refused before anything is allocated or written.

None of these comes from the paper (whose detector is 128 x 128 px and whose datasets hold 1000
scans); they bound what one machine can hold, so that an absurd option gives a one-line error at
once instead of a MemoryError after a long wait (docs/reliability.md lists them).
"""

from __future__ import annotations

from hdcore.bounds import Bound, int_bound
from lidarsim import terrain_defaults

# Detector pixels per side: one ray-casting batch (16 scans) of 1024 x 1024 rays needs ~0.4 GB.
MAX_DETECTOR_PX: int = 1024
# Scans per dataset (the paper's datasets hold 1000).
MAX_SCANS: int = 1_000_000
# Uncompressed bytes of one shard, which a worker builds in memory before writing it (1 GiB).
MAX_SHARD_BYTES: int = 1 << 30
# Local worker processes of one command.
MAX_WORKERS: int = 512
# A scan whose rays hit the terrain less often than this (dead elements aside) fails the build:
# the planner places every footprint on valid terrain, so ~100% of the rays return.
MIN_RETURN_FRACTION: float = 0.5
# DataLoader worker processes of `hd train`.
MAX_LOADER_WORKERS: int = 256
# Shard files one build may create unless told otherwise (`hd build-dataset --max-shards`). Ten
# thousand files hold ten times the paper's 1000 scans at one scan per file (the published recipes
# make 4 to 50); more is almost always a --shard-size typed too small, and every file of a
# dataset is listed, checksummed (hd verify), labelled into a label shard of its own and copied.
MAX_SHARD_FILES: int = 10_000


# Seeds: unsigned 32-bit integers, which every random generator hd seeds (numpy, PyTorch, Dask)
# and every file that records them (shard attributes, JSON, checkpoints) take as they are.
MAX_SEED: int = 2**32 - 1
SEED = int_bound(0, MAX_SEED)
SCANS = int_bound(1, MAX_SCANS)
SHARD_SIZE = int_bound(1, MAX_SCANS)
# The shard files a build may create (--max-shards): a build writes at most one shard per scan.
SHARD_FILES = int_bound(1, MAX_SCANS)
WORKERS = int_bound(1, MAX_WORKERS)
LOADER_WORKERS = int_bound(0, MAX_LOADER_WORKERS)
DETECTOR_PX = int_bound(2, MAX_DETECTOR_PX)
# Dead or damaged detector elements (together at most the detector's pixels, checked with --resolution).
DETECTOR_ELEMENTS = int_bound(0, MAX_DETECTOR_PX * MAX_DETECTOR_PX)
# hd choice: the largest range-noise 1-sigma any command takes, metres: ten times the paper's largest
# level (7 cm). Beyond it the 0.2 m roughness rule is drowned and the DEMs are noise; a larger value is
# almost always centimetres typed where metres are meant.
MAX_SIGMA_M: float = 0.7
SIGMA_HINT = "noise levels are in metres: 7 cm is 0.07"
# Range noise 1-sigma of a dataset's noise level, metres (a noise-free copy is stored beside every level).
SIGMA_M = Bound(0.0, MAX_SIGMA_M, low_open=True, hint=SIGMA_HINT)
# A range noise 1-sigma where noise-free (0) is allowed: a sensor's, a training input's, a sweep's; metres.
NOISE_SIGMA_M = Bound(0.0, MAX_SIGMA_M, hint=SIGMA_HINT)
# Sensor altitude, metres (the footprint is then compared with the terrain before any work).
ALTITUDE_M = Bound(0.0, low_open=True)
# Off-nadir tilt of the boresight, degrees (beyond 60 degrees the footprint grazes the terrain).
TILT_DEG = Bound(-60.0, 60.0, low_open=True, high_open=True)
# 1-sigma attitude jitter per axis, degrees.
JITTER_DEG = Bound(0.0, 5.0, high_open=True)
# Frames per descent (hd build-dataset --descent-frames; 0 = single frames, else at least 2). hd choice:
# 64 frames, far more than the few frames a hazard-detection pass takes (the docs' examples use 9); the
# frames of a descent are held in one shard, so K also bounds a shard's size from below.
MAX_DESCENT_FRAMES: int = 64
DESCENT_FRAMES = int_bound(0, MAX_DESCENT_FRAMES)
# Angle of a descent's straight approach path from the vertical, degrees (the boresight is tilted by
# it to look at the target; as --tilt, beyond 60 degrees the footprint grazes the terrain).
APPROACH_DEG = Bound(0.0, 60.0, high_open=True)
# Navigation error of a descent, 1-sigma per axis: position (metres) and attitude (degrees), the bias
# of a descent and the increment of its random walk per frame. hd choice: at most 100 m, twice the
# footprint of a 12-degree frame from 250 m (a larger error puts a frame's estimate off its own
# terrain: almost always a value in the wrong unit), and 5 degrees, the bound of --jitter.
NAV_POSITION_M = Bound(0.0, 100.0)
NAV_ATTITUDE_DEG = Bound(0.0, 5.0, high_open=True)
# Field of view per side, degrees (a pinhole detector cannot see 180 degrees).
FOV_DEG = Bound(0.0, 170.0, low_open=True, high_open=True)
# Resampling factor of a DTM (1 = full resolution; hd never invents detail by upsampling).
DTM_SCALE = Bound(0.0, 1.0, low_open=True)
# Procedural terrain (hd make-dtm): side and grid spacing, metres; the side is also checked against
# the spacing (two cells at least, 16384 at most).
TERRAIN_SIZE_M = Bound(0.0, low_open=True)
TERRAIN_SPACING_M = Bound(0.0, terrain_defaults.MAX_SPACING_M, low_open=True)
# Golombek-Rapp rock abundance k: 0 (no rocks) or within the model's range (from ROCK_K_MIN).
ROCK_K = Bound(0.0, terrain_defaults.ROCK_K_MAX)
# Largest crater added below a base DTM's resolution (hd make-dtm --base), metres: at least the
# smallest crater the model samples.
CRATER_DIAMETER_M = Bound(terrain_defaults.CRATER_D_MIN_M)
# Sub-rays per pixel side of the footprint model (K x K sub-rays per pixel; 16: 256 rays per pixel).
FOOTPRINT_SAMPLES = int_bound(1, 16)
# Full width at half maximum of the returned pulse in range, metres.
PULSE_WIDTH_M = Bound(0.0, 30.0, low_open=True)
# Fraction of the waveform's peak at which the first-return estimator fires.
RETURN_FRACTION = Bound(0.0, 1.0, low_open=True, high_open=True)
# Signal-to-noise ratio of a full-pixel return at the reference range and normal incidence.
SNR_REF = Bound(0.0, low_open=True)
# Detection threshold on the signal-to-noise ratio (0: every return is kept).
SNR_MIN = Bound(0.0)
# The range at which the snr noise model's signal-to-noise ratio is given, metres.
SNR_REF_RANGE_M = Bound(0.0, low_open=True)
