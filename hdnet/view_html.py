"""The HTML of ``hd view``: one self-contained page (its style, its script and its images inside it).

Nothing on a page is fetched: images are ``data:`` URIs, the style and the script are inline, and
the page's Content-Security-Policy (``default-src 'none'``) lets a browser load nothing else, so a
page opened offline, mailed or archived shows all it has. The policy allows the page's own style
block and script block by their SHA-256 (:func:`csp`, computed from the exact text written) and
nothing inline besides: no other ``<script>``, no ``on...=`` handler, no ``style="..."`` attribute
runs or applies, so a text that slipped through unescaped could still not run. Every text taken from
a file is escaped (:func:`esc`) all the same. What a page needs of its own (the colour bars'
gradients, the map's aspect ratio, where H_t stands) is a rule of its style block, given to
:func:`page` as ``style``. The page names its maker in ``<meta name="generator">``
(:data:`GENERATOR`), by which ``hd view`` recognises a page it may replace.

Building blocks: :func:`page` (the document), :func:`table`, :func:`definitions` (name/value
rows), :func:`data_uri`, and :func:`markdown_html`, which renders the Markdown that hd writes for a
report (headings, bullet lists, pipe tables, paragraphs, images, ``code`` and ``**bold**``).
"""

from __future__ import annotations

import base64
import hashlib
import html
import re
from collections.abc import Iterable, Mapping, Sequence

from hdnet._version import __version__

GENERATOR = "hd view"

STYLE = """
:root { --fg: #1d2125; --muted: #5c6670; --line: #d5dae0; --band: #f4f6f8; --accent: #1f5fbf; }
* { box-sizing: border-box; }
body { font: 14px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; color: var(--fg);
  margin: 0 auto; padding: 16px 24px 48px; max-width: 1600px; }
h1 { font-size: 22px; margin: 8px 0 4px; } h2 { font-size: 18px; margin: 28px 0 8px; border-bottom: 1px solid
  var(--line); padding-bottom: 4px; } h3 { font-size: 15px; margin: 20px 0 6px; }
.sub { color: var(--muted); margin: 0 0 12px; word-break: break-all; }
.note { color: var(--muted); font-size: 13px; }
.warning { background: #fff4e0; border: 1px solid #e0a040; padding: 8px 12px; border-radius: 4px; margin: 8px 0; }
code, pre { font: 12.5px/1.4 ui-monospace, SFMono-Regular, Menlo, Consolas, monospace; }
code { background: var(--band); padding: 0 3px; border-radius: 3px; word-break: break-all; }
pre { background: var(--band); padding: 10px; overflow: auto; max-height: 480px; }
table { border-collapse: collapse; margin: 6px 0 14px; font-size: 13px; }
th, td { border: 1px solid var(--line); padding: 3px 8px; text-align: left; vertical-align: top; }
th { background: var(--band); font-weight: 600; }
td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; }
table.defs th { width: 16em; } table.defs td { word-break: break-all; }
nav.toc { font-size: 13px; } nav.toc a { margin-right: 12px; }
.layout { display: flex; gap: 16px; align-items: flex-start; }
.controls { flex: 0 0 290px; position: sticky; top: 8px; }
.controls fieldset { border: 1px solid var(--line); margin: 0 0 10px; padding: 6px 10px; }
.layer-control { margin: 6px 0 10px; }
.layer-control label { font-weight: 600; }
.layer-control input[type=range] { width: 100%; margin: 2px 0; }
.legend { font-size: 12px; color: var(--muted); }
.bar { height: 10px; border: 1px solid var(--line); position: relative; margin-top: 2px; }
.bar .tick { position: absolute; top: -3px; bottom: -3px; width: 2px; background: #000; }
.tick-label { position: relative; height: 1.4em; margin-top: 2px; }
.tick-label span { position: absolute; white-space: nowrap; color: var(--fg); font-weight: 600; }
.bar-labels { display: flex; justify-content: space-between; }
.swatch { display: inline-block; width: 11px; height: 11px; border: 1px solid #888; margin: 0 3px 0 8px;
  vertical-align: -1px; }
.map-scroll { flex: 1 1 0; min-width: 0; overflow: auto; max-height: 88vh; border: 1px solid var(--line);
  background: #fff; cursor: grab; }
.map-scroll.dragging { cursor: grabbing; }
.map { position: relative; width: 100%; }
.map .layer { position: absolute; left: 0; top: 0; width: 100%; height: 100%; image-rendering: pixelated;
  user-select: none; -webkit-user-drag: none; }
.map svg.layer { overflow: visible; pointer-events: none; }
.site-marker { cursor: pointer; pointer-events: visiblePainted; }
.site-marker circle { fill: none; }
.site-marker .halo { stroke: #000; stroke-width: 3px; pointer-events: all; }
.site-marker .ring { stroke: #fff; stroke-width: 1.4px; }
.site-marker.selected .ring { stroke: #ffd400; stroke-width: 2.5px; }
.site-marker .margin { stroke: #fff; stroke-width: 1.2px; stroke-dasharray: 4 3; }
.site-marker text { fill: #000; paint-order: stroke; stroke: #fff; stroke-width: 3px; font-weight: 700; }
.scale-bar .box { fill: #fff; fill-opacity: 0.85; stroke: #5c6670; }
.scale-bar .rule { fill: #1d2125; }
.scale-bar text { fill: #1d2125; font-weight: 400; font-style: italic; }
#readout { font: 12.5px ui-monospace, Menlo, Consolas, monospace; min-height: 1.4em; }
button.zoom { margin-right: 4px; }
button.zoom.active { font-weight: 700; }
tr.site-row { cursor: pointer; } tr.site-row:hover { background: #eef3fb; }
tr.site-row.selected { background: #fff3b0; }
figure { margin: 12px 0 20px; } figure img { max-width: 100%; height: auto; border: 1px solid var(--line); }
figcaption { color: var(--muted); font-size: 13px; }
"""

# The page's behaviour: layer visibility and opacity, zoom, what is under the pointer (map coordinates,
# the cell's class and the maps' values read back from the layers' colours), and the
# selection of a landing site (a table row and its marker together).
SCRIPT = """
(function () {
  "use strict";
  function each(selector, f) { Array.prototype.forEach.call(document.querySelectorAll(selector), f); }
  each("input.layer-toggle", function (box) {
    var layer = document.getElementById(box.dataset.layer);
    function apply() { layer.style.display = box.checked ? "" : "none"; }
    box.addEventListener("change", apply);
    apply();
  });
  each("input.layer-opacity", function (slider) {
    var layer = document.getElementById(slider.dataset.layer);
    function apply() { layer.style.opacity = String(Number(slider.value) / 100); }
    slider.addEventListener("input", apply);
    apply();
  });
  var map = document.getElementById("map");
  if (!map) { return; }
  var d = map.dataset, pxWide = Number(d.px), pxHigh = Number(d.pxHeight);
  var scroller = map.parentNode;
  // The map's size: "relative" times the fit (the whole map in its panel and the window), or one
  // image pixel per CSS pixel ("pixels").
  var zoom = {relative: 1, pixels: false};
  function room() {
    var box = scroller.getBoundingClientRect(), top = box.top + window.scrollY;
    var high = Math.max(window.innerHeight - top - 16, 0.6 * window.innerHeight);
    return {wide: Math.max(box.width - 2, 1), high: Math.max(high, 1)};
  }
  function fitScale() { var r = room(); return Math.min(r.wide / pxWide, r.high / pxHigh); }
  function apply() {
    var r = room(), s = zoom.pixels ? 1 : zoom.relative * Math.min(r.wide / pxWide, r.high / pxHigh);
    scroller.style.maxHeight = String(r.high + 2) + "px";
    map.style.width = String(pxWide * s) + "px";
    map.style.height = String(pxHigh * s) + "px";
    each("button.zoom", function (button) {
      var z = button.dataset.zoom;
      button.classList.toggle("active", zoom.pixels ? z === "pixels" : Number(z) === zoom.relative);
    });
  }
  // Zoom about a point of the window (cx, cy; the panel's centre when not given): it stays where it is.
  function setZoom(pixels, relative, cx, cy) {
    var before = map.getBoundingClientRect(), panel = scroller.getBoundingClientRect();
    if (cx === undefined) { cx = panel.left + panel.width / 2; cy = panel.top + panel.height / 2; }
    var fx = (cx - before.left) / before.width, fy = (cy - before.top) / before.height;
    zoom.pixels = pixels;
    zoom.relative = relative;
    apply();
    var after = map.getBoundingClientRect();
    scroller.scrollLeft += after.left + fx * after.width - cx;
    scroller.scrollTop += after.top + fy * after.height - cy;
  }
  each("button.zoom", function (button) {
    button.addEventListener("click", function () {
      var z = button.dataset.zoom;
      setZoom(z === "pixels", z === "pixels" ? 1 : Number(z));
    });
  });
  scroller.addEventListener("wheel", function (event) {
    event.preventDefault();
    var now = zoom.pixels ? 1 / fitScale() : zoom.relative;
    var next = Math.min(64, Math.max(1, now * (event.deltaY < 0 ? 1.25 : 0.8)));
    setZoom(false, Math.abs(next - 1) < 1e-6 ? 1 : next, event.clientX, event.clientY);
  }, {passive: false});
  // Drag to pan; a drag that ends on a site is no click on it.
  var drag = null, dragged = false;
  scroller.addEventListener("mousedown", function (event) {
    dragged = false;
    if (event.button !== 0 || !map.contains(event.target)) { return; }
    drag = {x: event.clientX, y: event.clientY, left: scroller.scrollLeft, top: scroller.scrollTop};
    event.preventDefault();
  });
  window.addEventListener("mousemove", function (event) {
    if (!drag) { return; }
    var dx = event.clientX - drag.x, dy = event.clientY - drag.y;
    if (Math.abs(dx) + Math.abs(dy) > 3) { dragged = true; scroller.classList.add("dragging"); }
    scroller.scrollLeft = drag.left - dx;
    scroller.scrollTop = drag.top - dy;
  });
  window.addEventListener("mouseup", function () { drag = null; scroller.classList.remove("dragging"); });
  scroller.addEventListener("click", function (event) { if (dragged) { event.stopPropagation(); } }, true);
  window.addEventListener("resize", apply);
  apply();
  var readout = document.getElementById("readout");
  function fmt(v) { return v.toFixed(Math.abs(v) < 1e4 ? 2 : 1); }
  // Each map image with data-probe: its pixels (read once decoded) and how a colour becomes a value.
  var probes = [];
  each("img.layer[data-probe]", function (img) {
    var probe = {img: img, pixels: null, classes: null, index: null, n: 0};
    if (img.dataset.classes) { probe.classes = JSON.parse(img.dataset.classes); }
    if (img.dataset.lut) {
      var table = img.dataset.lut.split(" ");
      probe.index = new Map();
      probe.n = table.length;
      table.forEach(function (colour, i) { probe.index.set(colour, i); });
    }
    function grab() {
      var canvas = document.createElement("canvas");
      canvas.width = img.naturalWidth;
      canvas.height = img.naturalHeight;
      var context = canvas.getContext("2d", {willReadFrequently: true});
      context.drawImage(img, 0, 0);
      probe.pixels = context.getImageData(0, 0, canvas.width, canvas.height).data;
    }
    if (img.complete && img.naturalWidth) { grab(); } else { img.addEventListener("load", grab); }
    probes.push(probe);
  });
  probes.sort(function (a, b) { return Number(a.img.dataset.order) - Number(b.img.dataset.order); });
  function hex(p, k) {
    return "#" + [p[k], p[k + 1], p[k + 2]].map(function (v) { return (v < 16 ? "0" : "") + v.toString(16); }).join("");
  }
  function values(fx, fy) {
    var words = [];
    probes.forEach(function (probe) {
      var img = probe.img, w = img.naturalWidth, h = img.naturalHeight;
      if (!probe.pixels) { return; }
      var col = Math.min(w - 1, Math.floor(fx * w)), row = Math.min(h - 1, Math.floor(fy * h));
      var k = 4 * (row * w + col), colour = hex(probe.pixels, k);
      if (probe.pixels[k + 3] === 0) { return; }
      if (probe.classes) {
        if (colour in probe.classes) { words.push(probe.classes[colour]); }
        return;
      }
      var i = probe.index.get(colour);
      if (i === undefined) { return; }
      var lo = Number(img.dataset.min), hi = Number(img.dataset.max);
      words.push(img.dataset.probe + " ≈ " + (lo + (i + 0.5) / probe.n * (hi - lo)).toFixed(3) + img.dataset.unit);
    });
    return words.length ? ": " + words.join(", ") : " (no valid cell)";
  }
  map.addEventListener("mousemove", function (event) {
    var r = map.getBoundingClientRect();
    function within(v) { return Math.min(Math.max(v, 0), 0.999999); }
    var fx = within((event.clientX - r.left) / r.width), fy = within((event.clientY - r.top) / r.height);
    var x = Number(d.left) + fx * Number(d.width), y = Number(d.top) - fy * Number(d.height);
    readout.textContent = "x " + fmt(x) + " m, y " + fmt(y) + " m" + values(fx, fy);
  });
  map.addEventListener("mouseleave", function () { readout.textContent = ""; });
  function select(rank, scroll) {
    each(".site-marker, tr.site-row", function (el) {
      el.classList.toggle("selected", el.dataset.rank === rank);
    });
    var target = document.querySelector(
      (scroll === "row" ? "tr.site-row" : ".site-marker") + "[data-rank='" + rank + "']");
    if (target && target.scrollIntoView) { target.scrollIntoView({block: "nearest", inline: "nearest"}); }
  }
  each("tr.site-row", function (row) {
    row.addEventListener("click", function () { select(row.dataset.rank, "marker"); });
  });
  each(".site-marker", function (marker) {
    marker.addEventListener("click", function () { select(marker.dataset.rank, "row"); });
  });
})();
"""


# A descent page's own style (``hd view`` of an ``hd descend`` output), after STYLE: each descent's map
# (its frames stacked, one shown), the frame stepper and the site track drawn over the maps.
DESCENT_STYLE = """
.descent-panel { flex: 1 1 0; min-width: 0; max-width: 820px; }
.descent-map { position: relative; width: 100%; border: 1px solid var(--line); background: #fff; }
.descent-map .frame { position: absolute; left: 0; top: 0; width: 100%; height: 100%; }
.descent-map .no-map { position: absolute; left: 8px; top: 8px; margin: 0; background: #fff4e0;
  border: 1px solid #e0a040; padding: 4px 8px; border-radius: 4px; font-size: 13px; }
.stepper { display: flex; gap: 6px; align-items: center; }
.stepper input[type=range] { flex: 1 1 auto; }
.frame-label { font-weight: 600; min-height: 2.9em; margin: 4px 0; }
.track-line { fill: none; stroke: #ffffff; stroke-width: 2.5px; }
.track-line-under { fill: none; stroke: #000; stroke-width: 4.5px; }
.track-point { fill: #fff; stroke: #000; stroke-width: 1px; }
.aim-ring { fill: none; stroke: #ffd400; stroke-width: 2.5px; }
.aim-halo { fill: none; stroke: #000; stroke-width: 4.5px; }
.site-dot { fill: none; stroke: #fff; stroke-width: 1px; stroke-dasharray: 2 2; }
.divert-arrow { stroke: #ff2d9b; stroke-width: 2.5px; fill: none; }
.divert-head { fill: #ff2d9b; stroke: none; }
.divert-label { fill: #000; paint-order: stroke; stroke: #fff; font-weight: 700; }
tr.frame-row { cursor: pointer; } tr.frame-row:hover { background: #eef3fb; }
tr.frame-row.selected { background: #fff3b0; }
"""

# A descent page's behaviour, after SCRIPT: per descent section, the frame shown (slider, step buttons,
# a click on a frame's row), the layers' visibility and opacity (every frame's layer of that name), and
# the map coordinates under the pointer.
DESCENT_SCRIPT = """
(function () {
  "use strict";
  function all(root, selector) { return Array.prototype.slice.call(root.querySelectorAll(selector)); }
  all(document, "section.descent").forEach(function (section) {
    var frames = all(section, ".frame"), slider = section.querySelector("input.frame-slider");
    var label = section.querySelector(".frame-label"), rows = all(section, "tr.frame-row");
    function show(k) {
      k = Math.max(0, Math.min(frames.length - 1, k));
      slider.value = String(k);
      frames.forEach(function (f) { f.hidden = Number(f.dataset.frame) !== k; });
      rows.forEach(function (r) { r.classList.toggle("selected", Number(r.dataset.frame) === k); });
      label.textContent = frames[k].dataset.label;
      section.dataset.shown = String(k);
    }
    slider.addEventListener("input", function () { show(Number(slider.value)); });
    all(section, "button.frame-step").forEach(function (button) {
      button.addEventListener("click", function () { show(Number(slider.value) + Number(button.dataset.step)); });
    });
    rows.forEach(function (row) { row.addEventListener("click", function () { show(Number(row.dataset.frame)); }); });
    all(section, "input.descent-toggle").forEach(function (box) {
      function apply() {
        all(section, ".layer-" + box.dataset.key).forEach(function (l) {
          l.style.display = box.checked ? "" : "none";
        });
      }
      box.addEventListener("change", apply);
      apply();
    });
    all(section, "input.descent-opacity").forEach(function (slide) {
      function apply() {
        all(section, ".layer-" + slide.dataset.key).forEach(function (l) {
          l.style.opacity = String(Number(slide.value) / 100);
        });
      }
      slide.addEventListener("input", apply);
      apply();
    });
    var map = section.querySelector(".descent-map"), readout = section.querySelector(".descent-readout");
    map.addEventListener("mousemove", function (event) {
      var r = map.getBoundingClientRect(), d = map.dataset;
      var x = Number(d.left) + (event.clientX - r.left) / r.width * Number(d.width);
      var y = Number(d.top) - (event.clientY - r.top) / r.height * Number(d.height);
      readout.textContent = "x " + x.toFixed(1) + " m, y " + y.toFixed(1) + " m";
    });
    map.addEventListener("mouseleave", function () { readout.textContent = ""; });
    show(Number(slider.value));
  });
})();
"""


def esc(text: object) -> str:
    """``text`` as HTML text or attribute value (``&``, ``<``, ``>`` and both quotes escaped)."""
    return html.escape(str(text), quote=True)


def data_uri(png: bytes) -> str:
    """A ``data:`` URI of PNG bytes."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def source_hash(text: str) -> str:
    """The CSP source expression that allows an inline block whose text is ``text``:
    ``'sha256-<base64 of the SHA-256 of its UTF-8 bytes>'``."""
    digest = base64.b64encode(hashlib.sha256(text.encode("utf-8")).digest()).decode("ascii")
    return f"'sha256-{digest}'"


def csp(style: str, script: str) -> str:
    """The page's Content-Security-Policy: nothing fetched (``default-src 'none'``), images from
    ``data:`` URIs, and of inline content only the style block ``style`` and the script block
    ``script`` (by their hashes; no ``'unsafe-inline'``)."""
    return (
        f"default-src 'none'; img-src data:; style-src {source_hash(style)}; script-src {source_hash(script)}; "
        "base-uri 'none'; form-action 'none'"
    )


def page(title: str, body: str, description: str = "", style: str = "", script: str = "") -> str:
    """The whole HTML document: ``title`` (text) and ``body`` (HTML), with the style and script inline
    and the policy that allows them and nothing else inline (:func:`csp`). ``style``: CSS rules of this
    page (made by hd, never of a file's text), after the common ones; ``script``: this page's own
    script (one of this module's, e.g. :data:`DESCENT_SCRIPT`), after the common one, in the same block.

    Raises:
        ValueError: ``style`` holds ``<`` (it could end the style block), ``script`` holds ``</`` (it
            could end the script block).
    """
    if "<" in style:
        raise ValueError("a page's style holds '<'")
    if "</" in script:
        raise ValueError("a page's script holds '</'")
    sheet = STYLE + style
    code = SCRIPT + script
    return (
        "<!DOCTYPE html>\n"
        '<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f'<meta name="generator" content="{GENERATOR} {esc(__version__)}">\n'
        f'<meta http-equiv="Content-Security-Policy" content="{csp(sheet, code)}">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        + (f'<meta name="description" content="{esc(description)}">\n' if description else "")
        + f"<title>{esc(title)}</title>\n<style>{sheet}</style>\n</head>\n<body>\n{body}\n"
        f"<script>{code}</script>\n</body>\n</html>\n"
    )


_NAME = re.compile(r"[a-z][a-z0-9_-]*")
_COLOUR = re.compile(r"#[0-9a-fA-F]{6}")


def map_style(
    aspect: tuple[float, float],
    gradients: Mapping[str, Sequence[str]],
    swatches: Mapping[str, str],
    tick: float | None = None,
) -> str:
    """The style rules of a detect page's map, for :func:`page`'s ``style``: the map's aspect ratio
    (``aspect``: its width and height, metres), each colour bar's gradient (class ``bar-NAME``, its
    ``#rrggbb`` colours left to right), each legend swatch's colour (class ``swatch-NAME``) and where
    the threshold H_t stands on its bar (``tick``, 0 to 1 of the bar's width: classes ``tick-at`` and
    ``tick-label-at``).

    Raises:
        ValueError: a name that is not a plain class name, a colour that is not ``#rrggbb`` or an
            aspect that is not two positive finite numbers (the rules hold nothing else).
    """
    width, height = (float(v) for v in aspect)
    if not (0.0 < width < float("inf") and 0.0 < height < float("inf")):
        raise ValueError(f"map aspect {aspect!r}")
    colours = [*(c for stops in gradients.values() for c in stops), *swatches.values()]
    if not all(_NAME.fullmatch(n) for n in [*gradients, *swatches]) or not all(_COLOUR.fullmatch(c) for c in colours):
        raise ValueError("a map style's class name or colour")
    rules = [f"#map {{ aspect-ratio: {width:.6f} / {height:.6f}; }}"]
    rules += [f".bar-{n} {{ background: linear-gradient(to right, {', '.join(c)}); }}" for n, c in gradients.items()]
    rules += [f".swatch-{n} {{ background: {c}; }}" for n, c in swatches.items()]
    if tick is not None:
        at = 100.0 * min(max(float(tick), 0.0), 1.0)
        rules.append(f".tick-at {{ left: calc({at:.2f}% - 1px); }}")
        # The label starts at the tick on the bar's left half and ends there on its right half.
        rules.append(f".tick-label-at {{ {'left' if at <= 50 else 'right'}: {min(at, 100 - at):.2f}%; }}")
    return "\n".join(rules) + "\n"


def is_page(head: bytes) -> bool:
    """True when ``head`` (the first bytes of a file) is the start of a page ``hd view`` wrote."""
    text = head[:4096].decode("utf-8", errors="replace")
    return text.startswith("<!DOCTYPE html>") and f'<meta name="generator" content="{GENERATOR} ' in text


NUMERIC = ' class="num"'  # the attribute of a right-aligned number's cell


def _numeric(cell: str) -> bool:
    return bool(re.fullmatch(r"[-+]?(\d+(\.\d*)?|\.\d+)([eE][-+]?\d+)?( ?%)?|--", cell.strip()))


def table(
    header: Sequence[str],
    rows: Iterable[Sequence[str]],
    *,
    table_id: str = "",
    row_attrs: Sequence[Mapping[str, str]] | None = None,
    header_titles: Sequence[str] | None = None,
) -> str:
    """An HTML table of text cells (escaped); numeric cells right-aligned. ``row_attrs``: each body
    row's attributes (``class``, ``data-*``); ``header_titles``: each column's tooltip."""
    attrs = list(row_attrs or [])
    titles = list(header_titles or [])
    head = "".join(
        f"<th{f' title={_q(titles[i])}' if i < len(titles) and titles[i] else ''}>{esc(h)}</th>"
        for i, h in enumerate(header)
    )
    body = []
    for k, row in enumerate(rows):
        extra = "".join(f" {esc(n)}={_q(v)}" for n, v in (attrs[k] if k < len(attrs) else {}).items())
        cells = "".join(f"<td{NUMERIC if _numeric(c) else ''}>{esc(c)}</td>" for c in row)
        body.append(f"<tr{extra}>{cells}</tr>")
    ident = f" id={_q(table_id)}" if table_id else ""
    return f"<table{ident}>\n<thead><tr>{head}</tr></thead>\n<tbody>\n" + "\n".join(body) + "\n</tbody>\n</table>"


def definitions(items: Iterable[tuple[str, str]], table_id: str = "") -> str:
    """A two-column table of names and values (both text, escaped)."""
    rows = "\n".join(f"<tr><th>{esc(k)}</th><td>{esc(v)}</td></tr>" for k, v in items)
    ident = f" id={_q(table_id)}" if table_id else ""
    return f'<table class="defs"{ident}>\n<tbody>\n{rows}\n</tbody>\n</table>'


def _q(value: str) -> str:
    return f'"{esc(value)}"'


def anchor(text: str) -> str:
    """An element id made of a heading's text (``Table 1: noise levels`` -> ``table-1-noise-levels``)."""
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "section"


# --------------------------------------------------------------------------------------- Markdown
_TABLE_RULE = re.compile(r"^\|(\s*:?-+:?\s*\|)+\s*$")
_IMAGE = re.compile(r"^!\[([^\]]*)\]\(([^)\s]+)\)$")


def _inline(text: str) -> str:
    """Escaped text with hd's inline Markdown: ``code`` and **bold** (code spans first, verbatim)."""
    out = []
    for k, part in enumerate(re.split(r"`([^`]*)`", text)):
        if k % 2:
            out.append(f"<code>{esc(part)}</code>")
        else:
            out.append(re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", esc(part)))
    return "".join(out)


def _cells(line: str) -> list[str]:
    """The cells of a pipe-table row (``\\|`` is a pipe inside a cell)."""
    inner = line.strip()[1:-1] if line.strip().endswith("|") else line.strip()[1:]
    return [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", inner)]


def markdown_html(markdown: str, images: Mapping[str, tuple[str, int, int]] | None = None) -> tuple[str, list[str]]:
    """HTML of the Markdown hd writes, and the headings (level 2) in order, for a table of contents.

    ``images``: an image's target (``reliability.png``) -> (data URI, width, height); an image line
    whose target is not there is shown as its text.
    """
    figures = images or {}
    lines = markdown.splitlines()
    out: list[str] = []
    headings: list[str] = []
    i = 0
    while i < len(lines):
        line = lines[i]
        stripped = line.strip()
        if not stripped:
            i += 1
            continue
        heading = re.match(r"^(#{1,4}) (.*)$", stripped)
        if heading:
            level, text = len(heading.group(1)), heading.group(2).strip()
            if level == 2:
                headings.append(text)
            out.append(f"<h{level} id={_q(anchor(text))}>{_inline(text)}</h{level}>")
            i += 1
            continue
        if stripped.startswith("|") and i + 1 < len(lines) and _TABLE_RULE.match(lines[i + 1].strip()):
            header = _cells(stripped)
            body = []
            i += 2
            while i < len(lines) and lines[i].strip().startswith("|"):
                body.append(_cells(lines[i]))
                i += 1
            out.append(table(header, body))
            continue
        if stripped.startswith("- "):
            items = []
            while i < len(lines) and lines[i].strip().startswith("- "):
                items.append(f"<li>{_inline(lines[i].strip()[2:])}</li>")
                i += 1
            out.append("<ul>\n" + "\n".join(items) + "\n</ul>")
            continue
        image = _IMAGE.match(stripped)
        if image:
            alt, target = image.groups()
            if target in figures:
                uri, w, h = figures[target]
                out.append(
                    f'<figure id={_q("figure-" + anchor(alt))}><img src="{uri}" width="{w}" height="{h}" '
                    f"alt={_q(alt)}><figcaption>{esc(target)} ({w} x {h} px)</figcaption></figure>"
                )
            else:
                out.append(f"<p>{_inline(stripped)}</p>")
            i += 1
            continue
        para = []
        while i < len(lines) and lines[i].strip() and not re.match(r"^(#{1,4} |\||- |!\[)", lines[i].strip()):
            para.append(lines[i].strip())
            i += 1
        out.append(f"<p>{_inline(' '.join(para))}</p>")
    return "\n".join(out), headings


def colour_bar(name: str, low: str, high: str, tick: float | None = None, tick_label: str = "") -> str:
    """A colour bar (its gradient: the page style's ``bar-NAME``) from ``low`` to ``high``, with the
    threshold's tick and its label above the bar where ``tick`` (0 to 1 of its width) is given (their
    place: the page style's ``tick-at`` and ``tick-label-at``, :func:`hdnet.view_html.map_style`)."""
    mark, label = "", ""
    if tick is not None:
        mark = f'<span class="tick tick-at" title="{esc(tick_label)}: the threshold"></span>'
        label = f'<div class="tick-label"><span class="tick-label-at">{esc(tick_label)}</span></div>'
    return (
        f'{label}<div class="bar bar-{name}">{mark}</div>'
        f'<div class="bar-labels"><span>{esc(low)}</span><span>{esc(high)}</span></div>'
    )
