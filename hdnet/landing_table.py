"""The landing table of ``hd eval``: every method's best site in every scored scene (the test split's, or
``--split``'s), landed on with the navigation dispersion and scored against the truths the dataset has
(``hdnet.landing``).

Per test scene and noise level, each method's map is made from the split's inference exactly as
``hd detect`` makes its safety map (invalid where the ALHAT baseline has no value: the border band
and footprints that touch a hole of the noisy DEM):

* ``alhat_baseline``: safe where the baseline's P(safe) >= 0.5, ranked by that P(safe);
* ``base_net``: safe where the network's mean softmax says safe, ranked by its P(safe);
* ``uncertainty_aware``: the base net's map with the pixels whose uncertainty score (predictive
  entropy or mutual information, ``hdnet.uncertainty``) is at or above H_t uncertain.

``hdnet.sites.select_sites`` picks the best site (one, with the same dispersion the touchdowns are
drawn with: a system ranks its sites knowing its navigation), ``hdnet.landing`` draws the touchdowns
and scores them against each truth's labels of the scene, read as stored (the clean scan's
labelling and the terrain's, when the dataset has them: ``hd label --truth terrain``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from rasterio.transform import Affine

from hdlabels import defaults as label_defaults
from hdlabels.lander import Lander
from hdnet import defaults
from hdnet.errors import HdNetError
from hdnet.landing import (
    LandingTally,
    score_touchdowns,
    touchdown_offsets,
    truth_clearance_map,
)
from hdnet.results import METHODS, LandingRow, LandingSettings, SplitInference
from hdnet.sites import SAFETY_INVALID, SAFETY_SAFE, SAFETY_UNCERTAIN, SAFETY_UNSAFE, select_sites
from hdnet.uncertainty import ENTROPY, UncertaintyScore

# The ALHAT baseline is safe where P(safe) >= this (paper, "Label generation"; one source: hdlabels.defaults).
BASELINE_THRESHOLD = label_defaults.SAFE_PROBABILITY_THRESHOLD


def method_map(
    method: str, inf: SplitInference, j: int, threshold_nats: float, uncertainty: UncertaintyScore = ENTROPY
) -> tuple[np.ndarray, np.ndarray]:
    """The safety map (uint8 ``hdnet.detect`` codes) and the P(safe) that ranks sites, of scene ``j``
    of ``inf`` under ``method`` (``threshold_nats``: H_t of the uncertainty-aware map, applied to
    the score ``uncertainty``)."""
    if inf.baseline_p_safe is None:
        raise HdNetError("the landing table needs the baseline's P(safe) of every test scene.")
    base = inf.baseline_p_safe[j]
    invalid = ~np.isfinite(base)
    if method == "alhat_baseline":
        p = np.nan_to_num(base, nan=0.0)
        safe = p >= BASELINE_THRESHOLD
    elif method in ("base_net", "uncertainty_aware"):
        p = inf.prob_safe[j]
        safe = inf.prediction[j] == defaults.CLASS_SAFE
    else:
        raise HdNetError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}.")
    safety = np.where(safe, SAFETY_SAFE, SAFETY_UNSAFE).astype(np.uint8)
    if method == "uncertainty_aware":
        safety[uncertainty.of(inf)[j] >= threshold_nats] = SAFETY_UNCERTAIN
    safety[invalid] = SAFETY_INVALID
    return safety, p


def landing_rows(
    inf: SplitInference,
    threshold_nats: float,
    truths: Mapping[str, Mapping[int, np.ndarray]],
    lander: Lander,
    spacing_m: float,
    settings: LandingSettings = LandingSettings(),
    methods: Sequence[str] = METHODS,
    uncertainty: UncertaintyScore = ENTROPY,
) -> list[LandingRow]:
    """The rows (method x dispersion x truth) of one noise level's test split ``inf``.

    ``truths``: per truth name, the stored labels of every scene by scan index (``hdnet.data.split_labels``);
    ``uncertainty``: the score H_t (``threshold_nats``) applies to.

    Raises:
        HdNetError: a scene without the truth's labels, or of another shape.
    """
    spacing = (float(spacing_m), float(spacing_m))
    h = inf.label.shape[1]
    transform = Affine(spacing_m, 0.0, 0.0, 0.0, -spacing_m, h * spacing_m)
    tallies = {(m, s, t): LandingTally() for m in methods for s in settings.nav_sigmas_m for t in truths}
    for j, scan in enumerate(inf.scan_index):
        scan = int(scan)
        truth_maps = {}
        for name, labels in truths.items():
            lab = labels.get(scan)
            if lab is None or lab.shape != inf.label.shape[1:]:
                raise HdNetError(f"the {name} labels have no DEM of shape {inf.label.shape[1:]} for test scan {scan}.")
            truth_maps[name] = (lab, truth_clearance_map(lab, spacing))
        unit_offsets = touchdown_offsets(settings.touchdowns, 1.0, settings.seed, scan)
        for method in methods:
            safety, p = method_map(method, inf, j, threshold_nats, uncertainty)
            base = inf.baseline_p_safe[j] if inf.baseline_p_safe is not None else p  # method_map checked it
            for nav in settings.nav_sigmas_m:
                sites = select_sites(
                    safety, p, inf.entropy_nats[j], base, transform, spacing, lander, 1, nav, settings.margin_m
                )
                for name, (lab, clearance) in truth_maps.items():
                    tally = tallies[(method, nav, name)]
                    if not sites:
                        tally.abstain()
                        continue
                    site = sites[0]
                    score = score_touchdowns(lab, site.row, site.col, unit_offsets * nav, spacing)
                    tally.land(score, site.clearance_m, float(clearance[site.row, site.col]))
    return [
        tallies[(m, s, t)].row(m, inf.sigma_m, s, t) for t in truths for m in methods for s in settings.nav_sigmas_m
    ]
