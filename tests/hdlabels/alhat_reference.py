"""A slow, obviously-correct ALHAT replica: plain Python loops straight from docs/labels.md.

It shares no code with ``hdlabels.alhat`` except the Lander dataclass: pad positions, pad samples,
bilinear interpolation, the tipping rule (all pad triples, kept if the remaining pads are not
above the plane), the body nodes and the worst case are written out again here, one site and one
yaw at a time. Keep the DEMs tiny (about 30x30): it runs at a few hundred sites per second.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from hdlabels.lander import Lander

RIM_SAMPLES = 8  # docs/labels.md: pad rim sampled at 8 fixed map angles


def bilinear(dem: np.ndarray, row: float, col: float) -> float:
    """Bilinear height at fractional (row, col); taps with zero weight are skipped."""
    i0, j0 = math.floor(row + 1e-9), math.floor(col + 1e-9)
    ti, tj = row - i0, col - j0
    ti = 0.0 if abs(ti) < 1e-9 else ti
    tj = 0.0 if abs(tj) < 1e-9 else tj
    total = 0.0
    for a, wa in ((0, 1 - ti), (1, ti)):
        for b, wb in ((0, 1 - tj), (1, tj)):
            if wa * wb > 0:
                total += wa * wb * dem[i0 + a, j0 + b]
    return total


def pad_height(dem: np.ndarray, row: float, col: float, r_px: float) -> float:
    """Highest bilinear terrain under a pad centred at (row, col): rim samples and inner nodes."""
    best = -math.inf
    for q in range(RIM_SAMPLES):
        psi = 2 * math.pi * q / RIM_SAMPLES
        # map angle psi: x east = +col, y north = -row
        best = max(best, bilinear(dem, row - r_px * math.sin(psi), col + r_px * math.cos(psi)))
    inner = r_px * math.cos(math.pi / RIM_SAMPLES)
    for i in range(math.floor(row - inner) - 1, math.ceil(row + inner) + 2):
        for j in range(math.floor(col - inner) - 1, math.ceil(col + inner) + 2):
            if (i - row) ** 2 + (j - col) ** 2 <= inner**2 + 1e-9:
                best = max(best, dem[i, j])
    return best


def plane_through(p: list[tuple[float, float, float]]) -> tuple[float, float, float]:
    """(gx, gy, c) of z = gx x + gy y + c through three (x, y, z) points (x east, y north)."""
    a = np.array([[x, y, 1.0] for x, y, _ in p])
    z = np.array([zz for _, _, zz in p])
    gx, gy, c = np.linalg.solve(a, z)
    return float(gx), float(gy), float(c)


def reference_maps(dem: np.ndarray, spacing_m: float, lander: Lander) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Slope (rad), roughness (m) and label (uint8) of every site, one site at a time."""
    h, w = dem.shape
    slope = np.full((h, w), np.nan)
    rough = np.full((h, w), np.nan)
    label = np.full((h, w), 255, dtype=np.uint8)
    rho = lander.pad_centre_radius_m / spacing_m
    r_pad = lander.pad_diameter_m / 2 / spacing_m
    r_body = lander.diameter_m / 2 / spacing_m
    n = 4 if lander.layout == "square" else 3
    yaws = [m * (2 * math.pi / n) / lander.n_yaws for m in range(lander.n_yaws)]
    band = math.ceil(r_body - 1e-9)
    reach = math.floor(r_body + 1e-9)
    body = [
        (a, b) for a in range(-reach, reach + 1) for b in range(-reach, reach + 1) if a * a + b * b <= r_body**2 + 1e-9
    ]
    for i in range(band, h - band):
        for j in range(band, w - band):
            worst_tan, worst_rough = 0.0, 0.0
            for yaw in yaws:
                pads = []
                for k in range(n):
                    phi = yaw + 2 * math.pi * k / n
                    x, y = rho * math.cos(phi), rho * math.sin(phi)
                    pads.append((x, y, pad_height(dem, i - y, j + x, r_pad)))
                for triple in itertools.combinations(range(n), 3):
                    gx, gy, c = plane_through([pads[k] for k in triple])
                    others = [k for k in range(n) if k not in triple]
                    if any(pads[k][2] > gx * pads[k][0] + gy * pads[k][1] + c + 1e-9 for k in others):
                        continue  # a remaining pad would be above the plane: the lander cannot rest so
                    tan = math.hypot(gx, gy) / spacing_m
                    cos = 1 / math.sqrt(1 + tan * tan)
                    height = 0.0
                    for a, b in body:
                        dev = dem[i + a, j + b] - (gx * b + gy * (-a) + c)
                        height = max(height, abs(dev) if lander.count_holes else dev)
                    worst_tan = max(worst_tan, tan)
                    worst_rough = max(worst_rough, height * cos)
            slope[i, j] = math.atan(worst_tan)
            rough[i, j] = worst_rough
            safe = slope[i, j] < math.radians(lander.max_slope_deg) and worst_rough < lander.max_roughness_m
            label[i, j] = 1 if safe else 0
    return slope, rough, label
