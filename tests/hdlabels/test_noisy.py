"""hdlabels.noisy: noisy DEMs at any noise level from the clean points, equal to the stored ones at stored levels."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from scipy import ndimage

from hdlabels.labeling import label_dataset
from hdlabels.noisy import NoisyDems
from hdlabels.settings import LabelSettings
from hdlabels.store import find_labeling
from lidarsim.build import BuildConfig, build_dataset
from lidarsim.errors import LidarsimError
from lidarsim.footprint import FootprintConfig
from lidarsim.noise import NoiseModel
from lidarsim.scan import STATUS_DAMAGED, STATUS_DEAD
from lidarsim.sensor import SensorConfig
from lidarsim.trajectory import TrajectoryConfig
from tests.geotiff import write_geotiff

SIGMAS = (0.0167, 0.05)


def _dtm(path, n=300, seed=4):
    rng = np.random.default_rng(seed)
    z = ndimage.gaussian_filter(rng.normal(0.0, 1.0, (n, n)), 10) * 20.0
    return write_geotiff(path, z, 1.0, (5000.0, 9000.0))


@pytest.fixture(scope="module", params=["linear", "nearest", "nearest-snr"])
def dataset(request, tmp_path_factory):
    """6 scans with tilt, attitude jitter, dead and damaged elements; labelled with one gridding
    (``-snr``: the snr noise model, whose sigma differs per element, and a 3 x 3 pixel footprint)."""
    root = tmp_path_factory.mktemp(f"noisy-{request.param}")
    gridding, _, model = request.param.partition("-")
    snr = model == "snr"
    config = BuildConfig(
        sigmas_m=SIGMAS,
        sensor=SensorConfig(rows=40, cols=40, dead_elements=7, damaged_elements=5),
        trajectory=TrajectoryConfig(n_scans=6, altitude_m=400.0, tilt_deg=2.0, jitter_deg=0.3),
        dtm_path=str(_dtm(root / "t.tif")),
        shard_size=3,
        seed=11,
        noise_model=NoiseModel(kind="snr", snr_ref=25.0) if snr else NoiseModel(),
        footprint=FootprintConfig(samples=3) if snr else FootprintConfig(),
    )
    out = root / "data"
    build_dataset(out, config, workers=1)
    label_dataset(out, LabelSettings(dem_size=50, dem_spacing_m=1.0, gridding=gridding), workers=1)
    return out


def test_made_dems_equal_the_stored_ones_bit_for_bit_at_stored_levels(dataset):
    entry = find_labeling(dataset)
    maker = NoisyDems.of_dataset(dataset, entry.dem)
    assert maker.seed == 11 and maker.sensor.damaged_elements == 5
    checked = 0
    for shard in entry.shards:
        with h5py.File(dataset / shard.path) as lab, h5py.File(dataset / shard.source_path) as src:
            scans = maker.read_scans(dataset, shard, range(lab["scan_index"].shape[0]))
            status = src["status"][:]
            assert (status == STATUS_DAMAGED).any() and (status == STATUS_DEAD).any()
            for k, scan in enumerate(scans):
                for s, sigma in enumerate(SIGMAS):
                    points = maker.points(scan, sigma)
                    assert np.array_equal(points, src["points_noisy"][k, s], equal_nan=True)
                    assert np.array_equal(maker.dem(scan, sigma), lab["dem_noisy"][k, s], equal_nan=True)
                    checked += 1
    assert checked == 6 * len(SIGMAS)


def test_other_levels_and_realisations(dataset):
    entry = find_labeling(dataset)
    maker = NoisyDems.of_dataset(dataset, entry.dem)
    scan = maker.read_scans(dataset, entry.shards[0], [0])[0]
    clean = maker.dem(scan, 0.0)
    noisy = maker.dem(scan, 0.10)
    again = maker.dem(scan, 0.10)
    other = maker.dem(scan, 0.10, realisation=3)
    assert np.array_equal(noisy, again, equal_nan=True) and not np.array_equal(noisy, other, equal_nan=True)
    diff = (noisy - clean)[np.isfinite(noisy - clean)]
    robust_std = 1.4826 * np.median(np.abs(diff - np.median(diff)))  # damaged elements add 5 m outliers
    assert 0.03 < robust_std < 0.12  # the DEM keeps a share of the 10 cm range noise
    assert np.nanstd(maker.dem(scan, 0.0) - clean) == 0.0


def test_altered_clean_points_are_refused(dataset, tmp_path):
    entry = find_labeling(dataset)
    maker = NoisyDems.of_dataset(dataset, entry.dem)
    with h5py.File(dataset / entry.shards[0].source_path) as src:
        pts = src["points_clean"][0].copy()
        pose = src["sensor_position"][0], src["sensor_attitude"][0], src["status"][0]
    finite = np.argwhere(np.isfinite(pts).all(axis=-1))[0]
    pts[tuple(finite)] += np.float32(0.3)
    with pytest.raises(LidarsimError, match="scan 0"):
        maker.clean_scan(pts, pose[2], pose[0], pose[1], 0)
