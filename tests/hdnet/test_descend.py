"""``hd descend`` (``hdnet.descend``, ``hdnet.descent_flight``): descents flown frame by frame, whose last
frame is the offline ``hd mosaic`` + ``hd detect`` result, and whose aim diverts from ground that turns
out unsafe."""

from __future__ import annotations

import html
import importlib
import json
import re
import shutil
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from scipy import ndimage

from hdcli.cli import main
from hdcore.errors import HdWarning
from hdlabels.lander import Lander
from hdlabels.mosaic import descent_frames
from hdnet.descent_flight import REASON_NO_MAP, FrameStep, aim_is_safe, fly, retarget
from hdnet.detect import DetectMaps, centred_transform, load_run
from hdnet.detect_json import input_name
from hdnet.detect_settings import DetectSettings
from hdnet.sites import SAFETY_SAFE, SAFETY_UNSAFE, select_sites
from hdnet.view import view
from lidarsim.build import build_dataset
from lidarsim.errors import TerrainError
from lidarsim.recipe import BuildSettings
from lidarsim.shards import iter_descents, iter_scans
from tests.geotiff import write_geotiff

DEM_SIDE = 40
GRID = ["--dem-size", str(DEM_SIDE), "--convention", "paper"]  # nearest gridding, 1 m cells
QUICK = ["--mc-samples", "2", "--threshold", "nats:1"]  # an untrained network: no cell uncertain


def hills(side: int = 600) -> np.ndarray:
    """Seeded smooth relief with rocks around the middle, 1 m cells, metres."""
    rng = np.random.default_rng(5)
    z = ndimage.gaussian_filter(rng.normal(0.0, 1.0, (side, side)), 15)
    z = z / z.std() * 3.0
    rocks = np.zeros((side, side))
    idx = rng.integers(200, 400, (200, 2))
    rocks[idx[:, 0], idx[:, 1]] = 1.0
    return z + ndimage.gaussian_filter(rocks, 1.2) * 6.0


def invoke(*args: str) -> str:
    result = CliRunner().invoke(main, list(args))
    assert result.exit_code == 0, result.output
    return result.output


@pytest.fixture(scope="module")
def flown(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A descent build (four descents of three frames, 300 m to 150 m, 1 m / 0.1 degree navigation error),
    its registered mosaics, labelled, a tiny run trained on them, and the test descent flown."""
    tmp = tmp_path_factory.mktemp("descend")
    write_geotiff(tmp / "hills.tif", hills(), 1.0, (0.0, 600.0))
    settings = BuildSettings(
        scans=4,
        descent_frames=3,
        descent_altitudes_m="300:150",
        resolution=48,
        sigmas_m=(0.02,),
        seed=3,
        dtm_path=str(tmp / "hills.tif"),
        nav_position_sigma_m=1.0,
        nav_attitude_sigma_deg=0.1,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", HdWarning)  # coarse sensor, neighbouring descents share ground
        build_dataset(tmp / "source", settings.to_config(), workers=1)
    invoke("mosaic", str(tmp / "source"), "--out", str(tmp / "mosaics"), "--workers", "1", *GRID)
    invoke("label", str(tmp / "mosaics"), *GRID)
    invoke("train", str(tmp / "mosaics"), "--profile", "tiny", "--epochs", "1", "--out", str(tmp / "run"))
    test = next(m.scan_index for m in iter_scans(tmp / "mosaics") if m.split == "test")
    out = invoke(
        "--json",
        "--no-progress",
        "descend",
        str(tmp / "run"),
        "--data",
        str(tmp / "source"),
        "--descent",
        str(test),
        "--out",
        str(tmp / "online"),
        *QUICK,
    )
    summary = json.loads(out)  # hd --json: the record of descend.json
    assert summary["command"] == "descend" and [d["descent"] for d in summary["descents"]] == [test]
    assert summary["descents"] == json.loads((tmp / "online" / "descend.json").read_text())["descents"]
    return {
        "tmp": tmp,
        "source": tmp / "source",
        "mosaics": tmp / "mosaics",
        "run": tmp / "run",
        "online": tmp / "online",
        "test": Path(str(test)),
    }


def test_the_last_frame_is_the_offline_mosaic_and_its_detect_maps(flown: dict[str, Path]) -> None:
    test = int(str(flown["test"]))
    online = flown["online"]
    last = np.load(online / f"descent-{test:05d}-frame-02.npz")
    mosaic = next(m for m in iter_scans(flown["mosaics"]) if m.scan_index == test)
    assert last["heights_m"].tobytes() == mosaic.points_noisy[0, ..., 2].tobytes()  # byte-identical heights
    offline = flown["tmp"] / "offline"
    invoke(
        "detect", str(flown["run"]), "--data", str(flown["mosaics"]), "--scan", str(test), "--out", str(offline), *QUICK
    )
    for field, name in (
        ("p_safe", "p_safe.tif"),
        ("entropy_nats", "entropy.tif"),
        ("safety", "safety.tif"),
        ("mutual_information_nats", "mutual_information.tif"),
        ("baseline_p_safe", "baseline_p_safe.tif"),
    ):
        with rasterio.open(offline / name) as src:
            np.testing.assert_array_equal(last[field], src.read(1), err_msg=name)
    info = json.loads((offline / "detect.json").read_text())
    sites = info["sites"]
    # A mosaic is called so, with its frames, not a scan: in detect.json and on hd view's page.
    assert info["input"]["mosaic_frames"] == 3 and input_name(info["input"]) == f"mosaic {test} (3 frames)"
    page = flown["tmp"] / "offline-view.html"
    invoke("view", str(offline), "--out", str(page))
    text = html.unescape(page.read_text(encoding="utf-8"))
    assert f"mosaic {test} (3 frames) (test split)" in text and f"scan {test} " not in text
    record = json.loads((online / "descend.json").read_text())
    assert record["descents"][0]["frames"][-1]["n_sites"] == len(sites)
    columns = [str(c) for c in last["site_columns"]]
    assert sites and np.isfinite(last["p_safe"]).mean() > 0.3  # a map with valid cells and sites to compare
    for row, site in zip(last["sites"], sites, strict=True):
        assert {c: float(v) for c, v in zip(columns, row, strict=True)} == pytest.approx(site, nan_ok=True)
    earlier = np.load(online / f"descent-{test:05d}-frame-00.npz")["heights_m"]
    assert earlier.tobytes() != last["heights_m"].tobytes()  # the mosaic grew frame by frame


def test_the_record_has_every_frame_its_seconds_and_the_settings(flown: dict[str, Path]) -> None:
    test = int(str(flown["test"]))
    record = json.loads((flown["online"] / "descend.json").read_text())
    (descent,) = record["descents"]
    assert descent["descent"] == test and descent["split"] == "test"
    assert [f["frame"] for f in descent["frames"]] == [0, 1, 2]
    altitudes = [f["altitude_m"] for f in descent["frames"]]
    assert altitudes == sorted(altitudes, reverse=True) and 140 < altitudes[-1] < 160
    for frame in descent["frames"]:
        assert set(frame["timings_s"]) == {"registration", "mosaic", "map", "sites"}
        assert all(v >= 0 for v in frame["timings_s"].values())
        assert len(frame["registration_fitness"]) == frame["frame"] + 1  # every frame so far, registered again
    assert record["settings"]["mc_samples"] == 2 and record["input"]["poses"] == "registered"
    assert record["input"]["dem"] == {"rows": DEM_SIDE, "cols": DEM_SIDE, "spacing_m": 1.0, "gridding": "nearest"}
    for divert in descent["diverts"]:
        assert divert["distance_m"] > 0 and len(divert["old"]) == 2 and len(divert["new"]) == 2
    track = json.loads((flown["online"] / f"descent-{test:05d}-track.geojson").read_text())
    points = [f for f in track["features"] if f["geometry"]["type"] == "Point"]
    (line,) = [f for f in track["features"] if f["geometry"]["type"] == "LineString"]
    assert line["geometry"]["coordinates"] == [p["geometry"]["coordinates"] for p in points]
    written = sorted(p.name for p in flown["online"].iterdir() if not p.name.startswith("."))
    assert written == sorted([*descent["files"], "descend.json"])


def lander() -> Lander:
    return Lander(diameter_m=4.0, pad_diameter_m=1.0)


def maps_of(safety: np.ndarray) -> DetectMaps:
    """Hand-made maps: P(safe) 0.9 on safe cells, 0.1 elsewhere; the sites as hd detect chooses them."""
    p = np.where(safety == SAFETY_SAFE, 0.9, 0.1).astype(np.float32)
    h = np.zeros_like(p)
    transform = centred_transform(safety.shape, 1.0)
    sites = select_sites(safety, p, h, p, transform, (1.0, 1.0), lander(), 5)
    return DetectMaps(p, h, h, safety, p, sites, 0.5, "entropy", 0.02, transform)


def test_a_detection_names_its_input_a_dtm_a_scan_or_a_mosaic_of_frames() -> None:
    assert input_name({"kind": "dtm", "name": "jezero.tif"}) == "jezero.tif"
    assert input_name({"kind": "scan", "scan_index": 19}) == "scan 19"
    assert input_name({"kind": "scan", "scan_index": 19, "mosaic_frames": 9}) == "mosaic 19 (9 frames)"


def test_a_hazard_seen_under_the_aim_makes_the_lander_divert_and_only_then() -> None:
    safety = np.full((30, 30), SAFETY_SAFE, np.uint8)
    first = maps_of(safety)
    aim, diverted = retarget(None, first.sites, first.safety, first.transform, lander())
    assert aim is first.sites[0] and not diverted
    rock = safety.copy()
    rock[aim.row - 1 : aim.row + 2, aim.col] = SAFETY_UNSAFE  # a rock under the aim, seen from lower down
    elsewhere = safety.copy()
    elsewhere[0:3, 0:3] = SAFETY_UNSAFE
    held, moved = retarget(aim, maps_of(elsewhere).sites, elsewhere, first.transform, lander())
    assert held is not None and not moved and (held.x, held.y) == (aim.x, aim.y)  # a hazard elsewhere: held
    second = maps_of(rock)
    new, moved = retarget(aim, second.sites, rock, second.transform, lander())
    assert new is not None and moved and new is second.sites[0]
    assert not aim_is_safe(aim, rock, second.transform, lander()) and aim_is_safe(new, rock, second.transform, lander())
    assert np.hypot(new.x - aim.x, new.y - aim.y) >= 2.0  # at least a lander radius away from the rock


def test_fly_records_the_divert_with_its_distance(flown: dict[str, Path], monkeypatch: pytest.MonkeyPatch) -> None:
    """Frame 0's map is all safe; from frame 1 on a rock lies under frame 0's aim: one divert, after frame 1."""
    safety = np.full((DEM_SIDE, DEM_SIDE), SAFETY_SAFE, np.uint8)
    first = maps_of(safety)
    a = first.sites[0]
    rock = safety.copy()
    rock[a.row - 1 : a.row + 2, a.col - 1 : a.col + 2] = SAFETY_UNSAFE
    later = maps_of(rock)
    calls: list[int] = []

    def stub(*args: object, timings: dict[str, float], **kwargs: object) -> DetectMaps:
        timings |= {"map": 0.0, "sites": 0.0}
        calls.append(1)
        return first if len(calls) == 1 else later

    module = importlib.import_module("hdnet.descent_flight")
    monkeypatch.setattr(module, "map_heights", stub)
    run = load_run(flown["run"], "cpu")
    scans = next(iter(iter_descents(flown["source"])))
    frames, target = descent_frames(scans, 0)
    settings = DetectSettings(mc_samples=2)
    steps: list[FrameStep] = fly(run, frames, target, run.labeling.dem, "nav", settings, (0.5, {}))
    assert [s.divert is not None for s in steps] == [False, True, False]
    divert = steps[1].divert
    assert divert is not None and divert.frame == 1 and divert.old == (a.x, a.y)
    assert divert.new == (later.sites[0].x, later.sites[0].y)
    assert divert.distance_m == pytest.approx(np.hypot(divert.new[0] - a.x, divert.new[1] - a.y))
    assert divert.elapsed_s >= 0 and divert.altitude_m > steps[2].altitude_m
    assert steps[2].aim is not None and (steps[2].aim.x, steps[2].aim.y) == divert.new  # held afterwards


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--descent", "9"], "descent 9 is not in"),
        (["--descent", "x"], "--descent 'x' is not"),
        ([], "give --descent K"),
        (["--descent", "1", "--split", "test"], "--split goes with --descent all"),
    ],
)
def test_bad_descents_are_refused_in_one_line_and_nothing_is_written(
    flown: dict[str, Path], tmp_path: Path, args: list[str], words: str
) -> None:
    result = CliRunner().invoke(
        main, ["descend", str(flown["run"]), "--data", str(flown["source"]), "--out", str(tmp_path / "d"), *args]
    )
    assert result.exit_code == 1 and words in result.output, result.output
    assert len(result.output.strip().splitlines()) == 1 and not (tmp_path / "d").exists()


def test_what_is_not_a_descent_build_or_a_mosaic_run_is_refused(flown: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "d"
    for data, words in ((flown["mosaics"], "is a mosaic dataset"), (tmp_path, "is not a dataset")):
        result = CliRunner().invoke(
            main, ["descend", str(flown["run"]), "--data", str(data), "--descent", "0", "--out", str(out)]
        )
        assert result.exit_code == 1 and words in result.output, result.output
        assert len(result.output.strip().splitlines()) == 1 and not out.exists()
    scans = tmp_path / "scans"
    shutil.copytree(flown["source"], scans)
    invoke("label", str(scans), *GRID)  # the frames labelled as single scans
    single = tmp_path / "single-run"
    invoke("train", str(scans), "--profile", "tiny", "--epochs", "1", "--out", str(single))
    result = CliRunner().invoke(
        main, ["descend", str(single), "--data", str(flown["source"]), "--descent", "0", "--out", str(out)]
    )
    assert result.exit_code == 1 and "holds single scans, not descent mosaics" in result.output, result.output
    assert len(result.output.strip().splitlines()) == 1 and not out.exists()


def test_a_frame_without_a_map_is_recorded_and_the_descent_goes_on(
    flown: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Frame 0's mosaic has no lander-sized valid square (TerrainError, as map_heights raises it): the frame
    is recorded without a map, the aim is the next frame's best site, the last frame is as before; an
    unfinished run is said as hd detect says it; the plain summary line."""
    module = importlib.import_module("hdnet.descent_flight")
    real = module.map_heights
    calls: list[int] = []

    def first_has_no_room(*args: Any, **kwargs: Any) -> DetectMaps:
        calls.append(1)
        if len(calls) == 1:
            raise TerrainError("the height array is too small for the lander footprint")
        return real(*args, **kwargs)

    monkeypatch.setattr(module, "map_heights", first_has_no_room)
    partial = tmp_path / "run"
    shutil.copytree(flown["run"], partial)
    config = json.loads((partial / "config.json").read_text())
    (partial / "config.json").write_text(json.dumps(config | {"epochs": 10}))
    test = int(str(flown["test"]))
    out = tmp_path / "d"
    args = ["--no-progress", "descend", str(partial), "--data", str(flown["source"]), "--descent", str(test)]
    result = CliRunner().invoke(main, [*args, "--out", str(out), *QUICK])
    assert result.exit_code == 0, result.output
    lines = result.output.strip().splitlines()
    assert any(line.startswith("Warning: ") and "1 of its 10 epochs trained" in line for line in lines), lines
    summary = next(line for line in lines if line.startswith(f"descent {test}: "))
    pattern = (
        rf"descent {test}: 3 frames \(1 without a map: 0\), (\d+) divert\(s\)( \(.*\))?; final site "
        r"\((-?\d+\.\d), (-?\d+\.\d)\) m from the target, P\(safe\) (\d\.\d{3}); (\d+\.\d\d) s per frame \(median\)"
    )
    match = re.fullmatch(pattern, summary)
    assert match is not None, summary
    assert lines[-1] == f"per-frame maps (.npz), site tracks (.geojson) and descend.json in {out}"
    (descent,) = json.loads((out / "descend.json").read_text())["descents"]
    first, *later = descent["frames"]
    assert first["no_map"].startswith(REASON_NO_MAP) and "too small for the lander footprint" in first["no_map"]
    assert first["aim"] is None and first["counts"] is None and first["n_sites"] == 0 and first["divert"] is None
    assert all(f["no_map"] is None and f["counts"] for f in later) and later[0]["aim"] is not None
    assert int(match.group(1)) == len(descent["diverts"])
    final = descent["final_site"]
    assert (match.group(3), match.group(4), match.group(5)) == (
        f"{final['x']:.1f}",
        f"{final['y']:.1f}",
        f"{final['p_safe']:.3f}",
    )
    frame0 = np.load(out / f"descent-{test:05d}-frame-00.npz")
    assert set(frame0.files) == {"heights_m", "transform", "sites", "site_columns"} and frame0["sites"].shape == (0, 8)
    before = np.load(flown["online"] / f"descent-{test:05d}-frame-00.npz")
    assert frame0["heights_m"].tobytes() == before["heights_m"].tobytes()
    np.testing.assert_array_equal(frame0["transform"], before["transform"])  # the grid its maps would have had
    last = f"descent-{test:05d}-frame-02.npz"
    assert np.load(out / last)["p_safe"].tobytes() == np.load(flown["online"] / last)["p_safe"].tobytes()
    page = view(out).path.read_text()  # the page of a descent with a frame without a map, beside it
    assert html.escape("N" + REASON_NO_MAP[1:]) in page


def test_the_page_of_a_descent_flown_has_its_frames_and_its_track(flown: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "online"
    shutil.copytree(flown["online"], out)
    result = CliRunner().invoke(main, ["view", str(out)])
    assert result.exit_code == 0, result.output
    assert "hd descend output, 1 descent(s), 3 frames, images 40 x 40 px" in result.output
    raw = (tmp_path / "online-view.html").read_text(encoding="utf-8")
    test = int(str(flown["test"]))
    record = json.loads((out / "descend.json").read_text())
    assert str(flown["tmp"]) not in raw and record["run"]["checkpoint"] not in raw  # no absolute path
    section = raw[raw.index(f'<section class="descent" id="descent-{test}"') :]
    assert section.count('<div class="frame" data-frame=') == 3
    aims = [f for f in record["descents"][0]["frames"] if f["aim"] is not None]
    last_track = section[section.index('data-frame="2"') :]
    assert last_track.count('class="track-point"') == len(aims) == 3  # every frame has an aim
    assert record["lander"]["diameter_m"] > 0 and record["descents"][0]["frames"][0]["no_map"] is None
