"""Draw what the realistic sensor does to small terrain features, from lidarsim's own ray casting.

``sensor_realism_rock.png``: a hemispherical rock 0.4 m across (smaller than the 0.82 m footprint of
a pixel at 500 m) seen with one ray per pixel (K = 1) and with 5 x 5 sub-rays (K = 5);
``sensor_realism_step.png``: the mixed pixels of a 1 m step edge, both range estimators;
``sensor_realism_sigma.png``: the range noise's 1-sigma against incidence under the ``snr`` model,
the formula and the residuals measured on tilted planes.
Run: ``.venv/bin/python docs/figures/sensor_realism.py``; it prints the numbers quoted in docs/lidarsim.md.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from lidarsim.footprint import FootprintConfig
from lidarsim.noise import NoiseModel
from lidarsim.procedural import geotiff_bytes
from lidarsim.scan import ScanGeometry, ScanResult, TileScene, simulate_scans
from lidarsim.sensor import SensorConfig, ray_directions, sensor_attitude
from lidarsim.terrain import DTM

HERE = Path(__file__).parent
ALTITUDE_M = 500.0
IFOV_DEG = 12.0 / 128.0  # the paper's pixel, 1.64 mrad


def scene_of(heights: np.ndarray, spacing_m: float) -> tuple[TileScene, float, float]:
    """The ray-casting scene of a height grid (top-left corner at map (0, 0)) and its centre (x, y)."""
    side = heights.shape[0] * spacing_m
    data = geotiff_bytes(heights, spacing_m, origin_xy=(0.0, 0.0), name="figure.tif")
    with DTM.from_bytes(data, HERE / "figure.tif") as dtm:
        scene = TileScene(dtm, (side / 2, -side / 2), side / 2 - spacing_m)
    return scene, side / 2, -side / 2


def sensor_of(pixels: int) -> SensorConfig:
    """A square detector of ``pixels`` pixels of the paper's IFOV."""
    return SensorConfig(rows=pixels, cols=pixels, fov_x_deg=pixels * IFOV_DEG, fov_y_deg=pixels * IFOV_DEG)


def shoot(
    scene: TileScene,
    centre: tuple[float, float],
    pixels: int,
    footprint: FootprintConfig,
    noise: NoiseModel | None = None,
    sigma_m: float = 0.0167,
    z_ref: float = 0.0,
    altitude_m: float = ALTITUDE_M,
) -> ScanResult:
    """One nadir scan of ``pixels`` x ``pixels`` pixels of the paper's IFOV from ``altitude_m`` above
    (centre, z_ref)."""
    sensor = sensor_of(pixels)
    geometry = ScanGeometry(
        origin_map=np.array([centre[0], centre[1], z_ref]),
        sensor_position=np.array([0.0, 0.0, altitude_m]),
        attitude=sensor_attitude(0.0),
    )
    return simulate_scans(scene, [geometry], [0], sensor, (sigma_m,), 1, footprint=footprint, noise_model=noise)[0]


def rock_figure() -> None:
    """A 0.4 m hemispherical rock at K = 1 and K = 5: pixel heights and the profile through its centre."""
    radius, spacing, n = 0.2, 0.01, 600
    c = (np.arange(n) + 0.5) * spacing
    x, y = c - n * spacing / 2, n * spacing / 2 - c
    heights = np.sqrt(np.maximum(radius**2 - x[None, :] ** 2 - y[:, None] ** 2, 0.0))
    scene, cx, cy = scene_of(heights, spacing)
    pixels = 7
    seen = {k: shoot(scene, (cx, cy), pixels, FootprintConfig(samples=k)).points_clean for k in (1, 5)}
    fig, axes = plt.subplots(1, 3, figsize=(14, 4), layout="constrained")
    extent = pixels * ALTITUDE_M * math.radians(IFOV_DEG) / 2
    for ax, k in zip(axes[:2], (1, 5), strict=True):
        im = ax.imshow(seen[k][..., 2], extent=(-extent, extent, -extent, extent), vmin=0, vmax=radius, cmap="viridis")
        ax.add_patch(plt.Circle((0, 0), radius, fill=False, color="w", ls="--"))
        ax.set_title(f"K = {k}: peak {seen[k][..., 2].max() * 100:.1f} cm")
        ax.set_xlabel("x (m)")
    axes[0].set_ylabel("y (m)")
    fig.colorbar(im, ax=axes[1], label="pixel height (m)")
    ax = axes[2]
    mid = pixels // 2
    for k, style in ((1, "o-"), (5, "s-")):
        ax.plot(seen[k][mid, :, 0], seen[k][mid, :, 2], style, label=f"K = {k}")
    ax.plot(x, heights[n // 2], "k-", lw=1, label="terrain")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("height (m)")
    ax.set_title("profile through the rock (pixel pitch 0.82 m)")
    ax.legend()
    fig.savefig(HERE / "sensor_realism_rock.png", dpi=80, bbox_inches="tight")
    plt.close(fig)
    print(f"rock 0.4 m: K=1 peak {seen[1][..., 2].max():.3f} m, K=5 peak {seen[5][..., 2].max():.3f} m")


def step_figure() -> None:
    """A 1 m step edge swept across the nadir pixel: the pixel's height for each estimator against the
    edge's position in the pixel (the share of the pixel's field of view on the high side)."""
    spacing, n, high = 0.02, 300, 1.0
    c = (np.arange(n) + 0.5) * spacing
    x = c - n * spacing / 2
    heights = np.where(x[None, :] >= 0.0, high, 0.0) * np.ones((n, 1))
    scene, cx, cy = scene_of(heights, spacing)
    half_pitch = ALTITUDE_M * math.tan(math.radians(IFOV_DEG) / 2)
    offsets = np.linspace(-1.2, 1.2, 49) * half_pitch  # the edge's position east of the pixel centre, metres
    fig, ax = plt.subplots(figsize=(7, 4))
    for label, footprint, style in (
        ("K = 1", FootprintConfig(), "o-"),
        ("K = 5, centroid", FootprintConfig(samples=5), "s-"),
        ("K = 5, first return (0.5 of peak)", FootprintConfig(samples=5, range_estimator="first"), "^-"),
    ):
        z = [float(shoot(scene, (cx - dx, cy), 3, footprint).points_clean[1, 1, 2]) for dx in offsets]
        ax.plot(offsets / half_pitch, z, style, ms=3, label=label)
        print(f"step, {label}: height with the edge at -0.5/0/+0.5 half-pixels: {z[14]:.3f} {z[24]:.3f} {z[34]:.3f} m")
    ax.axvspan(-1, 1, color="0.9", zorder=0)
    ax.set_xlabel("position of the edge in the pixel (half-pixels, 0.41 m at 500 m; grey: inside)")
    ax.set_ylabel("pixel height (m)")
    ax.set_title("a 1 m step edge: the mixed pixel")
    ax.legend(fontsize=8)
    fig.savefig(HERE / "sensor_realism_step.png", dpi=80, bbox_inches="tight")
    plt.close(fig)


def sigma_figure() -> None:
    """The snr model's sigma against incidence at three ranges: formula and residuals on tilted planes."""
    sigma, noise = 0.0167, NoiseModel(kind="snr", snr_min=0.0)
    theta = np.linspace(0.0, 80.0, 161)
    fig, ax = plt.subplots(figsize=(7, 4))
    for altitude, colour in ((250.0, "C0"), (500.0, "C1"), (1000.0, "C2")):
        ax.plot(theta, sigma * (altitude / 500.0) / np.sqrt(np.cos(np.radians(theta))) * 100, color=colour)
        measured = []
        for incidence in (0.0, 20.0, 40.0, 60.0, 70.0):
            g = math.tan(math.radians(incidence))
            spacing, n = 0.5, 200
            c = (np.arange(n) + 0.5) * spacing
            heights = g * (c[None, :] - n * spacing / 2) * np.ones((n, 1))
            scene, cx, cy = scene_of(heights, spacing)
            res = shoot(scene, (cx, cy), 32, FootprintConfig(), noise, sigma, altitude_m=altitude)
            d = ray_directions(sensor_of(32)) @ sensor_attitude(0.0).T
            sp = res.geometry.sensor_position
            clean = np.einsum("ijk,ijk->ij", res.points_clean.astype(np.float64) - sp, d)
            noisy = np.einsum("ijk,ijk->ij", res.points_noisy[0].astype(np.float64) - sp, d)
            measured.append((noisy - clean).std() * 100)
        ax.plot((0.0, 20.0, 40.0, 60.0, 70.0), measured, "o", color=colour, label=f"{altitude:g} m")
        print(f"sigma at {altitude:g} m, incidence 0/20/40/60/70 deg: {np.round(measured, 2).tolist()} cm")
    ax.set_xlabel("incidence angle (degrees)")
    ax.set_ylabel("range noise 1-sigma (cm)")
    ax.set_title("snr model, σ = 1.67 cm at 500 m: σ (r / 500 m) / √cos θ (lines), residuals (dots)")
    ax.legend(title="range")
    fig.savefig(HERE / "sensor_realism_sigma.png", dpi=80, bbox_inches="tight")
    plt.close(fig)


if __name__ == "__main__":
    rock_figure()
    step_figure()
    sigma_figure()
