"""Ranges of hdlabels' numeric settings (``hd label``'s options and a recipe's ``[label]`` keys).

Each is declared once here, as a :class:`hdcore.bounds.Bound`, and used by the checks of
:class:`hdlabels.lander.Lander` and by the command line (shown in ``hd label --help``). Ranges that
depend on two settings (the pads smaller than the lander, the lander within the DEM) are checked
where both are known.
"""

from __future__ import annotations

from hdcore.bounds import Bound
from hdlabels import defaults

# Yaws per symmetry period of the pad layout (hd convention): one per degree of a full turn is far
# finer than the pads' sampling of the grid (hd choice; the default is defaults.N_YAWS).
MAX_YAWS: int = 360

# Lander and footpad diameters, metres.
LANDER_DIAMETER_M = Bound(0.0, low_open=True)
PAD_DIAMETER_M = Bound(0.0, low_open=True)
# Critical slope, degrees (a plane at 90 degrees is a wall).
MAX_SLOPE_DEG = Bound(0.0, 90.0, low_open=True, high_open=True)
# Critical roughness, metres.
MAX_ROUGHNESS_M = Bound(0.0, low_open=True)
YAWS = Bound(1, MAX_YAWS, integer=True)
# DEM side, pixels (defaults.MAX_DEM_SIDE_PX bounds one label shard's memory).
DEM_SIZE_PX = Bound(2, defaults.MAX_DEM_SIDE_PX, integer=True)
# DEM spacing, metres per pixel.
DEM_SPACING_M = Bound(0.0, low_open=True)
