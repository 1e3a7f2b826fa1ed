"""One descent flown as a lander flies it, the algorithm of ``hd descend`` (``hdnet.descend``): frames in
order, one mosaic, a map after every frame, and an aim that diverts when the ground under it turns out
unsafe.

A descent's frames (``lidarsim``'s descent mode: frame 0 the highest) arrive one at a time. After each
frame ``t`` the lander has:

1. *registration*: the frames 0..t placed by their navigation poses and, for ``registered`` poses,
   registered to the newest frame ``t`` (``hdlabels.mosaic.registered_clouds``: the ICP of ``hd mosaic``
   with frame ``t`` as its anchor). The newest frame is the lowest and densest, and it is where the
   lander is now: its navigation frame is the frame the lander steers in. Every frame seen so far is
   registered again, because the anchor moved: a correction found against frame ``t - 1`` is not one
   against frame ``t``. After the last frame this is exactly ``hd mosaic``'s registration of all the
   frames anchored on the last one, so the online mosaic after the last frame *is* the offline mosaic,
   byte for byte. (Registering only the new frame to the mosaic so far would be cheaper, but its final
   mosaic would be anchored on the highest frame, not the lowest, and differ from the offline one.)
   For ``nav`` and ``true`` poses a frame's placement does not depend on the others, and its grid is
   kept from frame to frame (reuse that gives the same bytes: ``frame_grids`` grids each frame alone);
2. *mosaic*: the frames gridded and combined (``hdlabels.mosaic.frame_grids``, ``combine_grids``), the
   DEM grid of the mosaics the run was trained on;
3. *map*: the mosaic mapped by the run as ``hd detect --data MOSAICS --scan K`` maps it
   (``hdnet.detect.map_heights``: the same tiles, MC-dropout draws from ``seed``, threshold found once
   for the descent, ALHAT baseline and ranked sites);
4. *sites*: the aim (:func:`retarget`): the first frame's best site; then held while its lander
   footprint stays safe and certain in the newest map, else a *divert* to the newest map's best site
   (recorded: frame, seconds since the descent began, altitude, old and new aim, distance).

Coordinates are the mosaic frame's: metres east and north of the descent's target, as the newest
frame's navigation places it (the aim is held as these coordinates).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from rasterio.transform import Affine

from hdlabels.lander import Lander
from hdlabels.mosaic import (
    MosaicFrame,
    Poses,
    Registration,
    combine_grids,
    frame_grids,
    placed_points,
    registered_clouds,
)
from hdlabels.store import DemSpec
from hdnet.detect import DetectMaps, DetectRun, map_heights
from hdnet.detect_settings import DetectSettings
from hdnet.report_json import ThresholdJson
from hdnet.results import Site
from hdnet.sites import SAFETY_SAFE, body_disk
from lidarsim.errors import TerrainError

# Why an aim changed (``Divert.reason``).
REASON_UNSAFE = "the aim's lander footprint is no longer safe and certain"
# Why a frame has no map (``FrameStep.no_map``, followed by the mapping's own words).
REASON_NO_MAP = "no map of this frame's mosaic, the aim held"


@dataclass(frozen=True)
class FrameTiming:
    """Seconds one frame took: registration (placing and registering the frames so far), mosaic (gridding
    and combining them), map (the network and the baseline) and sites (ranking them and the aim)."""

    registration_s: float
    mosaic_s: float
    map_s: float
    sites_s: float

    @property
    def total_s(self) -> float:
        """The frame's seconds, all four steps."""
        return self.registration_s + self.mosaic_s + self.map_s + self.sites_s


@dataclass(frozen=True)
class Divert:
    """A change of aim: after frame ``frame`` (``elapsed_s`` seconds after the descent's first frame
    arrived, at ``altitude_m`` metres above the target by the navigation), from ``old`` to ``new``
    (mosaic-frame metres), ``distance_m`` apart, for ``reason``."""

    frame: int
    elapsed_s: float
    altitude_m: float
    old: tuple[float, float]
    new: tuple[float, float]
    distance_m: float
    reason: str


@dataclass(frozen=True)
class FrameStep:
    """What the lander knows after one frame.

    Attributes:
        frame: the frame's index in the descent (0 the highest).
        altitude_m: the frame's sensor height above the target by the navigation, metres.
        heights: float32 (rows, cols) the mosaic of the frames so far, metres (NaN where none has a height).
        maps: its maps and ranked sites (``hdnet.detect.DetectMaps``); None when the mosaic has no map
            (``no_map`` says why).
        aim: the site aimed at after this frame (None: no site yet); held from the frame before when
            the frame has no map.
        divert: the change of aim this frame made (None: none).
        timing: the seconds of each step.
        registration: the registration of the frames so far to this one (``registered`` poses only).
        no_map: why the frame has no map (None: it has one), e.g. a mosaic without a lander-sized square
            of valid cells.
    """

    frame: int
    altitude_m: float
    heights: np.ndarray
    maps: DetectMaps | None
    aim: Site | None
    divert: Divert | None
    timing: FrameTiming
    registration: Registration | None = None
    no_map: str | None = None

    @property
    def sites(self) -> list[Site]:
        """The frame's ranked sites (none when it has no map)."""
        return [] if self.maps is None else self.maps.sites


class OnlineMosaic:
    """The mosaic of a descent's frames so far, updated as each frame arrives (steps 1-2 of the module)."""

    def __init__(self, target_map: np.ndarray, dem: DemSpec, poses: Poses) -> None:
        self.target_map = np.asarray(target_map, dtype=np.float64)
        self.dem = dem
        self.poses = poses
        self._placed: list[np.ndarray] = []  # each frame placed by its navigation (or true) pose
        self._grids: list[np.ndarray] = []  # each frame's grid, kept for the poses without registration
        self._weights: list[float] = []

    def add(self, frame: MosaicFrame) -> tuple[np.ndarray, Registration | None, float, float]:
        """Take the next frame: returns the mosaic of the frames so far (float32 metres), their
        registration to this frame (``registered`` poses; else None) and the seconds of registration
        and of gridding."""
        t0 = time.perf_counter()
        self._placed.append(placed_points(frame, self.target_map, "true" if self.poses == "true" else "nav"))
        registration = None
        if self.poses == "registered":
            clouds, registration = registered_clouds(self._placed, self.dem)
        t1 = time.perf_counter()
        if registration is not None:
            grids, weights = frame_grids(clouds, self.dem)
        else:
            grid, weight = frame_grids(self._placed[-1:], self.dem)
            self._grids.append(grid[0])
            self._weights.append(float(weight[0]))
            grids, weights = np.stack(self._grids), np.array(self._weights)
        heights = combine_grids(grids, weights, self.dem.spacing_m)
        return heights, registration, t1 - t0, time.perf_counter() - t1


def aim_is_safe(aim: Site, safety: np.ndarray, transform: Affine, lander: Lander, margin_m: float = 0.0) -> bool:
    """True when the aim's whole lander body disk (widened by ``margin_m`` metres, as ``select_sites``'s
    footprint) lies on safe and certain cells (``safety == 1``) of a map of ``transform``'s grid; a disk
    reaching past the map is not safe."""
    col, row = ~transform @ (aim.x, aim.y)
    r, c = math.floor(row), math.floor(col)
    spacing = math.sqrt(abs(float(transform.a)) * abs(float(transform.e)))
    disk = body_disk(lander, spacing, margin_m)
    k = disk.shape[0] // 2
    rows, cols = safety.shape
    if r - k < 0 or c - k < 0 or r + k >= rows or c + k >= cols:
        return False
    return bool((safety[r - k : r + k + 1, c - k : c + k + 1][disk] == SAFETY_SAFE).all())


def retarget(
    aim: Site | None,
    sites: Sequence[Site],
    safety: np.ndarray,
    transform: Affine,
    lander: Lander,
    margin_m: float = 0.0,
) -> tuple[Site | None, bool]:
    """The aim after a new map: ``(aim, diverted)``.

    No aim yet: the best site (``sites[0]``; None when there is none), not a divert. An aim whose
    footprint is still safe and certain in the new map (:func:`aim_is_safe`) is held (as the new map's
    site at that cell when it ranks it, else as it was); otherwise the lander diverts to the new best
    site, or, when the new map has none, holds the old aim (there is nowhere better to go).
    """
    if aim is None:
        return (sites[0] if sites else None), False
    if aim_is_safe(aim, safety, transform, lander, margin_m) or not sites:
        same = next((s for s in sites if (s.x, s.y) == (aim.x, aim.y)), aim)
        return same, False
    return sites[0], True


def frame_altitude_m(frame: MosaicFrame, target_map: np.ndarray) -> float:
    """The frame's sensor height above the target by the navigation estimate, metres."""
    return float(frame.origin_map[2] + frame.nav_sensor_position[2] - np.asarray(target_map, np.float64)[2])


def fly(
    run: DetectRun,
    frames: Sequence[MosaicFrame],
    target_map: np.ndarray,
    dem: DemSpec,
    poses: Poses,
    settings: DetectSettings,
    threshold: tuple[float, ThresholdJson],
) -> list[FrameStep]:
    """One descent flown frame by frame (the module's steps 1-4): one :class:`FrameStep` per frame.

    ``frames``: the descent's frames in the order they arrive (``hdlabels.mosaic.descent_frames`` at one
    noise level); ``dem``: the mosaic's grid (the run's); ``settings``: how each mosaic is mapped
    (``settings.sigma_m`` the frames' noise level, metres); ``threshold``: H_t (nats) and its record,
    found once (``hdnet.detect.detect_threshold``). A mosaic with no lander-footprint-sized square of
    valid cells (a frame that saw little ground) is recorded without a map, the aim held, and the
    descent goes on (``FrameStep.no_map`` says why).
    """
    mosaic = OnlineMosaic(target_map, dem, poses)
    steps: list[FrameStep] = []
    aim: Site | None = None
    start = time.perf_counter()
    for k, frame in enumerate(frames):
        heights, registration, t_reg, t_mosaic = mosaic.add(frame)
        times: dict[str, float] = {"map": 0.0, "sites": 0.0}
        maps, no_map = _map_of(run, heights, settings, threshold, times)
        t0 = time.perf_counter()
        old = aim
        diverted = False
        if maps is not None:
            aim, diverted = retarget(aim, maps.sites, maps.safety, maps.transform, run.lander, settings.site_margin_m)
        t_sites = times["sites"] + time.perf_counter() - t0
        divert = None
        altitude = frame_altitude_m(frame, target_map)
        if diverted and old is not None and aim is not None:
            divert = Divert(
                frame=k,
                elapsed_s=time.perf_counter() - start,
                altitude_m=altitude,
                old=(old.x, old.y),
                new=(aim.x, aim.y),
                distance_m=math.hypot(aim.x - old.x, aim.y - old.y),
                reason=REASON_UNSAFE,
            )
        timing = FrameTiming(t_reg, t_mosaic, times["map"], t_sites)
        steps.append(FrameStep(k, altitude, heights, maps, aim, divert, timing, registration, no_map))
    return steps


def _map_of(
    run: DetectRun,
    heights: np.ndarray,
    settings: DetectSettings,
    threshold: tuple[float, ThresholdJson],
    times: dict[str, float],
) -> tuple[DetectMaps | None, str | None]:
    """Step 3 of :func:`fly`: the mosaic's maps and sites, or (None, why) when it has no
    lander-footprint-sized square of valid cells (``TerrainError``; the seconds spent into ``times``)."""
    t0 = time.perf_counter()
    try:
        return map_heights(run, heights, settings, threshold, scan_frame=True, timings=times), None
    except TerrainError as exc:
        times["map"] = time.perf_counter() - t0
        return None, f"{REASON_NO_MAP}: {exc}"
