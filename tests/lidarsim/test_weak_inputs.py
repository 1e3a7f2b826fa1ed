"""Weak inputs said with numbers: a DTM coarser than the sensor, held-out scans on training terrain."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from hdcore.errors import HdWarning
from lidarsim.sensor import SensorConfig
from lidarsim.weak_inputs import coarse_dtm_message, ground_sample_m, overlap_message, split_overlap

REPO = Path(__file__).resolve().parents[2]
REAL = REPO.parent / "shared" / "data" / "real-terrain"
JEZERO = REPO / "datasets" / "mars-jezero" / "jezero-hirise-3.69m.tif"  # shipped with its recipe


def test_the_ground_sample_of_the_paper_sensor():
    # 12 deg over 128 pixels from 500 m: 500 * radians(12 / 128) = 0.818 m.
    assert ground_sample_m(SensorConfig(), 500.0) == pytest.approx(500 * math.radians(12 / 128))
    assert coarse_dtm_message("fine.tif", 1.0, SensorConfig(), 500.0) is None  # under 1.5 samples
    message = coarse_dtm_message("hirise.tif", 3.69, SensorConfig(), 500.0)
    assert message is not None and "3.69 m cells" in message and "0.82 m ground sample" in message


def test_footprint_overlap_by_hand():
    # Training scan at the origin; a test scan 50 m east (half of a 100 m footprint shared), a
    # validation scan 75 m east and 75 m north (a quarter of each side: 1/16 of the area).
    xy = np.array([[0.0, 0.0], [50.0, 0.0], [75.0, 75.0]])
    splits = np.array([0, 2, 1])
    overlap = split_overlap(xy, splits, 100.0)
    assert overlap[2] == pytest.approx(0.5) and overlap[1] == pytest.approx(1 / 16)
    message = overlap_message(overlap, 50.0, 100.0)
    assert message is not None and "test 50 %" in message and "validation" not in message
    assert overlap_message({1: 0.0, 2: 0.1}, 200.0, 100.0) is None


def _build_warnings(tmp_path, dtm: str, n_scans: int, rows: int) -> list[str]:
    from lidarsim.build import BuildConfig, build_dataset
    from lidarsim.trajectory import TrajectoryConfig

    config = BuildConfig(
        sensor=SensorConfig(rows=rows, cols=rows),
        trajectory=TrajectoryConfig(n_scans=n_scans),
        dtm_path=dtm,
        shard_size=n_scans,
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        build_dataset(tmp_path / "d", config, workers=1)
    return [str(w.message) for w in caught if issubclass(w.category, HdWarning)]


@pytest.mark.skipif(not REAL.is_dir(), reason="shared real-terrain data not present")
def test_builds_on_real_terrain_say_what_weakens_them(tmp_path):
    """Jezero's 3.69 m posts against the 0.82 m sample; Autzen's 20 scans 14-28 m apart, 115 m wide."""
    jezero = _build_warnings(tmp_path / "j", str(JEZERO), 2, 128)
    assert len(jezero) == 1 and "3.69 m cells are coarser than the LiDAR's 0.82 m ground sample" in jezero[0]
    autzen = _build_warnings(tmp_path / "a", str(REAL / "autzen-ground-1m.tif"), 20, 32)
    assert len(autzen) == 1 and "share terrain with the training scans" in autzen[0]
