"""The settings of ``hd descend``, described once (help, unit, default, range as field metadata: the
command's options and checks are made from them).

A leaf module without PyTorch, like ``hdnet.detect_settings``: the mapping settings are ``hd
detect``'s own fields (``described_as``), the placement of the frames ``hd mosaic``'s.
"""

from __future__ import annotations

from dataclasses import dataclass

from hdcore.bounds import parse_integer
from hdcore.setting import check, described_as, setting
from hdlabels.mosaic_dataset import MosaicSettings
from hdnet.detect_settings import DetectSettings
from hdnet.errors import HdNetError
from lidarsim.shards import SPLIT_NAMES

ALL_DESCENTS = "all"  # --descent's word for every descent (of --split, when given)


@dataclass(frozen=True)
class DescendSettings:
    """How ``hd descend`` flies the descents of a descent build (the settings of :func:`hdnet.descend.descend`)."""

    descent: str | None = setting(
        None,
        "The descent to fly: its index in the descent build, or all (every descent; of --split when given)",
        kind=str,
        metavar="K|all",
    )
    split: str | None = setting(
        None, "Fly every descent of this split (alone, or with --descent all)", choices=SPLIT_NAMES
    )
    poses: str = described_as(MosaicSettings, "poses")
    sigma_m: float | None = described_as(
        DetectSettings,
        "sigma_m",
        help="The noise level of the frames' points, {unit}: one the descent build stores (default: the run's "
        "reference training sigma); also the ALHAT baseline's sigma and the network's noise input where it takes one",
    )
    mc_samples: int = described_as(DetectSettings, "mc_samples")
    threshold: str = described_as(DetectSettings, "threshold")
    uncertainty: str = described_as(DetectSettings, "uncertainty")
    calibrate: str = described_as(DetectSettings, "calibrate")
    n_sites: int = described_as(DetectSettings, "n_sites")
    nav_sigma_m: float = described_as(DetectSettings, "nav_sigma_m")
    site_margin_m: float = described_as(DetectSettings, "site_margin_m")
    seed: int = described_as(DetectSettings, "seed")
    batch_size: int = described_as(DetectSettings, "batch_size")
    layout: str = described_as(DetectSettings, "layout")
    overwrite: bool = setting(
        False, "Replace an earlier hd descend output in the output directory (never other files)", cli=False
    )
    device: str | None = setting(None, "A torch device (default: CUDA when available)", kind=str, cli=False)

    def __post_init__(self) -> None:
        check(self, HdNetError)
        self.detect_settings(None)  # the threshold's form
        if self.descent is None and self.split is None:
            raise HdNetError("give --descent K (one descent), --descent all or --split SPLIT (every descent of it).")
        if self.descent is not None and self.descent != ALL_DESCENTS:
            self.descent_index()
            if self.split is not None:
                raise HdNetError(f"--split goes with --descent all, not with one descent (--descent {self.descent}).")

    def descent_index(self) -> int | None:
        """The one descent asked for (None: every descent, of ``split`` when given).

        Raises:
            HdNetError: ``descent`` is neither a whole number >= 0 nor ``all``.
        """
        if self.descent is None or self.descent == ALL_DESCENTS:
            return None
        hint = "give a descent index, e.g. --descent 0, or --descent all"
        index = parse_integer(self.descent, "--descent", hint=hint, error=HdNetError)
        if index < 0:
            raise HdNetError(f"--descent {self.descent}: a descent index is 0 or more; {hint}")
        return index

    def detect_settings(self, sigma_m: float | None) -> DetectSettings:
        """The settings every frame is mapped with (``hd detect``'s), at the frames' noise level ``sigma_m``
        (metres; None: the run's training sigma)."""
        return DetectSettings(
            mc_samples=self.mc_samples,
            threshold=self.threshold,
            uncertainty=self.uncertainty,
            sigma_m=sigma_m,
            calibrate=self.calibrate,
            n_sites=self.n_sites,
            nav_sigma_m=self.nav_sigma_m,
            site_margin_m=self.site_margin_m,
            seed=self.seed,
            batch_size=self.batch_size,
            layout=self.layout,
            device=self.device,
        )
