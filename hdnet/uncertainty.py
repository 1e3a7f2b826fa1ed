"""The uncertainty score whose threshold H_t makes a pixel uncertain: predictive entropy or mutual information.

Both are per pixel, in nats, from the M Monte Carlo dropout softmaxes p_1 ... p_M of ``hdnet.infer``:

* ``entropy`` (the paper's, the default): the predictive entropy H[mean_m p_m] of the mean softmax.
  It is high where a pixel is hard to call: ambiguous terrain the network has learnt to be unsure
  about (aleatoric) as well as terrain unlike its training data (epistemic).
* ``mutual-information``: MI = H[mean_m p_m] - mean_m H[p_m], the mutual information between the
  prediction and the network's weights (the BALD score: Houlsby et al. 2011, Gal et al. 2017;
  Smith & Gal 2018; docs/references.md). It is the epistemic part alone: high only where the
  dropout samples disagree, which is the established score for inputs unlike the training data.
  0 <= MI <= H.

A score is one record here (its name, its words and which array of an inference holds it), so
that every place that thresholds "the uncertainty" (calibration, the uncertainty-aware map, the
sweeps, risk control, the landing table, ``hd detect``'s safety map) reads it through
:meth:`UncertaintyScore.of`. A record of a threshold (``report.json``, ``detect.json``, the
threshold cache) names a score other than the default under :data:`RECORD_KEY`; a record without
it was made with predictive entropy, as every record made before the choice existed.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final, Protocol, TypeVar

from hdnet.errors import HdNetError
from hdnet.report_json import ThresholdJson

T_co = TypeVar("T_co", covariant=True)
T = TypeVar("T")

# The key of a threshold record (report.json's and detect.json's ``threshold``) that names its score.
RECORD_KEY: Final = "uncertainty"


class Scored(Protocol[T_co]):
    """An inference that holds both scores per pixel, nats (``hdnet.infer.MCPrediction``: tensors;
    ``hdnet.results.SplitInference``: arrays, without mutual information when made before it was kept)."""

    @property
    def entropy_nats(self) -> T_co: ...

    @property
    def mutual_information_nats(self) -> T_co | None: ...


@dataclass(frozen=True)
class UncertaintyScore:
    """One uncertainty score: ``name`` (the value of ``--uncertainty``), ``noun`` (how reports name it),
    ``short`` (how figure labels name it), ``description`` (one line: what it measures and its formula)
    and ``attribute`` (the array of an inference, :class:`Scored`, that holds it)."""

    name: str
    noun: str
    short: str
    description: str
    attribute: str

    def of(self, inference: Scored[T]) -> T:
        """The score's per-pixel values (nats) in ``inference``.

        Raises:
            HdNetError: the inference does not hold this score.
        """
        values: T | None = getattr(inference, self.attribute)
        if values is None:
            raise HdNetError(f"this inference holds no {self.noun}; run the inference again with this hd.")
        return values

    @property
    def qualifier(self) -> str:
        """Words that name the score after a threshold in a one-line summary (" on the mutual
        information"); empty for the default, whose threshold is the paper's entropy threshold."""
        return "" if self.is_default else f" on the {self.noun}"

    @property
    def is_default(self) -> bool:
        """True for the paper's score (the one a threshold record leaves unnamed)."""
        return self is SCORES[DEFAULT]


ENTROPY = UncertaintyScore(
    "entropy",
    "entropy",
    "entropy",
    "predictive entropy H[mean p] of the mean softmax, how hard a pixel is to call (aleatoric and epistemic; "
    "the paper's)",
    "entropy_nats",
)
MUTUAL_INFORMATION = UncertaintyScore(
    "mutual-information",
    "mutual information",
    "MI",
    "mutual information H[mean p] - mean H[p] of the MC-dropout samples (BALD), their disagreement (the "
    "epistemic part alone, for terrain unlike the training data)",
    "mutual_information_nats",
)
SCORES: dict[str, UncertaintyScore] = {s.name: s for s in (ENTROPY, MUTUAL_INFORMATION)}
DEFAULT = ENTROPY.name  # the paper's score (Tomita et al., "Uncertainty-aware Safety Map Generation")


def uncertainty_score(name: str) -> UncertaintyScore:
    """The score called ``name`` (one of :data:`SCORES`).

    Raises:
        HdNetError: an unknown name.
    """
    score = SCORES.get(name) if isinstance(name, str) else None
    if score is None:
        raise HdNetError(f"uncertainty score {name!r} is not one of {', '.join(SCORES)}.")
    return score


def recorded_score(record: Mapping[str, Any]) -> UncertaintyScore:
    """The score a threshold record names (none named: predictive entropy)."""
    return uncertainty_score(str(record.get(RECORD_KEY, DEFAULT)))


def score_entry(score: UncertaintyScore) -> dict[str, str]:
    """The entry of a record that names ``score``: ``{RECORD_KEY: name}``, or nothing for the default
    score, so that a record made with it is the record made before the choice existed."""
    return {} if score.is_default else {RECORD_KEY: score.name}


def with_score(record: ThresholdJson, score: UncertaintyScore) -> ThresholdJson:
    """The threshold record ``record`` naming ``score`` (in place, and returned), as :func:`score_entry`
    says: the default score unnamed."""
    if not score.is_default:
        record[RECORD_KEY] = score.name
    return record


def help_text() -> str:
    """The scores worded for a command's ``--help``: each name with its description."""
    return "; ".join(f"{s.name} = {s.description}" for s in SCORES.values())
