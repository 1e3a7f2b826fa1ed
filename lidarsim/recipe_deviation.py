"""A recipe built at another size: ``hd build-dataset --recipe datasets/<name> --scans 50``.

A recipe fixes every content setting of its dataset; only its size may be changed on the command
line, to try a recipe small before building it whole. Such a build deviates from its recipe: its
manifest records which settings, with the recipe's value and the value used (``recipe_deviation``,
manifest schema 1.1, docs/shard-format.md), and ``hd verify --recipe`` names the deviation instead
of comparing checksums that cannot match.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from hdcore.setting import described_fields
from hdcore.storage import FormatError
from lidarsim.build import BuildConfig
from lidarsim.manifest_json import ManifestJson, RecipeDeviationJson
from lidarsim.recipe import BuildSettings, Recipe

# The manifest key of a deviating build's record.
DEVIATION_KEY = "recipe_deviation"
# The settings (``BuildSettings`` fields) a recipe build may take from the command line: its size
# only (scans, scans per shard). Every other content setting is the recipe's: edit a copy of it.
SIZE_SETTINGS = ("scans", "shard_size")


def _option(setting: str) -> str:
    """The command-line flag of a ``BuildSettings`` field (``--shard-size``)."""
    return next(d.option_name(f.name) for f, d in described_fields(BuildSettings) if f.name == setting)


# Each size setting's flag (``--scans``, ``--shard-size``), from its description.
SIZE_OPTIONS = {name: _option(name) for name in SIZE_SETTINGS}


@dataclass(frozen=True)
class Deviation:
    """One setting of a build that differs from its recipe: ``setting`` (a ``BuildSettings`` field),
    its ``option`` (``--scans``), the ``recipe``'s value and the value ``used``."""

    setting: str
    option: str
    recipe: int
    used: int

    def words(self) -> str:
        """``--scans 50 (recipe: 1000)``."""
        return f"{self.option} {self.used} (recipe: {self.recipe})"


@dataclass(frozen=True)
class RecipeDeviation:
    """A deviating build's record: the recipe's name and version, and the settings that differ."""

    recipe: str
    recipe_version: int
    settings: tuple[Deviation, ...]

    def words(self) -> str:
        """``--scans 50 (recipe: 1000), --shard-size 10 (recipe: 50)``."""
        return ", ".join(d.words() for d in self.settings)

    def to_dict(self) -> RecipeDeviationJson:
        """The manifest's ``recipe_deviation``."""
        return {
            "recipe": self.recipe,
            "recipe_version": self.recipe_version,
            "settings": [
                {"setting": d.setting, "option": d.option, "recipe": d.recipe, "used": d.used} for d in self.settings
            ],
        }

    def out_dir_name(self) -> str:
        """A default output directory that is not the recipe's own: ``mars-jezero-scans50``."""
        return "-".join([self.recipe, *(f"{d.option.lstrip('-')}{d.used}" for d in self.settings)])


def _value(config: BuildConfig, setting: str) -> int:
    """The recipe's value of a size setting as ``--scans`` counts it (a descent recipe: descents)."""
    return int(config.trajectory.n_positions if setting == "scans" else config.shard_size)


def _with(config: BuildConfig, setting: str, value: int) -> BuildConfig:
    if setting == "scans":
        scans = value * config.trajectory.frames
        return dataclasses.replace(config, trajectory=dataclasses.replace(config.trajectory, n_scans=scans))
    return dataclasses.replace(config, shard_size=value)


def deviate(recipe: Recipe, given: dict[str, Any]) -> tuple[BuildConfig, RecipeDeviation | None]:
    """The recipe's build configuration with the size settings ``given`` (``BuildSettings`` field ->
    value, from the command line), and the record of the deviation (None when every value given is
    the recipe's own).

    Raises:
        LidarsimError: a setting that is not a size setting, or a configuration the values make
            invalid (e.g. a shard too large for memory).
    """
    from lidarsim.errors import LidarsimError

    unknown = sorted(set(given) - set(SIZE_SETTINGS))
    if unknown:
        raise LidarsimError(f"a recipe build may change only its size ({', '.join(SIZE_OPTIONS.values())})")
    config = recipe.build
    deviations = []
    for setting in SIZE_SETTINGS:
        if setting in given and int(given[setting]) != _value(recipe.build, setting):
            used = int(given[setting])
            deviations.append(Deviation(setting, SIZE_OPTIONS[setting], _value(recipe.build, setting), used))
            config = _with(config, setting, used)
    if not deviations:
        return config, None
    return config, RecipeDeviation(recipe.name, recipe.version, tuple(deviations))


def recorded_deviation(manifest: ManifestJson) -> RecipeDeviation | None:
    """The deviation a manifest records (None for a build that is its recipe's or made without one).

    Raises:
        FormatError: a record of another shape than :meth:`RecipeDeviation.to_dict` writes.
    """
    record = manifest.get(DEVIATION_KEY)
    if record is None:
        return None
    bad = FormatError(f"manifest.json: '{DEVIATION_KEY}' is not a record of a recipe's deviation")
    if not isinstance(record, dict) or not isinstance(record.get("recipe"), str):
        raise bad
    settings = record.get("settings")
    if not isinstance(settings, list) or not settings:
        raise bad
    deviations = []
    for entry in settings:
        if not isinstance(entry, dict) or not all(isinstance(entry.get(k), str) for k in ("setting", "option")):
            raise bad
        values = [entry.get(k) for k in ("recipe", "used")]
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in values):
            raise bad
        deviations.append(Deviation(entry["setting"], entry["option"], int(entry["recipe"]), int(entry["used"])))
    version = record.get("recipe_version")
    return RecipeDeviation(
        record["recipe"],
        version if isinstance(version, int) and not isinstance(version, bool) else 0,
        tuple(deviations),
    )
