"""Hazard maps and ranked landing sites for any terrain from a trained run (``hd detect``).

Input: a DTM file (any size; read window by window through ``lidarsim.terrain.DTM``, resampled to
the run's DEM spacing) or one scan's noisy DEM of a labelled dataset (scan frame). Output, into a
new or empty directory or over an earlier ``hd detect`` output (``hdcore.storage.OutputDir``:
never an input or a directory holding one, under a writer lock, staged inside the directory and
moved into place file by file with ``detect.json`` last, so the output is complete when
``detect.json`` is there):

* ``p_safe.tif`` (float32, MC-dropout mean P(safe)), ``entropy.tif`` (float32, predictive entropy,
  nats), ``mutual_information.tif`` (float32, the MC-dropout samples' mutual information, nats),
  ``safety.tif`` (uint8: 0 unsafe, 1 safe, 2 uncertain = the uncertainty score, entropy or mutual
  information (``hdnet.uncertainty``), >= H_t, 255 invalid) and ``baseline_p_safe.tif`` (float32,
  the ALHAT P(safe) baseline), all on one grid: the input's extent at the run's DEM spacing, with
  its CRS; NaN / 255 where invalid;
* ``sites.csv`` and ``sites.geojson``: ranked landing sites (``SITE_COLUMNS``);
* ``overview.png`` (hillshade, safety map, numbered sites) and ``detect.json`` (run, input sha256,
  threshold, tiling, counts, timings).

Pipeline (docs/user-guide.md, "Hazard maps and landing sites"):

1. the run: model, input preparation (``hdnet.run_record``), lander and label convention (the run's
   labelling entry; older runs: their dataset's manifest), DEM size and spacing;
2. H_t exactly as ``hd eval`` computes it (``validation_threshold`` on the uncertainty score of a
   validation split at the training sigma), or a fixed ``nats:H``;
3. tiles of the training DEM size overlapping by ``overlap_px`` (``hdnet.tiling``), one row of
   tiles at a time: DTM window -> scan frame (heights minus the tile's mean height, as the
   simulator's scan frame is referenced to the mean terrain height under the footprint) ->
   ``network_input`` -> MC dropout with the shared prefix -> ``network_output``; the ALHAT baseline
   on the same window (``baseline_p_safe``), whose invalid cells (border band, footprint touching
   nodata) are the invalid cells of every map; owned centre crops written to the GeoTIFFs;
4. sites (``select_sites``) from the finished maps.
"""

from __future__ import annotations

import csv
import io
import math
import os
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import torch
from rasterio.transform import Affine
from rasterio.windows import Window
from scipy import ndimage

from hdcore.errors import HdError, HdWarning
from hdcore.storage import (
    GeoTiffWriter,
    OutputDir,
    StorageError,
    describe_os_error,
    write_json_atomic,
    write_text_atomic,
)
from hdlabels import defaults as label_defaults
from hdlabels.alhat import safety_probability
from hdlabels.lander import Lander, geometry
from hdlabels.store import LabelingEntry, LabelShardEntry, find_labeling, open_label_shard
from hdnet import defaults
from hdnet._version import __version__
from hdnet.data import dataset_sigmas, open_labeling, sigma_index
from hdnet.detect_json import DetectInfoJson, DetectInputJson, SitesGeoJson, UpsampledJson, input_name
from hdnet.detect_settings import DetectSettings
from hdnet.engine import inference_model, predict
from hdnet.errors import HdNetError
from hdnet.evaluate import (
    checkpoint_path,
    guard_above_training,
    preferred_labeling,
    split_dataset,
    validation_threshold,
)
from hdnet.fit import is_run_dir
from hdnet.infer import MCPrediction
from hdnet.inputs import InputSpec, to_dem_grid
from hdnet.inputs import network_input as prepare_input
from hdnet.model import BayesianSegNet
from hdnet.noise_levels import TrainingNoise
from hdnet.preflight import check_inputs
from hdnet.report import json_plain
from hdnet.report_json import ThresholdJson
from hdnet.results import SITE_COLUMNS, Site
from hdnet.run_record import CheckpointHeader, TrainingData, unfinished_training
from hdnet.sites import (
    SAFETY_INVALID,
    SAFETY_SAFE,
    SAFETY_UNCERTAIN,
    SAFETY_UNSAFE,
    SITE_FOOTPRINTS,
    SITE_RANK_RULES,
    select_sites,
)
from hdnet.threshold_cache import CachedThreshold, cache_key
from hdnet.thresholds import ThresholdSpec, parse_threshold_spec, uncertain_mask, warn_if_unreachable
from hdnet.tiling import TilePlan
from hdnet.trained_run import TrainedRun
from hdnet.uncertainty import ENTROPY, UncertaintyScore, recorded_score, uncertainty_score, with_score
from lidarsim.errors import TerrainError
from lidarsim.location import dataset_at, dataset_key, dataset_label, has_manifest, manifest_sha256
from lidarsim.manifest_json import ShardRefJson
from lidarsim.map_window import MapWindow, WindowCells, bounds_text, grid_bounds, window_cells
from lidarsim.procedural import geotiff_profile
from lidarsim.shards import MANIFEST_NAME, open_scan_shard, read_manifest
from lidarsim.terrain import DTM
from lidarsim.upsampled import UpsampledDTM


@dataclass(frozen=True)
class TileCells:
    """One tile's outputs on the cells it owns (its centre crop ``crop``), from which every map is made.

    Attributes:
        mc: the MC-dropout prediction of the tile's batch on the run's grid (``hdnet.infer.MCPrediction``).
        index: the tile's place in that batch.
        crop: (rows, cols) slices of the owned cells in the tile.
        baseline_p_safe: the ALHAT P(safe) baseline of the owned cells, float32, NaN where invalid.
        uncertain: bool, the owned cells whose uncertainty score is >= H_t.
    """

    mc: MCPrediction
    index: int
    crop: tuple[slice, slice]
    baseline_p_safe: np.ndarray
    uncertain: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """The owned cells with a baseline (a finite DEM around them): the others are every map's nodata."""
        return np.isfinite(self.baseline_p_safe)

    def cells(self, batch: torch.Tensor) -> np.ndarray:
        """The owned cells of the tile in a (N, H, W) tensor of its batch (``mc``'s arrays)."""
        return batch[self.index].numpy()[self.crop]

    def masked(self, batch: torch.Tensor) -> np.ndarray:
        """:meth:`cells`, NaN where invalid."""
        return np.where(self.valid, self.cells(batch), np.nan)


def _safety_codes(t: TileCells) -> np.ndarray:
    """The safety map's uint8 codes of a tile's owned cells: safe/unsafe by the network, uncertain, invalid."""
    safety = np.where(t.cells(t.mc.prediction) == defaults.CLASS_SAFE, SAFETY_SAFE, SAFETY_UNSAFE).astype(np.uint8)
    safety[t.uncertain] = SAFETY_UNCERTAIN
    safety[~t.valid] = SAFETY_INVALID
    return safety


@dataclass(frozen=True)
class MapSpec:
    """One map of ``hd detect``: its field (in ``DetectMaps`` and ``detect_dem``'s result), its
    GeoTIFF, its array type, its nodata value, and how a tile's owned cells of it are computed."""

    field: str
    file: str
    dtype: type[np.generic]
    nodata: float
    compute: Callable[[TileCells], np.ndarray]


# The maps of a detection, in the order of their files: a new map is one entry here (and its field of
# DetectMaps).
MAPS: tuple[MapSpec, ...] = (
    MapSpec("p_safe", "p_safe.tif", np.float32, math.nan, lambda t: t.masked(t.mc.mean_probs[:, defaults.CLASS_SAFE])),
    MapSpec("entropy_nats", "entropy.tif", np.float32, math.nan, lambda t: t.masked(t.mc.entropy_nats)),
    MapSpec(
        "mutual_information_nats",
        "mutual_information.tif",
        np.float32,
        math.nan,
        lambda t: t.masked(t.mc.mutual_information_nats),
    ),
    MapSpec("safety", "safety.tif", np.uint8, SAFETY_INVALID, _safety_codes),
    MapSpec("baseline_p_safe", "baseline_p_safe.tif", np.float32, math.nan, lambda t: t.baseline_p_safe),
)
MAP_FILES = tuple(spec.file for spec in MAPS)
OUTPUT_FILES = (*MAP_FILES, "sites.csv", "sites.geojson", "overview.png", "detect.json")
# The ALHAT baseline is safe where P(safe) >= this (paper, "Label generation"; one source: hdlabels.defaults).
BASELINE_THRESHOLD = label_defaults.SAFE_PROBABILITY_THRESHOLD
# hd choice: a DTM may be up to 2 % coarser than the run's DEM spacing (HiRISE "1 m" products are
# 1.01 m); it is then read at full resolution. Anything coarser would have to invent detail.
SPACING_TOLERANCE = 0.02
# hd choice: cells of a DTM upsampled (--upsample): 2**28, as lidarsim's limit of cells in memory. The
# interpolated grid is computed window by window (lidarsim.upsampled), but the maps' own arrays (the
# sites' safety map and P(safe)) and the footprint check (one byte per cell) still hold the whole grid.
MAX_UPSAMPLED_CELLS = 1 << 28
OVERVIEW_MAX_PX = 1200  # hd choice: longest side of the overview's hillshade, pixels


# --- the run ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DetectRun:
    """What detection needs from a trained run.

    ``labeling`` is the labelling entry the run was trained on (lander, DEM grid, label convention);
    ``dem_shape`` (rows, cols) and ``spacing_m`` (metres/pixel) are its DEM grid; ``dataset`` the
    training dataset (None when it is not present any more); ``data`` the run record's training data
    (``hdnet.run_record``; None for a model made in code).
    """

    checkpoint: Path
    model: BayesianSegNet = field(repr=False)
    header: CheckpointHeader
    train_sigma_m: float
    input_spec: InputSpec
    labels: str
    labeling: LabelingEntry = field(repr=False)
    lander: Lander
    dem_shape: tuple[int, int]
    spacing_m: float
    dataset: Path | str | None
    data: TrainingData | None = field(default=None, repr=False)

    @property
    def input_size(self) -> int | None:
        """Network input size in pixels (square), None when DEMs are padded instead of resized."""
        return self.input_spec.input_size

    @property
    def train_noise(self) -> TrainingNoise:
        """The run's training noise levels (one level for runs that do not record them)."""
        return self.data.train_noise if self.data is not None else TrainingNoise.single(self.train_sigma_m)

    @property
    def training_datasets(self) -> tuple[Path | str, ...] | None:
        """Every dataset the run was trained on (its dataset and each ``--also`` one), or None when
        one of them is not present any more."""
        if self.data is None:  # a run made in code: its dataset alone
            return None if self.dataset is None else (self.dataset,)
        if not self.data.datasets or self.data.missing_datasets():
            return None
        return tuple(dataset_at(d) for d in self.data.datasets)

    @property
    def recorded_dataset(self) -> str | None:
        """The training dataset's path as the run records it (present or not)."""
        return None if self.data is None else self.data.dataset


def load_run(run_dir: str | os.PathLike, device: torch.device | str | None = None) -> DetectRun:
    """The run at ``run_dir`` (a run directory or a checkpoint file), ready for detection, its model
    on ``device`` (a torch device or its name; None: CUDA when available, else the CPU).

    The labelling entry comes from the run's config (runs trained since it is recorded) or, for
    older runs, from the manifest of the dataset the run was trained on.

    Raises:
        HdNetError: no such run, a checkpoint of another model or schema, an old run whose dataset
            (which names its lander) is not present.
    """
    path = checkpoint_path(run_dir)
    if not Path(run_dir).exists():
        raise HdNetError(f"run {run_dir} does not exist.")
    trained = TrainedRun.load(path, _device(device))
    data = trained.data
    labels = data.labels
    dataset = dataset_at(data.dataset) if data.dataset else None
    if dataset is not None and not has_manifest(dataset, MANIFEST_NAME):
        dataset = None
    labeling = data.labeling
    if labeling is None:
        if dataset is None:
            raise HdNetError(
                f"{path} does not record its lander and its dataset {data.dataset} is not present; "
                "retrain it with this hd or restore the dataset."
            )
        labeling = find_labeling(dataset, labels).without_shards()
    shape = data.dem_shape or (labeling.dem.rows, labeling.dem.cols)
    return DetectRun(
        path,
        trained.model,
        trained.header,
        data.train_sigma_m,
        data.input,
        labeling.name,
        labeling,
        labeling.lander,
        (int(shape[0]), int(shape[1])),
        labeling.spacing_m,
        dataset,
        data,
    )


def _warn_if_unfinished(run: DetectRun) -> None:
    """Warn (``HdWarning``) when the run's training stopped before its last epoch."""
    unfinished = unfinished_training(run.checkpoint, run.header.epoch)
    if unfinished is not None:
        warnings.warn(unfinished, HdWarning, stacklevel=3)


def _device(device: torch.device | str | None) -> torch.device:
    """``device`` as a torch device; None: CUDA when available, else the CPU."""
    if device is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


def network_input(dem_m: np.ndarray, run: DetectRun, sigma_m: float | None = None) -> torch.Tensor:
    """(1, C, H, W) network input of one DEM (metres, scan frame, NaN holes), prepared exactly as in training.

    ``hdnet.inputs.network_input`` with the run's ``InputSpec``: the call ``HazardDataset`` makes;
    ``sigma_m`` (metres) is the DEM's noise level, for runs that take it as an input (default: the
    run's reference level).
    """
    level = run.train_sigma_m if sigma_m is None else sigma_m
    return prepare_input(np.asarray(dem_m, np.float32), run.input_spec, level)[None].contiguous()


def network_output(mean_probs: torch.Tensor, run: DetectRun) -> torch.Tensor:
    """Network-grid mean softmax (N, C, H, W) back to the DEM grid (``hdnet.data.to_dem_grid``)."""
    return to_dem_grid(mean_probs, run.dem_shape, run.input_size)


def baseline_p_safe(dem_m: np.ndarray, spacing_m: float, sigma_m: float, labeling: LabelingEntry) -> np.ndarray:
    """The ALHAT P(safe) baseline of a DEM (float32, NaN where invalid) for a run's labelling entry.

    The one place where detection calls the baseline: the labelling entry says which lander (and
    label convention) the run was trained with.
    """
    return safety_probability(dem_m, spacing_m, sigma_m, labeling.lander)


def overlap_px(lander: Lander, spacing_m: float) -> int:
    """Minimum tile overlap (cells): the lander diameter plus the invalid border on both sides.

    The cut between tiles is the middle of the overlap, so every kept cell is at least one lander
    radius plus the border band (cells whose labels were invalid in training) from its tile's edge.
    """
    return int(math.ceil(lander.diameter_m / spacing_m - 1e-9)) + 2 * geometry(lander, spacing_m).band_px


# --- inputs ----------------------------------------------------------------------------------------
class _Terrain:
    """The grid detection runs on: heights by window, georeferencing, provenance."""

    shape: tuple[int, int]
    transform: Affine
    crs_wkt: str
    spacing_xy_m: tuple[float, float]
    scan_frame: bool  # heights are already in a scan frame (no re-referencing)
    provenance: DetectInputJson

    def read(self, row0: int, col0: int, rows: int, cols: int) -> np.ndarray:
        raise NotImplementedError

    def hillshade_heights(self, max_px: int) -> tuple[np.ndarray, float]:
        """Heights decimated to at most ``max_px`` per side (metres, NaN invalid) and their cell size (m)."""
        raise NotImplementedError

    def close(self) -> None:
        pass


class _DtmTerrain(_Terrain):
    """A DTM file, or the cells of it that a window (``--window``, map metres) overlaps: then the grid
    is those cells alone (reads outside them are NaN), as if the DTM had been cut to them."""

    def __init__(self, path: Path, run: DetectRun, upsample: bool = False, window: MapWindow | None = None) -> None:
        with DTM.open(path) as probe:
            info = probe.info
        sx, sy = info.spacing_m
        if abs(sx - sy) > SPACING_TOLERANCE * min(sx, sy):
            raise TerrainError(
                f"{info.path}: has non-square cells ({sx:g} m x {sy:g} m); warp it to square cells "
                "first, e.g. with gdalwarp -tr"
            )
        coarse = max(sx, sy)
        self.path = Path(info.path)
        self.upsampled: UpsampledJson | None = None
        self.window = window
        self.dtm: DTM | UpsampledDTM
        if coarse > run.spacing_m * (1.0 + SPACING_TOLERANCE):
            if not upsample:
                raise TerrainError(
                    f"{info.path}: its {coarse:g} m cells are coarser than the run's DEM spacing "
                    f"({run.spacing_m:g} m/px); pass --upsample to interpolate it bilinearly between its cell "
                    "centres (how a ray caster sees a mesh through its posts; no rocks below its resolution), "
                    "or map a finer DTM, e.g. one made by `hd make-dtm --base` (with rocks)"
                )
            self.scale = 1.0
            source = self._window_cells(info)  # the window's cells of the coarse DTM, upsampled alone
            self.dtm = self._upsampled(path, info, run.spacing_m, source)
            self.cells = WindowCells(0, 0, self.dtm.info.rows, self.dtm.info.cols, source.clipped)
        else:
            self.scale = min(1.0, coarse / run.spacing_m)  # spacing / scale = the run's spacing
            self.dtm = DTM.open(path, scale=self.scale)
        try:
            if self.upsampled is None:
                self.cells = self._window_cells(self.dtm.info)
            self._describe(info, run)
        except BaseException:
            self.dtm.close()
            raise

    def _window_cells(self, info: Any) -> WindowCells:
        """The cells of the grid ``info`` describes that the window overlaps (all of them without a
        window), with a warning when the window reaches past the grid and is clipped to it."""
        if self.window is None:
            return WindowCells(0, 0, info.rows, info.cols)
        cells = window_cells(self.window, info.transform, info.rows, info.cols, info.name)
        if cells.clipped:
            warnings.warn(
                f"the window {self.window.text()} reaches past {info.name} "
                f"({bounds_text(grid_bounds(info.transform, info.rows, info.cols))}): only the part inside it is "
                f"mapped, {bounds_text(cells.bounds(info.transform))}",
                HdWarning,
                stacklevel=2,
            )
        return cells

    def _upsampled(self, path: Path, info: Any, spacing_m: float, source: WindowCells) -> UpsampledDTM:
        """The cells ``source`` of the DTM at ``path`` (all of them without a window) interpolated
        bilinearly to ``spacing_m`` (metres/pixel) over the same extent, window by window as the
        tiles read them (``lidarsim.upsampled``: only the coarse cells are held)."""
        sx, sy = info.spacing_m
        rows, cols = (
            max(1, int(source.rows * sy / spacing_m + 1e-9)),
            max(1, int(source.cols * sx / spacing_m + 1e-9)),
        )
        if rows * cols > MAX_UPSAMPLED_CELLS:
            raise TerrainError(
                f"{info.path}: upsampled to {spacing_m:g} m/px it would be {rows} x {cols} cells, more than "
                f"hd's {MAX_UPSAMPLED_CELLS:,} for --upsample; map it in parts (--window, or gdal_translate -srcwin)"
            )
        dtm = UpsampledDTM(path, source, spacing_m)
        self.upsampled = {
            "method": "bilinear between cell centres (lidarsim.base_relief.resample_bilinear)",
            "source_spacing_m": [sx, sy],
            "spacing_m": spacing_m,
            "source_sha256": dtm.sha256(),
        }
        return dtm

    def _describe(self, info: Any, run: DetectRun) -> None:
        sx, sy = info.spacing_m
        i = self.dtm.info
        self.shape = (self.cells.rows, self.cells.cols)
        self.transform = Affine(*self.cells.transform(i.transform))
        self.crs_wkt = i.crs_wkt
        self.spacing_xy_m = (float(i.spacing_m[0]), float(i.spacing_m[1]))
        self.scan_frame = False
        self.provenance = {
            "kind": "dtm",
            "path": str(self.path),
            "name": i.name,
            "sha256": self.dtm.sha256(),
            "driver": i.driver,
            "source_spacing_m": [sx, sy],
            "scale": self.scale,
            "source_transform": list(info.transform),
            "source_shape": [info.rows, info.cols],
        }
        if self.upsampled is not None:
            self.provenance["upsampled"] = self.upsampled
        if self.window is not None:
            self.provenance["window"] = {
                "requested": list(self.window),
                "mapped": list(grid_bounds(tuple(self.transform)[:6], *self.shape)),
                "clipped": self.cells.clipped,
                "dtm_bounds": list(grid_bounds(info.transform, info.rows, info.cols)),
            }
        self._check_fits(run)

    def _check_fits(self, run: DetectRun) -> None:
        """Refuse a DTM with no lander-footprint-sized square of valid cells (as build-dataset does for scans)."""
        name = self.dtm.info.name
        what, fix = "the DTM", "use a larger DTM"
        if self.window is not None:
            source = self.provenance
            bounds = bounds_text(grid_bounds(tuple(source["source_transform"]), *source["source_shape"]))
            name = f"the window {self.window.text()} of {name}"
            what, fix = "the window", f"widen the window (the DTM's bounds: {bounds})"
        c, coarse = self.cells, max(self.spacing_xy_m)
        part = None if self.window is None else (c.row0, c.col0, *self.shape)
        # "every cell is nodata" from here (of the window's cells: only they are read)
        dtm = self.dtm
        if isinstance(dtm, UpsampledDTM):  # its own cells, at the run's spacing
            _check_footprint_fits(run, name, what, fix, self.shape, self.spacing_xy_m, dtm.valid_cells)
        else:
            _check_footprint_fits(
                run, name, what, fix, self.shape, self.spacing_xy_m, lambda: dtm.validity_overview(coarse, part)[0]
            )

    def read(self, row0: int, col0: int, rows: int, cols: int) -> np.ndarray:
        """Heights of cells of the grid (the window's own, without a window the DTM's); NaN outside it."""
        out = np.full((rows, cols), np.nan, np.float64)
        h, w = self.shape
        r0, r1, c0, c1 = max(row0, 0), min(row0 + rows, h), max(col0, 0), min(col0 + cols, w)
        if r0 < r1 and c0 < c1:
            out[r0 - row0 : r1 - row0, c0 - col0 : c1 - col0] = self.dtm.read(
                r0 + self.cells.row0, c0 + self.cells.col0, r1 - r0, c1 - c0
            )
        return out

    def hillshade_heights(self, max_px: int) -> tuple[np.ndarray, float]:
        rows, cols = self.shape
        factor = min(1.0, max_px / max(rows, cols))
        if factor >= 1.0:
            return self.read(0, 0, rows, cols), float(np.mean(self.spacing_xy_m))
        if self.window is not None or isinstance(self.dtm, UpsampledDTM):  # the window's cells, decimated in one read
            c = self.cells
            heights = self.dtm.preview(max_px, c.row0, c.col0, rows, cols)
            return heights, float(np.mean(self.spacing_xy_m)) * rows / heights.shape[0]
        with DTM.open(self.path, scale=self.scale * factor) as small:
            return small.read(0, 0, small.info.rows, small.info.cols), float(np.mean(small.info.spacing_m))

    def close(self) -> None:
        self.dtm.close()


def _check_footprint_fits(
    run: DetectRun,
    name: str,
    what: str,
    fix: str,
    shape: tuple[int, int],
    spacing_xy_m: tuple[float, float],
    validity: Callable[[], np.ndarray],
) -> None:
    """Refuse a grid of ``shape`` cells (``spacing_xy_m`` metres) with no lander-footprint-sized square
    of valid cells (as build-dataset does for scans); ``validity()`` gives its valid cells (bool, at
    any resolution that keeps "no valid cell" true).

    Raises:
        TerrainError: naming ``name``, ``what`` it is ("the DTM", "the window", "the height array")
            and ``fix``, what to do.
    """
    need = 2 * geometry(run.lander, run.spacing_m).band_px + 1
    rows, cols = shape
    sx, sy = spacing_xy_m
    words = (
        f"{name} is too small for the lander footprint: a {run.lander.diameter_m:g} m lander needs "
        f"{need} x {need} cells of valid terrain at {run.spacing_m:g} m/px"
    )
    if rows < need or cols < need:
        raise TerrainError(
            f"{words}, {what} covers {cols * sx:.0f} m x {rows * sy:.0f} m ({rows} x {cols} cells); {fix}"
        )
    fits = ndimage.binary_erosion(validity(), structure=np.ones((need, need), bool), border_value=0)
    if not fits.any():
        raise TerrainError(f"{words} and {what} has no such valid square; {fix}")


class _ArrayTerrain(_Terrain):
    """Heights held in memory (metres, NaN invalid) on a grid of ``transform`` (cells of ``spacing_xy_m``)."""

    def __init__(
        self,
        heights_m: np.ndarray,
        transform: Affine,
        scan_frame: bool,
        provenance: DetectInputJson,
        crs_wkt: str = "",
    ) -> None:
        self.dem = heights_m
        self.shape = (int(heights_m.shape[0]), int(heights_m.shape[1]))
        self.transform = transform
        self.crs_wkt = crs_wkt
        self.spacing_xy_m = (abs(float(transform.a)), abs(float(transform.e)))
        self.scan_frame = scan_frame
        self.provenance = provenance

    def read(self, row0: int, col0: int, rows: int, cols: int) -> np.ndarray:
        out = np.full((rows, cols), np.nan, np.float64)
        h, w = self.shape
        r0, r1, c0, c1 = max(row0, 0), min(row0 + rows, h), max(col0, 0), min(col0 + cols, w)
        if r0 < r1 and c0 < c1:
            out[r0 - row0 : r1 - row0, c0 - col0 : c1 - col0] = self.dem[r0:r1, c0:c1]
        return out

    def hillshade_heights(self, max_px: int) -> tuple[np.ndarray, float]:
        return np.asarray(self.dem, np.float64), self.spacing_xy_m[0]


def centred_transform(shape: tuple[int, int], spacing_m: float) -> Affine:
    """The scan frame's transform of a grid of ``shape`` cells of ``spacing_m`` metres: origin at the
    grid's centre, x east, y north (metres), row 0 north."""
    h, w = shape
    return Affine(spacing_m, 0.0, -w * spacing_m / 2.0, 0.0, -spacing_m, h * spacing_m / 2.0)


class _ScanTerrain(_ArrayTerrain):
    """One scan's noisy DEM at one noise level (scan frame: origin at nadir, x east, y north, metres)."""

    def __init__(self, dataset: Path | str, scan: int, sigma_m: float, labels: str | None, run: DetectRun) -> None:
        entry, paths = open_labeling(dataset, labels)
        sigmas = dataset_sigmas(paths, entry.first_sha256)
        k = sigma_index(sigmas, sigma_m)
        spacing = entry.spacing_m
        if abs(spacing - run.spacing_m) > SPACING_TOLERANCE * run.spacing_m:
            raise HdNetError(
                f"{dataset_label(dataset)}: its DEMs are at {spacing:g} m/px, the run was trained at "
                f"{run.spacing_m:g} m/px."
            )
        found = None
        all_scans: list[int] = []
        for path, shard in zip(paths, entry.shards, strict=True):
            # through the storage layer: checksum first, damaged chunks named with the scan
            with open_label_shard(dataset, shard) as reader:
                f = reader.h5
                scans = f["scan_index"][:]
                all_scans += scans.tolist()
                rows = np.flatnonzero(scans == scan)
                if rows.size:
                    r = int(rows[0])
                    found = (path, f["dem_noisy"][r, k].astype(np.float32), int(f["split"][r]), shard)
        if found is None:
            span = f"scans {min(all_scans)}..{max(all_scans)}" if all_scans else "no scans"
            raise HdNetError(f"scan {scan} is not in {dataset_label(dataset)} ({span}).")
        dem = found[1]
        manifest = read_manifest(dataset)
        origin = _origin_map(dataset, found[3], scan)
        provenance: DetectInputJson = {
            "kind": "scan",
            "dataset": dataset_key(dataset),
            "manifest_sha256": manifest_sha256(dataset, MANIFEST_NAME),
            "labels": entry.name,
            "scan_index": scan,
            "split": ("train", "val", "test")[found[2]],
            "sigma_m": sigmas[k],
            "label_shard": Path(found[3].path).name,  # the manifest's name (a URL's query is no part of it)
            "origin_map": origin,
            "dtm_crs_wkt": manifest.get("dtm", {}).get("crs_wkt", ""),
            "frame": (
                "scan frame: origin at the nadir point on the reference height (origin_map); x east, y north; metres"
            ),
        }
        if "mosaic" in manifest:  # a descent-mosaics dataset (hd mosaic): the scan is a mosaic of frames
            provenance["mosaic_frames"] = len(manifest["mosaic"]["frames"])
        super().__init__(dem, centred_transform(dem.shape, spacing), True, provenance)
        self.sigma_m = sigmas[k]
        self.labels = entry.name
        self.dataset = dataset_at(dataset)
        self.source_sha256 = found[3].source_sha256


def _origin_map(dataset: Path | str, label_shard: LabelShardEntry, scan: int) -> list[float]:
    """Map coordinates (metres) of a scan's frame origin, from the scan shard behind its label shard
    (through the storage layer: checksum first; damage is an error naming the file and the scan)."""
    source: ShardRefJson = {"path": label_shard.source_path, "sha256": label_shard.source_sha256}
    with open_scan_shard(dataset, source) as reader:
        rows = np.flatnonzero(reader.h5["scan_index"][:] == scan)
        if not rows.size:
            raise HdNetError(f"{source['path']}: holds no scan {scan}, which its label shard lists.")
        return [float(v) for v in reader.h5["origin_map"][int(rows[0])]]


def trained_on(run: DetectRun, dataset: Path | str, source_sha256: str) -> bool:
    """True when the run was trained on the scans of ``dataset`` whose scan shard has ``source_sha256``:
    ``dataset`` is a training dataset of the run (the same directory, or the same manifest), or a
    present training dataset lists a scan shard of those bytes (a copy or a rebuild of it)."""
    data = run.data
    recorded = data.datasets if data is not None else ((str(run.dataset),) if run.dataset is not None else ())
    if dataset_key(dataset) in {dataset_key(d) for d in recorded}:
        return True
    if data is not None:
        sums = {data.manifest_sha256, *(a.manifest_sha256 for a in data.also)} - {None}
        if manifest_sha256(dataset, MANIFEST_NAME) in sums:
            return True
    for d in recorded:
        if not has_manifest(d, MANIFEST_NAME):
            continue
        try:
            shards = read_manifest(d)["shards"]
        except HdError:  # a training dataset damaged since: it says nothing of this scan
            continue
        if any(entry.get("sha256") == source_sha256 for entry in shards):
            return True
    return False


# --- options -----------------------------------------------------------------------------------------
def _fixed_threshold(spec: str) -> float | None:
    """H_t of a ``nats:H`` spec (H >= 0 nats, 'inf' allowed), or None for the calibrated specs."""
    parsed = parse_threshold_spec(spec)
    return None if parsed.rule.calibrated or parsed.value is None else float(parsed.value)


def is_detect_file(name: str) -> bool:
    """True for the names of the files ``hd detect`` writes (its output's own files)."""
    return name in OUTPUT_FILES


def output_dir(out: str | os.PathLike, inputs: dict[str, str | os.PathLike | None]) -> OutputDir:
    """The output transaction of ``hd detect`` (``detect.json`` marks its output)."""
    return OutputDir(out, what="detect", marker="detect.json", owns=is_detect_file, inputs=inputs)


# --- sites -----------------------------------------------------------------------------------------
class _RasterWindows:
    """Band 1 of an open raster, read by 2-D slicing (``reader[r0:r1, c0:c1]``), window by window."""

    def __init__(self, src: Any) -> None:
        self.src = src

    def __getitem__(self, index: tuple[slice, slice]) -> np.ndarray:
        rows, cols = index
        return self.src.read(1, window=Window(cols.start, rows.start, cols.stop - cols.start, rows.stop - rows.start))


def _sites_csv(sites: list[Site]) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(SITE_COLUMNS)
    for s in sites:
        writer.writerow(
            [
                s.rank,
                f"{s.x:.3f}",
                f"{s.y:.3f}",
                f"{s.p_safe:.6f}",
                f"{s.entropy_max:.6f}",
                f"{s.clearance_m:.3f}",
                "" if not math.isfinite(s.baseline_p_safe) else f"{s.baseline_p_safe:.6f}",
                f"{s.touchdown_p_safe:.6f}",
            ]
        )
    return buf.getvalue()


def _sites_geojson(sites: list[Site], crs_wkt: str) -> SitesGeoJson:
    collection: SitesGeoJson = {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": [round(s.x, 3), round(s.y, 3)]},
                "properties": json_plain(s.columns()),
            }
            for s in sites
        ],
    }
    if crs_wkt:
        from rasterio.crs import CRS

        epsg = CRS.from_wkt(crs_wkt).to_epsg()
        if epsg:  # GeoJSON 2008 named CRS: the coordinates are in the DTM's CRS, not WGS 84
            collection["crs"] = {"type": "name", "properties": {"name": f"urn:ogc:def:crs:EPSG::{epsg}"}}
    return collection


# --- the detection ---------------------------------------------------------------------------------
@dataclass
class DetectResult:
    """What ``detect`` wrote and measured (``detect.json`` holds ``info``)."""

    out_dir: Path
    sites: list[Site]
    threshold_nats: float
    counts: dict[str, int]
    timings_s: dict[str, float]
    info: DetectInfoJson = field(repr=False)

    def summary(self) -> str:
        valid = sum(self.counts[k] for k in ("safe", "unsafe", "uncertain"))
        pct = {
            k: 100.0 * self.counts[k] / valid if valid else 0.0
            for k in ("safe", "unsafe", "uncertain", "baseline_safe")
        }
        t = "unbounded" if not math.isfinite(self.threshold_nats) else f"{self.threshold_nats:.4f} nats"
        t += recorded_score(self.info.get("threshold", {})).qualifier
        rule = self.info.get("site_rule", {})
        nav, margin = float(rule.get("nav_sigma_m") or 0.0), float(rule.get("margin_m") or 0.0)
        best = (
            (
                f"; best site #1 at ({self.sites[0].x:.1f}, {self.sites[0].y:.1f}): aim-point P(safe) "
                f"{self.sites[0].p_safe:.3f}"
                + ("" if nav > 0 else " (the ranking)")
                + f", clearance {self.sites[0].clearance_m:.1f} m"
                + (
                    f", expected touchdown P(safe) {self.sites[0].touchdown_p_safe:.3f} under navigation 1σ {nav:g} m "
                    "(the ranking; it may exceed the aim point's where the dispersion reaches safer ground)"
                    if nav > 0
                    else ""
                )
            )
            if self.sites
            else "; no site: no lander footprint is wholly safe and certain"
        )
        disk = " around the lander's disk" if margin > 0 else " (the lander's disk alone)"
        best += f"; site margin {margin:g} m{disk}"
        th = self.info.get("threshold", {})
        if th.get("unreachable"):  # risk:ALPHA below 1/(n+1): every cell uncertain by construction
            t += (
                f", {th.get('spec')} unreachable with {th.get('calibration_images')} validation images: "
                f"it needs {th.get('needs_images')}"
            )
        return (
            f"{self.out_dir}: {pct['safe']:.1f}% safe, {pct['unsafe']:.1f}% unsafe, {pct['uncertain']:.1f}% uncertain "
            f"of {valid} valid cells (H_t {t}; the ALHAT baseline calls {pct['baseline_safe']:.1f}% safe); "
            f"{len(self.sites)} site(s){best}; {self.timings_s['total']:.1f} s"
        )


@dataclass(frozen=True)
class DetectMaps:
    """The hazard maps and landing sites of one terrain, in memory (:func:`detect_dem`): what ``hd
    detect`` writes as files, as arrays.

    Every map is a (rows, cols) array on the grid of ``transform`` (cells of the run's DEM spacing),
    NaN (``safety``: 255) where invalid, i.e. in the border band and where the lander footprint
    touches a cell without height:

    * ``p_safe``: float32, the MC-dropout mean P(safe), in [0, 1];
    * ``entropy_nats``: float32, the predictive entropy, nats (0 certain, at most ln 2);
    * ``mutual_information_nats``: float32, the MC-dropout samples' mutual information, nats;
    * ``safety``: uint8, 0 unsafe, 1 safe, 2 uncertain (the score ``uncertainty`` at or above
      ``threshold_nats``), 255 invalid (``hdnet.sites``);
    * ``baseline_p_safe``: float32, the ALHAT P(safe) baseline at the noise level ``sigma_m``
      (metres); the baseline calls a cell safe where it is >= 0.5.

    ``sites``: the ranked landing sites (``select_sites``; x, y in the grid's coordinates, metres);
    ``threshold_nats``: H_t, nats (inf: unbounded); ``uncertainty``: the score H_t applies to
    (``entropy`` or ``mutual-information``); ``transform``: the grid's affine transform (column, row
    of a cell corner -> x, y in metres); ``threshold``: how H_t was found (``detect.json``'s record).
    """

    p_safe: np.ndarray = field(repr=False)
    entropy_nats: np.ndarray = field(repr=False)
    mutual_information_nats: np.ndarray = field(repr=False)
    safety: np.ndarray = field(repr=False)
    baseline_p_safe: np.ndarray = field(repr=False)
    sites: list[Site]
    threshold_nats: float
    uncertainty: str
    sigma_m: float
    transform: Affine
    threshold: ThresholdJson = field(default_factory=lambda: ThresholdJson(), repr=False)

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) of every map."""
        return (int(self.safety.shape[0]), int(self.safety.shape[1]))

    @property
    def spacing_m(self) -> float:
        """Cell size, metres/pixel."""
        return abs(float(self.transform.a))

    @property
    def valid(self) -> np.ndarray:
        """Bool map of the valid cells (all but the invalid ones)."""
        return self.safety != SAFETY_INVALID

    @property
    def safe_and_certain(self) -> np.ndarray:
        """Bool map of the cells the network calls safe with an uncertainty below H_t (``safety == 1``)."""
        return self.safety == SAFETY_SAFE

    @property
    def uncertain(self) -> np.ndarray:
        """Bool map of the cells whose uncertainty is at or above H_t (``safety == 2``)."""
        return self.safety == SAFETY_UNCERTAIN

    @property
    def baseline_safe(self) -> np.ndarray:
        """Bool map of the cells the ALHAT baseline calls safe (P(safe) >= 0.5)."""
        return np.nan_to_num(self.baseline_p_safe, nan=0.0) >= BASELINE_THRESHOLD

    @property
    def uncertainty_nats(self) -> np.ndarray:
        """The score H_t applies to (``entropy_nats`` or ``mutual_information_nats``), nats."""
        return uncertainty_score(self.uncertainty).of(self)

    @property
    def counts(self) -> dict[str, int]:
        """Cells per safety code and those the baseline calls safe (``detect.json``'s ``counts``)."""
        counts: dict[str, int] = {}
        _add_counts(counts, self.safety, self.baseline_p_safe)
        return counts

    @property
    def safe_fraction(self) -> float:
        """Safe-and-certain cells over valid cells (0 when no cell is valid)."""
        valid = int(self.valid.sum())
        return int(self.safe_and_certain.sum()) / valid if valid else 0.0


def detect_dem(
    run: DetectRun | str | os.PathLike,
    heights_m: np.ndarray,
    *,
    transform: Affine | tuple[float, ...] | None = None,
    scan_frame: bool = False,
    sigma_m: float | None = None,
    mc_samples: int = defaults.MC_SAMPLES,
    threshold: str = defaults.THRESHOLD_SPEC,
    calibrate: str = "reference",
    uncertainty: str = ENTROPY.name,
    n_sites: int = 10,
    nav_sigma_m: float = 0.0,
    seed: int = 0,
    batch_size: int = 8,
    progress: Callable[[int, int], None] | None = None,
    layout: str = "channels-last",
    site_margin_m: float = 0.0,
) -> DetectMaps:
    """Hazard maps and ranked landing sites of a height array, in memory: ``hd detect`` without files.

    ``run``: a run loaded by :func:`load_run` (or its directory, loaded here). ``heights_m``: a 2-D
    array of heights (metres, row 0 north, NaN or inf where there is no data) on the run's DEM grid
    (``run.spacing_m`` metres/pixel), of any size: it is mapped in tiles of the run's DEM size, as
    ``hd detect`` maps a DTM. ``transform``: the array's affine transform (column, row -> x, y in
    metres; an ``Affine`` or its six numbers, as ``lidarsim.DTMInfo.transform``), whose cells must
    be the run's spacing (within 2 %); None: the scan frame, origin at the array's centre, x east, y
    north. ``scan_frame``: True for heights in a scan frame (a dataset's
    DEMs, ``hdlabels.LabeledScan``), taken as they are; False for map heights (a DTM's), each tile
    then taken relative to its mean height, as ``hd detect --dtm`` does.

    The other keywords are those of :func:`detect` (``DetectSettings``): ``sigma_m`` (metres) the
    sensor's noise level (default: the run's training sigma), for the baseline and the runs that
    take it as an input; ``threshold`` a calibrated ``mean``, ``quantile:Q`` or ``risk:ALPHA``
    (calibrated on the validation split of the run's own training data, cached in the run directory
    like ``hd detect``'s) or a fixed ``nats:H``; ``uncertainty`` the score it applies to;
    ``n_sites``, ``nav_sigma_m`` and ``site_margin_m`` (metres) for the sites; ``progress`` is called with (tiles
    done, tiles total). The model runs on the device it was loaded on.

    Raises:
        HdNetError: a bad setting, an array that is not 2-D numbers, a transform of other cells than
            the run's, a calibrated threshold whose data is not present.
        TerrainError: no lander-footprint-sized square of valid cells.
    """
    settings = DetectSettings(
        mc_samples=mc_samples,
        threshold=threshold,
        sigma_m=sigma_m,
        calibrate=calibrate,
        n_sites=n_sites,
        nav_sigma_m=nav_sigma_m,
        site_margin_m=site_margin_m,
        seed=seed,
        batch_size=batch_size,
        uncertainty=uncertainty,
        layout=layout,
    )  # each value's kind and range, and the threshold's form, before the run is loaded
    heights = _height_array(heights_m)  # and the array's
    if not isinstance(run, DetectRun):
        run = load_run(run)
    _warn_if_unfinished(run)
    return map_heights(
        run,
        heights,
        settings,
        detect_threshold(run, settings),
        transform=transform,
        scan_frame=scan_frame,
        progress=progress,
    )


def detect_threshold(run: DetectRun, settings: DetectSettings) -> tuple[float, ThresholdJson]:
    """H_t (nats; inf: unbounded) and its record, as :func:`detect_dem` finds it for ``settings``: a fixed
    ``nats:H``, or calibrated (``settings.threshold``, ``calibrate``, ``uncertainty``) on the validation
    split of the run's own training data at its reference noise level or at ``settings.sigma_m`` (metres;
    default the run's training sigma). Found once, it maps any number of arrays (:func:`map_heights`).

    Raises:
        HdNetError: a calibrated threshold whose data is not present.
    """
    score = uncertainty_score(settings.uncertainty)
    sigma = run.train_sigma_m if settings.sigma_m is None else float(settings.sigma_m)
    dev = next(run.model.parameters()).device
    own = (run.training_datasets or (), run.labels)  # calibrated on the run's own training data
    s = settings
    return _threshold(run, s.threshold, *own, s.mc_samples, s.batch_size, s.seed, dev, s.calibrate, sigma, score)


def map_heights(
    run: DetectRun,
    heights_m: np.ndarray,
    settings: DetectSettings,
    threshold: tuple[float, ThresholdJson],
    *,
    transform: Affine | tuple[float, ...] | None = None,
    scan_frame: bool = False,
    progress: Callable[[int, int], None] | None = None,
    timings: dict[str, float] | None = None,
) -> DetectMaps:
    """:func:`detect_dem` with its threshold found already (``threshold``: H_t in nats and its record,
    :func:`detect_threshold`): the maps of ``heights_m`` (metres, on the run's DEM grid) and their sites,
    with the same MC-dropout draws (``settings.seed``) and the same site rule. ``timings``, when given,
    gets the seconds spent on the maps (``"map"``) and on choosing the sites (``"sites"``).

    Raises:
        HdNetError: an array that is not 2-D numbers, a transform of other cells than the run's.
        TerrainError: no lander-footprint-sized square of valid cells.
    """
    heights = _height_array(heights_m)
    terrain, grid = _array_terrain(run, heights, transform, scan_frame)
    return _maps_of_array(run, terrain, grid, settings, threshold, progress, timings if timings is not None else {})


def _maps_of_array(
    run: DetectRun,
    terrain: _ArrayTerrain,
    grid: Affine,
    s: DetectSettings,
    threshold: tuple[float, ThresholdJson],
    progress: Callable[[int, int], None] | None,
    timings: dict[str, float],
) -> DetectMaps:
    """``detect_dem``'s steps 3-5 on the array's terrain at the threshold found (H_t, its record): the maps
    in memory and the sites (the seconds of each into ``timings``: ``"map"``, ``"sites"``)."""
    score = uncertainty_score(s.uncertainty)
    sigma = run.train_sigma_m if s.sigma_m is None else float(s.sigma_m)
    dev = next(run.model.parameters()).device
    h_t, threshold_info = threshold
    t0 = time.perf_counter()
    plan = TilePlan.make(terrain.shape, run.dem_shape, overlap_px(run.lander, run.spacing_m))
    maps = _maps_in_memory(
        terrain, run, plan, h_t, sigma, s.mc_samples, s.batch_size, s.seed, dev, progress, score, layout=s.layout
    )
    t1 = time.perf_counter()
    layers = (maps["safety"], maps["p_safe"], maps["entropy_nats"], maps["baseline_p_safe"])
    sites = select_sites(*layers, grid, terrain.spacing_xy_m, run.lander, s.n_sites, s.nav_sigma_m, s.site_margin_m)
    timings["map"], timings["sites"] = t1 - t0, time.perf_counter() - t1
    return DetectMaps(
        **maps,
        sites=sites,
        threshold_nats=h_t,
        uncertainty=score.name,
        sigma_m=sigma,
        transform=grid,
        threshold=threshold_info,
    )


def _array_terrain(
    run: DetectRun, heights: np.ndarray, transform: Affine | tuple[float, ...] | None, scan_frame: bool
) -> tuple[_ArrayTerrain, Affine]:
    """Step 1 of ``detect_dem``: the height array as a terrain on its grid (``transform``, default the scan
    frame centred on it), checked: cells of the run's spacing, room for one lander footprint.

    Raises:
        HdNetError: a transform of other cells than the run's.
        TerrainError: no lander-footprint-sized square of valid cells.
    """
    grid = centred_transform(heights.shape, run.spacing_m) if transform is None else Affine(*list(transform)[:6])
    _check_grid(grid, run)
    terrain = _ArrayTerrain(heights, grid, scan_frame, {"kind": "array"})
    where = ("the height array", "the height array", "give a larger one")
    _check_footprint_fits(run, *where, terrain.shape, terrain.spacing_xy_m, lambda: np.isfinite(heights))
    return terrain, grid


def _height_array(heights_m: Any) -> np.ndarray:
    """``heights_m`` as a 2-D float array with NaN where it held NaN or inf.

    Raises:
        HdNetError: not a 2-D array of numbers.
    """
    heights = np.asarray(heights_m)
    if heights.ndim != 2 or heights.dtype.kind not in "fiu":
        raise HdNetError(
            f"heights_m must be a 2-D array of heights in metres, got {heights.dtype} of shape {heights.shape}."
        )
    heights = heights.astype(np.float32 if heights.dtype == np.float32 else np.float64, copy=False)
    if np.isinf(heights).any():
        heights = np.where(np.isfinite(heights), heights, np.nan)
    return heights


def _check_grid(transform: Affine, run: DetectRun) -> None:
    """Refuse a grid that is rotated or whose cells are not the run's DEM spacing (within 2 %).

    Raises:
        HdNetError: naming both spacings.
    """
    sx, sy = abs(float(transform.a)), abs(float(transform.e))
    if transform.b != 0.0 or transform.d != 0.0:
        raise HdNetError("the transform is rotated; give heights on a north-up grid (row 0 north).")
    if max(abs(sx - run.spacing_m), abs(sy - run.spacing_m)) > SPACING_TOLERANCE * run.spacing_m:
        raise HdNetError(
            f"the heights' cells are {sx:g} m x {sy:g} m, the run's DEM spacing is {run.spacing_m:g} m/px; "
            "resample them to it first (e.g. lidarsim.DTM.open(path, scale=...))."
        )


def detect(
    run_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    settings: DetectSettings | None = None,
    *,
    dtm: str | os.PathLike | None = None,
    dataset: str | os.PathLike | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> DetectResult:
    """Hazard maps and ranked landing sites of a DTM (``dtm``) or of one scan (``dataset`` + ``settings.scan``)
    as ``settings`` says (default: ``DetectSettings()``; each field's meaning, unit and range are its metadata,
    ``hdnet.detect_settings``).

    ``settings.upsample``: a DTM coarser than the run's DEM spacing is interpolated bilinearly to it (recorded
    in ``detect.json`` under ``input.upsampled``) instead of being refused.

    ``settings.window`` (with ``dtm``): the map rectangle (metres in the DTM's CRS) to map: the cells it
    overlaps (``lidarsim.map_window``) are read and mapped as if they were the whole DTM (the maps' grid,
    the tiling and the sites are the window's), and ``detect.json`` records it under ``input.window``; a
    window reaching past the DTM is clipped to it with a warning.

    ``settings.sigma_m`` (metres): the baseline's DEM noise (default: the run's training sigma); with a scan,
    also the noise level of the DEM taken. ``settings.threshold``: ``mean``, ``quantile:Q``, ``risk:ALPHA``
    (calibrated on the validation split at the training sigma of the run's dataset, or of ``dataset`` with a
    scan, as ``hd eval`` does) or ``nats:H`` (fixed); ``settings.calibrate``: ``reference`` (at the run's
    reference noise level) or ``each`` (at the sensor's ``sigma_m``, guarded above the run's training levels;
    ``hd eval --calibrate``); ``settings.uncertainty``: the score H_t applies to (``entropy``, the paper's, or
    ``mutual-information``: ``hdnet.uncertainty``; calibrated on that score of the validation split;
    ``mutual_information.tif`` is written either way). ``progress`` is called with (tiles done, tiles total).
    Runs that take the noise level as an input receive ``sigma_m``. ``settings.nav_sigma_m`` (metres, 1-sigma
    per horizontal axis): the navigation dispersion the sites are ranked with (``select_sites``; recorded in
    ``detect.json`` under ``site_rule``).

        Raises:
            HdNetError / TerrainError: bad options, a missing or foreign run, an unusable DTM (geographic
            CRS, coarser than the run's spacing, smaller than one lander footprint, all nodata), a scan
            not in the dataset. Nothing is written then.
            StorageError / OutputExistsError: an ``out_dir`` that is, holds or lies inside an input (the
            run, its checkpoint or dataset, the DTM, the dataset), that holds an earlier output without
            ``overwrite`` or anything else, or that another process is writing.
    """
    t_start = time.perf_counter()
    settings = settings if settings is not None else DetectSettings()
    spec = parse_threshold_spec(settings.threshold) if _fixed_threshold(settings.threshold) is None else None
    settings.check_inputs(dtm, dataset)
    # the paths, the labelling and the window, before the run is loaded
    check_inputs(run_dir, dataset, settings.labels, dtm=dtm, window=settings.window)
    output = output_dir(out_dir, {"the run": run_dir, "the DTM": dtm, "the dataset": dataset})
    output.check_place()  # a usable path that is no input, before the run is even loaded
    dev = _device(settings.device or None)
    run = load_run(run_dir, dev)
    _warn_if_unfinished(run)
    output.add_inputs({"the checkpoint": run.checkpoint, "the run's dataset": run.dataset})
    out = output.check(settings.overwrite)
    baseline_sigma = run.train_sigma_m if settings.sigma_m is None else float(settings.sigma_m)
    terrain, calib_dirs, calib_labels = _open_terrain(
        run, dtm, dataset, settings.scan, settings.labels, baseline_sigma, settings.upsample, settings.window
    )
    if isinstance(terrain, _ScanTerrain):
        baseline_sigma = terrain.sigma_m
        _warn_if_seen(run, terrain, settings.scan, dataset)
    try:
        _check_calibration_data(run, spec, calib_dirs)
        plan = TilePlan.make(terrain.shape, run.dem_shape, overlap_px(run.lander, run.spacing_m))
        with output.open(settings.overwrite) as tmp:
            result = _detect_into(
                tmp, out, run, terrain, plan, settings, (calib_dirs, calib_labels), baseline_sigma, dev, progress
            )
            result.timings_s["total"] = round(time.perf_counter() - t_start, 3)
            result.info["timings_s"]["total"] = result.timings_s["total"]
            write_json_atomic(tmp / "detect.json", json_plain(result.info))
            output.commit()
    finally:
        terrain.close()
    return result


def _warn_if_seen(run: DetectRun, terrain: _ScanTerrain, scan: int | None, dataset: str | os.PathLike | None) -> None:
    """Step 2b: mark (and warn about) a scan of the training split of the data the run was trained on."""
    if terrain.provenance["split"] == "train" and trained_on(run, terrain.dataset, terrain.source_sha256):
        terrain.provenance["seen_in_training"] = True
        warnings.warn(
            f"scan {scan} is in the training split of {dataset_label(terrain.dataset)}, on which the run was trained: "
            "the network has seen it, so its maps are not those of unseen terrain; map a scan of the test split "
            "(or a DTM)",
            HdWarning,
            stacklevel=3,
        )


def _detect_into(
    tmp: Path,
    out: Path,
    run: DetectRun,
    terrain: _Terrain,
    plan: TilePlan,
    settings: DetectSettings,
    calibration: tuple[tuple[Path | str, ...], str],
    baseline_sigma: float,
    dev: torch.device,
    progress: Callable[[int, int], None] | None,
) -> DetectResult:
    """Step 3: the threshold, the maps, the sites and the overview written into ``tmp`` (the output's
    temporary directory), with the record of ``detect.json`` (its total time filled in by the caller)."""
    s = settings
    score = uncertainty_score(s.uncertainty)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    h_t, threshold_info = _threshold(
        run, s.threshold, *calibration, s.mc_samples, s.batch_size, s.seed, dev, s.calibrate, baseline_sigma, score
    )
    timings["calibration"] = time.perf_counter() - t0
    counts, map_timings = _write_maps(
        tmp,
        terrain,
        run,
        plan,
        h_t,
        baseline_sigma,
        s.mc_samples,
        s.batch_size,
        s.seed,
        dev,
        progress,
        score,
        layout=s.layout,
    )
    timings |= map_timings
    t0 = time.perf_counter()
    sites = _write_sites(tmp, terrain, run, s.n_sites, s.nav_sigma_m, s.site_margin_m)
    timings["sites"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    _overview(tmp, terrain, sites, run, h_t, baseline_sigma, score)
    timings["overview"] = time.perf_counter() - t0
    info = _info(
        run, terrain, plan, threshold_info, baseline_sigma, s.mc_samples, s.seed, counts, sites, timings, s.nav_sigma_m
    )
    info["network_layout"] = s.layout  # hdnet.engine: the same draws; the maps within round-off of nchw's
    info["site_rule"]["margin_m"] = s.site_margin_m
    info["site_rule"]["footprint"] = SITE_FOOTPRINTS["margin" if s.site_margin_m > 0.0 else "body"]
    return DetectResult(out, sites, h_t, counts, {k: round(v, 3) for k, v in timings.items()}, info)


def _open_terrain(
    run: DetectRun,
    dtm: str | os.PathLike | None,
    dataset: str | os.PathLike | None,
    scan: int | None,
    labels: str | None,
    sigma_m: float,
    upsample: bool = False,
    window: MapWindow | None = None,
) -> tuple[_Terrain, tuple[Path | str, ...], str]:
    """Step 2: the terrain (a DTM or its ``window``, or one scan's noisy DEM at ``sigma_m`` metres), with the datasets
    and labelling the threshold is calibrated on: the run's own training data (every ``--also``
    dataset included), as ``hd eval`` does; for a scan whose run's data is not present any more, the
    scan's dataset; for a DTM then none (only a fixed threshold can be used)."""
    own = run.training_datasets
    if dtm is not None:
        return _DtmTerrain(Path(dtm), run, upsample, window), own or (), run.labels
    if dataset is None or scan is None:  # excluded by DetectSettings.check_inputs
        raise HdNetError("give either a DTM (--dtm) or a dataset and a scan (--data with --scan).")
    lab = labels if labels is not None else preferred_labeling(dataset, run.labels)
    terrain = _ScanTerrain(dataset_at(dataset), scan, sigma_m, lab, run)
    if own is not None:
        return terrain, own, run.labels
    return terrain, (dataset_at(dataset),), terrain.labels


def _check_calibration_data(run: DetectRun, spec: ThresholdSpec | None, calib_dirs: tuple[Path | str, ...]) -> None:
    """Refuse a calibrated threshold (``spec``; None: a fixed one) without a dataset to calibrate it on."""
    if spec is not None and not calib_dirs:
        raise HdNetError(
            f"the {spec} threshold is calibrated on the run's validation split, but its dataset "
            f"{run.recorded_dataset} is not present; restore it or give "
            "a fixed threshold, e.g. --threshold nats:0.3."
        )


def _threshold(
    run: DetectRun,
    threshold: str,
    calib_dirs: tuple[Path | str, ...],
    calib_labels: str,
    mc_samples: int,
    batch_size: int,
    seed: int,
    dev: torch.device,
    calibrate: str,
    sensor_sigma_m: float,
    uncertainty: UncertaintyScore,
) -> tuple[float, ThresholdJson]:
    """Step 3: H_t (nats; inf: unbounded) of the spec ``threshold`` and its record: a fixed ``nats:H``,
    or calibrated on ``calib_dirs`` (``_calibrated_threshold``); the record states the threshold the
    maps use, whatever its source (``hdnet.threshold_cache``), and whether a ``risk:ALPHA`` is
    reachable with the validation images it was calibrated on (a warning when not)."""
    fixed = _fixed_threshold(threshold)
    spec = parse_threshold_spec(threshold) if fixed is None else None
    _check_calibration_data(run, spec, calib_dirs)
    if spec is not None:
        h_t, info = _calibrated_threshold(
            run,
            spec,
            calib_dirs,
            calib_labels,
            mc_samples,
            batch_size,
            seed,
            dev,
            calibrate,
            sensor_sigma_m,
            uncertainty,
        )
    else:
        assert fixed is not None  # exactly one of fixed and spec is set
        h_t = float(fixed)
        info = with_score({"spec": f"nats:{h_t:g}", "kind": "fixed", "parameter": h_t, "value_nats": h_t}, uncertainty)
    info = {**info, "value_nats": None if math.isinf(h_t) else h_t}
    if spec is not None and spec.rule.certifies_risk:  # also a record cached before
        info |= spec.reach(int(info["calibration_images"]))
        warn_if_unreachable(info)
    return h_t, info


def _calibrated_threshold(
    run: DetectRun,
    spec: ThresholdSpec,
    calib_dirs: tuple[Path | str, ...],
    calib_labels: str,
    mc_samples: int,
    batch_size: int,
    seed: int,
    dev: torch.device,
    calibrate: str = "reference",
    sensor_sigma_m: float | None = None,
    uncertainty: UncertaintyScore = ENTROPY,
) -> tuple[float, ThresholdJson]:
    """Step 3: the threshold (nats) of the score ``uncertainty`` calibrated on the validation splits of
    ``calib_dirs``, as ``hd eval`` does: at the run's reference noise level, or (``calibrate="each"``)
    at the sensor's ``sensor_sigma_m`` with the precision guard above the training levels."""
    sigma = run.train_sigma_m if calibrate == "reference" or sensor_sigma_m is None else sensor_sigma_m
    # Cached in the run directory (never beside a checkpoint file given on its own).
    cache = CachedThreshold(run.checkpoint.parent) if is_run_dir(run.checkpoint.parent) else None
    key = cache_key(
        run.checkpoint, calib_dirs, calib_labels, sigma, str(spec), calibrate, mc_samples, batch_size, seed, uncertainty
    )
    hit = cache.get(key) if cache is not None else None
    if hit is not None and cache is not None:
        return hit[0], {**hit[1], "cached": str(cache.path)}
    val_ds = [
        split_dataset(d, "val", sigma, labels=calib_labels, input_spec=run.input_spec, seed=seed) for d in calib_dirs
    ]
    th = validation_threshold(
        run.model,
        val_ds,
        spec,
        mc_samples=mc_samples,
        batch_size=batch_size,
        seed=seed,
        device=dev,
        uncertainty=uncertainty,
    )
    if calibrate == "each":
        th = guard_above_training(th, sigma, run.train_noise)
    info: ThresholdJson = {
        **th.info,
        "calibrate": calibrate,
        "calibration_dataset": dataset_key(calib_dirs[0]),
        "calibration_datasets": [dataset_key(d) for d in calib_dirs],
        "calibration_labels": calib_labels,
    }
    if cache is not None:
        cache.put(key, th.value_nats, info)
    return th.value_nats, info


def _write_sites(
    tmp: Path, terrain: _Terrain, run: DetectRun, n_sites: int, nav_sigma_m: float = 0.0, margin_m: float = 0.0
) -> list[Site]:
    """Step 5: the ranked landing sites from the written maps, as ``sites.csv`` and ``sites.geojson``."""
    with rasterio.open(tmp / "entropy.tif") as h_src, rasterio.open(tmp / "baseline_p_safe.tif") as b_src:
        sites = select_sites(
            _read_map(tmp / "safety.tif"),
            _read_map(tmp / "p_safe.tif"),
            _RasterWindows(h_src),
            _RasterWindows(b_src),
            terrain.transform,
            terrain.spacing_xy_m,
            run.lander,
            n_sites,
            nav_sigma_m,
            margin_m,
        )
    write_text_atomic(tmp / "sites.csv", _sites_csv(sites))
    write_json_atomic(tmp / "sites.geojson", _sites_geojson(sites, terrain.crs_wkt), indent=1)
    return sites


def _read_map(path: Path) -> np.ndarray:
    with rasterio.open(path) as src:
        return src.read(1)


# The maps of a detection, by the name of their field in DetectMaps and of their file (MAP_FILES).
MAP_FIELDS = {spec.field: spec.file for spec in MAPS}
MAP_TIMINGS = ("read", "network", "baseline")


def _map_strips(
    terrain: _Terrain,
    run: DetectRun,
    plan: TilePlan,
    h_t: float,
    sigma_m: float,
    mc_samples: int,
    batch_size: int,
    seed: int,
    dev: torch.device,
    progress: Callable[[int, int], None] | None,
    uncertainty: UncertaintyScore,
    timings: dict[str, float],
    *,
    layout: str = "channels-last",
) -> Iterator[tuple[int, dict[str, np.ndarray]]]:
    """Step 4: every row of tiles through the network and the baseline; yields, per row of tiles, the
    first grid row it owns and its maps (``MAP_FIELDS``: owned rows, every column); a cell is
    uncertain where the score ``uncertainty`` is >= ``h_t``. Adds the seconds spent to ``timings``
    (``MAP_TIMINGS``). ``hd detect`` writes the strips to its GeoTIFFs, ``detect_dem`` keeps them.
    ``layout``: the network's memory layout (``hdnet.engine``: the same draws, the same maps within
    round-off)."""
    # The baseline, like the network, takes the cells as the run's: the grid is within 2 % of that
    # spacing, and the lander's sampling (pads on grid nodes in the paper convention) is then exactly
    # the one of the training labels.
    spacing = run.spacing_m
    done = 0
    model = inference_model(run.model, layout)
    torch.manual_seed(seed)
    if progress:
        progress(0, plan.n_tiles)
    for (r_lo, r_hi), tiles in plan.strips():
        n_rows, n_cols = r_hi - r_lo, terrain.shape[1]
        strip = {spec.field: np.full((n_rows, n_cols), spec.nodata, spec.dtype) for spec in MAPS}
        for start in range(0, len(tiles), batch_size):
            batch = tiles[start : start + batch_size]
            t0 = time.perf_counter()
            dems = [terrain.read(t.row0, t.col0, t.rows, t.cols) for t in batch]
            timings["read"] += time.perf_counter() - t0
            live = [k for k, d in enumerate(dems) if np.isfinite(d).any()]
            if live:
                t0 = time.perf_counter()
                x = torch.cat([network_input(_scan_frame(dems[k], terrain), run, sigma_m) for k in live]).to(dev)
                out_grid = predict(model, x, mc_samples, layout).on_grid(lambda t: network_output(t, run).cpu())
                u_all = uncertainty.of(out_grid).numpy()
                timings["network"] += time.perf_counter() - t0
            for j, k in enumerate(live):
                tile = batch[k]
                t0 = time.perf_counter()
                base = baseline_p_safe(dems[k], spacing, sigma_m, run.labeling)
                timings["baseline"] += time.perf_counter() - t0
                crop = tile.crop
                uncertain = uncertain_mask(torch.from_numpy(u_all[j][crop]), h_t).numpy()
                cells = TileCells(out_grid, j, crop, base[crop], uncertain)
                out = (slice(None), slice(tile.own_cols[0], tile.own_cols[1]))
                for spec in MAPS:
                    strip[spec.field][out] = spec.compute(cells)
            done += len(batch)
            if progress:
                progress(done, plan.n_tiles)
        yield r_lo, strip


def _add_counts(counts: dict[str, int], safety: np.ndarray, baseline_p_safe: np.ndarray) -> None:
    """Add the cells of each safety code, and those the baseline calls safe, of a map (or a strip of one)."""
    for name, code in (
        ("unsafe", SAFETY_UNSAFE),
        ("safe", SAFETY_SAFE),
        ("uncertain", SAFETY_UNCERTAIN),
        ("invalid", SAFETY_INVALID),
    ):
        counts[name] = counts.get(name, 0) + int((safety == code).sum())
    safe = int((np.nan_to_num(baseline_p_safe, nan=0.0) >= BASELINE_THRESHOLD).sum())
    counts["baseline_safe"] = counts.get("baseline_safe", 0) + safe


def _write_maps(
    tmp: Path,
    terrain: _Terrain,
    run: DetectRun,
    plan: TilePlan,
    h_t: float,
    sigma_m: float,
    mc_samples: int,
    batch_size: int,
    seed: int,
    dev: torch.device,
    progress: Callable[[int, int], None] | None,
    uncertainty: UncertaintyScore = ENTROPY,
    *,
    layout: str = "channels-last",
) -> tuple[dict[str, int], dict[str, float]]:
    """Step 4 (``hd detect``): the maps of ``_map_strips`` written strip by strip to the five GeoTIFFs;
    returns the counts of cells per safety code and the timings (seconds)."""
    counts = {"safe": 0, "unsafe": 0, "uncertain": 0, "invalid": 0, "baseline_safe": 0}
    timings = dict.fromkeys((*MAP_TIMINGS, "write"), 0.0)
    profiles = {
        spec.file: geotiff_profile(
            terrain.shape,
            terrain.transform,
            terrain.crs_wkt,
            dtype=np.dtype(spec.dtype).name,
            nodata=spec.nodata,
        )
        for spec in MAPS
    }
    strips = _map_strips(
        terrain,
        run,
        plan,
        h_t,
        sigma_m,
        mc_samples,
        batch_size,
        seed,
        dev,
        progress,
        uncertainty,
        timings,
        layout=layout,
    )
    with _writers(tmp, profiles) as dst:
        for r_lo, strip in strips:
            t0 = time.perf_counter()
            window = Window(0, r_lo, terrain.shape[1], strip["safety"].shape[0])
            for name, values in strip.items():
                dst[MAP_FIELDS[name]].write(values, window)
            timings["write"] += time.perf_counter() - t0
            _add_counts(counts, strip["safety"], strip["baseline_p_safe"])
    return counts, timings


def _maps_in_memory(
    terrain: _Terrain,
    run: DetectRun,
    plan: TilePlan,
    h_t: float,
    sigma_m: float,
    mc_samples: int,
    batch_size: int,
    seed: int,
    dev: torch.device,
    progress: Callable[[int, int], None] | None,
    uncertainty: UncertaintyScore,
    *,
    layout: str = "channels-last",
) -> dict[str, np.ndarray]:
    """Step 4 (``detect_dem``): the maps of ``_map_strips`` as whole arrays (``MAP_FIELDS``)."""
    maps = {spec.field: np.full(terrain.shape, spec.nodata, spec.dtype) for spec in MAPS}
    timings = dict.fromkeys(MAP_TIMINGS, 0.0)
    for r_lo, strip in _map_strips(
        terrain,
        run,
        plan,
        h_t,
        sigma_m,
        mc_samples,
        batch_size,
        seed,
        dev,
        progress,
        uncertainty,
        timings,
        layout=layout,
    ):
        for name, values in strip.items():
            maps[name][r_lo : r_lo + values.shape[0]] = values
    return maps


def _scan_frame(dem_m: np.ndarray, terrain: _Terrain) -> np.ndarray:
    """A DTM window in a scan frame: minus the mean of its valid heights (scan DEMs are already in one)."""
    if terrain.scan_frame:
        return dem_m
    return dem_m - np.nanmean(dem_m)


@contextmanager
def _writers(tmp: Path, profiles: dict[str, dict[str, Any]]) -> Iterator[dict[str, GeoTiffWriter]]:
    """The maps' GeoTIFF writers: a failed write or flush (a full disk) is one StorageError naming
    the map, GDAL's own messages never printed."""
    opened: dict[str, GeoTiffWriter] = {}
    try:
        for name, profile in profiles.items():
            opened[name] = GeoTiffWriter(tmp / name, profile)
        yield opened
        for writer in opened.values():
            writer.close()  # GDAL flushes its block cache here: most write errors surface now
    finally:
        for writer in opened.values():
            writer.abandon()  # after an error: closed without a word (a no-op for closed ones)


def _overview(
    tmp: Path,
    terrain: _Terrain,
    sites: list[Site],
    run: DetectRun,
    h_t: float,
    sigma_m: float,
    uncertainty: UncertaintyScore = ENTROPY,
) -> None:
    from hdnet.figures import detect_overview

    heights, cell_m = terrain.hillshade_heights(OVERVIEW_MAX_PX)
    with rasterio.open(tmp / "safety.tif") as src:
        safety = src.read(1, out_shape=heights.shape, resampling=rasterio.enums.Resampling.nearest)
    a, _, c, _, e, f = list(terrain.transform)[:6]
    rows, cols = terrain.shape
    left, right, top, bottom = c, c + a * cols, f, f + e * rows
    name = input_name(terrain.provenance)
    if "window" in terrain.provenance:
        name += f" (window {MapWindow(*terrain.provenance['window']['mapped']).text()})"
    t = "unbounded" if not math.isfinite(h_t) else f"{h_t:.3f} nats"
    t += uncertainty.qualifier
    title = (
        f"{name}: {len(sites)} site(s), lander {run.lander.diameter_m:g} m, sensor σ {sigma_m * 100:.2f} cm, H_t {t}"
    )
    try:
        detect_overview(
            heights, cell_m, safety, (left, right, bottom, top), sites, run.lander.radius_m, title, tmp / "overview.png"
        )
    except OSError as exc:  # matplotlib's write (a full disk) names no file
        raise StorageError(describe_os_error(exc, tmp / "overview.png")) from exc


def _info(
    run: DetectRun,
    terrain: _Terrain,
    plan: TilePlan,
    threshold_info: ThresholdJson,
    sigma_m: float,
    mc_samples: int,
    seed: int,
    counts: dict[str, int],
    sites: list[Site],
    timings: dict[str, float],
    nav_sigma_m: float = 0.0,
) -> DetectInfoJson:
    return {
        "software": "hd",
        "software_version": __version__,
        "run": {
            "checkpoint": str(run.checkpoint.resolve()),
            **run.header.to_dict(),
            "train_sigma_m": run.train_sigma_m,
            "train_noise": run.train_noise.to_dict(),
            "input_size": run.input_size,
            "dataset": run.recorded_dataset,
            "labels": run.labels,
            "dem_shape": list(run.dem_shape),
            "dem_spacing_m": run.spacing_m,
        },
        "input": terrain.provenance,
        "grid": {
            "rows": terrain.shape[0],
            "cols": terrain.shape[1],
            "spacing_m": list(terrain.spacing_xy_m),
            "transform": list(terrain.transform)[:6],
            "crs_wkt": terrain.crs_wkt,
        },
        "lander": asdict(run.lander),
        "threshold": threshold_info,
        "baseline": {"sigma_m": sigma_m, "safe_if_p_safe_at_least": BASELINE_THRESHOLD},
        "sensor_sigma_m": sigma_m,
        "mc_samples": mc_samples,
        "seed": seed,
        "tiling": plan.to_dict(),
        "safety_codes": {
            "unsafe": SAFETY_UNSAFE,
            "safe": SAFETY_SAFE,
            "uncertain": SAFETY_UNCERTAIN,
            "invalid": SAFETY_INVALID,
        },
        "counts": counts,
        "sites": [s.columns() for s in sites],
        "site_rule": {
            "footprint": SITE_FOOTPRINTS["body"],
            "min_separation_m": run.lander.diameter_m,
            "nav_sigma_m": nav_sigma_m,
            "rank_by": SITE_RANK_RULES["touchdown" if nav_sigma_m > 0.0 else "aim"],
            "touchdown_p_safe": "the map's expected P(safe) at the touchdown under nav_sigma_m (hdnet.landing)",
        },
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
        "files": list(OUTPUT_FILES),
    }
