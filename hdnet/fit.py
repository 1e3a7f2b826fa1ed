"""Train Bayesian SegNet on a labelled dataset (``hd train``): datasets, input spec, run config.

``fit`` builds the run's ``InputSpec`` from the profile (the paper's min-max heights take the
training split's min and max at the training noise level), the training and validation
``HazardDataset`` at that noise level (D4 augmentation on the training split only, when the profile
asks for it), and hands them to ``hdnet.train.train``. What evaluation and inference need to
prepare new inputs exactly like the training inputs is stored in the run's ``config.json`` and in
every checkpoint under ``extra_config`` (``hdnet.run_record.TrainingData``; ``input`` is the ``InputSpec``).

The run directory is checked before any work (``prepare_run_dir``: a writable place, not the
dataset nor inside it; a non-empty directory that is not an hd run is refused, ``overwrite`` or
not) and written under its writer lock, so two trainings never share a run directory.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from torch.utils.data import ConcatDataset, Dataset

from hdcore.errors import HdWarning, StorageError
from hdcore.setting import DIRECTORY, check, setting
from hdcore.storage import (
    LOCK_NAME,
    PARTIAL_MARK,
    OutputTransaction,
    check_not_input,
    check_output_dir,
    check_regular_file,
    read_regular_bytes,
    read_regular_text,
    sha256_bytes,
)
from hdlabels.store import LabelingEntry
from hdnet import defaults, limits
from hdnet.augment import check_augment
from hdnet.checkpoint_json import CheckpointJson, EpochProgress
from hdnet.data import (
    HazardDataset,
    MixedDataset,
    compute_normalisation,
    dataset_sigmas,
    open_labeling,
)
from hdnet.errors import HdNetError
from hdnet.inputs import InputSpec, Normalisation
from hdnet.noise_levels import TrainingNoise
from hdnet.profiles import PROFILES, TrainingProfile, get_profile
from hdnet.run_check import RUN_FILES, check_run
from hdnet.run_record import CONFIG, RUN_SCHEMA, AlsoDataset, TrainingData, checkpoint_data, schedule_refusal
from hdnet.train import LAST, load_checkpoint, train
from lidarsim import limits as lidar_limits
from lidarsim.location import dataset_key, dataset_label, has_manifest, is_url, manifest_sha256
from lidarsim.shards import MANIFEST_NAME


def input_spec_for(profile: TrainingProfile, spacing_m: float, normalisation: Normalisation | None) -> InputSpec:
    """The ``InputSpec`` a profile asks for on DEMs of ``spacing_m`` metres per pixel."""
    return InputSpec(
        heights=profile.heights,
        normalisation=normalisation,
        height_scale_m=profile.height_scale_m,
        extra_channels=tuple(profile.extra_channels),
        spacing_m=spacing_m,
        input_size=profile.input_size,
        size_multiple=2**profile.depth,
    )


def training_data(
    dataset_dir: str | os.PathLike,
    labels: str,
    sigma_m: float,
    spec: InputSpec,
    dem_shape: tuple[int, int],
    labeling: LabelingEntry | None = None,
    noise: TrainingNoise | None = None,
    also: tuple[str | os.PathLike, ...] = (),
) -> TrainingData:
    """The training data of a run (its ``extra_config``, ``hdnet.run_record.TrainingData``): the data
    a model was trained on and how inputs were prepared.

    ``labeling`` is the dataset manifest's entry of the labelling trained on (lander, DEM grid, label
    convention); it is kept without its shard list, so a run can be used without its dataset.
    ``noise``: the training noise levels (default: ``sigma_m`` alone, metres), ``sigma_m`` the
    reference level (``reference_sigma``); ``also``: further training datasets.
    """
    return TrainingData(
        dataset=dataset_key(dataset_dir),
        manifest_sha256=manifest_sha256(dataset_dir),
        labels=labels,
        labeling=None if labeling is None else labeling.without_shards(),
        train_sigma_m=float(sigma_m),
        train_noise=noise if noise is not None else TrainingNoise.single(sigma_m),
        dem_shape=(int(dem_shape[0]), int(dem_shape[1])),
        input=spec,
        also=_also_datasets(also),
    )


def _also_datasets(also: tuple[str | os.PathLike, ...]) -> tuple[AlsoDataset, ...]:
    return tuple(AlsoDataset(dataset_key(d), manifest_sha256(d)) for d in also)


def _manifest_sha256(dataset_dir: str | os.PathLike) -> str | None:
    """The sha256 of a dataset's manifest (a directory's or a URL's); None when it has none (the
    dataset's readers say why).

    Raises:
        StorageError: a manifest that is not a regular file (a FIFO is never opened) or unreadable.
    """
    if is_url(dataset_dir):
        return manifest_sha256(dataset_dir) if has_manifest(dataset_dir) else None
    manifest = Path(dataset_dir) / MANIFEST_NAME
    return sha256_bytes(read_regular_bytes(manifest)) if os.path.lexists(manifest) else None


def check_distinct_datasets(dataset_dir: str | os.PathLike, also: tuple[str | os.PathLike, ...]) -> None:
    """Refuse a mix (``--also``) that names the same data twice: two arguments that resolve to the
    same directory (the dataset itself again, a symbolic link to it), or whose manifests are the same
    bytes (a copy elsewhere: the manifest lists every file's sha256). Such a mix would train on the
    same scans twice per epoch and record two datasets where there is one.

    Raises:
        HdNetError: naming the two arguments, as given, that are the same data.
    """
    seen: list[tuple[str, str, str | None]] = []
    for name, given in (
        (f"DATASET {dataset_label(dataset_dir)}", dataset_dir),
        *((f"--also {dataset_label(d)}", d) for d in also),
    ):
        root = dataset_key(given)
        digest = _manifest_sha256(given)
        for earlier, earlier_root, earlier_digest in seen:
            if root == earlier_root:
                why = f"the same directory, {root}"
            elif digest is not None and digest == earlier_digest:
                why = f"byte-identical manifests, sha256 {digest[:12]}..."
            else:
                continue
            raise HdNetError(
                f"{earlier} and {name} are the same data ({why}): a mix would train on their scans twice; "
                "give each dataset once."
            )
        seen.append((name, root, digest))


def is_run_dir(run_dir: str | os.PathLike) -> bool:
    """True when ``run_dir`` holds an hd run (a checkpoint, or the config.json ``train`` writes)."""
    run_dir = Path(run_dir)
    if (run_dir / LAST).is_file():
        return True
    try:
        return json.loads(read_regular_text(run_dir / CONFIG)).get("schema") == RUN_SCHEMA
    except (OSError, ValueError, AttributeError):
        return False


def prepare_run_dir(
    run_dir: str | os.PathLike, resume: bool, overwrite: bool, dataset: str | os.PathLike | None = None
) -> tuple[Path, bool]:
    """Check a run directory before any work; returns (absolute path, whether an old run is replaced).

    Raises:
        HdNetError: an unwritable place; a directory that is, holds or lies inside ``dataset``; a
            non-empty directory that is not an hd run (``overwrite`` or not: it replaces runs only);
            a run with a checkpoint and neither ``resume`` nor ``overwrite``.
        StorageError: a run file (checkpoint, config.json, metrics.csv) that is not a regular file
            (``overwrite`` or not).
    """
    path = check_output_dir(run_dir, "--out")
    check_not_input(run_dir, {"the dataset": dataset})
    if not path.exists():
        return path, False
    content = [p for p in path.iterdir() if p.name != LOCK_NAME and PARTIAL_MARK not in p.name]
    if not content:
        return path, False
    if not is_run_dir(path):
        raise HdNetError(
            f"{path} is not empty and is not an hd run; choose another --out (--overwrite replaces an hd run, "
            "never other files)."
        )
    for name in RUN_FILES:  # a FIFO, device or directory in a run file's place is not hd's: never opened nor replaced
        if os.path.lexists(path / name):
            try:
                check_regular_file(path / name)
            except StorageError as exc:
                raise type(exc)(f"{exc}; move it away, or choose another --out") from exc
    if overwrite:
        return path, True
    if (path / LAST).exists() and not resume:
        raise HdNetError(
            f"{path} already holds a checkpoint; resume it (--resume), start again (--overwrite) "
            "or choose another run directory."
        )
    return path, False


@contextlib.contextmanager
def run_transaction(run_dir: Path, check: Callable[[], Any], rollback: Callable[[], None]) -> Iterator[Any]:
    """The run directory's output transaction (``hdcore.storage.OutputTransaction``, in place:
    checkpoints are written one by one, each atomically, and a later call resumes them); yields
    ``check()``'s result, checked under the lock. Rank 0 only under torchrun (other ranks write
    nothing)."""
    if int(os.environ.get("RANK", "0")) != 0:
        yield check()
        return
    with OutputTransaction(run_dir, "run", check=check, rollback=rollback) as tx:
        yield tx.checked


@dataclass(frozen=True)
class FitConfig:
    """How ``fit`` trains (the options of ``hd train``).

    ``profile``: a profile's name or a ``TrainingProfile`` (e.g. a variant in an ablation);
    ``epochs``: the schedule's length (None: the profile's); ``train_sigma_m``: the noise level of
    the training inputs, metres (None: the dataset's noise level when it has only one, else the
    paper's 1.67 cm, ``training_sigma``); ``train_noise``: several levels or a range instead
    (``hdnet.noise_levels``; noisy DEMs made on the fly); ``seed``: initialisation, shuffling and
    noise draws; ``resume``: continue the
    run's ``last.pt``; ``labels``: the labelling to train on (None: the dataset's only or newest);
    ``progress``: progress bars; ``num_workers``: DataLoader worker processes; ``overwrite``: write
    into a non-empty directory that is not an hd run, or start an existing run again (its
    checkpoints, metrics.csv and config.json are replaced); ``stop_after``: end this call after
    that many epochs of the ``epochs``-long schedule (resume later).

    Each setting's help, unit, default and range is its field's metadata (``hdcore.setting``),
    from which ``hd train``'s options and the checks here are made.

    Raises:
        HdNetError: a wrong kind or an out-of-range value, e.g. a negative seed or number of workers
            (checked here, before any file is looked at).
    """

    profile: str | TrainingProfile = setting(
        "cpu",
        "Training profile: paper (GPU, 512x512, full width), cpu (2-core machine, at one noise level), robust "
        "(2-core machine, across 0 to 10 cm of noise, the noise level as an input), tiny (tests, demos); "
        "docs/hdnet.md lists their settings",
        choices=PROFILES,
        checked=False,  # a name (one of the choices) or a TrainingProfile itself
    )
    epochs: int | None = setting(None, "Epochs (default: the profile's)", bound=limits.EPOCHS)
    train_sigma_m: float | None = setting(
        None, "Noise level of the training inputs", unit="metres", bound=limits.NOISE_SIGMA_M, cli=False
    )
    train_noise: TrainingNoise | None = None
    seed: int = setting(0, "Seed of initialisation, shuffling and noise draws", bound=lidar_limits.SEED)
    resume: bool = setting(False, "Continue an interrupted run from its last checkpoint")
    labels: str | None = setting(None, "Labelling to train on (when the dataset has several)", kind=str)
    progress: EpochProgress = True
    num_workers: int = setting(0, "DataLoader worker processes", bound=lidar_limits.LOADER_WORKERS)
    overwrite: bool = setting(
        False, "Start an existing run again, or write into a non-empty directory that is not a run"
    )
    stop_after: int | None = None
    also: tuple[str, ...] = setting(
        (),
        "Another labelled dataset to train on as well (a mix of terrains): its train split joins the training "
        "data, its validation split the validation. Repeatable; each needs DATASET's labelling",
        kind=Path,
        click_type=DIRECTORY,
    )

    def __post_init__(self) -> None:
        check(self, HdNetError)

    def training_profile(self) -> TrainingProfile:
        """The profile itself (a name is looked up in ``hdnet.profiles``)."""
        return self.profile if isinstance(self.profile, TrainingProfile) else get_profile(self.profile)


def training_noise(
    requested: TrainingNoise | None,
    requested_sigma_m: float | None,
    profile: TrainingProfile,
    dataset_sigmas_m: tuple[float, ...],
) -> TrainingNoise:
    """The noise levels of training: ``requested`` (several levels or a range), else one level
    ``requested_sigma_m``, else the profile's range (``TrainingProfile.train_sigma_range_m``), else the
    default level of ``training_sigma``."""
    if requested is not None and requested_sigma_m is not None:
        raise HdNetError("give one training sigma or training noise levels, not both.")
    if requested is not None:
        return requested
    if requested_sigma_m is None and profile.train_sigma_range_m is not None:
        return TrainingNoise(range_m=profile.train_sigma_range_m)
    return TrainingNoise.single(training_sigma(requested_sigma_m, dataset_sigmas_m))


def reference_sigma(noise: TrainingNoise, dataset_sigmas_m: tuple[float, ...]) -> float:
    """The run's reference noise level, metres (``train_sigma_m`` of its config): its only level, or
    for several levels or a range the level the uncertainty threshold is calibrated at by default
    (``hdnet.thresholds``, "Runs trained across noise levels"): the paper's 1.67 cm when the
    training levels cover it, else the lowest training level."""
    if noise.is_single:
        return noise.levels_m[0]
    paper = defaults.TRAIN_SIGMA_M
    return paper if noise.contains(paper) else noise.low_m


def nearest_stored(noise: TrainingNoise, dataset_sigmas_m: tuple[float, ...]) -> float:
    """The stored level nearest the middle of the training levels (min-max heights are taken there)."""
    mid = 0.5 * (noise.low_m + noise.high_m)
    return min(dataset_sigmas_m, key=lambda s: abs(s - mid)) if not noise.is_single else noise.levels_m[0]


def training_sigma(requested_m: float | None, dataset_sigmas_m: tuple[float, ...]) -> float:
    """The training noise level, metres: ``requested_m``, or by default the dataset's only noise level
    (a dataset built with one ``--sigma``), or the paper's 1.67 cm for a dataset with several."""
    if requested_m is not None:
        return float(requested_m)
    return float(dataset_sigmas_m[0]) if len(dataset_sigmas_m) == 1 else defaults.TRAIN_SIGMA_M


# Seed offset of the k-th dataset of a mix (``FitConfig.also``): its drawn noise levels, noise
# realisations and augmentations never repeat those of the same scan index in another dataset.
MIX_SEED_STRIDE = 1_000_003


def _mix(
    cfg: FitConfig,
    train_ds: HazardDataset,
    val_ds: Dataset,
    noise: TrainingNoise,
    train_sigma_m: float,
    profile: TrainingProfile,
    common: dict[str, Any],
) -> tuple[MixedDataset, MixedDataset]:
    """The train and validation splits of the first dataset and of every ``cfg.also`` dataset, one
    after the other; each extra dataset must hold the first one's labelling (same lander and DEM)."""
    trains: list[Dataset] = [train_ds]
    vals: list[Dataset] = [val_ds]
    for k, other in enumerate(cfg.also, start=1):
        entry, _ = open_labeling(other, train_ds.labels)
        if entry.spacing_m != train_ds.spacing_m:
            raise HdNetError(
                f"{dataset_label(other)}: its DEMs are not on the first dataset's grid; label it with the same "
                "settings."
            )
        mine = {**common, "labels": train_ds.labels, "seed": cfg.seed + k * MIX_SEED_STRIDE}
        if noise.is_single:
            trains.append(HazardDataset(other, "train", train_sigma_m, augment=profile.augment, **mine))
            vals.append(HazardDataset(other, "val", train_sigma_m, **mine))
        else:
            trains.append(HazardDataset(other, "train", None, augment=profile.augment, noise=noise, **mine))
            vals.extend(HazardDataset(other, "val", s, **mine) for s in noise.validation_levels())
        for name, ds in (("train", trains[-1]), ("val", vals[-1])):
            if len(ds) == 0:  # type: ignore[arg-type]  # map-style datasets have a length
                raise HdNetError(f"{dataset_label(other)}: the {name} split is empty; build a dataset with more scans.")
    return MixedDataset(trains), MixedDataset(vals)


def already_trained(dataset_dir: str | os.PathLike, run_dir: str | os.PathLike, config: FitConfig) -> bool:
    """True when ``run_dir`` holds a finished run of exactly this training (``hd train`` run again):
    the same profile, epochs, seed, training noise, labelling and datasets (by manifest sha256), every
    epoch done, and its files intact and in step (``hdnet.run_check.check_run``). ``--overwrite``
    trains again; anything unreadable, damaged, being trained or different is not "the same" (the
    command then reads it and names the damage, or resumes it)."""
    if config.overwrite:
        return False
    run = Path(run_dir)
    try:
        checked = check_run(run)
        profile = config.training_profile()
        entry, paths = open_labeling(dataset_dir, config.labels)
        sigmas = dataset_sigmas(paths, entry.first_sha256)
        noise = training_noise(config.train_noise, config.train_sigma_m, profile, sigmas)
    except (OSError, ValueError, HdNetError):
        return False
    recorded, data = checked.record, checked.data
    if data is None or checked.writer_pid is not None:
        return False
    epochs = profile.epochs if config.epochs is None else int(config.epochs)
    return (
        recorded.profile == json.loads(json.dumps(profile.to_dict()))
        and recorded.epochs == epochs == checked.epochs_done == len(checked.rows)
        and recorded.seed == config.seed
        and data.dataset == dataset_key(dataset_dir)
        and data.manifest_sha256 == manifest_sha256(dataset_dir)
        and data.labels == entry.name
        and data.train_noise == noise
        and data.also == _also_datasets(tuple(config.also))
    )


def _recorded_data(last: Path) -> tuple[TrainingData, CheckpointJson]:
    """The training data the checkpoint ``last`` records (its content checked first), and the checkpoint.

    Raises:
        HdNetError: a damaged checkpoint, or one that records no training data of ``hdnet.fit``.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", HdWarning)  # said once, by the training that loads it next
        ckpt = load_checkpoint(last)
    return checkpoint_data(ckpt, last), ckpt


def check_resumed_data(
    run_dir: Path,
    dataset_dir: str | os.PathLike,
    entry: LabelingEntry,
    noise: TrainingNoise,
    also: tuple[str, ...],
    schedule: tuple[TrainingProfile, int, int] | None = None,
) -> None:
    """Refuse to resume the run at ``run_dir`` on other data than its ``last.pt`` records, before any
    data is read: the dataset (path and manifest sha256), the ``--also`` datasets, the labelling
    (``entry``, its manifest entry) and the training noise; with ``schedule`` (profile, seed, total
    epochs), also another seed or total than the run's (``hdnet.run_record.schedule_refusal``).
    ``hdnet.train.train`` compares the whole record (input preparation included) again when it
    loads the checkpoint.

    Raises:
        HdNetError: naming what differs, as recorded and as given, and what to do instead.
    """
    labels = entry.name
    for other in also:
        open_labeling(other, labels)  # the clear "not a dataset" or "no such labelling" first
    recorded, ckpt = _recorded_data(run_dir / LAST)
    given = dataclasses.replace(
        recorded,
        dataset=dataset_key(dataset_dir),
        manifest_sha256=manifest_sha256(dataset_dir),
        labels=labels,
        labeling=entry.without_shards(),
        train_noise=noise,
        also=_also_datasets(also),
    )
    difference = recorded.difference(given)
    if difference is not None:
        raise HdNetError(difference.resume_refusal(run_dir))
    if schedule is not None:
        profile, seed, epochs = schedule
        done = ckpt.get("epoch")
        done = done if isinstance(done, int) else 0  # hdnet.train.train names a damaged epoch
        refusal = schedule_refusal(run_dir, ckpt.get("seed"), done, profile.extendable, (seed, epochs))
        if refusal is not None:
            raise HdNetError(refusal)


def fit(dataset_dir: str | os.PathLike, run_dir: str | os.PathLike, config: FitConfig | None = None) -> Path:
    """Train a model on ``dataset_dir`` as ``config`` says (default: ``FitConfig()``); returns ``last.pt``.

    Raises:
        HdNetError: a bad run directory (see ``prepare_run_dir``), a mix that names the same data
            twice (``check_distinct_datasets``), a run resumed on other data than it was trained on
            (``check_resumed_data``), a dataset without labels, a sigma not in the dataset, an empty
            training or validation split, an unknown profile, or anything ``hdnet.train.train`` refuses.
    """
    cfg = config if config is not None else FitConfig()
    resume, overwrite, labels = cfg.resume, cfg.overwrite, cfg.labels
    check_distinct_datasets(dataset_dir, cfg.also)
    if already_trained(dataset_dir, run_dir, cfg):
        return Path(run_dir).resolve() / LAST
    run_path, _ = prepare_run_dir(run_dir, resume, overwrite, dataset_dir)
    for other in cfg.also:
        prepare_run_dir(run_dir, resume, overwrite, other)
    profile = cfg.training_profile()
    entry, paths = open_labeling(dataset_dir, labels)  # the clear "no labels" error first
    noise = training_noise(cfg.train_noise, cfg.train_sigma_m, profile, dataset_sigmas(paths, entry.first_sha256))
    if resume and not overwrite and (run_path / LAST).exists():
        epochs = profile.epochs if cfg.epochs is None else int(cfg.epochs)
        check_resumed_data(run_path, dataset_dir, entry, noise, tuple(cfg.also), (profile, cfg.seed, epochs))
    train_sigma_m = reference_sigma(noise, dataset_sigmas(paths, entry.first_sha256))
    check_augment(profile.augment, entry.lander)
    normalisation = (
        compute_normalisation(dataset_dir, nearest_stored(noise, dataset_sigmas(paths, entry.first_sha256)), labels)
        if profile.heights == "minmax"
        else None
    )
    spec = input_spec_for(profile, entry.spacing_m, normalisation)
    common: dict[str, Any] = {"labels": labels, "input_spec": spec, "seed": cfg.seed}
    if noise.is_single:
        train_ds = HazardDataset(dataset_dir, "train", train_sigma_m, augment=profile.augment, **common)
        val_ds: Dataset = HazardDataset(dataset_dir, "val", train_sigma_m, **common)
        train_sigma_m = train_ds.sigma_m
    else:
        train_ds = HazardDataset(dataset_dir, "train", None, augment=profile.augment, noise=noise, **common)
        val_ds = ConcatDataset([HazardDataset(dataset_dir, "val", s, **common) for s in noise.validation_levels()])
    for name, ds in (("train", train_ds), ("val", val_ds)):
        if len(ds) == 0:  # type: ignore[arg-type]  # map-style datasets have a length
            raise HdNetError(
                f"{dataset_label(dataset_dir)}: the {name} split is empty; build a dataset with more scans."
            )
    labels, dem_shape, entry = train_ds.labels, train_ds.dem_shape, train_ds.entry
    if cfg.also:
        mixed_train, mixed_val = _mix(cfg, train_ds, val_ds, noise, train_sigma_m, profile, common)
        train_ds, val_ds = mixed_train, mixed_val  # type: ignore[assignment]  # the mix reads like one dataset
    data = training_data(
        dataset_dir, labels, train_sigma_m, spec, dem_shape, labeling=entry, noise=noise, also=tuple(cfg.also)
    )

    def no_run_without_epoch() -> None:  # a config.json alone is no run
        if not (run_path / LAST).exists():
            (run_path / CONFIG).unlink(missing_ok=True)

    with run_transaction(
        run_path, lambda: prepare_run_dir(run_path, resume, overwrite, dataset_dir), no_run_without_epoch
    ) as (_, replace):
        if replace:
            for name in RUN_FILES:
                (run_path / name).unlink(missing_ok=True)
        return train(
            run_path,
            train_ds,
            val_ds,
            profile,
            epochs=cfg.epochs,
            seed=cfg.seed,
            resume=resume and not replace,
            progress=cfg.progress,
            extra_config=data.to_dict(),
            num_workers=cfg.num_workers,
            stop_after=cfg.stop_after,
        )
