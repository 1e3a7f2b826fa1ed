"""``hd detect``: hazard maps and ranked landing sites of a DTM (or of one scan) from a trained run.

:class:`DetectSettings` describes the command's settings once (help, unit, default, range as field
metadata: the options and checks are made from it); :func:`detect_job` runs ``hdnet.detect.detect``
with them and says what it wrote.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from hdnet import limits
from hdnet.errors import HdNetError
from hdnet.shared_options import (
    batch_size_setting,
    calibrate_setting,
    labels_setting,
    mc_samples_setting,
    seed_setting,
    threshold_setting,
)
from lidarsim.outcome import Done
from lidarsim.setting import check, setting


@dataclass(frozen=True)
class DetectSettings:
    """How ``hd detect`` maps a terrain (the keywords of :func:`hdnet.detect.detect`)."""

    scan: int | None = setting(
        None, "With --data: the scan whose noisy DEM to map (scan frame)", bound=limits.SCAN_INDEX
    )
    mc_samples: int = mc_samples_setting()
    threshold: str = threshold_setting("Calibrated as hd eval does.")
    sigma_m: float | None = setting(
        None,
        "The sensor's range noise, {unit} (default: the run's reference training sigma): the ALHAT baseline's "
        "sigma, the network's noise input where it takes one, the calibration level with --calibrate each; with "
        "--data also the noise level of the scan's DEM.",
        unit="metres",
        bound=limits.NOISE_SIGMA_M,
        flag="--sigma",
    )
    calibrate: str = calibrate_setting(
        "Calibrate the threshold on the validation split at the run's reference noise level, or at the sensor's "
        "--sigma (guarded above the run's training levels), as hd eval --calibrate"
    )
    n_sites: int = setting(10, "Most landing sites to propose", bound=limits.SITES, flag="--sites")
    upsample: bool = setting(
        False,
        "A DTM coarser than the run's DEM spacing (e.g. HiRISE at 2-4 m) is interpolated bilinearly to it "
        "(recorded in detect.json) instead of refused; it holds no rocks below its own resolution",
    )
    labels: str | None = labels_setting("With --data: the labelling (when the dataset has several)")
    seed: int = seed_setting("MC dropout")
    batch_size: int = batch_size_setting("Tiles per inference batch")

    def __post_init__(self) -> None:
        check(self, HdNetError)


def detect_job(
    run_dir: Path,
    out_dir: Path,
    dtm: Path | None,
    dataset: Path | None,
    settings: DetectSettings,
    overwrite: bool,
    progress: Callable[[int, int], None] | None = None,
) -> Done:
    """Map ``dtm`` (or the scan ``settings.scan`` of ``dataset``) with the run ``run_dir`` into ``out_dir``.

    Raises:
        HdNetError / TerrainError / StorageError: as ``hdnet.detect.detect``, before anything is written.
    """
    from hdnet.detect import detect

    result = detect(
        run_dir,
        out_dir,
        dtm=dtm,
        dataset=dataset,
        overwrite=overwrite,
        progress=progress,
        **dataclasses.asdict(settings),
    )
    lines = [result.summary(), f"maps, sites.csv, sites.geojson, overview.png and detect.json in {out_dir}"]
    return Done(lines, {"command": "detect", "out": str(out_dir), **result.info})
