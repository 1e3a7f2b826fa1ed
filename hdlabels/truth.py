"""The terrain truth: the DTM a dataset was built on, sampled on each scan's DEM grid (``hd label --truth terrain``).

The paper labels the clean *scan*: its DEM is the sensor's view of the terrain. Once the sensor
blurs (a pixel footprint) or misses (occlusion), the truth must come from the terrain itself. This
module gives, for one scan, the DEM of the terrain under that scan's DEM grid:

* the terrain is the surface the build cast its rays against: the triangle mesh of the DTM's cell
  centres that ``lidarsim.scan.terrain_mesh`` makes for ``TileScene`` (same file, same
  ``--dtm-scale``), evaluated where a vertical ray would meet it (:func:`mesh_heights`);
* the grid is the scan's: north-up, centred at the scan's nadir point ``origin_map`` (its x, y),
  heights relative to its reference height (its z), the scan frame the clean points are in;
* the surface is sampled at ``n x n`` points per DEM cell (the cell centre among
  them; ``hdlabels.defaults.TERRAIN_SAMPLES_MIN``), and those points are gridded by the labelling's
  own gridding (``hdlabels.grid.grid_points``), so a truth DEM is what a perfect, dense sensor
  straight above every cell would give. The ``nearest`` and ``linear`` griddings take the centre's
  height from such samples (the most central point; a vertex of the triangulation), so for them the
  centre alone is sampled (``n = 1``): the same DEM from ``n * n`` times fewer samples;
* cells where the clean scan's DEM has no support (outside the scan's footprint) stay NaN, so the
  truth covers the same ground as the clean-scan truth;
* a descent mosaic (``hd mosaic``) lies where the lowest frame's navigation estimate put it, not
  where the ground is: its ``frame_to_map`` takes each sample point to the true map first, so that
  a cell's truth is the ground a lander aiming at that cell would meet.

The dataset records its DTM in the manifest (``dtm``: path, sha256, scale in ``config.dtm_scale``):
the procedural terrain inside the dataset (``terrain/``), a user's DTM by its absolute path. A DTM
that is missing or whose bytes changed is refused with one line (:func:`check_build_terrain`),
except the procedural terrain, which is regenerated from the build's seed and parameters when that
gives the recorded sha256 (``lidarsim.build.restore_procedural_terrain``). The terrain is hashed
once per labelling (:func:`verified_build_terrain`) and checked again for every label shard, as it
is read (:func:`labelled_terrain`): by its identity (device, inode, size, modification and change
times) before and after the shard, hashed again when that changed. A DTM replaced or changed while
a dataset is labelled stops the labelling before a shard of another terrain is written. Each shard
records the sha256 it was labelled from (``truth_dtm_sha256``, ``docs/labels-format.md``).
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from hdcore.errors import HdError
from hdcore.storage import confine
from hdlabels import defaults
from hdlabels.grid import cell_centres, grid_points
from hdlabels.store import DemSpec, LabelStoreError
from lidarsim.manifest_json import ManifestJson
from lidarsim.terrain import DTM, dtm_sha256, gdal_side_files

# Griddings whose DEM value is the height at the cell centre when a sample lies there.
CENTRE_GRIDDINGS: tuple[str, ...] = ("nearest", "linear")


def build_terrain_path(root: Path, manifest: ManifestJson) -> tuple[Path, str, float]:
    """The DTM a dataset was built on: its path (a relative one confined to the dataset), recorded
    sha256 and the build's ``--dtm-scale``.

    Raises:
        LabelStoreError: the manifest records no DTM.
        FormatError: a relative path that leaves the dataset.
    """
    dtm = manifest.get("dtm")
    if not isinstance(dtm, dict) or not isinstance(dtm.get("path"), str) or not isinstance(dtm.get("sha256"), str):
        raise LabelStoreError(f"{root}: the manifest records no terrain (dtm path, sha256); --truth terrain needs it")
    config = manifest.get("config")
    scale = config.get("dtm_scale", 1.0) if isinstance(config, dict) else 1.0
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0.0 < scale <= 1.0:
        raise LabelStoreError(f"{root}: the manifest's config.dtm_scale {scale!r} is not a scale in (0, 1]")
    path = Path(dtm["path"])
    return (path if path.is_absolute() else confine(root, dtm["path"])), str(dtm["sha256"]), float(scale)


def check_build_terrain(root: Path, manifest: ManifestJson) -> tuple[Path, str, float]:
    """The DTM a dataset was built on, checked: present and the bytes the build read (sha256). The
    procedural terrain, missing or changed, is first regenerated when that gives the recorded bytes.

    Returns:
        ``(path, sha256, scale)``: the sha256 the manifest records, which every label shard is
        checked against as the terrain is read (:func:`labelled_terrain`) and records.

    Raises:
        LabelStoreError: one line naming the file: missing, unreadable or changed since the build.
        LidarsimError: a procedural terrain that regenerates to other bytes than the build's.
    """
    path, recorded, scale = build_terrain_path(root, manifest)
    from lidarsim.build import restore_procedural_terrain

    restored = restore_procedural_terrain(root, manifest)  # None: intact, or not the procedural terrain
    if restored is not None:
        return restored, recorded, scale
    if not path.is_file():
        raise LabelStoreError(
            f"{path}: the terrain {root.name} was built on is missing; --truth terrain samples it (restore the "
            "file, or label with --truth clean-scan)"
        )
    digest = _terrain_digest(path, root.name)
    if digest != recorded:
        raise LabelStoreError(
            f"{path}: the terrain changed since {root.name} was built (sha256 {digest[:12]}..., the manifest "
            f"says {recorded[:12]}...); --truth terrain needs the DTM the scans were cast on"
        )
    return path, recorded, scale


def terrain_identity(path: str | os.PathLike, dataset: str) -> tuple[int, ...]:
    """What tells one file from another and a file from its changed self: device, inode, size,
    modification and change times (the change time is set by the kernel on every write), of the DTM
    and of each side file GDAL reads with it (``lidarsim.terrain.gdal_side_files``)."""
    try:
        files = (Path(path), *gdal_side_files(path))
        stats = [os.stat(f) for f in files]
    except OSError as exc:
        raise LabelStoreError(
            f"{path}: the terrain {dataset} was built on went missing while it was labelled ({exc.strerror}); "
            "restore it and re-run the same command"
        ) from exc
    return tuple(v for st in stats for v in (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns))


def _terrain_digest(path: str | os.PathLike, dataset: str) -> str:
    """The sha256 of the terrain file at ``path`` that the dataset ``dataset`` was built on.

    Raises:
        LabelStoreError: the file cannot be read.
    """
    try:
        return dtm_sha256(path)
    except HdError as exc:
        raise LabelStoreError(f"{path}: the terrain {dataset} was built on cannot be read ({exc})") from exc


def _check_digest(path: str | os.PathLike, sha256: str, dataset: str) -> None:
    """Refuse the terrain file at ``path`` unless its bytes are the build's (``sha256``)."""
    digest = _terrain_digest(path, dataset)
    if digest != sha256:
        raise LabelStoreError(
            f"{path}: the terrain changed while {dataset} was labelled (sha256 {digest[:12]}..., the manifest "
            f"says {sha256[:12]}...); every label shard must come from the DTM the scans were cast on: restore "
            "it and re-run the same command"
        )


@contextmanager
def labelled_terrain(
    path: str | os.PathLike,
    sha256: str,
    scale: float,
    dataset: str,
    identity: tuple[int, ...] | None = None,
) -> Iterator[DTM]:
    """The build's DTM, open (at the build's scale) while one label shard is made, checked as it is read.

    Its sha256 must be the build's record (``sha256``) before it is opened, unless the file is still
    the one the labelling hashed (``identity``, :func:`verified_build_terrain`'s: device, inode, size,
    modification and change times), so that a labelling hashes its DTM once, not once per shard. When
    the shard's scans are labelled and the file at ``path`` is no longer the one opened (replaced, or
    written in place), it is hashed again and must still be the build's. A terrain replaced or
    changed during a labelling therefore stops it before a shard of another terrain is written.
    ``dataset`` names the dataset in messages.

    Raises:
        LabelStoreError: one line naming the DTM: changed, missing or unreadable while labelled.
    """
    before = terrain_identity(path, dataset)
    if identity is None or tuple(identity) != before:
        _check_digest(path, sha256, dataset)
    with DTM.open(path, scale=scale) as dtm:
        yield dtm
    if terrain_identity(path, dataset) != before:
        _check_digest(path, sha256, dataset)


def verified_build_terrain(root: Path, manifest: ManifestJson) -> tuple[Path, str, float, tuple[int, ...] | None]:
    """:func:`check_build_terrain`, and the identity of the file it hashed (:func:`terrain_identity`;
    None when the file changed while it was hashed, or was regenerated): the label shards then read
    the DTM without hashing it again while it is still that file (:func:`labelled_terrain`)."""
    path, _, _ = build_terrain_path(root, manifest)
    before = terrain_identity(path, root.name) if path.is_file() else None
    path, sha256, scale = check_build_terrain(root, manifest)
    after = terrain_identity(path, root.name)
    return path, sha256, scale, (after if after == before else None)


def samples_per_cell(dem_spacing_m: float, dtm_spacing_m: float, gridding: str = "mean") -> int:
    """Odd number of samples per DEM cell and axis: at least two per DTM cell for the ``mean`` and
    ``max`` griddings, the centre alone for ``nearest`` and ``linear`` (module docstring)."""
    if gridding in CENTRE_GRIDDINGS:
        return 1
    n = math.ceil(2.0 * dem_spacing_m / dtm_spacing_m - 1e-9)
    n += 1 - n % 2
    return int(min(defaults.TERRAIN_SAMPLES_MAX, max(defaults.TERRAIN_SAMPLES_MIN, n)))


def mesh_heights(dtm: DTM, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Heights of the DTM's triangle mesh at map points, metres: the surface the build's rays hit.

    The mesh is ``lidarsim.scan.terrain_mesh``'s: a vertex at every cell centre (at the DTM's scale),
    each 2 x 2 block of centres split into two triangles along the diagonal from its north-east to
    its south-west centre, a triangle with a nodata vertex left out. A point's height is the plane
    of the triangle under it (exact where a vertical ray cast on the scene meets it, without the
    scene's float32 rounding).

    Args:
        dtm: the open DTM.
        x, y: map coordinates, metres (arrays of one shape).

    Returns:
        float64 heights of that shape, NaN off the DTM or over a left-out triangle.
    """
    r, c = dtm.rowcol_of_xy(x, y)
    i, j = np.floor(r), np.floor(c)
    row0, col0 = int(np.min(i)), int(np.min(j))
    heights = dtm.read(row0, col0, int(np.max(i)) - row0 + 2, int(np.max(j)) - col0 + 2)
    ii, jj = (i - row0).astype(np.int64), (j - col0).astype(np.int64)
    fv, fu = r - i, c - j  # southwards and eastwards within the block, in [0, 1)
    a, b = heights[ii, jj], heights[ii, jj + 1]  # north-west, north-east
    c_, d = heights[ii + 1, jj], heights[ii + 1, jj + 1]  # south-west, south-east
    upper = a + fu * (b - a) + fv * (c_ - a)  # triangle (a, c, b)
    lower = d + (1.0 - fu) * (c_ - d) + (1.0 - fv) * (b - d)  # triangle (b, c, d)
    return np.where(fu + fv <= 1.0, upper, lower)


def sample_points(
    origin_map: np.ndarray, dem: DemSpec, n: int, dtm: DTM, frame_to_map: np.ndarray | None = None
) -> np.ndarray:
    """The DTM's surface under a scan's DEM grid at ``n x n`` points per cell: an organised point cloud.

    Args:
        origin_map: (3,) map coordinates of the scan frame's origin (nadir x, y; reference height), metres.
        dem: the DEM grid (rows, cols, spacing_m metres/pixel), centred at the nadir point.
        n: odd number of samples per cell along each axis.
        dtm: the open DTM (at the build's scale).
        frame_to_map: 4 x 4 rigid transform from the grid's placement in the map to the true map (a
            descent mosaic's, ``lidarsim.shards.MosaicRecord``), or None (the identity: a scan's grid
            lies where it says). Each sample point, at the reference height, is taken to the true map
            and the terrain's height is read there: the ground a lander aiming at that point meets.

    Returns:
        float64 (rows * n, cols * n, 3) points in the scan frame (x east, y north, z up, metres), row-major
        from the north-west corner; NaN where the surface has no triangle (nodata, off the DTM).
    """
    x0, y0, z0 = (float(v) for v in origin_map)
    xc, yc = cell_centres((dem.rows, dem.cols), dem.spacing_m)
    offsets = (np.arange(n) - (n - 1) / 2.0) * (dem.spacing_m / n)
    xs = (xc[:, None] + offsets[None, :]).ravel()  # west to east
    ys = (yc[:, None] - offsets[None, :]).ravel()  # north to south
    xx, yy = np.meshgrid(xs, ys)
    mx, my = x0 + xx, y0 + yy
    if frame_to_map is not None:
        t = np.asarray(frame_to_map, dtype=np.float64)
        placed = np.stack([mx, my, np.full_like(mx, z0)], axis=-1)
        true = placed @ t[:3, :3].T + t[:3, 3]
        mx, my = true[..., 0], true[..., 1]
    z = mesh_heights(dtm, mx, my) - z0
    points = np.stack([xx, yy, z], axis=-1)
    points[~np.isfinite(z)] = np.nan  # no surface there: no point, as a ray that misses
    return points


def terrain_dem(
    origin_map: np.ndarray, dem_clean: np.ndarray, dem: DemSpec, dtm: DTM, frame_to_map: np.ndarray | None = None
) -> np.ndarray:
    """The terrain-truth DEM of one scan (float32 metres, scan frame; NaN where ``dem_clean`` is NaN).

    Args:
        origin_map: (3,) the scan's ``origin_map`` (metres).
        dem_clean: the clean scan's DEM on the same grid: its support is the scan's footprint.
        dem: the DEM grid and gridding.
        dtm: the open DTM the dataset was built on (at the build's scale).
        frame_to_map: a descent mosaic's transform to the true map (:func:`sample_points`), or None.
    """
    n = samples_per_cell(dem.spacing_m, min(dtm.info.spacing_m), dem.gridding)
    points = sample_points(origin_map, dem, n, dtm, frame_to_map)
    out = grid_points(points, (dem.rows, dem.cols), dem.spacing_m, method=dem.gridding)
    out[~np.isfinite(dem_clean)] = np.nan
    return out.astype(np.float32, copy=False)
