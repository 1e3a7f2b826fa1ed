"""Label a whole dataset: DEMs, ALHAT labels and the baseline P(safe) for every scan (``hd label``).

One task per scan shard (process pool or Dask, like the factory). For each scan:

* the clean points are gridded into the clean DEM, the noisy points of every sigma into noisy DEMs
  (``hdlabels.grid.grid_points``);
* the clean DEM gives slope, roughness and the label (``hdlabels.alhat.hazard_maps``); with the
  terrain truth (``truth="terrain"``) the DTM sampled on the same grid gives them instead
  (``hdlabels.truth``);
* every noisy DEM gives the baseline P(safe) with that sigma (``hdlabels.alhat.safety_probability``).

Label shards are written atomically beside the scan shards; the manifest gets the labelling entry
only when every shard is complete. An interrupted run resumes; an existing labelling with the
same settings is kept. A run holds the dataset's writer lock (one writer per dataset), checks
every scan shard against the manifest's sha256 before reading it, and removes its partial files
(and a labelling directory it created and left empty) when it fails.

With the terrain truth, every label shard is made from the terrain the build recorded: the DTM is
checked against the manifest's sha256 as each shard reads it (``hdlabels.truth.labelled_terrain``)
and each shard records that sha256 (``truth_dtm_sha256``). A shard that records another terrain is
damaged: it is never kept when a run resumes, and an existing labelling with such shards is
labelled again (with a warning) instead of being reported as already labelled.
"""

from __future__ import annotations

import math
import os
import shutil
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial, wraps
from pathlib import Path
from typing import Any

import numpy as np

from hdcore.errors import HdWarning, StorageError
from hdcore.outcome import counted
from hdcore.storage import OutputTransaction, check_h5_data, confine, open_h5
from hdlabels import defaults
from hdlabels.alhat import hazard_maps, safety_probability
from hdlabels.grid import grid_points
from hdlabels.lander import Lander, geometry
from hdlabels.mosaic_dataset import check_mosaic_grid
from hdlabels.settings import LabelSettings
from hdlabels.store import (
    LABELS_DIR,
    DemSpec,
    LabelingEntry,
    LabelShardEntry,
    LabelShardReader,
    LabelShardWriter,
    LabelStoreError,
    add_labeling_to_manifest,
    label_schema_version,
    label_shard_name,
    labeling_name,
)
from hdlabels.truth import labelled_terrain, terrain_dem, verified_build_terrain
from lidarsim.manifest_json import ManifestJson
from lidarsim.parallel import run_tasks
from lidarsim.shards import (
    MANIFEST_NAME,
    TRUTH_DTM_SHA256_ATTR,
    ShardFormatError,
    open_scan_shard,
    read_manifest,
    remove_partials,
    sha256_file,
)
from lidarsim.terrain import DTM


@dataclass(frozen=True)
class LabelTask:
    """Label one scan shard."""

    dataset: str
    source_path: str  # relative to the dataset
    source_sha256: str
    out_path: str  # relative to the dataset
    lander: Lander
    dem: DemSpec
    labeling: str
    truth: str = defaults.TRUTH
    dtm_path: str | None = None  # the terrain truth's DTM (checked by the parent), None for the clean scan
    dtm_scale: float = 1.0
    dtm_sha256: str | None = None  # the build's record of that DTM, checked again as each shard reads it
    dtm_identity: tuple[int, ...] | None = None  # the DTM file the parent hashed (hdlabels.truth.terrain_identity)


@dataclass(frozen=True)
class LabelRecord:
    """Manifest entry of one label shard, plus its label counts and the baseline's safe counts."""

    entry: LabelShardEntry
    counts: tuple[int, int, int]  # unsafe, safe, invalid pixels
    baseline_safe: tuple[int, ...]  # per sigma: labelled pixels whose P(safe) >= 0.5


@dataclass(frozen=True)
class LabelSummary:
    """What ``label_dataset`` did."""

    name: str
    n_scans: int
    n_shards: int
    safe_fraction: float
    baseline_safe_fraction: dict[str, float]
    seconds: float
    reused: bool
    truth: str = defaults.TRUTH

    def paragraph(self) -> str:
        base = ", ".join(f"{_cm(k)}: {v * 100:.1f}%" for k, v in self.baseline_safe_fraction.items())
        verb = "already labelled" if self.reused else f"labelled in {self.seconds:.1f} s"
        return (
            f"Labelling {self.name}: {self.n_scans} scans in {counted(self.n_shards, 'label shard')}, {verb}. "
            f"{self.safe_fraction * 100:.1f}% of labelled pixels are safe ({_TRUTH_WORDS[self.truth]}); the ALHAT "
            f"baseline "
            f"(P(safe) >= {defaults.SAFE_PROBABILITY_THRESHOLD:g}) calls safe {base} of them (sigma per noise level)."
        )


# How the summary names the DEMs the deterministic labels come from, per truth.
_TRUTH_WORDS = {"clean-scan": "clean DEMs", "terrain": "the terrain truth: the DTM on each scan's DEM grid"}


def _cm(sigma_m: str) -> str:
    """A noise level recorded in metres ("0.0167"), written in centimetres ("1.67 cm")."""
    try:
        return f"{float(sigma_m) * 100:.2f} cm"
    except ValueError:
        return sigma_m


def check_lander_fits(lander: Lander, dem: DemSpec) -> None:
    """Refuse a lander the convention cannot place on the grid, or whose border band leaves no pixel to label."""
    too_large = lander.diameter_m >= min(dem.rows, dem.cols) * dem.spacing_m  # before any geometry is laid out
    if too_large or 2 * geometry(lander, dem.spacing_m).band_px >= min(dem.rows, dem.cols):
        raise LabelStoreError(
            f"the lander ({lander.diameter_m:g} m) is larger than the DEM ({dem.rows} x {dem.cols} cells of "
            f"{dem.spacing_m:g} m): no pixel could be labelled"
        )


def label_scan(
    points_clean: np.ndarray,
    points_noisy: np.ndarray,
    sigmas_m: tuple[float, ...],
    lander: Lander,
    dem: DemSpec,
    truth: Callable[[np.ndarray], np.ndarray] | None = None,
) -> dict[str, np.ndarray]:
    """DEMs, hazard maps and P(safe) of one scan (arrays as stored in a label shard).

    ``truth`` maps the clean scan's DEM to the DEM the labels come from (the terrain truth,
    ``hdlabels.truth.terrain_dem``); None labels the clean scan's DEM itself.
    """
    shape = (dem.rows, dem.cols)
    dem_clean = grid_points(points_clean, shape, dem.spacing_m, method=dem.gridding)
    if not np.isfinite(dem_clean).any():
        raise LabelStoreError("a clean DEM is all NaN: the scan has no returns under the DEM grid")
    if truth is not None:
        dem_clean = truth(dem_clean)
    maps = hazard_maps(dem_clean, dem.spacing_m, lander)
    dem_noisy = np.stack(
        [grid_points(points_noisy[s], shape, dem.spacing_m, method=dem.gridding) for s in range(len(sigmas_m))]
    )
    p_safe = np.stack(
        [safety_probability(dem_noisy[s], dem.spacing_m, sigma, lander) for s, sigma in enumerate(sigmas_m)]
    )
    return {
        "dem_clean": dem_clean,
        "dem_noisy": dem_noisy,
        "label": maps.label,
        "slope_rad": maps.slope_rad,
        "roughness_m": maps.roughness_m,
        "p_safe": p_safe,
    }


def baseline_safe_counts(label: np.ndarray, p_safe: np.ndarray) -> np.ndarray:
    """Per sigma, the labelled pixels (label not invalid) whose P(safe) calls them safe (>= 0.5),
    int64 (S,), of one scan's (H, W) label and (S, H, W) P(safe) or of a shard's (N, H, W) and (N, S, H, W)."""
    labelled = label != defaults.LABEL_INVALID
    sigma_axis = p_safe.ndim - 3
    safe = (p_safe >= defaults.SAFE_PROBABILITY_THRESHOLD) & np.expand_dims(labelled, sigma_axis)
    return safe.sum(axis=tuple(a for a in range(p_safe.ndim) if a != sigma_axis), dtype=np.int64)


def label_counts(label: np.ndarray) -> np.ndarray:
    """Pixel counts (unsafe, safe, invalid) of a label array, int64 (3,)."""
    return np.array(
        [(label == code).sum() for code in (defaults.LABEL_UNSAFE, defaults.LABEL_SAFE, defaults.LABEL_INVALID)],
        dtype=np.int64,
    )


def run_label_task(task: LabelTask) -> LabelRecord:
    """Label one scan shard and write its label shard (worker side)."""
    root = Path(task.dataset)
    out = root / task.out_path
    counts = np.zeros(3, dtype=np.int64)
    with open_scan_shard(root, {"path": task.source_path, "sha256": task.source_sha256}) as reader:
        sigmas = reader.sigmas_m
        n_scans = len(reader)
        baseline = np.zeros(len(sigmas), dtype=np.int64)
        attrs: dict[str, object] = {
            "labeling": task.labeling,
            "source_shard": task.source_path,
            "source_sha256": task.source_sha256,
            "sigmas_m": np.asarray(sigmas, dtype=np.float64),
            **{f"lander_{k}": v for k, v in task.lander.to_attrs().items()},
        }
        if task.truth != defaults.TRUTH:  # the clean-scan truth's shards keep their bytes: no attribute
            attrs.update(truth_attrs(task))
        writer = LabelShardWriter(
            out, len(reader), len(sigmas), task.dem, attrs, schema_version=label_schema_version(task.truth)
        )
        try:
            f = reader.h5
            points_clean, points_noisy = f["points_clean"], f["points_noisy"]
            scan_index, split = f["scan_index"][:], f["split"][:]
            with _truth_dtm(task) as dtm:
                for k in range(n_scans):
                    truth = None
                    if dtm is not None:
                        origin = np.asarray(f["origin_map"][k], dtype=np.float64)
                        to_map = np.asarray(f["frame_to_map"][k], dtype=np.float64) if reader.is_mosaic else None
                        truth = partial(_terrain_truth, origin_map=origin, dem=task.dem, dtm=dtm, frame_to_map=to_map)
                    try:
                        arrays = label_scan(points_clean[k], points_noisy[k], sigmas, task.lander, task.dem, truth)
                    except LabelStoreError as exc:
                        raise LabelStoreError(f"{task.source_path} scan {int(scan_index[k])}: {exc}") from exc
                    writer.write(k, int(scan_index[k]), int(split[k]), **arrays)
                    counts += label_counts(arrays["label"])
                    baseline += baseline_safe_counts(arrays["label"], arrays["p_safe"])
            sha256 = writer.commit()
        except BaseException:
            writer.abort()
            raise
    return _record(task, sha256, n_scans, counts, baseline)


def _terrain_truth(
    dem_clean: np.ndarray, *, origin_map: np.ndarray, dem: DemSpec, dtm: DTM, frame_to_map: np.ndarray | None
) -> np.ndarray:
    return terrain_dem(origin_map, dem_clean, dem, dtm, frame_to_map)


@contextmanager
def _truth_dtm(task: LabelTask) -> Iterator[DTM | None]:
    """The DTM of the terrain truth, open while a shard is labelled and checked against the build's
    sha256 as it is read (None for the clean-scan truth)."""
    if task.truth == defaults.TRUTH or task.dtm_path is None or task.dtm_sha256 is None:
        yield None
        return
    name = Path(task.dataset).name
    with labelled_terrain(task.dtm_path, task.dtm_sha256, task.dtm_scale, name, task.dtm_identity) as dtm:
        yield dtm


def truth_attrs(task: LabelTask) -> dict[str, object]:
    """The label-shard attributes of a labelling's truth (written only for the terrain truth)."""
    return {
        "truth": task.truth,
        "truth_dtm": Path(task.dtm_path).name if task.dtm_path else "",
        "truth_dtm_scale": float(task.dtm_scale),
        TRUTH_DTM_SHA256_ATTR: task.dtm_sha256 or "",
    }


def _record(task: LabelTask, sha256: str, n_scans: int, counts: np.ndarray, baseline: np.ndarray) -> LabelRecord:
    entry = LabelShardEntry(
        path=task.out_path,
        sha256=sha256,
        n_scans=n_scans,
        source_path=task.source_path,
        source_sha256=task.source_sha256,
        schema_version=label_schema_version(task.truth),
        size_bytes=(Path(task.dataset) / task.out_path).stat().st_size,
    )
    return LabelRecord(
        entry=entry,
        counts=(int(counts[0]), int(counts[1]), int(counts[2])),
        baseline_safe=tuple(int(c) for c in baseline),
    )


def _existing(task: LabelTask) -> LabelRecord | None:
    """A complete label shard of an earlier, interrupted run of the same labelling."""
    out = Path(task.dataset) / task.out_path
    if not out.is_file():
        return None
    try:
        with LabelShardReader(out) as reader:
            a = reader.h5.attrs
            if a.get("source_sha256") != task.source_sha256 or a.get("labeling") != task.labeling:
                return None
            if str(a.get("truth", defaults.TRUTH)) != task.truth:
                return None
            if task.truth != defaults.TRUTH and a.get(TRUTH_DTM_SHA256_ATTR) != task.dtm_sha256:
                return None  # labelled from another terrain, or before shards recorded theirs
            lab = reader.h5["label"][:]
            p_safe = reader.h5["p_safe"][:]
            n = len(reader)
        check_h5_data(out)  # every chunk's fletcher32 checksum
    except (LabelStoreError, ShardFormatError, OSError, KeyError):
        return None
    return _record(task, sha256_file(out), n, label_counts(lab), baseline_safe_counts(lab, p_safe))


def other_terrain_shards(root: Path, labeling: LabelingEntry, dtm_sha256: str) -> list[str]:
    """The label shards of a labelling entry that record another terrain than ``dtm_sha256`` (the
    build's), as ``PATH: truth_dtm_sha256 ABC...``. Shards that record none (written before shards
    recorded their terrain) and shards that cannot be read (``hd verify`` names those) are not listed.
    """
    foreign: list[str] = []
    for entry in labeling.shards:
        try:
            with open_h5(confine(root, entry.path), entry.path) as f:
                recorded = f.attrs.get(TRUTH_DTM_SHA256_ATTR)
        except (StorageError, OSError, KeyError, TypeError):
            continue
        if recorded is not None and recorded != dtm_sha256:
            foreign.append(f"{entry.path}: {TRUTH_DTM_SHA256_ATTR} {str(recorded)[:12]}...")
    return foreign


def _single_writer(func: Callable[..., LabelSummary]) -> Callable[..., LabelSummary]:
    """Run a labelling holding the dataset's writer lock; on failure remove its partial files and
    the labelling directories it created and left empty."""

    @wraps(func)
    def wrapper(directory: str | os.PathLike, *args: Any, **kwargs: Any) -> LabelSummary:
        root = Path(directory).resolve()
        read_manifest(root)
        labels = root / LABELS_DIR
        if labels.is_symlink():
            raise LabelStoreError(f"{labels} is a symbolic link; hd writes label shards only inside the dataset")
        before = {p.name for p in labels.iterdir()} if labels.is_dir() else None

        def rollback() -> None:
            for d in labels.iterdir() if labels.is_dir() else []:
                if d.is_dir() and not d.is_symlink():
                    remove_partials(d)
                    if (before is None or d.name not in before) and not any(d.iterdir()):
                        d.rmdir()
            if before is None and labels.is_dir() and not any(labels.iterdir()):
                labels.rmdir()

        with OutputTransaction(root, "dataset", rollback=rollback):  # the dataset exists: in place
            return func(root, *args, **kwargs)

    return wrapper


@_single_writer
def label_dataset(
    directory: str | os.PathLike,
    settings: LabelSettings | None = None,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> LabelSummary:
    """Label every scan of the dataset at ``directory`` as ``settings`` says (default: ``LabelSettings()``:
    the lander, its convention, the DEM grid, 100 x 100 cells of 1 m made with the convention's gridding,
    and the truth; each field's meaning, unit and range are its metadata, ``hdlabels.settings``).

    ``settings.truth``: ``"clean-scan"`` (the deterministic labels of the clean scan's DEM, the paper's) or
    ``"terrain"`` (of the DTM the dataset was built on, sampled on each scan's DEM grid; ``hdlabels.truth``).
    ``workers``/``scheduler``: how the shards are labelled in parallel; ``progress`` is called with (scans
    labelled, scans in all).

    Raises:
        HdLabelsError: an invalid lander (``LabelSettings.to_lander``).
        LabelStoreError: not an hd dataset, a lander too large for the DEM, an all-NaN DEM, a terrain truth
            whose DTM is missing or changed.
    """
    t0 = time.perf_counter()
    label = settings if settings is not None else LabelSettings()
    lander, dem, truth = label.to_lander(), label.to_dem_spec(), label.truth
    root = Path(directory).resolve()
    manifest = read_manifest(root)
    check_lander_fits(lander, dem)
    check_mosaic_grid(manifest, dem, str(root))
    name = labeling_name(lander, dem, truth)
    dtm_path, dtm_sha256, dtm_scale, dtm_identity = (
        (None, None, 1.0, None) if truth == defaults.TRUTH else verified_build_terrain(root, manifest)
    )
    earlier = _current_labeling(root, manifest, name, dtm_sha256)
    if earlier is not None:
        return _summary_from_entry(earlier, manifest, time.perf_counter() - t0, reused=True)
    tasks = [
        LabelTask(
            dataset=str(root),
            source_path=s["path"],
            source_sha256=s["sha256"],
            out_path=f"{LABELS_DIR}/{name}/{label_shard_name(i)}",
            lander=lander,
            dem=dem,
            labeling=name,
            truth=truth,
            dtm_path=None if dtm_path is None else str(dtm_path),
            dtm_scale=dtm_scale,
            dtm_sha256=dtm_sha256,
            dtm_identity=dtm_identity,
        )
        for i, s in enumerate(manifest["shards"])
    ]
    records = _label_shards(root / LABELS_DIR / name, tasks, int(manifest["n_scans"]), workers, scheduler, progress)
    entry = _labeling_entry(name, lander, dem, truth, records, manifest["sigmas_m"])
    add_labeling_to_manifest(root, entry)
    return _summary_from_entry(entry, manifest, time.perf_counter() - t0, reused=False)


def _current_labeling(root: Path, manifest: ManifestJson, name: str, dtm_sha256: str | None) -> LabelingEntry | None:
    """Step 1: the manifest's entry of the labelling ``name`` when it is there and whole (every shard labelled
    from the terrain the scans were cast on), else None (a foreign shard: warned, labelled again)."""
    for raw in manifest.get("labelings", []):
        if raw["name"] == name:
            lab = LabelingEntry.from_json(raw, f"{root}/{MANIFEST_NAME}: labelling {name}")
            foreign = [] if dtm_sha256 is None else other_terrain_shards(root, lab, dtm_sha256)
            if not foreign:
                return lab
            warnings.warn(
                HdWarning(
                    f"{root.name}: {len(foreign)} label shard(s) of {name} were labelled from another terrain than "
                    f"the one the scans were cast on ({foreign[0]}); damaged: labelling them again"
                ),
                stacklevel=3,
            )
    return None


def _label_shards(
    out_dir: Path,
    tasks: list[LabelTask],
    total: int,
    workers: int | None,
    scheduler: str | None,
    progress: Callable[[int, int], None] | None,
) -> list[LabelRecord]:
    """Step 2: the record of each task's shard, in the tasks' order: those complete on disk counted from
    their files, the others labelled (``workers`` processes, or ``scheduler``); a new ``out_dir`` is
    removed again when labelling fails."""
    created = not out_dir.exists()
    out_dir.mkdir(parents=True, exist_ok=True)
    remove_partials(out_dir)
    records: dict[int, LabelRecord] = {}
    pending = []
    for i, task in enumerate(tasks):
        rec = _existing(task)
        if rec is None:
            pending.append((i, task))
        else:
            records[i] = rec
    done = sum(r.entry.n_scans for r in records.values())
    if progress:
        progress(done, total)
    n_workers = max(1, workers if workers is not None else (os.cpu_count() or 1))
    try:
        for position, rec in run_tasks(run_label_task, [t for _, t in pending], n_workers, scheduler):
            i = pending[position][0]
            records[i] = rec
            done += rec.entry.n_scans
            if progress:
                progress(done, total)
    except LabelStoreError:
        if created:
            shutil.rmtree(out_dir, ignore_errors=True)
        raise
    return [records[i] for i in sorted(records)]


def _labeling_entry(
    name: str, lander: Lander, dem: DemSpec, truth: str, records: list[LabelRecord], sigmas_m: list[float]
) -> LabelingEntry:
    """Step 3: the manifest's entry of the labelling (its counts summed over the shards' ``records``)."""
    counts = np.sum([r.counts for r in records], axis=0)
    return LabelingEntry(
        name=name,
        lander=lander,
        dem=dem,
        truth=truth,
        schema_version=label_schema_version(truth),
        label_counts=(int(counts[0]), int(counts[1]), int(counts[2])),
        safe_fraction=float(counts[1] / max(1, counts[0] + counts[1])),
        baseline_safe_fraction=_baseline_fractions(records, sigmas_m),
        shards=tuple(r.entry for r in records),
    )


def _baseline_fractions(records: list[LabelRecord], sigmas: list[float]) -> dict[str, float]:
    """Fraction of labelled pixels the baseline (P >= 0.5) calls safe, per sigma (``sigmas``, metres: the
    dataset's noise levels)."""
    safe = np.zeros(len(sigmas), dtype=np.int64)
    for r in records:
        safe += r.baseline_safe
    valid = sum(r.counts[0] + r.counts[1] for r in records)
    return {f"{sig:g}": float(safe[s] / max(1, valid)) for s, sig in enumerate(sigmas)}


def _summary_from_entry(entry: LabelingEntry, manifest: ManifestJson, seconds: float, reused: bool) -> LabelSummary:
    return LabelSummary(
        name=entry.name,
        n_scans=int(manifest["n_scans"]),
        n_shards=len(entry.shards),
        safe_fraction=math.nan if entry.safe_fraction is None else entry.safe_fraction,
        baseline_safe_fraction=dict(entry.baseline_safe_fraction),
        seconds=seconds,
        reused=reused,
        truth=entry.truth,
    )
