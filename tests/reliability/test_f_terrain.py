"""Class F: non-finite and absurd heights are nodata; a build whose scans come back empty fails.

A DTM whose top third holds a fill value the producer did not declare (+-inf, +-1e30, 3e38, NaN)
must give the same kind of dataset as a clean one: scans placed on the valid part only, every ray
returning, scan origins at finite heights.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import warnings
from collections.abc import Iterator
from pathlib import Path

import h5py
import numpy as np
import pytest
import rasterio
from click.testing import Result
from rasterio.transform import from_origin
from reliability_kit import (
    BUILD_ARGS,
    assert_one_line_error,
    hd_process,
    hills,
    invoke,
    partials,
    shard_sums,
)

from lidarsim import limits
from lidarsim.build import check_returns
from lidarsim.errors import LidarsimError
from lidarsim.scan import STATUS_DEAD, STATUS_MISS, STATUS_RETURN
from lidarsim.shards import iter_scans, read_manifest, sha256_file
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


# ------------------------------------------------------------------ terrain-truth labels and their terrain
@pytest.fixture(scope="module")
def on_own_dtm(tmp_path_factory) -> tuple[Path, Path]:
    """A dataset built on a DTM of its own (the manifest records the DTM's absolute path and sha256)."""
    root = tmp_path_factory.mktemp("own")
    dtm = hills(root / "own.tif")
    data = root / "data"
    result = invoke("build-dataset", "--out", data, "--dtm", dtm, "--workers", "1", *BUILD_ARGS)
    assert result.exit_code == 0, result.output
    return dtm, data


@pytest.fixture
def own(tmp_path, on_own_dtm) -> Iterator[tuple[Path, Path]]:
    """A private copy of that dataset, and its DTM, whose bytes are put back after the test."""
    dtm, data = on_own_dtm
    original = dtm.read_bytes()
    copy = tmp_path / "copy"
    shutil.copytree(data, copy)
    yield dtm, copy
    dtm.unlink()
    dtm.write_bytes(original)


def reseal(dataset: Path) -> None:
    """Record every file's sha256 in the manifest (a copy edited consistently)."""
    m = read_manifest(dataset)
    for e in m["shards"] + [e for lab in m["labelings"] for e in lab["shards"]]:
        e["sha256"] = sha256_file(dataset / e["path"])
        e["size_bytes"] = (dataset / e["path"]).stat().st_size
    (dataset / "manifest.json").write_text(json.dumps(m))


def terrain_label(data: Path) -> Result:
    return invoke("label", data, "--truth", "terrain", "--workers", "1")


@pytest.mark.parametrize("when", ["between-shards", "within-a-shard"])
def test_a_terrain_replaced_while_labelled_stops_the_labelling(own, tmp_path, monkeypatch, when):
    """The DTM was checked once, before the labelling: one replaced while the shards read it gave a
    labelling of two terrains, with exit status 0. It is now checked as each shard reads it: in place
    after the first shard, or as a new file under its name after a scan of the first shard."""
    from hdlabels import labeling

    dtm, data = own
    other = hills(tmp_path / "other.tif", seed=4)
    before = (data / "manifest.json").read_text()
    if when == "between-shards":
        real_task = labeling.run_label_task

        def replaced_after(task):
            record = real_task(task)
            shutil.copyfile(other, dtm)  # the same file, other bytes
            return record

        monkeypatch.setattr(labeling, "run_label_task", replaced_after)
    else:
        real_scan = labeling.label_scan

        def replaced_after_scan(*args, **kwargs):
            arrays = real_scan(*args, **kwargs)
            os.replace(shutil.copyfile(other, tmp_path / "swap.tif"), dtm)  # another file under its name
            return arrays

        monkeypatch.setattr(labeling, "label_scan", replaced_after_scan)
    assert_one_line_error(terrain_label(data), "own.tif: the terrain changed while copy was labelled")
    assert (data / "manifest.json").read_text() == before
    assert not list(data.glob("labels/**/*.h5")) and partials(data) == []


def test_a_terrain_labelling_hashes_its_dtm_once(own, monkeypatch):
    """Each label shard hashed the whole DTM before it read it (about 21 GB read for a 1 GB HiRISE
    DTM): now the labelling hashes it once and each shard compares the file's identity (device,
    inode, size, modification and change times), hashing again only when that changed (the test
    above: a DTM replaced between or within shards is still refused)."""
    from hdlabels import truth

    dtm, data = own
    assert len(read_manifest(data)["shards"]) == 4
    hashed: list[str] = []
    real = truth.dtm_sha256

    def counting(path, *args, **kwargs):
        hashed.append(Path(path).name)
        return real(path, *args, **kwargs)

    monkeypatch.setattr(truth, "dtm_sha256", counting)
    result = terrain_label(data)
    assert result.exit_code == 0, result.output
    assert hashed == [dtm.name]


def test_a_side_file_written_beside_the_dtm_is_a_changed_terrain(own, tmp_path):
    """GDAL reads an .aux.xml beside a GeoTIFF (its metadata, nodata, scale, offset), but the DTM's
    digest was its own bytes alone: one written after the build went unnoticed. It is now part of
    the digest: the terrain truth refuses the terrain, and the same build is not reused."""
    dtm, data = own
    aux = dtm.with_name(dtm.name + ".aux.xml")
    before = (data / "manifest.json").read_text()
    try:
        aux.write_text("<PAMDataset><PAMRasterBand band='1'><Offset>100</Offset></PAMRasterBand></PAMDataset>")
        assert_one_line_error(terrain_label(data), "own.tif: the terrain changed since copy was built")
        again = invoke("build-dataset", "--out", data, "--dtm", dtm, "--workers", "1", *BUILD_ARGS)
        assert_one_line_error(again, "whose shards or DTM changed")
        assert (data / "manifest.json").read_text() == before
    finally:
        aux.unlink(missing_ok=True)
    assert terrain_label(data).exit_code == 0


def test_a_label_shard_of_another_terrain_is_damage_to_verify_and_to_label(own, tmp_path, labelled):
    """Each terrain-truth label shard records the sha256 of the terrain it was labelled from (schema
    1.2); one that records another terrain made `hd verify` say OK and a second `hd label` say
    "already labelled". Now verify names it, and label labels it again (with a warning)."""
    dtm, data = own
    assert terrain_label(data).exit_code == 0
    manifest = read_manifest(data)
    (lab,) = manifest["labelings"]
    assert lab["schema_version"] == "1.2" and {e["schema_version"] for e in lab["shards"]} == {"1.2"}
    for entry in lab["shards"]:
        with h5py.File(data / entry["path"], "r") as f:
            assert f.attrs["schema_version"] == "1.2"
            assert f.attrs["truth_dtm_sha256"] == manifest["dtm"]["sha256"] == sha256_file(dtm)
    for entry in read_manifest(labelled)["labelings"][0]["shards"]:  # the clean scan's: as before
        with h5py.File(labelled / entry["path"], "r") as f:
            assert f.attrs["schema_version"] == "1.1" and "truth_dtm_sha256" not in f.attrs
    path = data / lab["shards"][1]["path"]
    made = sha256_file(path)
    with h5py.File(path, "r+") as f:  # as a shard labelled from another terrain records it
        f.attrs["truth_dtm_sha256"] = sha256_file(hills(tmp_path / "other.tif", seed=4))
    reseal(data)
    checked = invoke("verify", data)
    assert checked.exit_code == 1
    assert f"{lab['shards'][1]['path']}: labelled from another terrain (truth_dtm_sha256 " in checked.stderr
    again = terrain_label(data)
    assert again.exit_code == 0 and "already labelled" not in again.output
    assert "Warning: copy: 1 label shard(s) of " in again.stderr and "labelling them again" in again.stderr
    assert sha256_file(path) == made and invoke("verify", data).exit_code == 0
    assert "already labelled" in terrain_label(data).output


def test_a_resumed_terrain_labelling_keeps_no_shard_of_another_terrain(own, tmp_path, monkeypatch):
    """An interrupted labelling resumed with a complete shard on disk that records another terrain
    (labelled before the DTM was put back): the shard is labelled again, not kept."""
    from hdlabels import labeling

    _, data = own
    fresh = tmp_path / "fresh"
    shutil.copytree(data, fresh)
    assert terrain_label(fresh).exit_code == 0
    real_task = labeling.run_label_task
    calls: list[int] = []

    def full_disk_after_one(task):
        calls.append(1)
        if len(calls) > 1:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), task.out_path)
        return real_task(task)

    monkeypatch.setattr(labeling, "run_label_task", full_disk_after_one)
    assert terrain_label(data).exit_code == 1
    monkeypatch.undo()
    (left,) = data.glob("labels/*/labels-*.h5")
    with h5py.File(left, "r+") as f:
        f.attrs["truth_dtm_sha256"] = "0" * 64
    assert terrain_label(data).exit_code == 0
    assert shard_sums(data) == shard_sums(fresh)


def test_a_changed_procedural_terrain_is_regenerated_for_the_terrain_truth(tmp_path):
    """The procedural terrain is a function of the build's seed and parameters: a changed terrain/
    file was refused; it is written back when it regenerates to the recorded sha256 (as a missing one)."""
    from lidarsim.build import BuildConfig, build_dataset
    from lidarsim.procedural import MarsTerrainParams
    from lidarsim.sensor import SensorConfig
    from lidarsim.trajectory import TrajectoryConfig

    data = tmp_path / "data"
    config = BuildConfig(
        sigmas_m=(0.02,),
        seed=3,
        sensor=SensorConfig(rows=32, cols=32),
        trajectory=TrajectoryConfig(n_scans=2),
        terrain=MarsTerrainParams(size_m=256.0),
        shard_size=2,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the tiny terrain's overlap warning
        build_dataset(data, config, workers=1)
    terrain = data / "terrain" / "mars-procedural-seed3.tif"
    recorded = read_manifest(data)["dtm"]["sha256"]
    terrain.write_bytes(terrain.read_bytes()[:-64] + bytes(64))
    result = terrain_label(data)
    assert result.exit_code == 0, result.output
    assert "had changed since the build: regenerated from the build's seed 3" in result.stderr
    assert sha256_file(terrain) == recorded and invoke("verify", data).exit_code == 0
