"""Label shards (schema ``hd.labels``): writer, lazy reader and the labelling entry of the manifest.

A *labelling* is the result of one set of lander parameters and DEM settings applied to every
scan of a dataset. It lives in ``DATASET/labels/<name>/`` with one label shard per scan shard
(``labels-NNNNN.h5``, linked to its source shard by path and sha256) and is listed in the
manifest's ``labelings``. Scan shards are never modified. Field-by-field documentation:
``docs/labels-format.md``. Files go through ``hdcore.storage``: built in memory, written
atomically, a fletcher32 checksum on every chunk (schema 1.1); readers check the manifest's
sha256 and name the file and the scan in every error.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from hdcore.storage import CheckedH5File, H5Image, RowBlocks, verify_sha256
from hdlabels import conventions, defaults
from hdlabels._version import __version__
from hdlabels.errors import HdLabelsError, LabelStoreError
from hdlabels.lander import Lander
from lidarsim.location import dataset_label, is_url, join, open_h5_at
from lidarsim.manifest_json import DemGridJson, LabelingJson, LabelShardJson
from lidarsim.shards import (
    MANIFEST_NAME,
    SPLIT_NAMES,
    ShardFormatError,
    check_arrays,
    check_schema,
    compression_kwargs,
    read_manifest,
    sizes_version,
    write_attrs,
    write_json_atomic,
)

LABEL_SCHEMA = "hd.labels"
# 1.1: the label convention, the baseline's combination and the gridding are recorded (attributes
# lander_convention, lander_baseline_combine, dem_gridding), and every dataset is chunked with a
# fletcher32 checksum per chunk. 1.0 shards stay readable: the hd convention, the "min"
# combination and linear gridding.
# 1.2: a label shard of the terrain truth records the sha256 of the terrain it was labelled from
# (truth_dtm_sha256). Only terrain-truth labellings are 1.2: the clean-scan truth still writes 1.1,
# byte for byte as before (label_schema_version), so published checksums of its labels hold.
LABEL_SCHEMA_VERSION = "1.2"
LABEL_SCHEMA_VERSION_CLEAN_SCAN = "1.1"
LABELS_DIR = "labels"


@dataclass(frozen=True)
class DemSpec:
    """DEM grid: ``rows x cols`` cells of ``spacing_m`` metres, north-up, centred at the nadir point,
    made from the points by ``gridding`` (``"linear"``, ``"mean"``, ``"max"`` or ``"nearest"``, ``hdlabels.grid``)."""

    rows: int = defaults.DEM_ROWS
    cols: int = defaults.DEM_COLS
    spacing_m: float = defaults.DEM_SPACING_M
    gridding: str = defaults.GRIDDING["hd"]

    def __post_init__(self) -> None:
        for name in ("rows", "cols"):
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, np.integer))
                or not 2 <= value <= defaults.MAX_DEM_SIDE_PX
            ):
                raise LabelStoreError(
                    f"the DEM side (--dem-size) must be an integer in 2..{defaults.MAX_DEM_SIDE_PX} pixels, "
                    f"got {value!r}"
                )
        s = self.spacing_m
        if isinstance(s, bool) or not isinstance(s, (int, float)) or not math.isfinite(s) or s <= 0:
            raise LabelStoreError(
                f"the DEM spacing (--dem-spacing) must be a positive finite number of metres, got {s!r}"
            )
        if self.gridding not in defaults.GRIDDINGS:
            raise LabelStoreError(f"unknown gridding {self.gridding!r}; use one of {', '.join(defaults.GRIDDINGS)}")

    def to_attrs(self) -> dict[str, float | int | str]:
        return {
            "dem_rows": self.rows,
            "dem_cols": self.cols,
            "dem_spacing_m": self.spacing_m,
            "dem_gridding": self.gridding,
        }

    def to_entry(self) -> DemGridJson:
        """The manifest's ``dem`` entry of a labelling."""
        return {"rows": self.rows, "cols": self.cols, "spacing_m": self.spacing_m, "gridding": self.gridding}

    @classmethod
    def for_convention(
        cls,
        convention: str,
        rows: int = defaults.DEM_ROWS,
        cols: int = defaults.DEM_COLS,
        spacing_m: float = defaults.DEM_SPACING_M,
        gridding: str | None = None,
    ) -> DemSpec:
        """A grid with the label convention's gridding unless ``gridding`` is given."""
        default = conventions.convention(convention).gridding
        return cls(rows, cols, spacing_m, gridding if gridding is not None else default)

    @classmethod
    def from_entry(cls, entry: DemGridJson) -> DemSpec:
        """The grid of a manifest ``dem`` entry (entries written before griddings existed are the hd
        convention's, linear; every entry records its rows, columns and spacing).

        Raises:
            LabelStoreError: a missing ``rows``, ``cols`` or ``spacing_m`` (or the grid's own checks).
        """
        missing = [k for k in ("rows", "cols", "spacing_m") if k not in entry]
        if missing:
            raise LabelStoreError(f"the DEM grid entry lacks {', '.join(repr(k) for k in missing)}")
        return cls(
            int(entry["rows"]),
            int(entry["cols"]),
            float(entry["spacing_m"]),
            str(entry.get("gridding", defaults.GRIDDING["hd"])),
        )


@dataclass(frozen=True)
class LabelShardEntry:
    """One label shard as a labelling's manifest entry lists it: its file (``path``, relative to the
    dataset), the file's sha256, its number of scans and the scan shard it labels (path, sha256)."""

    path: str
    sha256: str
    n_scans: int
    source_path: str
    source_sha256: str
    schema_version: str = LABEL_SCHEMA_VERSION_CLEAN_SCAN
    size_bytes: int | None = None  # the file's size (manifest 1.4; None: an older manifest's entry)

    def to_json(self) -> LabelShardJson:
        """The manifest's entry (keys in the order hd has always written them, its size after its sha256)."""
        entry: LabelShardJson = {
            "path": self.path,
            "sha256": self.sha256,
            "size_bytes": self.size_bytes or 0,
            "n_scans": self.n_scans,
            "source_path": self.source_path,
            "source_sha256": self.source_sha256,
            "schema": LABEL_SCHEMA,
            "schema_version": self.schema_version,
        }
        if self.size_bytes is None:  # an older manifest's entry keeps its keys
            del entry["size_bytes"]
        return entry

    @classmethod
    def from_json(cls, obj: object, where: str, labeling_version: str) -> LabelShardEntry:
        """The entry of a manifest (a 1.0 entry without a schema version has its labelling's).

        Raises:
            LabelStoreError: not an object, or a key missing or of the wrong type (naming ``where``).
        """
        if not isinstance(obj, dict):
            raise LabelStoreError(f"{where}: a label shard's entry must be a JSON object")
        texts = {}
        for key in ("path", "sha256", "source_path", "source_sha256"):
            value = obj.get(key)
            if not isinstance(value, str):
                raise LabelStoreError(f"{where}: its {key!r} must be a string, got {value!r}")
            texts[key] = value
        n = obj.get("n_scans")
        if isinstance(n, bool) or not isinstance(n, int) or n < 0:
            raise LabelStoreError(f"{where}: its 'n_scans' must be a non-negative integer, got {n!r}")
        size = obj.get("size_bytes")
        if size is not None and (isinstance(size, bool) or not isinstance(size, int) or size < 0):
            raise LabelStoreError(f"{where}: its 'size_bytes' must be a non-negative integer, got {size!r}")
        version = str(obj.get("schema_version", labeling_version))
        check_schema(str(obj.get("schema", LABEL_SCHEMA)), version, LABEL_SCHEMA, LABEL_SCHEMA_VERSION, where)
        return cls(n_scans=n, schema_version=version, size_bytes=size, **texts)


@dataclass(frozen=True)
class LabelingEntry:
    """A labelling as the dataset's manifest lists it (``docs/labels-format.md``): its name, label
    convention and truth, the lander and DEM grid it was made with, its label counts (pixels) and
    the baseline's safe fraction per noise level, and its shards in scan order.

    JSON is the file format (:meth:`from_json`, :meth:`to_json`); everything else reads this record.
    A run records its labelling without the shards (``shards == ()``).
    """

    name: str
    lander: Lander
    dem: DemSpec
    truth: str = defaults.TRUTH
    schema_version: str = LABEL_SCHEMA_VERSION_CLEAN_SCAN
    label_counts: tuple[int, int, int] | None = None  # unsafe, safe, invalid pixels (None: not recorded)
    safe_fraction: float | None = None  # of the labelled pixels (None: not recorded)
    baseline_safe_fraction: dict[str, float] = dataclasses.field(default_factory=dict)  # per sigma as written
    shards: tuple[LabelShardEntry, ...] = ()

    @property
    def convention(self) -> str:
        """The label convention (``"paper"`` or ``"hd"``), the lander's."""
        return self.lander.convention

    @property
    def spacing_m(self) -> float:
        """The DEM spacing, metres per pixel."""
        return self.dem.spacing_m

    @property
    def first_sha256(self) -> str | None:
        """The sha256 of the first label shard (None when the entry lists none)."""
        return self.shards[0].sha256 if self.shards else None

    def shard_paths(self, directory: str | os.PathLike) -> list[Path | str]:
        """Paths of the label shards, in scan order (each confined to the dataset; URLs under a URL).

        Raises:
            FormatError: a path that leaves the dataset.
        """
        return [join(directory, s.path, f"{dataset_label(directory)}/{s.path}") for s in self.shards]

    def same_hazards(self, other: LabelingEntry) -> bool:
        """True when ``other`` judges the same lander on the same DEM grid (its truth aside)."""
        return self.lander == other.lander and self.dem == other.dem

    def without_shards(self) -> LabelingEntry:
        """The entry as a run records it: everything but the shard list."""
        return dataclasses.replace(self, shards=())

    def to_json(self) -> LabelingJson:
        """The manifest's entry, keys in the order hd has always written them (the shard list only
        when the entry has shards; ``truth`` only for the terrain truth)."""
        out: LabelingJson = {
            "name": self.name,
            "schema": LABEL_SCHEMA,
            "schema_version": self.schema_version,
            "convention": self.convention,
            "lander": self.lander.to_attrs(),
            "dem": self.dem.to_entry(),
            "label_codes": {
                "unsafe": defaults.LABEL_UNSAFE,
                "safe": defaults.LABEL_SAFE,
                "invalid": defaults.LABEL_INVALID,
            },
        }
        if self.label_counts is not None:
            out["label_counts"] = dict(zip(("unsafe", "safe", "invalid"), self.label_counts, strict=True))
        if self.safe_fraction is not None:
            out["safe_fraction"] = self.safe_fraction
        out["baseline_safe_fraction"] = dict(self.baseline_safe_fraction)
        if self.shards:
            out["shards"] = [s.to_json() for s in self.shards]
        if self.truth != defaults.TRUTH:  # absent: the clean scan's (entries as before the terrain truth existed)
            out["truth"] = self.truth
        return out

    @classmethod
    def from_json(cls, obj: object, where: str) -> LabelingEntry:
        """The entry of a manifest or a run record (``where`` names it in errors). Entries made before
        conventions, truths or griddings existed read as the hd convention, the clean scan's truth and
        linear gridding.

        Raises:
            HdLabelsError: naming ``where``: a grid or lander hd cannot use (their own errors), or
                ``LabelStoreError``: not an object, a missing name, a shard entry or schema hd cannot read.
        """
        if not isinstance(obj, dict):
            raise LabelStoreError(f"{where}: a labelling entry must be a JSON object")
        name = obj.get("name")
        if not isinstance(name, str) or not name:
            raise LabelStoreError(f"{where}: a labelling entry needs a 'name' string, got {name!r}")
        version = str(obj.get("schema_version", "1.0"))  # absent in the copies early runs recorded
        check_schema(str(obj.get("schema", LABEL_SCHEMA)), version, LABEL_SCHEMA, LABEL_SCHEMA_VERSION, where)
        dem, lander = obj.get("dem", {}), obj.get("lander", {})
        if not isinstance(dem, dict) or not isinstance(lander, dict):
            raise LabelStoreError(f"{where}: its 'dem' and 'lander' entries must be JSON objects")
        try:
            grid, vehicle = DemSpec.from_entry(cast(DemGridJson, dem)), Lander.from_attrs(lander)
            counts = obj.get("label_counts")
            label_counts = (
                None if counts is None else (int(counts["unsafe"]), int(counts["safe"]), int(counts["invalid"]))
            )
            fraction = obj.get("safe_fraction")
            baseline = {str(k): float(v) for k, v in dict(obj.get("baseline_safe_fraction") or {}).items()}
        except HdLabelsError as exc:
            raise type(exc)(f"{where}: {exc}") from exc
        except (TypeError, ValueError, OverflowError, KeyError) as exc:
            raise LabelStoreError(f"{where}: its dem, lander or counts are not ones hd writes ({exc})") from exc
        truth = _raw_truth(obj)
        if truth not in defaults.TRUTHS:
            raise LabelStoreError(f"{where}: unknown truth {truth!r}; hd knows {', '.join(defaults.TRUTHS)}")
        shards = obj.get("shards", [])
        if not isinstance(shards, list):
            raise LabelStoreError(f"{where}: its 'shards' must be a list")
        return cls(
            name=name,
            lander=vehicle,
            dem=grid,
            truth=truth,
            schema_version=version,
            label_counts=label_counts,
            safe_fraction=None if fraction is None else float(fraction),
            baseline_safe_fraction=baseline,
            shards=tuple(LabelShardEntry.from_json(s, f"{where}: shards[{i}]", version) for i, s in enumerate(shards)),
        )


def label_schema_version(truth: str) -> str:
    """The schema version of the label shards (and manifest entries) a labelling of ``truth`` writes:
    1.2 for the terrain truth (it records its terrain's sha256), 1.1 for the clean scan's."""
    return LABEL_SCHEMA_VERSION_CLEAN_SCAN if truth == defaults.TRUTH else LABEL_SCHEMA_VERSION


def labeling_name(lander: Lander, dem: DemSpec, truth: str = defaults.TRUTH) -> str:
    """Directory name of a labelling, readable and unique per lander, convention, DEM settings and truth.

    hd-convention labellings with the "min" baseline on linear DEMs keep the names they had before
    conventions existed, so existing datasets keep their labellings; the clean-scan truth adds
    nothing to a name, the terrain truth ``-truth-terrain``.
    """
    return _labeling_body(lander, dem) + ("" if truth == defaults.TRUTH else f"-truth-{truth}")


def labelings_by_truth(directory: str | os.PathLike, entry: LabelingEntry) -> dict[str, str]:
    """The labellings of a dataset made with the lander and DEM of the labelling ``entry``, one name per
    truth (``"clean-scan"``, ``"terrain"``): the same hazards judged on the clean scan and on the terrain.
    Labellings hd cannot read are left out (``find_labeling`` names their faults when they are asked for)."""
    out: dict[str, str] = {}
    for i, raw in enumerate(read_manifest(directory).get("labelings", [])):
        try:
            other = LabelingEntry.from_json(raw, f"{dataset_label(directory)}: labelings[{i}]")
        except (HdLabelsError, ShardFormatError):
            continue
        if other.same_hazards(entry):
            out.setdefault(other.truth, other.name)
    return out


def _labeling_body(lander: Lander, dem: DemSpec) -> str:
    """The name of a labelling, truth aside."""
    holes = "-holes" if lander.count_holes else ""
    body = (
        f"{lander.layout}-d{lander.diameter_m:g}m-pad{lander.pad_diameter_m:g}m-slope{lander.max_slope_deg:g}deg"
        f"-rough{lander.max_roughness_m:g}m"
    )
    grid = f"dem{dem.rows}x{dem.cols}at{dem.spacing_m:g}m"
    return lander.rules.labeling_name(body, lander.n_yaws, holes, str(lander.baseline_combine), dem.gridding, grid)


def label_shard_name(index: int) -> str:
    """File name of label shard ``index`` (same index as its scan shard)."""
    return f"labels-{index:05d}.h5"


@dataclass(frozen=True)
class LabeledScan:
    """The labels of one scan (DEM arrays are north-up, metres, in the scan frame; P(safe) in [0, 1]).

    ``dem_noisy[k]`` and ``p_safe[k]`` are at the noise level ``sigmas_m[k]`` (metres, 1-sigma).
    """

    scan_index: int
    split: str
    dem_clean: np.ndarray  # float32 (H, W), NaN where no support
    dem_noisy: np.ndarray  # float32 (S, H, W)
    label: np.ndarray  # uint8 (H, W): 0 unsafe, 1 safe, 255 invalid
    slope_rad: np.ndarray  # float32 (H, W)
    roughness_m: np.ndarray  # float32 (H, W)
    p_safe: np.ndarray  # float32 (S, H, W)
    sigmas_m: tuple[float, ...] = ()  # the S noise levels, metres (the shard's sigmas_m)


class LabelShardWriter:
    """Writes one label shard: built in memory, written atomically by ``commit`` (``abort`` drops it).

    ``schema_version``: :func:`label_schema_version` of the labelling's truth (default: the clean scan's).
    """

    def __init__(
        self,
        path: Path,
        n_scans: int,
        n_sigmas: int,
        dem: DemSpec,
        attrs: dict[str, object],
        schema_version: str = LABEL_SCHEMA_VERSION_CLEAN_SCAN,
    ) -> None:
        self.path = path
        self._image = H5Image(path)
        self._f = self._image.file
        write_attrs(
            self._f,
            {
                "schema": LABEL_SCHEMA,
                "schema_version": schema_version,
                "software": "hd",
                "software_version": __version__,
                "n_scans": n_scans,
                **dem.to_attrs(),
                **attrs,
            },
        )
        h, w, n, s = dem.rows, dem.cols, n_scans, n_sigmas
        gz = compression_kwargs("gzip")
        small = compression_kwargs("none")
        f = self._f
        self._d = {
            "scan_index": f.create_dataset("scan_index", (n,), np.int64, chunks=(n,), **small),
            "split": f.create_dataset("split", (n,), np.uint8, chunks=(n,), **small),
            "dem_clean": f.create_dataset("dem_clean", (n, h, w), np.float32, chunks=(1, h, w), **gz),
            "dem_noisy": f.create_dataset("dem_noisy", (n, s, h, w), np.float32, chunks=(1, 1, h, w), **gz),
            "label": f.create_dataset("label", (n, h, w), np.uint8, chunks=(1, h, w), **gz),
            "slope_rad": f.create_dataset("slope_rad", (n, h, w), np.float32, chunks=(1, h, w), **gz),
            "roughness_m": f.create_dataset("roughness_m", (n, h, w), np.float32, chunks=(1, h, w), **gz),
            "p_safe": f.create_dataset("p_safe", (n, s, h, w), np.float32, chunks=(1, 1, h, w), **gz),
        }
        self._rows = RowBlocks(self._d)
        self._d["label"].attrs["codes"] = (
            f"{defaults.LABEL_UNSAFE} unsafe, {defaults.LABEL_SAFE} safe, {defaults.LABEL_INVALID} invalid"
        )

    def write(
        self,
        k: int,
        scan_index: int,
        split: int,
        dem_clean: np.ndarray,
        dem_noisy: np.ndarray,
        label: np.ndarray,
        slope_rad: np.ndarray,
        roughness_m: np.ndarray,
        p_safe: np.ndarray,
    ) -> None:
        """Write the labels of scan ``k`` of the shard."""
        self._rows.put(
            k,
            {
                "scan_index": scan_index,
                "split": split,
                "dem_clean": dem_clean,
                "dem_noisy": dem_noisy,
                "label": label,
                "slope_rad": slope_rad,
                "roughness_m": roughness_m,
                "p_safe": p_safe,
            },
        )

    def commit(self) -> str:
        """Write the shard to its final path (temporary name, fsync, rename); returns its sha256."""
        self._rows.flush()
        return self._image.commit()

    def abort(self) -> None:
        self._image.discard()


def _text(value: Any) -> str:
    if isinstance(value, bytes):
        return value.decode(errors="replace")
    if isinstance(value, np.ndarray):
        return str(value.tolist())
    return str(value)


# Every array of a label shard by its axes (named axes agree across the arrays; docs/labels-format.md).
LABEL_ARRAYS: dict[str, tuple[int | str, ...]] = {
    "scan_index": ("scan",),
    "split": ("scan",),
    "dem_clean": ("scan", "row", "col"),
    "dem_noisy": ("scan", "sigma", "row", "col"),
    "label": ("scan", "row", "col"),
    "slope_rad": ("scan", "row", "col"),
    "roughness_m": ("scan", "row", "col"),
    "p_safe": ("scan", "sigma", "row", "col"),
}


class LabelShardReader:
    """Lazy reader of one label shard (one scan at a time; ``h5`` gives h5py access with checked reads).

    Args:
        path: the label shard.
        sha256: the checksum its manifest records; when given, checked before the file is opened.
        what: how errors name the file (default: its path).
        size_bytes: the size its manifest records (1.4): at a URL, a server that sends more is refused.

    Raises:
        FormatError: not a label shard or an unknown major version (``DamagedFileError``: a checksum
            mismatch or damage), as ``hdcore.storage`` raises it.
        LabelStoreError: a file that opens but does not hold a label shard's arrays.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        sha256: str | None = None,
        what: str | None = None,
        size_bytes: int | None = None,
    ) -> None:
        self.path: Path | str = str(path) if is_url(path) else Path(path)
        self.what = what or dataset_label(self.path)
        if sha256 is not None and not is_url(path):  # a URL is read lazily: hd verify checks its sha256
            verify_sha256(self.path, sha256, self.what)
        self.h5: CheckedH5File = open_h5_at(self.path, self.what, sha256, size_bytes)
        attrs = self.h5.attrs
        try:
            check_schema(
                _text(attrs.get("schema", "")),
                _text(attrs.get("schema_version", "")),
                LABEL_SCHEMA,
                LABEL_SCHEMA_VERSION,
                self.what,
            )
            self.sigmas_m: tuple[float, ...] = tuple(float(s) for s in np.atleast_1d(attrs["sigmas_m"]))
            dims = check_arrays(self.h5, LABEL_ARRAYS, self.what)
            if dims["sigma"] != len(self.sigmas_m):
                raise ShardFormatError(
                    f"{self.what}: dem_noisy holds {dims['sigma']} noise levels, sigmas_m lists {len(self.sigmas_m)}"
                )
            self._n = dims["scan"]
        except (ShardFormatError, KeyError, TypeError, ValueError, OSError) as exc:
            self.h5.close()
            if isinstance(exc, ShardFormatError):
                raise
            raise LabelStoreError(f"{self.what}: not a readable label shard ({exc})") from exc

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, k: int) -> LabeledScan:
        if not -self._n <= k < self._n:
            raise IndexError(f"scan {k} out of range for {self.what} ({self._n} scans)")
        f = self.h5
        try:
            split = SPLIT_NAMES[int(f["split"][k])]
        except IndexError as exc:
            raise LabelStoreError(f"{self.what}: row {k} has an unknown split code") from exc
        return LabeledScan(
            scan_index=int(f["scan_index"][k]),
            split=split,
            dem_clean=f["dem_clean"][k],
            dem_noisy=f["dem_noisy"][k],
            label=f["label"][k],
            slope_rad=f["slope_rad"][k],
            roughness_m=f["roughness_m"][k],
            p_safe=f["p_safe"][k],
            sigmas_m=self.sigmas_m,
        )

    def __iter__(self) -> Iterator[LabeledScan]:
        for k in range(len(self)):
            yield self[k]

    def close(self) -> None:
        self.h5.close()

    def __enter__(self) -> LabelShardReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# A labelling's short names (aliases): its convention (``paper``, ``hd``), or its convention and truth
# joined by ALIAS_JOIN (``paper+terrain``). A convention alone names its clean-scan labelling, the
# paper's truth, when the convention has labellings of both truths.
ALIAS_JOIN = "+"


def find_labeling(directory: str | os.PathLike, name: str | None = None) -> LabelingEntry:
    """The manifest entry of a labelling of the dataset (the only one, or the one called ``name``).

    ``name`` is, in this order: a labelling's full name (an exact name always wins, also over
    labellings whose names begin with it, e.g. a clean-scan labelling's over its ``-truth-terrain``
    twin); an alias, case-insensitive: ``paper`` or ``hd`` (the convention's labelling; the
    clean-scan one when the convention has both truths), ``paper+terrain``, ``hd+clean-scan``...
    (the convention's labelling of that truth); or the beginning of one labelling's name.

    Raises:
        LabelStoreError: no labelling, several and no ``name``, an unknown ``name`` or one that fits
            several labellings (the message lists the names and aliases the dataset has).
        StorageError: not a dataset (no readable manifest; ``FormatError``: an unknown schema).
    """
    manifest = read_manifest(directory)
    where = dataset_label(directory)  # how messages name it (a URL without its secrets)
    labelings = manifest.get("labelings", [])
    if not labelings:
        raise LabelStoreError(f"{where}: the dataset has no labels; run `hd label {where}` first")
    for lab in labelings:
        check = str(lab.get("schema", "")), str(lab.get("schema_version", ""))
        check_schema(check[0], check[1], LABEL_SCHEMA, LABEL_SCHEMA_VERSION, f"{where} labelling {lab.get('name')}")
        for entry in lab["shards"]:
            check_schema(
                str(entry.get("schema", LABEL_SCHEMA)),
                str(entry.get("schema_version", check[1])),
                LABEL_SCHEMA,
                LABEL_SCHEMA_VERSION,
                f"{where}/{entry['path']}",
            )
    if name is None:
        if len(labelings) > 1:
            names = ", ".join(lab["name"] for lab in labelings)
            raise LabelStoreError(
                f"{where} has several labellings ({names}); choose one with --labels"
                + _alias_hint(labelings, ": a name or an alias ({})")
            )
        return LabelingEntry.from_json(labelings[0], f"{where}/{MANIFEST_NAME}: labelling {labelings[0]['name']}")
    for lab in labelings:
        if lab["name"] == name:
            return LabelingEntry.from_json(lab, f"{where}/{MANIFEST_NAME}: labelling {name}")
    named = _alias_matches(labelings, name)
    if named is None:  # not an alias: the beginning of one labelling's name
        named = [lab for lab in labelings if str(lab["name"]).startswith(name)]
    if len(named) == 1:
        return LabelingEntry.from_json(named[0], f"{where}/{MANIFEST_NAME}: labelling {named[0]['name']}")
    if named:
        raise LabelStoreError(
            f"{where}: {name!r} names {len(named)} labellings: "
            + ", ".join(str(lab["name"]) for lab in named)
            + "; give the full name"
            + _alias_hint(labelings, " or an alias ({})")
        )
    names = ", ".join(str(lab["name"]) for lab in labelings)
    aliases = labeling_aliases(labelings)
    raise LabelStoreError(
        f"{where} has no labelling named {name!r}; it has: {names}"
        + (f" (aliases: {', '.join(aliases)})" if aliases else "")
    )


def _raw_truth(lab: Mapping[str, object]) -> str:
    """The truth of a labelling as the manifest has it (absent: the clean scan's, as before truths existed)."""
    return str(lab.get("truth", defaults.TRUTH))


def _alias_matches(labelings: list[LabelingJson], alias: str) -> list[LabelingJson] | None:
    """The labellings ``alias`` names (``CONVENTION`` or ``CONVENTION+TRUTH``, any case), or None when it
    is no alias.

    Raises:
        LabelStoreError: a convention joined to something that is not a truth (``paper+rock``).
    """
    convention, joined, truth = alias.strip().lower().partition(ALIAS_JOIN)
    if convention not in conventions.CONVENTIONS:
        return None
    if joined and truth not in defaults.TRUTHS:
        raise LabelStoreError(
            f"{alias!r} is not an alias: a convention is followed by {ALIAS_JOIN} and a truth, "
            + " or ".join(f"{convention}{ALIAS_JOIN}{t}" for t in defaults.TRUTHS)
        )
    mine = [lab for lab in labelings if lab.get("convention", "hd") == convention]
    if joined:
        return [lab for lab in mine if _raw_truth(lab) == truth]
    paper_truth = [lab for lab in mine if _raw_truth(lab) == defaults.TRUTH]
    return paper_truth if len(paper_truth) == 1 else mine


def labeling_aliases(labelings: list[LabelingJson]) -> dict[str, str]:
    """Each alias that names exactly one of ``labelings`` (manifest entries), with that labelling's name,
    shortest first per convention (``paper``, ``paper+clean-scan``, ``paper+terrain``, ``hd``, ...)."""
    out: dict[str, str] = {}
    for convention in conventions.CONVENTIONS:
        for alias in (convention, *(f"{convention}{ALIAS_JOIN}{t}" for t in defaults.TRUTHS)):
            named = _alias_matches(labelings, alias)
            if named is not None and len(named) == 1:
                out[alias] = str(named[0]["name"])
    return out


def _alias_hint(labelings: list[LabelingJson], form: str) -> str:
    """``form`` filled with one alias per labelling that has one (``paper = NAME, paper+terrain = NAME``),
    or '' when none has."""
    first: dict[str, str] = {}
    for alias, name in labeling_aliases(labelings).items():
        first.setdefault(name, alias)
    return form.format(", ".join(f"{alias} = {name}" for name, alias in first.items())) if first else ""


def open_label_shard(directory: str | os.PathLike, entry: LabelShardEntry) -> LabelShardReader:
    """Open the label shard of a manifest entry: confined to the dataset, its sha256 checked first.

    Raises:
        FormatError: path outside the dataset, unknown schema (``DamagedFileError``: a missing or
            damaged file), as ``hdcore.storage`` raises it.
    """
    what = dataset_label(join(directory, entry.path)) if is_url(directory) else f"{Path(directory) / entry.path}"
    path = join(directory, entry.path, what)
    return LabelShardReader(path, sha256=entry.sha256, what=what, size_bytes=entry.size_bytes)


def iter_labeled_scans(
    directory: str | os.PathLike, labels: str | None = None, split: str | None = None
) -> Iterator[LabeledScan]:
    """Every labelled scan of a dataset (optionally one split: ``train``, ``val`` or ``test``), in scan order.

    ``labels`` names the labelling as :func:`find_labeling` takes it (None: the dataset's only one).
    Each label shard is checked against the manifest's sha256 before it is read; scans are read one
    at a time (``lidarsim.shards.iter_scans`` reads the point clouds the same way).

    Raises:
        LabelStoreError: no labelling, or not the one ``labels`` names; an unknown ``split``.
        FormatError: a label shard that is missing, damaged or of an unknown schema.
    """
    if split is not None and split not in SPLIT_NAMES:
        raise LabelStoreError(f"unknown split {split!r}; use one of {', '.join(SPLIT_NAMES)}")
    entry = find_labeling(directory, labels)  # its errors now, not at the first scan
    return _labeled_scans(directory, entry, split)


def _labeled_scans(directory: str | os.PathLike, entry: LabelingEntry, split: str | None) -> Iterator[LabeledScan]:
    for shard in entry.shards:
        with open_label_shard(directory, shard) as reader:
            for scan in reader:
                if split is None or scan.split == split:
                    yield scan


def add_labeling_to_manifest(directory: Path, entry: LabelingEntry) -> None:
    """Add (or replace, same name) a labelling entry in the manifest, atomically (writer lock held); the
    other labellings stay as the manifest has them."""
    manifest = read_manifest(directory)
    others = [lab for lab in manifest.get("labelings", []) if lab["name"] != entry.name]
    manifest["labelings"] = [*others, entry.to_json()]
    if any(shard.size_bytes is not None for shard in entry.shards):
        manifest["schema_version"] = sizes_version(manifest["schema_version"])
    write_json_atomic(directory / MANIFEST_NAME, manifest)
