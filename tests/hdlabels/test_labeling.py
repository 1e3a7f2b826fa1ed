"""Labelling a dataset: label shards beside scan shards, manifest entries, CLI errors."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from hdcli.cli import main
from hdcore.errors import FormatError
from hdlabels.alhat import hazard_maps, safety_probability
from hdlabels.grid import grid_points
from hdlabels.labeling import label_dataset
from hdlabels.lander import Lander
from hdlabels.store import (
    LABEL_SCHEMA_VERSION,
    LABEL_SCHEMA_VERSION_CLEAN_SCAN,
    DemSpec,
    LabelingEntry,
    LabelShardEntry,
    LabelShardReader,
    LabelStoreError,
    find_labeling,
    iter_labeled_scans,
)
from lidarsim.build import BuildConfig, build_dataset
from lidarsim.sensor import SensorConfig
from lidarsim.shards import ScanShardReader, read_manifest, sha256_file, verify_dataset
from lidarsim.trajectory import TrajectoryConfig
from tests.geotiff import write_geotiff


def write_terrain(path: Path, n: int = 320, spacing: float = 0.5) -> Path:
    """A plane with a few 0.6 m boulders (seeded), 160 m square."""
    rng = np.random.default_rng(11)
    x = (np.arange(n) + 0.5) * spacing
    z = 0.02 * x[None, :] + np.zeros((n, 1))
    yy, xx = np.mgrid[0:n, 0:n] * spacing
    for cx, cy in rng.uniform(20, 140, size=(40, 2)):
        r2 = (xx - cx) ** 2 + (yy - cy) ** 2
        z = np.maximum(z, np.where(r2 < 1.0, 0.02 * xx + 0.6 * np.sqrt(np.clip(1 - r2, 0, 1)), -np.inf))
    return write_geotiff(path, z, spacing, (0.0, n * spacing))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("labels")
    dtm = write_terrain(root / "t.tif")
    out = root / "data"
    build_dataset(
        out,
        BuildConfig(
            sigmas_m=(0.01, 0.07),
            seed=1,
            sensor=SensorConfig(rows=64, cols=64),
            trajectory=TrajectoryConfig(n_scans=6),
            dtm_path=str(dtm),
            shard_size=3,
        ),
        workers=1,
    )
    return out


def test_label_shards_hold_the_maps_of_the_gridded_scans(dataset):
    summary = label_dataset(dataset, workers=1)
    assert 0.0 < summary.safe_fraction < 1.0
    entry = find_labeling(dataset)
    assert entry.name == summary.name and len(entry.shards) == 2
    manifest = read_manifest(dataset)
    for label_entry, scan_entry in zip(entry.shards, manifest["shards"], strict=True):
        assert label_entry.source_path == scan_entry["path"]
        assert label_entry.source_sha256 == scan_entry["sha256"]
    paths = entry.shard_paths(dataset)
    with LabelShardReader(paths[1]) as labels, ScanShardReader(dataset / manifest["shards"][1]["path"]) as scans:
        assert labels.sigmas_m == (0.01, 0.07)
        scan, lab = scans[2], labels[2]
        assert lab.scan_index == scan.scan_index == 5
        # the default labelling: the paper convention, its gridding and its product baseline
        lander, grid = entry.lander, entry.dem
        assert (lander, grid) == (Lander(), DemSpec.for_convention("paper")) and entry.convention == "paper"
        assert labels.h5.attrs["lander_convention"] == "paper" and labels.h5.attrs["dem_gridding"] == grid.gridding
        dem = grid_points(scan.points_clean, method=grid.gridding)
        np.testing.assert_array_equal(lab.dem_clean, dem)
        maps = hazard_maps(dem, 1.0, lander)
        np.testing.assert_array_equal(lab.label, maps.label)
        np.testing.assert_array_equal(lab.slope_rad, maps.slope_rad)
        noisy = grid_points(scan.points_noisy[1], method=grid.gridding)
        np.testing.assert_array_equal(lab.dem_noisy[1], noisy)
        np.testing.assert_array_equal(lab.p_safe[1], safety_probability(noisy, 1.0, 0.07, lander))
        assert lab.label.dtype == np.uint8 and set(np.unique(lab.label)) <= {0, 1, 255}
        assert (lab.label[:5] == 255).all() and (lab.label[:, -5:] == 255).all()  # border band of 5 m
        assert lab.split == scan.split
    assert verify_dataset(dataset, {"hd.labels": LABEL_SCHEMA_VERSION}) == []
    # the same settings again: nothing recomputed, nothing duplicated
    again = label_dataset(dataset, workers=1)
    assert again.reused and len(read_manifest(dataset)["labelings"]) == 1


def test_labelled_scans_are_read_back_in_scan_order_by_split_with_their_noise_levels(dataset):
    """iter_labeled_scans reads every label shard's scans (the reader's own), one split or all, each
    with its shard's noise levels; an unknown split or labelling is refused as it is called."""
    name = label_dataset(dataset, workers=1).name
    entry = find_labeling(dataset, name)
    expected = []
    for path in entry.shard_paths(dataset):
        with LabelShardReader(path) as reader:
            expected += list(reader)
    every = list(iter_labeled_scans(dataset, name))
    assert [s.scan_index for s in every] == list(range(6)) == [s.scan_index for s in expected]
    for got, want in zip(every, expected, strict=True):
        np.testing.assert_array_equal(got.dem_noisy, want.dem_noisy)
        assert got.sigmas_m == (0.01, 0.07) and got.dem_noisy.shape == (2, 100, 100) and got.split == want.split
    for split in ("train", "val", "test"):
        assert [s.scan_index for s in iter_labeled_scans(dataset, name, split)] == [
            s.scan_index for s in every if s.split == split
        ]
    with pytest.raises(LabelStoreError, match="unknown split 'tset'; use one of train, val, test"):
        iter_labeled_scans(dataset, name, "tset")
    with pytest.raises(LabelStoreError, match="no labelling named 'nope'"):
        iter_labeled_scans(dataset, "nope")


def test_other_lander_makes_a_second_labelling(dataset):
    label_dataset(dataset, workers=1)
    before = {p: sha256_file(p) for p in (dataset / "shards").glob("*.h5")}
    result = CliRunner().invoke(
        main, ["label", str(dataset), "--lander", "triangle", "--max-roughness", "0.3", "--workers", "1"]
    )
    assert result.exit_code == 0, result.output
    labelings = read_manifest(dataset)["labelings"]
    assert len(labelings) == 2 and labelings[0]["name"] != labelings[1]["name"]
    assert {p: sha256_file(p) for p in before} == before  # scan shards untouched
    with pytest.raises(LabelStoreError, match="several labellings"):
        find_labeling(dataset)
    tri = find_labeling(dataset, labelings[1]["name"])
    assert tri.lander.layout == "triangle" and tri.lander.max_roughness_m == 0.3
    ok = CliRunner().invoke(main, ["verify", str(dataset)])
    assert ok.exit_code == 0 and "OK" in ok.output


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--lander-diameter", "150"], "larger than the DEM"),
        (["--pad-diameter", "12"], "pad diameter"),
        (["--max-slope-deg", "0"], "--max-slope-deg"),  # out of its range: a usage error
        (["--max-roughness", "-0.1"], "--max-roughness"),
    ],
)
def test_bad_lander_is_refused_and_nothing_is_written(dataset, args, needle):
    before = (dataset / "manifest.json").read_text()
    result = CliRunner().invoke(main, ["label", str(dataset), "--workers", "1", *args])
    assert result.exit_code != 0 and needle in result.output and "Traceback" not in result.output
    assert (dataset / "manifest.json").read_text() == before


def test_not_a_dataset_and_all_nan_dems_are_refused(tmp_path):
    result = CliRunner().invoke(main, ["label", str(tmp_path)])
    assert result.exit_code != 0 and "not an hd dataset" in result.output
    dtm = write_terrain(tmp_path / "t.tif")
    out = tmp_path / "blind"
    sensor = SensorConfig(rows=8, cols=8, dead_elements=64)  # every element dead: no return at all
    build_dataset(
        out,
        BuildConfig(
            sigmas_m=(0.01,), sensor=sensor, trajectory=TrajectoryConfig(n_scans=2), dtm_path=str(dtm), shard_size=2
        ),
        workers=1,
    )
    result = CliRunner().invoke(main, ["label", str(out), "--workers", "1"])
    assert result.exit_code != 0 and "all NaN" in result.output
    assert read_manifest(out)["labelings"] == []
    assert not (out / "labels").exists() or not any((out / "labels").rglob("*.h5"))


def test_the_labelling_entry_is_a_typed_record_that_writes_the_manifest_as_it_reads_it(dataset):
    """find_labeling gives a LabelingEntry; its JSON is the manifest's entry key for key and in order,
    and an entry hd cannot use is refused naming the manifest, not read with a silent default."""
    label_dataset(dataset, workers=1)
    raw = read_manifest(dataset)["labelings"][0]
    entry = find_labeling(dataset, raw["name"])
    assert isinstance(entry, LabelingEntry) and all(isinstance(s, LabelShardEntry) for s in entry.shards)
    assert json.dumps(entry.to_json()) == json.dumps(raw)  # the same keys, values and order
    assert entry.spacing_m == 1.0 and entry.first_sha256 == raw["shards"][0]["sha256"]
    assert sum(s.n_scans for s in entry.shards) == 6 and entry.truth == "clean-scan"
    assert "shards" not in entry.without_shards().to_json() and entry.without_shards().same_hazards(entry)
    for broken, message in (
        ({**raw, "dem": {"rows": [100], "cols": 100, "spacing_m": 1.0}}, "labelling x: its dem, lander or counts"),
        ({**raw, "dem": "100x100"}, "labelling x: its 'dem' and 'lander' entries must be JSON objects"),
        ({**raw, "dem": {"rows": 100, "cols": 100}}, "labelling x: the DEM grid entry lacks 'spacing_m'"),
        ({**raw, "truth": "rocks"}, "labelling x: unknown truth 'rocks'"),
        ({**raw, "shards": [{**raw["shards"][0], "n_scans": "3"}]}, r"x: shards\[0\]: its 'n_scans' must be"),
        ({**raw, "shards": [{k: v for k, v in raw["shards"][0].items() if k != "source_path"}]}, "'source_path'"),
    ):
        with pytest.raises(LabelStoreError, match=message):
            LabelingEntry.from_json(broken, "manifest.json: labelling x")


def test_unknown_label_schema_version_is_refused(dataset, tmp_path):
    label_dataset(dataset, workers=1)
    entry = find_labeling(dataset, read_manifest(dataset)["labelings"][0]["name"])
    copy = tmp_path / "copy.h5"
    copy.write_bytes(Path(entry.shard_paths(dataset)[0]).read_bytes())
    with h5py.File(copy, "r+") as f:
        f.attrs["schema_version"] = "3.0"
    with pytest.raises(FormatError, match=r"version 3\.0"):
        LabelShardReader(copy)
    manifest = json.loads((dataset / "manifest.json").read_text())
    # the clean scan's labellings keep version 1.1 (their bytes); 1.2 is the newest version hd writes
    assert all(lab["schema_version"] == LABEL_SCHEMA_VERSION_CLEAN_SCAN for lab in manifest["labelings"])
    assert LABEL_SCHEMA_VERSION == "1.2"


def test_convention_options_name_and_record_the_labelling(dataset):
    runner = CliRunner()
    hd = runner.invoke(main, ["label", str(dataset), "--convention", "hd", "--workers", "1"])
    assert hd.exit_code == 0, hd.output
    entry = find_labeling(
        dataset, "square-d10m-pad1m-slope10deg-rough0.2m-yaws8-dem100x100at1m"
    )  # the pre-convention name
    assert entry.convention == "hd" and entry.dem.gridding == "linear"
    assert entry.lander == Lander(convention="hd")
    with LabelShardReader(entry.shard_paths(dataset)[0]) as reader:
        assert reader.h5.attrs["lander_convention"] == "hd" and reader.h5.attrs["lander_baseline_combine"] == "min"
    mixed = runner.invoke(
        main,
        [
            "label",
            str(dataset),
            "--convention",
            "paper",
            "--baseline-combine",
            "min",
            "--gridding",
            "mean",
            "--workers",
            "1",
        ],
    )
    assert mixed.exit_code == 0, mixed.output
    entry = find_labeling(dataset, "paper-square-d10m-pad1m-slope10deg-rough0.2m-min-mean-dem100x100at1m")
    assert entry.lander.baseline_combine == "min" and entry.dem.gridding == "mean"


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--yaws", "4"], "--yaws applies to --convention hd only"),
        (["--convention", "alhat"], "Invalid value for '--convention'"),
        (["--gridding", "cubic"], "Invalid value for '--gridding'"),
        (["--lander-diameter", "3", "--pad-diameter", "1", "--dem-spacing", "1"], "too few"),
    ],
)
def test_bad_convention_settings_are_refused_before_any_work(dataset, args, needle):
    before = (dataset / "manifest.json").read_text()
    result = CliRunner().invoke(main, ["label", str(dataset), "--workers", "1", *args])
    assert result.exit_code != 0 and needle in result.output and "Traceback" not in result.output
    assert (dataset / "manifest.json").read_text() == before


def test_a_labelling_is_found_by_a_short_name_and_the_names_are_listed(dataset):
    from lidarsim.shards import read_manifest

    labelings = read_manifest(dataset)["labelings"]
    assert len(labelings) >= 2  # the tests above added several
    by_convention: dict[str, list[str]] = {}
    for lab in labelings:
        by_convention.setdefault(lab.get("convention", "hd"), []).append(lab["name"])
    for convention, names in by_convention.items():
        if len(names) == 1:
            assert find_labeling(dataset, convention).name == names[0]
        else:
            with pytest.raises(LabelStoreError, match=f"names {len(names)} labellings") as info:
                find_labeling(dataset, convention)
            assert all(n in str(info.value) for n in names)
    full = labelings[-1]["name"]
    assert find_labeling(dataset, full).name == full
    with pytest.raises(LabelStoreError, match="has no labelling named 'nope'; it has: ") as info:
        find_labeling(dataset, "nope")
    assert all(lab["name"] in str(info.value) for lab in labelings)


def test_the_manifests_counts_are_those_of_the_label_shards_also_after_a_resumed_run(dataset, tmp_path, monkeypatch):
    """The workers count labels and baseline-safe pixels as they label; a shard left by an
    interrupted run is counted from its file. Both must equal a count over the written shards."""
    import shutil

    from hdlabels import labeling

    data = tmp_path / "data"
    shutil.copytree(dataset, data)
    manifest = read_manifest(data)
    manifest.pop("labelings", None)
    (data / "manifest.json").write_text(json.dumps(manifest))
    shutil.rmtree(data / "labels", ignore_errors=True)
    real = labeling.run_label_task
    calls = []

    def second_fails(task):
        calls.append(task.out_path)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(task)

    monkeypatch.setattr(labeling, "run_label_task", second_fails)
    with pytest.raises(KeyboardInterrupt):
        label_dataset(data, workers=1)
    label_dataset(data, workers=1)  # the first shard is found complete and counted from its file
    assert len(calls) == 3 and calls[2] == calls[1]
    entry = find_labeling(data)
    labels, p_safe = [], []
    for path in entry.shard_paths(data):
        with h5py.File(path) as f:
            labels.append(f["label"][:])
            p_safe.append(f["p_safe"][:])
    label, p = np.concatenate(labels), np.concatenate(p_safe)
    labelled = label != 255
    assert entry.label_counts == (int((label == 0).sum()), int((label == 1).sum()), int((label == 255).sum()))
    expected = {
        f"{s:g}": float(((p[:, k] >= 0.5) & labelled).sum() / labelled.sum()) for k, s in enumerate((0.01, 0.07))
    }
    assert entry.baseline_safe_fraction == expected
    assert 0.0 < expected["0.01"] <= 1.0


def test_a_label_shard_written_in_blocks_reads_back_row_by_row(tmp_path, monkeypatch):
    """The writer holds up to ROW_BLOCK_BYTES of scans and writes them together: with blocks of 2,
    five scans come back exactly, and the bytes equal those of one block; rows go in order."""
    from hdcore import storage
    from hdlabels import store

    rng = np.random.default_rng(3)
    dem = DemSpec(rows=8, cols=8, spacing_m=1.0, gridding="nearest")
    rows: list[dict[str, np.ndarray]] = [
        {
            "dem_clean": rng.random((8, 8), dtype=np.float32),
            "dem_noisy": rng.random((2, 8, 8), dtype=np.float32),
            "label": rng.integers(0, 2, (8, 8)).astype(np.uint8),
            "slope_rad": rng.random((8, 8), dtype=np.float32),
            "roughness_m": rng.random((8, 8), dtype=np.float32),
            "p_safe": rng.random((2, 8, 8), dtype=np.float32),
        }
        for _ in range(5)
    ]

    row_bytes = 8 + 1 + sum(a.nbytes for a in rows[0].values())  # scan_index, split and the maps

    def write(path: Path, block: int) -> None:
        monkeypatch.setattr(storage.h5image, "ROW_BLOCK_BYTES", block * row_bytes)
        writer = store.LabelShardWriter(path, 5, 2, dem, {"labeling": "t", "sigmas_m": np.array([0.01, 0.07])})
        for k, arrays in enumerate(rows):
            writer.write(k, 10 + k, k % 3, **arrays)
        writer.commit()

    write(tmp_path / "blocks.h5", 2)
    write(tmp_path / "one.h5", 64)
    assert sha256_file(tmp_path / "blocks.h5") == sha256_file(tmp_path / "one.h5")
    with h5py.File(tmp_path / "blocks.h5") as f:
        assert f["scan_index"][:].tolist() == [10, 11, 12, 13, 14] and f["split"][:].tolist() == [0, 1, 2, 0, 1]
        for k, arrays in enumerate(rows):
            for name, value in arrays.items():
                np.testing.assert_array_equal(f[name][k], value)
    writer = store.LabelShardWriter(tmp_path / "order.h5", 5, 2, dem, {"labeling": "t"})
    writer.write(0, 0, 0, **rows[0])
    with pytest.raises(ValueError, match="in order"):
        writer.write(2, 2, 0, **rows[2])
    writer.abort()
