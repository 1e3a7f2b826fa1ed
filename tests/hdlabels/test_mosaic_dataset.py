"""Mosaic datasets (``hd mosaic``, ``hdlabels.mosaic_dataset``): one scan per descent that labels,
trains and maps like a scan, placed where the navigation put it and scored where the ground is."""

from __future__ import annotations

import importlib
import json
import warnings
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
from click.testing import CliRunner
from test_mosaic import SIDE_M, hills, tilted_plane

from hdcli.cli import main
from hdcore.errors import HdWarning
from hdlabels.grid import grid_points
from hdlabels.mosaic import descent_frames, mosaic_frames, navigation_error, placed_points, terrain_residual
from hdlabels.mosaic_dataset import MosaicSettings, cell_points, clean_mosaic, in_mosaic_frame, mosaic_dataset
from hdlabels.mosaic_resume import RESUME_DIR
from hdlabels.store import DemSpec, iter_labeled_scans
from hdlabels.truth import terrain_dem
from lidarsim.build import build_dataset
from lidarsim.recipe import BuildSettings
from lidarsim.shards import iter_descents, iter_scans, read_manifest
from lidarsim.terrain import DTM
from tests.geotiff import write_geotiff

DEM_SIDE = 40
GRID = ["--dem-size", str(DEM_SIDE), "--convention", "paper"]  # nearest gridding
DEM = DemSpec(DEM_SIDE, DEM_SIDE, 1.0, "nearest")


def descent_build(tmp: Path, heights: np.ndarray, name: str, position_m: float, attitude_deg: float) -> Path:
    """Four descents of three frames (300 m to 150 m) over a 600 m terrain, two noise levels, with this
    navigation error (1-sigma bias per descent)."""
    write_geotiff(tmp / f"{name}.tif", heights, 1.0, (0.0, SIDE_M))
    settings = BuildSettings(
        scans=4,
        descent_frames=3,
        descent_altitudes_m="300:150",
        resolution=48,
        sigmas_m=(0.02, 0.05),
        seed=3,
        dtm_path=str(tmp / f"{name}.tif"),
        nav_position_sigma_m=position_m,
        nav_attitude_sigma_deg=attitude_deg,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", HdWarning)  # coarse sensor, neighbouring descents share ground
        build_dataset(tmp / name, settings.to_config(), workers=1)
    return tmp / name


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A descent build on hills with 1 m / 0.1 degree navigation error, and its registered mosaics."""
    tmp = tmp_path_factory.mktemp("mosaics")
    source = descent_build(tmp, hills(), "hills", 1.0, 0.1)
    result = CliRunner().invoke(main, ["mosaic", str(source), "--out", str(tmp / "m"), "--workers", "1", *GRID])
    assert result.exit_code == 0, result.output
    assert "Mosaicked 4 descents of 3 frames (registered poses)" in result.output
    return source, tmp / "m"


def test_one_scan_per_descent_in_its_split_with_the_mosaics_heights(built: tuple[Path, Path]) -> None:
    source, out = built
    manifest = read_manifest(out)
    assert manifest["kind"] == "descent-mosaics" and manifest["schema_version"] == "1.4"
    assert manifest["mosaic"]["poses"] == "registered" and manifest["mosaic"]["dem"]["rows"] == DEM_SIDE
    assert manifest["n_scans"] == 4 and [s["schema_version"] for s in manifest["shards"]] == ["1.4"]
    descents = list(iter_descents(source))
    mosaics = list(iter_scans(out))
    assert [m.scan_index for m in mosaics] == [d[0].descent.descent_index for d in descents]  # type: ignore[union-attr]  # a descent build
    assert [m.split for m in mosaics] == [d[0].split for d in descents]
    for scans, m in zip(descents, mosaics, strict=True):
        frames, target = descent_frames(scans, None)
        error = navigation_error(frames[-1])
        assert m.mosaic is not None
        np.testing.assert_array_equal(m.origin_map, target)
        np.testing.assert_allclose(m.mosaic.frame_to_map, np.linalg.inv(error), atol=1e-12)
        expected = cell_points(clean_mosaic(frames, target, DEM, error), 1.0)
        np.testing.assert_array_equal(m.points_clean, expected)
        for s in range(2):
            noisy, _ = descent_frames(scans, s)
            mosaic = mosaic_frames(noisy, target, DEM, "registered")
            np.testing.assert_array_equal(m.points_noisy[s], cell_points(mosaic.heights, 1.0))
            assert mosaic.registration is not None
            np.testing.assert_array_equal(m.mosaic.registration_correction[s], mosaic.registration.corrections)
        np.testing.assert_array_equal(m.valid, np.isfinite(m.points_clean[..., 2]))


def test_the_clean_mosaic_lies_where_the_noisy_one_does_and_maps_back_to_the_ground(built: tuple[Path, Path]) -> None:
    source, out = built
    with DTM.open(source.parent / "hills.tif") as dtm:
        for m in iter_scans(out):
            assert m.mosaic is not None
            to_true = m.mosaic.frame_to_map
            clean = terrain_residual(m.points_clean[..., 2], DEM, m.origin_map, to_true, dtm)
            noisy = terrain_residual(m.points_noisy[0, ..., 2], DEM, m.origin_map, to_true, dtm)
            unmoved = terrain_residual(m.points_clean[..., 2], DEM, m.origin_map, np.eye(4), dtm)
            rms = [float(np.sqrt(np.nanmean(r**2))) for r in (clean, noisy, unmoved)]
            assert rms[0] < 0.1 and rms[1] < 0.15, rms  # the frame_to_map finds the ground under both
            assert rms[2] > 2 * rms[0], rms  # without it the mosaic is off by the navigation error


def test_a_mosaic_labels_on_its_own_heights(built: tuple[Path, Path]) -> None:
    _, out = built
    result = CliRunner().invoke(main, ["label", str(out), *GRID])
    assert result.exit_code == 0, result.output
    labelled = {s.scan_index: s for s in iter_labeled_scans(out)}
    for m in iter_scans(out):
        np.testing.assert_array_equal(labelled[m.scan_index].dem_clean, m.points_clean[..., 2])
        np.testing.assert_array_equal(labelled[m.scan_index].dem_noisy, m.points_noisy[..., 2])
    other = CliRunner().invoke(main, ["label", str(out), "--dem-size", "30", "--convention", "paper"])
    assert other.exit_code == 1
    assert "is a mosaic dataset made on 40 x 40 cells of 1.0 m" in other.output
    assert "pass --dem-size 40 --dem-spacing 1.0" in other.output


def test_the_terrain_truth_of_a_mosaic_is_read_where_frame_to_map_puts_it(tmp_path: Path) -> None:
    write_geotiff(tmp_path / "plane.tif", tilted_plane(), 1.0, (0.0, SIDE_M))  # z = 12 + 0.05 x + 0.02 y
    origin = np.array([300.0, 300.0, 33.0])
    dem = DemSpec(20, 20, 1.0, "nearest")
    shift = np.eye(4)
    shift[:3, 3] = [4.0, -2.0, 0.7]  # the lander aiming at a cell lands 4 m east and 2 m south of it
    with DTM.open(tmp_path / "plane.tif") as dtm:
        here = terrain_dem(origin, np.zeros((20, 20)), dem, dtm)
        there = terrain_dem(origin, np.zeros((20, 20)), dem, dtm, shift)
    np.testing.assert_allclose(there - here, 0.05 * 4.0 - 0.02 * 2.0, atol=1e-5)


def test_in_mosaic_frame_is_the_map_transform_seen_from_the_target() -> None:
    turn = np.eye(4)
    turn[:2, :2] = [[0.0, -1.0], [1.0, 0.0]]  # a quarter turn about the map's origin
    target = np.array([10.0, 0.0, 5.0])
    seen = in_mosaic_frame(turn, target)
    # the target itself (0 in the mosaic frame) goes to the map point (0, 10, 5), i.e. (-10, 10, 0) from the target
    np.testing.assert_allclose(seen @ [0.0, 0.0, 0.0, 1.0], [-10.0, 10.0, 0.0, 1.0])


def test_mosaics_are_the_same_bytes_with_any_worker_count(built: tuple[Path, Path], tmp_path: Path) -> None:
    source, out = built
    settings = MosaicSettings(dem_size=DEM_SIDE, convention="paper")
    mosaic_dataset(source, tmp_path / "two", settings, workers=2)
    ours = h5py.File(out / "mosaics-00000.h5")  # the label test added a labelling: compare the shards
    theirs = h5py.File(tmp_path / "two" / "mosaics-00000.h5")
    for name in ("points_clean", "points_noisy", "frame_to_map", "registration_correction"):
        np.testing.assert_array_equal(ours[name][:], theirs[name][:])
    assert read_manifest(out)["shards"] == read_manifest(tmp_path / "two")["shards"]


class Killed(Exception):
    """The stand-in for a kill (SIGTERM is raised as an exception too)."""


def _kill_after(monkeypatch: pytest.MonkeyPatch, n: int) -> list[int]:
    """Make the mosaicking of descents fail after ``n`` descents; returns the list of descents made."""
    module = importlib.import_module("hdlabels.mosaic_dataset")
    real = module.descent_mosaics
    made: list[int] = []

    def counting(*args: Any, **kwargs: Any) -> Any:
        if len(made) >= n:
            raise Killed("killed")
        made.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(module, "descent_mosaics", counting)
    return made


def _files(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()}


def test_a_killed_mosaic_resumes_per_descent_to_the_same_bytes(
    built: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """hd mosaic started again from nothing after a kill; now the descents done are kept and the
    output is byte for byte an uninterrupted run's."""
    source, out = built
    settings = MosaicSettings(dem_size=DEM_SIDE, convention="paper")
    new = tmp_path / "m"
    made = _kill_after(monkeypatch, 3)
    with pytest.raises(Killed):
        mosaic_dataset(source, new, settings, workers=1)
    assert not (new / "manifest.json").exists() and not list(new.glob("mosaics-*.h5"))
    kept = sorted(p.name for p in (new / RESUME_DIR).glob("*.npz"))
    assert kept == ["mosaics-00000.d000000.npz", "mosaics-00000.d000001.npz", "mosaics-00000.d000002.npz"]
    (new / ".mosaic.partial-1").mkdir()  # what a SIGKILL leaves: a staging directory, a partial descent
    (new / RESUME_DIR / ".mosaics-00000.d000003.npz.partial-1").write_bytes(b"half")
    made.clear()
    monkeypatch.undo()
    made = _kill_after(monkeypatch, 4)
    summary = mosaic_dataset(source, new, settings, workers=1)
    assert len(made) == 1 and summary.resumed_descents == 3 and summary.n_mosaics == 4
    assert "3 descents kept from the interrupted run" in summary.paragraph()
    assert (new / "mosaics-00000.h5").read_bytes() == (out / "mosaics-00000.h5").read_bytes()
    assert read_manifest(new)["shards"] == read_manifest(out)["shards"]
    assert read_manifest(new)["mosaic"] == read_manifest(out)["mosaic"]
    assert sorted(p.name for p in new.iterdir()) == ["manifest.json", "mosaics-00000.h5"]


def test_a_damaged_kept_descent_is_made_again(
    built: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source, out = built
    settings = MosaicSettings(dem_size=DEM_SIDE, convention="paper")
    new = tmp_path / "m"
    _kill_after(monkeypatch, 2)
    with pytest.raises(Killed):
        mosaic_dataset(source, new, settings, workers=1)
    damaged = new / RESUME_DIR / "mosaics-00000.d000001.npz"
    data = bytearray(damaged.read_bytes())
    data[len(data) // 2] ^= 0xFF  # inside an array: its CRC-32 fails
    damaged.write_bytes(bytes(data))
    monkeypatch.undo()
    made = _kill_after(monkeypatch, 4)
    summary = mosaic_dataset(source, new, settings, workers=1)
    assert len(made) == 3 and summary.resumed_descents == 2
    assert (new / "mosaics-00000.h5").read_bytes() == (out / "mosaics-00000.h5").read_bytes()


def test_a_finished_mosaic_says_so_and_other_settings_are_refused_unless_overwritten(
    built: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source, _ = built
    new = tmp_path / "m"
    args = ["mosaic", str(source), "--out", str(new), "--workers", "1", *GRID]
    assert CliRunner().invoke(main, args).exit_code == 0
    before = _files(new)
    again = CliRunner().invoke(main, args)
    assert again.exit_code == 0, again.output
    assert "already holds this mosaic dataset, made with the same settings (4 mosaics in 1 shard)" in again.output
    assert _files(new) == before
    # an unfinished run of other settings: refused in one line, kept; --overwrite starts again
    other = tmp_path / "o"
    _kill_after(monkeypatch, 1)
    with pytest.raises(Killed):
        mosaic_dataset(source, other, MosaicSettings(dem_size=DEM_SIDE, convention="paper", poses="nav"), workers=1)
    monkeypatch.undo()
    kept = _files(other / RESUME_DIR)
    refused = CliRunner().invoke(main, ["mosaic", str(source), "--out", str(other), "--workers", "1", *GRID])
    assert refused.exit_code == 1 and len(refused.output.strip().splitlines()) == 1, refused.output
    assert 'unfinished hd mosaic with other settings (poses "nav" -> "registered")' in refused.output
    assert _files(other / RESUME_DIR) == kept
    replaced = CliRunner().invoke(
        main, ["mosaic", str(source), "--out", str(other), "--workers", "1", *GRID, "--overwrite"]
    )
    assert replaced.exit_code == 0, replaced.output
    assert (other / "mosaics-00000.h5").read_bytes() == before["mosaics-00000.h5"]
    assert not (other / RESUME_DIR).exists()


def test_a_mosaic_dataset_trains_only_on_its_stored_noise_levels(built: tuple[Path, Path], tmp_path: Path) -> None:
    _, out = built
    CliRunner().invoke(main, ["label", str(out), *GRID])
    args = ["train", str(out), "--profile", "tiny", "--epochs", "1", "--out", str(tmp_path / "run")]
    refused = CliRunner().invoke(main, [*args, "--train-sigma-range", "0:0.1"])
    assert refused.exit_code == 1
    assert "a mosaic dataset's noise levels cannot be made on the fly" in refused.output
    assert not (tmp_path / "run" / "last.pt").exists()


def test_mosaic_refuses_what_is_not_a_descent_build(built: tuple[Path, Path], tmp_path: Path) -> None:
    source, out = built
    write_geotiff(tmp_path / "plane.tif", tilted_plane(), 1.0, (0.0, SIDE_M))
    single = BuildSettings(scans=2, resolution=16, sigmas_m=(0.02,), seed=2, dtm_path=str(tmp_path / "plane.tif"))
    build_dataset(tmp_path / "single", single.to_config(), workers=1)
    for src, words in (
        (tmp_path / "single", "not a descent build (its manifest records no descent_frames)"),
        (out, "already a mosaic dataset"),
    ):
        result = CliRunner().invoke(main, ["mosaic", str(src), "--out", str(tmp_path / "m"), *GRID])
        assert result.exit_code == 1 and words in result.output, result.output
        assert not (tmp_path / "m").exists()
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("mine")
    result = CliRunner().invoke(main, ["mosaic", str(source), "--out", str(tmp_path / "busy"), *GRID])
    assert result.exit_code == 1 and "holds no hd mosaic output" in result.output
    assert sorted(p.name for p in (tmp_path / "busy").iterdir()) == ["notes.txt"]
    again = CliRunner().invoke(main, ["mosaic", str(source), "--out", str(out), *GRID, "--poses", "nav"])
    assert again.exit_code == 1 and "pass --overwrite" in again.output
    inside = CliRunner().invoke(main, ["mosaic", str(source), "--out", str(source), *GRID])
    assert inside.exit_code == 1 and "descent build" in inside.output


def test_inspect_and_verify_describe_a_mosaic_dataset(built: tuple[Path, Path]) -> None:
    _, out = built
    shown = CliRunner().invoke(main, ["inspect", str(out)])
    assert shown.exit_code == 0, shown.output
    assert "mosaics   one per descent of 3 frames (registered poses), 40 x 40 cells of 1.0 m" in shown.output
    assert "sensor    None" not in shown.output
    record = json.loads(CliRunner().invoke(main, ["--json", "inspect", str(out)]).output)
    assert record["mosaic"]["poses"] == "registered"
    verified = CliRunner().invoke(main, ["verify", str(out)])
    assert verified.exit_code == 0 and "OK" in verified.output


def test_frames_picks_the_frames_and_one_frame_is_the_frame_as_its_navigation_places_it(
    built: tuple[Path, Path], tmp_path: Path
) -> None:
    source, _ = built
    result = CliRunner().invoke(main, ["mosaic", str(source), "--out", str(tmp_path / "low"), "--frames", "2", *GRID])
    assert result.exit_code == 0, result.output
    assert "4 descents of 3 frames, frames 2 (registered poses)" in result.output
    assert "registration moved" not in result.output  # one frame: nothing to register
    manifest = read_manifest(tmp_path / "low")
    assert manifest["mosaic"]["frames"] == [2] and manifest["mosaic"]["anchor_frame"] == 2
    for scans, m in zip(iter_descents(source), iter_scans(tmp_path / "low"), strict=True):
        frames, target = descent_frames(scans, None)
        placed = placed_points(frames[2], target, "nav")  # the lowest frame where its navigation puts it
        alone = grid_points(placed, (DEM_SIDE, DEM_SIDE), 1.0, method="nearest")
        np.testing.assert_allclose(m.points_clean[..., 2], alone, atol=1e-4)
        assert m.mosaic is not None and m.mosaic.registration_correction.shape == (2, 1, 4, 4)
    two = mosaic_dataset(source, tmp_path / "two", MosaicSettings(dem_size=DEM_SIDE, convention="paper", frames="0,2"))
    assert two.frames == (0, 2)
    with h5py.File(tmp_path / "two" / "mosaics-00000.h5") as f:
        assert f.attrs["mosaic_frame_indices"].tolist() == [0, 2] and f.attrs["mosaic_anchor_frame"] == 2
        assert f["registration_fitness"].shape == (4, 2, 2)


@pytest.mark.parametrize(
    ("frames", "words"),
    [
        ("3", "--frames '3': 3 is not frames of a descent of 3 frames; use frame indices and ranges of 0..2"),
        ("2-1", "2-1 is not frames of a descent of 3 frames"),
        ("x", "--frames 'x': frame"),
        ("1,", "--frames '1,': frame"),
    ],
)
def test_frames_outside_the_descent_are_refused_in_one_line(
    built: tuple[Path, Path], tmp_path: Path, frames: str, words: str
) -> None:
    source, _ = built
    result = CliRunner().invoke(main, ["mosaic", str(source), "--out", str(tmp_path / "m"), "--frames", frames, *GRID])
    assert result.exit_code == 1 and words in result.output, result.output
    assert len(result.output.strip().splitlines()) == 1 and not (tmp_path / "m").exists()


def test_a_network_trains_evaluates_and_maps_on_mosaics(built: tuple[Path, Path], tmp_path: Path) -> None:
    _, out = built
    for truth in ("terrain", "clean-scan"):
        labelled = CliRunner().invoke(main, ["label", str(out), *GRID, "--truth", truth])
        assert labelled.exit_code == 0, labelled.output
    run = tmp_path / "run"
    trained = CliRunner().invoke(
        main,
        [
            "train",
            str(out),
            "--profile",
            "tiny",
            "--epochs",
            "1",
            "--labels",
            "paper+terrain",
            "--train-sigma",
            "0.02",
            "--out",
            str(run),
        ],
    )
    assert trained.exit_code == 0, trained.output
    report = tmp_path / "eval"
    evaluated = CliRunner().invoke(
        main, ["eval", str(run), "--data", str(out), "--out", str(report), "--nav-sigma", "1", "--mc-samples", "2"]
    )
    assert evaluated.exit_code == 0, evaluated.output
    landing = json.loads((report / "report.json").read_text())["landing"]
    assert {row["truth"] for row in landing} == {"terrain", "clean-scan"}  # both truths, on the test mosaic
    assert {row["scenes"] for row in landing} == {1}  # one test descent: one scene per noise level
    test = next(m for m in iter_scans(out) if m.split == "test")
    detected = CliRunner().invoke(
        main,
        [
            "detect",
            str(run),
            "--data",
            str(out),
            "--scan",
            str(test.scan_index),
            "--out",
            str(tmp_path / "d"),
            "--mc-samples",
            "2",
        ],
    )
    assert detected.exit_code == 0, detected.output
    assert (tmp_path / "d" / "p_safe.tif").is_file()
