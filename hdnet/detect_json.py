"""The keys of ``detect.json`` and ``sites.geojson`` (what ``hd detect`` writes) as typed records.

``hd detect`` writes them and ``hd view`` reads ``detect.json`` back (after its own structure check,
``hdnet.view.read_detect``). They are ``TypedDict``: at run time the dictionaries the files hold,
keys in the order hd writes them; for mypy records whose every key a reader names is checked with
its type. docs/user-guide.md ("Hazard maps of any terrain") describes the files.
"""

from __future__ import annotations

from typing import NotRequired, TypedDict

from hdnet.report_json import ThresholdJson
from hdnet.run_json import TrainingNoiseJson

__all__ = [
    "DetectInfoJson",
    "DetectInputJson",
    "DetectRunJson",
    "GridJson",
    "SiteRuleJson",
    "SitesGeoJson",
    "TilingJson",
    "UpsampledJson",
    "WindowJson",
]


class UpsampledJson(TypedDict):
    """How a coarser DTM was interpolated to the run's spacing (``--upsample``), metres."""

    method: str
    source_spacing_m: list[float]
    spacing_m: float
    source_sha256: str


class WindowJson(TypedDict):
    """The part of a DTM mapped (``--window``): asked, mapped and the DTM's bounds, map metres."""

    requested: list[float]
    mapped: list[float]
    clipped: bool
    dtm_bounds: list[float]


class DetectInputJson(TypedDict, total=False):
    """``input``: what was mapped: a DTM (``kind`` ``dtm``) or one scan of a dataset (``scan``)."""

    kind: str
    # a DTM
    path: str
    name: str
    sha256: str
    driver: str
    source_spacing_m: list[float]
    scale: float
    source_transform: list[float]
    source_shape: list[int]
    upsampled: UpsampledJson
    window: WindowJson
    # a scan
    dataset: str
    manifest_sha256: str
    labels: str
    scan_index: int
    split: str
    sigma_m: float
    label_shard: str
    origin_map: list[float]
    dtm_crs_wkt: str
    frame: str
    seen_in_training: bool
    mosaic_frames: int  # a scan of a descent-mosaics dataset (hd mosaic): the frames its mosaic was made of


class TilingJson(TypedDict):
    """``tiling``: the tiles' size and least overlap (pixels), tiles per axis and in all."""

    tile_px: list[int]
    min_overlap_px: int
    tiles: list[int]
    n_tiles: int


class DetectRunJson(TypedDict):
    """``run``: the checkpoint that mapped, its header and its training."""

    checkpoint: str
    epoch: int
    profile: str | None
    model_config: dict[str, float | int] | None
    train_sigma_m: float
    train_noise: TrainingNoiseJson
    input_size: int | None
    dataset: str | None
    labels: str | None
    dem_shape: list[int]
    dem_spacing_m: float


class GridJson(TypedDict):
    """``grid``: the maps' grid (cells, metres per cell, GDAL transform, CRS as WKT; "" = local metres)."""

    rows: int
    cols: int
    spacing_m: list[float]
    transform: list[float]
    crs_wkt: str


class SiteRuleJson(TypedDict):
    """``site_rule``: how the landing sites were chosen and ranked."""

    footprint: str
    min_separation_m: float
    nav_sigma_m: float
    rank_by: str
    touchdown_p_safe: str
    margin_m: NotRequired[float]


class DetectInfoJson(TypedDict):
    """``detect.json``."""

    software: str
    software_version: str
    run: DetectRunJson
    input: DetectInputJson
    grid: GridJson
    lander: dict[str, float | str]  # hdlabels.Lander's fields
    threshold: ThresholdJson
    baseline: dict[str, float]
    sensor_sigma_m: float
    mc_samples: int
    seed: int
    tiling: TilingJson
    safety_codes: dict[str, int]
    counts: dict[str, int]
    sites: list[dict[str, float | int]]  # hdnet.results.SITE_COLUMNS of each site
    site_rule: SiteRuleJson
    timings_s: dict[str, float]
    files: list[str]
    network_layout: NotRequired[str]


class SitesGeoJson(TypedDict):
    """``sites.geojson``: a GeoJSON FeatureCollection of the sites (points in the DTM's CRS)."""

    type: str
    features: list[dict[str, object]]
    crs: NotRequired[dict[str, object]]  # a named CRS (GeoJSON 2008) when the DTM has an EPSG code


def input_name(source: DetectInputJson) -> str:
    """What a detection mapped, in words: the DTM's name, ``mosaic 19 (9 frames)`` for a scan of a
    mosaic dataset (``mosaic_frames`` recorded), else ``scan 19``."""
    if "name" in source:
        return str(source["name"])
    if "mosaic_frames" in source:
        return f"mosaic {source.get('scan_index')} ({source['mosaic_frames']} frames)"
    return f"scan {source.get('scan_index')}"
