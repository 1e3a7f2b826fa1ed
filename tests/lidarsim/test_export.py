"""hd export: scans as LAS 1.4 / LAZ read back with laspy, coordinates equal to the shard's to 0.1 mm."""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from rasterio.crs import CRS
from terrain_files import plane, write_tif

from hdcli.cli import main
from hdcore.errors import OutputExistsError, StorageError
from lidarsim.build import BuildConfig, build_dataset
from lidarsim.errors import LidarsimError
from lidarsim.export import COORDINATE_SCALE_M, ExportSettings, export_scans, parse_scans
from lidarsim.sensor import SensorConfig
from lidarsim.shards import ScanShardReader, read_manifest
from lidarsim.trajectory import TrajectoryConfig

X0, Y0 = 500000.0, 4100000.0  # top-left corner of the UTM terrain, metres
# Half a LAS unit (rounding) plus the float32 of the stored points at 500 m (about 0.03 mm).
TOLERANCE_M = COORDINATE_SCALE_M / 2 + 5e-5


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("export")
    z = plane(200, 200, 1.0, 100.0, 0.02, 0.03)
    dtm = write_tif(root / "utm.tif", z, 1.0, (X0, Y0), crs=CRS.from_epsg(32610))
    out = root / "data"
    build_dataset(
        out,
        BuildConfig(
            sigmas_m=(0.01, 0.05),
            seed=2,
            sensor=SensorConfig(rows=32, cols=32, dead_elements=5),
            trajectory=TrajectoryConfig(n_scans=3),
            dtm_path=str(dtm),
            shard_size=2,
        ),
        workers=1,
    )
    return out


def shard_scan(root: Path, index: int):
    manifest = read_manifest(root)
    for entry in manifest["shards"]:
        if entry["first_scan"] <= index < entry["first_scan"] + entry["n_scans"]:
            with ScanShardReader(root / entry["path"]) as reader:
                return reader[index - entry["first_scan"]]
    raise AssertionError(index)


def test_parse_scans():
    assert parse_scans("3") == (3,)
    assert parse_scans("0, 5,2-4,5") == (0, 5, 2, 3, 4)
    for bad in ("", "a", "3-1", "-2", "1,,2"):
        with pytest.raises(LidarsimError, match="--scans"):
            parse_scans(bad)


def test_laz_in_the_scan_frame_reads_back_as_the_shard(dataset, tmp_path):
    summary = export_scans(dataset, tmp_path / "out", ExportSettings(scans=(2, 0)))
    assert summary.n_files == 2 and not summary.crs
    record = json.loads((tmp_path / "out" / "export.json").read_text())
    assert [f["file"] for f in record["files"]] == ["scan-000000.laz", "scan-000002.laz"]
    for index in (0, 2):
        scan = shard_scan(dataset, index)
        las = laspy.read(tmp_path / "out" / f"scan-{index:06d}.laz")
        assert las.header.version.major == 1 and las.header.version.minor == 4
        assert las.header.point_format.id == 6 and np.allclose(las.header.scales, COORDINATE_SCALE_M)
        rows, cols = np.asarray(las.detector_row), np.asarray(las.detector_col)
        expected = scan.points_clean[rows, cols].astype(np.float64)
        got = np.stack([las.x, las.y, las.z], axis=-1)
        assert np.abs(got - expected).max() <= TOLERANCE_M
        returns = int(np.isfinite(scan.points_clean[..., 0]).sum())
        assert len(las.points) == returns == scan.valid.sum()  # every return, nothing else (5 dead elements)
        assert set(np.asarray(las.scan_index)) == {index} and set(np.asarray(las.point_source_id)) == {index}
        assert set(np.asarray(las.status)) <= {0, 3}
        assert not las.header.global_encoding.wkt and not [v for v in las.header.vlrs if v.record_id == 2112]


def test_noisy_points_in_map_coordinates_carry_the_crs(dataset, tmp_path):
    out = tmp_path / "map"
    summary = export_scans(dataset, out, ExportSettings(format="las", frame="map", cloud="noisy", sigma_m=0.05))
    assert summary.n_files == 3 and summary.crs
    scan = shard_scan(dataset, 1)
    las = laspy.read(out / "scan-000001.las")
    expected = scan.points_noisy[1][np.asarray(las.detector_row), np.asarray(las.detector_col)] + scan.origin_map
    got = np.stack([las.x, las.y, las.z], axis=-1)
    assert np.abs(got - expected).max() <= TOLERANCE_M
    assert got[:, 0].min() > X0 and got[:, 1].max() < Y0  # on the terrain, in UTM metres
    assert las.header.global_encoding.wkt
    (vlr,) = [v for v in las.header.vlrs if (v.user_id, v.record_id) == ("LASF_Projection", 2112)]  # OGC WKT
    assert CRS.from_wkt(vlr.string.rstrip("\x00")) == CRS.from_epsg(32610)


def test_an_exported_laz_gives_its_crs_back_to_laspy(dataset, tmp_path):
    """laspy reads a file's CRS with pyproj (``header.parse_crs``), which hd installs with laspy."""
    export_scans(dataset, tmp_path / "map", ExportSettings(frame="map", scans=(0,)))
    las = laspy.read(tmp_path / "map" / "scan-000000.laz")
    crs = las.header.parse_crs()
    assert crs is not None and crs.to_epsg() == 32610


def test_bad_input_is_one_line_and_an_export_is_not_replaced_silently(dataset, tmp_path):
    runner = CliRunner()
    out = tmp_path / "o"
    ok = runner.invoke(main, ["export", str(dataset), "--format", "laz", "--out", str(out), "--scans", "1"])
    assert ok.exit_code == 0, ok.output
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    again = runner.invoke(main, ["export", str(dataset), "--out", str(out), "--scans", "0"])
    assert again.exit_code != 0 and "--overwrite" in again.output and len(again.output.strip().splitlines()) == 1
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    replaced = runner.invoke(main, ["export", str(dataset), "--out", str(out), "--scans", "0", "--overwrite"])
    assert replaced.exit_code == 0, replaced.output
    assert sorted(p.name for p in out.iterdir()) == ["export.json", "scan-000000.laz"]
    for args, needle in [
        (["--scans", "7"], "has scans 0..2"),
        (["--cloud", "noisy", "--sigma", "0.02"], "0.02 is not one of them"),
        (["--scans", "x"], "--scans"),
    ]:
        bad = runner.invoke(main, ["export", str(dataset), "--out", str(tmp_path / "b"), *args])
        assert bad.exit_code != 0 and needle in bad.output and "Traceback" not in bad.output, bad.output
        assert not (tmp_path / "b").exists()
    missing = runner.invoke(main, ["export", str(tmp_path / "nothing"), "--out", str(tmp_path / "b")])
    assert missing.exit_code != 0 and "Traceback" not in missing.output


def test_a_failed_write_leaves_nothing(dataset, tmp_path, monkeypatch):
    calls = []

    def fail_second(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        return real(self, *args, **kwargs)

    real = laspy.LasData.write
    monkeypatch.setattr(laspy.LasData, "write", fail_second)
    with pytest.raises(StorageError, match="no space left on device"):
        export_scans(dataset, tmp_path / "full", ExportSettings())
    assert not (tmp_path / "full").exists()
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "notes.txt").write_text("mine")
    with pytest.raises(OutputExistsError, match="holds no hd export output"):
        export_scans(dataset, tmp_path / "taken", ExportSettings(), overwrite=True)
    assert [p.name for p in (tmp_path / "taken").iterdir()] == ["notes.txt"]
