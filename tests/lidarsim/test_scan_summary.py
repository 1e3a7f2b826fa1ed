"""lidarsim.scan_summary: which scans make the height sample (the summary: tests/hdnet/test_dataset_figure.py)."""

from __future__ import annotations

import numpy as np

from lidarsim.scan_summary import ScanSummary, sample_rows


def summary_of(splits: list[int]) -> ScanSummary:
    n = len(splits)
    return ScanSummary(
        scan_index=np.arange(n),
        split=np.asarray(splits, np.uint8),
        origin_map=np.zeros((n, 3)),
        altitude_m=np.full(n, 500.0),
        footprints_map=np.zeros((n, 4, 2)),
        shard=np.zeros(n, np.int64),
        row=np.arange(n),
    )


def test_the_sample_spreads_over_each_split_from_its_first_to_its_last_scan():
    s = summary_of([0] * 50 + [1] * 5 + [2] * 10 + [0] * 3)
    assert s.split_counts() == {"train": 53, "val": 5, "test": 10}
    # train is positions 0..49 and 65..67: 4 of its 53 at linspace(0, 52, 4) = 0, 17.3, 34.7, 52 of them
    assert sample_rows(s, 0, 4).tolist() == [0, 17, 35, 67]
    assert sample_rows(s, 1, 24).tolist() == [50, 51, 52, 53, 54]  # fewer than asked: every one
    assert sample_rows(s, 2, 1).tolist() == [55]
    assert sample_rows(summary_of([0, 0]), 2, 3).tolist() == []
