"""hd's documented maxima: values beyond them are refused before anything is allocated or written.

None of these comes from the paper (whose detector is 128 x 128 px and whose datasets hold 1000
scans); they bound what one machine can hold, so that an absurd option gives a one-line error at
once instead of a MemoryError after a long wait (docs/reliability.md lists them).
"""

from __future__ import annotations

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
