"""The colours of the safety classes, one palette for every figure and page of hd.

Okabe & Ito's colour-blind-safe set (Okabe and Ito 2008, "Color Universal Design"): safe blue
``#0072B2``, unsafe vermillion ``#D55E00``, uncertain yellow ``#F0E442``, invalid dark grey
``#505050``. Under a simulated deuteranopia or protanopia (Machado et al. 2009, full severity) every
pair of them stays more than 33 CIELAB units apart (CIE76 ΔE; ``tests/hdnet/test_palette.py``).
``hdnet.figures`` (the evaluation's and the detection's figures), ``hdnet.view_images`` (``hd
view``'s safety layer) and ``hdnet.view`` (its legend's swatches) take their colours from here.
"""

from __future__ import annotations

from typing import Final

SAFE: Final = "#0072b2"  # Okabe-Ito blue
UNSAFE: Final = "#d55e00"  # Okabe-Ito vermillion
UNCERTAIN: Final = "#f0e442"  # Okabe-Ito yellow
INVALID: Final = "#505050"  # dark grey: no label (border band, nodata, DEM holes)

# In the order of the figures' class codes: 0 unsafe, 1 safe, 2 uncertain, 3 invalid.
SAFETY_HEX: Final = (UNSAFE, SAFE, UNCERTAIN, INVALID)
SAFETY_NAMES: Final = ("unsafe", "safe", "uncertain (discarded)", "invalid (no label)")
