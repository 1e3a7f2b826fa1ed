"""From a stored DEM to the network input: the one preparation used by training, evaluation and inference.

``network_input(dem_m, spec)`` turns a DEM (metres, north-up, NaN where there is no data) into the
tensor the network sees, following an ``InputSpec`` that every run stores in its ``config.json``
and checkpoints (``extra_config["input"]``), so inference prepares inputs exactly like training:

1. holes: NaN cells take the value of the nearest finite cell (``fill_holes``);
2. heights channel (``InputSpec.heights``):

   * ``minmax`` (the paper): ``(z - min) / (max - min)`` with the training split's min and max
     heights (``Normalisation``); about 30 m of relief over the dataset squeezes 0.2 m of
     roughness into 1 % of the range;
   * ``median``: ``(z - median(z)) / height_scale_m``, each DEM relative to its own median height,
     in units of ``height_scale_m`` metres (tilt kept);
   * ``plane``: ``(z - plane(z)) / height_scale_m``, relative to the DEM's least-squares plane
     (tilt of the whole DEM removed: use with the ``slope`` channel);

3. extra channels (``InputSpec.extra_channels``), in the order given:

   * ``slope``: tangent of the local slope angle, ``|grad z|`` by central differences at the DEM
     spacing (unitless; one-sided at the border);
   * ``highpass``: ``z`` minus its mean over a ``highpass_window_m`` box (edges replicated), in
     units of ``height_scale_m`` metres: rocks and pits at lander scale, without the hills;
   * ``sigma``: the sensor's range-noise level, constant over the grid, in units of
     ``SIGMA_CHANNEL_SCALE_M`` (a flash LiDAR knows its noise specification): the DEM's noise
     level told to the network (training: the sample's sigma; evaluation and ``hd detect``: the
     sensor's);

4. grid: with ``input_size`` the channels are resized bilinearly to ``input_size`` squared (the
   paper's 512); without it they are padded on the bottom and right to a multiple of
   ``size_multiple`` (2**depth of the network) by edge replication. ``to_network_grid`` does the
   same to label masks (nearest neighbour, or padding with a given value) and ``to_dem_grid``
   brings network outputs back to the DEM grid.

Every channel is a function of the DEM (and the constant noise level) alone and commutes with the
eight rotations and flips of the grid (D4), so augmenting the DEM or its channels is the same.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
import torch.nn.functional as F
from scipy import ndimage

from hdcore.bounds import Bound
from hdcore.setting import check, setting
from hdnet import defaults
from hdnet.errors import HdNetError
from hdnet.run_json import InputSpecJson, NormalisationJson

Heights = Literal["minmax", "median", "plane"]
HEIGHTS: tuple[str, ...] = ("minmax", "median", "plane")
EXTRA_CHANNELS: tuple[str, ...] = ("slope", "highpass", "sigma")
# hd choice: the sigma channel holds sigma / 5 cm (about 0.3 at the paper's 1.67 cm, 1.4 at 7 cm).
SIGMA_CHANNEL_SCALE_M = 0.05
_POSITIVE = Bound(0.0, low_open=True)
_COUNT = Bound(1, integer=True)
HIGHPASS_WINDOW_M = 10.0  # hd choice: the lander diameter (the paper's 10 m lander), the scale of the hazard rule
INPUT_SCHEMA_VERSION = 1


@dataclass(frozen=True)
class Normalisation:
    """Min-max normalisation of heights: ``(z - min_m) / (max_m - min_m)`` (metres in, unitless out)."""

    min_m: float
    max_m: float

    def apply(self, dem_m: np.ndarray) -> np.ndarray:
        """Normalised heights (float32); a flat training set (max == min) only subtracts the min."""
        span = self.max_m - self.min_m
        return ((np.asarray(dem_m, np.float64) - self.min_m) / (span if span > 0 else 1.0)).astype(np.float32)

    def to_dict(self) -> NormalisationJson:
        return {"min_m": float(self.min_m), "max_m": float(self.max_m)}

    @classmethod
    def from_dict(cls, data: object) -> Normalisation:
        try:
            if not isinstance(data, dict):
                raise TypeError("not a dictionary")
            return cls(float(data["min_m"]), float(data["max_m"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise HdNetError(f"a normalisation needs numeric 'min_m' and 'max_m', got {data!r}.") from exc


@dataclass(frozen=True)
class InputSpec:
    """How a DEM becomes the network input (see the module docstring). Each field's meaning, unit
    and range is its metadata (``hdcore.setting``), from which the checks here are made;
    ``normalisation`` is the training split's min/max heights (metres), required for ``minmax`` only.
    """

    heights: Heights = setting("minmax", "How the heights enter", choices=HEIGHTS, cli=False)
    normalisation: Normalisation | None = None
    height_scale_m: float = setting(
        1.0, "Input unit of the median/plane heights and of highpass", unit="metres", bound=_POSITIVE, cli=False
    )
    extra_channels: tuple[str, ...] = setting((), "Channels after the heights", kind=str, cli=False)
    highpass_window_m: float = setting(
        HIGHPASS_WINDOW_M, "Side of the highpass averaging box", unit="metres", bound=_POSITIVE, cli=False
    )
    spacing_m: float = setting(
        1.0, "DEM spacing (for slope and the highpass window)", unit="metres/pixel", bound=_POSITIVE, cli=False
    )
    input_size: int | None = setting(
        None, "Square size the channels are resized to (None: padded)", unit="pixels", bound=_COUNT, cli=False
    )
    size_multiple: int = setting(
        defaults.SIZE_MULTIPLE_PX,
        "Padding multiple (the network's 2**depth) when input_size is None",
        unit="pixels",
        bound=_COUNT,
        cli=False,
    )

    def __post_init__(self) -> None:
        check(self, HdNetError)
        if self.heights == "minmax" and self.normalisation is None:
            raise HdNetError("minmax heights need the training split's normalisation (min and max heights).")
        bad = [c for c in self.extra_channels if c not in EXTRA_CHANNELS]
        if bad or len(set(self.extra_channels)) != len(self.extra_channels):
            raise HdNetError(
                f"extra channels must be distinct names from {', '.join(EXTRA_CHANNELS)}, "
                f"got {list(self.extra_channels)}."
            )

    @property
    def n_channels(self) -> int:
        """Input channels of the network: the heights plus the extra channels."""
        return 1 + len(self.extra_channels)

    @property
    def rule(self) -> str:
        """The grid rule in words: ``resize:N`` or ``pad:M``."""
        return f"resize:{self.input_size}" if self.input_size is not None else f"pad:{self.size_multiple}"

    def to_dict(self) -> InputSpecJson:
        """Plain-type dictionary (config.json, checkpoints' ``extra_config["input"]``)."""
        return {
            "schema_version": INPUT_SCHEMA_VERSION,
            "heights": self.heights,
            "normalisation": None if self.normalisation is None else self.normalisation.to_dict(),
            "height_scale_m": float(self.height_scale_m),
            "extra_channels": list(self.extra_channels),
            "highpass_window_m": float(self.highpass_window_m),
            "spacing_m": float(self.spacing_m),
            "input_size": self.input_size,
            "size_multiple": int(self.size_multiple),
        }

    @classmethod
    def from_dict(cls, data: object) -> InputSpec:
        """Rebuild a spec written by ``to_dict``."""
        if not isinstance(data, dict):
            raise HdNetError(f"an input spec must be a dictionary, got {type(data).__name__}.")
        version = data.get("schema_version", INPUT_SCHEMA_VERSION)
        if version != INPUT_SCHEMA_VERSION:
            raise HdNetError(
                f"input spec schema version {version} is not readable by this hdnet (reads {INPUT_SCHEMA_VERSION})."
            )
        known = {
            "heights",
            "normalisation",
            "height_scale_m",
            "extra_channels",
            "highpass_window_m",
            "spacing_m",
            "input_size",
            "size_multiple",
        }
        unknown = set(data) - known - {"schema_version"}
        if unknown:
            raise HdNetError(f"input spec has unknown field(s) {sorted(unknown)}.")
        kwargs = {k: data[k] for k in known if k in data}
        if kwargs.get("normalisation") is not None:
            kwargs["normalisation"] = Normalisation.from_dict(kwargs["normalisation"])
        kwargs["extra_channels"] = tuple(kwargs.get("extra_channels", ()))
        if kwargs.get("input_size") is not None:
            kwargs["input_size"] = int(kwargs["input_size"])
        return cls(**kwargs)

    @classmethod
    def from_run_config(
        cls, extra_config: Mapping[str, object], model_config: Mapping[str, object] | None = None
    ) -> InputSpec:
        """The input spec of a trained run from its ``extra_config`` (and model config).

        Runs written before input specs existed stored only ``normalisation`` and ``input_size``:
        they read as ``minmax`` heights with that normalisation, one channel, padding to 32.
        """
        extra = extra_config or {}
        if "input" in extra:
            return cls.from_dict(extra["input"])
        if "normalisation" not in extra:
            raise HdNetError(
                "the run config holds no input spec and no normalisation: it was not trained by hdnet.fit."
            )
        size = extra.get("input_size")
        depth = (model_config or {}).get("depth", len(defaults.ENCODER_CHANNELS))
        if (size is not None and not isinstance(size, int)) or not isinstance(depth, int):
            raise HdNetError(f"the run config's input size {size!r} or depth {depth!r} is not an integer.")
        return cls(
            heights="minmax",
            normalisation=Normalisation.from_dict(extra["normalisation"]),
            input_size=size,
            size_multiple=2**depth,
        )


# --- step 1: holes ------------------------------------------------------------------------------
def fill_holes(dem_m: np.ndarray) -> np.ndarray:
    """NaN cells take the value of the nearest finite cell (Euclidean); an all-NaN DEM becomes zeros."""
    bad = ~np.isfinite(dem_m)
    if not bad.any():
        return dem_m
    if bad.all():
        return np.zeros_like(dem_m)
    idx = ndimage.distance_transform_edt(bad, return_distances=False, return_indices=True)
    return dem_m[tuple(idx)]


# --- steps 2-3: channels ------------------------------------------------------------------------
def plane_residual(dem_m: np.ndarray, spacing_m: float = 1.0) -> np.ndarray:
    """``z`` minus its least-squares plane ``a + b x + c y`` over the whole grid (metres, float64)."""
    z = np.asarray(dem_m, np.float64)
    rows, cols = np.indices(z.shape, dtype=np.float64)
    design = np.stack([np.ones(z.size), cols.ravel() * spacing_m, rows.ravel() * spacing_m], axis=1)
    coef, *_ = np.linalg.lstsq(design, z.ravel(), rcond=None)
    return z - (design @ coef).reshape(z.shape)


def slope_tangent(dem_m: np.ndarray, spacing_m: float) -> np.ndarray:
    """Tangent of the local slope, ``sqrt(dz/dx^2 + dz/dy^2)``, central differences (unitless, float64)."""
    z = np.asarray(dem_m, np.float64)
    if min(z.shape) < 2:
        return np.zeros_like(z)
    dy, dx = np.gradient(z, spacing_m)
    return np.hypot(dx, dy)


def highpass(dem_m: np.ndarray, window_px: int) -> np.ndarray:
    """``z`` minus its mean over a ``window_px`` square box, edges replicated (metres, float64)."""
    z = np.asarray(dem_m, np.float64)
    return z - ndimage.uniform_filter(z, size=window_px, mode="nearest")


def highpass_window_px(spec: InputSpec) -> int:
    """The ``highpass`` box side in pixels: ``highpass_window_m / spacing_m`` rounded to an odd count >= 1."""
    n = max(1, int(round(spec.highpass_window_m / spec.spacing_m)))
    return n if n % 2 else n + 1


def input_channels(dem_filled_m: np.ndarray, spec: InputSpec, sigma_m: float | None = None) -> np.ndarray:
    """Steps 2-3 on a hole-free DEM: (C, H, W) float32 on the DEM grid; ``sigma_m`` (metres) for the
    ``sigma`` channel."""
    z = np.asarray(dem_filled_m, np.float64)
    if spec.heights == "minmax":
        assert spec.normalisation is not None  # checked by InputSpec
        first = spec.normalisation.apply(z).astype(np.float64)
    elif spec.heights == "median":
        first = (z - np.median(z)) / spec.height_scale_m
    else:
        first = plane_residual(z, spec.spacing_m) / spec.height_scale_m
    channels = [first]
    for name in spec.extra_channels:
        if name == "slope":
            channels.append(slope_tangent(z, spec.spacing_m))
        elif name == "sigma":
            channels.append(np.full(z.shape, _sigma_channel(sigma_m)))
        else:
            channels.append(highpass(z, highpass_window_px(spec)) / spec.height_scale_m)
    return np.stack(channels).astype(np.float32)


def _sigma_channel(sigma_m: float | None) -> float:
    if sigma_m is None:
        raise HdNetError("this run takes the sensor's noise level as an input: give the DEM's sigma in metres.")
    if isinstance(sigma_m, bool) or not isinstance(sigma_m, (int, float)) or not math.isfinite(sigma_m) or sigma_m < 0:
        raise HdNetError(f"the DEM's sigma must be a finite number of metres >= 0, got {sigma_m!r}.")
    return float(sigma_m) / SIGMA_CHANNEL_SCALE_M


def takes_sigma(spec: InputSpec) -> bool:
    """True when the network of ``spec`` receives the sensor's noise level as an input channel."""
    return "sigma" in spec.extra_channels


# --- step 4: grids ------------------------------------------------------------------------------
def network_shape(
    dem_shape: tuple[int, int], input_size: int | None, size_multiple: int = defaults.SIZE_MULTIPLE_PX
) -> tuple[int, int]:
    """(H, W) the network sees: ``input_size`` squared, or the DEM padded to a multiple of ``size_multiple``."""
    if input_size is not None:
        return int(input_size), int(input_size)
    m = int(size_multiple)
    rows, cols = dem_shape
    return int(math.ceil(rows / m) * m), int(math.ceil(cols / m) * m)


def to_network_grid(
    image: torch.Tensor,
    masks: list[torch.Tensor],
    input_size: int | None,
    pad_values: list[int],
    size_multiple: int = defaults.SIZE_MULTIPLE_PX,
) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """Image (C, h, w) float and masks (h, w) to the network grid (step 4 of the module docstring)."""
    h, w = image.shape[-2:]
    H, W = network_shape((h, w), input_size, size_multiple)
    if input_size is not None:
        img = F.interpolate(image[None], size=(H, W), mode="bilinear", align_corners=False)[0]
    elif (h, w) != (H, W):
        img = F.pad(image[None], (0, W - w, 0, H - h), mode="replicate")[0]
    else:
        img = image
    return img, masks_to_network_grid(masks, input_size, pad_values, size_multiple)


def masks_to_network_grid(
    masks: list[torch.Tensor],
    input_size: int | None,
    pad_values: list[int],
    size_multiple: int = defaults.SIZE_MULTIPLE_PX,
) -> list[torch.Tensor]:
    """Masks (h, w) to the network grid: nearest neighbour (``nearest-exact``) to ``input_size``, or
    padded on the bottom and right with ``pad_values`` (one per mask) to a multiple of ``size_multiple``."""
    out = []
    for m, v in zip(masks, pad_values, strict=False):  # pad_values may name more masks than given
        h, w = m.shape[-2:]
        H, W = network_shape((h, w), input_size, size_multiple)
        if input_size is not None:
            out.append(F.interpolate(m[None, None].float(), size=(H, W), mode="nearest-exact")[0, 0].to(m.dtype))
        else:
            out.append(F.pad(m, (0, W - w, 0, H - h), value=v))
    return out


def to_dem_grid(probs: torch.Tensor, dem_shape: tuple[int, int], input_size: int | None) -> torch.Tensor:
    """Network-grid probabilities (N, C, H, W) back to the DEM grid (N, C, h, w).

    Padding: crop the top-left ``dem_shape``. Resizing: the mean over the network pixels covering
    each DEM cell (``area`` interpolation = adaptive average pooling), which keeps probabilities summing to 1.
    """
    h, w = dem_shape
    if input_size is None:
        return probs[..., :h, :w]
    return F.interpolate(probs, size=(h, w), mode="area")


# --- the whole preparation ----------------------------------------------------------------------
def network_input(dem_m: np.ndarray, spec: InputSpec, sigma_m: float | None = None) -> torch.Tensor:
    """The network input (C, H, W) float32 of one DEM (metres, NaN = no data): steps 1-4.

    ``sigma_m``: the DEM's range-noise level, metres; needed when ``spec`` has the ``sigma`` channel.

    This is the only place a DEM becomes a network input; ``HazardDataset`` (training and
    evaluation) and inference on new DEMs all call it with the run's ``InputSpec``.
    """
    dem = np.asarray(dem_m)
    if dem.ndim != 2 or min(dem.shape) < 1:
        raise HdNetError(f"a DEM must be a non-empty 2-D array of heights, got shape {dem.shape}.")
    channels = torch.from_numpy(input_channels(fill_holes(dem.astype(np.float32, copy=False)), spec, sigma_m))
    image, _ = to_network_grid(channels, [], spec.input_size, [], spec.size_multiple)
    return image.contiguous()


def network_inputs(
    dems_m: np.ndarray | list[np.ndarray], spec: InputSpec, sigma_m: float | None = None
) -> torch.Tensor:
    """A batch (N, C, H, W) from N DEMs of one shape and noise level (``network_input`` of each)."""
    return torch.stack([network_input(d, spec, sigma_m) for d in dems_m])
