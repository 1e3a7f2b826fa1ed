"""The terrain truth (``hd label --truth terrain``): the DTM on each scan's DEM grid instead of the clean scan."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from hdcli.cli import main
from hdlabels.errors import HdLabelsError
from hdlabels.grid import grid_points
from hdlabels.labeling import label_dataset
from hdlabels.settings import LabelSettings
from hdlabels.store import (
    DemSpec,
    LabeledScan,
    LabelShardReader,
    LabelStoreError,
    find_labeling,
)
from hdlabels.truth import mesh_heights, sample_points, samples_per_cell
from lidarsim.build import BuildConfig, build_dataset
from lidarsim.procedural import MarsTerrainParams
from lidarsim.scan import TileScene
from lidarsim.sensor import SensorConfig
from lidarsim.shards import read_manifest
from lidarsim.terrain import DTM
from lidarsim.trajectory import TrajectoryConfig
from tests.geotiff import write_geotiff

SIDE_M = 160.0  # the rock field
PLANE_SIDE_M = 240.0  # room for a footprint tilted 4 degrees


def write_dtm(path: Path, heights: np.ndarray, spacing_m: float) -> Path:
    """A north-up float32 GeoTIFF of ``heights`` with its top-left corner at (0, its height in metres)."""
    return write_geotiff(path, heights, spacing_m, (0.0, heights.shape[0] * spacing_m))


def plane_dtm(path: Path, slope_deg: float, spacing_m: float = 0.5) -> Path:
    """A plane rising eastwards at ``slope_deg`` (and gently northwards), PLANE_SIDE_M square."""
    n = int(PLANE_SIDE_M / spacing_m)
    x = (np.arange(n) + 0.5) * spacing_m
    y = PLANE_SIDE_M - (np.arange(n) + 0.5) * spacing_m
    z = 20.0 + np.tan(np.radians(slope_deg)) * x[None, :] + 0.01 * y[:, None]
    return write_dtm(path, z, spacing_m)


def build(dtm: Path | None, out: Path, n_scans: int = 3, tilt_deg: float = 0.0) -> Path:
    """A small dataset (seed 3) on ``dtm``, or on a 256 m procedural terrain when None."""
    build_dataset(
        out,
        BuildConfig(
            sigmas_m=(0.02,),
            seed=3,
            sensor=SensorConfig(rows=64, cols=64),
            trajectory=TrajectoryConfig(n_scans=n_scans, tilt_deg=tilt_deg),
            dtm_path=None if dtm is None else str(dtm),
            terrain=MarsTerrainParams(size_m=256.0),
            shard_size=n_scans,
        ),
        workers=1,
    )
    return out


def labelled(root: Path, name: str) -> list[LabeledScan]:
    entry = find_labeling(root, name)
    scans: list[LabeledScan] = []
    for path in entry.shard_paths(root):
        with LabelShardReader(path) as reader:
            scans.extend(reader)
    return scans


def test_samples_per_cell_is_odd_and_covers_every_dtm_cell():
    assert samples_per_cell(1.0, 0.5) == 5  # 0.2 m apart: two per 0.5 m cell along each axis
    assert samples_per_cell(1.0, 1.0) == 3  # the minimum
    assert samples_per_cell(1.0, 0.1, "max") == 15  # the maximum
    assert all(samples_per_cell(1.0, s) % 2 == 1 for s in (0.13, 0.3, 0.7, 2.0))
    assert samples_per_cell(1.0, 0.1, "nearest") == samples_per_cell(1.0, 0.1, "linear") == 1  # the centre


@pytest.mark.parametrize("gridding", ["nearest", "linear"])
def test_the_centre_alone_gives_the_dense_dem_of_centre_griddings(tmp_path, gridding):
    """nearest takes the most central sample and linear interpolates at the centre, a sample: the
    centre's height either way, so one ray per cell gives the DEM of 5 x 5."""
    dtm_path, _ = rock_field(tmp_path / "rocks.tif")
    grid = DemSpec(rows=30, cols=30, spacing_m=1.0, gridding=gridding)
    origin = np.array([80.8, 81.2, 0.0])  # cell centres on the rocks' centres (x = 1.3 + 6k, y = 158.7 - 6k)
    with DTM.open(dtm_path) as dtm:
        dense = grid_points(sample_points(origin, grid, 5, dtm), (30, 30), 1.0, method=gridding)
        centre = grid_points(sample_points(origin, grid, 1, dtm), (30, 30), 1.0, method=gridding)
    assert np.ptp(dense) == pytest.approx(0.4, abs=1e-3)  # rocks under the grid, at their full height
    np.testing.assert_allclose(centre, dense, atol=1e-6)


def test_the_sampled_surface_is_the_one_the_rays_hit(tmp_path):
    """mesh_heights equals vertical rays cast on the build's Open3D scene of the same DTM (a rock field
    with a nodata hole), to the scene's float32 precision, holes included."""
    dtm_path, _ = rock_field(tmp_path / "rocks.tif")
    with rasterio.open(dtm_path, "r+") as f:
        z = f.read(1)
        z[400:420, 400:430] = np.nan  # a hole: the mesh leaves its triangles out
        f.write(z, 1)
    rng = np.random.default_rng(5)
    x, y = rng.uniform(70.0, 95.0, 4000), rng.uniform(70.0, 95.0, 4000)
    with DTM.open(dtm_path) as dtm:
        got = mesh_heights(dtm, x, y)
        scene = TileScene(dtm, (82.0, 82.0), 20.0)
        top = 10.0
        down = np.zeros((x.size, 1, 1, 3))
        down[..., 2] = -1.0
        t = scene.cast(np.stack([x, y, np.full_like(x, top)], axis=-1), down)[:, 0, 0]
    hit = top - t.astype(np.float64)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(hit))
    assert np.isnan(got).sum() > 100 and np.nanmax(got) > 0.39  # the hole and the rocks were sampled
    np.testing.assert_allclose(got, hit, atol=2e-5, equal_nan=True)


def test_sampled_surface_is_the_plane_in_the_scan_frame(tmp_path):
    """On a tilted plane the samples are z(x, y) - z_ref."""
    dtm_path = plane_dtm(tmp_path / "p.tif", 8.0)
    origin = np.array([80.3, 79.6, 25.0])
    with DTM.open(dtm_path) as dtm:
        pts = sample_points(origin, DemSpec(rows=10, cols=12, spacing_m=1.0), 3, dtm)
    assert pts.shape == (30, 36, 3)
    x, y = origin[0] + pts[..., 0], origin[1] + pts[..., 1]
    expected = 20.0 + np.tan(np.radians(8.0)) * x + 0.01 * y - origin[2]
    np.testing.assert_allclose(pts[..., 2], expected, atol=1e-4)  # the float32 GeoTIFF
    # the centre sample of the north-west cell sits at its centre: x = -5.5, y = +4.5 (metres)
    np.testing.assert_allclose(pts[1, 1, :2], [-5.5, 4.5])


@pytest.mark.parametrize(("slope_deg", "tilt_deg"), [(0.0, 0.0), (5.0, 0.0), (15.0, 4.0)])
@pytest.mark.parametrize("convention", ["paper", "hd"])
def test_on_a_plane_the_terrain_truth_equals_the_clean_scan_truth(tmp_path, slope_deg, tilt_deg, convention):
    root = build(plane_dtm(tmp_path / "p.tif", slope_deg), tmp_path / "d", tilt_deg=tilt_deg)
    grid = LabelSettings(convention=convention).to_dem_spec()
    clean = label_dataset(root, LabelSettings(convention=convention), workers=1)
    terrain = label_dataset(root, LabelSettings(convention=convention, truth="terrain"), workers=1)
    assert terrain.name == f"{clean.name}-truth-terrain" and terrain.truth == "terrain" and clean.truth == "clean-scan"
    assert terrain.safe_fraction == clean.safe_fraction == (0.0 if slope_deg > 10 else 1.0)
    for a, b in zip(labelled(root, clean.name), labelled(root, terrain.name), strict=True):
        np.testing.assert_array_equal(a.label, b.label)
        np.testing.assert_array_equal(np.isnan(a.dem_clean), np.isnan(b.dem_clean))
        if grid.gridding == "linear":  # both interpolate the plane at the cell centres
            np.testing.assert_allclose(a.dem_clean, b.dem_clean, atol=1e-3)
        np.testing.assert_array_equal(a.dem_noisy, b.dem_noisy)  # the baseline's inputs are the scan's
        np.testing.assert_array_equal(a.p_safe, b.p_safe)


def rock_field(path: Path, spacing_m: float = 0.2) -> tuple[Path, float]:
    """Flat ground with 0.4 m high flat-topped rocks every 6 m, 0.6 m wide at the top and 1 m at the foot
    on the 0.2 m mesh: no wider than a 1 m pixel, narrower than the 64 x 64 sensor's 1.64 m return
    spacing at 500 m. Returns the path and the rocks' height (metres)."""
    n = int(SIDE_M / spacing_m)
    c = (np.arange(n) + 0.5) * spacing_m
    dx = np.abs((c + 1.7) % 6.0 - 3.0)  # distance to the nearest rock centre along each axis
    r2 = dx[None, :] ** 2 + dx[:, None] ** 2
    height = 0.4
    return write_dtm(path, np.where(r2 <= 0.3**2, height, 0.0), spacing_m), height


def test_rocks_smaller_than_a_pixel_are_seen_by_the_terrain_truth(tmp_path):
    """The sensor's sparse returns catch few sub-pixel rocks and the gridding flattens those; the
    terrain truth samples every DEM cell centre, so it sees more rocks at their full height: more
    unsafe pixels, never fewer (hd convention, linear gridding)."""
    dtm_path, height = rock_field(tmp_path / "rocks.tif")
    root = build(dtm_path, tmp_path / "d", n_scans=2)
    clean = label_dataset(root, LabelSettings(convention="hd"), workers=1)
    terrain = label_dataset(root, LabelSettings(convention="hd", truth="terrain"), workers=1)
    n_unsafe = {"clean": 0, "terrain": 0}
    for a, b in zip(labelled(root, clean.name), labelled(root, terrain.name), strict=True):
        ground = np.nanmedian(b.dem_clean)  # the scan frame's heights are relative to its reference height
        assert np.nanmax(b.dem_clean) - ground == pytest.approx(height, abs=1e-3)  # a rock at full height
        rocky_truth = np.sum(b.dem_clean > ground + height - 0.01)
        rocky_scan = np.sum(a.dem_clean > ground + height - 0.01)
        assert rocky_truth > rocky_scan  # the scan's DEM reaches the full height at fewer cells
        n_unsafe["clean"] += int((a.label == 0).sum())
        n_unsafe["terrain"] += int((b.label == 0).sum())
    assert n_unsafe["terrain"] > n_unsafe["clean"]
    assert terrain.safe_fraction < clean.safe_fraction


def test_the_label_store_records_the_truth(tmp_path):
    root = build(plane_dtm(tmp_path / "p.tif", 0.0), tmp_path / "d", n_scans=2)
    clean = label_dataset(root, workers=1)
    terrain = label_dataset(root, LabelSettings(truth="terrain"), workers=1)
    manifest = read_manifest(root)
    by_name = {lab["name"]: lab for lab in manifest["labelings"]}
    assert "truth" not in by_name[clean.name]  # the clean scan's entries are as before
    assert by_name[terrain.name]["truth"] == "terrain"
    with LabelShardReader(find_labeling(root, clean.name).shard_paths(root)[0]) as reader:
        assert "truth" not in reader.h5.attrs
    with LabelShardReader(find_labeling(root, terrain.name).shard_paths(root)[0]) as reader:
        attrs = reader.h5.attrs
        assert attrs["truth"] == "terrain" and attrs["truth_dtm"] == "p.tif" and attrs["truth_dtm_scale"] == 1.0
    shown = CliRunner().invoke(main, ["inspect", str(root)])
    assert shown.exit_code == 0, shown.output
    lines = {line.split(":")[0]: line for line in shown.output.splitlines() if line.startswith("labels")}
    assert "truth: terrain" in lines[f"labels    {terrain.name}"]
    assert "truth: clean scan" in lines[f"labels    {clean.name}"]
    again = label_dataset(root, LabelSettings(truth="terrain"), workers=1)
    assert again.reused


def test_a_missing_or_changed_terrain_is_one_line(tmp_path):
    dtm_path = plane_dtm(tmp_path / "p.tif", 0.0)
    root = build(dtm_path, tmp_path / "d", n_scans=2)
    before = (root / "manifest.json").read_text()
    plane_dtm(dtm_path, 1.0)  # other heights, the same name
    with pytest.raises(LabelStoreError, match=r"p\.tif: the terrain changed since d was built"):
        label_dataset(root, LabelSettings(truth="terrain"), workers=1)
    dtm_path.unlink()
    result = CliRunner().invoke(main, ["label", str(root), "--truth", "terrain", "--workers", "1"])
    assert result.exit_code != 0 and "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1 and "is missing" in result.output
    assert (root / "manifest.json").read_text() == before
    assert not (root / "labels").exists() or not any((root / "labels").rglob("*.h5"))
    # the clean-scan truth needs no terrain
    assert label_dataset(root, workers=1).safe_fraction == 1.0


def test_a_recipe_names_the_truth():
    assert LabelSettings.from_recipe({}).truth == "clean-scan"
    assert LabelSettings.from_recipe({"truth": "terrain"}).truth == "terrain"
    with pytest.raises(HdLabelsError, match=r"\[label\] truth = 'dtm' is not one of clean-scan, terrain"):
        LabelSettings.from_recipe({"truth": "dtm"}, "r.toml")


def test_a_missing_procedural_terrain_is_regenerated_when_it_gives_the_recorded_bytes(tmp_path, monkeypatch):
    """The procedural terrain is a function of the build's seed and parameters (in the manifest):
    a deleted terrain/ file is written back, with a warning, when it hashes to the recorded sha256;
    otherwise the labelling stops with one line and writes nothing."""
    from hdcore.errors import HdWarning
    from lidarsim import build as build_module
    from lidarsim.errors import LidarsimError
    from lidarsim.shards import sha256_file

    root = build(None, tmp_path / "d", n_scans=2)
    terrain = root / "terrain" / "mars-procedural-seed3.tif"
    recorded = sha256_file(terrain)
    terrain.unlink()
    real = build_module._procedural_terrain_bytes
    monkeypatch.setattr(build_module, "_procedural_terrain_bytes", lambda *a: real(*a) + b"\0")
    with pytest.raises(
        LidarsimError, match=r"mars-procedural-seed3\.tif: .* is missing, and regenerating it .* other bytes"
    ):
        label_dataset(root, LabelSettings(truth="terrain"), workers=1)
    assert not terrain.exists() and not list(root.glob("labels/**/*.h5"))
    monkeypatch.setattr(build_module, "_procedural_terrain_bytes", real)
    with pytest.warns(HdWarning, match="was missing: regenerated from the build's seed 3"):
        summary = label_dataset(root, LabelSettings(truth="terrain"), workers=1)
    assert sha256_file(terrain) == recorded and summary.truth == "terrain" and 0.0 < summary.safe_fraction <= 1.0


def test_a_labelling_is_chosen_by_its_name_or_an_alias_and_an_ambiguity_names_both(tmp_path):
    """The clean-scan labelling's name is a prefix of its terrain twin's: the exact name wins, and the
    aliases ``paper`` / ``paper+terrain`` (convention, then truth; the clean scan's by default) pick one
    of the two; a name or alias that fits several is refused with the names and aliases there are."""
    root = build(plane_dtm(tmp_path / "p.tif", 0.0), tmp_path / "d", n_scans=2)
    clean = label_dataset(root, workers=1).name
    terrain = label_dataset(root, LabelSettings(truth="terrain"), workers=1).name
    assert terrain.startswith(clean)
    assert find_labeling(root, clean).name == clean  # exact beats the prefix of the terrain's name
    assert find_labeling(root, terrain).name == terrain
    assert find_labeling(root, "paper").name == clean  # the paper's own truth
    assert find_labeling(root, "paper+clean-scan").name == clean
    assert find_labeling(root, "paper+terrain").name == terrain
    assert find_labeling(root, "PAPER+Terrain").name == terrain
    with pytest.raises(LabelStoreError, match="several labellings") as info:
        find_labeling(root)
    assert f"paper = {clean}" in str(info.value) and f"paper+terrain = {terrain}" in str(info.value)
    with pytest.raises(LabelStoreError, match="no labelling named 'hd'") as info:
        find_labeling(root, "hd")  # no hd-convention labelling here
    assert "aliases: paper, paper+clean-scan, paper+terrain" in str(info.value)
    with pytest.raises(LabelStoreError, match="names 2 labellings") as info:
        find_labeling(root, clean[:12])  # a prefix of both
    assert "paper+terrain" in str(info.value)
    hd_clean = label_dataset(root, LabelSettings(convention="hd"), workers=1).name
    hd_terrain = label_dataset(root, LabelSettings(convention="hd", truth="terrain"), workers=1)
    assert find_labeling(root, "hd").name == hd_clean
    assert find_labeling(root, "hd+terrain").name == hd_terrain.name
    assert find_labeling(root, "paper").name == clean  # still, among four
    with pytest.raises(LabelStoreError, match="'paper\\+rock' is not an alias"):
        find_labeling(root, "paper+rock")
