"""One palette of the safety classes: colour-blind safe, and the same in every figure, map and legend.

Colour-vision deficiency is simulated with Machado, Oliveira and Fernandes (2009)'s matrices at full
severity, applied to linear RGB; colours are compared in CIELAB (D65) by CIE76 ΔE.
"""

from __future__ import annotations

import itertools

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.colors import to_hex, to_rgb
from matplotlib.patches import Patch

from hdnet import palette
from hdnet.figures import SAFETY_COLOURS, detect_overview, qualitative_figure, safety_legend_handles
from hdnet.sites import SAFETY_INVALID, SAFETY_SAFE, SAFETY_UNCERTAIN, SAFETY_UNSAFE
from hdnet.view_images import safety_classes, safety_rgba

# Machado et al. 2009, Table 1, severity 1.0: linear RGB -> linear RGB as seen.
MACHADO = {
    "protanopia": np.array(
        [[0.152286, 1.052583, -0.204868], [0.114503, 0.786281, 0.099216], [-0.003882, -0.048116, 1.051998]]
    ),
    "deuteranopia": np.array(
        [[0.367322, 0.860646, -0.227968], [0.280085, 0.672501, 0.047413], [-0.011820, 0.042940, 0.968881]]
    ),
    "normal vision": np.eye(3),
}
SRGB_TO_XYZ = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
D65 = np.array([0.95047, 1.0, 1.08883])
MIN_DELTA_E = 20.0  # clearly distinguishable side by side (a just-noticeable difference is ~2.3)


def linear(rgb: np.ndarray) -> np.ndarray:
    return np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)


def lab(linear_rgb: np.ndarray) -> np.ndarray:
    t = (SRGB_TO_XYZ @ np.clip(linear_rgb, 0.0, 1.0)) / D65
    f = np.where(t > (6 / 29) ** 3, np.cbrt(t), t / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


def test_the_lab_conversion_is_the_standard_one():
    np.testing.assert_allclose(lab(linear(np.ones(3))), [100.0, 0.0, 0.0], atol=0.02)
    np.testing.assert_allclose(lab(linear(np.array([1.0, 0.0, 0.0]))), [53.24, 80.09, 67.20], atol=0.05)
    # Machado's matrices keep grey grey (each row sums to 1).
    for matrix in MACHADO.values():
        np.testing.assert_allclose(matrix.sum(axis=1), 1.0, atol=1e-5)


@pytest.mark.parametrize("vision", list(MACHADO))
def test_every_pair_of_classes_stays_distinguishable(vision):
    seen = {
        name: lab(MACHADO[vision] @ linear(np.array(to_rgb(c))))
        for name, c in zip(("unsafe", "safe", "uncertain", "invalid"), palette.SAFETY_HEX, strict=True)
    }
    for (a, la), (b, lb) in itertools.combinations(seen.items(), 2):
        assert np.linalg.norm(la - lb) > MIN_DELTA_E, f"{a} and {b} under {vision}"


def test_a_red_green_pair_fails_the_same_check():
    """The check can fail: matplotlib's tab:red and tab:green, 120 ΔE apart, are 7 apart for a deuteranope
    (hd's former red and green, 108 apart, kept 21)."""
    red, green = ([lab(m @ linear(np.array(to_rgb(c)))) for m in MACHADO.values()] for c in ("#d62728", "#2ca02c"))
    distances = [float(np.linalg.norm(r - g)) for r, g in zip(red, green, strict=True)]
    assert distances[1] < MIN_DELTA_E < distances[2]


def test_maps_legends_and_pages_draw_the_palettes_colours():
    hexes = [c.lower() for c in palette.SAFETY_HEX]
    # The figures' class codes 0..3.
    assert [to_hex(SAFETY_COLOURS(k)) for k in range(4)] == hexes
    assert [to_hex(h.get_facecolor()) for h in safety_legend_handles()] == hexes
    # hd view's safety layer, opaque, and the classes read back from it.
    codes = np.array([[SAFETY_UNSAFE, SAFETY_SAFE, SAFETY_UNCERTAIN, SAFETY_INVALID]], np.uint8)
    rgba = safety_rgba(codes)[0]
    assert [to_hex(px[:3] / 255) for px in rgba[:3]] == hexes[:3] and rgba[:3, 3].tolist() == [255] * 3
    assert rgba[3, 3] == 0  # invalid: transparent over the hillshade
    assert safety_classes() == {hexes[0]: "unsafe", hexes[1]: "safe", hexes[2]: "uncertain"}


def test_the_pages_safety_layer_is_opaque_so_its_swatches_are_what_the_map_shows():
    from hdnet.view import SAFETY_OPACITY, SWATCHES
    from hdnet.view_html import map_style

    assert SAFETY_OPACITY == 100
    style = map_style((1.0, 1.0), {}, dict(zip(SWATCHES, palette.SAFETY_HEX, strict=False)))
    for name, colour in zip(SWATCHES, palette.SAFETY_HEX, strict=False):
        assert f".swatch-{name} {{ background: {colour}; }}" in style


def test_the_overview_draws_the_legends_colours_unblended(tmp_path, monkeypatch):
    drawn: list[np.ndarray] = []
    legends: list[list[str]] = []
    save = matplotlib.figure.Figure.savefig

    def keep(fig, *args, **kwargs):
        ax = fig.axes[0]
        drawn.append(ax.get_images()[1].get_array())
        legends.append([to_hex(h.get_facecolor(), keep_alpha=True) for h in ax.get_legend().legend_handles[:3]])
        return save(fig, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", keep)
    safety = np.array([[0, 1], [2, 255]], np.uint8)
    detect_overview(np.zeros((2, 2)), 1.0, safety, (0.0, 2.0, 0.0, 2.0), [], 0.5, "t", tmp_path / "o.png")
    rgba = np.asarray(drawn[0])
    for code in (0, 1, 2):
        r, c = np.argwhere(safety == code)[0]
        assert to_hex(rgba[r, c], keep_alpha=True) == palette.SAFETY_HEX[code].lower() + "ff"
        assert legends[0][code] == palette.SAFETY_HEX[code].lower() + "ff"


def test_the_qualitative_label_panels_draw_invalid_in_the_invalid_colour():
    from test_figures import _inference

    fig = qualitative_figure(_inference(), 0, threshold_nats=0.3)
    try:
        label_panel = fig.axes[1].get_images()[0]
        invalid = label_panel.to_rgba(np.array([[3]]), norm=True)[0, 0]
        assert to_hex(invalid) == palette.INVALID.lower() != "#ffffff"
        faces = [to_hex(h.get_facecolor()) for h in fig.legends[0].legend_handles if isinstance(h, Patch)]
        assert faces[3] == palette.INVALID.lower()
    finally:
        plt.close(fig)
