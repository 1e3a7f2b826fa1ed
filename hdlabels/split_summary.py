"""A labelling's pixel counts per split: the labels' classes and the ALHAT baseline's safe pixels at
each noise level (``hd inspect --plot``).

The counts are those of the labelling's manifest entry (``label_counts``, ``baseline_safe_fraction``:
``hdlabels.labeling.label_counts`` and ``baseline_safe_counts``), split by each scan's split, so
the three splits add up to the entry's numbers exactly. Only ``split``, ``label`` and ``p_safe`` of
each label shard are read, a block of scans at a time; files are opened through the storage layer
(confined to the dataset, every chunk's fletcher32 checksum checked) but not hashed whole:
``hd inspect`` checks every file's sha256 first.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hdcore.storage import confine
from hdlabels.labeling import baseline_safe_counts, label_counts
from hdlabels.store import LabelingEntry, LabelShardReader, LabelStoreError
from lidarsim.shards import SPLIT_NAMES

# hd choice: label-shard scans read at once (100 x 100 DEMs at 3 noise levels: 8 MB of P(safe)).
BLOCK_SCANS = 64


@dataclass(frozen=True)
class SplitCounts:
    """One split's pixels: ``unsafe``, ``safe`` and ``invalid`` labels, and per noise level of
    ``sigmas_m`` the labelled pixels the baseline calls safe (P(safe) >= 0.5), ``baseline_safe``."""

    scans: int
    unsafe: int
    safe: int
    invalid: int
    baseline_safe: tuple[int, ...]

    @property
    def labelled(self) -> int:
        """Pixels with a label (safe or unsafe)."""
        return self.unsafe + self.safe

    @property
    def safe_fraction(self) -> float | None:
        """The labels' safe pixels over the labelled ones; None for a split without labelled pixels."""
        return self.safe / self.labelled if self.labelled else None

    def baseline_fractions(self) -> tuple[float | None, ...]:
        """Per noise level, the baseline's safe pixels over the labelled ones (None without any)."""
        return tuple(n / self.labelled if self.labelled else None for n in self.baseline_safe)


@dataclass(frozen=True)
class SplitSummary:
    """A labelling's counts per split (``splits``: train, val, test) at the noise levels ``sigmas_m`` (metres)."""

    labeling: str
    truth: str
    sigmas_m: tuple[float, ...]
    splits: dict[str, SplitCounts]


def split_summary(directory: str | os.PathLike, labeling: LabelingEntry) -> SplitSummary:
    """The counts per split of the labelling ``labeling`` (its manifest entry, e.g. from
    ``hdlabels.store.find_labeling``) of the dataset at ``directory``.

    Raises:
        ShardFormatError / LabelStoreError: a label shard that is missing, damaged or not as hd writes it,
            or shards of different noise levels.
    """
    root = Path(directory)
    sigmas: tuple[float, ...] | None = None
    n = len(SPLIT_NAMES)
    scans = np.zeros(n, np.int64)
    classes = np.zeros((n, 3), np.int64)  # unsafe, safe, invalid pixels per split
    baseline = np.zeros((n, 0), np.int64)  # the baseline's safe pixels per split and noise level
    for entry in labeling.shards:
        what = f"{root / entry.path}"
        with LabelShardReader(confine(root, entry.path, what), what=what) as reader:
            if sigmas is None:
                sigmas = reader.sigmas_m
                baseline = np.zeros((n, len(sigmas)), np.int64)
            elif reader.sigmas_m != sigmas:
                raise LabelStoreError(
                    f"{what}: holds noise levels {reader.sigmas_m}, the labelling's first shard {sigmas}"
                )
            f = reader.h5
            for start in range(0, len(reader), BLOCK_SCANS):
                block = slice(start, min(start + BLOCK_SCANS, len(reader)))
                split, label, p_safe = f["split"][block], f["label"][block], f["p_safe"][block]
                for code in np.unique(split).tolist():
                    if not 0 <= code < n:
                        raise LabelStoreError(f"{what}: holds the split code {code}, not one of 0, 1, 2")
                    rows = split == code
                    scans[code] += int(rows.sum())
                    classes[code] += label_counts(label[rows])
                    baseline[code] += baseline_safe_counts(label[rows], p_safe[rows])
    counts = {
        name: SplitCounts(
            scans=int(scans[code]),
            unsafe=int(classes[code, 0]),
            safe=int(classes[code, 1]),
            invalid=int(classes[code, 2]),
            baseline_safe=tuple(int(v) for v in baseline[code]),
        )
        for code, name in enumerate(SPLIT_NAMES)
    }
    return SplitSummary(labeling.name, labeling.truth, sigmas or (), counts)
