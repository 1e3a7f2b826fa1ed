"""The settings of ``hd eval``, described once (help, unit, default, range as field metadata: the
command's options and checks are made from them).

A leaf module without PyTorch: ``hd eval`` reads and checks its options (the threshold's form
included) before ``hdnet.evaluate`` is imported or anything is loaded; ``hdnet.evaluate`` runs with
an :class:`EvalConfig`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from hdcore.setting import DIRECTORY, check, setting
from hdlabels import defaults as label_defaults
from hdnet import limits
from hdnet.defaults import NAV_SIGMAS_M
from hdnet.errors import HdNetError
from hdnet.noise_levels import check_levels
from hdnet.shared_settings import (
    batch_size_setting,
    calibrate_setting,
    labels_setting,
    mc_samples_setting,
    seed_setting,
    threshold_setting,
    uncertainty_setting,
)
from hdnet.threshold_spec import ThresholdSpec, parse_threshold_spec
from hdnet.uncertainty import UncertaintyScore, uncertainty_score

# The splits hd eval scores (--split): one of the dataset's three, or every scan once. The first is the
# default, the paper's protocol. (hdnet.data.SPLITS and ALL_SPLITS name them for the label shards.)
EVAL_SPLITS: tuple[str, ...] = ("test", "val", "train", "all")


@dataclass(frozen=True)
class EvalConfig:
    """How ``evaluate`` runs (the options of ``hd eval``).

    ``mc_samples``: MC-dropout samples per DEM; ``drop_pixels``: dead pixels
    per test DEM for Table 2 (0: no dead-pixel table); ``threshold``: ``mean``, ``quantile:Q`` or
    ``risk:ALPHA``; ``labels``: the labelling to score against, by name or alias
    (``hdlabels.store.find_labeling``; None: the one the run was trained on when the dataset has it,
    else the dataset's only one); ``uncertainty``: the score thresholded at
    H_t (``entropy``, the paper's, or ``mutual-information``: ``hdnet.uncertainty``); ``seed``:
    dropout masks and dead pixels;
    ``batch_size``: DEMs per inference batch; ``nav_sigma_m``: the navigation dispersions (metres)
    of the landing table (``hdnet.landing_table``); ``device``: a torch device
    (None: CUDA when available, else the CPU); ``sigma_sweep``: noise levels (metres) the test
    split is also scored at, made from the clean points where the dataset does not store them;
    ``calibrate``: ``reference`` (H_t calibrated once, on the validation split at the run's
    reference noise level, as the paper does) or ``each`` (H_t calibrated on the validation split
    at each test noise level: the sensor's, which a flash LiDAR knows); ``calibrate_on``: the
    datasets whose validation splits (together) calibrate H_t (empty: the run's own training data,
    what a user of the run has, when every training dataset is present with the run's labelling;
    else the evaluated dataset's validation split, said in the report); ``split``: the split every
    table scores (``test``, the paper's; ``val``, ``train``, or ``all``: every scan of the dataset
    once), H_t still calibrated on the validation splits of ``calibrate_on``'s choice (the report
    warns where scored scans calibrated H_t or trained the run).

    Raises:
        HdNetError: a value of the wrong kind or outside its range (each field's metadata,
            ``hdcore.setting``) or a bad threshold spec, checked here before any file is looked
            at; the dropped pixels are checked against the DEM size by ``evaluate``.
    """

    mc_samples: int = mc_samples_setting()
    drop_pixels: int = setting(
        0,
        f"Dead-pixel test: pixels dropped from each DEM and refilled (paper: {label_defaults.N_DEAD_PIXELS})",
        bound=limits.DROP_PIXELS,
    )
    threshold: str = threshold_setting()
    uncertainty: str = uncertainty_setting()
    labels: str | None = labels_setting(
        "Labelling to evaluate against (default: the one the run was trained on, when the dataset has it; else "
        "the dataset's only one)"
    )
    split: str = setting(
        EVAL_SPLITS[0],
        "The split every table scores: test (the paper's), val, train, or all (every scan of the dataset once, for "
        "a dataset built for evaluation only). The threshold is still calibrated on a validation split; the report "
        "warns where scored scans also calibrated it or trained the run",
        choices=EVAL_SPLITS,
    )
    seed: int = seed_setting("MC dropout and dropped pixels")
    batch_size: int = batch_size_setting("DEMs per inference batch")
    device: str | None = setting(None, "A torch device (default: CUDA when available)", kind=str, cli=False)
    sigma_sweep: tuple[float, ...] = setting(
        (), "Noise levels the test split is also scored at", unit="metres", bound=limits.NOISE_SIGMA_M, cli=False
    )
    calibrate: str = calibrate_setting(
        "Where the threshold is calibrated: once on the validation split at the run's reference noise level "
        "(the paper), or at each test noise level (the sensor's, which a flash LiDAR knows)"
    )
    calibrate_on: tuple[str, ...] = setting(
        (),
        "Calibrate the threshold on this labelled dataset's validation split (repeat it to calibrate on several "
        "together). Default: the run's own training data, what a user of the run has; --data's validation split "
        "when that data is not present (the report says so)",
        kind=Path,
        click_type=DIRECTORY,
    )

    nav_sigma_m: tuple[float, ...] = setting(
        NAV_SIGMAS_M,
        "Navigation dispersion of the landing table, {unit} 1-sigma per horizontal axis: each method's best site "
        "per test scene is landed on with it and scored against the truths the dataset has; repeat for several",
        unit="metres",
        bound=limits.NAV_SIGMA_M,
        flag="--nav-sigma",
    )
    site_margin_m: float = setting(
        0.0,
        "Safety margin of the landing table's sites, {unit}: a site's lander disk widened by it all round "
        "must be safe and certain in the method's map (0: the lander disk alone, as hd detect's default)",
        unit="metres",
        bound=limits.SITE_MARGIN_M,
        flag="--site-margin",
    )

    def __post_init__(self) -> None:
        parse_threshold_spec(self.threshold)
        object.__setattr__(self, "nav_sigma_m", tuple(sorted(set(self.nav_sigma_m))))
        object.__setattr__(self, "sigma_sweep", check_levels(tuple(self.sigma_sweep), "a sweep sigma"))
        check(self, HdNetError)

    @property
    def threshold_spec(self) -> ThresholdSpec:
        """The parsed ``threshold``."""
        return parse_threshold_spec(self.threshold)

    @property
    def uncertainty_score(self) -> UncertaintyScore:
        """The score ``uncertainty`` names."""
        return uncertainty_score(self.uncertainty)
