"""Dataset recipes: a TOML file that fixes every setting of a dataset (``datasets/<name>/recipe.toml``).

``hd build-dataset --recipe datasets/<name>`` builds exactly the recipe's dataset; the recipe
directory may also hold ``checksums.json`` (the published build's settings hash and shard
checksums) against which ``hd verify --recipe`` checks a received copy.

Recipe layout (every key optional; defaults are the paper's)::

    [dataset]
    name = "mars-paper"
    version = 2         # bumped whenever the content changes (here: the label convention)
    [build]
    scans = 1000
    sigmas_m = [0.0167, 0.03, 0.07]
    seed = 0
    altitude_m = 500.0
    dtm = ""            # "" = the built-in procedural Mars terrain; or a path (relative to the recipe)
    dtm_scale = 1.0
    shard_size = 50
    tilt_deg = 0.0
    jitter_deg = 0.0
    resolution = 128
    fov_deg = 12.0
    dead_elements = 0
    damaged_elements = 0
    compression = "gzip"
    [label]
    lander = "square"
    lander_diameter_m = 10.0
    pad_diameter_m = 1.0
    max_slope_deg = 10.0
    max_roughness_m = 0.20
    convention = "paper"     # "paper" or "hd"; a recipe without it is the hd convention
    baseline_combine = "product"   # optional; default: the convention's
    gridding = "nearest"     # optional; default: the convention's
"""

from __future__ import annotations

import json
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lidarsim import defaults
from lidarsim.build import BuildConfig
from lidarsim.errors import LidarsimError
from lidarsim.sensor import SensorConfig
from lidarsim.trajectory import TrajectoryConfig

RECIPE_FILE = "recipe.toml"
CHECKSUMS_FILE = "checksums.json"

_BUILD_KEYS = {
    "scans", "sigmas_m", "seed", "altitude_m", "dtm", "dtm_scale", "shard_size", "tilt_deg", "jitter_deg",
    "resolution", "fov_deg", "dead_elements", "damaged_elements", "compression",
}
_LABEL_KEYS = {"lander", "lander_diameter_m", "pad_diameter_m", "max_slope_deg", "max_roughness_m", "yaws",
               "count_holes", "dem_size", "dem_spacing_m", "convention", "baseline_combine", "gridding"}


class RecipeError(LidarsimError):
    """A recipe that cannot be read or holds unknown or invalid settings."""


@dataclass(frozen=True)
class Recipe:
    """A parsed recipe: the build configuration and the label settings (raw, for hdlabels)."""

    name: str
    path: Path
    build: BuildConfig
    label: dict[str, Any] = field(default_factory=dict)
    description: str = ""
    version: int = 1

    def checksums(self) -> dict[str, Any] | None:
        """The recorded checksums of the published build, or None when the recipe has none."""
        path = self.path.parent / CHECKSUMS_FILE
        if not path.is_file():
            return None
        try:
            return json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise RecipeError(f"{path}: unreadable checksums ({exc})") from None


def load_recipe(path: str | os.PathLike) -> Recipe:
    """Read ``recipe.toml`` (``path`` is the file or its directory).

    Raises:
        RecipeError: missing or unreadable file, unknown keys, invalid values.
    """
    path = Path(path)
    if path.is_dir():
        path = path / RECIPE_FILE
    if not path.is_file():
        raise RecipeError(f"{path}: no such recipe")
    try:
        data = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise RecipeError(f"{path}: not a valid TOML recipe ({exc})") from None
    unknown_sections = set(data) - {"dataset", "build", "label"}
    if unknown_sections:
        raise RecipeError(f"{path}: unknown section(s) {sorted(unknown_sections)}")
    build = data.get("build", {})
    label = data.get("label", {})
    for section, keys, known in (("build", build, _BUILD_KEYS), ("label", label, _LABEL_KEYS)):
        unknown = set(keys) - known
        if unknown:
            raise RecipeError(f"{path}: unknown [{section}] key(s) {sorted(unknown)}")
    dtm = build.get("dtm", "")
    dtm_path = None
    if dtm:
        dtm_path = Path(dtm) if Path(dtm).is_absolute() else (path.parent / dtm)
        dtm_path = str(dtm_path.resolve())
    try:
        resolution = int(build.get("resolution", defaults.DETECTOR_ROWS))
        fov = float(build.get("fov_deg", defaults.FOV_DEG))
        config = BuildConfig(
            sigmas_m=tuple(float(s) for s in build.get("sigmas_m", [defaults.DEFAULT_SIGMA_M])),
            seed=int(build.get("seed", 0)),
            sensor=SensorConfig(rows=resolution, cols=resolution, fov_x_deg=fov, fov_y_deg=fov,
                                dead_elements=int(build.get("dead_elements", 0)),
                                damaged_elements=int(build.get("damaged_elements", 0))),
            trajectory=TrajectoryConfig(n_scans=int(build.get("scans", defaults.N_SCANS)),
                                        altitude_m=float(build.get("altitude_m", defaults.ALTITUDE_M)),
                                        tilt_deg=float(build.get("tilt_deg", 0.0)),
                                        jitter_deg=float(build.get("jitter_deg", 0.0))),
            dtm_path=dtm_path,
            dtm_scale=float(build.get("dtm_scale", 1.0)),
            shard_size=int(build.get("shard_size", 50)),
            compression=str(build.get("compression", "gzip")),
        )
    except (TypeError, ValueError) as exc:
        if isinstance(exc, LidarsimError):
            raise RecipeError(f"{path}: {exc}") from None
        raise RecipeError(f"{path}: invalid value ({exc})") from None
    meta = data.get("dataset", {})
    unknown = set(meta) - {"name", "description", "version"}
    if unknown:
        raise RecipeError(f"{path}: unknown [dataset] key(s) {sorted(unknown)}")
    version = meta.get("version", 1)
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise RecipeError(f"{path}: [dataset] version must be a positive integer, got {version!r}")
    return Recipe(name=str(meta.get("name", path.parent.name)), path=path.resolve(), build=config, label=dict(label),
                  description=str(meta.get("description", "")), version=version)


def check_against_checksums(manifest: dict[str, Any], recorded: dict[str, Any]) -> list[str]:
    """Compare a dataset's manifest with a recipe's recorded checksums; returns one-line problems."""
    problems: list[str] = []
    if manifest.get("config_sha256") != recorded.get("config_sha256"):
        problems.append("the dataset was built with other settings than the recipe's published build")
    want = {s["path"]: s["sha256"] for s in recorded.get("shards", [])}
    have = {s["path"]: s["sha256"] for s in manifest.get("shards", [])}
    for p in sorted(set(want) | set(have)):
        if p not in have:
            problems.append(f"{p}: listed by the recipe's checksums, missing from the dataset")
        elif p not in want:
            problems.append(f"{p}: not part of the recipe's published build")
        elif want[p] != have[p]:
            problems.append(f"{p}: sha256 differs from the recipe's published build")
    return problems
