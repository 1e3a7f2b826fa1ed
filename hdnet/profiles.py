"""Training profiles: the paper's settings, a CPU-sized one, and a tiny one for tests.

``cpu`` evidence (the ablation in docs/results.md, "Choosing the cpu profile": validation split of
datasets/mars-paper, paper-convention labels, 1.67 cm, `benchmarks/ablate_cpu_profile.py`, on the
project's 2-core machine): the profile before the ablation (width 1/4, five pooling stages, the
paper's dataset min-max heights, 80 cosine epochs) reached validation PA 0.76 after 10 epochs. What
moved the numbers, in order: two pooling stages instead of five (+0.11 PA at 10 epochs: the 10 m
lander-scale rule needs a receptive field of ~20 px, not 200, and the shallow net keeps 100x100
DEMs at full resolution without padding); heights relative to each DEM's median in metres plus a
slope and a 10 m high-pass channel (+0.03); dropout 0.2 instead of the paper's 0.5 (+0.015); width
1/2 instead of 1/4 (+0.013); D4 augmentation over a longer run (+0.01). The chosen profile reaches
validation PA 0.935 and mIoU 0.878 in 40 epochs (10.3 min of training on this machine, quiet); width 3/4
reaches the same in 18 epochs at about the same time, width 1/4 reaches 0.929 in 88 epochs.
Class-balanced loss, one-cycle lr and batch 16 did not help. The channels-last memory format gives
1.13x images/s for this network (docs/benchmarks.md). Adam (lr 1e-3, cosine-annealed to 0)
replaces the paper's SGD (lr 1e-4, momentum 0.9), which needs the paper's 10^4 epochs.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import MISSING, asdict, dataclass, fields, replace
from typing import Literal

from hdcore.bounds import Bound
from hdcore.setting import check, setting
from hdnet import defaults
from hdnet.augment import AUGMENTATIONS
from hdnet.errors import HdNetError
from hdnet.inputs import EXTRA_CHANNELS, HEIGHTS
from hdnet.model import ModelConfig

LR_SCHEDULES: tuple[str, ...] = ("constant", "cosine", "onecycle")
CLASS_WEIGHTINGS: tuple[str, ...] = ("none", "balanced")
PRECISIONS: tuple[str, ...] = ("float32", "bfloat16")
_POSITIVE = Bound(0.0, low_open=True)
_COUNT = Bound(1, integer=True)
# torch.optim.lr_scheduler.OneCycleLR defaults (Smith and Topin 2019): warm-up share, start lr =
# peak / 25, final lr = start / 10^4.
ONECYCLE_PCT_START = 0.3
ONECYCLE_DIV_FACTOR = 25.0
ONECYCLE_FINAL_DIV_FACTOR = 1e4


@dataclass(frozen=True)
class TrainingProfile:
    """One training configuration. Each field's meaning, unit and range is its metadata
    (``hdcore.setting``), from which the checks here are made. The first fields are the paper's
    knobs; the others default to the paper's choices, so a profile saved before they existed reads
    back unchanged.
    """

    name: str = setting(MISSING, "The profile's name", kind=str, cli=False)
    input_size: int | None = setting(
        MISSING,
        "Square size the DEM is upsampled to (None: the native DEM size, padded to a multiple of 2**depth)",
        unit="pixels",
        bound=_COUNT,
        optional=True,
        cli=False,
    )
    width: float = setting(MISSING, "Scale of the channel counts", bound=_POSITIVE, cli=False)
    batch_size: int = setting(MISSING, "Images per training batch", bound=_COUNT, cli=False)
    lr: float = setting(MISSING, "The (peak) learning rate", bound=_POSITIVE, cli=False)
    momentum: float = setting(MISSING, "Momentum, used by SGD only", kind=float, cli=False)
    epochs: int = setting(MISSING, "The default epoch count", bound=_COUNT, cli=False)
    optimizer: Literal["sgd", "adam"] = setting(MISSING, "The optimiser", choices=("sgd", "adam"), cli=False)
    lr_schedule: Literal["constant", "cosine", "onecycle"] = setting(
        "constant",
        "constant; cosine (from lr to 0); onecycle (Smith and Topin 2019, the shape of "
        "torch.optim.lr_scheduler.OneCycleLR with its defaults, in continuous time: cosine warm-up from lr/25 to lr "
        "over the first 30 % of the run, then cosine down to lr/25/10^4). Every schedule is a pure function of the "
        "(fractional) epoch, set before every optimiser step",
        choices=LR_SCHEDULES,
        cli=False,
    )
    depth: int = setting(
        len(defaults.ENCODER_CHANNELS), "Encoder blocks (pooling stages) of the SegNet, 5 = VGG16", kind=int, cli=False
    )
    dropout_p: float = setting(
        defaults.DROPOUT_P, "Drop probability of the MC-dropout layers, in training and sampling", kind=float, cli=False
    )
    heights: Literal["minmax", "median", "plane"] = setting(
        "minmax",
        "The input heights (hdnet.inputs): minmax = the paper's dataset min-max, median/plane = heights relative "
        "to each DEM's median / least-squares plane in units of height_scale_m",
        choices=HEIGHTS,
        cli=False,
    )
    height_scale_m: float = setting(
        1.0, "Input unit of the median/plane heights", unit="metres", bound=_POSITIVE, cli=False
    )
    extra_channels: tuple[str, ...] = setting(
        (), "Input channels after the heights: slope, highpass, sigma (hdnet.inputs)", kind=str, cli=False
    )
    augment: Literal["none", "d4"] = setting(
        "none", "none or d4 (random rotation/flip of each training DEM and its label)", choices=AUGMENTATIONS, cli=False
    )
    class_weighting: Literal["none", "balanced"] = setting(
        "none",
        "none or balanced (cross-entropy weighted by N / (2 N_c) with the training split's pixel counts N_c of "
        "each class)",
        choices=CLASS_WEIGHTINGS,
        cli=False,
    )
    channels_last: bool = setting(
        False,
        "Run the network in the channels-last memory format (same numbers, faster convolutions on CPUs)",
        cli=False,
    )
    precision: Literal["float32", "bfloat16"] = setting(
        "float32",
        "Arithmetic of training's forward and backward passes: float32, or bfloat16 autocast (weights, optimiser "
        "state, loss and validation stay float32; about 1.7x the images/s on a CPU with AVX-512 BF16 or AMX, "
        "docs/benchmarks.md)",
        choices=PRECISIONS,
        cli=False,
    )
    fast_dropout: bool = setting(
        False,
        "Draw training's dropout masks with hdnet.dropout_masks (16-bit PCG64 draws, four times faster than "
        "torch.bernoulli on a CPU; other draws, the same distribution); MC-dropout inference draws hd's own "
        "masks whatever the profile",
        cli=False,
    )
    # (low, high) metres: by default the profile trains across this range of noise levels, drawn per
    # sample (hdnet.noise_levels); None: at one level.
    train_sigma_range_m: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        check(self, HdNetError)
        if isinstance(self.extra_channels, list):
            object.__setattr__(self, "extra_channels", tuple(self.extra_channels))
        if self.train_sigma_range_m is not None:
            lo, hi = self.train_sigma_range_m
            object.__setattr__(self, "train_sigma_range_m", (float(lo), float(hi)))
            if not 0.0 <= lo < hi:
                raise HdNetError(f"train_sigma_range_m must be (low, high) with 0 <= low < high, got ({lo}, {hi}).")
        if any(c not in EXTRA_CHANNELS for c in self.extra_channels):
            raise HdNetError(
                f"extra_channels must be names from {', '.join(EXTRA_CHANNELS)}, got {list(self.extra_channels)}."
            )

    def learning_rate(self, epoch: float, total_epochs: int) -> float:
        """Learning rate at (fractional, 0-based) ``epoch`` of a run of ``total_epochs``.

        ``epoch`` = completed epochs + fraction of the current epoch's steps done: a pure function of
        the position in the run, so a resumed run gets the same rates.
        """
        if total_epochs <= 0 or self.lr_schedule == "constant":
            return self.lr
        t = min(max(epoch / total_epochs, 0.0), 1.0)
        if self.lr_schedule == "cosine":
            return self.lr * 0.5 * (1.0 + math.cos(math.pi * t))
        start = self.lr / ONECYCLE_DIV_FACTOR
        end = start / ONECYCLE_FINAL_DIV_FACTOR
        if t < ONECYCLE_PCT_START:
            return _cosine_between(start, self.lr, t / ONECYCLE_PCT_START)
        return _cosine_between(self.lr, end, (t - ONECYCLE_PCT_START) / (1.0 - ONECYCLE_PCT_START))

    @property
    def extendable(self) -> bool:
        """True when the learning rate does not depend on the run's total of epochs (the constant
        schedule): a run of N epochs is then the first N epochs of any longer run, and a resumed
        run may raise its total (``hdnet.run_record.schedule_refusal``)."""
        return self.lr_schedule == "constant"

    def model_config(self, in_channels: int) -> ModelConfig:
        """The SegNet this profile trains on inputs of ``in_channels`` channels (width, depth, dropout)."""
        return ModelConfig(in_channels=in_channels, width=self.width, depth=self.depth, dropout_p=self.dropout_p)

    def to_dict(self) -> dict[str, object]:
        """Plain-type dictionary (config.json, checkpoints)."""
        out = asdict(self)
        out["extra_channels"] = list(self.extra_channels)
        # At their defaults they are left out, so the profiles saved before them read back equal.
        for key in ("precision", "fast_dropout"):
            if out[key] == _FIELD_DEFAULTS[key]:
                del out[key]
        if self.train_sigma_range_m is None:
            del out["train_sigma_range_m"]  # so the profiles saved before it read back equal
        else:
            out["train_sigma_range_m"] = list(self.train_sigma_range_m)
        return out


_FIELD_DEFAULTS: dict[str, object] = {f.name: f.default for f in fields(TrainingProfile)}


def _cosine_between(start: float, end: float, fraction: float) -> float:
    """Cosine interpolation from ``start`` (fraction 0) to ``end`` (fraction 1)."""
    return end + (start - end) * 0.5 * (1.0 + math.cos(math.pi * fraction))


PAPER = TrainingProfile(
    name="paper",
    input_size=defaults.INPUT_SIZE_PX,
    width=1.0,
    batch_size=defaults.BATCH_SIZE,
    lr=defaults.LEARNING_RATE,
    momentum=defaults.MOMENTUM,
    epochs=defaults.EPOCHS,
    optimizer="sgd",
)
CPU = TrainingProfile(
    name="cpu",
    input_size=None,
    width=0.5,
    batch_size=8,
    lr=1e-3,
    momentum=0.9,
    epochs=40,
    optimizer="adam",
    lr_schedule="cosine",
    depth=2,
    dropout_p=0.2,
    heights="median",
    extra_channels=("slope", "highpass"),
    augment="d4",
    channels_last=True,
)
ROBUST = replace(
    CPU,
    name="robust",
    width=0.75,
    extra_channels=("slope", "highpass", "sigma"),
    train_sigma_range_m=(0.0, 0.10),
    precision="bfloat16",
    fast_dropout=True,
)
# hd choice, made on the validation split (docs/results.md, "One network for all noise levels"):
# the rule of runs trained across noise levels, used with `--calibrate each` (H_t from the
# validation entropies at the sensor's noise level, guarded above the training range).
ROBUST_THRESHOLD_SPEC = "quantile:0.68"
TINY = TrainingProfile(
    name="tiny", input_size=None, width=1 / 16, batch_size=4, lr=1e-3, momentum=0.9, epochs=2, optimizer="adam"
)

PROFILES: dict[str, TrainingProfile] = {p.name: p for p in (PAPER, CPU, ROBUST, TINY)}


def get_profile(name: str) -> TrainingProfile:
    """The profile called ``name`` (paper, cpu, robust, tiny)."""
    try:
        return PROFILES[name]
    except KeyError as exc:
        raise HdNetError(f"unknown training profile {name!r}; choose one of {', '.join(PROFILES)}.") from exc


def profile_from_dict(data: Mapping[str, object]) -> TrainingProfile:
    """Rebuild a profile saved with ``to_dict`` (e.g. from a checkpoint or config.json); fields a
    profile saved by an older hd lacks take their defaults (the paper's choices)."""
    try:
        return TrainingProfile(**data)  # type: ignore[arg-type]  # saved fields, checked by TrainingProfile
    except TypeError as exc:
        raise HdNetError(f"saved training profile does not match TrainingProfile: {exc}.") from exc
