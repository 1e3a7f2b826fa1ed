"""hd detect: maps and sites for DTMs and scans, the contract with training and hd eval, bad input.

Two runs: the tiny run trained for one epoch on the tiny dataset (``hdnet_datasets``), and a
*constant* run made from it whose classifier ignores its input (zero weights, bias favouring
"safe"), so that its safety map is "safe wherever valid" and sites depend only on the terrain's
validity, which is hand-derivable.
"""

from __future__ import annotations

import csv
import dataclasses
import importlib
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rasterio
import torch
from click.testing import CliRunner
from hdnet_datasets import build_labelled
from rasterio.crs import CRS
from rasterio.transform import from_origin
from scipy import ndimage

from hdcli.cli import main
from hdcore.errors import HdWarning, LockedError, OutputExistsError
from hdcore.storage import PARTIAL_MARK, WriterLock
from hdlabels.grid import cell_centres
from hdlabels.lander import Lander, geometry
from hdlabels.store import find_labeling, iter_labeled_scans
from hdnet.data import HazardDataset, to_dem_grid
from hdnet.detect import (
    MAP_FILES,
    OUTPUT_FILES,
    SAFETY_INVALID,
    SAFETY_SAFE,
    SAFETY_UNCERTAIN,
    SAFETY_UNSAFE,
    SITE_COLUMNS,
    DetectMaps,
    detect,
    detect_dem,
    load_run,
    network_input,
    overlap_px,
    select_sites,
)
from hdnet.detect_settings import DetectSettings
from hdnet.errors import HdNetError
from hdnet.evaluate import EvalConfig, evaluate, validation_threshold
from hdnet.fit import FitConfig, fit
from hdnet.infer import mc_dropout_predict
from hdnet.landing import cell_masses
from hdnet.run_files import LAST_WHY
from hdnet.sites import SITE_RANK_RULES, body_disk
from hdnet.thresholds import parse_threshold_spec
from hdnet.train import save_checkpoint
from hdnet.uncertainty import MUTUAL_INFORMATION
from lidarsim.base_relief import resample_bilinear
from lidarsim.errors import TerrainError
from lidarsim.map_window import MapWindow
from lidarsim.procedural import MarsTerrainParams, generate_mars_terrain, write_geotiff
from lidarsim.shards import sha256_file
from lidarsim.terrain import DTM
from tests.geotiff import write_geotiff as write_test_geotiff

detect_module = importlib.import_module("hdnet.detect")  # the module: hdnet.detect is the function
REAL = Path("/work/shared/data/real-terrain")
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason=f"{REAL} (the shared real terrains) is not present")
CPU = torch.device("cpu")


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("detect")
    dataset = build_labelled(root / "data")
    run = root / "run"
    fit(dataset, run, FitConfig(profile="tiny", epochs=1, progress=False))
    ckpt = torch.load(run / "last.pt", weights_only=True)
    ckpt["model"]["classifier.weight"].zero_()
    ckpt["model"]["classifier.bias"] = torch.tensor([-3.0, 3.0])  # P(safe) = sigmoid(6) everywhere
    constant = root / "constant.pt"
    save_checkpoint(constant, ckpt)
    return dataset, run, constant


def write_dtm(path: Path, z: np.ndarray, spacing: float, origin=(1000.0, 2000.0), crs=None, nodata=None) -> Path:
    return write_test_geotiff(path, z, spacing, origin, crs, nodata)


def tilted_plane(n: int, spacing: float, slope_deg: float, azimuth_deg: float = 30.0) -> np.ndarray:
    x, y = np.meshgrid(np.arange(n) * spacing, -np.arange(n) * spacing)
    g = math.tan(math.radians(slope_deg))
    a = math.radians(azimuth_deg)
    return 50.0 + g * (math.cos(a) * x + math.sin(a) * y)


def read(path: Path) -> tuple[np.ndarray, rasterio.DatasetReader]:
    with rasterio.open(path) as src:
        return src.read(1), src


def profile_of(path: Path) -> dict:
    with rasterio.open(path) as src:
        t, (h, w) = src.transform, src.shape
        return {
            "crs": src.crs,
            "transform": t,
            "shape": (h, w),
            "bounds": (t.c, t.f + t.e * h, t.c + t.a * w, t.f),
            "dtype": src.dtypes[0],
            "nodata": src.nodata,
        }


def check_consistent_maps(out: Path, threshold_nats: float, score_map: str = "entropy.tif") -> dict[str, np.ndarray]:
    """The five maps agree: one invalid set, 0 <= MI <= H, codes from argmax and the score (the map
    ``score_map``) >= H_t; returns them."""
    maps = {name: read(out / name)[0] for name in MAP_FILES}
    p, h, s, b = maps["p_safe.tif"], maps["entropy.tif"], maps["safety.tif"], maps["baseline_p_safe.tif"]
    mi = maps["mutual_information.tif"]
    invalid = s == SAFETY_INVALID
    assert set(np.unique(s)) <= {SAFETY_UNSAFE, SAFETY_SAFE, SAFETY_UNCERTAIN, SAFETY_INVALID}
    for arr in (p, h, mi, b):
        np.testing.assert_array_equal(np.isnan(arr), invalid)
    v = ~invalid
    assert ((p[v] >= 0) & (p[v] <= 1)).all() and ((h[v] >= 0) & (h[v] <= math.log(2) + 1e-6)).all()
    assert ((mi[v] >= 0) & (mi[v] <= h[v] + 1e-6)).all()
    np.testing.assert_array_equal(s[v] == SAFETY_UNCERTAIN, maps[score_map][v] >= threshold_nats)
    certain = v & (s != SAFETY_UNCERTAIN)
    np.testing.assert_array_equal(s[certain] == SAFETY_SAFE, p[certain] > 0.5)
    return maps


def check_sites(out: Path, lander: Lander) -> list[dict]:
    """sites.csv == sites.geojson; every footprint safe and certain; one diameter apart; clearance by brute force."""
    rows = list(csv.DictReader((out / "sites.csv").open()))
    gj = json.loads((out / "sites.geojson").read_text())
    assert gj["type"] == "FeatureCollection" and len(gj["features"]) == len(rows)
    assert (
        list(rows[0].keys()) == list(SITE_COLUMNS)
        if rows
        else (out / "sites.csv").read_text().strip() == ",".join(SITE_COLUMNS)
    )
    safety, src = read(out / "safety.tif")
    transform = src.transform
    dx, dy = transform.a, -transform.e
    disk = body_disk(lander, 1.0)
    r = disk.shape[0] // 2
    bad_r, bad_c = np.nonzero(safety != SAFETY_SAFE)
    pos = []
    for k, (row, feat) in enumerate(zip(rows, gj["features"], strict=True)):
        assert int(row["rank"]) == k + 1 == feat["properties"]["rank"]
        x, y = float(row["x"]), float(row["y"])
        assert feat["geometry"] == {"type": "Point", "coordinates": [pytest.approx(x), pytest.approx(y)]}
        for col in SITE_COLUMNS[3:]:  # the CSV rounds metres to 1 mm, probabilities and nats to 1e-6
            assert feat["properties"][col] == pytest.approx(float(row[col]), abs=5e-4 if col.endswith("_m") else 5e-7)
        c, rr = ~transform @ (x, y)
        ci, ri = int(math.floor(c)), int(math.floor(rr))
        assert abs(c - ci - 0.5) < 1e-6 and abs(rr - ri - 0.5) < 1e-6  # a cell centre
        window = safety[ri - r : ri + r + 1, ci - r : ci + r + 1]
        assert window.shape == disk.shape and (window[disk] == SAFETY_SAFE).all()  # never overlaps a bad cell
        brute = np.sqrt(((bad_r - ri) * dy) ** 2 + ((bad_c - ci) * dx) ** 2).min()
        assert float(row["clearance_m"]) == pytest.approx(brute, abs=1e-3)
        pos.append((x, y))
    for i in range(len(pos)):
        for j in range(i):
            assert math.dist(pos[i], pos[j]) >= lander.diameter_m - 1e-9
    return rows


# --- the contract with training and evaluation ------------------------------------------------------
@pytest.mark.parametrize(
    "change",
    [
        {},  # the tiny profile: the paper's min-max heights, padding to 32
        {"input_size": 64},  # the paper profile's bilinear resize
        {
            "heights": "median",
            "normalisation": None,
            "extra_channels": ("slope", "highpass"),
            "size_multiple": 4,
        },  # cpu
    ],
)
def test_network_input_is_exactly_the_training_input(trained, change):
    dataset, run_dir, _ = trained
    run = load_run(run_dir, CPU)
    spec = dataclasses.replace(run.input_spec, **change)
    run = dataclasses.replace(run, input_spec=spec)
    ds = HazardDataset(dataset, "val", 0.07, input_spec=spec)
    assert network_input(ds.dem_sample(0).dem_noisy_m, run).shape[1] == spec.n_channels
    for i in range(len(ds)):
        sample = ds.dem_sample(i)
        expected = ds.prepare(sample)["image"]
        torch.testing.assert_close(network_input(sample.dem_noisy_m, run)[0], expected, rtol=0, atol=0)


def test_run_records_its_lander_and_old_runs_fall_back_to_their_dataset(trained, tmp_path):
    dataset, run_dir, _ = trained
    run = load_run(run_dir, CPU)
    entry = find_labeling(dataset)
    assert run.lander == entry.lander and run.spacing_m == 1.0 and run.dem_shape == (100, 100)
    ckpt = torch.load(run_dir / "last.pt", weights_only=True)
    del ckpt["extra_config"]["labeling"]  # a run trained before the labelling was recorded
    save_checkpoint(tmp_path / "old.pt", ckpt)
    assert load_run(tmp_path / "old.pt", CPU).labeling == entry.without_shards()
    ckpt["extra_config"]["dataset"] = str(tmp_path / "gone")
    save_checkpoint(tmp_path / "old-gone.pt", ckpt)
    with pytest.raises(HdNetError, match="does not record its lander"):
        load_run(tmp_path / "old-gone.pt", CPU)


def test_scan_mode_is_the_evaluation_path(trained, tmp_path):
    """One scan's maps equal MC dropout on HazardDataset's input; the baseline equals the label shard's."""
    dataset, run_dir, _ = trained
    entry = find_labeling(dataset)
    path = entry.shard_paths(dataset)[0]
    import h5py

    with h5py.File(path) as f:
        scan, k_sigma = int(f["scan_index"][3]), 1
        stored_p = f["p_safe"][3, k_sigma]
    out = tmp_path / "scan"
    result = detect(
        run_dir,
        out,
        DetectSettings(scan=scan, sigma_m=0.07, threshold="nats:0.5", mc_samples=4, seed=3),
        dataset=dataset,
    )
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUT_FILES)
    run = load_run(run_dir, CPU)
    ds = next(
        d
        for d in (HazardDataset(dataset, s, 0.07, input_spec=run.input_spec) for s in ("train", "val", "test"))
        if scan in d.scan_indices
    )
    sample = ds.dem_sample(ds.scan_indices.index(scan))
    torch.manual_seed(3)
    probs = to_dem_grid(
        mc_dropout_predict(run.model, ds.prepare(sample)["image"][None], n_samples=4).mean_probs, (100, 100), None
    )
    maps = check_consistent_maps(out, 0.5)
    valid = maps["safety.tif"] != SAFETY_INVALID
    np.testing.assert_allclose(maps["p_safe.tif"][valid], probs[0, 1].numpy()[valid], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(maps["baseline_p_safe.tif"], stored_p)  # same DEM, sigma, lander: same numbers
    prof = profile_of(out / "p_safe.tif")
    x, y = cell_centres((100, 100), 1.0)  # the scan frame of the label shards
    assert prof["crs"] is None and prof["transform"] @ (0.5, 0.5) == (x[0], y[0]) and prof["shape"] == (100, 100)
    info = json.loads((out / "detect.json").read_text())
    assert info["input"]["kind"] == "scan" and info["input"]["scan_index"] == scan and info["input"]["sigma_m"] == 0.07
    assert len(info["input"]["origin_map"]) == 3 and info["threshold"]["value_nats"] == 0.5
    assert result.threshold_nats == 0.5


def test_mutual_information_map_and_a_threshold_on_it(trained, tmp_path):
    """mutual_information.tif = entropy - expected entropy of the same MC samples; with the mutual
    information as the score, H_t is its mean over the validation split and safety.tif's uncertain
    cells are MI >= H_t."""
    dataset, run_dir, _ = trained
    run = load_run(run_dir, CPU)
    ds = HazardDataset(dataset, "test", 0.07, input_spec=run.input_spec)
    scan = ds.scan_indices[1]
    out = tmp_path / "mi"
    result = detect(
        run_dir,
        out,
        DetectSettings(scan=scan, sigma_m=0.07, mc_samples=4, seed=3, uncertainty="mutual-information"),
        dataset=dataset,
    )
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUT_FILES) and "mutual_information.tif" in OUTPUT_FILES
    mi_profile, h_profile = profile_of(out / "mutual_information.tif"), profile_of(out / "entropy.tif")
    assert math.isnan(mi_profile.pop("nodata")) and math.isnan(h_profile.pop("nodata")) and mi_profile == h_profile
    maps = check_consistent_maps(out, result.threshold_nats, "mutual_information.tif")
    torch.manual_seed(3)  # the maps' MC samples: detect seeds them before the first tile
    sample = ds.dem_sample(1)
    prediction = mc_dropout_predict(run.model, ds.prepare(sample)["image"][None], n_samples=4).on_grid(
        lambda t: to_dem_grid(t, (100, 100), None)
    )
    valid = maps["safety.tif"] != SAFETY_INVALID
    h, mi = maps["entropy.tif"], maps["mutual_information.tif"]
    np.testing.assert_allclose(h[valid], prediction.entropy_nats[0].numpy()[valid], rtol=0, atol=1e-6)
    expected_entropy = prediction.expected_entropy_nats[0].numpy()
    np.testing.assert_allclose(mi[valid], (h - expected_entropy)[valid], rtol=0, atol=1e-6)
    uncertain = maps["safety.tif"] == SAFETY_UNCERTAIN
    assert 0 < uncertain.sum() < valid.sum()  # the mean validation MI splits this scan's cells
    np.testing.assert_array_equal(uncertain[valid], mi[valid] >= result.threshold_nats)
    # H_t: the validation split's mean mutual information, calibrated as hd eval does.
    val = validation_threshold(
        run.model,
        HazardDataset(dataset, "val", 0.0167, input_spec=run.input_spec),
        parse_threshold_spec("mean"),
        mc_samples=4,
        batch_size=8,
        seed=3,
        device=CPU,
        uncertainty=MUTUAL_INFORMATION,
    )
    assert val.inference.mutual_information_nats is not None
    assert result.threshold_nats == val.value_nats
    assert val.value_nats == pytest.approx(val.inference.mutual_information_nats[val.inference.valid].mean(), rel=1e-6)
    info = json.loads((out / "detect.json").read_text())
    assert info["threshold"]["uncertainty"] == "mutual-information" and "mutual_information.tif" in info["files"]
    assert "on the mutual information" in result.summary()


def test_threshold_is_calibrated_as_hd_eval_does(trained, tmp_path):
    dataset, run_dir, _ = trained
    report = evaluate(run_dir, dataset, EvalConfig(mc_samples=3, threshold="quantile:0.3", seed=5, batch_size=8))
    dtm = write_dtm(tmp_path / "hill.tif", tilted_plane(40, 1.0, 3.0), 1.0)
    result = detect(run_dir, tmp_path / "out", DetectSettings(mc_samples=3, threshold="quantile:0.3", seed=5), dtm=dtm)
    info = json.loads((tmp_path / "out" / "detect.json").read_text())["threshold"]
    assert result.threshold_nats == pytest.approx(report.threshold["value_nats"], rel=0, abs=0)
    for key in (
        "spec",
        "mean_nats",
        "calibration_split",
        "calibration_sigma_m",
        "calibration_images",
        "calibration_pixels",
    ):
        assert info[key] == report.threshold[key]
    check_consistent_maps(tmp_path / "out", result.threshold_nats)


# --- DTMs ---------------------------------------------------------------------------------------------
@needs_real
@pytest.mark.parametrize(("name", "crs"), [("autzen-ground-1m.tif", None), ("ames-0.5m.tif", CRS.from_epsg(32610))])
def test_real_terrain_maps_cover_the_input_with_its_crs(trained, tmp_path, name, crs):
    _, run_dir, _ = trained
    out = tmp_path / "out"
    calls = []
    result = detect(
        run_dir, out, DetectSettings(mc_samples=2), dtm=REAL / name, progress=lambda d, t: calls.append((d, t))
    )
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUT_FILES)
    src = profile_of(REAL / name)
    with rasterio.open(REAL / name) as s:
        z = s.read(1, masked=True)
        nodata = np.ma.getmaskarray(z) | ~np.isfinite(z.filled(0))
    for f in MAP_FILES:
        prof = profile_of(out / f)
        assert prof["crs"] == crs and prof["dtype"] == ("uint8" if f == "safety.tif" else "float32")
        for a, b in zip(prof["bounds"], src["bounds"], strict=True):
            assert a == pytest.approx(b, abs=1e-6)  # the input's extent, exactly
        assert abs(prof["transform"].a - 1.0) <= 0.02 and abs(-prof["transform"].e - 1.0) <= 0.02  # run spacing
    maps = check_consistent_maps(out, result.threshold_nats)
    safety = maps["safety.tif"]
    assert (safety != SAFETY_INVALID).sum() > 1000  # plenty of valid cells
    geo = geometry(Lander(), 1.0)
    edge = geo.band_px  # the border band is invalid
    assert (safety[:edge] == SAFETY_INVALID).all() and (safety[:, -edge:] == SAFETY_INVALID).all()
    if name.startswith("autzen"):  # same 1 m grid: invalid = the band and every footprint touching nodata
        expected = ndimage.binary_dilation(nodata, structure=geo.footprint)
        expected[:edge], expected[-edge:], expected[:, :edge], expected[:, -edge:] = True, True, True, True
        np.testing.assert_array_equal(safety == SAFETY_INVALID, expected)
    info = json.loads((out / "detect.json").read_text())
    assert calls[-1][0] == calls[-1][1] == info["tiling"]["n_tiles"]
    assert info["counts"] == {
        "safe": int((safety == SAFETY_SAFE).sum()),
        "unsafe": int((safety == SAFETY_UNSAFE).sum()),
        "uncertain": int((safety == SAFETY_UNCERTAIN).sum()),
        "invalid": int((safety == SAFETY_INVALID).sum()),
        "baseline_safe": int((np.nan_to_num(maps["baseline_p_safe.tif"]) >= 0.5).sum()),
    }
    assert info["input"]["sha256"] == sha256_file(REAL / name)
    assert info["input"]["scale"] == (1.0 if name.startswith("autzen") else 0.5)
    assert set(info["timings_s"]) >= {"calibration", "network", "baseline", "sites", "total"}
    check_sites(out, Lander())


def test_procedural_terrain_constant_run_sites_by_hand(trained, tmp_path):
    """Procedural Mars terrain (0.5 m, resampled to 1 m); with a run that says 'safe' everywhere, the
    safety map is the validity map and sites are the valid cells farthest from anything invalid."""
    _, _, constant = trained
    params = MarsTerrainParams(size_m=160.0, crater_n_gt_10m_per_km2=0.0, rock_k=0.0)
    heights = generate_mars_terrain(params, seed=4)
    heights[150:170, 60:200] = np.nan  # a nodata band across the middle (0.5 m cells)
    dtm = tmp_path / "mars.tif"
    write_geotiff(dtm, heights, 0.5, origin_xy=(0.0, 160.0))
    out = tmp_path / "out"
    result = detect(constant, out, DetectSettings(threshold="nats:0.5", mc_samples=2, n_sites=6), dtm=dtm)
    maps = check_consistent_maps(out, 0.5)
    safety = maps["safety.tif"]
    assert set(np.unique(safety)) == {SAFETY_SAFE, SAFETY_INVALID} and safety.shape == (160, 160)
    np.testing.assert_allclose(maps["p_safe.tif"][safety == SAFETY_SAFE], 1 / (1 + math.exp(-6)), rtol=1e-6)
    rows = check_sites(out, Lander())
    assert len(rows) == 6 == len(result.sites)
    clearances = [float(r["clearance_m"]) for r in rows]
    assert clearances == sorted(clearances, reverse=True)  # equal P(safe): ranked by clearance
    edt = ndimage.distance_transform_edt(np.pad(safety == SAFETY_SAFE, 1))[1:-1, 1:-1]
    assert clearances[0] == pytest.approx(edt.max(), abs=5e-4)  # site 1 is the clearest cell (CSV: 1 mm)
    assert profile_of(out / "safety.tif")["crs"] is None


def test_nav_sigma_ranks_sites_by_the_touchdown_and_records_the_rule(trained, tmp_path):
    """The same terrain with --nav-sigma 3: each site's touchdown_p_safe is the map's P(safe) on safe and
    certain cells weighted by the dispersion (by brute force from the written maps), the ranking follows
    it, and sites.csv and detect.json say so; without it the record names the aim-point rule."""
    _, _, constant = trained
    params = MarsTerrainParams(size_m=160.0, crater_n_gt_10m_per_km2=0.0, rock_k=0.0)
    heights = generate_mars_terrain(params, seed=4)
    heights[150:170, 60:200] = np.nan
    dtm = tmp_path / "mars.tif"
    write_geotiff(dtm, heights, 0.5, origin_xy=(0.0, 160.0))
    out = tmp_path / "nav"
    result = detect(
        constant, out, DetectSettings(threshold="nats:0.5", mc_samples=2, n_sites=4, nav_sigma_m=3.0), dtm=dtm
    )
    rows = check_sites(out, Lander())
    maps = check_consistent_maps(out, 0.5)
    ok = np.where(maps["safety.tif"] == SAFETY_SAFE, maps["p_safe.tif"], 0.0)
    weights = cell_masses(3.0, 1.0)
    k = len(weights) // 2
    padded = np.pad(ok, k)
    values = []
    for site in result.sites:
        brute = float(weights @ padded[site.row : site.row + 2 * k + 1, site.col : site.col + 2 * k + 1] @ weights)
        assert site.touchdown_p_safe == pytest.approx(brute, abs=1e-9)
        values.append(round(site.touchdown_p_safe, 3))
    assert values == sorted(values, reverse=True)
    assert [float(r["touchdown_p_safe"]) for r in rows] == pytest.approx(
        [s.touchdown_p_safe for s in result.sites], abs=1e-6
    )
    rule = json.loads((out / "detect.json").read_text())["site_rule"]
    assert rule["nav_sigma_m"] == 3.0 and rule["rank_by"] == SITE_RANK_RULES["touchdown"]
    summary = result.summary()
    assert f"expected touchdown P(safe) {result.sites[0].touchdown_p_safe:.3f} under navigation 1σ 3 m" in summary
    assert f"aim-point P(safe) {result.sites[0].p_safe:.3f}," in summary and "P(safe) at the touchdown" not in summary
    plain = detect(constant, tmp_path / "aim", DetectSettings(threshold="nats:0.5", mc_samples=2, n_sites=4), dtm=dtm)
    rule = json.loads((tmp_path / "aim" / "detect.json").read_text())["site_rule"]
    assert rule["nav_sigma_m"] == 0.0 and rule["rank_by"] == SITE_RANK_RULES["aim"]
    assert all(s.touchdown_p_safe == pytest.approx(1 / (1 + math.exp(-6)), rel=1e-6) for s in plain.sites)


@pytest.mark.parametrize(("slope_deg", "safe"), [(0.0, True), (5.0, True), (9.0, True), (11.0, False), (15.0, False)])
def test_tilted_plane_baseline_is_all_safe_below_10_degrees_and_all_unsafe_above(trained, tmp_path, slope_deg, safe):
    _, _, constant = trained
    n = 150  # two tiles per axis
    dtm = write_dtm(tmp_path / "plane.tif", tilted_plane(n, 1.0, slope_deg), 1.0)
    out = tmp_path / "out"
    detect(constant, out, DetectSettings(threshold="nats:0.5", mc_samples=1, sigma_m=0.03), dtm=dtm)
    base = read(out / "baseline_p_safe.tif")[0]
    b = geometry(Lander(), 1.0).band_px
    inner = base[b : n - b, b : n - b]
    assert np.isfinite(inner).all()  # valid away from the border band ...
    assert np.isnan(base[:b]).all() and np.isnan(base[:, -b:]).all()  # ... and invalid inside it
    if safe:
        assert (inner >= 0.5).all() and inner.min() == pytest.approx(1.0, abs=1e-6)
    else:
        assert (inner < 0.5).all() and inner.max() == 0.0


def test_a_run_at_another_spacing_resamples_to_its_own_and_refuses_coarser_dtms(trained, tmp_path):
    """A run trained on 0.5 m DEMs: a 0.25 m DTM is read at scale 0.5, a 1 m DTM is refused."""
    _, _, constant = trained
    ckpt = torch.load(constant, weights_only=True)
    ckpt["extra_config"]["labeling"]["dem"]["spacing_m"] = 0.5
    save_checkpoint(tmp_path / "half.pt", ckpt)
    fine = write_dtm(tmp_path / "fine.tif", tilted_plane(240, 0.25, 3.0), 0.25)
    detect(tmp_path / "half.pt", tmp_path / "out", DetectSettings(threshold="nats:0.5", mc_samples=1), dtm=fine)
    prof = profile_of(tmp_path / "out" / "safety.tif")
    assert prof["shape"] == (120, 120) and prof["transform"].a == 0.5
    safety = read(tmp_path / "out" / "safety.tif")[0]
    b = geometry(Lander(), 0.5).band_px  # the lander footprint in 0.5 m cells
    assert b == 10 and (safety[:b] == SAFETY_INVALID).all() and (safety[b:-b, b:-b] == SAFETY_SAFE).all()
    # a window of the 0.25 m DTM: cells of the run's 0.5 m grid (edges inside a 0.5 m cell snapped outwards)
    detect(
        tmp_path / "half.pt",
        tmp_path / "win",
        DetectSettings(window=MapWindow(1010.2, 1961.0, 1040.0, 1990.1), threshold="nats:0.5"),
        dtm=fine,
    )
    prof = profile_of(tmp_path / "win" / "safety.tif")
    assert prof["shape"] == (59, 60) and prof["transform"] == from_origin(1010.0, 1990.5, 0.5, 0.5)  # rows 19..77
    window = read(tmp_path / "win" / "safety.tif")[0]
    assert (window[:b] == SAFETY_INVALID).all() and (window[b:-b, b:-b] == SAFETY_SAFE).all()
    coarse = write_dtm(tmp_path / "coarse.tif", tilted_plane(60, 1.0, 3.0), 1.0)
    with pytest.raises(TerrainError, match=r"coarser than the run's DEM spacing \(0.5 m/px\)"):
        detect(tmp_path / "half.pt", tmp_path / "out2", DetectSettings(threshold="nats:0.5"), dtm=coarse)
    assert not (tmp_path / "out2").exists()
    # --upsample: the coarse plane interpolated to 0.5 m is the same plane (a plane is exact under
    # bilinear interpolation inside the outer cell centres), the source named in detect.json.
    detect(
        tmp_path / "half.pt",
        tmp_path / "out3",
        DetectSettings(threshold="nats:0.5", mc_samples=1, upsample=True),
        dtm=coarse,
    )
    prof = profile_of(tmp_path / "out3" / "safety.tif")
    assert prof["shape"] == (120, 120) and prof["transform"].a == 0.5 and prof["transform"].c == 1000.0
    info = json.loads((tmp_path / "out3" / "detect.json").read_text())
    up = info["input"]["upsampled"]
    assert up["source_spacing_m"] == [1.0, 1.0] and up["spacing_m"] == 0.5 and "bilinear" in up["method"]
    assert info["input"]["sha256"] == up["source_sha256"] == sha256_file(coarse)
    safety = read(tmp_path / "out3" / "safety.tif")[0]
    assert (safety[b:-b, b:-b] == SAFETY_SAFE).all()  # a 3 % tilt: safe wherever the lander fits


def test_hirise_pds3_at_1_01_m_keeps_its_mars_crs(trained, tmp_path):
    """A HiRISE-like PDS3 DTM (1.01 m, equirectangular Mars, NULL cells) is read as is, within the 2 % tolerance."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "terrain_files", Path(__file__).parents[1] / "lidarsim" / "terrain_files.py"
    )
    assert spec is not None and spec.loader is not None
    terrain_files = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(terrain_files)
    z = tilted_plane(60, 1.01, 2.0).astype(np.float32) - 2000.0
    z[20:24, 30:33] = np.float32(terrain_files.HIRISE_NULL)
    dtm = terrain_files.write_pds3(tmp_path / "DTEEC_TEST.IMG", z)
    detect(trained[2], tmp_path / "out", DetectSettings(threshold="nats:0.5", mc_samples=1, n_sites=4), dtm=dtm)
    with rasterio.open(dtm) as src:
        crs, transform = src.crs, src.transform
    prof = profile_of(tmp_path / "out" / "safety.tif")
    assert prof["crs"] == crs and prof["transform"] == transform and prof["shape"] == (60, 60)
    safety = read(tmp_path / "out" / "safety.tif")[0]
    assert (safety[20:24, 30:33] == SAFETY_INVALID).all() and (safety == SAFETY_SAFE).any()
    gj = json.loads((tmp_path / "out" / "sites.geojson").read_text())
    assert "crs" not in gj  # no EPSG code for Mars: the CRS is in detect.json
    assert json.loads((tmp_path / "out" / "detect.json").read_text())["grid"]["crs_wkt"] == crs.to_wkt()
    check_sites(tmp_path / "out", Lander())


def test_windowed_reads_only(trained, tmp_path, monkeypatch):
    _, _, constant = trained
    dtm = write_dtm(tmp_path / "big.tif", tilted_plane(230, 1.0, 2.0), 1.0)
    shapes = []
    original = detect_module.DTM.read

    def spy(self, row0, col0, rows, cols):
        shapes.append((rows, cols))
        return original(self, row0, col0, rows, cols)

    monkeypatch.setattr(detect_module.DTM, "read", spy)
    detect(constant, tmp_path / "out", DetectSettings(threshold="nats:0.5", mc_samples=1, n_sites=3), dtm=dtm)
    tiles = json.loads((tmp_path / "out" / "detect.json").read_text())["tiling"]
    assert tiles["tiles"] == [3, 3] and tiles["min_overlap_px"] == overlap_px(Lander(), 1.0) == 20
    assert shapes.count((100, 100)) == 9  # every network input is one window of the training size
    assert all(s == (100, 100) for s in shapes[:9])


# --- --window: a part of a large DTM ------------------------------------------------------------------
def rough_hills(rows: int, cols: int, seed: int = 5) -> np.ndarray:
    """Seeded hills with rocks and a tilt (metres): safe, unsafe and uncertain cells all occur."""
    rng = np.random.default_rng(seed)
    z = ndimage.gaussian_filter(rng.normal(0.0, 1.0, (rows, cols)), 6) * 25.0
    rocks = np.zeros((rows, cols))
    idx = rng.integers(0, min(rows, cols), (40, 2))
    rocks[idx[:, 0], idx[:, 1]] = 1.0
    return 40.0 + z + ndimage.gaussian_filter(rocks, 1.2) * 6.0 + 0.02 * np.arange(cols)[None, :]


def maps_of(out: Path) -> dict[str, np.ndarray]:
    return {name: read(out / name)[0] for name in MAP_FILES}


@pytest.mark.parametrize(
    ("window", "rows", "cols"),
    [
        ((1045.4, 1820.2, 1204.6, 1969.7), (30, 180), (45, 205)),  # 2 x 2 tiles
        ((1045.0, 1890.0, 1125.0, 1954.0), (46, 110), (45, 125)),  # smaller than one tile: its reads reach past
    ],
)
def test_a_window_maps_as_the_dtm_cut_to_it(trained, tmp_path, monkeypatch, window, rows, cols):
    """The window's cells (edges inside cells snapped outwards) are mapped exactly as a GeoTIFF of
    those cells alone: the tiles are laid on the window, and a window's reads stop at its edge (a
    tile reaching past it gets NaN there, as past a DTM's edge), so every tile holds the same
    heights, in the same order, under the same seed. The baseline, a local rule, also equals the
    full map's away from the window's edge."""
    _, run_dir, _ = trained
    z = rough_hills(200, 240)
    full = write_dtm(tmp_path / "full.tif", z, 1.0)  # top-left (1000, 2000): x 1000..1240, y 1800..2000
    (r0, r1), (c0, c1) = rows, cols
    corner = (1000.0 + c0, 2000.0 - r0)
    crop = write_dtm(tmp_path / "crop.tif", z[r0:r1, c0:c1], 1.0, origin=corner)
    kw: dict[str, Any] = {"threshold": "nats:inf", "mc_samples": 2, "n_sites": 5}  # all certain: sites by P(safe)
    reads = []
    original = detect_module.DTM.read

    def spy(self, row0, col0, rows, cols):
        reads.append((self.info.name, row0, col0, rows, cols))
        return original(self, row0, col0, rows, cols)

    monkeypatch.setattr(detect_module.DTM, "read", spy)
    detect(run_dir, tmp_path / "win", DetectSettings(window=window, **kw), dtm=full)
    assert reads and all(r0 <= r and r + n <= r1 and c0 <= c and c + m <= c1 for _, r, c, n, m in reads)
    monkeypatch.undo()
    detect(run_dir, tmp_path / "crop", DetectSettings(**kw), dtm=crop)
    win, cut = maps_of(tmp_path / "win"), maps_of(tmp_path / "crop")
    for name in MAP_FILES:
        np.testing.assert_array_equal(win[name], cut[name], err_msg=name)
        prof = profile_of(tmp_path / "win" / name)
        assert prof["transform"] == from_origin(*corner, 1.0, 1.0) and prof["shape"] == (r1 - r0, c1 - c0)
        assert prof["transform"] == profile_of(tmp_path / "crop" / name)["transform"]
    # not trivial maps: P(safe) varies, the baseline calls both, and there are sites
    assert np.nanstd(win["p_safe.tif"]) > 1e-3 and {0.0, 1.0} <= set(np.unique(win["baseline_p_safe.tif"]).tolist())
    assert (tmp_path / "win" / "sites.csv").read_text() == (tmp_path / "crop" / "sites.csv").read_text()
    info, other = (json.loads((tmp_path / d / "detect.json").read_text()) for d in ("win", "crop"))
    assert info["input"]["window"] == {
        "requested": list(window),
        "mapped": [1000.0 + c0, 2000.0 - r1, 1000.0 + c1, 2000.0 - r0],
        "clipped": False,
        "dtm_bounds": [1000.0, 1800.0, 1240.0, 2000.0],
    }
    assert info["grid"] == other["grid"] and info["tiling"] == other["tiling"] and info["counts"] == other["counts"]
    assert info["input"]["sha256"] == sha256_file(full) and "window" not in other["input"]
    assert info["sites"]
    for site in info["sites"]:
        assert 1000.0 + c0 < site["x"] < 1000.0 + c1 and 2000.0 - r1 < site["y"] < 2000.0 - r0
    # The baseline of the whole DTM, cut to the window, away from the window's edge (the border band):
    # equal to float32 rounding (its arithmetic runs on each tile's own cells, placed elsewhere).
    detect(run_dir, tmp_path / "all", DetectSettings(**kw), dtm=full)
    whole = read(tmp_path / "all" / "baseline_p_safe.tif")[0][r0:r1, c0:c1]
    band = geometry(Lander(), 1.0).band_px
    inner = (slice(band, -band), slice(band, -band))
    np.testing.assert_allclose(win["baseline_p_safe.tif"][inner], whole[inner], rtol=0, atol=1e-5)


def test_the_overview_of_a_large_window_is_decimated_from_the_window_alone(trained, tmp_path, monkeypatch):
    """A window wider than the overview's pixels: its heights decimated in one read, none from outside it."""
    import hdnet.figures

    _, _, constant = trained
    z = rough_hills(120, 140, seed=11)
    dtm = write_dtm(tmp_path / "dtm.tif", z, 1.0)
    drawn: dict[str, Any] = {}

    def capture(heights, cell_m, safety, extent, *args):
        drawn.update(heights=heights, cell_m=cell_m, safety=safety, extent=extent)

    monkeypatch.setattr(detect_module, "OVERVIEW_MAX_PX", 20)
    monkeypatch.setattr(hdnet.figures, "detect_overview", capture)
    detect(
        constant,
        tmp_path / "out",
        DetectSettings(window=MapWindow(1030.0, 1900.0, 1110.0, 1960.0), threshold="nats:0.5"),
        dtm=dtm,
    )
    assert drawn["heights"].shape == drawn["safety"].shape == (15, 20) and drawn["cell_m"] == 4.0
    assert drawn["extent"] == (1030.0, 1110.0, 1900.0, 1960.0)  # left, right, bottom, top
    inside = z[40:100, 30:110].astype(np.float32)  # rows 40..99, columns 30..109
    assert np.isin(drawn["heights"].astype(np.float32), inside).all()


def test_a_window_of_a_coarse_dtm_is_upsampled_alone_and_one_reaching_past_the_dtm_is_clipped(trained, tmp_path):
    """--upsample --window interpolates the window's cells of the coarse DTM alone (as a GeoTIFF of
    them would be); a window reaching past the DTM is mapped where they overlap, with a warning."""
    _, _, constant = trained
    z = rough_hills(60, 70, seed=9)
    coarse = write_dtm(tmp_path / "coarse.tif", z, 2.0)  # 2 m cells: x 1000..1140, y 1880..2000
    crop = write_dtm(tmp_path / "crop.tif", z[5:45, 10:60], 2.0, origin=(1020.0, 1990.0))
    kw: dict[str, Any] = {"threshold": "nats:0.5", "mc_samples": 1, "upsample": True}
    detect(constant, tmp_path / "win", DetectSettings(window=MapWindow.of("1021,1910.5,1119,1990"), **kw), dtm=coarse)
    detect(constant, tmp_path / "crop", DetectSettings(**kw), dtm=crop)
    win, cut = maps_of(tmp_path / "win"), maps_of(tmp_path / "crop")
    for name in MAP_FILES:
        np.testing.assert_array_equal(win[name], cut[name], err_msg=name)
    assert profile_of(tmp_path / "win" / "safety.tif")["transform"] == from_origin(1020.0, 1990.0, 1.0, 1.0)
    assert win["safety.tif"].shape == (80, 100)
    with pytest.warns(HdWarning, match=r"reaches past coarse.tif .*only the part inside it is mapped, x 1100 to 1140"):
        detect(
            constant,
            tmp_path / "past",
            DetectSettings(window=MapWindow(1100.0, 1950.0, 1500.0, 2500.0), **kw),
            dtm=coarse,
        )
    info = json.loads((tmp_path / "past" / "detect.json").read_text())
    assert info["input"]["window"]["clipped"] is True
    assert info["input"]["window"]["mapped"] == [1100.0, 1950.0, 1140.0, 2000.0]
    assert info["grid"]["rows"] == 50 and info["grid"]["cols"] == 40


def test_upsampling_window_by_window_maps_as_the_whole_interpolated_grid(trained, tmp_path):
    """--upsample computes the interpolated heights tile by tile (lidarsim.upsampled); the maps equal,
    bit for bit, those of the whole grid interpolated at once and stored as a float32 GeoTIFF (what
    hd detect held in memory before): the same heights, so the same network inputs and draws."""
    _, run, _ = trained  # a trained network: its maps follow the heights
    z = rough_hills(40, 45, seed=3)
    z[12, 20] = np.nan  # a nodata cell spreads to the cells interpolating from it, in both
    coarse = write_dtm(tmp_path / "coarse.tif", z, 2.0)
    with DTM.open(coarse) as src:
        source = src.read(0, 0, 40, 45)
    fine = write_dtm(tmp_path / "fine.tif", resample_bilinear(source, (2.0, 2.0), 1.0, (80, 90)), 1.0)
    kw: dict[str, Any] = {"threshold": "nats:0.5", "mc_samples": 2}
    detect(run, tmp_path / "up", DetectSettings(upsample=True, **kw), dtm=coarse)
    detect(run, tmp_path / "fine", DetectSettings(**kw), dtm=fine)
    up, whole = maps_of(tmp_path / "up"), maps_of(tmp_path / "fine")
    for name in MAP_FILES:
        np.testing.assert_array_equal(up[name], whole[name], err_msg=name)
    assert (up["safety.tif"] == SAFETY_INVALID).any() and (up["safety.tif"] != SAFETY_INVALID).any()
    p = up["p_safe.tif"][np.isfinite(up["p_safe.tif"])]
    assert p.std() > 1e-3  # maps that vary with the terrain


# --- sites by hand -------------------------------------------------------------------------------------
def test_select_sites_ranks_by_p_safe_then_clearance_and_keeps_a_diameter_apart():
    lander = Lander()
    safety = np.full((60, 120), SAFETY_INVALID, np.uint8)
    safety[5:55, 5:55] = SAFETY_SAFE  # west block: 50 x 50 cells, P(safe) 0.8
    safety[5:55, 65:115] = SAFETY_SAFE  # east block: same size, P(safe) 0.9
    p = np.where(safety == SAFETY_SAFE, 0.8, np.nan).astype(np.float32)
    p[:, 60:] = np.where(safety[:, 60:] == SAFETY_SAFE, 0.9, np.nan)
    h = np.where(safety == SAFETY_SAFE, 0.1, np.nan).astype(np.float32)
    base = np.full(safety.shape, 0.7, np.float32)
    transform = from_origin(0.0, 60.0, 1.0, 1.0)
    sites = select_sites(safety, p, h, base, transform, (1.0, 1.0), lander, 50)
    # The east block ranks first: its centre cells (29/30, 89/90) are 25 m from the nearest invalid cell
    # (row 4 or column 64); the north-west one wins the tie: cell (29, 89) at x 89.5, y 30.5.
    first = sites[0]
    assert (first.row, first.col, first.x, first.y) == (29, 89, 89.5, 30.5)
    assert first.p_safe == pytest.approx(0.9) and first.clearance_m == 25.0 and first.entropy_max == pytest.approx(0.1)
    assert first.baseline_p_safe == pytest.approx(0.7)
    east = [s for s in sites if s.col >= 60]
    assert sites[: len(east)] == east  # every east site before any west site
    for s in sites:
        assert (safety[s.row - 5 : s.row + 6, s.col - 5 : s.col + 6][body_disk(lander, 1.0)] == SAFETY_SAFE).all()
    for i, a in enumerate(sites):
        for b in sites[:i]:
            assert math.dist((a.x, a.y), (b.x, b.y)) >= 10.0
    # Candidates (whole body disk of radius 5 safe): rows 10..49 of both blocks. With room for 50 sites
    # the greedy choice is maximal: every candidate is closer than one diameter to some site.
    cand_r, cand_c = np.mgrid[10:50, 10:110]
    cand = (cand_c < 50) | (cand_c >= 70)
    chosen = np.array([(s.row, s.col) for s in sites])
    d = np.hypot(cand_r[cand][:, None] - chosen[:, 0], cand_c[cand][:, None] - chosen[:, 1]).min(axis=1)
    assert (d < 10.0).all() and len(sites) < 50
    assert [s.rank for s in sites] == list(range(1, len(sites) + 1))
    assert select_sites(safety, p, h, base, transform, (1.0, 1.0), lander, 3) == sites[:3]


def reference_sites(safety, p, lander, n):
    """Plain reference of the site rule: every candidate scored, sorted, picked one by one (cells of 1 m)."""
    disk = body_disk(lander, 1.0)
    r = disk.shape[0] // 2
    h, w = safety.shape
    bad = np.argwhere(safety != SAFETY_SAFE)
    scored = []
    for i in range(r, h - r):
        for j in range(r, w - r):
            win = safety[i - r : i + r + 1, j - r : j + r + 1]
            if (win[disk] == SAFETY_SAFE).all():
                mean = float(np.mean(p[i - r : i + r + 1, j - r : j + r + 1].astype(np.float64)[disk]))
                clearance = float(np.sqrt(((bad - (i, j)) ** 2).sum(axis=1)).min())
                scored.append((-round(mean, 3), -clearance, i, j, mean, clearance))
    chosen: list[tuple[float, float, int, int, float, float]] = []
    for item in sorted(scored):
        if all(math.dist(item[2:4], c[2:4]) >= lander.diameter_m for c in chosen):
            chosen.append(item)
        if len(chosen) == n:
            break
    return [(c[2], c[3], c[4], c[5]) for c in chosen]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_select_sites_equals_the_plain_reference_on_random_maps(seed):
    rng = np.random.default_rng(seed)
    shape = (70, 90)
    smooth = ndimage.gaussian_filter(rng.normal(size=shape), 6)
    safety = np.where(smooth > np.quantile(smooth, 0.3), SAFETY_SAFE, SAFETY_UNSAFE).astype(np.uint8)
    safety[rng.random(shape) < 0.002] = SAFETY_UNCERTAIN
    safety[:5], safety[-5:], safety[:, :5], safety[:, -5:] = (
        SAFETY_INVALID,
        SAFETY_INVALID,
        SAFETY_INVALID,
        SAFETY_INVALID,
    )
    p = (0.5 + 0.5 * ndimage.gaussian_filter(rng.random(shape), 3)).astype(np.float32)
    p[:, 45:] = np.round(p[:, 45:], 2)  # plateaus of equal P(safe): clearance decides there
    h = rng.random(shape).astype(np.float32)
    sites = select_sites(safety, p, h, p, from_origin(0, 70, 1, 1), (1.0, 1.0), Lander(), 12)
    expected = reference_sites(safety, p, Lander(), 12)
    assert len(sites) == len(expected) > 3
    for s, (i, j, mean, clearance) in zip(sites, expected, strict=True):
        assert (s.row, s.col) == (i, j)
        assert s.p_safe == pytest.approx(mean, abs=1e-9) and s.clearance_m == pytest.approx(clearance, abs=1e-5)
        assert s.entropy_max == h[i - 5 : i + 6, j - 5 : j + 6][body_disk(Lander(), 1.0)].max()


def test_body_disk_by_hand():
    assert body_disk(Lander(), 1.0).shape == (11, 11) and body_disk(Lander(), 1.0).sum() == 81  # i^2 + j^2 <= 25
    assert body_disk(Lander(), 0.5).sum() == 317  # Gauss circle count for radius 10 cells
    assert body_disk(Lander(), 2.0).sum() == 21  # radius 2.5 cells


def test_no_site_when_no_footprint_is_wholly_safe():
    lander = Lander()
    safety = np.full((40, 40), SAFETY_SAFE, np.uint8)
    safety[::8, :] = SAFETY_UNCERTAIN  # uncertain rows every 8 m: no 11-cell disk fits
    z = np.zeros(safety.shape, np.float32)
    assert select_sites(safety, z + 0.9, z, z, from_origin(0, 40, 1, 1), (1.0, 1.0), lander, 10) == []


# --- bad input, atomic output ----------------------------------------------------------------------------
@pytest.fixture
def terrains(tmp_path):
    d = tmp_path / "terrains"
    d.mkdir()
    stripes = tilted_plane(40, 1.0, 1.0)
    stripes[::8] = np.nan
    return {
        "ok": write_dtm(d / "ok.tif", tilted_plane(40, 1.0, 2.0), 1.0),
        "small": write_dtm(d / "small.tif", np.zeros((8, 30)), 1.0),
        "striped": write_dtm(d / "striped.tif", stripes, 1.0),
        "empty": write_dtm(d / "empty.tif", np.full((30, 30), np.nan), 1.0),
        "geographic": write_dtm(d / "wgs84.tif", np.zeros((40, 40)), 0.001, (-122.0, 37.0), crs=CRS.from_epsg(4326)),
        "coarse": write_dtm(d / "coarse.tif", np.zeros((40, 40)), 2.0),
        "feet": write_dtm(d / "feet.tif", np.zeros((40, 40)), 1.0, crs=CRS.from_epsg(2227)),
    }


BAD = [
    (["--dtm", "{missing}"], "no such file"),
    (["--dtm", "{small}"], "too small for the lander footprint"),
    (["--dtm", "{striped}"], "no such valid square"),
    (["--dtm", "{empty}"], "every cell is nodata"),
    (["--dtm", "{geographic}"], "geographic CRS"),
    (["--dtm", "{coarse}"], "coarser than the run's DEM spacing"),
    (["--dtm", "{feet}"], "not metres"),
    (["--dtm", "{ok}", "--threshold", "median"], "threshold spec"),
    (["--dtm", "{ok}", "--threshold", "risk:1.5"], "alpha"),
    (["--dtm", "{ok}", "--threshold", "nats:-1"], ">= 0 nats"),
    (["--dtm", "{ok}", "--mc-samples", "0"], "--mc-samples"),
    (["--dtm", "{ok}", "--mc-samples", "100000"], "1<=x<=1024"),  # was unbounded: 104 GB asked for
    (["--dtm", "{ok}", "--batch-size", "100000"], "1<=x<=1024"),
    (["--dtm", "{ok}", "--sites", "0"], "--sites"),
    (["--dtm", "{ok}", "--sigma", "-0.1"], "sigma"),
    (["--dtm", "{ok}", "--scan", "1"], "--scan goes with --data"),
    (["--dtm", "{ok}", "--data", "{dataset}", "--scan", "1"], "either"),
    ([], "either"),
    (["--data", "{dataset}"], "needs --scan"),
    (["--data", "{dataset}", "--scan", "999"], "scan 999 is not in"),
    (["--data", "{dataset}", "--scan", "0", "--sigma", "0.05"], "not in the dataset"),
    (["--dtm", "{ok}", "--window", "1030,1970,1010,1990"], "XMIN 1030 must be less than XMAX 1010"),
    (["--dtm", "{ok}", "--window", "1000,1990,1030,1970"], "YMIN 1990 must be less than YMAX 1970"),
    (["--dtm", "{ok}", "--window", "1000,1960,1040"], "give four numbers separated by commas"),
    (["--dtm", "{ok}", "--window", "1000,1960,1040,2000m"], "'2000m' is not a number"),
    (["--dtm", "{ok}", "--window", "1000,1960,inf,2000"], "'inf' is not a finite number"),
    (["--dtm", "{ok}", "--window", "0,0,100,100"], "lies outside ok.tif, whose bounds are x 1000 to 1040, y 1960"),
    (["--dtm", "{ok}", "--window", "1000,1990,1006,2000"], "widen the window (the DTM's bounds: x 1000 to 1040"),
    (["--dtm", "{striped}", "--window", "1000,1961,1040,1999"], "the window has no such valid square"),
    (["--data", "{dataset}", "--scan", "0", "--window", "0,0,10,10"], "--window goes with --dtm"),
]


def test_the_summary_says_which_checkpoint_it_read_and_why(trained, terrains, tmp_path):
    _, run_dir, _ = trained
    args = ["--dtm", str(terrains["ok"]), "--threshold", "nats:0.3", "--mc-samples", "1"]
    result = CliRunner().invoke(main, ["detect", str(run_dir), *args, "--out", str(tmp_path / "a")])
    assert result.exit_code == 0, result.output
    assert f"checkpoint: last.pt ({LAST_WHY})" in result.output.splitlines()
    assert "best.pt is not scored because it is the epoch chosen on the validation split" in LAST_WHY
    given = tmp_path / "chosen.pt"
    given.write_bytes((run_dir / "last.pt").read_bytes())
    result = CliRunner().invoke(main, ["detect", str(given), *args, "--out", str(tmp_path / "b")])
    assert result.exit_code == 0, result.output
    assert "checkpoint: chosen.pt (the file given)" in result.output.splitlines()


@pytest.mark.parametrize(("args", "needle"), BAD)
def test_bad_input_is_one_line_and_writes_nothing(trained, terrains, tmp_path, args, needle):
    dataset, run_dir, _ = trained
    names = {**{k: str(v) for k, v in terrains.items()}, "dataset": str(dataset), "missing": str(tmp_path / "nope.tif")}
    out = tmp_path / "new" / "out"
    result = CliRunner().invoke(main, ["detect", str(run_dir), "--out", str(out), *[a.format(**names) for a in args]])
    assert result.exit_code in (1, 2) and "Traceback" not in result.output, result.output  # 2: out of range
    lines = result.output.strip().splitlines()
    assert lines[-1].startswith("Error: ") and needle.lower() in lines[-1].lower(), result.output
    assert not (tmp_path / "new").exists()  # neither the output nor its parent was created


def test_missing_run_and_occupied_out_are_refused(trained, terrains, tmp_path):
    _, run_dir, _ = trained
    runner = CliRunner()
    result = runner.invoke(
        main, ["detect", str(tmp_path / "no-run"), "--dtm", str(terrains["ok"]), "--out", str(tmp_path / "o")]
    )
    assert result.exit_code == 1 and "does not exist" in result.output and not (tmp_path / "o").exists()
    occupied = tmp_path / "occupied"
    occupied.mkdir()
    (occupied / "keep.txt").write_text("mine")
    result = runner.invoke(main, ["detect", str(run_dir), "--dtm", str(terrains["ok"]), "--out", str(occupied)])
    assert result.exit_code == 1 and "--overwrite" in result.output
    assert [p.name for p in occupied.iterdir()] == ["keep.txt"]
    a_file = tmp_path / "file"
    a_file.write_text("x")
    result = runner.invoke(main, ["detect", str(run_dir), "--dtm", str(terrains["ok"]), "--out", str(a_file)])
    assert result.exit_code == 1 and "not a directory" in result.output and a_file.read_text() == "x"


def test_overwrite_replaces_only_a_detect_output_and_a_failure_leaves_it_whole(
    trained, terrains, tmp_path, monkeypatch
):
    _, _, constant = trained
    out = tmp_path / "out"
    detect(constant, out, DetectSettings(threshold="nats:0.5", mc_samples=1), dtm=terrains["ok"])
    (out / "notes.txt").write_text("mine")  # a user's file beside an output stays
    before = {name: (out / name).read_bytes() for name in OUTPUT_FILES}

    def boom(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(detect_module, "select_sites", boom)
    with pytest.raises(RuntimeError, match="disk full"):
        detect(constant, out, DetectSettings(threshold="nats:0.7", mc_samples=1, overwrite=True), dtm=terrains["ok"])
    assert {name: (out / name).read_bytes() for name in OUTPUT_FILES} == before  # untouched
    assert sorted(p.name for p in out.iterdir()) == sorted([*OUTPUT_FILES, "notes.txt"])  # no staging left
    monkeypatch.undo()
    empty = tmp_path / "empty"
    empty.mkdir()  # an empty directory needs no --overwrite
    detect(constant, empty, DetectSettings(threshold="nats:0.5", mc_samples=1), dtm=terrains["ok"])
    assert sorted(p.name for p in empty.iterdir()) == sorted(OUTPUT_FILES)
    detect(constant, out, DetectSettings(threshold="nats:0.7", mc_samples=1, overwrite=True), dtm=terrains["ok"])
    assert sorted(p.name for p in out.iterdir()) == sorted([*OUTPUT_FILES, "notes.txt"])
    assert json.loads((out / "detect.json").read_text())["threshold"]["value_nats"] == 0.7
    assert (out / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "out", "terrains"]


def _tree(path: Path) -> dict[str, bytes]:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def test_an_output_never_is_holds_or_lies_inside_an_input(trained, terrains, tmp_path, monkeypatch):
    """``--out RUN --overwrite`` and ``--dtm site/site.tif --out site --overwrite`` deleted their inputs."""
    dataset, run_dir, _ = trained
    runner = CliRunner()
    site = tmp_path / "site"
    site.mkdir()
    dtm = site / "site.tif"
    dtm.write_bytes(Path(terrains["ok"]).read_bytes())
    run_before, site_before, data_before = _tree(run_dir), _tree(site), _tree(dataset)
    cases = [
        ([str(run_dir), "--dtm", str(dtm), "--out", str(run_dir)], "is the run"),
        ([str(run_dir / "last.pt"), "--dtm", str(dtm), "--out", str(run_dir)], "contains the run"),
        ([str(run_dir), "--dtm", str(dtm), "--out", str(run_dir / "maps")], "lies inside the run"),
        ([str(run_dir), "--dtm", str(dtm), "--out", str(site)], "contains the DTM"),
        ([str(run_dir), "--dtm", str(dtm), "--out", str(tmp_path)], "contains the"),
        ([str(run_dir), "--data", str(dataset), "--scan", "0", "--out", str(dataset / "maps")], "dataset"),
        ([str(run_dir), "--dtm", str(dtm), "--out", str(dataset)], "the run's dataset"),
    ]
    for args, needle in cases:
        for extra in ([], ["--overwrite"]):
            result = runner.invoke(main, ["detect", *args, *extra, "--threshold", "nats:0.3", "--mc-samples", "1"])
            assert result.exit_code == 1 and "Traceback" not in result.output, result.output
            assert needle in result.output and "an output never replaces" in result.output, result.output
    assert (_tree(run_dir), _tree(site), _tree(dataset)) == (run_before, site_before, data_before)
    assert not (run_dir / "maps").exists() and not (dataset / "maps").exists()
    # A symbolic link to the run is the run.
    link = tmp_path / "link"
    link.symlink_to(run_dir)
    result = runner.invoke(main, ["detect", str(run_dir), "--dtm", str(dtm), "--out", str(link), "--overwrite"])
    assert result.exit_code == 1 and "is the run" in result.output and _tree(run_dir) == run_before
    # The working directory: usable when it is empty, refused when it holds the DTM.
    monkeypatch.chdir(site)
    result = runner.invoke(main, ["detect", str(run_dir), "--dtm", "site.tif", "--out", ".", "--overwrite"])
    assert result.exit_code == 1 and "contains the DTM" in result.output and _tree(site) == site_before
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    args = ["detect", str(run_dir), "--dtm", str(dtm), "--out", ".", "--threshold", "nats:0.3", "--mc-samples", "1"]
    assert runner.invoke(main, args).exit_code == 0
    assert runner.invoke(main, [*args, "--overwrite"]).exit_code == 0
    assert sorted(p.name for p in work.iterdir()) == sorted(OUTPUT_FILES)


def test_overwrite_never_replaces_a_directory_that_is_not_a_detect_output(trained, terrains, tmp_path):
    _, run_dir, _ = trained
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "p_safe.tif").write_text("a user's own file of the same name")
    (foreign / "thesis.tex").write_text("keep me")
    result = CliRunner().invoke(
        main, ["detect", str(run_dir), "--dtm", str(terrains["ok"]), "--out", str(foreign), "--overwrite"]
    )
    assert result.exit_code == 1 and "holds no hd detect output" in result.output, result.output
    assert _tree(foreign) == {"p_safe.tif": b"a user's own file of the same name", "thesis.tex": b"keep me"}


def test_a_second_writer_is_refused_and_a_killed_ones_staging_is_removed(trained, terrains, tmp_path):
    """Two detects into one --out: the second waited for nothing and replaced the first's output."""
    _, _, constant = trained
    out = tmp_path / "out"
    out.mkdir()
    with WriterLock(out, "detect"), pytest.raises(LockedError, match="another hd process"):  # another writer
        detect(constant, out, DetectSettings(threshold="nats:0.5", mc_samples=1), dtm=terrains["ok"])
    assert list(out.iterdir()) == []
    killed = out / f".detect{PARTIAL_MARK}999999"  # the staging directory of a detect killed by SIGKILL
    killed.mkdir()
    (killed / "p_safe.tif").write_bytes(b"half")
    detect(constant, out, DetectSettings(threshold="nats:0.5", mc_samples=1), dtm=terrains["ok"])
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUT_FILES)
    with pytest.raises(OutputExistsError, match="--overwrite"):  # a finished output is not replaced silently
        detect(constant, out, DetectSettings(threshold="nats:0.5", mc_samples=1), dtm=terrains["ok"])


def test_a_run_without_its_dataset_needs_a_fixed_threshold(trained, terrains, tmp_path):
    _, run_dir, _ = trained
    ckpt = torch.load(run_dir / "last.pt", weights_only=True)
    ckpt["extra_config"]["dataset"] = str(tmp_path / "moved-away")
    save_checkpoint(tmp_path / "portable.pt", ckpt)
    with pytest.raises(HdNetError, match="nats:"):
        detect(tmp_path / "portable.pt", tmp_path / "a", dtm=terrains["ok"])
    assert not (tmp_path / "a").exists()
    result = detect(
        tmp_path / "portable.pt", tmp_path / "b", DetectSettings(threshold="nats:0.2", mc_samples=2), dtm=terrains["ok"]
    )
    assert result.threshold_nats == 0.2 and (tmp_path / "b" / "detect.json").is_file()


def test_cli_detect_prints_a_summary(trained, terrains, tmp_path):
    _, run_dir, _ = trained
    out = tmp_path / "cli"
    result = CliRunner().invoke(
        main,
        [
            *("detect", str(run_dir), "--dtm", str(terrains["ok"]), "--out", str(out)),
            *("--mc-samples", "2", "--sites", "3", "--layout", "nchw", "--site-margin", "1"),
        ],
    )
    assert result.exit_code == 0, result.output
    assert "valid cells" in result.output and "detect.json" in result.output
    assert "site margin 1 m around the lander's disk" in result.output
    info = json.loads((out / "detect.json").read_text())
    assert info["threshold"]["spec"] == "mean" and info["mc_samples"] == 2 and len(info["sites"]) <= 3
    assert info["network_layout"] == "nchw"
    assert info["site_rule"]["margin_m"] == 1.0 and "widened" in info["site_rule"]["footprint"]
    assert info["baseline"]["sigma_m"] == 0.0167 and info["run"]["train_sigma_m"] == 0.0167


def test_the_calibrated_threshold_is_cached_in_the_run_and_keyed_on_what_it_depends_on(trained, tmp_path):
    _, run, constant = trained
    dtm = write_dtm(tmp_path / "site.tif", tilted_plane(60, 1.0, 3.0), 1.0)
    cache = run / "thresholds.json"
    cache.unlink(missing_ok=True)

    def threshold(out: str, **kw) -> dict:
        detect(run, tmp_path / out, DetectSettings(mc_samples=2, **kw), dtm=dtm)
        return json.loads((tmp_path / out / "detect.json").read_text())["threshold"]

    first = threshold("a")
    assert "cached" not in first and cache.is_file()
    second = threshold("b")
    assert second["cached"] == str(cache) and second["value_nats"] == first["value_nats"]
    mi = threshold("mi", uncertainty="mutual-information")  # another score: never the entropy's threshold
    assert "cached" not in mi and mi["uncertainty"] == "mutual-information" and mi["value_nats"] < first["value_nats"]
    again = threshold("mi-again", uncertainty="mutual-information")
    assert again["cached"] == str(cache) and again["value_nats"] == mi["value_nats"]
    keys = [e["key"] for e in json.loads(cache.read_text())["entries"]]
    assert [k.get("uncertainty") for k in keys] == [None, "mutual-information"]  # the entropy's key as before
    other = threshold("c", seed=1)  # another MC seed: calibrated again
    assert "cached" not in other
    # A damaged cache is ignored and rewritten; a checkpoint given on its own never writes one.
    cache.write_text("{not json")
    with pytest.warns(HdWarning, match="unreadable threshold cache"):
        assert "cached" not in threshold("d")
    assert json.loads(cache.read_text())["schema"] == "hd.threshold-cache"
    detect(constant, tmp_path / "e", DetectSettings(mc_samples=2), dtm=dtm)
    assert not (constant.parent / "thresholds.json").exists()


@pytest.mark.parametrize("forged", [5.0, None])
def test_a_forged_cached_threshold_is_recalibrated_and_the_record_states_the_value_used(trained, tmp_path, forged):
    _, run, _ = trained
    dtm = write_dtm(tmp_path / "site.tif", tilted_plane(60, 1.0, 3.0), 1.0)
    cache = run / "thresholds.json"
    cache.unlink(missing_ok=True)
    detect(run, tmp_path / "a", DetectSettings(mc_samples=2), dtm=dtm)
    calibrated = json.loads((tmp_path / "a" / "detect.json").read_text())["threshold"]["value_nats"]
    record = json.loads(cache.read_text())
    record["entries"][0]["value_nats"] = forged  # "H_t unbounded" (None) or beyond any entropy (5.0)
    cache.write_text(json.dumps(record))
    with pytest.warns(HdWarning, match="calibrated again"):
        result = detect(run, tmp_path / "b", DetectSettings(mc_samples=2), dtm=dtm)
    info = json.loads((tmp_path / "b" / "detect.json").read_text())["threshold"]
    assert "cached" not in info and info["value_nats"] == calibrated == result.threshold_nats
    with rasterio.open(tmp_path / "a" / "safety.tif") as a, rasterio.open(tmp_path / "b" / "safety.tif") as b:
        assert np.array_equal(a.read(1), b.read(1))
    # The entry is replaced by the calibrated one, which the next call uses.
    again = detect(run, tmp_path / "c", DetectSettings(mc_samples=2), dtm=dtm)
    assert again.threshold_nats == calibrated
    assert json.loads((tmp_path / "c" / "detect.json").read_text())["threshold"]["cached"] == str(cache)


def split_scans(dataset: Path, split: str) -> list[int]:
    """The scan indices of one split (0 train, 1 val, 2 test in the label shards)."""
    import h5py

    code = ("train", "val", "test").index(split)
    scans: list[int] = []
    for path in find_labeling(dataset).shard_paths(dataset):
        with h5py.File(path) as f:
            scans += [int(s) for s, k in zip(f["scan_index"][:], f["split"][:], strict=True) if k == code]
    return scans


def test_a_training_scan_an_unfinished_run_and_an_unreachable_risk_level_are_said(trained, tmp_path):
    """hd detect on a scan the run trained on, with a run stopped at epoch 1 of 10 and risk:0.05 on its
    2 validation images: three one-line warnings, detect.json and the summary say it; a test scan of
    a copy of the dataset is not called a training scan, a training scan of the copy is."""
    import shutil

    dataset, run_dir, _ = trained
    partial = tmp_path / "run"
    shutil.copytree(run_dir, partial)
    config = json.loads((partial / "config.json").read_text())
    config["epochs"] = 10
    (partial / "config.json").write_text(json.dumps(config))
    scan = split_scans(dataset, "train")[0]
    runner = CliRunner()
    args = ["detect", str(partial), "--data", str(dataset), "--scan", str(scan), "--out", str(tmp_path / "o")]
    result = runner.invoke(main, [*args, "--mc-samples", "2", "--threshold", "risk:0.05"])
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.output.splitlines() if line.startswith("Warning: ")]
    assert any("1 of its 10 epochs trained" in w for w in warnings), result.output
    assert any(f"scan {scan} is in the training split" in w and "not those of unseen terrain" in w for w in warnings)
    assert any("risk:0.05 cannot be certified with 2 validation image(s)" in w for w in warnings)
    assert "risk:0.05 unreachable with 2 validation images: it needs 19" in result.output
    info = json.loads((tmp_path / "o" / "detect.json").read_text())
    assert info["input"]["split"] == "train" and info["input"]["seen_in_training"] is True
    assert info["threshold"]["unreachable"] is True and info["threshold"]["needs_images"] == 19
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    for split, seen in (("test", False), ("train", True)):
        scan = split_scans(copy, split)[0]
        out = tmp_path / f"copy-{split}"
        args = ["detect", str(run_dir), "--data", str(copy), "--scan", str(scan), "--out", str(out)]
        result = runner.invoke(main, [*args, "--mc-samples", "2", "--threshold", "nats:0.3"])
        assert result.exit_code == 0, result.output
        assert ("in the training split" in result.output) is seen and "Warning:" not in result.output.replace(
            "Warning: scan", ""
        )
        assert json.loads((out / "detect.json").read_text())["input"].get("seen_in_training", False) is seen


# --- detect_dem: the maps in memory -------------------------------------------------------------------
def assert_same_maps(maps: DetectMaps, out: Path) -> None:
    """The arrays of ``maps`` are the files of the hd detect output ``out`` (NaN where NaN), its sites
    and counts those of detect.json, its transform the files'."""
    for name, file in (
        ("p_safe", "p_safe.tif"),
        ("entropy_nats", "entropy.tif"),
        ("mutual_information_nats", "mutual_information.tif"),
        ("safety", "safety.tif"),
        ("baseline_p_safe", "baseline_p_safe.tif"),
    ):
        written = read(out / file)[0]
        assert getattr(maps, name).dtype == written.dtype, name
        np.testing.assert_array_equal(getattr(maps, name), written, err_msg=name)
    info = json.loads((out / "detect.json").read_text())
    uncached = {k: v for k, v in maps.threshold.items() if k != "cached"}  # the second calibration: from the cache
    assert maps.counts == info["counts"] and uncached == info["threshold"]
    assert [s.columns() for s in maps.sites] == info["sites"]
    assert maps.transform == profile_of(out / "safety.tif")["transform"]


def test_detect_dem_of_a_scans_dem_is_hd_detect_of_the_scan(trained, tmp_path):
    """The noisy DEM of a test scan, read with hdlabels.iter_labeled_scans and mapped in memory, gives
    the arrays, sites and counts hd detect --data --scan writes; the record says the same threshold."""
    dataset, run_dir, _ = trained
    scan = next(iter_labeled_scans(dataset, split="test"))
    k = scan.sigmas_m.index(0.07)
    out = tmp_path / "files"
    options: dict[str, Any] = {"sigma_m": 0.07, "threshold": "mean", "mc_samples": 4, "seed": 3, "n_sites": 3}
    result = detect(run_dir, out, DetectSettings(scan=scan.scan_index, **options), dataset=dataset)
    maps = detect_dem(load_run(run_dir, "cpu"), scan.dem_noisy[k], scan_frame=True, **options)
    assert_same_maps(maps, out)
    assert maps.threshold["cached"] == str(run_dir / "thresholds.json")  # calibrated once, by hd detect
    assert maps.threshold_nats == result.threshold_nats and maps.shape == (100, 100) and maps.spacing_m == 1.0
    assert maps.sigma_m == 0.07 and maps.uncertainty == "entropy" and maps.uncertainty_nats is maps.entropy_nats
    valid = result.counts["safe"] + result.counts["unsafe"] + result.counts["uncertain"]
    assert maps.safe_fraction == result.counts["safe"] / valid and int(maps.valid.sum()) == valid
    assert not (tmp_path / "run-files").exists() and sorted(p.name for p in tmp_path.iterdir()) == ["files"]


def test_detect_dem_of_a_dtms_heights_is_hd_detect_of_the_dtm(trained, tmp_path):
    """A 150 x 150 DTM at the run's 1 m (four tiles, map heights): its heights and transform in memory
    give what hd detect --dtm writes, sites in the DTM's coordinates included; the run can be a path."""
    _, run_dir, _ = trained
    rng = np.random.default_rng(5)
    z = (tilted_plane(150, 1.0, 4.0) + ndimage.gaussian_filter(rng.normal(0, 1.0, (150, 150)), 3)).astype(np.float32)
    z[60:70, 20:90] = np.nan
    dtm = write_dtm(tmp_path / "t.tif", z, 1.0, origin=(1000.0, 2000.0))
    out = tmp_path / "files"
    options: dict[str, Any] = {"threshold": "nats:0.3", "mc_samples": 3, "seed": 1, "n_sites": 4}
    options["uncertainty"] = "mutual-information"
    detect(run_dir, out, DetectSettings(**options), dtm=dtm)
    with DTM.open(dtm) as src:  # the heights and the grid as lidarsim reads them
        heights, grid = src.read(0, 0, 150, 150), src.info.transform
    assert grid == tuple(from_origin(1000.0, 2000.0, 1.0, 1.0))[:6]
    maps = detect_dem(run_dir, heights, transform=grid, **options)
    assert_same_maps(maps, out)
    assert maps.uncertainty_nats is maps.mutual_information_nats
    assert maps.sites and all(1000.0 < s.x < 1150.0 and 1850.0 < s.y < 2000.0 for s in maps.sites)


def test_detect_dem_with_a_constant_run_on_a_plane_by_hand(trained):
    """A run that says 'safe' everywhere on a flat 100 x 100 plane with no threshold: every cell outside
    the border band of the lander footprint is safe and certain, the baseline calls the same cells safe,
    and the default grid is the scan frame centred on the array."""
    _, _, constant = trained
    maps = detect_dem(load_run(constant, "cpu"), np.zeros((100, 100)), threshold="nats:inf", mc_samples=2, n_sites=1)
    b = geometry(Lander(), 1.0).band_px
    inside = (100 - 2 * b) ** 2
    counts = {"unsafe": 0, "safe": inside, "uncertain": 0, "invalid": 100 * 100 - inside, "baseline_safe": inside}
    assert maps.counts == counts and int(maps.baseline_safe.sum()) == inside
    assert maps.safe_fraction == 1.0 and math.isinf(maps.threshold_nats) and maps.threshold["value_nats"] is None
    assert (maps.safe_and_certain == maps.valid).all() and not maps.uncertain.any()
    np.testing.assert_allclose(maps.p_safe[maps.valid], 1 / (1 + math.exp(-6)), rtol=1e-6)
    assert maps.transform @ (0, 0) == (-50.0, 50.0) and maps.transform @ (100, 100) == (50.0, -50.0)
    # the clearest cells: the four round the centre; ties go north, then west (row 49, col 49)
    assert (maps.sites[0].x, maps.sites[0].y) == (-0.5, 0.5)


def test_detect_dem_says_when_the_run_is_unfinished(trained, tmp_path):
    import shutil

    _, run_dir, _ = trained
    partial = tmp_path / "run"
    shutil.copytree(run_dir, partial)
    config = json.loads((partial / "config.json").read_text())
    (partial / "config.json").write_text(json.dumps(config | {"epochs": 10}))
    with pytest.warns(HdWarning, match="1 of its 10 epochs trained"):
        detect_dem(load_run(partial, "cpu"), np.zeros((100, 100)), threshold="nats:0.5", mc_samples=1)


@pytest.mark.parametrize(
    ("heights", "keywords", "error", "needle"),
    [
        (np.zeros((2, 100, 100)), {}, HdNetError, "2-D array of heights in metres"),
        (np.zeros((100, 100), bool), {}, HdNetError, "2-D array of heights in metres"),
        (np.zeros((100, 100)), {"transform": from_origin(0.0, 0.0, 0.5, 0.5)}, HdNetError, "run's DEM spacing is 1 m"),
        (np.zeros((10, 100)), {}, TerrainError, "too small for the lander footprint"),
        (np.full((100, 100), np.inf), {}, TerrainError, "has no such valid square"),
        (np.zeros((100, 100)), {"mc_samples": 0}, HdNetError, r"mc-samples must be an integer in \[1, "),
        (np.zeros((100, 100)), {"threshold": "quantil:0.9"}, HdNetError, "is not one of"),
    ],
)
def test_detect_dem_refuses_bad_input_with_one_line(trained, heights, keywords, error, needle):
    _, _, constant = trained
    with pytest.raises(error, match=needle):
        detect_dem(constant, heights, threshold=keywords.pop("threshold", "nats:0.5"), **keywords)
