"""Calibrated thresholds kept with their run (``RUN/thresholds.json``), so ``hd detect`` calibrates once.

Calibrating H_t (MC dropout over a validation split) is most of a small ``hd detect`` call. The
result depends only on the checkpoint, the validation split (its dataset manifest and labelling),
the noise level, the threshold spec and rule, the uncertainty score and the MC settings; the cache
keys an entry on all of them (the checkpoint and the manifest by sha256), so a retrained run, a relabelled dataset or
other settings never meet a stale value. The file is a cache: written atomically, ignored when it
cannot be read (a damaged file is recomputed and replaced) and skipped when the run directory is
not writable.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from hdnet.uncertainty import ENTROPY, UncertaintyScore, uncertainty_score, with_score
from lidarsim.shards import MANIFEST_NAME, sha256_file
from lidarsim.storage import StorageError, write_json_atomic

__all__ = ["CACHE_FILE", "CachedThreshold", "ThresholdKey", "cache_key"]

CACHE_FILE = "thresholds.json"
CACHE_SCHEMA = "hd.threshold-cache"
CACHE_SCHEMA_VERSION = 1
# hd choice: entries kept per run (the oldest go first); each is a few hundred bytes.
MAX_ENTRIES = 256


@dataclass(frozen=True)
class ThresholdKey:
    """Everything a calibrated H_t depends on: the checkpoint and the calibration dataset's manifest
    (by sha256), the labelling, the noise level (metres), the threshold spec and rule, the MC
    settings and the uncertainty score (``hdnet.uncertainty``) whose values H_t bounds. Stored in the
    cache file as a dictionary (:meth:`to_dict`)."""

    checkpoint_sha256: str
    manifest_sha256: str
    labels: str
    sigma_m: float
    spec: str
    calibrate: str
    mc_samples: int
    batch_size: int
    seed: int
    uncertainty: str = ENTROPY.name

    def to_dict(self) -> dict[str, Any]:
        """The key as stored; the default score unnamed (``hdnet.uncertainty.with_score``), so entries
        cached before the score was a choice, all of predictive entropy, keep their keys."""
        plain = asdict(self)
        del plain["uncertainty"]
        return with_score(plain, uncertainty_score(self.uncertainty))


def cache_key(
    checkpoint: Path,
    calib_dirs: Sequence[Path],
    labels: str,
    sigma_m: float,
    spec: str,
    calibrate: str,
    mc_samples: int,
    batch_size: int,
    seed: int,
    uncertainty: UncertaintyScore = ENTROPY,
) -> ThresholdKey:
    """The key of a calibration (the checkpoint and the manifests of the calibration datasets, in
    order, hashed here; one dataset's key is its manifest's sha256 alone) of H_t on the score
    ``uncertainty``."""
    return ThresholdKey(
        checkpoint_sha256=sha256_file(checkpoint),
        manifest_sha256=",".join(sha256_file(Path(d) / MANIFEST_NAME) for d in calib_dirs),
        labels=labels,
        sigma_m=round(float(sigma_m), 12),
        spec=spec,
        calibrate=calibrate,
        mc_samples=int(mc_samples),
        batch_size=int(batch_size),
        seed=int(seed),
        uncertainty=uncertainty.name,
    )


class CachedThreshold:
    """The threshold cache of the run directory ``run_dir``."""

    def __init__(self, run_dir: Path) -> None:
        self.path = Path(run_dir) / CACHE_FILE

    def _entries(self) -> list[dict[str, Any]]:
        try:
            record = json.loads(self.path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError):
            return []
        if not isinstance(record, dict) or record.get("schema") != CACHE_SCHEMA:
            return []
        if record.get("schema_version") != CACHE_SCHEMA_VERSION or not isinstance(record.get("entries"), list):
            return []
        return [e for e in record["entries"] if isinstance(e, dict) and isinstance(e.get("key"), dict)]

    def get(self, key: ThresholdKey) -> tuple[float, dict[str, Any]] | None:
        """(H_t in nats, its calibration info) stored under ``key``, or None."""
        plain = key.to_dict()
        for entry in self._entries():
            value = entry.get("value_nats")
            if entry["key"] == plain and (value is None or isinstance(value, (int, float))):
                info = entry.get("info")
                return (float("inf") if value is None else float(value)), info if isinstance(info, dict) else {}
        return None

    def put(self, key: ThresholdKey, value_nats: float, info: dict[str, Any]) -> bool:
        """Store an entry (replacing one of the same key); False when the run directory is not writable."""
        plain = key.to_dict()
        entries = [e for e in self._entries() if e["key"] != plain]
        finite = value_nats if value_nats != float("inf") else None
        entries.append({"key": plain, "value_nats": finite, "info": info})
        record = {"schema": CACHE_SCHEMA, "schema_version": CACHE_SCHEMA_VERSION, "entries": entries[-MAX_ENTRIES:]}
        if not os.access(self.path.parent, os.W_OK):
            return False
        try:
            write_json_atomic(self.path, record, indent=1)
        except (StorageError, OSError):
            return False
        return True
