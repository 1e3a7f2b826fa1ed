"""The settings of ``hd detect``, described once (help, unit, default, range as field metadata: the
command's options and checks are made from them).

A leaf module without PyTorch: ``hdnet.detect.detect`` takes a :class:`DetectSettings` and
``hdcli.detect_job`` runs it with the command's, without the two importing each other;
``hd detect`` reads and checks them (the threshold's form included) before anything heavy is
imported or loaded.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from hdcore.setting import check, setting
from hdnet import limits
from hdnet.errors import HdNetError
from hdnet.shared_settings import (
    batch_size_setting,
    calibrate_setting,
    labels_setting,
    mc_samples_setting,
    seed_setting,
    threshold_setting,
    uncertainty_setting,
)
from hdnet.threshold_spec import parse_threshold_spec
from lidarsim.errors import LidarsimError
from lidarsim.map_window import FORM, MAP_WINDOW, MapWindow

# The network's memory layouts on the CPU (``hdnet.engine``): the fast one first, the reference last.
LAYOUTS = ("channels-last", "channels-last-per-tile", "nchw")


@dataclass(frozen=True)
class DetectSettings:
    """How ``hd detect`` maps a terrain (the settings of :func:`hdnet.detect.detect`; ``window`` may also be
    given as four numbers or their text ``"xmin,ymin,xmax,ymax"``, made a checked ``MapWindow``)."""

    scan: int | None = setting(
        None, "With --data: the scan whose noisy DEM to map (scan frame)", bound=limits.SCAN_INDEX
    )
    mc_samples: int = mc_samples_setting()
    threshold: str = threshold_setting("Calibrated as hd eval does.")
    uncertainty: str = uncertainty_setting(
        "The uncertain cells of safety.tif are those at or above H_t; entropy.tif and mutual_information.tif "
        "hold both scores."
    )
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
    nav_sigma_m: float = setting(
        0.0,
        "Navigation dispersion of the touchdown around the aim point, {unit} 1-sigma per horizontal axis: sites "
        "are ranked by the map's expected P(safe) where the vehicle lands, not only at the aim point (0: by the "
        "aim point's footprint)",
        unit="metres",
        bound=limits.NAV_SIGMA_M,
        flag="--nav-sigma",
    )
    site_margin_m: float = setting(
        0.0,
        "Safety margin of the sites, {unit}: a site's lander disk widened by it all round must be safe and "
        "certain (0: the lander disk alone)",
        unit="metres",
        bound=limits.SITE_MARGIN_M,
        flag="--site-margin",
    )
    upsample: bool = setting(
        False,
        "A DTM coarser than the run's DEM spacing (e.g. HiRISE at 2-4 m) is interpolated bilinearly to it "
        "(recorded in detect.json) instead of refused; it holds no rocks below its own resolution",
    )
    window: MapWindow | None = setting(
        None,
        "With --dtm: map only this rectangle of it, XMIN,YMIN,XMAX,YMAX in the DTM's CRS, {unit} (as a GIS shows "
        "them): only its cells are read (the cells it overlaps; clipped to the DTM with a warning when it "
        "reaches past it) and mapped as if they were the whole DTM, and the sites are chosen in it",
        unit="metres",
        kind=MapWindow,
        click_type=MAP_WINDOW,
        metavar=FORM,
    )
    labels: str | None = labels_setting(
        "With --data: the labelling whose DEM of the scan to map (default: the one the run was trained on, when "
        "the dataset has it; else the dataset's only one)"
    )
    seed: int = seed_setting("MC dropout")
    batch_size: int = batch_size_setting("Tiles per inference batch")
    layout: str = setting(
        "channels-last",
        "The network's memory layout on the CPU: channels-last (faster; the same MC-dropout draws, maps equal "
        "to nchw's within float round-off, ~1e-4), channels-last-per-tile (the same, each tile's samples "
        "through the network alone with its rows of the batch's masks) or nchw (PyTorch's default, the reference)",
        choices=LAYOUTS,
    )
    overwrite: bool = setting(
        False,
        "Replace an earlier hd detect output in the output directory (never other files, never an input)",
        cli=False,
    )
    device: str | None = setting(None, "A torch device (default: CUDA when available)", kind=str, cli=False)

    def __post_init__(self) -> None:
        if self.window is not None and not isinstance(self.window, MapWindow):  # four numbers or their text
            try:
                object.__setattr__(self, "window", MapWindow.of(self.window))
            except LidarsimError as exc:
                raise type(exc)(f"--window: {exc}") from exc
        check(self, HdNetError)
        parse_threshold_spec(self.threshold)

    def check_inputs(self, dtm: str | os.PathLike | None, dataset: str | os.PathLike | None) -> None:
        """How the settings go with the inputs: a DTM, or a dataset and a scan (each value's kind and
        range are checked as the settings are made).

        Raises:
            HdNetError: both or neither of ``dtm`` and ``dataset``, a dataset without a scan, a scan
                with a DTM, a window with a dataset.
        """
        if (dtm is None) == (dataset is None):
            raise HdNetError("give either a DTM (--dtm) or a dataset and a scan (--data with --scan).")
        if dataset is not None and self.scan is None:
            raise HdNetError("--data needs --scan: the index of the scan whose noisy DEM to use.")
        if dtm is not None and self.scan is not None:
            raise HdNetError("--scan goes with --data, not with --dtm.")
        if dataset is not None and self.window is not None:
            raise HdNetError("--window goes with --dtm (a window of a DTM's map coordinates), not with --data.")
