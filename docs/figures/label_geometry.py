"""Draw the label conventions' sampling geometry on a 1 m grid from hdlabels' own tables.

``label_geometry.png``: the hd convention (sub-pixel pads, rim samples, body disk) and the tipping
rule; ``label_geometry_paper.png``: the paper convention (pads on nodes, the 7 distinct squares of
the 36 orientations, the nodes strictly inside two of them).
Run: ``.venv/bin/python docs/figures/label_geometry.py``. The figures show exactly what the code samples.
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

from hdlabels.lander import Lander, geometry, pad_sample_points

OUT = Path(__file__).with_suffix(".png")
OUT_PAPER = Path(__file__).with_name("label_geometry_paper.png")


def paper_figure() -> None:
    """The paper convention: the 7 distinct pad squares and the roughness nodes of two of them."""
    geo = geometry(Lander(), 1.0)
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.3))
    b = geo.band_px
    fp_i, fp_j = np.nonzero(geo.footprint)
    colours = plt.cm.tab10(np.arange(geo.n_yaws))
    ax = axes[0]
    ax.scatter(fp_j - b, -(fp_i - b), s=14, c="0.8", label="footprint nodes")
    for m in range(geo.n_yaws):
        square = np.vstack([geo.pad_xy_px[m], geo.pad_xy_px[m][:1]])
        ax.plot(square[:, 0], square[:, 1], "-o", ms=4, color=colours[m], lw=1)
    ax.set_title("the 7 distinct pad squares of 36 orientations")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), fontsize=8)
    for ax, m in zip(axes[1:], (0, 3), strict=True):
        di, dj = geo.nodes(m)
        square = np.vstack([geo.pad_xy_px[m], geo.pad_xy_px[m][:1]])
        ax.scatter(fp_j - b, -(fp_i - b), s=14, c="0.85")
        ax.plot(square[:, 0], square[:, 1], "-o", ms=7, color=colours[m], lw=1.5, label="pads (on nodes)")
        ax.scatter(dj, -di, s=16, c="tab:blue", label=f"{di.size} roughness nodes, strictly inside")
        ax.set_title(f"square {m + 1}: pads at {tuple(int(v) for v in geo.pad_xy_px[m][0])}, ...")
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), fontsize=8, ncol=2)
    for ax in axes:
        ax.set_aspect("equal")
        ax.set_xlim(-6, 6)
        ax.set_ylim(-6, 6)
        ax.set_xlabel("x east (m)")
    axes[0].set_ylabel("y north (m)")
    fig.tight_layout()
    fig.savefig(OUT_PAPER, dpi=80, bbox_inches="tight")
    print(f"wrote {OUT_PAPER}")


def main() -> None:
    paper_figure()
    lander = Lander(convention="hd")
    geo = geometry(lander, 1.0)
    fig, (top, side) = plt.subplots(1, 2, figsize=(10, 5.2), gridspec_kw={"width_ratios": [1.1, 1]})

    # Top view: map x east, y north, metres; the site at the origin.
    b = geo.band_px
    fp_i, fp_j = np.nonzero(geo.footprint)
    top.scatter(fp_j - b, -(fp_i - b), s=14, c="0.8", label="footprint nodes (NaN / dead-pixel reach)")
    body_di, body_dj = geo.nodes(0)
    top.scatter(body_dj, -body_di, s=14, c="tab:blue", label="body nodes (centre within 5 m)")
    top.add_patch(plt.Circle((0, 0), lander.radius_m, fill=False, color="tab:blue"))
    every = geo.pad_xy_px.reshape(-1, 2)
    top.scatter(every[:, 0], every[:, 1], s=6, c="tab:orange", alpha=0.5, label="pad centres, all 8 yaws")
    yaw = 1  # 11.25 deg
    for k, (cx, cy) in enumerate(geo.pad_xy_px[yaw]):
        top.add_patch(plt.Circle((cx, cy), lander.pad_radius_m, fill=False, color="tab:red"))
        pts = np.array(pad_sample_points((cx, cy), lander.pad_radius_m))
        top.scatter(pts[:, 0], pts[:, 1], s=8, c="tab:red", label="pad rim samples, yaw 11.25 deg" if k == 0 else None)
        top.annotate(str(k), (cx * 1.25, cy * 1.25), ha="center", va="center", fontsize=9, color="tab:red")
    top.set_aspect("equal")
    top.set_xlim(-6.5, 6.5)
    top.set_ylim(-6.5, 6.5)
    top.set_xlabel("x east (m)")
    top.set_ylabel("y north (m)")
    top.set_title("hd convention on a 1 m grid (square lander)")
    top.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2, fontsize=7)

    # Side view: section along diagonal (0, 2) with pad 0 on a 0.5 m rock. The lander rocks on this
    # diagonal (z0 + z2 > z1 + z3); both resting planes (through pad 1 or pad 3) contain it.
    x = np.linspace(-5.5, 5.5, 400)
    ground = np.where(np.abs(x - 4.5) <= 0.5, 0.5, 0.0)
    ground[np.abs(x + 1.5) <= 0.3] = -0.4  # a hole under the body
    plane = 0.25 + x * 0.5 / 9.0
    side.fill_between(x, -0.8, ground, color="0.85")
    side.plot(x, ground, color="0.4")
    side.plot(x, plane, color="tab:red", label="resting plane through pads 0, 2 (and 1 or 3)")
    side.plot([-4.5, 4.5], [0.0, 0.5], "o", color="tab:red")
    side.annotate("pad 0 on a 0.5 m rock", (4.4, 0.62), ha="right", fontsize=8)
    side.annotate("pad 2", (-4.5, 0.08), ha="center", fontsize=8)
    side.annotate(
        "hole: below the plane, not roughness\n(Lander(count_holes=True) counts it)",
        (-1.5, -0.55),
        ha="center",
        fontsize=8,
        color="tab:blue",
    )
    side.text(
        -5.3,
        0.85,
        "slope = angle of the plane's normal to vertical\nroughness = max height of body nodes above it x cos(slope)",
        fontsize=8,
        va="top",
    )
    side.set_xlim(-5.5, 5.5)
    side.set_ylim(-0.8, 1.0)
    side.set_xlabel("distance along the pad 2 - pad 0 diagonal (m)")
    side.set_ylabel("height (m)")
    side.set_title(f"Tipping rule: this case tilts {math.degrees(math.atan(0.5 * math.sqrt(2) / 9)):.2f} deg")
    side.legend(loc="lower right", fontsize=8)

    fig.tight_layout()
    fig.savefig(OUT, dpi=80, bbox_inches="tight")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
