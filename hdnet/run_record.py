"""The run record: what a training run is, as one typed value (``RUN/config.json`` and the
metadata every checkpoint carries).

One writer (:func:`write_run_record`, called by ``hdnet.train``), one reader of ``config.json``
(:func:`read_run_record`) and one of a checkpoint's metadata (:func:`checkpoint_data`); every
record read, of any age, goes through :func:`migrate` first.

Schema ``hdnet.run``, version 2:

* ``model_name``, ``model_config``, ``profile`` (``TrainingProfile.to_dict``), ``epochs`` (the
  schedule's length), ``seed``, ``world_size``, ``hd_version``, ``torch_version``,
  ``class_weights`` (None unless the profile balances the classes);
* ``extra_config``: for a run trained by ``hdnet.fit``, :class:`TrainingData` - the dataset (path
  and manifest sha256), the labelling (name and manifest entry without its shard list), the
  training noise (reference level and levels or range), the input spec (``hdnet.inputs``), the DEM
  shape and the ``--also`` datasets. ``hdnet.train.train`` used alone stores any JSON dictionary
  there.

Earlier versions, read through :func:`migrate`:

* version 1 (hd 0.1.x) repeated parts of the input spec beside it in ``extra_config``
  (``normalisation``, ``input_size``, ``input_rule``); they are dropped;
* the first runs (hd 0.1.0) had no input spec: min-max heights with the recorded normalisation,
  one channel, padding to the model's ``2**depth`` (``InputSpec.from_run_config``); runs without a
  ``train_noise`` were trained at ``train_sigma_m`` alone; runs without a ``labeling`` entry are
  read with None there (``hd detect`` then reads it from the dataset).
"""

from __future__ import annotations

import contextlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hdcore.errors import StorageError
from hdcore.storage import read_regular_text, write_json_atomic
from hdlabels.errors import HdLabelsError
from hdlabels.store import LabelingEntry
from hdnet.checkpoint_json import CheckpointJson
from hdnet.errors import HdNetError
from hdnet.inputs import InputSpec
from hdnet.noise_levels import TrainingNoise
from hdnet.run_files import CONFIG, LAST, METRICS
from hdnet.run_json import AlsoDatasetJson, CheckpointHeaderJson, RunRecordJson, TrainingDataJson
from lidarsim.location import has_manifest
from lidarsim.shards import MANIFEST_NAME

__all__ = [
    "CONFIG",
    "RUN_DATA_KEYS",
    "RUN_SCHEMA",
    "RUN_SCHEMA_VERSION",
    "AlsoDataset",
    "DataDifference",
    "RunRecord",
    "TrainingData",
    "checkpoint_data",
    "extra_difference",
    "json_difference",
    "migrate",
    "read_run_record",
    "schedule_refusal",
    "unfinished_training",
    "write_run_record",
]

RUN_SCHEMA = "hdnet.run"
RUN_SCHEMA_VERSION = 2
# Keys of extra_config that version 1 repeated from the input spec (dropped by ``migrate``).
_LEGACY_INPUT_KEYS = ("normalisation", "input_size", "input_rule")
# The extra_config of a run of hdnet.fit (``also`` only with further datasets).
RUN_DATA_KEYS = (
    "dataset",
    "manifest_sha256",
    "labels",
    "labeling",
    "train_sigma_m",
    "train_noise",
    "dem_shape",
    "input",
)


@dataclass(frozen=True)
class AlsoDataset:
    """A further training dataset (``hd train --also``): its absolute path and manifest sha256."""

    dataset: str
    manifest_sha256: str

    def to_dict(self) -> AlsoDatasetJson:
        return {"dataset": self.dataset, "manifest_sha256": self.manifest_sha256}


@dataclass(frozen=True)
class TrainingData:
    """What a model was trained on and how its inputs are prepared (a run's ``extra_config``).

    ``dataset``: the training dataset's absolute path at training time and ``manifest_sha256`` its
    manifest's checksum (None in records that lack them); ``labels``: the labelling's name;
    ``labeling``: its manifest entry without the shard list (lander, DEM grid, convention; None for
    runs trained before it was recorded); ``train_sigma_m``: the reference noise level, metres;
    ``train_noise``: every training level or the range; ``input``: how DEMs become network inputs;
    ``dem_shape``: (rows, cols) of the training DEMs (None when not recorded); ``also``: further
    training datasets.
    """

    train_sigma_m: float
    input: InputSpec
    train_noise: TrainingNoise
    dataset: str | None = None
    manifest_sha256: str | None = None
    labels: str | None = None
    labeling: LabelingEntry | None = None
    dem_shape: tuple[int, int] | None = None
    also: tuple[AlsoDataset, ...] = ()

    @property
    def datasets(self) -> tuple[str, ...]:
        """Every dataset the run was trained on: ``dataset`` and each ``also`` one (empty when the
        record names none)."""
        return (self.dataset, *(a.dataset for a in self.also)) if self.dataset else ()

    def missing_datasets(self) -> list[str]:
        """The training datasets (:attr:`datasets`) that are not present any more (no manifest)."""
        return [d for d in self.datasets if not has_manifest(d, MANIFEST_NAME)]

    def difference(self, given: TrainingData) -> DataDifference | None:
        """The first way ``given`` is not the training data this record names (None when it is).

        In order: the dataset (its path, then its manifest's sha256), the ``--also`` datasets (the
        same, in order: the order of a mix is its order of samples), the labelling (its name, then
        its manifest entry), the training noise, the DEM shape, then the input preparation. Paths
        are compared as recorded (absolute, resolved when the run was trained). A labelling entry
        or DEM shape this record lacks (runs trained before they were recorded) is not a
        difference: the dataset's manifest, compared first, fixes both.
        """
        if self.dataset != given.dataset:
            return DataDifference("dataset", _or_none(self.dataset), _or_none(given.dataset))
        if self.manifest_sha256 != given.manifest_sha256:
            return DataDifference(
                f"manifest of {self.dataset}", _sha(self.manifest_sha256), _sha(given.manifest_sha256)
            )
        if [a.dataset for a in self.also] != [a.dataset for a in given.also]:
            return DataDifference("--also datasets", _also_text(self.also), _also_text(given.also))
        for mine, theirs in zip(self.also, given.also, strict=True):
            if mine.manifest_sha256 != theirs.manifest_sha256:
                return DataDifference(
                    f"manifest of --also {mine.dataset}", _sha(mine.manifest_sha256), _sha(theirs.manifest_sha256)
                )
        if self.labels != given.labels:
            return DataDifference("labelling", _or_none(self.labels), _or_none(given.labels))
        if self.train_noise != given.train_noise:
            return DataDifference("training noise", self.train_noise.describe(), given.train_noise.describe())
        if self.train_sigma_m != given.train_sigma_m:
            return DataDifference(
                "reference noise level", f"{self.train_sigma_m * 100:.4g} cm", f"{given.train_sigma_m * 100:.4g} cm"
            )
        mine_d, theirs_d = _plain_json(self.to_dict()), _plain_json(given.to_dict())
        for key in ("labeling", "dem_shape"):
            if mine_d.get(key) is None:
                mine_d.pop(key, None)
                theirs_d.pop(key, None)
        names = {"labeling": "labelling's entry", "dem_shape": "DEM shape", "input": "input preparation"}
        for key in sorted(set(mine_d) | set(theirs_d), key=lambda k: (k not in names, str(k))):
            found = json_difference(mine_d.get(key), theirs_d.get(key), names.get(key, key))
            if found is not None:
                return found
        return None

    def to_dict(self) -> TrainingDataJson:
        """The ``extra_config`` of schema version 2 (JSON types)."""
        out: TrainingDataJson = {
            "dataset": self.dataset,
            "manifest_sha256": self.manifest_sha256,
            "labels": self.labels,
            "labeling": None if self.labeling is None else self.labeling.without_shards().to_json(),
            "train_sigma_m": float(self.train_sigma_m),
            "train_noise": self.train_noise.to_dict(),
            "dem_shape": None if self.dem_shape is None else list(self.dem_shape),
            "input": self.input.to_dict(),
        }
        if self.also:
            out["also"] = [a.to_dict() for a in self.also]
        return out

    @classmethod
    def from_dict(cls, extra: Any, where: str = "the run config") -> TrainingData:
        """Rebuild from a migrated ``extra_config`` (see :func:`migrate`).

        Raises:
            HdNetError: not a run of ``hdnet.fit`` (no training sigma or input spec), or a field of
                the wrong type; the message starts with ``where``.
        """
        if not isinstance(extra, dict) or "train_sigma_m" not in extra or "input" not in extra:
            raise HdNetError(
                f"{where} was not trained by hdnet.fit: its run config lacks the training sigma and normalisation."
            )
        try:
            sigma = float(extra["train_sigma_m"])
            spec = InputSpec.from_dict(extra["input"])
            noise = TrainingNoise.from_dict(extra["train_noise"])
            shape = extra.get("dem_shape")
            also = tuple(AlsoDataset(str(a["dataset"]), str(a["manifest_sha256"])) for a in extra.get("also") or ())
            labeling = extra.get("labeling") or None
            entry = None if labeling is None else LabelingEntry.from_json(labeling, "its labelling's entry")
            return cls(
                train_sigma_m=sigma,
                input=spec,
                train_noise=noise,
                dataset=_optional_str(extra.get("dataset")),
                manifest_sha256=_optional_str(extra.get("manifest_sha256")),
                labels=_optional_str(extra.get("labels")),
                labeling=entry,
                dem_shape=None if not shape else (int(shape[0]), int(shape[1])),
                also=also,
            )
        except (HdNetError, HdLabelsError) as exc:
            raise HdNetError(f"{where}: {str(exc).rstrip('.')}.") from exc
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise HdNetError(f"{where}: unreadable training data record ({exc}).") from exc


def _optional_str(value: Any) -> str | None:
    return None if value is None else str(value)


@dataclass(frozen=True)
class DataDifference:
    """One way two records of a run's training data differ: ``what`` differs (in words) and its
    value in each record, as text (``recorded``: the run's; ``given``: the other one's)."""

    what: str
    recorded: str
    given: str

    def resume_refusal(self, run_dir: str | os.PathLike) -> str:
        """The one line that refuses to continue the run at ``run_dir`` on the given data."""
        return (
            f"{run_dir} cannot be resumed on other data: {self.what}: recorded {self.recorded}, given "
            f"{self.given}; the run's record would no longer say what it was trained on: train a new run "
            "(another --out), or start this one again (--overwrite)."
        )


def _or_none(value: str | None) -> str:
    return "(not recorded)" if value is None else value


def _sha(value: str | None) -> str:
    return f"sha256 {value[:12]}..." if value else "no sha256"


def _also_text(also: tuple[AlsoDataset, ...]) -> str:
    return " ".join(f"--also {a.dataset}" for a in also) if also else "no --also dataset"


def _plain_json(value: Any) -> Any:
    """``value`` as JSON reads it back (tuples as lists, every number as JSON writes it)."""
    return json.loads(json.dumps(value, default=str))


def _brief(value: Any, limit: int = 80) -> str:
    text = json.dumps(value, sort_keys=True, default=str)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def json_difference(recorded: Any, given: Any, what: str) -> DataDifference | None:
    """The first key (depth first, in sorted order) whose value differs between two JSON values
    (None when they are equal); ``what`` names the whole value."""
    if isinstance(recorded, dict) and isinstance(given, dict):
        for key in sorted(set(recorded) | set(given), key=str):
            found = json_difference(recorded.get(key), given.get(key), f"{what}'s {key}")
            if found is not None:
                return found
        return None
    if json.dumps(recorded, sort_keys=True, default=str) == json.dumps(given, sort_keys=True, default=str):
        return None
    return DataDifference(what, _brief(recorded), _brief(given))


def extra_difference(recorded: Any, given: Any) -> DataDifference | None:
    """The first way two runs' ``extra_config`` differ (None when they are the same), each read
    through :func:`migrate`: as training data (:meth:`TrainingData.difference`) when both are records
    of ``hdnet.fit``, else the first key whose value differs (``hdnet.train.train`` stores any JSON)."""
    try:
        mine = migrate({"extra_config": recorded})["extra_config"]
        theirs = migrate({"extra_config": given})["extra_config"]
    except HdNetError:
        mine, theirs = recorded, given
    try:
        return TrainingData.from_dict(mine).difference(TrainingData.from_dict(theirs))
    except HdNetError:
        return json_difference(_plain_json(mine), _plain_json(theirs), "extra_config")


@dataclass(frozen=True)
class RunRecord:
    """A run's ``config.json``: how the network was trained (see the module docstring).

    ``extra_config`` stays plain JSON (``hdnet.train.train`` takes any); :attr:`data` reads it as
    :class:`TrainingData`. ``file_version`` is the schema version the record was read from (the
    writer always writes :data:`RUN_SCHEMA_VERSION`).
    """

    model_name: str
    model_config: dict[str, float | int]
    profile: dict[str, object]
    epochs: int
    seed: int
    world_size: int
    hd_version: str
    torch_version: str
    extra_config: dict[str, object] = field(default_factory=dict)
    class_weights: list[float] | None = None
    file_version: int = RUN_SCHEMA_VERSION

    @property
    def profile_name(self) -> str | None:
        name = self.profile.get("name")
        return None if name is None else str(name)

    @property
    def data(self) -> TrainingData:
        """The training data of a run of ``hdnet.fit``.

        Raises:
            HdNetError: a run of ``hdnet.train.train`` alone, without one.
        """
        return TrainingData.from_dict(self.extra_config)

    def to_dict(self) -> RunRecordJson:
        """``config.json`` of schema version :data:`RUN_SCHEMA_VERSION`."""
        return {
            "schema": RUN_SCHEMA,
            "schema_version": RUN_SCHEMA_VERSION,
            "model_name": self.model_name,
            "model_config": self.model_config,
            "profile": self.profile,
            "epochs": self.epochs,
            "seed": self.seed,
            "world_size": self.world_size,
            "hd_version": self.hd_version,
            "torch_version": self.torch_version,
            "extra_config": self.extra_config,
            "class_weights": self.class_weights,
        }

    @classmethod
    def from_dict(cls, raw: Any, where: str = "run config") -> RunRecord:
        """Read a ``config.json`` of any schema version (through :func:`migrate`).

        Raises:
            HdNetError: another schema, a newer version, or fields of the wrong type.
        """
        version = raw.get("schema_version") if isinstance(raw, dict) else None
        record = migrate(raw, where)
        try:
            return cls(
                model_name=str(record.get("model_name", "")),
                model_config=dict(record.get("model_config") or {}),
                profile=dict(record.get("profile") or {}),
                epochs=int(record.get("epochs") or 0),
                seed=int(record.get("seed") or 0),
                world_size=int(record.get("world_size") or 1),
                hd_version=str(record.get("hd_version", "")),
                torch_version=str(record.get("torch_version", "")),
                extra_config=dict(record.get("extra_config") or {}),
                class_weights=None if record.get("class_weights") is None else list(record["class_weights"]),
                file_version=int(version) if isinstance(version, int) else RUN_SCHEMA_VERSION,
            )
        except (TypeError, ValueError) as exc:
            raise HdNetError(f"{where}: unreadable run config ({exc}).") from exc


def migrate(raw: Any, where: str = "run config") -> dict[str, Any]:
    """A run record of any schema version in the current version's layout (a new dictionary).

    ``raw`` is a ``config.json`` or a checkpoint's metadata (``model_config`` and ``extra_config``;
    a record without ``schema_version`` is read as version 1, which is how checkpoints store it).
    Only runs of ``hdnet.fit`` have an ``extra_config`` to migrate: one without a training sigma
    (``hdnet.train.train`` alone) is kept as it is.

    Raises:
        HdNetError: not a dictionary, another schema, or a version newer than this hd reads.
    """
    if not isinstance(raw, dict):
        raise HdNetError(f"{where}: not a JSON object.")
    schema = raw.get("schema", RUN_SCHEMA)
    version = raw.get("schema_version", 1)
    if schema != RUN_SCHEMA:
        raise HdNetError(f"{where}: schema {schema!r} is not an hd run ({RUN_SCHEMA}).")
    if isinstance(version, bool) or not isinstance(version, int) or not 1 <= version <= RUN_SCHEMA_VERSION:
        raise HdNetError(
            f"{where}: run schema version {version!r} is not readable by this hd (reads 1 to {RUN_SCHEMA_VERSION})."
        )
    record = {**raw, "schema": RUN_SCHEMA, "schema_version": RUN_SCHEMA_VERSION}
    extra = raw.get("extra_config")
    if not isinstance(extra, dict) or "train_sigma_m" not in extra:
        return record
    extra = dict(extra)
    if "input" not in extra and "normalisation" in extra:  # hd 0.1.0: no input spec
        try:
            extra["input"] = InputSpec.from_run_config(extra, raw.get("model_config")).to_dict()
        except HdNetError as exc:
            raise HdNetError(f"{where}: {str(exc).rstrip('.')}.") from exc
    for key in _LEGACY_INPUT_KEYS:  # version 1: parts of the input spec repeated beside it
        extra.pop(key, None)
    if not extra.get("train_noise"):
        with contextlib.suppress(TypeError, ValueError, HdNetError):  # TrainingData.from_dict names a bad sigma
            extra["train_noise"] = TrainingNoise.single(float(extra["train_sigma_m"])).to_dict()
    extra.setdefault("labeling", None)
    record["extra_config"] = extra
    return record


def read_run_record(run_dir: str | os.PathLike) -> RunRecord:
    """The record of the run at ``run_dir`` (its ``config.json``).

    Raises:
        HdNetError: a missing or unreadable ``config.json``, or one that is no run record.
    """
    path = Path(run_dir) / CONFIG
    try:
        raw = json.loads(read_regular_text(path))
    except (ValueError, RecursionError) as exc:  # StorageError and JSONDecodeError are ValueErrors
        raise HdNetError(f"{path}: unreadable run config ({exc}).") from exc
    return RunRecord.from_dict(raw, str(path))


def schedule_refusal(
    run_dir: str | os.PathLike,
    recorded_seed: object,
    epochs_done: int,
    extendable: bool,
    given: tuple[int, int],
) -> str | None:
    """The one line that refuses to resume the run at ``run_dir`` (``epochs_done`` epochs trained,
    with the seed ``recorded_seed``) with the ``given`` (seed, total of epochs); None when the resume
    may go on.

    Refused: another seed than the checkpoint's (``config.json``'s for checkpoints that record none);
    a total below the epochs done; another total than ``config.json``'s when the schedule is not
    ``extendable`` (``TrainingProfile.extendable``: a learning rate that depends on the total, so the
    epochs done would belong to another schedule than the rest, a run neither of the old total nor
    of the new one). A constant rate's run of N epochs is the first N epochs of a longer one, so there
    a resume may raise the total (the record then says the new total). The total is not compared
    when ``config.json`` is missing or unreadable (the resume writes it again).
    """
    seed, epochs = given
    record: RunRecord | None = None
    if (Path(run_dir) / CONFIG).is_file():
        with contextlib.suppress(HdNetError, StorageError):
            record = read_run_record(run_dir)
    if not isinstance(recorded_seed, int) or isinstance(recorded_seed, bool):
        recorded_seed = None if record is None else record.seed
    new_run = f"train a new run of {epochs} epochs (another --out), or start this one again (--overwrite)"
    if recorded_seed is not None and recorded_seed != seed:
        return (
            f"{run_dir} cannot be resumed with --seed {seed}: it was trained with seed {recorded_seed}; resume it "
            f"with --seed {recorded_seed}, or train a new run (another --out), or start this one again (--overwrite)."
        )
    if epochs < epochs_done:
        done = f"it has trained {epochs_done} epochs already"
        return f"{run_dir} cannot be resumed with --epochs {epochs}: {done}; {new_run}."
    if record is not None and record.epochs != epochs and not extendable:
        return (
            f"{run_dir} cannot be resumed with --epochs {epochs}: its learning-rate schedule spans "
            f"{record.epochs} epochs; finish it with --epochs {record.epochs}, or {new_run}."
        )
    return None


def unfinished_training(checkpoint: str | os.PathLike, epoch: int) -> str | None:
    """One sentence with the epochs done and planned when ``checkpoint`` (saved after ``epoch`` epochs)
    belongs to a run whose training has not reached the epochs its ``config.json`` plans, else None
    (a finished run, or a checkpoint outside a run directory, whose plan is not known); ``hd eval``
    and ``hd detect`` warn with it.

    The epochs done are the checkpoint's own for the run's ``last.pt``; for another checkpoint of the
    run (``best.pt``) those of ``metrics.csv``, one row per epoch done, so that the best epoch of a
    finished run is not called unfinished.
    """
    path = Path(checkpoint)
    run = path.parent
    if not (run / CONFIG).is_file():
        return None
    try:
        planned = read_run_record(run).epochs
        done = int(epoch)
        if path.name != LAST and (run / METRICS).is_file():
            done = max(done, len(read_regular_text(run / METRICS).splitlines()) - 1)
    except (HdNetError, StorageError, TypeError, ValueError):
        return None
    if not 0 <= done < planned:
        return None
    return (
        f"{run} is an unfinished run: {done} of its {planned} epochs trained (`hd train ... --resume` finishes "
        f"it); {path.name} is the network of epoch {int(epoch)}, not the trained one"
    )


def write_run_record(run_dir: str | os.PathLike, record: RunRecord) -> None:
    """Write ``RUN/config.json`` atomically (``hdcore.storage.write_json_atomic``).

    Raises:
        StorageError: a value JSON cannot hold, or an OS error (a full disk); nothing is half-written.
    """
    write_json_atomic(Path(run_dir) / CONFIG, record.to_dict())


@dataclass(frozen=True)
class CheckpointHeader:
    """What a checkpoint says of its training, read in one place (``hd eval``'s report and ``hd
    detect``'s detect.json record it; an unfinished run is warned about from ``epoch``).

    Attributes:
        epoch: the epochs trained when it was saved (0 when not recorded).
        profile: the training profile's name, or None (a checkpoint not made by ``hdnet.fit``).
        model_config: the network's configuration as stored (plain JSON), or None.
    """

    epoch: int
    profile: str | None
    model_config: dict[str, float | int] | None

    @classmethod
    def of(cls, ckpt: CheckpointJson) -> CheckpointHeader:
        """The header of a loaded checkpoint (``hdnet.train.load_checkpoint``'s dictionary)."""
        name = (ckpt.get("profile") or {}).get("name")
        return cls(int(ckpt.get("epoch", 0)), None if name is None else str(name), ckpt.get("model_config"))

    def to_dict(self) -> CheckpointHeaderJson:
        """The three fields as reports record them (``epoch``, ``profile``, ``model_config``)."""
        return {"epoch": self.epoch, "profile": self.profile, "model_config": self.model_config}


def checkpoint_data(ckpt: CheckpointJson, path: str | os.PathLike) -> TrainingData:
    """The training data a checkpoint carries (its ``extra_config``, migrated like a ``config.json``).

    Raises:
        HdNetError: a checkpoint not trained by ``hdnet.fit``; the message names ``path``.
    """
    raw = {"model_config": ckpt.get("model_config"), "extra_config": ckpt.get("extra_config") or {}}
    return TrainingData.from_dict(migrate(raw, str(path))["extra_config"], str(path))
