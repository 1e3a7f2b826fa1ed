"""Seeded random streams: one independent generator per (master seed, purpose, keys: a scan, a descent...).

Every random draw of a build comes from ``stream(seed, purpose, *keys)``, so the output is the
same whatever the number of workers, the shard size or the order in which shards run.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np


class Purpose(IntEnum):
    """What a random stream is used for (part of the stream key; never renumber)."""

    RANGE_NOISE = 1  # keys: scan index, sigma in nanometres[, realisation k of an on-the-fly draw]
    ATTITUDE_JITTER = 2  # keys: scan index
    DEAD_ELEMENTS = 3  # keys: none (a property of the detector, shared by all scans)
    DAMAGED_ELEMENTS = 4  # keys: none
    DAMAGED_ERROR = 5  # keys: scan index, sigma in nanometres[, realisation k]
    SPLIT = 6  # keys: none
    TRAINING_DRAW = 7  # keys: epoch, scan index (hdnet: the noise level and D4 draw of a training sample)
    SCAN_POSE = 8  # keys: scan index (altitude, tilt and jitter level drawn from their ranges)
    NAV_BIAS = 9  # keys: descent index (the navigation error's bias: position, then attitude)
    NAV_WALK = 10  # keys: descent index, frame index >= 1 (the random walk's increment at that frame)
    DESCENT_AZIMUTH = 11  # keys: descent index (the direction the approach comes from)


def stream(seed: int, purpose: Purpose, *keys: int) -> np.random.Generator:
    """An independent PCG64 generator for ``(seed, purpose, *keys)``; all keys are integers >= 0."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(purpose), *map(int, keys)]))


def sigma_key(sigma_m: float) -> int:
    """Integer stream key of a noise level: sigma in nanometres (so adding a level changes no other)."""
    return int(round(sigma_m * 1e9))
