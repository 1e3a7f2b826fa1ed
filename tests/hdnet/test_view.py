"""hd view: the self-contained page of a detect output and of a report, parsed as HTML; bad input.

The outputs are real: the tiny dataset (``hdnet_datasets``), a run trained one epoch on it, a
*constant* run made from it (its classifier ignores the input and calls every cell safe with
P(safe) = sigmoid(6), so that its detection has landing sites), a detection of the dataset's DTM
with the constant run, one of a scan with the trained run, and an evaluation report with landing
rows and a dead-pixel table. A larger detect output is made by hand (maps of hand-derivable values
on a 2 m grid) for the reduction of maps that do not fit the image size.

The browser tests open pages in headless Chromium (``headless_chromium``: chromedriver's WebDriver
protocol, no Selenium) at 1400 x 1000 and skip, saying so, where Chromium or chromedriver is missing.
"""

from __future__ import annotations

import base64
import csv
import hashlib
import io
import json
import math
import os
import re
import shutil
import subprocess
import sys
import warnings
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import matplotlib.image
import numpy as np
import pytest
import rasterio
import torch
from click.testing import CliRunner
from hdnet_datasets import build_labelled
from headless_chromium import Browser, browser_or_skip

from hdcli.cli import main
from hdcore.errors import HdWarning, LockedError, OutputExistsError
from hdcore.storage import WriterLock
from hdnet import view_images
from hdnet.detect import MAP_FILES, detect
from hdnet.detect_settings import DetectSettings
from hdnet.errors import HdNetError
from hdnet.eval_settings import EvalConfig
from hdnet.evaluate import evaluate
from hdnet.fit import FitConfig, fit
from hdnet.report import METHOD_NAMES, write_report
from hdnet.results import SITE_COLUMNS
from hdnet.sites import SAFETY_INVALID, SAFETY_SAFE, SAFETY_UNCERTAIN, SAFETY_UNSAFE
from hdnet.train import save_checkpoint
from hdnet.view import ViewSettings, default_page, view
from hdnet.view_html import map_style
from hdnet.view_html import page as html_page
from hdnet.view_images import Reduction, colour_rgba, reduced_map, safety_rgba
from tests.geotiff import write_geotiff

ROOT = Path(__file__).resolve().parents[2]
LAYERS = ("hillshade", "safety", "p_safe", "entropy", "mutual_information", "baseline_p_safe", "sites")


# ------------------------------------------------------------------------------------------ outputs
@pytest.fixture(scope="module")
def outputs(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("view")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", HdWarning)  # the tiny dataset's held-out scans overlap its training scans
        dataset = build_labelled(root / "data")
        run = root / "run"
        fit(dataset, run, FitConfig(profile="tiny", epochs=1, progress=False))
        ckpt = torch.load(run / "last.pt", weights_only=True)
        ckpt["model"]["classifier.weight"].zero_()
        ckpt["model"]["classifier.bias"] = torch.tensor([-3.0, 3.0])  # P(safe) = sigmoid(6) everywhere
        constant = root / "constant.pt"
        save_checkpoint(constant, ckpt)
        dtm = root / "data" / "hills.tif"
        detect(constant, root / "detect", DetectSettings(threshold="nats:0.5", mc_samples=1, n_sites=6), dtm=dtm)
        test_scan = _test_scan(dataset)
        detect(run, root / "scan", DetectSettings(scan=test_scan, threshold="nats:0.3", mc_samples=2), dataset=dataset)
        result = evaluate(run, dataset, EvalConfig(mc_samples=2, drop_pixels=3, nav_sigma_m=(0.0, 2.0)))
        write_report(result, root / "report")
    return {
        "root": root,
        "dataset": dataset,
        "dtm": dtm,
        "detect": root / "detect",
        "scan": root / "scan",
        "report": root / "report",
    }


def _test_scan(dataset: Path) -> int:
    import h5py

    for shard in sorted((dataset / "labels").rglob("*.h5")):
        with h5py.File(shard, "r") as f:
            test = np.flatnonzero(f["split"][:] == 2)
            if test.size:
                return int(f["scan_index"][int(test[0])])
    raise AssertionError("the tiny dataset has no test scan")


def copy_of(source: Path, tmp_path: Path, name: str = "copy") -> Path:
    """A copy of an output without any earlier page (a test's own to view, damage or move)."""
    out = tmp_path / name
    shutil.copytree(source, out, ignore=shutil.ignore_patterns("*view.html", ".hd-lock"))
    return out


def page_of(out: Path) -> Path:
    """The page hd view writes of ``out`` without --out: beside it, ``OUT-view.html``."""
    return out.parent / f"{out.name}-view.html"


def tree(path: Path) -> dict[str, str]:
    """Every file under ``path`` and its sha256."""
    return {
        str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest() for p in path.rglob("*") if p.is_file()
    }


# ------------------------------------------------------------------------------------------- parsing
VOID = {"meta", "img", "input", "br", "hr", "link", "source", "area", "base", "col", "embed", "param", "track", "wbr"}


class Node:
    def __init__(self, tag: str, attrs: dict[str, str], parent: Node | None) -> None:
        self.tag, self.attrs, self.parent = tag, attrs, parent
        self.children: list[Node] = []
        self.parts: list[str] = []

    def text(self) -> str:
        return "".join(self.parts) + "".join(c.text() for c in self.children)

    def walk(self):
        yield self
        for c in self.children:
            yield from c.walk()

    def find_all(self, tag: str | None = None, **attrs: str) -> list[Node]:
        return [
            n
            for n in self.walk()
            if (tag is None or n.tag == tag) and all(n.attrs.get(k.rstrip("_")) == v for k, v in attrs.items())
        ]

    def find(self, tag: str | None = None, **attrs: str) -> Node:
        found = self.find_all(tag, **attrs)
        assert len(found) == 1, (tag, attrs, len(found))
        return found[0]


class Page(HTMLParser):
    """The page as a tree of elements (the standard library's parser; text in the element it is in)."""

    def __init__(self, text: str) -> None:
        super().__init__(convert_charrefs=True)
        self.root = Node("#root", {}, None)
        self.node = self.root
        self.doctype = ""
        self.feed(text)
        self.close()

    def handle_decl(self, decl: str) -> None:
        self.doctype = decl

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        node = Node(tag, {k: v or "" for k, v in attrs}, self.node)
        self.node.children.append(node)
        if tag not in VOID:
            self.node = node

    def handle_startendtag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.node.children.append(Node(tag, {k: v or "" for k, v in attrs}, self.node))

    def handle_endtag(self, tag: str) -> None:
        node = self.node
        while node is not self.root and node.tag != tag:
            node = node.parent  # type: ignore[assignment]  # a parent below the root is a Node
        assert node is not self.root, f"</{tag}> closes nothing"
        self.node = node.parent  # type: ignore[assignment]  # as above

    def handle_data(self, data: str) -> None:
        self.node.parts.append(data)

    def table_rows(self, table: Node) -> list[list[str]]:
        return [[td.text() for td in tr.find_all("td")] for tr in table.find("tbody").find_all("tr")]


def parse(path: Path) -> Page:
    return Page(path.read_text(encoding="utf-8"))


def png_of(uri: str) -> np.ndarray:
    """The pixels (uint8 RGBA, rows x cols x 4) of a PNG data URI."""
    prefix = "data:image/png;base64,"
    assert uri.startswith(prefix)
    return matplotlib_pixels(base64.b64decode(uri[len(prefix) :], validate=True))


def settings_of(page: Page) -> dict[str, str]:
    """The page's settings table, name -> value."""
    return {tr.find("th").text(): tr.find("td").text() for tr in page.root.find("table", id="settings").find_all("tr")}


def matplotlib_pixels(data: bytes) -> np.ndarray:
    """The pixels (uint8 RGBA) of PNG bytes, decoded."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pixels = matplotlib.image.imread(io.BytesIO(data), format="png")
    if pixels.shape[2] == 3:
        pixels = np.concatenate([pixels, np.ones((*pixels.shape[:2], 1))], axis=2)
    return np.round(pixels * 255).astype(np.uint8)


def check_self_contained(page: Page, raw: str) -> None:
    """Nothing on the page is fetched: data: images only, inline scripts and style, no network address."""
    assert page.doctype.lower() == "doctype html"
    csp = page.root.find("meta", **{"http-equiv": "Content-Security-Policy"}).attrs["content"]
    assert "default-src 'none'" in csp and "img-src data:" in csp
    assert page.root.find("meta", name="generator").attrs["content"].startswith("hd view ")
    for node in page.root.walk():
        assert node.tag not in ("link", "iframe", "object", "embed", "audio", "video", "source", "base", "frame")
        assert "src" not in node.attrs or node.tag == "img", node.tag
        if node.tag == "img":
            assert node.attrs["src"].startswith("data:image/png;base64,")
        for key, value in node.attrs.items():
            assert not key.startswith("on"), f"inline handler {key} (the script binds its own)"
            assert key != "style", f"a style attribute on <{node.tag}> (the policy blocks it: a class instead)"
            if key in ("href", "xlink:href"):
                assert value.startswith("#"), value
    for style in page.root.find_all("style"):
        assert "@import" not in style.text() and "url(" not in style.text()
    without_svg_namespace = raw.replace('xmlns="http://www.w3.org/2000/svg"', "")
    assert "http://" not in without_svg_namespace and "https://" not in without_svg_namespace
    assert "//" not in "".join(node.attrs.get("src", "")[:30] for node in page.root.walk())


# ---------------------------------------------------------------------------------------- detect page
def test_a_detect_page_holds_every_layer_the_sites_and_the_settings(outputs, tmp_path):
    out = copy_of(outputs["detect"], tmp_path)
    before = tree(out)
    result = view(out)
    assert result.path == page_of(out) == out.parent / "copy-view.html" and result.kind == "detect"
    assert tree(out) == before  # the output untouched: the page lies beside it
    raw = result.path.read_text(encoding="utf-8")
    page = Page(raw)
    check_self_contained(page, raw)
    # Every layer, each with its checkbox and opacity slider; the default view: hillshade, safety, sites.
    for key in LAYERS:
        layer = page.root.find(id=f"layer-{key}")
        box = page.root.find("input", id=f"toggle-{key}")
        assert box.attrs["data-layer"] == f"layer-{key}" and box.attrs["type"] == "checkbox"
        assert page.root.find("input", id=f"opacity-{key}").attrs["data-layer"] == f"layer-{key}"
        assert ("checked" in box.attrs) == (key in ("hillshade", "safety", "sites"))
        if key != "sites":
            pixels = png_of(layer.attrs["src"])
            assert pixels.shape == (400, 400, 4) == (int(layer.attrs["height"]), int(layer.attrs["width"]), 4)
    # The constant run: every valid cell safe, so the safety image is the safe colour where valid.
    with rasterio.open(out / "safety.tif") as src:
        safety = src.read(1)
    np.testing.assert_array_equal(png_of(page.root.find(id="layer-safety").attrs["src"]), safety_rgba(safety))
    assert set(np.unique(safety)) == {SAFETY_SAFE, SAFETY_INVALID}
    with rasterio.open(out / "entropy.tif") as src:
        entropy = src.read(1)
    expected = colour_rgba(entropy, "viridis", 0.0, math.log(2))
    np.testing.assert_array_equal(png_of(page.root.find(id="layer-entropy").attrs["src"]), expected)
    # The site table is sites.csv, row for row (its numbers to 3 decimals), and each site has its marker.
    rows = list(csv.reader((out / "sites.csv").open()))
    table = page.root.find("table", id="sites")
    assert list(SITE_COLUMNS) == rows[0] and len(rows) > 1
    assert [th.text() for th in table.find("thead").find_all("th")] == [
        "#",
        "x (m)",
        "y (m)",
        "aim P(safe) ▼ ranked by",  # no navigation dispersion: ranked by the aim point's P(safe)
        "max entropy (nats)",
        "clearance (m)",
        "baseline P(safe)",
        "touchdown P(safe)",
    ]
    for shown, row in zip(page.table_rows(table), rows[1:], strict=True):
        assert shown[0] == row[0]
        assert [float(v) for v in shown[1:]] == [pytest.approx(float(v), abs=5e-4) for v in row[1:]]
        assert all(re.fullmatch(r"-?\d+\.\d{3}", v) for v in shown[1:])
    markers = page.root.find(id="layer-sites").find_all("g", class_="site-marker")
    assert [m.attrs["data-rank"] for m in markers] == [r[0] for r in rows[1:]]
    for marker, row in zip(markers, rows[1:], strict=True):
        circle = marker.find_all("circle")[0]
        assert float(circle.attrs["cx"]) == pytest.approx(float(row[1])) and float(circle.attrs["cy"]) == pytest.approx(
            -float(row[2])
        )
        assert float(circle.attrs["r"]) == pytest.approx(5.0)  # the 10 m lander's footprint, to scale
    # The map's extent: x 1000 to 1400 m, y 1600 to 2000 m (tests.geotiff's origin, 400 cells of 1 m).
    m = page.root.find(id="map").attrs
    assert (float(m["data-left"]), float(m["data-top"]), float(m["data-width"]), float(m["data-height"])) == (
        1000.0,
        2000.0,
        400.0,
        400.0,
    )
    assert page.root.find(id="extent").text().startswith("x 1000 to 1400 m, y 1600 to 2000 m")
    assert "one pixel per cell" in page.root.find(id="resolution").text()
    # The settings of the detection.
    settings = settings_of(page)
    info = json.loads((out / "detect.json").read_text())
    assert settings["threshold"] == "nats:0.5: H_t = 0.5000 nats"
    assert settings["input"] == f"DTM {os.path.relpath(outputs['dtm'], out.parent)}"
    assert settings["navigation sigma"].startswith("0 m")
    assert settings["site margin"].startswith("0 m") and settings["tiling"].startswith("tile_px: ")
    assert settings["sensor sigma (baseline, network input)"] == "1.67 cm (0.0167 m)"
    assert settings["MC samples, seed"] == "1, 0"
    assert os.path.relpath(info["run"]["checkpoint"], out.parent) in settings["run"]
    counts = {r[0]: r[1] for r in page.table_rows(page.root.find("table", id="counts"))}
    assert counts["safe (certain)"] == str(info["counts"]["safe"])
    # detect.json whole, its paths relative to the page.
    shown_info = json.loads(page.root.find("pre").text())
    assert shown_info["input"]["path"] == os.path.relpath(outputs["dtm"], out.parent)
    assert {**shown_info, "run": info["run"], "input": info["input"]} == info
    # H_t is named beside its tick, on the entropy bar (the score of nats:0.5), at 0.5 / ln 2 of its width.
    (control,) = [c for c in page.root.find_all("div", class_="layer-control") if c.find_all(id="toggle-entropy")]
    legend = control.find("div", class_="legend")
    assert legend.find("span", class_="tick-label-at").text() == "H_t = 0.5 nats"
    assert legend.find_all("span", class_="tick tick-at") and not page.root.find_all(class_="tick-label-at")[1:]
    assert f".tick-at {{ left: calc({100 * 0.5 / math.log(2):.2f}% - 1px); }}" in page.root.find("style").text()
    # The scale bar: a rule and its length on a box, not a site's haloed callout.
    bar = page.root.find("g", class_="scale-bar")
    assert bar.find("text").text() == "50 m" and "stroke" not in bar.find("text").attrs
    assert [r.attrs["class"] for r in bar.find_all("rect")] == ["box", "rule"]
    assert float(bar.find("rect", class_="rule").attrs["width"]) == 50.0


def csp_of(page: Page) -> dict[str, str]:
    """The page's Content-Security-Policy, directive -> its sources."""
    csp = page.root.find("meta", **{"http-equiv": "Content-Security-Policy"}).attrs["content"]
    return {d.split()[0]: " ".join(d.split()[1:]) for d in csp.split(";") if d.strip()}


def sha256_source(text: str) -> str:
    return "'sha256-" + base64.b64encode(hashlib.sha256(text.encode("utf-8")).digest()).decode("ascii") + "'"


@pytest.mark.parametrize("which", ["detect", "report"])
def test_the_policy_allows_the_pages_own_script_and_style_by_their_hashes_only(outputs, tmp_path, which):
    page = parse(view(copy_of(outputs[which], tmp_path)).path)
    policy = csp_of(page)
    assert "unsafe-inline" not in " ".join(policy.values()) and "nonce" not in " ".join(policy.values())
    (script,), (style,) = page.root.find_all("script"), page.root.find_all("style")
    assert policy["script-src"] == sha256_source(script.text())
    assert policy["style-src"] == sha256_source(style.text())
    assert policy["default-src"] == "'none'" and policy["img-src"] == "data:" and policy["base-uri"] == "'none'"
    # One character more in the script is another hash: the policy is of the very text written.
    assert sha256_source(script.text() + " ") != policy["script-src"]


def test_a_pages_own_style_holds_only_what_hd_makes():
    with pytest.raises(ValueError, match="'<'"):
        html_page("t", "<p>b</p>", style="</style><script>alert(1)</script>")
    with pytest.raises(ValueError, match="class name or colour"):
        map_style((1.0, 1.0), {"x; }": ["#000000"]}, {})
    with pytest.raises(ValueError, match="class name or colour"):
        map_style((1.0, 1.0), {}, {"safe": "red; } body { display: none"})
    with pytest.raises(ValueError, match="aspect"):
        map_style((math.nan, 1.0), {}, {})
    rules = map_style((131.0, 300.0), {"probability": ["#000000", "#ffffff"]}, {"safe": "#27ae60"}, 0.8)
    assert "#map { aspect-ratio: 131.000000 / 300.000000; }" in rules
    assert ".bar-probability { background: linear-gradient(to right, #000000, #ffffff); }" in rules
    assert ".tick-at { left: calc(80.00% - 1px); }" in rules and ".tick-label-at { right: 20.00%; }" in rules


def test_a_scan_page_shades_the_scans_dem_and_names_its_split(outputs, tmp_path):
    out = copy_of(outputs["scan"], tmp_path)
    page = parse(view(out).path)
    info = json.loads((out / "detect.json").read_text())
    assert info["input"]["split"] == "test"
    settings = settings_of(page)
    assert settings["split"] == "test" and settings["input"].startswith(f"scan {info['input']['scan_index']} of ")
    assert settings["scan's noise level"] == "1.67 cm (0.0167 m)"
    hillshade = png_of(page.root.find(id="layer-hillshade").attrs["src"])
    assert hillshade.shape == (100, 100, 4) and hillshade[..., 3].max() == 255
    assert "scan frame" in page.root.find(id="extent").text()
    assert page.root.find(id="no-sites").text().startswith("No site")  # a network of one epoch finds none
    assert page.root.find("h1").text() == "hd detect: scan {} (test split)".format(info["input"]["scan_index"])


def test_the_hillshade_needs_the_very_dtm_hd_detect_read(outputs, tmp_path):
    out = copy_of(outputs["detect"], tmp_path)
    info = json.loads((out / "detect.json").read_text())
    moved = tmp_path / "moved.tif"
    shutil.copy(outputs["dtm"], moved)
    info["input"]["path"] = str(tmp_path / "gone.tif")
    (out / "detect.json").write_text(json.dumps(info))
    result = CliRunner().invoke(main, ["view", str(out)])
    assert result.exit_code == 0, result.output
    assert "No hillshade: the DTM" in result.output and "give it with --dtm" in result.output
    page = parse(page_of(out))
    assert not page.root.find_all(id="layer-hillshade")
    assert "--dtm" in page.root.find(id="hillshade-note").text()
    view(out, dtm=moved)  # the same bytes elsewhere: shaded again
    assert parse(page_of(out)).root.find_all(id="layer-hillshade")
    other = write_geotiff(tmp_path / "other.tif", np.zeros((400, 400)))
    view(out, dtm=other)
    note = parse(page_of(out)).root.find(id="hillshade-note").text()
    assert "is not the DTM hd detect read" in note and info["input"]["sha256"][:12] in note


# ------------------------------------------------------------------------------------ large maps
def big_output(source: Path, tmp_path: Path, rows: int = 300, cols: int = 131) -> tuple[Path, dict[str, np.ndarray]]:
    """A detect output of ``rows x cols`` cells of 2 m made by hand from ``source``'s detect.json: P(safe)
    = column / cols, entropy = ln 2 * row / rows, one unsafe cell at (7, 7), uncertain rows 50-54, an
    invalid border of 3 cells; its DTM a plane rising east."""
    out = copy_of(source, tmp_path, "big")
    for name in MAP_FILES:
        (out / name).unlink()
    r, c = np.mgrid[0:rows, 0:cols]
    invalid = (r < 3) | (c < 3) | (r >= rows - 3) | (c >= cols - 3)
    safety = np.full((rows, cols), SAFETY_SAFE, np.uint8)
    safety[7, 7] = SAFETY_UNSAFE
    safety[50:55] = SAFETY_UNCERTAIN
    safety[invalid] = SAFETY_INVALID
    maps: dict[str, np.ndarray] = {
        "p_safe": np.where(invalid, np.nan, c / cols).astype(np.float32),
        "entropy": np.where(invalid, np.nan, math.log(2) * r / rows).astype(np.float32),
        "mutual_information": np.where(invalid, np.nan, 0.1).astype(np.float32),
        "baseline_p_safe": np.where(invalid, np.nan, 0.5).astype(np.float32),
        "safety": safety,
    }
    origin = (500.0, 900.0)
    for key, values in maps.items():
        dtype = "uint8" if key == "safety" else "float32"
        write_geotiff(out / f"{key}.tif", values, 2.0, origin, dtype=dtype)
    dtm = write_geotiff(tmp_path / "big-dtm.tif", 0.05 * c * 2.0, 2.0, origin)
    info = json.loads((out / "detect.json").read_text())
    transform = [2.0, 0, 500.0, 0, -2.0, 900.0]
    info["grid"] = {"rows": rows, "cols": cols, "spacing_m": [2.0, 2.0], "transform": transform, "crs_wkt": ""}
    info["input"].update(path=str(dtm), name="big-dtm.tif", sha256=hashlib.sha256(dtm.read_bytes()).hexdigest())
    info["sites"] = []
    (out / "detect.json").write_text(json.dumps(info))
    (out / "sites.csv").write_text(",".join(SITE_COLUMNS) + "\n")
    return out, maps


def block_reference(values: np.ndarray, f: int) -> np.ndarray:
    """Plain loops: each f x f block's mean of its finite cells (NaN when none)."""
    rows, cols = math.ceil(values.shape[0] / f), math.ceil(values.shape[1] / f)
    out = np.full((rows, cols), np.nan)
    for i in range(rows):
        for j in range(cols):
            block = values[i * f : (i + 1) * f, j * f : (j + 1) * f]
            if np.isfinite(block).any():
                out[i, j] = np.nanmean(block)
    return out


def test_a_map_larger_than_the_image_is_reduced_by_blocks_and_the_page_says_so(outputs, tmp_path):
    out, maps = big_output(outputs["detect"], tmp_path)
    result = view(out, settings=ViewSettings(max_px=64))
    assert result.info["cells_per_pixel"] == 5 and result.info["image_px"] == [27, 60]  # ceil(300/64); 131/5, 300/5
    page = parse(result.path)
    for key in LAYERS[:-1]:
        img = page.root.find(id=f"layer-{key}")
        assert png_of(img.attrs["src"]).shape == (60, 27, 4) and (img.attrs["width"], img.attrs["height"]) == (
            "27",
            "60",
        )
    note = page.root.find(id="resolution").text()
    assert "300 x 131 cells of 2 m" in note and "60 x 27 pixels, one pixel per 5 x 5 cells (10 m)" in note
    # The safety map: each block's worst class. Block (1, 1) holds the unsafe cell (7, 7); rows 50-54 are block row 10.
    safety = png_of(page.root.find(id="layer-safety").attrs["src"])
    colour = {code: tuple(safety_rgba(np.array([[code]], np.uint8))[0, 0]) for code in (0, 1, 2, 255)}
    assert tuple(safety[1, 1]) == colour[SAFETY_UNSAFE] and tuple(safety[1, 2]) == colour[SAFETY_SAFE]
    assert tuple(safety[10, 3]) == colour[SAFETY_UNCERTAIN] and tuple(safety[0, 0]) == colour[SAFETY_SAFE]
    assert tuple(safety[59, 26]) == colour[SAFETY_INVALID]  # the last block: 1 column of map, the rest past it
    # P(safe): block means of the valid cells, coloured.
    p = png_of(page.root.find(id="layer-p_safe").attrs["src"])
    np.testing.assert_array_equal(p, colour_rgba(block_reference(maps["p_safe"], 5), "RdYlGn", 0.0, 1.0))
    # The page reads a value back from a pixel's colour: its index in the layer's colour table.
    img = page.root.find(id="layer-p_safe")
    table = img.attrs["data-lut"].split()
    index = {colour: i for i, colour in enumerate(table)}  # a colour repeated: its last entry, as the page's script
    assert len(table) == 256 and (img.attrs["data-min"], img.attrs["data-max"]) == ("0", "1.0")
    reference = block_reference(maps["p_safe"], 5)
    for row, col in ((5, 1), (5, 13), (30, 25), (59, 24)):
        read = (index["#{:02x}{:02x}{:02x}".format(*p[row, col, :3])] + 0.5) / 256
        assert abs(read - reference[row, col]) <= 1 / 256
    classes = json.loads(page.root.find(id="layer-safety").attrs["data-classes"])
    assert classes[("#{:02x}{:02x}{:02x}".format(*safety[1, 1, :3]))] == "unsafe"
    assert sorted(classes.values()) == ["safe", "uncertain", "unsafe"]
    # The hillshade of the plane: one grey wherever its blocks lie wholly on the DTM.
    shade = png_of(page.root.find(id="layer-hillshade").attrs["src"])
    assert shade.shape == (60, 27, 4) and (shade[..., 3] == 255).all() and np.ptp(shade[:, :25, 0]) <= 1
    assert page.root.find(id="extent").text().startswith("x 500 to 762 m, y 300 to 900 m")


@pytest.mark.parametrize(
    ("shape", "factor", "strip_cells"), [((37, 23), 1, 1 << 22), ((37, 23), 4, 40), ((5, 90), 7, 1)]
)
def test_reduced_maps_equal_plain_block_loops_in_any_strips(tmp_path, monkeypatch, shape, factor, strip_cells):
    rng = np.random.default_rng(7)
    values = rng.random(shape).astype(np.float32)
    values[rng.random(shape) < 0.3] = np.nan
    codes = rng.choice(np.array([0, 1, 2, 255], np.uint8), size=shape)
    write_geotiff(tmp_path / "p.tif", values)
    write_geotiff(tmp_path / "s.tif", codes, dtype="uint8")
    monkeypatch.setattr(view_images, "STRIP_CELLS", strip_cells)  # one image row per read, or all at once
    reduction = Reduction(shape, factor, (math.ceil(shape[0] / factor), math.ceil(shape[1] / factor)))
    np.testing.assert_allclose(reduced_map(tmp_path / "p.tif", reduction), block_reference(values, factor), rtol=1e-6)
    got = reduced_map(tmp_path / "s.tif", reduction, categorical=True)
    for i in range(reduction.shape[0]):
        for j in range(reduction.shape[1]):
            block = set(codes[i * factor : (i + 1) * factor, j * factor : (j + 1) * factor].ravel().tolist())
            worst = next(c for c in (SAFETY_UNSAFE, SAFETY_UNCERTAIN, SAFETY_SAFE, SAFETY_INVALID) if c in block)
            assert got[i, j] == worst


def test_reduction_bounds_the_longer_side():
    assert Reduction.of((400, 400), 2048) == Reduction((400, 400), 1, (400, 400))
    assert Reduction.of((10000, 3000), 2048) == Reduction((10000, 3000), 5, (2000, 600))
    assert Reduction.of((2049, 10), 2048) == Reduction((2049, 10), 2, (1025, 5))


# ---------------------------------------------------------------------------------------- report page
def _numbers(cell: str) -> list[float]:
    return [float(x) for x in re.findall(r"-?\d+(?:\.\d+)?", cell)]


def _table_after(page: Page, heading_id: str) -> Node:
    article = page.root.find("article", id="report")
    kids = article.children
    start = next(i for i, n in enumerate(kids) if n.attrs.get("id") == heading_id)
    return next(n for n in kids[start + 1 :] if n.tag == "table")


def test_a_report_page_shows_report_json_numbers_its_figures_and_settings(outputs, tmp_path):
    out = copy_of(outputs["report"], tmp_path)
    before = tree(out)
    raw = view(out).path.read_text(encoding="utf-8")
    assert tree(out) == before  # the report untouched: the page lies beside it
    page = Page(raw)
    check_self_contained(page, raw)
    content = json.loads((out / "report.json").read_text())
    for table_name, heading in (("noise", "table-1-noise-levels"), ("dead_pixels", "table-2-dead-pixels")):
        rows = [r for r in content["rows"] if r["table"] == table_name]
        cells = page.table_rows(_table_after(page, heading))
        assert len(cells) == len(rows) > 0
        for row, html_row in zip(rows, cells, strict=True):
            assert html_row[0] == METHOD_NAMES[row["method"]]
            assert _numbers(html_row[2]) == [pytest.approx(row["test_sigma_m"] * 100, abs=0.005)]
            vc = row["vc_fraction"]
            assert html_row[3] == "--" if vc is None else _numbers(html_row[3]) == [pytest.approx(100 * vc, abs=0.5)]
            for k, key in enumerate(("pixel_accuracy", "miou", "precision", "sensitivity")):
                value = row[key]
                assert (
                    html_row[4 + k] == "--"
                    if value is None
                    else float(html_row[4 + k]) == pytest.approx(value, abs=5e-5)
                )
    ece = page.table_rows(_table_after(page, "calibration-of-p-safe-15-bins"))
    assert [float(r[1]) for r in ece] == [
        pytest.approx(c["ece"], abs=5e-5) for c in content["calibration"]["per_sigma"]
    ]
    sweep = page.table_rows(_table_after(page, "threshold-sweep-uncertainty-aware"))
    assert [float(r[2]) for r in sweep] == [pytest.approx(s["threshold_nats"], abs=5e-5) for s in content["sweep"]]
    landing = page.table_rows(page.root.find("article", id="report").find_all("table")[2])
    assert len(landing) == len(content["landing"])
    for row, html_row in zip(content["landing"], landing, strict=True):
        if row["landed"]:
            assert _numbers(html_row[4]) == [
                pytest.approx(row[k], abs=5e-5) for k in ("p_safe", "p_safe_low", "p_safe_high")
            ]
    # The figures report.md shows, inline, of their own size.
    shown = [
        line[line.index("(") + 1 : -1] for line in (out / "report.md").read_text().splitlines() if line.startswith("![")
    ]
    figures = page.root.find_all("figure")
    assert len(figures) == len(shown) >= 4
    for figure, name in zip(figures, shown, strict=True):
        img = figure.find("img")
        pixels = png_of(img.attrs["src"])
        assert pixels.shape[:2] == (int(img.attrs["height"]), int(img.attrs["width"]))
        assert np.array_equal(pixels, matplotlib_pixels((out / name).read_bytes()))
    settings = settings_of(page)
    assert settings["run.checkpoint"] == os.path.relpath(content["run"]["checkpoint"], out.parent)
    assert settings["threshold.spec"] == "mean"
    assert settings["run.mc_samples"] == "2" and settings["landing_settings.nav_sigmas_m"] == "0, 2"
    assert page.root.find("h1").text() == "hd eval report: copy"


@pytest.mark.parametrize("which", ["detect", "scan", "report"])
@pytest.mark.parametrize("where", ["inside", "elsewhere"])
def test_no_page_shows_a_machine_path(outputs, tmp_path, which, where):
    out = copy_of(outputs[which], tmp_path)
    target = out / "view.html" if where == "inside" else tmp_path / "pages" / "page.html"
    target.parent.mkdir(exist_ok=True)
    raw = view(out, target).path.read_text(encoding="utf-8")
    for machine in {str(tmp_path), str(outputs["root"]), str(tmp_path.resolve()), str(outputs["root"].resolve())}:
        assert machine not in raw
    assert not re.search(r"(?<![\w.])/(tmp|home|work|Users|private|var)/", raw)
    page = Page(raw)
    sub = page.root.find("p", class_="sub").text()
    assert sub == "the folder of this page" if where == "inside" else sub == "../copy (relative to this page)"
    if which != "report":
        run = settings_of(page)["run"]
        checkpoint = outputs["root"] / ("constant.pt" if which == "detect" else "run")
        assert run.startswith(os.path.relpath(checkpoint, target.parent))


def test_a_site_margin_is_a_setting_and_a_dashed_ring_around_each_site(outputs, tmp_path):
    out = copy_of(outputs["detect"], tmp_path)
    info = json.loads((out / "detect.json").read_text())
    info["site_rule"]["margin_m"] = 2.0
    (out / "detect.json").write_text(json.dumps(info))
    page = Page(view(out).path.read_text(encoding="utf-8"))
    assert settings_of(page)["site margin"].startswith("2 m: the lander's disk widened by 2 m")
    markers = page.root.find(id="layer-sites").find_all("g", class_="site-marker")
    assert markers and len(markers) == len(info["sites"])
    for marker in markers:
        ring, lander = marker.find("circle", class_="margin"), marker.find("circle", class_="ring")
        assert float(ring.attrs["r"]) == pytest.approx(float(lander.attrs["r"]) + 2.0)  # 5 m lander + 2 m
        assert (ring.attrs["cx"], ring.attrs["cy"]) == (lander.attrs["cx"], lander.attrs["cy"])
    (control,) = [c for c in page.root.find_all("div", class_="layer-control") if c.find_all(id="toggle-sites")]
    assert "dashed ring: the site margin, 2 m" in control.text()
    plain = Page(view(copy_of(outputs["detect"], tmp_path, "plain")).path.read_text(encoding="utf-8"))
    assert not plain.root.find_all("circle", class_="margin")


def test_a_run_that_learnt_nothing_is_said_on_the_page(outputs, tmp_path):
    out = copy_of(outputs["detect"], tmp_path)
    page = Page(view(out).path.read_text(encoding="utf-8"))
    assert not [w for w in page.root.find_all("p", class_="warning") if "top of the entropy scale" in w.text()]
    info = json.loads((out / "detect.json").read_text())
    info["threshold"]["value_nats"] = 0.6928
    (out / "detect.json").write_text(json.dumps(info))
    page = Page(view(out).path.read_text(encoding="utf-8"))
    (said,) = [w.text() for w in page.root.find_all("p", class_="warning") if "top of the entropy scale" in w.text()]
    assert said.startswith("H_t = 0.693 nats is at the top of the entropy scale") and "6 site(s) found" in said


def test_the_site_table_marks_the_column_it_is_ranked_by():
    from hdnet.view import site_cells, site_headers

    assert site_headers({"nav_sigma_m": 0.0})[3] == "aim P(safe) ▼ ranked by"
    with_dispersion = site_headers({"nav_sigma_m": 2.0})
    assert with_dispersion[7] == "touchdown P(safe) ▼ ranked by" and with_dispersion[3] == "aim P(safe)"
    assert [h for h in with_dispersion if "ranked by" in h] == [with_dispersion[7]]
    assert site_cells(["2", "1207.5", "1807.5", "0.992000", "0.017311", "188.000", "0.000000", "0.986123"]) == [
        "2",
        "1207.500",
        "1807.500",
        "0.992",
        "0.017",
        "188.000",
        "0.000",
        "0.986",
    ]


def test_recorded_values_read_as_words(tmp_path):
    from hdnet.page_values import number, readable, shown_path

    assert number(0.30000000000000004) == "0.3" and number(1992000.0) == "1992000" and number(0.0166666) == "0.01667"
    assert readable([0.0, 2.0], tmp_path) == "0, 2"
    assert readable({"a": 1, "b": [1.5, None]}, tmp_path) == "a: 1; b: 1.5, --"
    assert shown_path(tmp_path / "x" / "run", tmp_path) == "x/run"
    assert shown_path(tmp_path.parent / "data" / "d.tif", tmp_path) == "../data/d.tif"
    assert shown_path("/a/b/c/d/e/f/g.tif", tmp_path / "p" / "q" / "r") == "g.tif"  # too far up: its name
    assert shown_path("relative/x.tif", tmp_path) == "relative/x.tif"
    assert readable("C:\\runs\\last.pt", tmp_path) == "last.pt" and readable("s3://b/k", tmp_path) == "s3://b/k"


def test_text_from_files_is_escaped(outputs, tmp_path):
    markup = '<script>alert("x")</script><img src=http://example.org/x.png>'
    out = copy_of(outputs["detect"], tmp_path)
    info = json.loads((out / "detect.json").read_text())
    info["input"]["name"] = markup
    info["run"]["profile"] = markup
    (out / "detect.json").write_text(json.dumps(info))
    raw = view(out, dtm=outputs["dtm"]).path.read_text(encoding="utf-8")
    page = Page(raw)
    assert len(page.root.find_all("script")) == 1 and not page.root.find("script").attrs  # the page's own only
    assert (
        page.root.find("h1").text() == f"hd detect: {markup}" and markup in page.root.find("head").find("title").text()
    )
    report = copy_of(outputs["report"], tmp_path, "report")
    content = json.loads((report / "report.json").read_text())
    content["run"]["labels"] = markup
    (report / "report.json").write_text(json.dumps(content))
    page = Page(view(report).path.read_text(encoding="utf-8"))
    assert len(page.root.find_all("script")) == 1 and markup in page.root.find("article").text()
    assert all(img.attrs["src"].startswith("data:") for img in page.root.find_all("img"))


# ------------------------------------------------------------------------------------- bad input
def _damage(kind: str, out: Path) -> None:
    if kind == "detect.json cut short":
        (out / "detect.json").write_bytes((out / "detect.json").read_bytes()[:50])
    elif kind == "detect.json an array":
        (out / "detect.json").write_text("[1, 2]")
    elif kind == "detect.json without grid":
        info = json.loads((out / "detect.json").read_text())
        del info["grid"]
        (out / "detect.json").write_text(json.dumps(info))
    elif kind == "detect.json with odd values":
        info = json.loads((out / "detect.json").read_text())
        info["run"]["train_noise"] = {"range_m": "wide"}
        (out / "detect.json").write_text(json.dumps(info))
    elif kind == "detect.json with counts as text":
        info = json.loads((out / "detect.json").read_text())
        info["counts"]["safe"] = "many"
        (out / "detect.json").write_text(json.dumps(info))
    elif kind == "sites.csv missing":
        (out / "sites.csv").unlink()
    elif kind == "sites.csv of another site":
        text = (out / "sites.csv").read_text().splitlines()
        text[1] = text[1].replace(text[1].split(",")[1], "1.000", 1)
        (out / "sites.csv").write_text("\n".join(text) + "\n")
    elif kind == "sites.csv a row less":
        (out / "sites.csv").write_text("\n".join((out / "sites.csv").read_text().splitlines()[:-1]) + "\n")
    elif kind == "a map cut short":
        (out / "p_safe.tif").write_bytes((out / "p_safe.tif").read_bytes()[:3000])
    elif kind == "a map missing":
        (out / "entropy.tif").unlink()
    elif kind == "a map of another size":
        write_geotiff(out / "baseline_p_safe.tif", np.zeros((40, 40)))
    elif kind == "a safety code that is none":
        write_geotiff(out / "safety.tif", np.full((400, 400), 7), dtype="uint8")
    elif kind == "report.json cut short":
        (out / "report.json").write_bytes((out / "report.json").read_bytes()[:80])
    elif kind == "report.json of another schema":
        content = json.loads((out / "report.json").read_text())
        del content["calibration"]
        (out / "report.json").write_text(json.dumps(content))
    elif kind == "a figure missing":
        (out / "reliability.png").unlink()
    elif kind == "a figure damaged":
        data = (out / "threshold_sweep.png").read_bytes()
        (out / "threshold_sweep.png").write_bytes(data[: len(data) // 2])
    elif kind == "report.md missing":
        (out / "report.md").unlink()


DAMAGE = [
    ("detect", "detect.json cut short", "unreadable detect.json"),
    ("detect", "detect.json an array", "not an hd detect output of this schema"),
    ("detect", "detect.json without grid", "no 'grid' object"),
    ("detect", "detect.json with odd values", "detect.json: not an hd detect output of this schema ("),
    ("detect", "detect.json with counts as text", "cell counts"),
    ("detect", "sites.csv missing", "sites.csv"),
    ("detect", "sites.csv of another site", "is not detect.json's site 1"),
    ("detect", "sites.csv a row less", "detect.json records"),
    ("detect", "a map cut short", "p_safe.tif: unreadable"),
    ("detect", "a map missing", "entropy.tif: missing"),
    ("detect", "a map of another size", "not the one band of 400 x 400 cells"),
    ("detect", "a safety code that is none", "is no safety code"),
    ("report", "report.json cut short", "unreadable report"),
    ("report", "report.json of another schema", "no 'calibration' dict"),
    ("report", "a figure missing", "reliability.png: missing"),
    ("report", "a figure damaged", "threshold_sweep.png: a damaged PNG"),
    ("report", "report.md missing", "report.md"),
]


@pytest.mark.parametrize(("which", "kind", "needle"), DAMAGE)
def test_a_damaged_output_is_one_line_and_nothing_is_written(outputs, tmp_path, which, kind, needle):
    out = copy_of(outputs[which], tmp_path)
    _damage(kind, out)
    before = tree(out)
    result = CliRunner().invoke(main, ["view", str(out)])
    assert result.exit_code == 1 and "Traceback" not in result.output, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: ") and needle in lines[0], result.output
    assert tree(out) == before and not list(out.glob(".*partial*"))


def _other(root: Path) -> Path:
    (root / "other").mkdir()
    (root / "other" / "a.txt").write_text("x")
    return root / "other"


@pytest.mark.parametrize(
    ("make", "needle"),
    [
        (lambda root: root / "missing", "no such directory"),
        (lambda root: root.joinpath("empty").mkdir() or root / "empty", "is empty"),
        (lambda root: _other(root), "holds neither detect.json (hd detect) nor report.json (hd eval)"),
    ],
)
def test_what_is_neither_kind_is_refused_with_what_to_give(tmp_path, make, needle):
    path = make(tmp_path)
    result = CliRunner().invoke(main, ["view", str(path)])
    assert result.exit_code == 1 and needle in result.output and "hd detect --out or hd eval --out" in result.output
    assert not list(tmp_path.rglob("*view.html"))


def test_a_run_and_a_dataset_are_named_as_such(outputs):
    runner = CliRunner()
    result = runner.invoke(main, ["view", str(outputs["root"] / "run")])
    assert result.exit_code == 1 and "is a run" in result.output and "hd detect" in result.output
    result = runner.invoke(main, ["view", str(outputs["dataset"])])
    assert result.exit_code == 1 and "is a dataset" in result.output and "hd inspect" in result.output
    assert not list(outputs["root"].rglob("run*view.html")) and not page_of(outputs["dataset"]).exists()


def test_the_page_replaces_only_an_earlier_page_and_goes_where_out_says(outputs, tmp_path):
    out = copy_of(outputs["report"], tmp_path)
    runner = CliRunner()
    assert runner.invoke(main, ["view", str(out)]).exit_code == 0
    first = page_of(out).read_bytes()
    assert runner.invoke(main, ["view", str(out / "report.json")]).exit_code == 0  # the marker file names it too
    assert page_of(out).read_bytes() == first  # the same page again, replaced
    mine = tmp_path / "notes.html"
    mine.write_text("<html>mine</html>")
    result = runner.invoke(main, ["view", str(out), "--out", str(mine)])
    assert (
        result.exit_code == 1
        and "is not a page of hd view" in result.output
        and mine.read_text() == "<html>mine</html>"
    )
    result = runner.invoke(main, ["view", str(out), "--out", str(out / "report.md")])
    assert result.exit_code == 1 and "is not a page of hd view" in result.output
    elsewhere = tmp_path / "r.html"  # beside the report, as the default page: the same page, paths and all
    result = runner.invoke(main, ["--json", "view", str(out), "--out", str(elsewhere)])
    assert result.exit_code == 0, result.output
    record = json.loads(result.output)
    assert record["command"] == "view" and record["kind"] == "report" and record["out"] == str(elsewhere.resolve())
    assert record["bytes"] == elsewhere.stat().st_size and elsewhere.read_bytes() == first
    os.mkfifo(tmp_path / "fifo")
    result = runner.invoke(main, ["view", str(out), "--out", str(tmp_path / "fifo")])
    assert result.exit_code == 1 and "is not a page of hd view" in result.output


def test_a_directory_being_written_is_not_read(outputs, tmp_path):
    out = copy_of(outputs["detect"], tmp_path)
    with WriterLock(out, "detect"):
        with pytest.raises(LockedError, match="another hd process"):
            view(out, out / "view.html")  # the page would go into it
        with pytest.raises(LockedError, match="being written by another hd process"):
            view(out)  # beside it
    assert not (out / "view.html").exists() and not page_of(out).exists()
    with pytest.raises(OutputExistsError, match="not a page of hd view"):
        view(out, out / "sites.csv")


def test_the_default_page_lies_beside_the_output_and_the_root_needs_out(tmp_path, monkeypatch):
    assert default_page(tmp_path / "site-7") == tmp_path / "site-7-view.html"
    (tmp_path / "report").mkdir()
    monkeypatch.chdir(tmp_path / "report")
    assert default_page(Path(".")) == tmp_path / "report-view.html"  # the working directory, by its name
    with pytest.raises(HdNetError, match="no name to put the page beside it; give --out FILE"):
        default_page(Path("/"))


def test_cli_view_says_what_it_wrote(outputs, tmp_path):
    out = copy_of(outputs["detect"], tmp_path)
    result = CliRunner().invoke(main, ["view", str(out), "--max-px", "100"])
    assert result.exit_code == 0, result.output
    assert result.output.startswith(f"wrote {page_of(out)} (") and "shown at 1 pixel per 4 x 4" in result.output
    assert "6 site(s)" in result.output and "no network needed" in result.output
    result = CliRunner().invoke(main, ["view", str(out), "--max-px", "10"])
    assert result.exit_code == 2 and "64<=x<=8192" in result.output
    result = CliRunner().invoke(main, ["view", str(outputs["report"]), "--dtm", str(outputs["dtm"])])
    assert result.exit_code == 1 and "--dtm goes with an hd detect output" in result.output


@pytest.mark.parametrize("which", ["detect", "scan", "report"])
def test_hd_view_never_imports_the_network_library(outputs, tmp_path, which):
    out = copy_of(outputs[which], tmp_path)
    code = (
        "import sys\nfrom hdcli.cli import main\ntry:\n    main(['view', sys.argv[1]])\nexcept SystemExit as exc:\n"
        "    assert exc.code == 0, exc.code\nassert 'torch' not in sys.modules, 'torch imported'\n"
    )
    done = subprocess.run([sys.executable, "-c", code, str(out)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert page_of(out).is_file()


# ------------------------------------------------------------------------------------------ browser
@pytest.fixture(scope="module")
def browser():
    chromium = browser_or_skip()
    yield chromium
    chromium.close()


def _problems(chromium: Browser) -> list[dict[str, Any]]:
    return [e for e in chromium.console() if e["level"] in ("SEVERE", "WARNING")]


def _rect(chromium: Browser, selector: str) -> dict[str, float]:
    return chromium.run(
        "var r = document.querySelector(arguments[0]).getBoundingClientRect();"
        "return {left: r.left, top: r.top, right: r.right, bottom: r.bottom, width: r.width, height: r.height};",
        selector,
    )


def _wait_for(chromium: Browser, script: str, *args: Any) -> Any:
    """``script``'s value once it is truthy (input events arrive a moment after the actions call)."""
    for _ in range(50):
        value = chromium.run(script, *args)
        if value:
            return value
        chromium.run("return new Promise(function (done) { setTimeout(done, 20); });")
    raise AssertionError(f"never true: {script}")


def test_pages_work_in_a_real_browser(browser, outputs, tmp_path):
    detect_dir = copy_of(outputs["detect"], tmp_path, "detect")
    report_dir = copy_of(outputs["report"], tmp_path, "report")
    detect_page, report_page = view(detect_dir).path, view(report_dir).path
    n_sites = len((detect_dir / "sites.csv").read_text().splitlines()) - 1
    browser.get(detect_page.as_uri())
    assert browser.run("return document.readyState") == "complete"
    for key in LAYERS[:-1]:  # every image decoded by the browser at its size
        loaded = browser.run(
            "var i = document.getElementById(arguments[0]); return [i.complete, i.naturalWidth, i.naturalHeight];",
            f"layer-{key}",
        )
        assert loaded == [True, 400, 400], key
    shown = "return getComputedStyle(document.getElementById(arguments[0])).display !== 'none';"
    assert not browser.run(shown, "layer-p_safe")
    browser.click("#toggle-p_safe")
    assert browser.run(shown, "layer-p_safe") and browser.run("return document.getElementById('toggle-p_safe').checked")
    assert browser.run(shown, "layer-safety")
    browser.click("#toggle-safety")
    assert not browser.run(shown, "layer-safety")
    browser.run("var s = document.getElementById('opacity-p_safe'); s.value = 30; s.dispatchEvent(new Event('input'));")
    assert float(browser.run("return getComputedStyle(document.getElementById('layer-p_safe')).opacity")) == (
        pytest.approx(0.3)
    )
    assert browser.run("return document.querySelectorAll('#sites tbody tr').length") == n_sites > 0
    browser.click("#sites tbody tr:nth-child(2)")  # selects site 2: its row and its marker
    assert browser.run(
        "return Array.prototype.map.call(document.querySelectorAll('.site-marker.selected, tr.selected'), "
        "function (e) { return e.tagName + ' ' + e.dataset.rank; });"
    ) == ["g 2", "TR 2"]
    # The pointer over site 1: its coordinates, class and values read back from the layers' colours.
    x, y = (float(v) for v in (detect_dir / "sites.csv").read_text().splitlines()[1].split(",")[1:3])
    readout = browser.run(
        "var m = document.getElementById('map'), r = m.getBoundingClientRect(), d = m.dataset;"
        "var fx = (arguments[0] - Number(d.left)) / Number(d.width), fy = (Number(d.top) - arguments[1]) / "
        "Number(d.height); m.dispatchEvent(new MouseEvent('mousemove', {clientX: r.left + fx * r.width, "
        "clientY: r.top + fy * r.height, bubbles: true}));"
        "return document.getElementById('readout').textContent;",
        x,
        y,
    )
    read_x, read_y = (float(v) for v in re.findall(r"[xy] (-?[\d.]+) m", readout))
    assert abs(read_x - x) < 1.0 and abs(read_y - y) < 1.0, readout  # events land on whole CSS pixels
    assert ": safe, P(safe) ≈ 0.998, entropy ≈ " in readout, readout
    assert _problems(browser) == []
    browser.get(report_page.as_uri())
    figures = browser.run(
        "return Array.prototype.map.call(document.querySelectorAll('figure img'), "
        "function (i) { return i.complete && i.naturalWidth > 0; });"
    )
    assert figures and all(figures)
    assert browser.run("return document.querySelectorAll('#report table').length") >= 4
    assert _problems(browser) == []


def test_a_planted_inline_script_does_not_run_and_the_pages_own_does(browser, outputs, tmp_path):
    out = copy_of(outputs["detect"], tmp_path)
    path = view(out).path
    raw = path.read_text(encoding="utf-8")
    planted = (
        "<script>document.title = 'pwned';</script>"
        '<p id="planted" style="color: rgb(255, 0, 0)" onclick="document.title = \'clicked\'">planted</p>'
    )
    path.write_text(raw.replace("<body>\n", "<body>\n" + planted, 1), encoding="utf-8")
    browser.get(path.as_uri())
    assert browser.run("return document.title") == "hd detect: hills.tif"  # the planted script was blocked
    assert browser.run("return getComputedStyle(document.getElementById('planted')).color") != "rgb(255, 0, 0)"
    browser.click("#planted")
    assert browser.run("return document.title") == "hd detect: hills.tif"  # and its handler
    blocked = [e["message"] for e in browser.console() if "Content Security Policy" in e["message"]]
    assert len(blocked) >= 2, blocked  # the script and the style attribute, each reported
    # The page's own script runs: it sizes the map, and a row's click marks its site.
    assert browser.run("return document.getElementById('map').style.width").endswith("px")
    browser.click("#sites tbody tr:nth-child(3)")
    assert browser.run("return document.querySelector('.site-marker.selected').dataset.rank") == "3"
    # The page's own style applies: the bars' gradients are rules of the hashed style block.
    assert "linear-gradient" in browser.run("return getComputedStyle(document.querySelector('.bar')).backgroundImage")


@pytest.mark.parametrize("shape", ["detect", "tall"])
def test_the_whole_map_and_its_scale_bar_show_at_1400_by_1000(browser, outputs, tmp_path, shape):
    if shape == "tall":  # 300 x 131 cells: fitted by its height, not its width
        out, _ = big_output(outputs["detect"], tmp_path)
    else:
        out = copy_of(outputs["detect"], tmp_path)
    browser.get(view(out).path.as_uri())
    assert browser.run("return [innerWidth, innerHeight, scrollY]") == [1400, 1000, 0]
    panel, rule = _rect(browser, ".map-scroll"), _rect(browser, ".scale-bar .rule")
    shown = _rect(browser, "#map")
    for box in (shown, rule):
        assert box["left"] >= panel["left"] and box["right"] <= panel["right"] and box["top"] >= panel["top"]
        assert box["bottom"] <= panel["bottom"] <= 1000 and box["right"] <= 1400, (box, panel)
    assert browser.run(
        "var s = document.querySelector('.map-scroll'); return s.scrollHeight <= s.clientHeight && "
        "s.scrollWidth <= s.clientWidth;"
    )  # no scrollbar at the fit
    # The map keeps its aspect ratio, and fills the panel's height or width.
    width_m, height_m = (400.0, 400.0) if shape == "detect" else (262.0, 600.0)
    assert shown["width"] / shown["height"] == pytest.approx(width_m / height_m, rel=1e-3)
    assert shown["bottom"] > 950 or shown["right"] > panel["right"] - 4
    # The screenshot shows the scale bar's rule in its own colour where the page says it is.
    pixels = matplotlib_pixels(browser.screenshot())
    assert pixels.shape == (1000, 1400, 4)
    y, x = int((rule["top"] + rule["bottom"]) / 2), int((rule["left"] + rule["right"]) / 2)
    assert tuple(pixels[y, x, :3]) == (0x1D, 0x21, 0x25)


def test_a_click_on_a_site_marks_it_and_the_map_zooms_and_pans(browser, outputs, tmp_path):
    out = copy_of(outputs["detect"], tmp_path)
    browser.get(view(out).path.as_uri())
    ranks = browser.run(
        "return Array.prototype.map.call(document.querySelectorAll('.site-marker'), function (m) { "
        "return m.dataset.rank; });"
    )
    top = ranks[-1]  # the last drawn: no other circle over it
    browser.click(f".site-marker[data-rank='{top}'] circle.halo")  # intercepted were an overlay over the map
    assert browser.run(
        "return Array.prototype.map.call(document.querySelectorAll('.selected'), function (e) { "
        "return e.dataset.rank; });"
    ) == [top, top]
    fit = _rect(browser, "#map")
    browser.click("button.zoom[data-zoom='2']")  # twice the fit, about the panel's centre
    assert _rect(browser, "#map")["width"] == pytest.approx(2 * fit["width"], abs=0.5)
    browser.click("button.zoom[data-zoom='pixels']")  # one image pixel per CSS pixel
    assert _rect(browser, "#map")["width"] == pytest.approx(400.0, abs=0.5)
    browser.click("button.zoom[data-zoom='1']")
    assert _rect(browser, "#map")["width"] == pytest.approx(fit["width"], abs=0.5)
    # The wheel zooms by 1.25 about the pointer: the map point under it stays under it (the map at 2x
    # overflows its panel both ways, so that it can be scrolled to stay).
    browser.click("button.zoom[data-zoom='2']")
    panel, two = _rect(browser, ".map-scroll"), _rect(browser, "#map")
    px, py = int(panel["left"] + 0.4 * panel["width"]), int(panel["top"] + 0.6 * panel["height"])
    fx, fy = (px - two["left"]) / two["width"], (py - two["top"]) / two["height"]
    browser.wheel(px, py, -100)
    zoomed = _wait_for(
        browser,
        "var r = document.getElementById('map').getBoundingClientRect(); return r.width > arguments[0] + 1 && r;",
        two["width"],
    )
    assert zoomed["width"] == pytest.approx(2.5 * fit["width"], abs=0.5)
    assert (px - zoomed["left"]) / zoomed["width"] == pytest.approx(fx, abs=0.002)
    assert (py - zoomed["top"]) / zoomed["height"] == pytest.approx(fy, abs=0.002)
    # A drag pans by as much as the pointer moved, and selects no site on its way.
    before = browser.run("var s = document.querySelector('.map-scroll'); return [s.scrollLeft, s.scrollTop];")
    browser.pointer(
        {"type": "pointerMove", "x": px, "y": py, "duration": 0},
        {"type": "pointerDown", "button": 0},
        {"type": "pointerMove", "x": px - 40, "y": py - 30, "duration": 50},
        {"type": "pointerUp", "button": 0},
    )
    after = browser.run("var s = document.querySelector('.map-scroll'); return [s.scrollLeft, s.scrollTop];")
    assert after[0] - before[0] == pytest.approx(40, abs=1) and after[1] - before[1] == pytest.approx(30, abs=1)
    assert _problems(browser) == []
