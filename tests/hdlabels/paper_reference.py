"""A slow, literal paper-convention replica: every one of the 36 orientations, one site at a time.

Written from the rules in docs/labels.md ("The paper convention") and sharing no code with
``hdlabels``: no de-duplication of orientations, the plane through pads 0, 1, 2 by a cross product
in (row, column, height) coordinates, the tipping test on pad 3, the strict inside test on every
node of the square window, the per-node probabilities multiplied (or their minimum taken). Keep
the DEMs tiny (about 24x24): it evaluates a few hundred sites per second.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ndtr


def pads_of(layout: str, r: int, theta: float) -> list[tuple[int, int]]:
    if layout == "square":
        c, s = int(r * math.cos(theta)), int(r * math.sin(theta))
        return [(s, -c), (c, s), (-s, c), (-c, -s)]
    return [
        (int(r * math.sin(theta)), int(r * math.cos(theta + math.pi))),
        (int(r * math.sin(theta + 2 * math.pi / 3)), int(r * math.cos(theta - math.pi / 3))),
        (int(r * math.sin(theta - 2 * math.pi / 3)), int(r * math.cos(theta + math.pi / 3))),
    ]


def left_of(p: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> bool:
    return (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]) > 0


def reference(
    dem: np.ndarray,
    spacing: float,
    layout: str = "square",
    sigma: float = 0.0,
    combine: str = "product",
    holes: bool = False,
    diameter: float = 10.0,
    pad: float = 1.0,
    max_slope_deg: float = 10.0,
    max_rough: float = 0.2,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(label uint8 with 255 invalid, P(safe) float with NaN invalid, slope rad) of every site."""
    h, w = dem.shape
    n_pad, n_body = int(pad / 2 / spacing), int(diameter / 2 / spacing)
    r = n_body - n_pad
    reach = n_body - (2 * n_pad + 1)
    thetas = [k * math.radians(10.0) for k in range(36)]
    label = np.full((h, w), 255, dtype=np.uint8)
    prob = np.full((h, w), np.nan)
    slope_map = np.full((h, w), np.nan)
    for i in range(n_body, h - n_body):
        for j in range(n_body, w - n_body):
            worst_slope, worst_rough, p_min = -1.0, 0.0, 1.0
            for theta in thetas:
                pads = pads_of(layout, r, theta)
                z = [
                    max(
                        dem[i + a + u, j + b + v]
                        for u in range(-n_pad, n_pad + 1)
                        for v in range(-n_pad, n_pad + 1)
                        if u * u + v * v <= n_pad * n_pad
                    )
                    for a, b in pads
                ]
                p3 = [(a * spacing, b * spacing, zz) for (a, b), zz in zip(pads, z, strict=True)]
                v1 = np.subtract(p3[1], p3[0])
                v2 = np.subtract(p3[2], p3[0])
                normal = np.cross(v1, v2)
                normal = normal / np.linalg.norm(normal)
                d = -float(normal @ np.array(p3[0]))
                if layout == "square" and float(normal @ np.array(p3[3])) + d > 0:
                    continue  # pad 3 would be above the plane: the lander cannot rest so
                worst_slope = max(worst_slope, math.acos(normal[2]))
                corners = pads if layout == "square" else pads[:3]
                p_theta = 1.0
                for a in range(-reach, reach + 1):
                    for b in range(-reach, reach + 1):
                        if not all(left_of((a, b), corners[k - 1], corners[k]) for k in range(len(corners))):
                            continue
                        dist = float(normal @ np.array([a * spacing, b * spacing, dem[i + a, j + b]])) + d
                        worst_rough = max(worst_rough, abs(dist) if holes else dist)
                        if sigma > 0:
                            q = float(ndtr((max_rough - dist) / (normal[2] * sigma)))
                            p_theta = p_theta * q if combine == "product" else min(p_theta, q)
                p_min = min(p_min, p_theta)
            limit = math.radians(max_slope_deg)
            label[i, j] = 1 if (worst_slope < limit and worst_rough < max_rough) else 0
            prob[i, j] = p_min if worst_slope <= limit else 0.0
            slope_map[i, j] = worst_slope
    return label, prob, slope_map
