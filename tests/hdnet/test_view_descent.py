"""hd view of an hd descend output: the page of a hand-made descent (its files written by hd descend's own
writers from frames made by hand), parsed as HTML and stepped through in headless Chromium; damaged
outputs refused.

The descent: 30 x 30 cells of 1 m, three frames. Frame 0 saw only a 6 x 6 patch (no map: the aim none);
frame 1 a 20 x 20 patch, all safe (the aim: its best site); frame 2 the whole grid, with a rock under
that aim: a divert to frame 2's best site. A second descent (index 7) is frame 2 alone, twice.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner
from headless_chromium import Browser, browser_or_skip
from test_view import Page, check_self_contained, csp_of, png_of, settings_of, sha256_source

from hdcli.cli import main
from hdcore.errors import DamagedFileError
from hdcore.storage import write_json_atomic
from hdlabels.lander import Lander
from hdnet.descend import descent_record, track_geojson, write_descent
from hdnet.descend_json import DescendJson, frame_file, track_file
from hdnet.descent_flight import REASON_NO_MAP, Divert, FrameStep, FrameTiming
from hdnet.detect import DetectMaps, centred_transform
from hdnet.errors import HdNetError
from hdnet.sites import SAFETY_INVALID, SAFETY_SAFE, SAFETY_UNSAFE, select_sites
from hdnet.view import view
from hdnet.view_images import safety_rgba

ROOT = Path(__file__).resolve().parents[2]
SIDE = 30
LANDER = Lander(diameter_m=4.0, pad_diameter_m=1.0)


def patch(half: int) -> np.ndarray:
    """Heights (metres) valid in the centred square of side 2 * half, NaN elsewhere: a gentle slope."""
    z = np.full((SIDE, SIDE), np.nan, np.float32)
    c = SIDE // 2
    z[c - half : c + half, c - half : c + half] = np.add.outer(np.arange(2 * half), np.arange(2 * half)) * 0.01
    return z


def maps_of(safety: np.ndarray) -> DetectMaps:
    """Hand-made maps: P(safe) 0.9 on safe cells, 0.1 elsewhere, entropy 0.2 nats where valid; the sites as
    hd detect chooses them."""
    valid = safety != SAFETY_INVALID
    p = np.where(valid, np.where(safety == SAFETY_SAFE, 0.9, 0.1), np.nan).astype(np.float32)
    h = np.where(valid, 0.2, np.nan).astype(np.float32)
    transform = centred_transform(safety.shape, 1.0)
    sites = select_sites(safety, p, h, p, transform, (1.0, 1.0), LANDER, 3)
    return DetectMaps(p, h, h, safety, p, sites, 0.5, "entropy", 0.02, transform)


def steps_of_a_descent() -> list[FrameStep]:
    timing = FrameTiming(0.5, 0.02, 1.25, 0.001)
    first = np.full((SIDE, SIDE), SAFETY_INVALID, np.uint8)
    first[5:25, 5:25] = SAFETY_SAFE
    one = maps_of(first)
    aim = one.sites[0]
    rock = np.full((SIDE, SIDE), SAFETY_SAFE, np.uint8)
    rock[aim.row - 1 : aim.row + 2, aim.col - 1 : aim.col + 2] = SAFETY_UNSAFE
    two = maps_of(rock)
    new = two.sites[0]
    divert = Divert(2, 3.5, 150.0, (aim.x, aim.y), (new.x, new.y), math.hypot(new.x - aim.x, new.y - aim.y), "unsafe")
    why = f"{REASON_NO_MAP}: the height array has no such valid square"
    return [
        FrameStep(0, 300.0, patch(3), None, None, None, timing, no_map=why),
        FrameStep(1, 225.0, patch(10), one, aim, None, timing),
        FrameStep(2, 150.0, patch(15), two, new, divert, timing),
    ]


def write_output(out: Path) -> DescendJson:
    """A descend output of two descents (3 and 7) in ``out``, written by hd descend's writers."""
    out.mkdir()
    steps = steps_of_a_descent()
    last = steps[2]
    other = [
        FrameStep(k, altitude, last.heights, last.maps, last.aim, None, last.timing)
        for k, altitude in enumerate((120.0, 100.0))
    ]
    write_descent(out, 3, steps, 1.0)
    write_descent(out, 7, other, 1.0)
    record: DescendJson = {
        "software": "hd",
        "software_version": "test",
        "run": {"checkpoint": str(out.parent / "somewhere" / "run" / "last.pt"), "dataset": None, "labels": "paper"},
        "input": {
            "dataset": str(out.parent / "somewhere" / "descents"),
            "sigma_m": 0.02,
            "poses": "registered",
            "dem": {"rows": SIDE, "cols": SIDE, "spacing_m": 1.0, "gridding": "nearest"},
        },
        "lander": {"diameter_m": LANDER.diameter_m, "pad_diameter_m": LANDER.pad_diameter_m},
        "settings": {"descent": "all", "mc_samples": 2, "threshold": "nats:0.5", "device": None},
        "threshold": {"kind": "fixed", "spec": "nats:0.5", "value_nats": 0.5},
        "frame": "metres east and north of each descent's target",
        "timing_steps": ["registration", "mosaic", "map", "sites"],
        "descents": [descent_record(3, "test", steps), descent_record(7, "test", other)],
        "seconds": 9.0,
    }
    write_json_atomic(out / "descend.json", json.loads(json.dumps(record)))
    return record


@pytest.fixture
def output(tmp_path: Path) -> Path:
    out = tmp_path / "descend-out"
    write_output(out)
    return out


def descent_of(page: Page, index: int) -> Any:
    return page.root.find("section", id=f"descent-{index}")


def test_a_descent_page_has_every_frame_its_track_and_its_settings(output: Path) -> None:
    before = sorted(p.name for p in output.iterdir())
    result = view(output)
    assert result.kind == "descend" and result.path == output.parent / f"{output.name}-view.html"
    assert sorted(p.name for p in output.iterdir()) == sorted(before)  # the output untouched: the page beside it
    raw = result.path.read_text(encoding="utf-8")
    page = Page(raw)
    check_self_contained(page, raw)
    assert str(output.parent) not in raw and "/somewhere/" not in raw  # no absolute path on the page
    assert result.info["frames"] == 5 and result.info["descents"] == [3, 7] and result.info["diverts"] == 1
    section = descent_of(page, 3)
    frames = section.find_all("div", class_="frame")
    assert [f.attrs["data-frame"] for f in frames] == ["0", "1", "2"]
    assert ["hidden" in f.attrs for f in frames] == [True, True, False]  # the last frame shown first
    slider = section.find("input", class_="frame-slider")
    assert (slider.attrs["min"], slider.attrs["max"], slider.attrs["value"]) == ("0", "2", "2")
    # Frame 0 has no map: its hillshade and why; the others the detect page's layers.
    layers = [sorted(i.attrs["class"].split()[1] for i in f.find_all("img")) for f in frames]
    assert layers[0] == ["layer-hillshade"] and layers[1] == layers[2] == sorted(
        ["layer-hillshade", "layer-safety", "layer-p_safe", "layer-entropy"]
    )
    assert frames[0].find("p", class_="no-map").text().startswith("N" + REASON_NO_MAP[1:])
    # The mosaic grows: frame 0's hillshade is opaque on its 6 x 6 cells only, frame 2's everywhere.
    shades = [png_of(f.find("img", class_="layer layer-hillshade").attrs["src"]) for f in frames]
    assert [int((s[..., 3] > 0).sum()) for s in shades] == [36, 400, 900]
    # The safety layer is the frame's safety map in the detect page's colours.
    safety = np.load(output / frame_file(3, 2))["safety"]
    np.testing.assert_array_equal(
        png_of(frames[2].find("img", class_="layer layer-safety").attrs["src"]), safety_rgba(safety)
    )
    # The track: the aims so far (none after frame 0, one after frame 1, two after frame 2), one divert.
    track = json.loads((output / track_file(3)).read_text())
    points = [f for f in track["features"] if f["geometry"]["type"] == "Point"]
    assert [p["properties"]["frame"] for p in points] == [1, 2]
    svgs = [f.find("svg", class_="layer layer-track") for f in frames]
    assert [len(s.find_all("circle", class_="track-point")) for s in svgs] == [0, 1, 2]
    assert [len(s.find_all("polygon", class_="divert-head")) for s in svgs] == [0, 0, 1]
    (aim,) = svgs[2].find_all("circle", class_="aim-ring")
    x, y = points[1]["geometry"]["coordinates"]
    assert (float(aim.attrs["cx"]), float(aim.attrs["cy"]), float(aim.attrs["r"])) == pytest.approx((x, -y, 2.0))
    record = json.loads((output / "descend.json").read_text())
    distance = record["descents"][0]["diverts"][0]["distance_m"]
    assert svgs[2].find("text", class_="divert-label").text() == f"frame 2: {distance:.1f} m"
    # The table of frames: one row per frame, its altitude, seconds, aim and divert.
    rows = page.table_rows(section.find("table", id="frames-3"))
    assert [r[:2] for r in rows] == [["0", "300.0"], ["1", "225.0"], ["2", "150.0"]]
    assert rows[1][2:7] == ["0.500", "0.020", "1.250", "0.001", "1.771"]
    assert rows[0][7:10] == ["--", "--", "--"] and rows[0][-1].startswith(REASON_NO_MAP)
    assert rows[2][7:9] == [f"{x:.1f}", f"{y:.1f}"] and rows[2][-1].startswith(f"{distance:.1f} m from (")
    assert len(descent_of(page, 7).find_all("div", class_="frame")) == 2
    settings = settings_of(page)
    assert settings["threshold"] == "nats:0.5: H_t = 0.5000 nats" and settings["run"].startswith("run/last.pt ")
    assert settings["descent build"] == "descents" and settings["--mc-samples"] == "2"
    assert "H_t 0.5000 nats" in page.root.find(id="lead").text()


def test_the_policy_allows_the_descent_pages_own_script_and_style_only(output: Path) -> None:
    page = Page(view(output).path.read_text(encoding="utf-8"))
    policy = csp_of(page)
    (script,), (style,) = page.root.find_all("script"), page.root.find_all("style")
    assert policy["script-src"] == sha256_source(script.text()) and "section.descent" in script.text()
    assert policy["style-src"] == sha256_source(style.text()) and ".descent-map" in style.text()
    assert "unsafe-inline" not in " ".join(policy.values())


@pytest.mark.parametrize(
    ("damage", "error", "needle"),
    [
        (lambda o: (o / "descend.json").write_text("[1]"), HdNetError, "not an hd descend output"),
        (lambda o: (o / frame_file(3, 1)).write_bytes(b"PK\x03\x04 cut"), DamagedFileError, "unreadable"),
        (lambda o: (o / frame_file(3, 2)).unlink(), DamagedFileError, "missing, and descend.json lists it"),
        (lambda o: (o / track_file(7)).write_text(json.dumps(track_geojson([]))), DamagedFileError, "0 point(s)"),
        (
            lambda o: np.savez(o / frame_file(3, 2), heights_m=np.zeros((4, 4))),
            DamagedFileError,
            "no transform, sites, site_columns, p_safe",
        ),
    ],
)
def test_a_damaged_descent_output_is_one_line_and_nothing_is_written(
    output: Path, damage: Any, error: type[Exception], needle: str
) -> None:
    damage(output)
    with pytest.raises(error, match=re.escape(needle)):
        view(output)
    assert not (output / "view.html").exists() and not (output.parent / f"{output.name}-view.html").exists()
    result = CliRunner().invoke(main, ["view", str(output)])
    assert result.exit_code == 1 and len(result.output.strip().splitlines()) == 1, result.output


def test_hd_view_of_a_descent_says_what_it_wrote_without_the_network_library(output: Path) -> None:
    code = (
        "import sys\nfrom hdcli.cli import main\ntry:\n    main(['view', sys.argv[1], '--max-px', '64'])\n"
        "except SystemExit as exc:\n    assert exc.code == 0, exc.code\nassert 'torch' not in sys.modules\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code, str(output)], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert "hd descend output, 2 descent(s), 5 frames, images 30 x 30 px" in done.stdout
    result = CliRunner().invoke(main, ["view", str(output), "--dtm", str(output / "descend.json")])
    assert result.exit_code == 1 and "is an hd descend output" in result.output


# ------------------------------------------------------------------------------------------ browser
@pytest.fixture(scope="module")
def browser() -> Any:
    chromium = browser_or_skip()
    yield chromium
    chromium.close()


def shown_frame(chromium: Browser, index: int) -> list[str]:
    """The frames of descent ``index`` that are displayed (their data-frame)."""
    return chromium.run(
        "return Array.prototype.filter.call(document.querySelectorAll('#descent-' + arguments[0] + ' .frame'), "
        "function (f) { return getComputedStyle(f).display !== 'none' && f.offsetWidth > 0; })"
        ".map(function (f) { return f.dataset.frame; });",
        index,
    )


def test_stepping_through_frames_in_a_real_browser(browser: Browser, output: Path) -> None:
    path = view(output).path
    browser.get(path.as_uri())
    assert browser.run("return document.readyState") == "complete"
    assert shown_frame(browser, 3) == ["2"] and shown_frame(browser, 7) == ["1"]
    label = "return document.querySelector('#descent-3 .frame-label').textContent"
    assert browser.run(label).startswith("frame 2 of 2")
    browser.click("#descent-3 button.frame-step[data-step='-1']")
    assert shown_frame(browser, 3) == ["1"] and browser.run(label).startswith("frame 1 of 2")
    browser.click("#descent-3 button.frame-step[data-step='-1']")
    assert shown_frame(browser, 3) == ["0"] and "no map" in browser.run(label)
    browser.click("#descent-3 button.frame-step[data-step='-1']")  # stays at the first frame
    assert shown_frame(browser, 3) == ["0"]
    browser.run("var s = document.getElementById('frame-slider-3'); s.value = 2; s.dispatchEvent(new Event('input'));")
    assert shown_frame(browser, 3) == ["2"] and shown_frame(browser, 7) == ["1"]  # the other descent untouched
    browser.click("#frames-3 tbody tr:nth-child(2)")  # a row shows its frame
    assert shown_frame(browser, 3) == ["1"]
    assert browser.run("return document.querySelector('#frames-3 tr.selected').dataset.frame") == "1"
    # The shown frame's images are decoded at their size and fill the map.
    loaded = browser.run(
        "var i = document.querySelector('#descent-3 .frame[data-frame=\"1\"] img.layer-hillshade');"
        "var m = document.getElementById('descent-map-3').getBoundingClientRect(), r = i.getBoundingClientRect();"
        "return [i.complete, i.naturalWidth, Math.round(r.width - m.width + 2), m.height > 100];"
    )
    assert loaded == [True, SIDE, 0, True]
    # A layer's checkbox hides that layer in every frame of its descent only.
    browser.click("#toggle-safety-3")
    hidden = (
        "return Array.prototype.map.call(document.querySelectorAll(arguments[0]), "
        "function (i) { return getComputedStyle(i).display === 'none'; });"
    )
    assert browser.run(hidden, "#descent-3 img.layer-safety") == [True, True]
    assert browser.run(hidden, "#descent-7 img.layer-safety") == [False, False]
    assert [e for e in browser.console() if e["level"] in ("SEVERE", "WARNING")] == []
