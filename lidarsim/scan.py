"""Ray casting: terrain mesh, Open3D scene and the clean and noisy points of each scan.

The terrain under a tile of scans is read as a window of the DTM, turned into a triangle mesh
whose vertices are the DTM cell centres (two triangles per 2x2 block of valid cells; a triangle
touching a nodata cell is left out, so rays through holes miss), recentred at the tile centre
(Open3D works in float32) and handed to Open3D's ``RaycastingScene`` (Embree).

Each ray has a unit direction, so the ray parameter returned by Open3D is the true range ``r``.
A noisy range is ``r + N(0, sigma^2)``, drawn from the stream ``(seed, RANGE_NOISE, scan,
sigma)``; the noisy point is ``o + r_noisy * d`` (``lidarsim.noise``, the one noise model, also
used on the fly by training and evaluation). Points are returned in the scan frame (origin
at the nadir point on the reference height, x east, y north, z up), computed in float64 and
stored as float32.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from lidarsim.descent import frame_pose
from lidarsim.footprint import FootprintConfig, pixel_ranges, spot_weights, subray_directions, subreturn_energy
from lidarsim.noise import NoiseModel, noisy_points, points_at_ranges, scan_directions
from lidarsim.reach import candidate_triangles
from lidarsim.sensor import SensorConfig, sensor_attitude
from lidarsim.streams import Purpose, stream
from lidarsim.terrain import DTM
from lidarsim.trajectory import TrajectoryConfig

# Element status codes stored per detector element (public: documented in docs/shard-format.md).
STATUS_RETURN = 0  # a return from the terrain
STATUS_MISS = 1  # the ray hit no terrain (nodata hole or beyond the DTM)
STATUS_DEAD = 2  # a dead detector element: never returns
STATUS_DAMAGED = 3  # a damaged element: returns, with a large extra range error in the noisy ranges
STATUS_WEAK = 4  # no return: the signal was below the noise model's detection threshold (NaN points)


def terrain_mesh(
    heights: np.ndarray,
    x_centres: np.ndarray,
    y_centres: np.ndarray,
    origin: tuple[float, float, float],
    keep: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Triangle mesh of a gridded height window, recentred at ``origin``.

    Args:
        heights: float64 (rows, cols) heights, metres, NaN where nodata.
        x_centres: (cols,) map x of the cell centres, metres.
        y_centres: (rows,) map y of the cell centres, metres.
        origin: map coordinates (x, y, z) subtracted from every vertex, metres.
        keep: optional bool (rows - 1, cols - 1) masks of the triangles to keep of each 2 x 2
            block, ``(a, c, b)`` and ``(b, c, d)`` (``lidarsim.reach.candidate_triangles``); the
            vertices are all kept.

    Returns:
        ``(vertices, triangles)``: float32 (rows*cols, 3) and uint32 (M, 3). Only triangles whose
        three vertices are valid are kept.
    """
    rows, cols = heights.shape
    valid = np.isfinite(heights)
    xx = np.broadcast_to(x_centres[None, :] - origin[0], (rows, cols))
    yy = np.broadcast_to(y_centres[:, None] - origin[1], (rows, cols))
    zz = np.where(valid, heights - origin[2], 0.0)
    vertices = np.stack([xx, yy, zz], axis=-1).reshape(-1, 3).astype(np.float32)
    idx = np.arange(rows * cols, dtype=np.uint32).reshape(rows, cols)
    a, b = idx[:-1, :-1], idx[:-1, 1:]
    c, d = idx[1:, :-1], idx[1:, 1:]
    va, vb, vc, vd = valid[:-1, :-1], valid[:-1, 1:], valid[1:, :-1], valid[1:, 1:]
    ok1, ok2 = va & vc & vb, vb & vc & vd
    if keep is not None:
        ok1, ok2 = ok1 & keep[0], ok2 & keep[1]
    tri1 = np.stack([a, c, b], axis=-1)[ok1]
    tri2 = np.stack([b, c, d], axis=-1)[ok2]
    return vertices, np.concatenate([tri1, tri2]).astype(np.uint32)


@dataclass(frozen=True)
class ScanGeometry:
    """Pose of one scan.

    Attributes:
        origin_map: (3,) map coordinates of the scan-frame origin (nadir x, y, or a descent's target;
            reference height), metres.
        sensor_position: (3,) sensor position in the scan frame, metres.
        attitude: (3, 3) rotation from the sensor frame to the scan frame.
    """

    origin_map: np.ndarray
    sensor_position: np.ndarray
    attitude: np.ndarray


@dataclass(frozen=True)
class ScanResult:
    """Clean and noisy points of one scan (scan frame, metres)."""

    geometry: ScanGeometry
    points_clean: np.ndarray  # float32 (rows, cols, 3), NaN where no return
    points_noisy: np.ndarray  # float32 (n_sigma, rows, cols, 3)
    status: np.ndarray  # uint8 (rows, cols), STATUS_* codes
    noise_scale: np.ndarray | None = None  # float32 (rows, cols): factor on each sigma (snr noise model)


def element_defects(sensor: SensorConfig, seed: int) -> np.ndarray:
    """Status map of the detector's permanent defects (dead and damaged elements), uint8 (rows, cols)."""
    status = np.zeros((sensor.rows, sensor.cols), dtype=np.uint8)
    n = sensor.rows * sensor.cols
    if sensor.dead_elements:
        dead = stream(seed, Purpose.DEAD_ELEMENTS).choice(n, sensor.dead_elements, replace=False)
        status.flat[dead] = STATUS_DEAD
    if sensor.damaged_elements:
        free = np.flatnonzero(status.ravel() == STATUS_RETURN)
        damaged = stream(seed, Purpose.DAMAGED_ELEMENTS).choice(free, sensor.damaged_elements, replace=False)
        status.flat[damaged] = STATUS_DAMAGED
    return status


# A window of the tile's grid: rows row0 .. row1 - 1, columns col0 .. col1 - 1 (indices into its heights).
Window = tuple[int, int, int, int]


class TileScene:
    """The terrain around one tile of scans, and the Open3D scenes its rays are cast against.

    The tile's window of the DTM is read once; its mean height fixes the float32 frame's origin.
    Rays are cast against a mesh of only the part of the window they can reach (:meth:`reach`,
    :meth:`focus`): a sub-window of the same grid recentred at the same origin, so its vertices
    and triangles are bit for bit those of the whole window's mesh, and every ray's first hit is
    the same triangle at the same float32 range. Embree's BVH build, linear in the triangles, then
    costs the ground the scans see rather than the whole tile (docs/benchmarks.md, "Large terrains").

    Args:
        dtm: an open DTM.
        centre_xy: map coordinates of the tile centre, metres (the float32 frame's origin).
        half_extent_m: half side of the square terrain window loaded around the centre, metres.
    """

    def __init__(self, dtm: DTM, centre_xy: tuple[float, float], half_extent_m: float) -> None:
        cx, cy = centre_xy
        r_a, c_a = dtm.rowcol_of_xy(
            np.array([cx - half_extent_m, cx + half_extent_m]), np.array([cy + half_extent_m, cy - half_extent_m])
        )
        row0 = int(np.floor(min(r_a))) - 1
        col0 = int(np.floor(min(c_a))) - 1
        nrows = int(np.ceil(max(r_a))) + 2 - row0
        ncols = int(np.ceil(max(c_a))) + 2 - col0
        heights = dtm.read(row0, col0, nrows, ncols)
        xs, _ = dtm.cell_center_xy(
            np.full(ncols, row0, dtype=np.float64), np.arange(col0, col0 + ncols, dtype=np.float64)
        )
        _, ys = dtm.cell_center_xy(
            np.arange(row0, row0 + nrows, dtype=np.float64), np.full(nrows, col0, dtype=np.float64)
        )
        finite = heights[np.isfinite(heights)]
        z_ref = float(np.round(finite.mean())) if finite.size else 0.0
        self.origin = np.array([cx, cy, z_ref], dtype=np.float64)
        self.heights = heights
        self.x_centres = np.asarray(xs, dtype=np.float64)
        self.y_centres = np.asarray(ys, dtype=np.float64)
        # the lowest and highest terrain (map z, metres): a ray's hit lies between the two heights
        self.z_range = (float(finite.min()), float(finite.max())) if finite.size else (z_ref, z_ref)
        self.full_window: Window = (0, nrows, 0, ncols)
        self.window: Window | None = None  # the window of the scene rays are cast against now
        self.only_hits: Window | None = None  # the window whose hit triangles the next cast meshes
        self.scene = o3d.t.geometry.RaycastingScene()
        self.n_triangles = 0
        self.triangles_built = 0  # triangles of every scene built so far (the BVH builds' work)

    def reach(self, origins_map: np.ndarray, directions: np.ndarray) -> Window:
        """The smallest window holding every triangle that rays from ``origins_map`` along
        ``directions`` can hit, one cell beyond on every side.

        A ray meets the terrain only between the window's highest and lowest heights, so its hit
        lies, seen from above, on the segment between the points where it crosses those two
        heights; the box of these segments, widened by a cell, holds every cell of a triangle the
        ray can hit. A ray that does not descend may hit anything: the whole window.

        Args:
            origins_map: float64 (S, 3) ray origins (map coordinates), metres.
            directions: float64 (S, ..., 3) unit directions of the rays from each origin; any rays
                inside the pyramid they span may be cast (e.g. the detector's corner rays).
        """
        s = origins_map.shape[0]
        d = np.asarray(directions, dtype=np.float64).reshape(s, -1, 3)
        if not (d[..., 2] < -1e-9).all():
            return self.full_window
        o = np.asarray(origins_map, dtype=np.float64)[:, None, :]
        window = self._box_window(o, d, self.z_range)
        # Again with the heights of that window: the hit lies in it, hence between its own extremes.
        r0, r1, c0, c1 = window
        sub = self.heights[r0:r1, c0:c1]
        finite = sub[np.isfinite(sub)]
        if finite.size == 0:
            return window
        return self._box_window(o, d, (float(finite.min()), float(finite.max())))

    def _box_window(self, o: np.ndarray, d: np.ndarray, z_range: tuple[float, float]) -> Window:
        """The window of the box of the rays' segments between heights ``z_range`` (map z, metres), plus a cell."""
        z_low, z_high = z_range
        xs, ys = [], []
        for z in (z_low, z_high):
            t = np.maximum((z - o[..., 2]) / d[..., 2], 0.0)
            xs.append(o[..., 0] + t * d[..., 0])
            ys.append(o[..., 1] + t * d[..., 1])
        x_min, x_max = min(float(x.min()) for x in xs), max(float(x.max()) for x in xs)
        y_min, y_max = min(float(y.min()) for y in ys), max(float(y.max()) for y in ys)
        nrows, ncols = self.heights.shape
        if ncols < 2 or nrows < 2:
            return self.full_window
        dx = self.x_centres[1] - self.x_centres[0]
        dy = self.y_centres[0] - self.y_centres[1]  # row 0 is north
        col0 = math.floor((x_min - self.x_centres[0]) / dx) - 1
        col1 = math.ceil((x_max - self.x_centres[0]) / dx) + 2
        row0 = math.floor((self.y_centres[0] - y_max) / dy) - 1
        row1 = math.ceil((self.y_centres[0] - y_min) / dy) + 2
        clip = lambda v, n: min(max(v, 0), n)  # noqa: E731 - one line, used four times
        return (clip(row0, nrows), clip(row1, nrows), clip(col0, ncols), clip(col1, ncols))

    def focus(self, window: Window, only_hits: bool = False) -> None:
        """Cast the next rays against the mesh of ``window`` (kept if the current one holds it).

        With ``only_hits``, the next :meth:`cast` builds a mesh of only the triangles of ``window``
        its rays can hit first (``lidarsim.reach``), for that call alone: a scan whose rays are
        cast in one call (a sparse trajectory) then costs a BVH of ~25,000 triangles, not ~94,000."""
        self.only_hits = window if only_hits else None
        if only_hits or (self.window is not None and _holds(self.window, window)):
            return
        self._build(window)

    def _build(self, window: Window, keep: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """A new scene of the mesh of ``window`` (only the triangles in ``keep``, if given)."""
        r0, r1, c0, c1 = window
        vertices, triangles = terrain_mesh(
            self.heights[r0:r1, c0:c1], self.x_centres[c0:c1], self.y_centres[r0:r1], tuple(self.origin), keep
        )
        self.window = window if keep is None else None
        self.n_triangles = int(triangles.shape[0])
        self.triangles_built += self.n_triangles
        self.scene = o3d.t.geometry.RaycastingScene()
        if self.n_triangles:
            self.scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(triangles))  # type: ignore[call-overload]  # stubs omit ndarray

    def plan(self, windows: list[Window]) -> list[tuple[Window, list[int]]]:
        """Group consecutive scans whose windows are cheaper built as one: ``(window, positions in
        windows)`` in order. A scan joins the group before it when their joint window has no more
        cells than the two apart; groups that together hold as many cells as the whole window
        become one group of the whole window (a dense trajectory: one BVH per tile, as before)."""
        groups: list[tuple[Window, list[int]]] = []
        for k, w in enumerate(windows):
            if groups:
                joint = _union(groups[-1][0], w)
                if _cells(joint) <= _cells(groups[-1][0]) + _cells(w):
                    groups[-1] = (joint, [*groups[-1][1], k])
                    continue
            groups.append((w, [k]))
        if sum(_cells(w) for w, _ in groups) >= _cells(self.full_window):
            return [(self.full_window, list(range(len(windows))))]
        return groups

    def mean_height(self, x: float, y: float, half_width_m: float) -> float:
        """Mean valid terrain height in the square of half-width ``half_width_m`` around (x, y), metres."""
        cols = np.abs(self.x_centres - x) <= half_width_m
        rows = np.abs(self.y_centres - y) <= half_width_m
        window = self.heights[np.ix_(rows, cols)]
        return float(np.nanmean(window))

    def cast(self, origins_map: np.ndarray, directions: np.ndarray, n_threads: int = 0) -> np.ndarray:
        """Ranges of rays, metres.

        Args:
            origins_map: float64 (S, 3) ray origins (map coordinates), one per scan.
            directions: float64 (S, rows, cols, 3) unit directions.
            n_threads: Embree threads (0 = all cores).

        Returns:
            float32 (S, rows, cols) ranges, NaN where the ray hits no terrain.
        """
        s, rows, cols, _ = directions.shape
        self._focus_on(origins_map, directions)
        rays = np.empty((s, rows, cols, 6), dtype=np.float32)
        rays[..., :3] = (origins_map - self.origin)[:, None, None, :]
        rays[..., 3:] = directions
        if self.n_triangles == 0:
            return np.full((s, rows, cols), np.nan, dtype=np.float32)
        rays_o3d = o3d.core.Tensor(rays.reshape(-1, 6))  # type: ignore[call-overload]  # stubs omit ndarray
        hit = self.scene.cast_rays(rays_o3d, nthreads=n_threads)
        t = hit["t_hit"].numpy().reshape(s, rows, cols)
        return np.where(np.isfinite(t), t, np.float32(np.nan)).astype(np.float32, copy=False)

    def cast_with_incidence(
        self, origin_map: np.ndarray, directions: np.ndarray, n_threads: int = 0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Ranges and incidence of rays from one origin, in one call (the footprint's sub-rays).

        Args:
            origin_map: float64 (3,) ray origin (map coordinates).
            directions: float64 (..., 3) unit directions.
            n_threads: Embree threads (0 = all cores).

        Returns:
            ``(ranges, cos_incidence)``: float32 (...) ranges, metres, NaN where the ray hits no
            terrain, and float64 (...) ``|cos|`` of the angle between the ray and the hit triangle's normal.
        """
        shape = directions.shape[:-1]
        # The whole window: a sub-ray through the edge two triangles share hits both at the same
        # range, and which one Embree reports (its normal) depends on the BVH's order of traversal.
        self.focus(self.full_window)
        if self.n_triangles == 0:
            return np.full(shape, np.nan, dtype=np.float32), np.zeros(shape)
        rays = np.empty((*shape, 6), dtype=np.float32)
        rays[..., :3] = origin_map - self.origin
        rays[..., 3:] = directions
        hit = self.scene.cast_rays(o3d.core.Tensor(rays.reshape(-1, 6)), nthreads=n_threads)  # type: ignore[call-overload]  # stubs omit ndarray
        t = hit["t_hit"].numpy().reshape(shape)
        normals = hit["primitive_normals"].numpy().reshape(*shape, 3).astype(np.float64)
        cos = np.abs((normals * directions).sum(axis=-1))
        ranges = np.where(np.isfinite(t), t, np.float32(np.nan)).astype(np.float32, copy=False)
        return ranges, np.where(np.isfinite(t), cos, 0.0)

    def _focus_on(self, origins_map: np.ndarray, directions: np.ndarray) -> None:
        """Make sure the scene holds every triangle these rays can hit first (a new one if the current does not)."""
        need = self.reach(origins_map, directions)
        window, self.only_hits = self.only_hits, None
        if window is not None and _holds(window, need):
            r0, r1, c0, c1 = window
            s = origins_map.shape[0]
            d = directions.reshape(s, -1, 3)
            o = np.broadcast_to(np.asarray(origins_map, dtype=np.float64)[:, None, :], d.shape)
            keep = candidate_triangles(self.heights[r0:r1, c0:c1], self.x_centres[c0:c1], self.y_centres[r0:r1], o, d)
            if keep is not None:
                # the marked triangles, unless they are most of the window (rays crowding one spot)
                dense = 2 * int(keep[0].sum() + keep[1].sum()) > 2 * (r1 - r0 - 1) * (c1 - c0 - 1)
                self._build(window, None if dense else keep)
                return
        if self.window is None or not _holds(self.window, need):
            self.focus(need)


def _holds(outer: Window, inner: Window) -> bool:
    return outer[0] <= inner[0] and inner[1] <= outer[1] and outer[2] <= inner[2] and inner[3] <= outer[3]


def _union(a: Window, b: Window) -> Window:
    return (min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3]))


def _cells(w: Window) -> int:
    return max(0, w[1] - w[0]) * max(0, w[3] - w[2])


def scan_geometry(
    scene: TileScene,
    nadir_xy: np.ndarray,
    scan_index: int,
    trajectory: TrajectoryConfig,
    footprint_half_width_m: float,
    seed: int,
) -> ScanGeometry:
    """Pose of scan ``scan_index``: the sensor at its altitude (``TrajectoryConfig.scan_pose``) above
    the mean terrain under its footprint, with its tilt and attitude jitter.

    In a descent build ``nadir_xy`` is the descent's target and the scan is frame ``scan_index mod
    K`` of descent ``scan_index // K`` (``lidarsim.descent.frame_pose``): the scan frame's origin is
    the target on the mean terrain height within ``footprint_half_width_m`` of it, the same for
    every frame of the descent."""
    x, y = float(nadir_xy[0]), float(nadir_xy[1])
    z_ref = scene.mean_height(x, y, footprint_half_width_m)
    altitude_m, tilt_deg, jitter_deg = trajectory.scan_pose(seed, scan_index)
    jitter = (0.0, 0.0, 0.0)
    if jitter_deg > 0.0:
        jitter = tuple(np.radians(jitter_deg) * stream(seed, Purpose.ATTITUDE_JITTER, scan_index).standard_normal(3))
    descent = trajectory.descent
    if descent is not None:
        descent_index, frame = divmod(scan_index, descent.frames)
        position, attitude = frame_pose(descent, frame, descent.azimuth_deg(seed, descent_index), jitter)
        return ScanGeometry(origin_map=np.array([x, y, z_ref]), sensor_position=position, attitude=attitude)
    return ScanGeometry(
        origin_map=np.array([x, y, z_ref]),
        sensor_position=np.array([0.0, 0.0, altitude_m]),
        attitude=sensor_attitude(tilt_deg, jitter),
    )


def simulate_scans(
    scene: TileScene,
    geometries: list[ScanGeometry],
    scan_indices: list[int],
    sensor: SensorConfig,
    sigmas_m: tuple[float, ...],
    seed: int,
    n_threads: int = 0,
    footprint: FootprintConfig | None = None,
    noise_model: NoiseModel | None = None,
) -> list[ScanResult]:
    """Cast the rays of several scans and derive clean and noisy points.

    With the paper's sensor (one ray per pixel, constant sigma) the rays of all the scans go in one
    call. With a footprint (``footprint.samples > 1``) or the ``snr`` noise model, each scan's K x K
    sub-rays per pixel go in one call, and the pixel's range, signal and noise come from
    ``lidarsim.footprint`` and ``lidarsim.noise.NoiseModel``.
    """
    footprint = footprint or FootprintConfig()
    noise_model = noise_model or NoiseModel()
    directions = np.stack([scan_directions(sensor, g.attitude) for g in geometries])
    origins = np.stack([g.origin_map + g.sensor_position for g in geometries])
    realistic = not (footprint.is_default and noise_model.is_default)
    ranges = None if realistic else scene.cast(origins, directions, n_threads=n_threads)
    defects = element_defects(sensor, seed)
    dead = defects == STATUS_DEAD
    damaged = defects == STATUS_DAMAGED
    results = []
    for k, (g, scan) in enumerate(zip(geometries, scan_indices, strict=True)):
        sigma_scale = None
        if ranges is None:
            cast, signal = pixel_returns(scene, origins[k], g.attitude, sensor, footprint, noise_model, n_threads)
            weak = np.isfinite(cast) & ~noise_model.detected(signal)
            cast[weak] = np.nan
            scale = noise_model.sigma_scale(signal)
            # float32 as stored (noise_scale), so that noise drawn later from the shard is the stored noise
            sigma_scale = None if scale is None else scale.astype(np.float32).astype(np.float64)
        else:
            cast, weak = ranges[k], None
        r = cast.astype(np.float64)
        r[dead] = np.nan
        status = np.where(np.isnan(cast), STATUS_MISS, defects).astype(np.uint8)
        if weak is not None:
            status[weak & ~dead] = STATUS_WEAK
        status[dead] = STATUS_DEAD
        d = directions[k]
        clean = points_at_ranges(g.sensor_position, r, d)
        noisy = np.empty((len(sigmas_m), *clean.shape), dtype=np.float32)
        for s_i, sigma in enumerate(sigmas_m):
            noisy[s_i] = noisy_points(
                r, d, g.sensor_position, sigma, seed, scan, damaged, sensor.damaged_error_m, sigma_scale=sigma_scale
            )
        results.append(
            ScanResult(
                geometry=g,
                points_clean=clean,
                points_noisy=noisy,
                status=status,
                noise_scale=None if sigma_scale is None else sigma_scale.astype(np.float32),
            )
        )
    return results


def pixel_returns(
    scene: TileScene,
    origin_map: np.ndarray,
    attitude: np.ndarray,
    sensor: SensorConfig,
    footprint: FootprintConfig,
    noise_model: NoiseModel,
    n_threads: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Range and relative signal of every pixel of one scan through its K x K sub-rays (one cast).

    Returns:
        ``(ranges, signal)``: float32 (rows, cols) ranges, metres (NaN where no sub-ray hit the
        terrain), and float64 (rows, cols) signal relative to a whole pixel's return at normal
        incidence from the noise model's reference range (``lidarsim.footprint.subreturn_energy``).
    """
    sub = subray_directions(sensor, footprint.samples) @ np.asarray(attitude, dtype=np.float64).T
    sub_ranges, cos = scene.cast_with_incidence(origin_map, sub, n_threads=n_threads)
    energy = subreturn_energy(
        sub_ranges.astype(np.float64), cos, spot_weights(footprint), noise_model.reference_range_m
    )
    # float32 like the ray caster's ranges, so that the clean points keep recover_ranges' contract
    ranges = pixel_ranges(sub_ranges.astype(np.float64), energy, footprint).astype(np.float32)
    return ranges, energy.sum(axis=-1)
