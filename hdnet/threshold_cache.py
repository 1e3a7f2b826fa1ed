"""Calibrated thresholds kept with their run (``RUN/thresholds.json``), so ``hd detect`` calibrates once.

Calibrating H_t (MC dropout over a validation split) is most of a small ``hd detect`` call. The
result depends only on the checkpoint, the validation split (its dataset manifest and labelling),
the noise level, the threshold spec and rule, the uncertainty score and the MC settings; the cache
keys an entry on all of them (the checkpoint and the manifest by sha256), so a retrained run, a relabelled dataset or
other settings never meet a stale value.

The file decides which cells a safety map calls uncertain, so nothing in it is trusted as read: an
entry is used only when it passes every check below, and anything else is ignored with a warning
and recalibrated (then replaced):

* the file is a regular file of at most :data:`MAX_FILE_BYTES` (a FIFO, a device or a huge file is
  never read), valid JSON of this schema and version;
* the entry's key is exactly the key of the calibration asked for (checkpoint and manifest
  digests included), its value a number of nats within the score's range [0, ln 2] (the largest
  entropy of a two-class prediction; ``null`` = unbounded, a rule that no pixel limits), its
  calibration record a JSON object that states the same value, spec and rule;
* the entry's ``sha256`` is the digest of its key, value and record (:func:`entry_digest`): an
  entry edited by hand or damaged on disk no longer matches it.

The digest ties an entry to its run's checkpoint and calibration data (their digests are in the
key) and catches edits and damage; it is no signature: someone who can write the run directory can
also write its checkpoint. The file is a cache: written atomically and skipped when the run
directory is not writable.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, cast

from hdcore.errors import HdWarning
from hdcore.storage import StorageError, read_regular_bytes, write_json_atomic
from hdnet.report_json import ThresholdJson
from hdnet.uncertainty import ENTROPY, UncertaintyScore, score_entry, uncertainty_score
from lidarsim.location import manifest_sha256
from lidarsim.shards import MANIFEST_NAME, sha256_file

__all__ = ["CACHE_FILE", "CachedThreshold", "ThresholdKey", "cache_key", "entry_digest"]

CACHE_FILE = "thresholds.json"
CACHE_SCHEMA = "hd.threshold-cache"
# Version 2 adds each entry's sha256 (entry_digest); files of version 1 are recalibrated once.
CACHE_SCHEMA_VERSION = 2
# hd choice: entries kept per run (the oldest go first); each is a few hundred bytes.
MAX_ENTRIES = 256
# hd choice: the largest file read (MAX_ENTRIES entries of a few kB each fit many times over).
MAX_FILE_BYTES = 4 << 20
# The largest value of either score (predictive entropy, mutual information) of a two-class
# prediction, nats: ln 2 (hdnet.uncertainty); the float slack covers the rounding of float32 maps.
MAX_SCORE_NATS = math.log(2.0) + 1e-6


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
        return plain | score_entry(uncertainty_score(self.uncertainty))


def cache_key(
    checkpoint: Path,
    calib_dirs: Sequence[Path | str],
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
        manifest_sha256=",".join(manifest_sha256(d, MANIFEST_NAME) for d in calib_dirs),
        labels=labels,
        sigma_m=round(float(sigma_m), 12),
        spec=spec,
        calibrate=calibrate,
        mc_samples=int(mc_samples),
        batch_size=int(batch_size),
        seed=int(seed),
        uncertainty=uncertainty.name,
    )


def entry_digest(key: dict[str, Any], value_nats: float | None, info: Mapping[str, object]) -> str:
    """The sha256 of an entry's key, value (nats; None = unbounded) and calibration record, over their
    canonical JSON (sorted keys, no spaces): what ``thresholds.json`` stores as the entry's ``sha256``."""
    canonical = json.dumps(
        {"key": key, "value_nats": value_nats, "info": info}, sort_keys=True, separators=(",", ":"), allow_nan=False
    )
    return hashlib.sha256(canonical.encode("utf-8")).hexdigest()


def _value_problem(value: Any) -> str | None:
    """Why ``value`` is not a threshold in nats this cache can hold, or None."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f"value {value!r} is not a number"
    if not math.isfinite(value) or not 0.0 <= value <= MAX_SCORE_NATS:
        return f"value {value!r} is outside the score's range [0, ln 2] nats"
    return None


def _entry_problem(entry: Any, plain: dict[str, Any]) -> str | None:
    """Why the stored ``entry`` of key ``plain`` cannot be used, or None (the checks of the module's docstring)."""
    if not isinstance(entry, dict) or set(entry) != {"key", "value_nats", "info", "sha256"}:
        return "the entry is not {key, value_nats, info, sha256}"
    value, info = entry["value_nats"], entry["info"]
    problem = _value_problem(value)
    if problem is not None:
        return problem
    if not isinstance(info, dict):
        return "its calibration record is not an object"
    if "value_nats" in info and info["value_nats"] != value:
        return f"its calibration record states {info['value_nats']!r} nats, the entry {value!r}"
    if "spec" in info and info["spec"] != plain["spec"]:
        return f"its calibration record is of the rule {info['spec']!r}, the key of {plain['spec']!r}"
    try:
        digest = entry_digest(plain, value, info)
    except (TypeError, ValueError, RecursionError):
        return "its calibration record is not plain JSON"
    if entry["sha256"] != digest:
        return "its sha256 does not match its content (edited or damaged)"
    return None


class CachedThreshold:
    """The threshold cache of the run directory ``run_dir``."""

    def __init__(self, run_dir: Path) -> None:
        self.path = Path(run_dir) / CACHE_FILE

    def _warn(self, why: str) -> None:
        warnings.warn(f"{self.path}: {why}; ignored, the threshold is calibrated again", HdWarning, stacklevel=3)

    def _entries(self, warn: bool = True) -> list[dict[str, Any]]:
        """The file's entries that have a key (their values unchecked: :meth:`get` checks the one it uses)."""
        if not os.path.lexists(self.path):
            return []
        try:
            record = json.loads(read_regular_bytes(self.path, max_bytes=MAX_FILE_BYTES).decode("utf-8"))
        except (ValueError, RecursionError) as exc:  # StorageError, decoding, JSON, digit limit
            if warn:
                self._warn(f"unreadable threshold cache ({exc})")
            return []
        if not isinstance(record, dict) or record.get("schema") != CACHE_SCHEMA:
            if warn:
                self._warn("not a threshold cache")
            return []
        if record.get("schema_version") != CACHE_SCHEMA_VERSION or not isinstance(record.get("entries"), list):
            if warn and record.get("schema_version") != 1:  # version 1 (no digests) is simply replaced
                self._warn(f"threshold cache of unknown version {record.get('schema_version')!r}")
            return []
        return [e for e in record["entries"] if isinstance(e, dict) and isinstance(e.get("key"), dict)]

    def get(self, key: ThresholdKey) -> tuple[float, ThresholdJson] | None:
        """(H_t in nats, its calibration record) stored under ``key``, or None: nothing stored, or a
        stored entry that fails a check (a warning says which)."""
        plain = key.to_dict()
        for entry in self._entries():
            if entry["key"] != plain:
                continue
            problem = _entry_problem(entry, plain)
            if problem is not None:
                self._warn(f"the cached threshold for {plain['spec']} at sigma {plain['sigma_m']:g} m: {problem}")
                return None
            value = entry["value_nats"]
            return (math.inf if value is None else float(value)), cast("ThresholdJson", dict(entry["info"]))
        return None

    def entries_of(self, checkpoint_sha256: str) -> list[tuple[dict[str, Any], float, ThresholdJson]]:
        """(key, H_t in nats, calibration record) of every entry calibrated for the checkpoint whose file
        has the sha256 ``checkpoint_sha256`` and that passes every check of the module's docstring, in
        the file's order (the oldest first); the others are skipped without a warning (``hd
        export-model`` reports what the cache holds, it calibrates nothing)."""
        found: list[tuple[dict[str, Any], float, ThresholdJson]] = []
        for entry in self._entries(warn=False):
            plain = entry["key"]
            if plain.get("checkpoint_sha256") != checkpoint_sha256 or _entry_problem(entry, plain) is not None:
                continue
            value = entry["value_nats"]
            found.append(
                (plain, math.inf if value is None else float(value), cast("ThresholdJson", dict(entry["info"])))
            )
        return found

    def put(self, key: ThresholdKey, value_nats: float, info: ThresholdJson) -> bool:
        """Store an entry (replacing one of the same key) with its digest; False when the run directory
        is not writable or the entry cannot be stored."""
        plain = key.to_dict()
        finite = None if math.isinf(value_nats) and value_nats > 0 else float(value_nats)
        if _value_problem(finite) is not None:
            return False
        record_info: ThresholdJson = {**info, "value_nats": finite}
        try:
            digest = entry_digest(plain, finite, record_info)
        except (TypeError, ValueError):
            return False
        entries = [e for e in self._entries(warn=False) if e["key"] != plain]
        entries.append({"key": plain, "value_nats": finite, "info": record_info, "sha256": digest})
        record = {"schema": CACHE_SCHEMA, "schema_version": CACHE_SCHEMA_VERSION, "entries": entries[-MAX_ENTRIES:]}
        if not os.access(self.path.parent, os.W_OK):
            return False
        try:
            write_json_atomic(self.path, record, indent=1)
        except (StorageError, OSError):
            return False
        return True
