"""Inputs that build a valid but weaker dataset than it looks: said with numbers, never refused.

Two cases, each a one-line :class:`~hdcore.errors.HdWarning` from ``hd build-dataset``:

* a DTM coarser than the LiDAR's ground sample (altitude x the angle of one detector pixel): the
  returns then come from a mesh through the DTM's posts, and no hazard smaller than its cells
  (boulders) is in the data;
* footprints of the validation or test scans that overlap the training scans' footprints: the
  "held-out" splits then share terrain with training, and their scores are not those of unseen
  terrain. The overlap of a scan is the largest fraction of its footprint that one training
  footprint covers (square footprints of the planned width).
"""

from __future__ import annotations

import math

import numpy as np

from lidarsim.sensor import SensorConfig

__all__ = ["COARSE_FACTOR", "OVERLAP_WARNING", "coarse_dtm_message", "ground_sample_m", "split_overlap"]

# hd choice: a DTM whose cells exceed 1.5 ground samples is "coarser than the sensor".
COARSE_FACTOR = 1.5
# hd choice: warn when a held-out split's scans share on average more than this fraction of their
# footprint with one training footprint.
OVERLAP_WARNING = 0.25


def ground_sample_m(sensor: SensorConfig, altitude_m: float) -> float:
    """Ground distance between neighbouring rays at nadir (metres): altitude x FOV / pixels."""
    ifov = math.radians(max(sensor.fov_x_deg / sensor.cols, sensor.fov_y_deg / sensor.rows))
    return altitude_m * ifov


def coarse_dtm_message(name: str, spacing_m: float, sensor: SensorConfig, altitude_m: float) -> str | None:
    """The warning for a DTM of ``spacing_m`` metres/pixel scanned by ``sensor`` from ``altitude_m``, or None."""
    sample = ground_sample_m(sensor, altitude_m)
    if spacing_m <= COARSE_FACTOR * sample:
        return None
    return (
        f"{name}: its {spacing_m:.2f} m cells are coarser than the LiDAR's {sample:.2f} m ground sample at "
        f"{altitude_m:g} m: the scans see a mesh through its posts and no hazard smaller than a cell (no boulder); "
        "add a rock population with --rocks-on-dtm (or hd make-dtm --base) if the labels should hold rocks"
    )


def split_overlap(nadir_xy: np.ndarray, splits: np.ndarray, footprint_m: float) -> dict[int, float]:
    """Mean, over the scans of each held-out split (1 val, 2 test), of the largest fraction of a scan's
    footprint (a ``footprint_m`` square, metres) that one training scan's footprint covers."""
    xy = np.asarray(nadir_xy, dtype=np.float64)
    train = xy[splits == 0]
    out: dict[int, float] = {}
    for split in (1, 2):
        held = xy[splits == split]
        if held.size == 0 or train.size == 0:
            continue
        best = np.zeros(len(held))
        for start in range(0, len(held), 256):  # bounded memory: 256 x N_train pairs at a time
            h = held[start : start + 256]
            dx = np.clip(footprint_m - np.abs(h[:, None, 0] - train[None, :, 0]), 0.0, None)
            dy = np.clip(footprint_m - np.abs(h[:, None, 1] - train[None, :, 1]), 0.0, None)
            best[start : start + 256] = (dx * dy).max(axis=1) / footprint_m**2
        out[split] = float(best.mean())
    return out


def overlap_message(overlap: dict[int, float], step_m: float, footprint_m: float) -> str | None:
    """The warning for held-out splits that share terrain with training, or None."""
    shared = {name: overlap[k] for k, name in ((1, "validation"), (2, "test")) if overlap.get(k, 0.0) > OVERLAP_WARNING}
    if not shared:
        return None
    parts = ", ".join(f"{name} {frac * 100:.0f} %" for name, frac in shared.items())
    return (
        f"the held-out scans share terrain with the training scans (mean footprint overlap: {parts}; scans "
        f"{step_m:.0f} m apart, footprints {footprint_m:.0f} m wide): their scores are not those of unseen terrain; "
        "use a larger terrain or fewer scans for a held-out test"
    )
