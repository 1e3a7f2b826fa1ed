"""Torch dataset over the label shards of one split: noisy DEM in, ALHAT label out (docs/evaluation.md).

One sample is one scan: the noisy DEM at one noise level ``sigma_m`` (metres), prepared for the
network, and its label (0 unsafe, 1 safe, 255 ignored), as a dict
``{"image": (C, H, W) float32, "mask": (H, W) int64, "index": int, "sigma_m": float}`` (plus
``"ignore"``, bool (H, W), with dead pixels).

The noisy DEM is the labelling's stored one when the dataset stores that noise level; otherwise it
is made from the scan's clean points with the factory's noise model and the labelling's gridding
(``hdlabels.noisy``; equal to the stored DEM at a stored level), and its ALHAT baseline P(safe) is
computed when asked for (``baseline_p_safe``). With ``noise`` (a ``TrainingNoise`` of several
levels or a range), every sample draws its level, and its D4 transform, from the stream
``(seed, TRAINING_DRAW, epoch, scan index)`` and its noise from an independent realisation per
epoch (``set_epoch``): the same samples whatever the number of DataLoader workers.

Preparation, in order:

1. dead pixels (``dead_pixels=K`` only): K pixels of the noisy DEM, drawn per scan index with
   ``hdlabels.deadpixels.random_dead_pixels`` (the same pixels for every noise level, seeded by
   ``(seed, scan index)``), dropped and refilled by ``hdlabels.deadpixels.drop_and_repair``; its
   lander-size neighbourhood mask becomes ``"ignore"``;
2. holes: NaN cells of the noisy DEM (no lidar return) take the value of the nearest finite cell
   (Euclidean distance, ``scipy.ndimage.distance_transform_edt``) and their label is set to 255;
3. augmentation (``augment="d4"``, training only): one of the eight rotations/flips of the square
   grid, drawn uniformly from torch's random stream, applied to the DEMs, label and masks alike
   (``hdnet.augment``; allowed only for labellings whose rule is invariant under them);
4. the input channels of ``hdnet.inputs.network_input`` with the run's ``InputSpec``: the paper's
   min-max normalisation with the *training* split's min and max at the same noise level
   (``compute_normalisation``) by default, or per-DEM relative heights and extra channels (the
   ``sigma`` channel takes the sample's noise level);
5. grid: with ``input_size`` (the ``paper`` profile: 512) the image is resized bilinearly
   (``align_corners=False``) to ``input_size x input_size`` and the label and ignore mask by
   nearest neighbour (``nearest-exact``); without it the image is padded on the bottom and right to
   the next multiple of the network's 2**depth (32 for the paper's depth) by edge replication and
   the label with 255 (never trained on).

``to_dem_grid`` undoes step 5 for network outputs: crop for padding, area averaging of the
probabilities over each DEM cell for resizing, so metrics are always computed on the DEM grid.

The h5py handles are opened lazily in the process that reads (re-opened after a fork), never
pickled: the dataset works with ``DataLoader(num_workers > 0)``. Every label shard is checked
against the manifest's sha256 and schema when the dataset is made, and every later read error
(a chunk whose fletcher32 checksum fails) names the file and the scan (``hdcore.storage``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import ConcatDataset, Dataset

from hdcore.errors import HdError
from hdcore.storage import CheckedH5File
from hdlabels.alhat import safety_probability
from hdlabels.deadpixels import drop_and_repair, random_dead_pixels
from hdlabels.noisy import CleanScan, NoisyDems
from hdlabels.store import LabelingEntry, LabelShardReader, find_labeling, open_label_shard
from hdnet import defaults
from hdnet.augment import D4_ORDER, check_augment, transform_sample
from hdnet.errors import HdNetError
from hdnet.inputs import (  # noqa: F401  (re-exported: the grid helpers belong to the input preparation)
    InputSpec,
    Normalisation,
    fill_holes,
    masks_to_network_grid,
    network_input,
    network_shape,
    to_dem_grid,
    to_network_grid,
)
from hdnet.noise_levels import TrainingNoise, check_levels
from hdnet.sample import DemSample
from lidarsim.location import dataset_label, is_url, open_h5_at
from lidarsim.streams import Purpose, stream

SPLITS: tuple[str, str, str] = ("train", "val", "test")  # split codes 0, 1, 2 of the label shards
ALL_SPLITS = "all"  # every scan of the dataset, each once, in shard order (hd eval --split all)
SIGMA_EXACT_TOLERANCE_M = 1e-9  # hd choice: two noise levels closer than this are the same level
# hd choice: a requested sigma also matches a dataset sigma that rounds to it at 0.1 mm (e.g. 0.0167
# for S-167 = 0.05/3 m, as written on the command line), when exactly one dataset sigma does.
SIGMA_PRINTED_TOLERANCE_M = 0.5e-4
DEAD_PIXEL_STREAM = 0xDEAD  # hd choice: stream key of the dead-pixel draws, (seed, scan index, this)


# --- labelling and noise levels ----------------------------------------------------------------
def split_codes(split: str) -> tuple[int, ...]:
    """The label shards' split codes of ``split``: one of ``SPLITS``, or all three for ``ALL_SPLITS``.

    Raises:
        HdNetError: any other name.
    """
    if split == ALL_SPLITS:
        return tuple(range(len(SPLITS)))
    if split not in SPLITS:
        raise HdNetError(f"split must be one of {', '.join(SPLITS)} or {ALL_SPLITS}, got {split!r}.")
    return (SPLITS.index(split),)


def open_labeling(dataset_dir: str | os.PathLike, labels: str | None = None) -> tuple[LabelingEntry, list[Path | str]]:
    """The labelling entry of a dataset and its label shard paths (``LabelStoreError`` when there are no labels)."""
    entry = find_labeling(dataset_dir, labels)
    return entry, entry.shard_paths(dataset_dir)


def dataset_sigmas(paths: list[Path | str], sha256: str | None = None) -> tuple[float, ...]:
    """Noise levels (metres) of a labelling, read from its first label shard.

    ``sha256``: the manifest's checksum of that shard; at a URL, a shard this process has fetched and
    checked already is then read again without a request (a local file is not hashed for it).
    """
    if not paths:
        raise HdNetError("the labelling lists no label shards.")
    with LabelShardReader(paths[0], sha256=sha256 if is_url(paths[0]) else None) as reader:
        return reader.sigmas_m


def format_sigmas(sigmas_m: tuple[float, ...]) -> str:
    return ", ".join(f"{s:.6g}" for s in sigmas_m)


def sigma_index(sigmas_m: tuple[float, ...], sigma_m: float) -> int:
    """Index of ``sigma_m`` (metres) among a dataset's noise levels.

    Exact within 1e-9 m; else the one dataset sigma within 0.05 mm (what 0.1 mm rounding allows,
    e.g. 0.0167 for 0.05/3). Raises HdNetError naming the available levels otherwise.
    """
    if not isinstance(sigma_m, (int, float)) or not math.isfinite(sigma_m):
        raise HdNetError(f"sigma must be a finite number of metres, got {sigma_m!r}.")
    for tol in (SIGMA_EXACT_TOLERANCE_M, SIGMA_PRINTED_TOLERANCE_M):
        hits = [k for k, s in enumerate(sigmas_m) if abs(s - sigma_m) <= tol]
        if len(hits) == 1:
            return hits[0]
    raise HdNetError(f"sigma {sigma_m:g} m is not in the dataset; it has {format_sigmas(sigmas_m)} m.")


def split_labels(dataset_dir: str | os.PathLike, split: str, labels: str) -> dict[int, np.ndarray]:
    """The labels of every scan of ``split`` (one of ``SPLITS``, or ``ALL_SPLITS``) under the labelling
    ``labels``, by scan index, as stored (uint8 DEM grids: 1 safe, 0 unsafe, 255 invalid), every label
    shard checked before it is read."""
    codes = split_codes(split)
    entry = find_labeling(dataset_dir, labels)
    out: dict[int, np.ndarray] = {}
    for shard in entry.shards:
        with open_label_shard(dataset_dir, shard) as reader:
            f = reader.h5
            rows = np.flatnonzero(np.isin(f["split"][:], codes))
            if rows.size:
                scans = f["scan_index"][:]
                block = f["label"][rows[0] : rows[-1] + 1][rows - rows[0]]
                out.update((int(scans[r]), block[k]) for k, r in enumerate(rows))
    return out


# --- normalisation -----------------------------------------------------------------------------
def compute_normalisation(dataset_dir: str | os.PathLike, sigma_m: float, labels: str | None = None) -> Normalisation:
    """Min and max (metres) of the finite noisy-DEM heights at ``sigma_m`` over the training split only."""
    entry, paths = open_labeling(dataset_dir, labels)
    return labeling_normalisation(dataset_dir, entry, dataset_sigmas(paths, entry.first_sha256), sigma_m)


def labeling_normalisation(
    dataset_dir: str | os.PathLike, entry: LabelingEntry, sigmas_m: tuple[float, ...], sigma_m: float
) -> Normalisation:
    """:func:`compute_normalisation` of a labelling entry already read from the manifest (with its
    noise levels ``sigmas_m``, metres): the manifest is not read again."""
    s = sigma_index(sigmas_m, sigma_m)
    lo, hi = math.inf, -math.inf
    for shard in entry.shards:
        with open_label_shard(dataset_dir, shard) as reader:
            f = reader.h5
            rows = np.flatnonzero(f["split"][:] == 0)
            if rows.size == 0:
                continue
            dem = f["dem_noisy"][rows[0] : rows[-1] + 1, s][rows - rows[0]]
            finite = dem[np.isfinite(dem)]
            if finite.size:
                lo, hi = min(lo, float(finite.min())), max(hi, float(finite.max()))
    if not math.isfinite(lo):
        raise HdNetError(
            f"{dataset_label(dataset_dir)}: the training split has no scan with a finite height at sigma {sigma_m:g} m."
        )
    return Normalisation(lo, hi)


# --- the dataset -------------------------------------------------------------------------------
class HazardDataset(Dataset):
    """Samples of one split of a labelled dataset at one noise level, or drawn from several (see the
    module docstring).

    Args:
        dataset_dir: the dataset directory (``manifest.json`` with a labelling).
        split: ``train``, ``val`` or ``test``; ``all`` (``ALL_SPLITS``): every scan, in shard order.
        sigma_m: noise level of the input DEM, metres (stored in the dataset, or made on the fly);
            with ``noise`` of several levels or a range: None.
        input_size: network input size in pixels (square, bilinear), or None to pad to a multiple of 32.
        labels: the labelling's name (needed only when the dataset has several).
        normalisation: min/max heights; default: ``compute_normalisation`` on the training split.
        dead_pixels: K pixels dropped and repaired per noisy DEM (0: none).
        seed: seed of the dead-pixel draws and of the noise-level draws.
        input_spec: how DEMs become network inputs (``hdnet.inputs``); when given it replaces
            ``input_size`` and ``normalisation`` (default: the paper's min-max heights with them).
        augment: ``"none"`` or ``"d4"`` (a random rotation/flip per sample; refused for a labelling
            whose lander rule is not invariant under them).
        noise: training noise levels (``hdnet.noise_levels.TrainingNoise``); one level is the
            same as ``sigma_m``.
    """

    def __init__(
        self,
        dataset_dir: str | os.PathLike,
        split: str,
        sigma_m: float | None,
        input_size: int | None = None,
        labels: str | None = None,
        normalisation: Normalisation | None = None,
        dead_pixels: int = 0,
        seed: int = 0,
        input_spec: InputSpec | None = None,
        augment: str = "none",
        noise: TrainingNoise | None = None,
    ) -> None:
        codes = split_codes(split)
        if noise is not None and noise.is_single:
            sigma_m, noise = noise.levels_m[0], None
        if (sigma_m is None) == (noise is None):
            raise HdNetError("give either one noise level (sigma_m) or training noise levels, not both.")
        self.dataset_dir: Path | str = str(dataset_dir).rstrip("/") if is_url(dataset_dir) else Path(dataset_dir)
        self.split = split
        self.entry, self.paths = open_labeling(dataset_dir, labels)
        self.labels = self.entry.name
        self.sigmas_m = dataset_sigmas(self.paths, self.entry.first_sha256)
        self.noise = noise
        self.sigma_index: int | None = None
        if sigma_m is not None:
            self.sigma_index = stored_sigma_index(self.sigmas_m, sigma_m)
            self.sigma_m = self.sigmas_m[self.sigma_index] if self.sigma_index is not None else float(sigma_m)
        else:
            assert noise is not None
            self.sigma_m = math.nan  # drawn per sample
        self.lander = self.entry.lander
        self.spacing_m = self.entry.spacing_m
        self.dem_shape = (self.entry.dem.rows, self.entry.dem.cols)
        n_pixels = self.dem_shape[0] * self.dem_shape[1]
        if (
            isinstance(dead_pixels, bool)
            or not isinstance(dead_pixels, (int, np.integer))
            or not 0 <= dead_pixels < n_pixels
        ):
            raise HdNetError(
                f"the number of dead pixels must be an integer in [0, {n_pixels - 1}], got {dead_pixels!r}."
            )
        self.dead_pixels = int(dead_pixels)
        self.seed = int(seed)
        self.epoch = 0
        items: list[tuple[int, int, int]] = []  # (shard number, row in shard, scan index)
        for k, (path, shard) in enumerate(zip(self.paths, self.entry.shards, strict=True)):
            with open_label_shard(dataset_dir, shard) as reader:
                splits, scans = reader.h5["split"][:], reader.h5["scan_index"][:]
                shard_sigmas = reader.sigmas_m
            if len(shard_sigmas) != len(self.sigmas_m) or any(
                abs(a - b) > SIGMA_EXACT_TOLERANCE_M for a, b in zip(shard_sigmas, self.sigmas_m, strict=True)
            ):
                raise HdNetError(f"{path}: its noise levels differ from the other label shards.")
            items += [(k, int(r), int(scans[r])) for r in np.flatnonzero(np.isin(splits, codes))]
        self.items = items
        if input_spec is None:
            norm = (
                normalisation
                if normalisation is not None
                else labeling_normalisation(dataset_dir, self.entry, self.sigmas_m, self.nearest_stored_sigma_m)
            )
            input_spec = InputSpec(
                heights="minmax", normalisation=norm, input_size=input_size, spacing_m=self.spacing_m
            )
        self.input_spec = input_spec
        self.input_size = input_spec.input_size
        self.normalisation = input_spec.normalisation
        self.augment = check_augment(augment, self.lander)
        self._files: dict[int, CheckedH5File] = {}
        self._pid = -1
        self._clean: list[CleanScan] | None = None
        self._maker: NoisyDems | None = None
        if self.made_on_the_fly:  # read once here: DataLoader workers share them
            self.clean_scans()

    @property
    def made_on_the_fly(self) -> bool:
        """True when the noisy DEMs are made from the clean points (a level the dataset does not store, or drawn)."""
        return self.sigma_index is None

    @property
    def nearest_stored_sigma_m(self) -> float:
        """The stored noise level nearest this dataset's level (the middle of drawn levels), metres."""
        target = self.sigma_m if self.noise is None else 0.5 * (self.noise.low_m + self.noise.high_m)
        return min(self.sigmas_m, key=lambda s: abs(s - target))

    def set_epoch(self, epoch: int) -> None:
        """The training epoch (0-based): with drawn noise, it keys the draws and the noise realisation."""
        self.epoch = int(epoch)

    # Pickling: never the open files.
    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_files"], state["_pid"] = {}, -1
        return state

    def _file(self, k: int) -> CheckedH5File:
        if self._pid != os.getpid():  # first use in this process (e.g. a DataLoader worker after fork)
            self._files, self._pid = {}, os.getpid()
        f = self._files.get(k)
        if f is None:
            # the manifest's sha256: at a URL, the shard checked as the dataset was made is read without a request
            shard = self.entry.shards[k]
            f = self._files[k] = open_h5_at(self.paths[k], sha256=shard.sha256, size_bytes=shard.size_bytes)
        return f

    def close(self) -> None:
        """Close the open label shards of this process."""
        if self._pid == os.getpid():
            for f in self._files.values():
                f.close()
        self._files = {}

    def __len__(self) -> int:
        return len(self.items)

    @property
    def scan_indices(self) -> list[int]:
        """Global scan index of every sample, in order."""
        return [scan for _, _, scan in self.items]

    # --- noisy DEMs made on the fly ---
    def noisy_dems(self) -> NoisyDems:
        """The maker of this dataset's noisy DEMs at any level (``hdlabels.noisy``)."""
        if self._maker is None:
            try:
                self._maker = NoisyDems.of_dataset(self.dataset_dir, self.entry.dem)
            except HdError as exc:  # hd's own errors (storage included), with the dataset named
                raise type(exc)(f"{self.dataset_dir}: {exc}") from exc
        return self._maker

    def clean_scans(self) -> list[CleanScan]:
        """Every sample's clean scan (ranges recovered from the clean points), read once per dataset."""
        if self._clean is None:
            maker = self.noisy_dems()
            by_shard: dict[int, list[int]] = {}
            for n, (k, _row, _scan) in enumerate(self.items):
                by_shard.setdefault(k, []).append(n)
            clean: list[CleanScan | None] = [None] * len(self.items)
            for k, members in by_shard.items():
                shard = self.entry.shards[k]
                try:
                    scans = maker.read_scans(self.dataset_dir, shard, [self.items[n][1] for n in members])
                except (HdError, KeyError) as exc:
                    error = HdNetError if isinstance(exc, KeyError) else type(exc)
                    raise error(
                        f"{self.dataset_dir}: cannot make noisy DEMs from the clean points of "
                        f"{shard.source_path}: {str(exc).rstrip('.')}."
                    ) from exc
                for n, c in zip(members, scans, strict=True):
                    if c.scan_index != self.items[n][2]:
                        raise HdNetError(
                            f"{shard.source_path}: row {self.items[n][1]} holds scan {c.scan_index}, its "
                            f"label shard scan {self.items[n][2]}; relabel the dataset."
                        )
                    clean[n] = c
            self._clean = [c for c in clean if c is not None]
        return self._clean

    def baseline_p_safe(self, sample: DemSample) -> np.ndarray:
        """The ALHAT baseline P(safe) of a sample: stored, or computed on its noisy DEM at its level."""
        if sample.p_safe is not None:
            return sample.p_safe
        return safety_probability(sample.dem_noisy_m, self.spacing_m, sample.sigma_m, self.lander)

    # --- samples ---
    def dem_sample(self, i: int, sigma_m: float | None = None, realisation: int | None = None) -> DemSample:
        """Sample ``i`` on the DEM grid, metres (steps 1-2 of the module docstring).

        ``sigma_m``: another noise level than the dataset's (made on the fly), with the noise
        ``realisation`` (None: the dataset's own draw at that level).
        """
        if not 0 <= i < len(self.items):
            raise IndexError(f"sample {i} out of range for {len(self.items)} samples")
        k, row, scan = self.items[i]
        f = self._file(k)
        if sigma_m is None and self.noise is not None:
            raise HdNetError("a dataset of drawn noise levels needs the sample's sigma.")
        level = self.sigma_m if sigma_m is None else float(sigma_m)
        p_safe: np.ndarray | None = None
        if sigma_m is None and realisation is None and self.sigma_index is not None:
            noisy = f["dem_noisy"][row, self.sigma_index].astype(np.float32)
            p_safe = f["p_safe"][row, self.sigma_index]
        else:
            noisy = self.noisy_dems().dem(self.clean_scans()[i], level, realisation)
        label = f["label"][row].astype(np.int64)
        ignore = np.zeros(noisy.shape, dtype=bool)
        dead = np.zeros((0, 2), dtype=np.int64)
        if self.dead_pixels:
            rng = np.random.default_rng(np.random.SeedSequence([self.seed, scan, DEAD_PIXEL_STREAM]))
            dead = random_dead_pixels(noisy.shape, self.dead_pixels, rng)
            noisy, ignore = drop_and_repair(noisy, dead, self.lander, self.spacing_m)
            p_safe = None  # the baseline of the repaired DEM is computed on it
        holes = ~np.isfinite(noisy)
        label[holes] = defaults.IGNORE_INDEX
        return DemSample(
            scan_index=scan,
            dem_clean_m=f["dem_clean"][row],
            dem_noisy_m=noisy,
            dem_filled_m=fill_holes(noisy),
            label=label,
            p_safe=p_safe,
            ignore=ignore,
            dead_pixels=dead,
            sigma_m=level,
        )

    def prepare(self, sample: DemSample) -> dict[str, Any]:
        """Steps 4-5: the network-ready dict of a DEM-grid sample (``network_input`` for the image)."""
        spec = self.input_spec
        image = network_input(sample.dem_filled_m, spec, sample.sigma_m)
        masks = [torch.from_numpy(np.ascontiguousarray(sample.label))]
        if self.dead_pixels:
            masks.append(torch.from_numpy(np.ascontiguousarray(sample.ignore)))
        masks = masks_to_network_grid(masks, spec.input_size, [defaults.IGNORE_INDEX, True], spec.size_multiple)
        out: dict[str, Any] = {
            "image": image,
            "mask": masks[0].contiguous(),
            "index": sample.scan_index,
            "sigma_m": sample.sigma_m,
        }
        if self.dead_pixels:
            out["ignore"] = masks[1].contiguous()
        return out

    def __getitem__(self, i: int) -> dict[str, Any]:
        if self.noise is not None:  # drawn: level, transform and noise keyed by (seed, epoch, scan)
            rng = stream(self.seed, Purpose.TRAINING_DRAW, self.epoch, self.items[i][2])
            sigma = self.noise.draw(rng)
            transform = int(rng.integers(D4_ORDER))
            sample = self.dem_sample(i, sigma, realisation=self.epoch)
            if self.augment == "d4":
                sample = transform_sample(sample, transform)
            return self.prepare(sample)
        sample = self.dem_sample(i)
        if self.augment == "d4":
            sample = transform_sample(sample, int(torch.randint(D4_ORDER, ())))
        return self.prepare(sample)

    def to_dem_grid(self, probs: torch.Tensor) -> torch.Tensor:
        """Network-grid probabilities (N, C, H, W) of this dataset's samples back to the DEM grid."""
        return to_dem_grid(probs, self.dem_shape, self.input_spec.input_size)


def stored_sigma_index(sigmas_m: tuple[float, ...], sigma_m: float) -> int | None:
    """Index of ``sigma_m`` among the stored levels (as ``sigma_index``), or None when it is not stored
    (a level in [0, ``MAX_SIGMA_M``] made on the fly)."""
    try:
        return sigma_index(sigmas_m, sigma_m)
    except HdNetError:
        check_levels([sigma_m], "sigma")
        return None


class MixedDataset(ConcatDataset):
    """Several datasets read as one (a mix of terrains, ``hd train --also``): their samples one
    after the other; ``set_epoch`` reaches every part that draws per epoch."""

    def set_epoch(self, epoch: int) -> None:
        """The training epoch (0-based), passed on to every part."""
        for part in self.datasets:
            set_part = getattr(part, "set_epoch", None)
            if callable(set_part):
                set_part(epoch)
