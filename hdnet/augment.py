"""D4 augmentation: the eight rotations and flips of a square grid, applied to a DEM and its label alike.

Element ``k`` (0-7) of the dihedral group D4 acts on an (..., H, W) array as ``k % 4`` quarter turns
counter-clockwise (``numpy.rot90`` on the last two axes) followed, for ``k >= 4``, by a left-right
flip. For a lander whose pads and evaluated yaws are symmetric under these maps, the hazard label of
a transformed DEM is the transformed label of the DEM (tested on ``hdlabels.alhat.hazard_maps``), so
each training DEM gives eight exact training samples.

Which labellings qualify: a **square** lander, in both label conventions. In the ``hd``
convention its pads repeat every 90 degrees, so a quarter turn maps each evaluated yaw onto another
one (the yaws are evenly spaced over the 90-degree period), and a flip maps yaw ``t`` to ``-t``,
again an evaluated yaw. In the ``paper`` convention each pixel-grid square (pads snapped towards
zero, an odd function) is mapped onto itself by a quarter turn and onto the square of orientation
``-theta`` by a flip; the roughness nodes strictly inside it and the tipping rule (the diagonal with
the higher pads) follow the pads. A triangular lander repeats every 120 degrees: a quarter turn is a
symmetry only for particular yaw sets, and hd does not rely on that, so D4 augmentation is refused
for it. The noisy DEM comes from a nadir-looking square detector with noise
along each ray; its statistics do not depend on the grid's orientation either.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from hdlabels.lander import Lander
from hdnet.errors import HdNetError
from hdnet.sample import DemSample

D4_ORDER = 8  # rotations by 0, 90, 180, 270 degrees, each with and without a flip
AUGMENTATIONS: tuple[str, ...] = ("none", "d4")


def d4(array: np.ndarray, k: int) -> np.ndarray:
    """Element ``k`` (0-7) of D4 applied to the last two axes of ``array`` (a view when possible)."""
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < D4_ORDER:
        raise HdNetError(f"a D4 element is an integer in [0, {D4_ORDER - 1}], got {k!r}.")
    out = np.rot90(array, int(k) % 4, axes=(-2, -1))
    return out[..., ::-1] if k >= 4 else out


def d4_inverse(k: int) -> int:
    """The element undoing ``k``: quarter turns are undone by the opposite turn, flipped ones are their own inverse."""
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < D4_ORDER:
        raise HdNetError(f"a D4 element is an integer in [0, {D4_ORDER - 1}], got {k!r}.")
    return (4 - int(k)) % 4 if k < 4 else int(k)


def label_is_d4_invariant(lander: Lander) -> bool:
    """True when hd relies on the lander's hazard rule commuting with D4 (the square layout)."""
    return lander.layout == "square"


def check_augment(augment: str, lander: Lander) -> str:
    """``augment`` when it is known and valid for ``lander``; HdNetError otherwise."""
    if augment not in AUGMENTATIONS:
        raise HdNetError(f"augmentation must be one of {', '.join(AUGMENTATIONS)}, got {augment!r}.")
    if augment == "d4" and not label_is_d4_invariant(lander):
        raise HdNetError(
            f"D4 augmentation needs labels invariant under rotations and flips; "
            f"a {lander.layout} lander's are not (use augment 'none')."
        )
    return augment


def transform_sample(sample: DemSample, k: int) -> DemSample:
    """``sample`` with every grid (DEMs, label, P(safe), ignore mask) under D4 element ``k``.

    Dead-pixel coordinates are mapped too.
    """
    grids: dict[str, Any] = {
        name: np.ascontiguousarray(d4(getattr(sample, name), k))
        for name in ("dem_clean_m", "dem_noisy_m", "dem_filled_m", "label", "p_safe", "ignore")
        if getattr(sample, name) is not None  # p_safe of a DEM made on the fly
    }
    dead = sample.dead_pixels
    if dead.size:
        marks = np.zeros(sample.label.shape, dtype=np.int64)
        marks[tuple(dead.T)] = np.arange(1, len(dead) + 1)
        moved = d4(marks, k)
        where = np.argwhere(moved > 0)
        dead = where[np.argsort(moved[tuple(where.T)])]
    return replace(sample, dead_pixels=dead, **grids)
