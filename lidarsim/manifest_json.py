"""The keys of ``manifest.json`` as typed records (``docs/shard-format.md``, ``docs/labels-format.md``).

A manifest is read and written as JSON, so its records are ``TypedDict``: at run time they are the
file's own dictionaries (their keys in the file's order, unknown keys of a later minor version kept
when hd rewrites the manifest), and mypy checks every key a reader names and every value's type.
``lidarsim.shards.validate_manifest`` checks a file against them before anything reads it.

Keys marked ``NotRequired`` are absent in manifests written before they existed (or, like
``n_descents``, present only in one kind of build).
"""

from __future__ import annotations

from typing import Any, NotRequired, TypedDict

__all__ = [
    "BuildConfigJson",
    "DemGridJson",
    "DescentJson",
    "DeviationJson",
    "DtmJson",
    "FileEntryJson",
    "FootprintJson",
    "LabelShardJson",
    "LabelingJson",
    "ManifestJson",
    "MosaicJson",
    "MosaicSourceJson",
    "NavigationJson",
    "NoiseModelJson",
    "RecipeDeviationJson",
    "ScanShardJson",
    "SensorJson",
    "ShardRefJson",
    "TrajectoryConfigJson",
    "TrajectoryJson",
]


class ShardRefJson(TypedDict):
    """A file of the dataset named by its path (relative to the dataset) and its sha256."""

    path: str
    sha256: str


class FileEntryJson(ShardRefJson):
    """What every file entry of a manifest gives: its path, sha256, scans and (1.4) size in bytes."""

    n_scans: int
    size_bytes: NotRequired[int]  # 1.4; absent in older manifests


class ScanShardJson(FileEntryJson):
    """One scan shard of ``shards``."""

    first_scan: NotRequired[int]
    split: NotRequired[str]  # train, val, test or mixed
    split_counts: NotRequired[dict[str, int]]
    schema: NotRequired[str]
    schema_version: NotRequired[str]


class LabelShardJson(FileEntryJson):
    """One label shard of a labelling's ``shards``: the scan shard it labels by path and sha256."""

    source_path: str
    source_sha256: str
    schema: NotRequired[str]
    schema_version: NotRequired[str]


class DemGridJson(TypedDict):
    """A DEM grid (a labelling's and a mosaic's ``dem``): cells a side and metres per cell."""

    rows: int
    cols: int
    spacing_m: float
    gridding: NotRequired[str]  # absent in 1.0 labellings: the hd convention's linear gridding


class LabelingJson(TypedDict):
    """One labelling of ``labelings`` (written by ``hd label``; ``hdlabels.LabelingEntry`` reads it)."""

    name: str
    schema: NotRequired[str]
    schema_version: NotRequired[str]
    convention: NotRequired[str]
    lander: NotRequired[dict[str, float | int | str | bool]]
    dem: NotRequired[DemGridJson]
    label_codes: NotRequired[dict[str, int]]
    label_counts: NotRequired[dict[str, int]]
    safe_fraction: NotRequired[float]
    baseline_safe_fraction: NotRequired[dict[str, float]]
    shards: NotRequired[list[LabelShardJson]]
    truth: NotRequired[str]  # only for the terrain truth; absent: the clean scan


class DtmJson(TypedDict, total=False):
    """The terrain's provenance (``lidarsim.terrain.DTMInfo.to_attrs`` and its sha256)."""

    path: str
    name: str
    sha256: str
    size_bytes: int  # 1.4, for a terrain kept inside the dataset (a relative path)
    crs_wkt: str  # "" = local metres
    transform: list[float]  # GDAL order, at the scale used
    rows: int
    cols: int
    spacing_m: list[float]
    scale: float
    nodata: float
    driver: str


class TrajectoryJson(TypedDict):
    """The scan plan's lattice step and the footprint's half-width, metres."""

    step_m: float
    footprint_half_width_m: float


class DeviationJson(TypedDict):
    """One setting of a recipe built at another size."""

    setting: str
    option: str
    recipe: int
    used: int


class RecipeDeviationJson(TypedDict):
    """``recipe_deviation`` (1.1): the recipe, its version and the settings that differ."""

    recipe: str
    recipe_version: int
    settings: list[DeviationJson]


class MosaicSourceJson(TypedDict):
    """The descent dataset a mosaic dataset was made from."""

    path: str
    n_descents: int
    descent_frames: int
    config_sha256: str | None
    shards_sha256: list[str]


class MosaicJson(TypedDict):
    """``mosaic`` (1.3): how the mosaics were made."""

    source: MosaicSourceJson
    poses: str  # registered, nav or true
    frames: list[int]
    anchor_frame: int
    dem: DemGridJson
    icp_voxels_m: list[float]


class SensorJson(TypedDict):
    """``lidarsim.sensor.SensorConfig``: detector pixels, field of view (degrees), focal length and
    detector defects."""

    rows: int
    cols: int
    fov_x_deg: float
    fov_y_deg: float
    focal_length_m: float
    dead_elements: int
    damaged_elements: int
    damaged_error_m: float


class NavigationJson(TypedDict):
    """``lidarsim.navigation.NavigationError``: 1-sigma bias and walk per frame, metres and degrees."""

    position_sigma_m: float
    position_walk_m: float
    attitude_sigma_deg: float
    attitude_walk_deg: float


class DescentJson(TypedDict):
    """``lidarsim.descent.DescentConfig``: frames per descent, altitudes (m), approach angle (degrees)."""

    frames: int
    altitude_start_m: float
    altitude_end_m: float
    approach_deg: float
    nav: NavigationJson


class TrajectoryConfigJson(TypedDict):
    """``lidarsim.trajectory.TrajectoryConfig`` as a build records it: settings left unset (None) are
    absent, and a descent build has its descent instead of ``altitude_m`` and ``tilt_deg``."""

    n_scans: int
    altitude_m: NotRequired[float]
    tilt_deg: NotRequired[float]
    jitter_deg: float
    margin_m: float
    tile_m: float
    altitude_max_m: NotRequired[float]
    tilt_max_deg: NotRequired[float]
    jitter_max_deg: NotRequired[float]
    descent: NotRequired[DescentJson]


class FootprintJson(TypedDict):
    """``lidarsim.footprint.FootprintConfig``: sub-rays a side, spot profile, range estimator, pulse (m)."""

    samples: int
    spot_profile: str
    range_estimator: str
    pulse_width_m: float
    return_fraction: float


class NoiseModelJson(TypedDict):
    """``lidarsim.noise.NoiseModel``: its kind and the SNR model's parameters."""

    kind: str
    snr_ref: float
    snr_min: float
    reference_range_m: float


class BuildConfigJson(TypedDict):
    """``config`` (``lidarsim.build.BuildConfig.to_dict``): every build setting. The sensor-realism
    settings and ``rocks_on_dtm`` are absent at their defaults (the manifests written before them read
    the same); ``terrain`` is null for a user's DTM without rocks."""

    sigmas_m: list[float]
    seed: int
    sensor: SensorJson
    trajectory: TrajectoryConfigJson
    dtm_path: str | None
    dtm_scale: float
    terrain: dict[str, Any] | None  # lidarsim.procedural.MarsTerrainParams: its keywords
    shard_size: int
    compression: str
    rocks_on_dtm: NotRequired[bool]
    footprint: NotRequired[FootprintJson]
    noise_model: NotRequired[NoiseModelJson]


class ManifestJson(TypedDict):
    """``manifest.json`` of a dataset (``docs/shard-format.md``)."""

    schema: str
    schema_version: str
    kind: NotRequired[str]  # lidar-scans or descent-mosaics
    software: NotRequired[str]
    software_version: NotRequired[str]
    n_scans: int
    n_descents: NotRequired[int]
    descent_frames: NotRequired[int]
    sigmas_m: list[float]
    seed: NotRequired[int]
    config_sha256: NotRequired[str | None]
    config: NotRequired[BuildConfigJson]
    dtm: NotRequired[DtmJson]
    trajectory: NotRequired[TrajectoryJson]
    splits: NotRequired[dict[str, int]]
    shards: list[ScanShardJson]
    labelings: NotRequired[list[LabelingJson]]
    recipe_deviation: NotRequired[RecipeDeviationJson]
    mosaic: NotRequired[MosaicJson]
