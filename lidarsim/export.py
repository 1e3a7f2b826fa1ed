"""Scans as LAS 1.4 / LAZ point clouds for point-cloud tools (``hd export``: CloudCompare, PDAL, QGIS).

One file per scan, ``scan-NNNNNN.laz`` (or ``.las``), written with laspy (LAZ through its lazrs
backend) in point format 6, the LAS 1.4 format without colour:

* coordinates: the scan's clean or noisy points (one noise level), in the scan frame (origin at the
  nadir point on the reference height, x east, y north, z up, metres) or in map coordinates (the
  scan frame plus the scan's ``origin_map``: the frames differ by a translation only), stored as
  integers of ``COORDINATE_SCALE_M`` (0.1 mm) about an offset of whole metres;
* the DTM's CRS as an OGC WKT coordinate-system VLR (and the header's WKT bit) in map coordinates
  when the DTM had one; the scan frame is a local frame and carries none;
* per point: ``point_source_id`` the scan index (when it fits in 16 bits), ``gps_time`` the scan
  index too (hd's scans have no time stamps: one "time" per scan lets tools split the file by
  scan), ``intensity`` 0, classification 1 (unclassified), and extra bytes ``scan_index`` (uint32),
  ``detector_row`` and ``detector_col`` (uint16: the element the return came from) and ``status``
  (uint8: the shard's status code, 0 a return, 3 a damaged element's return);
* only elements with a return (status 0 or 3) become points: misses and dead elements have none.

Beside the files, ``export.json`` records the dataset, the settings and, per file, its scan, point
count, origin_map and sha256. The output directory follows hd's rules for outputs
(:class:`hdcore.storage.OutputDir`): files are staged under a temporary name and moved into place
when all are written, so an interrupted export leaves no partial file; an existing export is
replaced only with ``overwrite``.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hdcore.bounds import Bound, parse_integer
from hdcore.setting import check, setting
from hdcore.storage import OutputDir, sha256_file, write_json_atomic
from lidarsim import limits
from lidarsim._version import __version__
from lidarsim.errors import LidarsimError
from lidarsim.manifest_json import ManifestJson
from lidarsim.scan import STATUS_DAMAGED, STATUS_RETURN
from lidarsim.shards import open_scan_shard, read_manifest

EXPORT_FORMATS: tuple[str, ...] = ("laz", "las")
EXPORT_FRAMES: tuple[str, ...] = ("scan", "map")
EXPORT_CLOUDS: tuple[str, ...] = ("clean", "noisy")
EXPORT_MARKER = "export.json"
# hd choice: LAS coordinates are integers of 0.1 mm, far below the smallest noise level (1.67 cm) and
# the float32 precision of the stored points at 1000 m (0.06 mm).
COORDINATE_SCALE_M = 1e-4
# LAS 1.4 point format 6: X, Y, Z, intensity, returns, classification, scan angle, user data,
# point source ID and GPS time (ASPRS LAS 1.4 R15, Table 15).
POINT_FORMAT = 6
CLASS_UNCLASSIFIED = 1  # ASPRS standard class 1, "unclassified"


@dataclass(frozen=True)
class ExportSettings:
    """Settings of ``hd export``, each described once as field metadata: the options and the checks
    are made from it (``scans`` is typed as a list and parsed by :func:`parse_scans`)."""

    format: str = setting("laz", "File format: laz (LAS compressed by lazrs) or las", choices=EXPORT_FORMATS)
    frame: str = setting(
        "scan",
        "Coordinates: the scan frame (origin at the scan's nadir point) or the DTM's map coordinates, with its CRS",
        choices=EXPORT_FRAMES,
    )
    cloud: str = setting("clean", "Points: the clean ones, or the noisy ones of one noise level", choices=EXPORT_CLOUDS)
    sigma_m: float | None = setting(
        None,
        "With --cloud noisy: the noise level (default: the dataset's first)",
        unit="metres",
        bound=limits.SIGMA_M,
        flag="--sigma",
    )
    scans: tuple[int, ...] = setting(
        (), "Scan indices to export (none: every scan)", bound=Bound(0, limits.MAX_SCANS - 1, integer=True), cli=False
    )

    def __post_init__(self) -> None:
        check(self, LidarsimError)
        if self.sigma_m is not None and self.cloud != "noisy":
            raise LidarsimError("--sigma chooses the noise level of --cloud noisy; the clean points have none")


@dataclass(frozen=True)
class ExportSummary:
    """What :func:`export_scans` wrote."""

    out_dir: str
    n_files: int
    n_points: int
    frame: str
    cloud: str
    crs: bool

    def paragraph(self) -> str:
        where = "map coordinates" + (" with the DTM's CRS" if self.crs else " (the DTM has no CRS)")
        frame = where if self.frame == "map" else "the scan frame"
        return (
            f"Exported {self.n_files} scan{'' if self.n_files == 1 else 's'} ({self.n_points:,} {self.cloud} points, "
            f"{frame}) to {self.out_dir}; "
            f"{EXPORT_MARKER} lists them."
        )


def parse_scans(text: str) -> tuple[int, ...]:
    """Scan indices from ``"3"``, ``"0,5,9"`` or ranges ``"10-19"`` (inclusive), in the order given;
    indices in the ASCII digits 0-9 (:func:`hdcore.bounds.parse_integer`). The scans a list names
    (ranges counted in full, repeats included) are bounded by ``limits.SCANS`` - a dataset holds no
    more - before the list is expanded.

    Raises:
        LidarsimError: anything else, naming the text.
    """
    usage = "use scan indices and ranges, e.g. 0,5,10-19"
    where = f"--scans {text!r}" if len(text) <= 40 else f"--scans {text[:37] + '...'!r}"
    spans: list[tuple[int, int]] = []
    for part in text.split(","):
        item = part.strip()
        if not item:
            raise LidarsimError(f"{where}: an empty entry; {usage}")
        lo, sep, hi = item.partition("-")
        first = parse_integer(lo, f"{where}: scan", hint=usage, error=LidarsimError)
        last = parse_integer(hi, f"{where}: scan", hint=usage, error=LidarsimError) if sep else first
        if last < first:
            raise LidarsimError(f"{where}: the range {item} runs backwards")
        spans.append((first, last))
    named = sum(last - first + 1 for first, last in spans)
    if not limits.SCANS.contains(named):
        raise LidarsimError(
            f"{where} names {named:,} scans; a list names at most {limits.MAX_SCANS:,} (a dataset holds no more)"
        )
    return tuple(dict.fromkeys(k for first, last in spans for k in range(first, last + 1)))


def is_export_file(name: str) -> bool:
    """True for the names an export writes (its files and its marker)."""
    return name == EXPORT_MARKER or (name.startswith("scan-") and name.endswith((".laz", ".las")))


def export_scans(
    dataset: str | os.PathLike,
    out_dir: str | os.PathLike,
    settings: ExportSettings = ExportSettings(),
    overwrite: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> ExportSummary:
    """Write scans of ``dataset`` as LAS/LAZ files into ``out_dir`` (module docstring).

    Raises:
        LidarsimError: not a dataset, an unknown scan or noise level, an output that exists (without
            ``overwrite``) or is not hd's, laspy or lazrs missing.
        StorageError: a write failed (nothing partial is left).
    """
    laspy = _laspy(settings.format)
    root = Path(dataset)
    manifest = read_manifest(root)
    wanted = settings.scans or tuple(range(int(manifest["n_scans"])))
    locations = _locate(manifest, wanted, root)
    sigma_index = _sigma_index(manifest, settings)
    crs_wkt = str((manifest.get("dtm") or {}).get("crs_wkt") or "") if settings.frame == "map" else ""
    out = OutputDir(out_dir, what="export", marker=EXPORT_MARKER, owns=is_export_file, inputs={"the dataset": root})
    out.check(overwrite)
    files: list[dict[str, Any]] = []
    total = 0
    with out.open(overwrite) as staging:
        done = 0
        for shard_position, rows in locations.items():
            with open_scan_shard(root, manifest["shards"][shard_position]) as reader:
                for row in rows:
                    scan = reader[row]
                    name = f"scan-{scan.scan_index:06d}.{settings.format}"
                    points = scan.points_clean if sigma_index is None else scan.points_noisy[sigma_index]
                    n = _write_las(
                        laspy, staging / name, points, scan.status, scan.scan_index, scan.origin_map, settings, crs_wkt
                    )
                    files.append(
                        {
                            "file": name,
                            "scan_index": scan.scan_index,
                            "split": scan.split,
                            "n_points": n,
                            "origin_map": [float(v) for v in scan.origin_map],
                            "sha256": sha256_file(staging / name),
                        }
                    )
                    total += n
                    done += 1
                    if progress:
                        progress(done, len(wanted))
        record = {
            "kind": "hd.export",
            "software": "hd",
            "software_version": __version__,
            "dataset": str(root.resolve()),
            "dataset_config_sha256": manifest.get("config_sha256"),
            "settings": asdict(settings) | {"scans": list(wanted)},
            "sigma_m": None if sigma_index is None else float(manifest["sigmas_m"][sigma_index]),
            "coordinate_scale_m": COORDINATE_SCALE_M,
            "frame": _FRAME_WORDS[settings.frame],
            "crs_wkt": crs_wkt,
            "files": sorted(files, key=lambda f: f["scan_index"]),
        }
        write_json_atomic(staging / EXPORT_MARKER, record)
        out.commit()
    return ExportSummary(str(out.path), len(files), total, settings.frame, settings.cloud, bool(crs_wkt))


_FRAME_WORDS = {
    "scan": "scan frame: origin at the scan's nadir point on its reference height (origin_map); x east, y north, "
    "z up; metres",
    "map": "map coordinates of the dataset's DTM (scan frame + origin_map); metres",
}


def _laspy(fmt: str) -> Any:
    """laspy, with a LAZ backend when ``fmt`` is laz."""
    try:
        import laspy
    except ImportError as exc:
        raise LidarsimError("hd export needs laspy: pip install 'laspy[lazrs]'") from exc
    if fmt == "laz" and not laspy.LazBackend.Lazrs.is_available():
        raise LidarsimError("hd export --format laz needs the lazrs backend: pip install 'laspy[lazrs]'")
    return laspy


def _locate(manifest: ManifestJson, wanted: tuple[int, ...], root: Path) -> dict[int, list[int]]:
    """The rows of the wanted scans, grouped by shard (position in the manifest's list), in shard order.

    Raises:
        LidarsimError: a scan index the dataset does not have.
    """
    n_scans = int(manifest["n_scans"])
    bad = [k for k in wanted if k >= n_scans]
    if bad:
        raise LidarsimError(f"{root} has scans 0..{n_scans - 1}; --scans asks for {bad[0]}")
    starts = [int(s.get("first_scan", 0)) for s in manifest["shards"]]
    sizes = [int(s["n_scans"]) for s in manifest["shards"]]
    grouped: dict[int, list[int]] = {}
    for k in sorted(wanted):
        for i, (first, size) in enumerate(zip(starts, sizes, strict=True)):
            if first <= k < first + size:
                grouped.setdefault(i, []).append(k - first)
                break
        else:
            raise LidarsimError(f"{root}: no shard of the manifest holds scan {k}")
    return dict(sorted(grouped.items()))


def _sigma_index(manifest: ManifestJson, settings: ExportSettings) -> int | None:
    """The position of the exported noise level among the dataset's (None for the clean points)."""
    if settings.cloud == "clean":
        return None
    sigmas = [float(s) for s in manifest["sigmas_m"]]
    if settings.sigma_m is None:
        return 0
    for i, s in enumerate(sigmas):
        if abs(s - settings.sigma_m) <= 1e-9:
            return i
    levels = ", ".join(f"{s:g}" for s in sigmas)
    raise LidarsimError(f"the dataset stores noise levels {levels} m; --sigma {settings.sigma_m:g} is not one of them")


def _write_las(
    laspy: Any,
    path: Path,
    points: np.ndarray,
    status: np.ndarray,
    scan_index: int,
    origin_map: np.ndarray,
    settings: ExportSettings,
    crs_wkt: str,
) -> int:
    """Write one scan's returns as a LAS 1.4 file at ``path``; returns the number of points."""
    keep = ((status == STATUS_RETURN) | (status == STATUS_DAMAGED)) & np.isfinite(points).all(axis=-1)
    rows, cols = np.nonzero(keep)
    xyz = points[rows, cols].astype(np.float64)
    offset = np.zeros(3)
    if settings.frame == "map":
        xyz += np.asarray(origin_map, dtype=np.float64)
        offset = np.floor(np.asarray(origin_map, dtype=np.float64))
    header = laspy.LasHeader(point_format=POINT_FORMAT, version="1.4")
    header.scales = np.full(3, COORDINATE_SCALE_M)
    header.offsets = offset
    header.system_identifier = "hd lidarsim (simulated)"
    header.generating_software = f"hd {__version__}"[:32]
    header.add_extra_dims(
        [
            laspy.ExtraBytesParams("scan_index", "uint32", description="hd scan index"),
            laspy.ExtraBytesParams("detector_row", "uint16", description="detector element row"),
            laspy.ExtraBytesParams("detector_col", "uint16", description="detector element column"),
            laspy.ExtraBytesParams("status", "uint8", description="hd status: 0 return, 3 damaged"),
        ]
    )
    if crs_wkt:
        header.vlrs.append(laspy.vlrs.known.WktCoordinateSystemVlr(crs_wkt))
        header.global_encoding.wkt = True
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    n = len(rows)
    las.classification = np.full(n, CLASS_UNCLASSIFIED, dtype=np.uint8)
    las.return_number = np.ones(n, dtype=np.uint8)
    las.number_of_returns = np.ones(n, dtype=np.uint8)
    las.point_source_id = np.full(n, scan_index if scan_index < 2**16 else 0, dtype=np.uint16)
    las.gps_time = np.full(n, float(scan_index))
    las.scan_index = np.full(n, scan_index, dtype=np.uint32)
    las.detector_row = rows.astype(np.uint16)
    las.detector_col = cols.astype(np.uint16)
    las.status = status[rows, cols].astype(np.uint8)
    backend = laspy.LazBackend.Lazrs if settings.format == "laz" else None
    with open(path, "wb") as f:
        las.write(f, do_compress=settings.format == "laz", laz_backend=backend)
    return n
