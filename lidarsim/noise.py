"""The range-noise model of the flash LiDAR: one code path for the factory and every on-the-fly use.

A noisy range is ``r + sigma * n`` with ``n`` standard normal, drawn from the stream ``(seed,
RANGE_NOISE, scan, sigma in nm)`` (``lidarsim.streams``); damaged detector elements add
``damaged_error_m * m`` with ``m`` from ``(seed, DAMAGED_ERROR, scan, sigma in nm)``. A noisy point
is ``sensor position + noisy range * ray direction`` (scan frame, float64, stored as float32).

``hd build-dataset`` draws the noise of its stored levels with :func:`noisy_points`. Training at
noise levels a dataset does not store (``hd train --train-sigma-range``) and the noise sweep of
``hd eval`` make noisy points of any sigma from the stored *clean* points: :func:`recover_ranges`
finds the exact float32 range the ray caster returned (the one whose clean point rounds to the
stored float32 point), and :func:`noisy_points` then gives, at a stored sigma with the dataset's
seed, the stored noisy points bit for bit.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import numpy as np

from hdcore.setting import check, setting
from lidarsim import defaults, limits
from lidarsim.errors import LidarsimError
from lidarsim.sensor import SensorConfig, ray_directions
from lidarsim.streams import Purpose, sigma_key, stream

# How many float32 steps (ulps) around the first estimate recover_ranges searches for the exact range.
_RECOVERY_ULPS = 3


class NoiseKind:
    """One range-noise model, as registered in ``NOISE_KINDS`` (``--noise-model``): what it means,
    the settings it reads, the per-scan arrays it stores, how it scales sigma and detects a return,
    and its line in ``hd inspect``. A new model is one subclass here (and its settings, if it reads
    new ones, in ``lidarsim.recipe`` and ``lidarsim.limits``).

    Attributes:
        name: the model's word (``--noise-model``, the shards' ``noise_model`` attribute).
        words: what it means, for the command-line help.
        parameters: the ``NoiseModel`` fields it reads (the others are stored but unused).
        stored_fields: the optional per-scan arrays a shard of this model holds (``lidarsim.shards``):
            ``noise_scale`` for a model whose ``sigma_scale`` is not None, so that noise drawn later
            from the shard (``hdlabels.noisy``) is the stored noise.
        is_default: True for the paper's model.
    """

    name: ClassVar[str]
    words: ClassVar[str]
    parameters: ClassVar[tuple[str, ...]] = ()
    stored_fields: ClassVar[tuple[str, ...]] = ()
    is_default: ClassVar[bool] = False

    def sigma_scale(self, model: NoiseModel, signal: np.ndarray) -> np.ndarray | None:
        """Factor on the noise level's sigma for returns of relative signal ``signal`` (None: 1 everywhere)."""
        return None

    def detected(self, model: NoiseModel, signal: np.ndarray) -> np.ndarray:
        """True where a return of relative signal ``signal`` is detected."""
        return np.ones(np.shape(signal), dtype=bool)

    def inspect_line(self, attrs: Mapping[str, Any]) -> str:
        """The model in words for ``hd inspect`` from a shard's attributes ("" for nothing to say)."""
        return ""


class ConstantNoise(NoiseKind):
    """The paper's: every return has the dataset's sigma, and every return is detected."""

    name = "constant"
    words = "one sigma everywhere"
    is_default = True


class SnrNoise(NoiseKind):
    """Sigma of a return of relative signal P: ``sigma_ref / sqrt(P)``; SNR = snr_ref * P below snr_min: no return."""

    name = "snr"
    words = "--sigma at 500 m and normal incidence, growing as range / sqrt(cos incidence), weak returns dropped"
    parameters = ("snr_ref", "snr_min", "reference_range_m")
    stored_fields = ("noise_scale",)

    def sigma_scale(self, model: NoiseModel, signal: np.ndarray) -> np.ndarray | None:
        signal = np.asarray(signal, dtype=np.float64)
        return 1.0 / np.sqrt(np.where(signal > 0.0, signal, 1.0))

    def detected(self, model: NoiseModel, signal: np.ndarray) -> np.ndarray:
        return model.snr_ref * np.asarray(signal, dtype=np.float64) >= model.snr_min

    def inspect_line(self, attrs: Mapping[str, Any]) -> str:
        return (
            f"snr noise (sigma at {attrs.get('noise_reference_range_m')} m, SNR {attrs.get('noise_snr_ref')}; "
            f"no return below SNR {attrs.get('noise_snr_min')})"
        )


# The registry: one instance per model, the paper's first.
NOISE_KINDS: dict[str, NoiseKind] = {kind.name: kind for kind in (ConstantNoise(), SnrNoise())}


def help_text() -> str:
    """The command-line help of ``--noise-model``: every registered model and its meaning."""
    return "; ".join(f"{kind.name}: {kind.words}" for kind in NOISE_KINDS.values())


def stored_kind(attrs: Mapping[str, Any]) -> NoiseKind:
    """The noise model a shard's attributes name (``noise_model``; the paper's when absent or unknown)."""
    return NOISE_KINDS.get(str(attrs.get("noise_model", defaults.NOISE_MODEL)), NOISE_KINDS[defaults.NOISE_MODEL])


@dataclass(frozen=True)
class NoiseModel:
    """How the range noise's 1-sigma depends on the returned signal (docs/lidarsim.md, "Signal-dependent noise").
    Each field's help, unit, default and range is its metadata (``hdcore.setting``): ``hd
    build-dataset``'s options, a recipe's ``[build]`` keys (``lidarsim.recipe.BuildSettings``) and
    the checks here are made from it.

    ``constant`` (the paper's): every return has the dataset's sigma. ``snr``: the sigma of a noise
    level is its value for a whole pixel's return at ``reference_range_m`` and normal incidence,
    where the signal-to-noise ratio is ``snr_ref``. A return of relative signal ``P`` (the summed
    sub-return energies of ``lidarsim.footprint``: ``P = cos(theta) (R_ref / r)^2`` for one ray per
    pixel) has ``SNR = snr_ref * P`` and ``sigma = sigma_ref * sqrt(snr_ref / SNR) = sigma_ref /
    sqrt(P)`` (range precision proportional to 1/sqrt(SNR), docs/references.md); a return with
    ``SNR < snr_min`` is not detected (status ``weak``, no range).

    Attributes:
        kind: a registered model (``NOISE_KINDS``): "constant" or "snr".
        snr_ref: signal-to-noise ratio of a whole pixel's return at the reference range, normal incidence.
        snr_min: detection threshold on the signal-to-noise ratio (0: every return is detected).
        reference_range_m: the reference range, metres.
    """

    kind: str = setting(defaults.NOISE_MODEL, help_text(), choices=tuple(NOISE_KINDS), flag="--noise-model")
    snr_ref: float = setting(
        defaults.SNR_REF,
        "snr model: signal-to-noise ratio of a whole pixel's return at 500 m, normal incidence",
        bound=limits.SNR_REF,
    )
    snr_min: float = setting(
        defaults.SNR_MIN,
        "snr model: returns below this signal-to-noise ratio come back as no return (status weak)",
        bound=limits.SNR_MIN,
    )
    reference_range_m: float = setting(
        defaults.SNR_REF_RANGE_M,
        "The range at which snr_ref holds",
        unit="metres",
        bound=limits.SNR_REF_RANGE_M,
        cli=False,
    )

    def __post_init__(self) -> None:
        if self.kind not in NOISE_KINDS:
            raise LidarsimError(f"unknown noise model {self.kind!r}; use {', '.join(NOISE_KINDS)}")
        check(self, LidarsimError)

    @property
    def is_default(self) -> bool:
        """True for the paper's constant sigma (whatever the unused SNR settings)."""
        return self.law.is_default

    @property
    def law(self) -> NoiseKind:
        """The registered model ``kind`` names (``NOISE_KINDS``)."""
        return NOISE_KINDS[self.kind]

    def to_attrs(self) -> dict[str, float | str]:
        """Flat attribute dictionary (HDF5/JSON friendly): ``noise_model`` and ``noise_*``."""
        return {"noise_model": self.kind, **{f"noise_{k}": v for k, v in asdict(self).items() if k != "kind"}}

    def sigma_scale(self, signal: np.ndarray) -> np.ndarray | None:
        """Factor on the noise level's sigma for returns of relative signal ``signal`` (None: 1 everywhere;
        1 where there is no signal, which has no range to add noise to)."""
        return self.law.sigma_scale(self, signal)

    def detected(self, signal: np.ndarray) -> np.ndarray:
        """True where a return of relative signal ``signal`` is detected (SNR >= snr_min)."""
        return self.law.detected(self, signal)


def scan_directions(sensor: SensorConfig, attitude: np.ndarray) -> np.ndarray:
    """Unit ray directions of one scan in the scan frame, float64 (rows, cols, 3), as the factory computes them."""
    return ray_directions(sensor) @ np.asarray(attitude, dtype=np.float64).T


def noisy_ranges(
    ranges_m: np.ndarray,
    sigma_m: float,
    seed: int,
    scan_index: int,
    damaged: np.ndarray | None = None,
    damaged_error_m: float = 0.0,
    realisation: int | None = None,
    sigma_scale: np.ndarray | None = None,
) -> np.ndarray:
    """Noisy ranges (float64, metres) of one scan at noise level ``sigma_m`` (metres).

    Args:
        ranges_m: (rows, cols) clean ranges, metres, float64 holding float32 values; NaN where none.
        sigma_m: 1-sigma of the Gaussian range noise, metres.
        seed: the dataset's master seed.
        scan_index: the scan's global index.
        damaged: (rows, cols) bool, the damaged detector elements (None: none).
        damaged_error_m: 1-sigma of their extra range error, metres.
        realisation: None for the dataset's own draw at this sigma (what ``hd build-dataset`` stores);
            k >= 0 for the k-th independent other draw (stream keys extended by k), e.g. one per
            training epoch.
        sigma_scale: (rows, cols) factor on ``sigma_m`` per element (:meth:`NoiseModel.sigma_scale`);
            None: the constant sigma.
    """
    keys = (scan_index, sigma_key(sigma_m)) if realisation is None else (scan_index, sigma_key(sigma_m), realisation)
    r = np.asarray(ranges_m, dtype=np.float64)
    draw = sigma_m * stream(seed, Purpose.RANGE_NOISE, *keys).standard_normal(r.shape)
    r_noisy = r + (draw if sigma_scale is None else draw * sigma_scale)
    if damaged is not None and damaged.any():
        extra = stream(seed, Purpose.DAMAGED_ERROR, *keys).standard_normal(int(damaged.sum()))
        r_noisy[damaged] += damaged_error_m * extra
    return r_noisy


def points_at_ranges(sensor_position: np.ndarray, ranges_m: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Points ``sensor position + range * direction`` (scan frame, metres) as float32 (rows, cols, 3)."""
    return (np.asarray(sensor_position, dtype=np.float64) + ranges_m[..., None] * directions).astype(np.float32)


def noisy_points(
    ranges_m: np.ndarray,
    directions: np.ndarray,
    sensor_position: np.ndarray,
    sigma_m: float,
    seed: int,
    scan_index: int,
    damaged: np.ndarray | None = None,
    damaged_error_m: float = 0.0,
    realisation: int | None = None,
    sigma_scale: np.ndarray | None = None,
) -> np.ndarray:
    """Noisy points (float32 (rows, cols, 3), scan frame, metres) of one scan at ``sigma_m`` metres
    (arguments as :func:`noisy_ranges`)."""
    r_noisy = noisy_ranges(ranges_m, sigma_m, seed, scan_index, damaged, damaged_error_m, realisation, sigma_scale)
    return points_at_ranges(sensor_position, r_noisy, directions)


def recover_ranges(points_clean: np.ndarray, sensor_position: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """The ray caster's float32 ranges (as float64, metres) behind stored float32 clean points.

    The range of each return is estimated along its ray in float64, rounded to float32, and the
    float32 values within ``_RECOVERY_ULPS`` steps of it are tried: the one whose point rounds to
    the stored point is the range the factory used (unique: near the sensor's 500 m range a float32
    step of the range moves the point by more than a float32 step of its coordinates). NaN where
    the stored point is NaN.

    Raises:
        LidarsimError: a finite point that no nearby float32 range reproduces (the points were not
            made by this sensor geometry, or were altered).
    """
    pts = np.asarray(points_clean, dtype=np.float32)
    sp = np.asarray(sensor_position, dtype=np.float64)
    finite = np.isfinite(pts).all(axis=-1)
    estimate = np.einsum("...k,...k->...", pts.astype(np.float64) - sp, directions)
    estimate = np.where(finite, estimate, 0.0).astype(np.float32)
    best = np.full(pts.shape[:-1], np.nan, dtype=np.float64)
    todo = finite.copy()
    offsets = sorted(range(-_RECOVERY_ULPS, _RECOVERY_ULPS + 1), key=abs)
    up, down = np.float32(np.inf), np.float32(-np.inf)
    for k in offsets:
        if not todo.any():
            break
        cand = estimate.copy()
        toward = up if k > 0 else down
        for _ in range(abs(k)):
            cand = np.nextafter(cand, toward)
        r = cand.astype(np.float64)
        match = todo & (points_at_ranges(sp, r, directions) == pts).all(axis=-1)
        best[match] = r[match]
        todo &= ~match
    if todo.any():
        i, j = np.argwhere(todo)[0]
        raise LidarsimError(
            f"the clean point of detector element ({i}, {j}) is not the return of this sensor's ray: "
            f"{int(todo.sum())} point(s) match no float32 range (altered points, or another sensor geometry)"
        )
    return best
