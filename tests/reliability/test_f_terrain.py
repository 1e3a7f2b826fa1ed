"""Class F: non-finite and absurd heights are nodata; a build whose scans come back empty fails.

A DTM whose top third holds a fill value the producer did not declare (+-inf, +-1e30, 3e38, NaN)
must give the same kind of dataset as a clean one: scans placed on the valid part only, every ray
returning, scan origins at finite heights.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin
from reliability_kit import BUILD_ARGS, assert_one_line_error, hd_process, hills, invoke

from lidarsim import limits
from lidarsim.build import check_returns
from lidarsim.errors import LidarsimError
from lidarsim.scan import STATUS_DEAD, STATUS_MISS, STATUS_RETURN
from lidarsim.shards import iter_scans
from tests.geotiff import write_geotiff


@pytest.mark.parametrize("fill", [np.inf, -np.inf, 1e30, -1e30, 3e38, np.nan], ids=str)
def test_undeclared_fill_values_are_nodata(tmp_path, fill):
    dtm = hills(tmp_path / "filled.tif", fill_rows=100, fill=fill)
    out = tmp_path / "data"
    result = invoke("build-dataset", "--out", out, "--dtm", dtm, "--workers", "1", *BUILD_ARGS)
    assert result.exit_code == 0, result.output
    for scan in iter_scans(out):
        assert scan.valid.all(), "every ray of a scan placed on valid terrain returns"
        assert np.isfinite(scan.origin_map).all() and abs(scan.origin_map[2]) < 100
        assert np.nanmax(np.abs(scan.points_clean[..., 2])) < 50
        assert scan.origin_map[1] < 2000.0 - 100.0  # the scan lies south of the filled band


@pytest.mark.parametrize("fill", [np.inf, 1e30, -3.0e38], ids=str)
def test_a_dtm_of_fill_values_only_is_refused(tmp_path, fill):
    dtm = hills(tmp_path / "all.tif", n=200, fill_rows=200, fill=fill)
    out = tmp_path / "data"
    assert_one_line_error(invoke("build-dataset", "--out", out, "--dtm", dtm, *BUILD_ARGS), "every cell is nodata")
    assert not out.exists()


def test_absurd_integer_heights_are_nodata(tmp_path):
    z = np.full((300, 300), 100, dtype=np.int32)
    z[:100] = 2_000_000_000
    path = write_geotiff(tmp_path / "int.tif", z, 1.0, (0.0, 300.0), dtype="int32")
    out = tmp_path / "data"
    result = invoke("build-dataset", "--out", out, "--dtm", path, "--workers", "1", *BUILD_ARGS)
    assert result.exit_code == 0, result.output
    assert all(scan.valid.all() and abs(scan.origin_map[2] - 100) < 1e-6 for scan in iter_scans(out))


def test_a_build_whose_rays_miss_fails_and_leaves_nothing(tmp_path, dtm, monkeypatch):
    from lidarsim.scan import TileScene

    def no_returns(self, origins_map, directions, n_threads=0):
        return np.full(directions.shape[:3], np.nan, dtype=np.float32)

    monkeypatch.setattr(TileScene, "cast", no_returns)
    out = tmp_path / "data"
    assert_one_line_error(
        invoke("build-dataset", "--out", out, "--dtm", dtm, "--workers", "1", *BUILD_ARGS),
        "scan 0",
        "only 0.0% of the rays hit the terrain",
        "hills.tif",
    )
    assert not out.exists()


@pytest.mark.parametrize(("hits", "ok"), [(0.0, False), (0.49, False), (0.5, True), (1.0, True)])
def test_the_return_threshold(hits, ok):
    status = np.full((10, 10), STATUS_MISS, np.uint8)
    status[0, :] = STATUS_DEAD  # dead elements are not counted
    working = np.flatnonzero(status.ravel() != STATUS_DEAD)
    status.ravel()[working[: int(round(hits * working.size))]] = STATUS_RETURN
    assert limits.MIN_RETURN_FRACTION == 0.5
    if ok:
        check_returns(status, 7, "x.tif")
    else:
        with pytest.raises(LidarsimError, match="scan 7: only"):
            check_returns(status, 7, "x.tif")


@pytest.mark.parametrize("georeferencing", ["origin-0-1m", "none"])
def test_detect_on_a_dtm_in_local_metres_prints_no_warning(tmp_path, trained, georeferencing):
    """No CRS (local metres): 1 m cells with the corner at 0, 0 (the transform GDAL calls "the identity or
    its flipped counterpart"), or no geotransform at all (cells taken as 1 m). hd maps it without a
    word: rasterio's NotGeoreferencedWarning was printed raw when the maps were written."""
    heights = rasterio.open(hills(tmp_path / "hills.tif", n=120)).read(1)
    dtm = tmp_path / "local.tif"
    place = {"transform": from_origin(0.0, 0.0, 1.0, 1.0)} if georeferencing != "none" else {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)  # this test's own writing
        with rasterio.open(dtm, "w", driver="GTiff", width=120, height=120, count=1, dtype="float32", **place) as dst:
            dst.write(heights, 1)
    out = tmp_path / "maps"
    proc = hd_process(["detect", trained, "--dtm", dtm, "--out", out, "--threshold", "nats:0.3", "--mc-samples", "2"])
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    lines = [line for line in err.replace("\r", "\n").splitlines() if line.strip() and not line.startswith("tiles:")]
    assert lines == [], err
    assert (out / "detect.json").is_file()


def _base(path, kind: str):
    """A 20 x 20 base DTM of 1 m cells: all NaN, all its declared nodata value, or valid cells that
    never form a 2 x 2 block (every other row and column)."""
    if kind == "all-nan":
        return write_geotiff(path, np.full((20, 20), np.nan, np.float32))
    if kind == "all-nodata":
        return write_geotiff(path, np.full((20, 20), -9999.0, np.float32), nodata=-9999.0)
    z = np.full((20, 20), np.nan, np.float32)
    z[::2, ::2] = 5.0
    return write_geotiff(path, z)


@pytest.mark.parametrize(
    ("kind", "needle"),
    [
        ("all-nan", "every cell is nodata"),
        ("all-nodata", "every cell is nodata"),
        ("isolated", "100 of 400 cells are valid, none in a 2 x 2 block of valid cells"),
    ],
)
def test_make_dtm_refuses_a_base_without_relief_before_any_work(tmp_path, monkeypatch, kind, needle):
    """hd make-dtm --base wrote a terrain of rocks on NaN (a numpy RuntimeWarning, exit 0): nodata
    everywhere, or valid cells so scattered that bilinear resampling leaves no relief."""
    from lidarsim import base_relief

    def no_work(*args, **kwargs):
        raise AssertionError("the base was resampled before it was checked")

    monkeypatch.setattr(base_relief, "resample_bilinear", no_work)
    base = _base(tmp_path / "base.tif", kind)
    out = tmp_path / "rocky.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        assert_one_line_error(invoke("make-dtm", out, "--base", base), "base.tif", needle)
    assert not out.exists()


def test_a_build_with_rocks_on_a_dtm_of_nodata_is_one_line(tmp_path):
    base = _base(tmp_path / "base.tif", "all-nan")
    out = tmp_path / "data"
    result = invoke("build-dataset", "--out", out, "--dtm", base, "--rocks-on-dtm", "--workers", "1", *BUILD_ARGS)
    last = assert_one_line_error(result, "base.tif", "every cell is nodata")
    assert "RuntimeWarning" not in result.output and last == result.output.strip()
    assert not out.exists()
