"""Descent mosaics: the frames of one descent placed in one frame and gridded into one DEM.

A descent (``lidarsim``'s descent mode, docs/lidarsim.md) is K frames taken from decreasing
altitudes toward one target point. Each frame is stored in its own scan frame with its true pose
and the navigation system's estimate of it. A hazard-detection system knows only the estimate, so it
places each frame's points in the map with the estimated pose (:func:`placed_points`); frames
placed with poses that are wrong by metres and tenths of a degree disagree where they overlap, and
the mosaic gets steps and tilts that look like slopes and rocks.

Three ways to place the frames, the *poses* of a mosaic:

* ``"true"``: the true poses (what a perfect navigation system would give; the reference);
* ``"nav"``: the navigation estimates alone (a system without terrain-relative registration);
* ``"registered"``: the navigation estimates corrected by registering every frame to the
  *anchor* frame, the last (lowest, densest) one, with Open3D's point-to-plane ICP run coarse to
  fine (:func:`register_frames`). Registration makes the frames agree with each other; the mosaic
  as a whole keeps the anchor's navigation error (nothing in the scans tells where the terrain is
  in the map).

The mosaic frame is centred at the descent's target point (``target_map``: x east, y north, z up,
metres, relative to the target and its reference height), so a mosaic DEM is gridded exactly like a
single frame's DEM, centred at its origin. Each frame is gridded on its own by the labelling's
gridding (``hdlabels.grid.grid_points``, which needs a frame's detector order). A cell takes the
mean of the heights of the frames that *resolve* it (their returns no farther apart than the DEM's
spacing), weighted by each frame's density of returns (returns per square metre,
``1 / spacing**2``); the coarser frames fill, the same way, only the cells that no resolving frame
covers: the edges of the area that the low frames do not see (:func:`combine_grids`). A coarse
frame's cell is interpolated between returns a metre or more apart, which flattens the rocks the
fine frames see: averaged in everywhere, it made a mosaic that calls rocky ground safe.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from hdlabels.errors import HdLabelsError
from hdlabels.grid import cell_centres, grid_points
from hdlabels.store import DemSpec
from hdlabels.truth import mesh_heights
from lidarsim.navigation import estimated_map_points
from lidarsim.shards import Scan
from lidarsim.terrain import DTM

Poses = Literal["true", "nav", "registered"]
POSES: tuple[Poses, ...] = ("true", "nav", "registered")

# hd choice: the ICP's voxel sizes (metres), coarse to fine, and at each scale the largest
# correspondence distance (multiple of the voxel) and the iterations. The coarse scale reaches
# frames misplaced by a few metres (3 m of navigation error, 1 degree at 250 m); the fine one works
# at the low frames' spacing (0.4 m at 250 m).
ICP_VOXELS_M: tuple[float, ...] = (2.0, 1.0, 0.5, 0.25)
ICP_MAX_DISTANCE_VOXELS = 3.0
ICP_ITERATIONS = 30
# hd choice: ICP stops at a scale when fitness and RMS change by less than this fraction.
ICP_RELATIVE_CHANGE = 1e-6
# hd choice: the source frames are downsampled to at least this voxel (metres), also at the finest
# scale: their points only need the anchor's fine surface (and its normals) to slide onto.
SOURCE_MIN_VOXEL_M = 0.5
# hd choice: neighbours (at most) and radius (voxels) for the anchor's normals at each scale.
NORMAL_MAX_NN = 30
NORMAL_RADIUS_VOXELS = 3.0
# hd choice: the area registered: the anchor's returns within the DEM's half-width plus this margin
# (metres) of the target, and the other frames' returns within the box those span, widened by the
# coarsest correspondence distance (points farther out cannot have a correspondence).
REGISTRATION_MARGIN_M = 10.0


@dataclass(frozen=True)
class MosaicFrame:
    """One frame of a descent, as stored in its scan shard (docs/shard-format.md, schema 1.3).

    Attributes:
        points: float32 (H, W, 3) returns in the frame's scan frame, metres; NaN where none.
        origin_map: (3,) map coordinates of the scan frame's origin, metres.
        sensor_position: (3,) true sensor position in the scan frame, metres.
        attitude: (3, 3) true rotation from the sensor frame to the scan frame.
        nav_sensor_position: (3,) the navigation estimate of ``sensor_position``, metres.
        nav_attitude: (3, 3) the navigation estimate of ``attitude``.
    """

    points: np.ndarray
    origin_map: np.ndarray
    sensor_position: np.ndarray
    attitude: np.ndarray
    nav_sensor_position: np.ndarray
    nav_attitude: np.ndarray

    @property
    def navigation_is_perfect(self) -> bool:
        """True when the navigation estimate is the true pose exactly (it then places the frame bit for bit
        as the true pose does)."""
        return np.array_equal(self.nav_attitude, self.attitude) and np.array_equal(
            self.nav_sensor_position, self.sensor_position
        )


def rigid(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """The 4 x 4 homogeneous matrix of ``x -> rotation @ x + translation`` (metres)."""
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = translation
    return out


def apply(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``transform`` (4 x 4) applied to float points (..., 3), in float64; NaN stays NaN."""
    p = np.asarray(points, dtype=np.float64)
    return p @ transform[:3, :3].T + transform[:3, 3]


def navigation_error(frame: MosaicFrame) -> np.ndarray:
    """The rigid map transform (4 x 4) taking a true map point to where the navigation estimate puts it:
    ``lidarsim.navigation.estimated_map_points`` as a matrix, so that it can be inverted.

    A return at true map point ``m`` was measured as range and direction from the sensor; the
    navigation system rebuilds it from its own pose, at
    ``origin + s_nav + R_nav R^T (m - origin - s)`` (``s``, ``R``: the true pose; ``_nav``: the estimate).
    A frame whose estimate equals its true pose gets the identity exactly.
    """
    if frame.navigation_is_perfect:
        return np.eye(4)
    r_err = frame.nav_attitude @ frame.attitude.T
    s_true = frame.origin_map + frame.sensor_position
    s_nav = frame.origin_map + frame.nav_sensor_position
    return rigid(r_err, s_nav - r_err @ s_true)


def placed_points(frame: MosaicFrame, target_map: np.ndarray, poses: Literal["true", "nav"]) -> np.ndarray:
    """The frame's returns in the mosaic frame (relative to ``target_map``), float64 (H, W, 3), metres.

    ``poses="true"`` places them with the true pose, ``"nav"`` with the navigation estimate.
    """
    if poses == "true" or frame.navigation_is_perfect:
        placed = frame.points.astype(np.float64) + frame.origin_map
    else:
        placed = estimated_map_points(
            frame.points,
            frame.origin_map,
            frame.sensor_position,
            frame.attitude,
            frame.nav_sensor_position,
            frame.nav_attitude,
        )
    return placed - np.asarray(target_map, dtype=np.float64)


def sample_spacing_m(points: np.ndarray) -> float:
    """Median horizontal distance between detector neighbours (metres): a frame's ground sample spacing."""
    p = np.asarray(points, dtype=np.float64)
    dx = np.hypot(*(p[:, 1:, :2] - p[:, :-1, :2]).transpose(2, 0, 1)).ravel()
    dy = np.hypot(*(p[1:, :, :2] - p[:-1, :, :2]).transpose(2, 0, 1)).ravel()
    d = np.concatenate([dx, dy])
    d = d[np.isfinite(d) & (d > 0)]
    if d.size == 0:
        raise HdLabelsError("a frame of the descent has no two neighbouring returns: it cannot be placed")
    return float(np.median(d))


def frame_grids(clouds: Sequence[np.ndarray], dem: DemSpec) -> tuple[np.ndarray, np.ndarray]:
    """Each placed frame gridded alone, and its weight.

    Returns:
        ``(grids, weights)``: float64 (K, rows, cols) heights, metres (NaN where the frame has no
        support), and (K,) returns per square metre of each frame (``1 / sample_spacing_m**2``).
    """
    if not clouds:
        raise HdLabelsError("a mosaic needs at least one frame")
    grids = np.stack(
        [grid_points(c, (dem.rows, dem.cols), dem.spacing_m, method=dem.gridding).astype(np.float64) for c in clouds]
    )
    weights = np.array([1.0 / sample_spacing_m(c) ** 2 for c in clouds])
    return grids, weights


def weighted_mean(grids: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The weighted mean of the frames' heights in each cell (float64 metres; NaN where none has one)."""
    ok = np.isfinite(grids)
    w = np.where(ok, weights[:, None, None], 0.0)
    total = (w * np.where(ok, grids, 0.0)).sum(axis=0)
    weight = w.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = total / weight
    out[weight == 0] = np.nan
    return out


def combine_grids(grids: np.ndarray, weights: np.ndarray, spacing_m: float) -> np.ndarray:
    """One DEM from the frames' grids (float32 metres; NaN where no frame has a height).

    Args:
        grids: (K, rows, cols) each frame gridded alone, metres.
        weights: (K,) each frame's returns per square metre (``1 / sample_spacing_m**2``).
        spacing_m: the DEM's spacing, metres/pixel.

    A cell takes the weighted mean (``weights``) of the frames that resolve it, those whose returns
    are at most ``spacing_m`` apart (``weights >= 1 / spacing_m**2``); where none of them has a
    height, the weighted mean of the coarser frames. When no frame resolves the grid, all are
    averaged. (Measured on mars-descent's test descents against the terrain: averaging every frame
    everywhere gave the clean mosaic's labels a precision of 0.852 for "safe", this rule 0.886, the
    finest frame alone in each cell 0.894 with far lower sensitivity, docs/results.md.)
    """
    resolving = weights >= 1.0 / spacing_m**2 * (1.0 - 1e-9)
    if resolving.all() or not resolving.any():
        return weighted_mean(grids, weights).astype(np.float32)
    out = weighted_mean(grids[resolving], weights[resolving])
    gaps = np.isnan(out)
    out[gaps] = weighted_mean(grids[~resolving], weights[~resolving])[gaps]
    return out.astype(np.float32)


def mosaic_dem(clouds: Sequence[np.ndarray], dem: DemSpec) -> np.ndarray:
    """One DEM from several placed frames (float32 metres, NaN where no frame has support).

    Args:
        clouds: organised (H, W, 3) returns of each frame in the mosaic frame (metres), in detector
            order (the ``linear`` gridding triangulates over it).
        dem: the grid (rows, cols, spacing_m metres/pixel, gridding), centred at the target.

    Each frame is gridded alone and the grids are combined by :func:`combine_grids` (the frames
    that resolve a cell, weighted by their returns per square metre; coarser ones where none does).
    """
    return combine_grids(*frame_grids(clouds, dem), dem.spacing_m)


def anchor_residuals(grids: np.ndarray, anchor: int = -1) -> np.ndarray:
    """(K,) RMS height difference of each frame's grid to the anchor's on the cells both cover, metres
    (0 for the anchor; NaN for a frame sharing no cell with it): how well the frames agree."""
    ref = grids[anchor]
    out = np.full(grids.shape[0], np.nan)
    for k in range(grids.shape[0]):
        d = grids[k] - ref
        d = d[np.isfinite(d)]
        if d.size:
            out[k] = float(np.sqrt(np.mean(d * d)))
    return out


@dataclass(frozen=True)
class Registration:
    """Corrections found by :func:`register_frames`.

    Attributes:
        corrections: (K, 4, 4) rigid transforms applied to each placed frame (identity for the anchor).
        fitness: (K,) fraction of the frame's registered points with a correspondence at the finest scale.
        rmse_m: (K,) RMS distance of those correspondences (to the nearest anchor point after the
            finest scale's downsampling; Open3D's ``inlier_rmse``), metres.
    """

    corrections: np.ndarray
    fitness: np.ndarray
    rmse_m: np.ndarray

    def translation_m(self) -> np.ndarray:
        """(K,) length of each correction's translation, metres."""
        return np.linalg.norm(self.corrections[:, :3, 3], axis=1)

    def rotation_deg(self) -> np.ndarray:
        """(K,) angle of each correction's rotation, degrees."""
        trace = np.trace(self.corrections[:, :3, :3], axis1=1, axis2=2)
        return np.degrees(np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0)))


def _cloud(points: np.ndarray, half_width_m: float) -> np.ndarray:
    """Finite returns within ``half_width_m`` of the target (horizontally), (N, 3) float64."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    keep = np.isfinite(p).all(axis=1) & (np.abs(p[:, 0]) <= half_width_m) & (np.abs(p[:, 1]) <= half_width_m)
    return p[keep]


def register_frames(clouds: Sequence[np.ndarray], half_width_m: float, anchor: int = -1) -> Registration:
    """Register every frame to the anchor frame: coarse-to-fine point-to-plane ICP (Open3D).

    Args:
        clouds: (H, W, 3) returns of each frame placed in the mosaic frame with the navigation poses, metres.
        half_width_m: half-width of the area registered around the target, metres (the DEM's
            half-width; ``REGISTRATION_MARGIN_M`` is added).
        anchor: index of the frame the others are registered to (default the last, lowest frame).

    Returns:
        The corrections (the anchor's is the identity) and each frame's fit at the finest scale.

    At each voxel size of ``ICP_VOXELS_M`` both clouds are voxel-downsampled (the source to at least
    ``SOURCE_MIN_VOXEL_M``), the anchor's normals estimated (``NORMAL_RADIUS_VOXELS``,
    ``NORMAL_MAX_NN``), and ICP runs from the previous scale's transform with correspondences up to
    ``ICP_MAX_DISTANCE_VOXELS`` voxels, until fitness and RMS change by less than
    ``ICP_RELATIVE_CHANGE`` (at most ``ICP_ITERATIONS`` iterations). Only returns where the anchor
    has some take part (``REGISTRATION_MARGIN_M``). Open3D runs in one thread here: its parallel
    sums are not reproducible to the last bit, and a mosaic must be the same bytes on every run
    (``hd mosaic`` runs descents in parallel processes instead).
    """
    import open3d as o3d  # Open3D loads in ~0.5 s: only registration needs it

    threads = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(1)  # ICP's parallel sums differ in the last bits from run to run
    try:
        return _register(o3d, clouds, half_width_m, anchor)
    finally:
        o3d.utility.set_max_threads(threads)


def _register(o3d: Any, clouds: Sequence[np.ndarray], half_width_m: float, anchor: int) -> Registration:
    """:func:`register_frames` with Open3D loaded and set to one thread."""
    reg = o3d.pipelines.registration
    k_frames = len(clouds)
    if k_frames == 0:
        raise HdLabelsError("registration needs at least one frame")
    anchor = anchor % k_frames
    reach = half_width_m + REGISTRATION_MARGIN_M
    target_points = _cloud(clouds[anchor], reach)
    corrections = np.tile(np.eye(4), (k_frames, 1, 1))
    fitness = np.ones(k_frames)
    rmse = np.zeros(k_frames)
    if target_points.shape[0] < 3:
        raise HdLabelsError("the anchor frame has fewer than 3 returns near the target: nothing to register to")
    widen = ICP_MAX_DISTANCE_VOXELS * max(ICP_VOXELS_M)
    box_lo, box_hi = target_points[:, :2].min(axis=0) - widen, target_points[:, :2].max(axis=0) + widen
    target_full = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target_points))
    targets = []
    for voxel in ICP_VOXELS_M:
        target = target_full.voxel_down_sample(voxel)
        target.estimate_normals(
            o3d.geometry.KDTreeSearchParamHybrid(radius=NORMAL_RADIUS_VOXELS * voxel, max_nn=NORMAL_MAX_NN)
        )
        targets.append(target)
    criteria = reg.ICPConvergenceCriteria(
        relative_fitness=ICP_RELATIVE_CHANGE, relative_rmse=ICP_RELATIVE_CHANGE, max_iteration=ICP_ITERATIONS
    )
    estimation = reg.TransformationEstimationPointToPlane()
    # From the anchor outwards: each frame starts from the correction of its neighbour nearer the
    # anchor, whose navigation error differs from its own by one step of the random walk.
    order = [*range(anchor - 1, -1, -1), *range(anchor + 1, k_frames)]
    for k in order:
        source_points = _cloud(clouds[k], reach)
        source_points = source_points[((source_points[:, :2] >= box_lo) & (source_points[:, :2] <= box_hi)).all(axis=1)]
        if source_points.shape[0] < 3:
            fitness[k], rmse[k] = 0.0, math.nan
            continue
        source_full = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source_points))
        current = corrections[k + 1] if k < anchor else corrections[k - 1]
        result = None
        for voxel, target in zip(ICP_VOXELS_M, targets, strict=True):
            source = source_full.voxel_down_sample(max(voxel, SOURCE_MIN_VOXEL_M))
            result = reg.registration_icp(
                source, target, ICP_MAX_DISTANCE_VOXELS * voxel, current, estimation, criteria
            )
            current = np.asarray(result.transformation)
        assert result is not None
        corrections[k] = current
        fitness[k], rmse[k] = float(result.fitness), float(result.inlier_rmse)
    return Registration(corrections=corrections, fitness=fitness, rmse_m=rmse)


def registered_clouds(placed: Sequence[np.ndarray], dem: DemSpec) -> tuple[list[np.ndarray], Registration]:
    """Frames placed by their navigation poses, registered to the last one (:func:`register_frames` over
    the DEM's half-width) and moved by their corrections: the placement of :func:`mosaic_frames`'s
    ``"registered"`` poses (the anchor, whose correction is the identity, is returned as it is)."""
    half_width = 0.5 * max(dem.rows, dem.cols) * dem.spacing_m
    registration = register_frames(placed, half_width)
    moved = [
        p if np.array_equal(t, np.eye(4)) else apply(t, p)
        for t, p in zip(registration.corrections, placed, strict=True)
    ]
    return moved, registration


@dataclass(frozen=True)
class Mosaic:
    """The mosaic of one descent.

    Attributes:
        heights: float32 (rows, cols) DEM, metres, in the mosaic frame (centred at the target).
        poses: how the frames were placed (one of ``POSES``).
        frame_residual_m: (K,) RMS height difference of each frame to the anchor (the last frame)
            where both cover the grid, metres (``anchor_residuals``).
        registration: the registration's corrections and fit (``"registered"`` only).
    """

    heights: np.ndarray
    poses: Poses
    frame_residual_m: np.ndarray
    registration: Registration | None = None


def mosaic_frames(frames: Sequence[MosaicFrame], target_map: np.ndarray, dem: DemSpec, poses: Poses) -> Mosaic:
    """The mosaic of one descent: its frames placed by ``poses`` (registered for ``"registered"``) and gridded."""
    if poses not in POSES:
        raise HdLabelsError(f"unknown poses {poses!r}; use one of {', '.join(POSES)}")
    placed = [placed_points(f, target_map, "true" if poses == "true" else "nav") for f in frames]
    registration = None
    if poses == "registered":
        placed, registration = registered_clouds(placed, dem)
    grids, weights = frame_grids(placed, dem)
    return Mosaic(combine_grids(grids, weights, dem.spacing_m), poses, anchor_residuals(grids), registration)


def terrain_residual(
    heights: np.ndarray, dem: DemSpec, target_map: np.ndarray, to_true: np.ndarray, dtm: DTM
) -> np.ndarray:
    """Height error of a mosaic DEM against the terrain, metres (float64, NaN where the DEM has none).

    Args:
        heights: (rows, cols) mosaic DEM, metres, in the mosaic frame.
        dem: its grid (centred at the target).
        target_map: (3,) the target's map coordinates (the mosaic frame's origin), metres.
        to_true: 4 x 4 transform taking a placed map point to the true map point: the identity for
            the true poses, the inverse of the anchor's :func:`navigation_error` for a mosaic placed
            in the anchor's navigation frame (``"nav"`` and ``"registered"``).
        dtm: the terrain the frames were cast on (its triangle mesh is the truth, ``hdlabels.truth.mesh_heights``).

    Each cell centre with its mosaic height is taken back to the true map and compared with the
    terrain's height there (vertically).
    """
    xc, yc = cell_centres((dem.rows, dem.cols), dem.spacing_m)
    xx, yy = np.meshgrid(xc, yc)
    placed = np.stack([xx, yy, np.asarray(heights, dtype=np.float64)], axis=-1) + np.asarray(target_map, float)
    true = apply(to_true, placed)
    return true[..., 2] - mesh_heights(dtm, true[..., 0], true[..., 1])


def descent_frames(scans: Sequence[Scan], sigma_index: int | None) -> tuple[list[MosaicFrame], np.ndarray]:
    """The frames of one descent as read from its shard (``lidarsim.shards.iter_descents``), and its target.

    Args:
        scans: the descent's K frames, frame 0 first (each with its ``descent`` record, schema 1.3).
        sigma_index: which stored noise level's points (``points_noisy[sigma_index]``); None: the clean points.

    Returns:
        ``(frames, target_map)``: the frames with both poses, and the descent's target (3,), map metres.

    Raises:
        HdLabelsError: a scan without its descent record (not a descent build's).
    """
    frames = []
    for scan in scans:
        record = scan.descent
        if record is None:
            raise HdLabelsError(f"scan {scan.scan_index} is not a descent's frame (its shard has no descent record)")
        points = scan.points_clean if sigma_index is None else scan.points_noisy[sigma_index]
        frames.append(
            MosaicFrame(
                points=points,
                origin_map=np.asarray(scan.origin_map, dtype=np.float64),
                sensor_position=np.asarray(scan.sensor_position, dtype=np.float64),
                attitude=np.asarray(scan.sensor_attitude, dtype=np.float64),
                nav_sensor_position=np.asarray(record.nav_sensor_position, dtype=np.float64),
                nav_attitude=np.asarray(record.nav_sensor_attitude, dtype=np.float64),
            )
        )
    if not frames:
        raise HdLabelsError("a descent without frames")
    return frames, np.asarray(scans[0].descent.target_map, dtype=np.float64)  # type: ignore[union-attr]  # checked above
