"""Scan positions: where the sensor is when it takes each scan.

The sensor flies at a fixed altitude over the terrain. Scan positions are chosen on a regular
lattice of nadir points restricted to *admissible* places, those whose whole footprint (plus a
margin) lies on valid terrain:

1. the DTM's validity is summarised on a coarse grid (a coarse cell is valid only when every DTM
   cell inside it is valid);
2. the valid mask is eroded by a square of the footprint half-width (the footprint of the widest,
   corner ray, tilt and 3-sigma attitude jitter included, plus ``margin_m``);
3. the lattice step is the largest multiple of the coarse cell that still gives at least the
   requested number of admissible positions;
4. positions are ordered tile by tile (square tiles of ``tile_m``, row-major), boustrophedon
   inside a tile, and thinned evenly to the requested count. Consecutive scans are therefore
   neighbours on the ground, as along a survey track, and a shard covers a compact area.

A descent build (``TrajectoryConfig.descent``) plans its descents' target points the same way, one
position per descent, with the footprint half-width of the square that holds every frame of a
descent (``lidarsim.descent.DescentConfig.reach_m``); scan ``s`` is frame ``s mod K`` of descent
``s // K``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy import ndimage

from lidarsim import defaults, limits
from lidarsim.descent import DescentConfig
from lidarsim.errors import LidarsimError
from lidarsim.sensor import SensorConfig, footprint_half_width_m
from lidarsim.streams import Purpose, stream


@dataclass(frozen=True)
class TrajectoryConfig:
    """How the sensor moves over the terrain.

    Attributes:
        n_scans: number of scans (in a descent build, descents times frames per descent).
        altitude_m: height of the sensor above the mean terrain height under its footprint, metres.
        tilt_deg: off-nadir tilt of the boresight, degrees.
        jitter_deg: 1-sigma attitude jitter per axis, degrees (0 = perfect pointing).
        margin_m: extra valid terrain required around the footprint, metres.
        tile_m: side of the square tiles that group scans for ray casting, metres.
        altitude_max_m: with it, each scan's altitude is drawn uniformly from
            [altitude_m, altitude_max_m] (a descent); None: every scan at ``altitude_m``.
        tilt_max_deg: likewise for the tilt, from [tilt_deg, tilt_max_deg].
        jitter_max_deg: likewise for the jitter's 1-sigma, from [jitter_deg, jitter_max_deg].
        descent: with it, the scans are descents of ``descent.frames`` frames each
            (``lidarsim.descent``); altitude and tilt are then the descent's, so ``altitude_m``,
            ``tilt_deg`` and their ranges must be left at their defaults. None: single scans.
    """

    n_scans: int = defaults.N_SCANS
    altitude_m: float = defaults.ALTITUDE_M
    tilt_deg: float = defaults.TILT_DEG
    jitter_deg: float = defaults.JITTER_DEG
    margin_m: float = 5.0
    tile_m: float = 256.0
    altitude_max_m: float | None = None
    tilt_max_deg: float | None = None
    jitter_max_deg: float | None = None
    descent: DescentConfig | None = None

    def __post_init__(self) -> None:
        if self.n_scans <= 0:
            raise LidarsimError(f"the number of scans must be > 0, got {self.n_scans}")
        if self.n_scans > limits.MAX_SCANS:
            raise LidarsimError(f"the number of scans must be at most {limits.MAX_SCANS}, got {self.n_scans}")
        if not (self.altitude_m > 0.0 and math.isfinite(self.altitude_m)):
            raise LidarsimError(f"altitude must be > 0 metres, got {self.altitude_m}")
        if not limits.TILT_DEG.contains(self.tilt_deg):
            raise LidarsimError(f"tilt must be within {limits.TILT_DEG.interval()} degrees, got {self.tilt_deg}")
        if not limits.JITTER_DEG.contains(self.jitter_deg):
            raise LidarsimError(
                f"attitude jitter must be in {limits.JITTER_DEG.interval()} degrees, got {self.jitter_deg}"
            )
        if self.margin_m < 0.0 or self.tile_m <= 0.0:
            raise LidarsimError("margin_m must be >= 0 and tile_m > 0 metres")
        for name, low, high, bound, unit in (
            ("--altitude", self.altitude_m, self.altitude_max_m, limits.ALTITUDE_M, "metres"),
            ("--tilt", self.tilt_deg, self.tilt_max_deg, limits.TILT_DEG, "degrees"),
            ("--jitter", self.jitter_deg, self.jitter_max_deg, limits.JITTER_DEG, "degrees"),
        ):
            if high is None:
                continue
            if not bound.contains(high):
                raise LidarsimError(f"{name} range must end within {bound.interval()} {unit}, got {high}")
            if high < low:
                raise LidarsimError(f"{name} range {low:g}:{high:g} runs backwards; give LOW:HIGH")
        if self.descent is not None:
            k = self.descent.frames
            if self.n_scans % k:
                raise LidarsimError(f"{self.n_scans} scans are not whole descents of {k} frames")
            fixed = (self.altitude_m, self.tilt_deg, self.altitude_max_m, self.tilt_max_deg)
            if fixed != (defaults.ALTITUDE_M, defaults.TILT_DEG, None, None):
                raise LidarsimError(
                    "--altitude and --tilt do not apply to a descent: its frames fly --descent-altitudes "
                    "toward their target along --approach-deg"
                )

    @property
    def n_descents(self) -> int:
        """Descents of a descent build (0 for single scans)."""
        return 0 if self.descent is None else self.n_scans // self.descent.frames

    @property
    def n_positions(self) -> int:
        """Positions the planner places: one per descent (its target), else one per scan."""
        return self.n_scans if self.descent is None else self.n_descents

    @property
    def frames(self) -> int:
        """Scans per planned position: a descent's frames, else 1."""
        return 1 if self.descent is None else self.descent.frames

    @property
    def ranged(self) -> bool:
        """True when altitude, tilt or jitter is drawn per scan from a range."""
        return (self.altitude_max_m, self.tilt_max_deg, self.jitter_max_deg) != (None, None, None)

    @property
    def max_altitude_m(self) -> float:
        """The highest altitude of any scan, metres."""
        if self.descent is not None:
            return self.descent.altitude_start_m
        return self.altitude_m if self.altitude_max_m is None else self.altitude_max_m

    @property
    def min_altitude_m(self) -> float:
        """The lowest altitude of any scan, metres."""
        return self.altitude_m if self.descent is None else self.descent.altitude_end_m

    def reach_m(self, sensor: SensorConfig) -> float:
        """Half-width of the square around a planned position that every footprint of its scans
        lies in (flat ground, no margin), metres: a scan's footprint around its nadir point, or a
        descent's frames around its target."""
        if self.descent is not None:
            return self.descent.reach_m(sensor, self.max_jitter_deg)
        return footprint_half_width_m(sensor, self.max_altitude_m, self.max_abs_tilt_deg, self.max_jitter_deg)

    @property
    def max_abs_tilt_deg(self) -> float:
        """The largest off-nadir tilt of any scan, degrees."""
        return abs(self.tilt_deg) if self.tilt_max_deg is None else max(abs(self.tilt_deg), abs(self.tilt_max_deg))

    @property
    def max_jitter_deg(self) -> float:
        """The largest jitter 1-sigma of any scan, degrees."""
        return self.jitter_deg if self.jitter_max_deg is None else self.jitter_max_deg

    def scan_pose(self, seed: int, scan_index: int) -> tuple[float, float, float]:
        """``(altitude_m, tilt_deg, jitter_deg)`` of scan ``scan_index``: the fixed values, or drawn
        uniformly from their ranges with the stream ``(seed, SCAN_POSE, scan)`` (three draws, in that
        order, whichever are ranges). In a descent: the frame's altitude, the approach angle and the
        jitter (fixed or drawn as above)."""
        if self.descent is not None:
            jitter = self.jitter_deg
            if self.jitter_max_deg is not None:
                u = stream(seed, Purpose.SCAN_POSE, scan_index).random(3)
                jitter = self.jitter_deg + (self.jitter_max_deg - self.jitter_deg) * float(u[2])
            return self.descent.altitude_m(scan_index % self.descent.frames), self.descent.approach_deg, jitter
        if not self.ranged:
            return self.altitude_m, self.tilt_deg, self.jitter_deg
        u = stream(seed, Purpose.SCAN_POSE, scan_index).random(3)
        values = []
        for k, (low, high) in enumerate(
            (
                (self.altitude_m, self.altitude_max_m),
                (self.tilt_deg, self.tilt_max_deg),
                (self.jitter_deg, self.jitter_max_deg),
            )
        ):
            values.append(low if high is None else low + (high - low) * float(u[k]))
        return values[0], values[1], values[2]

    def to_attrs(self) -> dict[str, int | float]:
        """Flat attribute dictionary (HDF5/JSON friendly); the range ends only when set. A descent's
        settings are its own attributes (``DescentConfig.to_attrs``), and its altitude and tilt are
        the descent's, so ``trajectory_altitude_m`` and ``trajectory_tilt_deg`` are left out."""
        skip = {"descent"} if self.descent is None else {"descent", "altitude_m", "tilt_deg"}
        attrs = {f"trajectory_{k}": v for k, v in asdict(self).items() if v is not None and k not in skip}
        if self.descent is not None:
            attrs.update(self.descent.to_attrs())
        return attrs


@dataclass(frozen=True)
class ScanPlan:
    """Planned scans.

    Attributes:
        nadir_xy: float64 (N, 2) map coordinates of the nadir points (a descent build: of the N
            descents' targets), metres.
        tile_ij: int64 (N, 2) index of the ray-casting tile of each position.
        half_width_m: footprint half-width (with margin) the plan guarantees valid, metres.
        step_m: lattice step between neighbouring admissible positions, metres.
        tile_anchor_xy: map coordinates of the north-west corner of tile (0, 0), metres.
        tile_m: side of a tile, metres.
    """

    nadir_xy: np.ndarray
    tile_ij: np.ndarray
    half_width_m: float
    step_m: float
    tile_anchor_xy: tuple[float, float]
    tile_m: float

    def tile_centre_xy(self, tile_i: int, tile_j: int) -> tuple[float, float]:
        """Map coordinates of the centre of tile ``(tile_i, tile_j)``, metres."""
        x0, y0 = self.tile_anchor_xy
        return (x0 + (tile_j + 0.5) * self.tile_m, y0 - (tile_i + 0.5) * self.tile_m)


def plan_scans(
    valid: np.ndarray,
    transform: tuple[float, ...],
    sensor: SensorConfig,
    trajectory: TrajectoryConfig,
    dtm_name: str = "the DTM",
) -> ScanPlan:
    """Choose ``trajectory.n_positions`` nadir points (a descent build: descent targets) whose
    footprints lie on valid terrain.

    Args:
        valid: coarse validity grid (True where every DTM cell of the coarse cell is valid).
        transform: GDAL-order affine of ``valid`` (north-up, square cells assumed).
        sensor: the detector (its FOV sets the footprint).
        trajectory: altitude, tilt, jitter, margin and count.
        dtm_name: name used in error messages.

    Raises:
        LidarsimError: when no footprint fits, or fewer positions than requested fit.
    """
    a, _, c, _, e, f = transform[:6]
    cell = abs(a)
    half_width = trajectory.reach_m(sensor) + trajectory.margin_m
    n_positions = trajectory.n_positions
    what = "descent targets" if trajectory.descent is not None else "scan positions"
    reach = int(math.ceil(half_width / cell + 0.5))
    if 2 * reach + 1 > min(valid.shape):  # no footprint fits: say so before filtering with a huge window
        admissible = np.zeros(valid.shape, dtype=bool)
    else:
        admissible = ndimage.minimum_filter(valid.astype(np.uint8), size=2 * reach + 1, mode="constant", cval=0).astype(
            bool
        )
    if not admissible.any():
        need = 2.0 * half_width
        extent_x = valid.shape[1] * cell
        extent_y = valid.shape[0] * cell
        scan, lower = "a scan", "--altitude"
        if trajectory.descent is not None:
            scan, lower = "a descent", "the start of --descent-altitudes or --approach-deg"
        raise LidarsimError(
            f"{dtm_name} is too small for the sensor footprint: {scan} from {trajectory.max_altitude_m:g} m "
            f"needs {need:.0f} m x {need:.0f} m of valid terrain, the DTM covers {extent_x:.0f} m x "
            f"{extent_y:.0f} m with no such valid square; lower {lower} or use a larger DTM"
        )
    rows, cols = np.nonzero(admissible)
    r0, c0 = rows.min(), cols.min()
    step = _largest_step(admissible[r0:, c0:], n_positions)
    if step == 0:
        raise LidarsimError(
            f"only {int(admissible.sum())} {what} fit on {dtm_name} at {trajectory.max_altitude_m:g} m; "
            f"ask for fewer --scans (got {n_positions})"
        )
    sub = admissible[r0::step, c0::step]
    lattice_r, lattice_c = np.nonzero(sub)
    rr = r0 + lattice_r * step
    cc = c0 + lattice_c * step
    x = c + (cc + 0.5) * a
    y = f + (rr + 0.5) * e
    tile_i = np.floor((y.max() - y) / trajectory.tile_m).astype(np.int64)
    tile_j = np.floor((x - x.min()) / trajectory.tile_m).astype(np.int64)
    order = _tile_boustrophedon_order(tile_i, tile_j, lattice_r, lattice_c)
    keep = order[np.round(np.linspace(0, order.size - 1, n_positions)).astype(np.int64)]
    return ScanPlan(
        nadir_xy=np.stack([x[keep], y[keep]], axis=1).astype(np.float64),
        tile_ij=np.stack([tile_i[keep], tile_j[keep]], axis=1),
        half_width_m=half_width,
        step_m=step * cell,
        tile_anchor_xy=(float(x.min()), float(y.max())),
        tile_m=trajectory.tile_m,
    )


def _largest_step(admissible: np.ndarray, n: int) -> int:
    """Largest lattice step (in cells) that keeps at least ``n`` admissible positions; 0 if none."""
    lo, hi = 1, max(admissible.shape)
    if int(admissible.sum()) < n:
        return 0
    while lo < hi:  # invariant: step lo works
        mid = (lo + hi + 1) // 2
        if int(admissible[::mid, ::mid].sum()) >= n:
            lo = mid
        else:
            hi = mid - 1
    return lo


def _tile_boustrophedon_order(tile_i: np.ndarray, tile_j: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Order positions tile by tile (row-major), boustrophedon (serpentine) inside each tile."""
    serpentine_col = np.where(rows % 2 == 0, cols, -cols)
    return np.lexsort((serpentine_col, rows, tile_j, tile_i))
