"""Draw docs/figures/label_geometry.png: the lander's sampling geometry on a 1 m grid and the tipping rule.

Run: ``.venv/bin/python docs/figures/label_geometry.py``. Uses hdlabels' own tables, so the
figure shows exactly what the code samples.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from hdlabels.lander import Lander, geometry, pad_sample_points  # noqa: E402

OUT = Path(__file__).with_suffix(".png")


def main() -> None:
    lander = Lander()
    geo = geometry(lander, 1.0)
    fig, (top, side) = plt.subplots(1, 2, figsize=(10, 5.2), gridspec_kw={"width_ratios": [1.1, 1]})

    # Top view: map x east, y north, metres; the site at the origin.
    b = geo.band_px
    fp_i, fp_j = np.nonzero(geo.footprint)
    top.scatter(fp_j - b, -(fp_i - b), s=14, c="0.8", label="footprint nodes (NaN / dead-pixel reach)")
    top.scatter(geo.body_dj, -geo.body_di, s=14, c="tab:blue", label="body nodes (centre within 5 m)")
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
    top.set_title("Sampling on a 1 m grid (square lander)")
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
    side.annotate("hole: below the plane, not roughness\n(Lander(count_holes=True) counts it)",
                  (-1.5, -0.55), ha="center", fontsize=8, color="tab:blue")
    side.text(-5.3, 0.85, "slope = angle of the plane's normal to vertical\n"
              "roughness = max height of body nodes above it x cos(slope)", fontsize=8, va="top")
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
