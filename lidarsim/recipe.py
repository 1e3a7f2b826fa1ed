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
    altitude_m = 500.0  # or a range drawn per scan: "250:1000" (likewise tilt_deg, jitter_deg)
    dtm = ""            # "" = the built-in procedural Mars terrain; or a path (relative to the recipe)
    dtm_sha256 = ""     # optional: the DTM file's sha256; another file is refused
    rocks_on_dtm = false  # true: the DTM resampled to 0.5 m with the procedural rocks (lidarsim.base_relief)
    dtm_scale = 1.0
    shard_size = 50
    tilt_deg = 0.0
    jitter_deg = 0.0
    resolution = 128
    fov_deg = 12.0
    dead_elements = 0
    damaged_elements = 0
    compression = "gzip"
    footprint_samples = 1        # K x K sub-rays per pixel (lidarsim.footprint)
    spot_profile = "gaussian"
    range_estimator = "centroid"  # or "first"
    pulse_width_m = 0.75
    return_fraction = 0.5
    noise_model = "constant"     # or "snr" (lidarsim.noise.NoiseModel)
    snr_ref = 100.0
    snr_min = 5.0
    descent_frames = 0           # K >= 2: descents of K frames, `scans` of them (lidarsim.descent)
    descent_altitudes_m = "1000:250"  # or [1000, 250]: frame 0's and frame K-1's altitude
    approach_deg = 0.0
    nav_position_sigma_m = 0.0   # the navigation error (lidarsim.navigation), 1-sigma per axis
    nav_position_walk_m = 0.0
    nav_attitude_sigma_deg = 0.0
    nav_attitude_walk_deg = 0.0
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
import math
import os
import re
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, TypeVar, cast

from hdcore.bounds import Bound
from hdcore.setting import FILE_OR_DIRECTORY, check, described_as, described_fields, from_mapping, setting
from hdcore.storage import is_sha256, read_regular_bytes
from lidarsim import defaults, limits
from lidarsim.build import BuildConfig
from lidarsim.checksums_json import ChecksumsJson
from lidarsim.descent import DescentConfig
from lidarsim.errors import LidarsimError, RecipeError
from lidarsim.fingerprint import fingerprint_problem
from lidarsim.footprint import FootprintConfig
from lidarsim.manifest_json import ManifestJson
from lidarsim.navigation import NavigationError
from lidarsim.noise import NoiseModel
from lidarsim.sensor import SensorConfig
from lidarsim.span import DescendingPairType, SpanType, parse_pair, parse_span
from lidarsim.trajectory import TrajectoryConfig

RECIPE_FILE = "recipe.toml"
CHECKSUMS_FILE = "checksums.json"

_LABEL_KEYS = {
    "lander",
    "lander_diameter_m",
    "pad_diameter_m",
    "max_slope_deg",
    "max_roughness_m",
    "yaws",
    "count_holes",
    "dem_size",
    "dem_spacing_m",
    "convention",
    "baseline_combine",
    "gridding",
    "truth",
}


# The fields of a config class that this flat record names otherwise (the recipe key and option
# they always had): (class name, its field) -> BuildSettings' field.
_FLAT_NAMES = {("FootprintConfig", "samples"): "footprint_samples", ("NoiseModel", "kind"): "noise_model"}
T = TypeVar("T")


@dataclass(frozen=True)
class BuildSettings:
    """The content settings of a dataset as ``hd build-dataset`` takes them and a recipe's
    ``[build]`` section records them (one flat record; :meth:`to_config` makes the
    :class:`~lidarsim.build.BuildConfig`). Defaults are ``lidarsim.defaults``'. Each field's help,
    unit, default and range is its metadata (``hdcore.setting``): the options of
    ``hd build-dataset``, the reading of a recipe's ``[build]`` and the checks here are made from it.
    """

    sigmas_m: tuple[float, ...] = setting(
        (defaults.DEFAULT_SIGMA_M,),
        "Range noise 1-sigma, {unit}; repeat for several levels (with --noise-model snr: at 500 m, normal incidence)",
        unit="metres",
        bound=limits.SIGMA_M,
        flag="--sigma",
    )
    scans: int = setting(
        defaults.N_SCANS, "Number of scans (with --descent-frames K: of descents, each K scans)", bound=limits.SCANS
    )
    seed: int = setting(defaults.SEED, "Seed of every random stream of the build", bound=limits.SEED)
    altitude_m: float | tuple[float, float] | str = setting(
        defaults.ALTITUDE_M,
        "Sensor altitude above the terrain, {unit}, in {bound}; LOW:HIGH draws it per scan (250:1000).",
        unit="metres",
        bound=limits.ALTITUDE_M,
        checked=False,  # one number or LOW:HIGH: lidarsim.trajectory checks it, with the range's own messages
        flag="--altitude",
        metavar="M|LOW:HIGH",
        click_type=SpanType(limits.ALTITUDE_M),
    )
    dtm_path: str | None = setting(
        None,
        "DTM (GeoTIFF, HiRISE PDS3 .IMG, any GDAL raster in metres). Default: the procedural Mars terrain.",
        kind=Path,
        flag="--dtm",
        click_type=FILE_OR_DIRECTORY,
    )
    dtm_scale: float = setting(
        defaults.DTM_SCALE,
        f"Resample the DTM by this factor (the paper used {defaults.PAPER_DTM_SCALE})",
        bound=limits.DTM_SCALE,
    )
    shard_size: int = setting(defaults.SHARD_SIZE, "Scans per shard file", bound=limits.SHARD_SIZE)
    tilt_deg: float | tuple[float, float] | str = setting(
        defaults.TILT_DEG,
        "Off-nadir tilt of the boresight, {unit}, in {bound}; LOW:HIGH draws it per scan.",
        unit="degrees",
        bound=limits.TILT_DEG,
        checked=False,  # one number or LOW:HIGH: lidarsim.trajectory checks it, with the range's own messages
        flag="--tilt",
        metavar="DEG|LOW:HIGH",
        click_type=SpanType(limits.TILT_DEG),
    )
    jitter_deg: float | tuple[float, float] | str = setting(
        defaults.JITTER_DEG,
        "1-sigma attitude jitter per axis, {unit}, in {bound}; LOW:HIGH draws it per scan.",
        unit="degrees",
        bound=limits.JITTER_DEG,
        checked=False,  # one number or LOW:HIGH: lidarsim.trajectory checks it, with the range's own messages
        flag="--jitter",
        metavar="DEG|LOW:HIGH",
        click_type=SpanType(limits.JITTER_DEG),
    )
    resolution: int = setting(defaults.DETECTOR_ROWS, "Detector pixels per side", bound=limits.DETECTOR_PX)
    fov_deg: float = setting(
        defaults.FOV_DEG, "Field of view per side", unit="degrees", bound=limits.FOV_DEG, flag="--fov"
    )
    dead_elements: int = setting(
        defaults.DEAD_ELEMENTS, "Dead detector elements (no return)", bound=limits.DETECTOR_ELEMENTS
    )
    damaged_elements: int = setting(
        defaults.DAMAGED_ELEMENTS, "Damaged detector elements (large range error)", bound=limits.DETECTOR_ELEMENTS
    )
    compression: str = setting(
        defaults.COMPRESSION, "HDF5 compression of the point arrays", choices=defaults.COMPRESSIONS
    )
    rocks_on_dtm: bool = setting(
        False, "Scan the --dtm resampled to 0.5 m with the procedural rock population added (as hd make-dtm --base)"
    )
    # The footprint's and the noise model's settings, each described once in its config class.
    footprint_samples: int = described_as(FootprintConfig, "samples")
    spot_profile: str = described_as(FootprintConfig, "spot_profile")
    range_estimator: str = described_as(FootprintConfig, "range_estimator")
    pulse_width_m: float = described_as(FootprintConfig, "pulse_width_m")
    return_fraction: float = described_as(FootprintConfig, "return_fraction")
    noise_model: str = described_as(NoiseModel, "kind", flag="")
    snr_ref: float = described_as(NoiseModel, "snr_ref")
    snr_min: float = described_as(NoiseModel, "snr_min")
    descent_frames: int = setting(
        defaults.DESCENT_FRAMES,
        "Frames per descent: with K >= 2 the build flies descents instead of single scans, K frames each "
        "from the first to the second of --descent-altitudes toward one target; --scans then counts descents, "
        "the dataset holds scans x K frames (each a scan) and a shard whole descents (--shard-size rounded up "
        "to a multiple of K); 0: single scans",
        bound=limits.DESCENT_FRAMES,
    )
    descent_altitudes_m: tuple[float, float] | str = setting(
        f"{defaults.DESCENT_ALTITUDE_START_M:g}:{defaults.DESCENT_ALTITUDE_END_M:g}",
        "A descent's first and last frame altitudes above the target's terrain, {unit}, START:END with "
        "START > END, each in {bound}; frame k of K flies at START + (END - START) k / (K - 1).",
        unit="metres",
        bound=limits.ALTITUDE_M,
        checked=False,  # two numbers: lidarsim.descent checks them, with the descent's own messages
        flag="--descent-altitudes",
        metavar="START:END",
        click_type=DescendingPairType(limits.ALTITUDE_M),
    )
    approach_deg: float = setting(
        defaults.APPROACH_DEG,
        "Angle from the vertical, {unit}, of a descent's straight approach path toward its target "
        "(0: vertical); the boresight looks at the target, the direction the path comes from is drawn per descent.",
        unit="degrees",
        bound=limits.APPROACH_DEG,
    )
    nav_position_sigma_m: float = described_as(NavigationError, "position_sigma_m")
    nav_position_walk_m: float = described_as(NavigationError, "position_walk_m")
    nav_attitude_sigma_deg: float = described_as(NavigationError, "attitude_sigma_deg")
    nav_attitude_walk_deg: float = described_as(NavigationError, "attitude_walk_deg")

    def __post_init__(self) -> None:
        check(self, LidarsimError)

    def to_config(self) -> BuildConfig:
        """The build configuration (a square detector with the same FOV on both axes).

        Raises:
            LidarsimError: an invalid value, named by its option.
        """
        altitude, altitude_max = parse_span("altitude_m", self.altitude_m)
        tilt, tilt_max = parse_span("tilt_deg", self.tilt_deg)
        jitter, jitter_max = parse_span("jitter_deg", self.jitter_deg)
        descent = self._descent()
        scans = int(self.scans) * (1 if descent is None else descent.frames)
        if descent is not None and scans > limits.MAX_SCANS:
            raise LidarsimError(
                f"{self.scans} descents of {descent.frames} frames are {scans:,} scans, more than hd's maximum of "
                f"{limits.MAX_SCANS:,}; ask for fewer --scans or --descent-frames"
            )
        return BuildConfig(
            sigmas_m=tuple(float(s) for s in self.sigmas_m),
            seed=int(self.seed),
            sensor=SensorConfig(
                rows=int(self.resolution),
                cols=int(self.resolution),
                fov_x_deg=float(self.fov_deg),
                fov_y_deg=float(self.fov_deg),
                dead_elements=int(self.dead_elements),
                damaged_elements=int(self.damaged_elements),
            ),
            trajectory=TrajectoryConfig(
                n_scans=scans,
                altitude_m=altitude,
                tilt_deg=tilt,
                jitter_deg=jitter,
                altitude_max_m=altitude_max,
                tilt_max_deg=tilt_max,
                jitter_max_deg=jitter_max,
                descent=descent,
            ),
            dtm_path=self.dtm_path,
            dtm_scale=float(self.dtm_scale),
            shard_size=int(self.shard_size),
            compression=str(self.compression),
            rocks_on_dtm=self.rocks_on_dtm,
            footprint=self._filled(FootprintConfig),
            noise_model=self._filled(NoiseModel),
        )

    def _filled(self, cls: type[T]) -> T:
        """The config ``cls`` (``FootprintConfig``, ``NoiseModel``) made of this record's fields that are
        described as its own (``_FLAT_NAMES``: the fields named otherwise here), each of the field's kind."""
        values = {}
        for f, d in described_fields(cls):
            if d.cli:
                value = getattr(self, _FLAT_NAMES.get((cls.__name__, f.name), f.name))
                values[f.name] = d.kind(value)
        return cls(**values)

    def _descent(self) -> DescentConfig | None:
        """The descent of ``--descent-frames`` K >= 2 (None for 0: single scans, whose descent settings
        must then be left at their defaults).

        Raises:
            LidarsimError: a descent setting without --descent-frames, K = 1, or bad altitudes.
        """
        start, end = parse_pair("--descent-altitudes", self.descent_altitudes_m)
        nav = NavigationError(
            position_sigma_m=float(self.nav_position_sigma_m),
            position_walk_m=float(self.nav_position_walk_m),
            attitude_sigma_deg=float(self.nav_attitude_sigma_deg),
            attitude_walk_deg=float(self.nav_attitude_walk_deg),
        )
        if int(self.descent_frames) == 0:
            given = (start, end, float(self.approach_deg))
            if given != (defaults.DESCENT_ALTITUDE_START_M, defaults.DESCENT_ALTITUDE_END_M, defaults.APPROACH_DEG) or (
                not nav.is_perfect
            ):
                raise LidarsimError(
                    "--descent-altitudes, --approach-deg and the --nav-* errors describe descents: give "
                    "--descent-frames K (K >= 2) with them"
                )
            return None
        return DescentConfig(
            frames=int(self.descent_frames),
            altitude_start_m=start,
            altitude_end_m=end,
            approach_deg=float(self.approach_deg),
            nav=nav,
        )


# Recipe [build] keys that differ from the BuildSettings field they fill.
_BUILD_KEY_FIELDS = {"dtm": "dtm_path"}
_BUILD_KEYS = {k for k in (f.name for f in fields(BuildSettings)) if k not in _BUILD_KEY_FIELDS.values()} | {
    *_BUILD_KEY_FIELDS,
    "dtm_sha256",
}


@dataclass(frozen=True)
class RecipeMeta:
    """A recipe's ``[dataset]`` section (each key described once, as for the settings)."""

    name: str | None = setting(None, "The dataset's name (default: the recipe directory's)", kind=str, cli=False)
    description: str = setting("", "What the dataset is for", cli=False)
    version: int = setting(1, "Bumped whenever the content changes", bound=Bound(1, integer=True), cli=False)

    def __post_init__(self) -> None:
        check(self, RecipeError)


@dataclass(frozen=True)
class Recipe:
    """A parsed recipe: the build configuration and the label settings (raw, for hdlabels); ``dtm``:
    its ``[build] dtm`` as written (a relative path is read beside the recipe file)."""

    name: str
    path: Path
    build: BuildConfig
    label: dict[str, Any] = field(default_factory=dict)
    description: str = ""
    version: int = 1
    dtm: str = ""

    def checksums(self) -> ChecksumsJson | None:
        """The recorded checksums of the published build, or None when the recipe has none."""
        path = self.path.parent / CHECKSUMS_FILE
        if not path.is_file():
            return None
        try:
            recorded = json.loads(read_regular_bytes(path).decode("utf-8"))
        except (ValueError, RecursionError) as exc:  # StorageError, decoding, JSON, digit limit
            raise RecipeError(f"{path}: unreadable checksums ({exc})") from exc
        _check_checksums(recorded, path)
        return cast("ChecksumsJson", recorded)  # its structure checked above


# Directories (``os.pathsep``-separated) searched for a recipe given by its bare name.
RECIPE_PATH_ENV = "HD_RECIPE_PATH"
# The recipes of a source checkout (an editable install): datasets/ beside the packages.
SOURCE_RECIPES = Path(__file__).resolve().parents[1] / "datasets"
# The recipes of an installed wheel: the same datasets/ folder, shipped as the package data
# ``lidarsim/datasets`` (pyproject.toml maps the package ``lidarsim.datasets`` onto datasets/).
PACKAGED_RECIPES = Path(__file__).resolve().parent / "datasets"


def shipped_recipe_dirs() -> list[Path]:
    """The folders of the recipes that come with hd: the source checkout's ``datasets/`` and, in an
    installed wheel, the package data ``lidarsim/datasets`` (only those that exist)."""
    return [d for d in (SOURCE_RECIPES, PACKAGED_RECIPES) if d.is_dir()]


def recipe_search_dirs() -> list[Path]:
    """Where a recipe given by its bare name is looked for, in order: the current directory,
    each directory of ``$HD_RECIPE_PATH``, then the recipes that come with hd
    (:func:`shipped_recipe_dirs`)."""
    extra = [Path(d) for d in os.environ.get(RECIPE_PATH_ENV, "").split(os.pathsep) if d]
    return [Path("."), *extra, *shipped_recipe_dirs()]


def shipped_recipe(name: str) -> Path:
    """The directory of the recipe ``name`` that comes with hd (``mars-paper``), wherever hd is
    installed; never one of the current directory or of ``$HD_RECIPE_PATH``.

    Raises:
        RecipeError: hd ships no recipe of that name.
    """
    for d in shipped_recipe_dirs():
        if (d / name / RECIPE_FILE).is_file():
            return d / name
    raise RecipeError(f"{name}: hd ships no such recipe (looked in {', '.join(map(str, shipped_recipe_dirs()))})")


def find_recipe(path: str | os.PathLike) -> Path:
    """The recipe file named by ``path``: a ``recipe.toml`` or its directory (as given), or a bare
    name (``mars-paper``) looked for in :func:`recipe_search_dirs`.

    Raises:
        RecipeError: no such recipe, naming the places looked in and the recipes found there.
    """
    given = Path(path)
    candidates = [given]
    if len(given.parts) == 1 and given.name not in (".", ".."):
        candidates += [d / given for d in recipe_search_dirs()[1:]]
    for candidate in candidates:
        file = candidate / RECIPE_FILE if candidate.is_dir() else candidate
        if file.is_file():
            return file
    known = sorted({p.parent.name for d in recipe_search_dirs() if d.is_dir() for p in d.glob(f"*/{RECIPE_FILE}")})
    where = ", ".join(str(d) for d in recipe_search_dirs())
    raise RecipeError(
        f"{given}: no such recipe (looked in {where}; set {RECIPE_PATH_ENV} to add places)"
        + (f"; recipes there: {', '.join(known)}" if known else "")
    )


def load_recipe(path: str | os.PathLike) -> Recipe:
    """Read ``recipe.toml`` (``path`` is the file, its directory or a recipe's bare name, see
    :func:`find_recipe`).

    Raises:
        RecipeError: missing or unreadable file, unknown keys, invalid values.
    """
    path = find_recipe(path)
    try:
        data = tomllib.loads(read_regular_bytes(path).decode("utf-8"))
    except ValueError as exc:  # StorageError, decoding, TOML, digit limit
        raise RecipeError(f"{path}: not a valid TOML recipe ({exc})") from exc
    unknown_sections = set(data) - {"dataset", "build", "label"}
    if unknown_sections:
        raise RecipeError(f"{path}: unknown section(s) {sorted(unknown_sections)}")
    for section, value in data.items():
        if not isinstance(value, dict):
            raise RecipeError(f"{path}: [{section}] must be a table of settings, got {type(value).__name__}")
    build = data.get("build", {})
    label = data.get("label", {})
    for section, keys, known in (("build", build, _BUILD_KEYS), ("label", label, _LABEL_KEYS)):
        unknown = set(keys) - known
        if unknown:
            raise RecipeError(f"{path}: unknown [{section}] key(s) {sorted(unknown)}")
    values = {_BUILD_KEY_FIELDS.get(k, k): v for k, v in build.items()}
    dtm_sha256 = values.pop("dtm_sha256", "")
    try:
        dtm = values.pop("dtm_path", "")
        if dtm:  # "" is the procedural terrain; a relative path is relative to the recipe
            dtm_path = Path(dtm) if Path(dtm).is_absolute() else (path.parent / dtm)
            values["dtm_path"] = str(dtm_path.resolve())
            if dtm_sha256:
                if not dtm_path.is_file():
                    raise RecipeError(missing_dtm_message(path, str(dtm), dtm_path))
                _check_dtm_sha256(path, dtm_path, dtm_sha256)
        elif dtm_sha256:
            raise RecipeError(f"{path}: [build] dtm_sha256 is given without a dtm")
        config = from_mapping(BuildSettings, values, str(path), "build", RecipeError).to_config()
    except (TypeError, ValueError) as exc:
        if isinstance(exc, RecipeError):
            raise
        if isinstance(exc, LidarsimError):  # a bad value is a RecipeError; a TerrainError etc. stays one
            raise (RecipeError if type(exc) is LidarsimError else type(exc))(f"{path}: {exc}") from exc
        raise RecipeError(f"{path}: invalid value ({exc})") from exc
    meta = from_mapping(RecipeMeta, data.get("dataset", {}), str(path), "dataset", RecipeError)
    return Recipe(
        name=meta.name if meta.name is not None else path.parent.name,
        path=path.resolve(),
        build=config,
        label=dict(label),
        description=meta.description,
        version=meta.version,
        dtm=str(build.get("dtm", "")),
    )


def missing_dtm_message(recipe_path: Path, written: str, dtm_path: Path) -> str:
    """A recipe's DTM is not there: where it was looked for, and why there (a relative path is read
    beside the recipe file, not in the current directory)."""
    where = f"{recipe_path}: its DTM {dtm_path.resolve()} does not exist"
    if Path(written).is_absolute():
        return where
    return (
        f'{where} (a relative dtm is read beside the recipe: dtm = "{written}"); copy the DTM beside the recipe '
        "or give its absolute path"
    )


def check_recipe_dtm(recipe: Recipe) -> None:
    """The recipe's DTM is there to be built from (a recipe is also read without it: ``hd verify
    --recipe`` needs only its checksums).

    Raises:
        RecipeError: naming the file looked for and the recipe's own words for it.
    """
    if recipe.build.dtm_path is not None and not Path(recipe.build.dtm_path).is_file():
        raise RecipeError(missing_dtm_message(recipe.path, recipe.dtm, Path(recipe.build.dtm_path)))


def _check_dtm_sha256(recipe_path: Path, dtm_path: Path, expected: object) -> None:
    """Refuse a recipe DTM whose bytes are not the ones the recipe names (``dtm_sha256``)."""
    from lidarsim.terrain import dtm_sha256  # rasterio, only when a recipe names its DTM

    if not isinstance(expected, str) or len(expected) != 64:
        raise RecipeError(f"{recipe_path}: [build] dtm_sha256 must be 64 hex digits, got {expected!r}")
    if not dtm_path.is_file():
        raise RecipeError(f"{recipe_path}: the recipe's DTM {dtm_path} does not exist")
    actual = dtm_sha256(dtm_path)
    if actual != expected.lower():
        raise RecipeError(
            f"{recipe_path}: the DTM {dtm_path} has sha256 {actual[:12]}..., the recipe names {expected[:12]}...: "
            "not the recipe's terrain"
        )


def _check_checksums(recorded: Any, path: Path) -> None:
    """Every field of a recipe's ``checksums.json``, checked for its type and range when it is read:
    digests are sha256 (64 lower-case hex digits), versions ``MAJOR.MINOR``, file paths relative
    and inside the dataset, scan counts within ``limits.SCANS``, no number NaN or infinite, and each
    ``content`` a fingerprint whose values a file can have (``lidarsim.fingerprint.fingerprint_problem``).
    A file with impossible values would otherwise "verify": a NaN or infinite statistic widens a
    tolerance until any rebuild passes, and the identical copy never looks at them.

    Raises:
        RecipeError: one line naming the file, the field, its value and what it must be.
    """
    if not isinstance(recorded, dict):
        raise RecipeError(f"{path}: not a JSON object of checksums")
    field = _non_finite_field(recorded)
    if field is not None:
        raise RecipeError(f"{path}: {field[0]} is {field[1]}: a checksums file holds finite numbers only")
    for key in ("software_version", "schema", "fingerprint_schema"):
        if key in recorded and not isinstance(recorded[key], str):
            _impossible(path, key, recorded[key], "must be a string")
    for key in ("schema_version", "shard_schema_version", "fingerprint_schema_version"):
        value = recorded.get(key)
        if key in recorded and not (value is None and key == "shard_schema_version") and not _is_version(value):
            _impossible(path, key, value, "a schema version is MAJOR.MINOR (1.2)")
    if "config_sha256" in recorded and not is_sha256(recorded["config_sha256"]):
        _impossible(path, "config_sha256", recorded["config_sha256"], "a sha256 is 64 lower-case hex digits")
    shards = recorded.get("shards", [])
    if not isinstance(shards, list):
        raise RecipeError(f"{path}: 'shards' must be a list")
    for i, entry in enumerate(shards):
        _check_file_entry(entry, f"shards[{i}]", path)
    labelings = recorded.get("labelings", [])
    if not isinstance(labelings, list):
        raise RecipeError(f"{path}: 'labelings' must be a list")
    for i, lab in enumerate(labelings):
        if not isinstance(lab, dict) or not isinstance(lab.get("name"), str) or not lab["name"]:
            raise RecipeError(f"{path}: labelings[{i}] must give a 'name' as a non-empty string")
        if not isinstance(lab.get("shards", []), list):
            _impossible(path, f"labelings[{i}].shards", lab["shards"], "must be a list")
        for j, entry in enumerate(lab.get("shards", [])):
            _check_file_entry(entry, f"labelings[{i}].shards[{j}]", path)
    if "dtm" in recorded:
        _check_file_entry(recorded["dtm"], "dtm", path)


def _check_file_entry(entry: Any, where: str, path: Path) -> None:
    """One file of the published build: ``path``, ``sha256``, optional ``n_scans`` and ``content``."""
    if not isinstance(entry, dict) or not all(isinstance(entry.get(k), str) for k in ("path", "sha256")):
        raise RecipeError(f"{path}: {where} must give a 'path' and a 'sha256' as strings")
    rel = entry["path"]
    if not rel or Path(rel).is_absolute() or ".." in Path(rel).parts:
        _impossible(path, f"{where}.path", rel, "a file of the dataset is named by a path relative to it, without ..")
    if not is_sha256(entry["sha256"]):
        _impossible(path, f"{where}.sha256", entry["sha256"], "a sha256 is 64 lower-case hex digits")
    if "n_scans" in entry:
        n = entry["n_scans"]
        if isinstance(n, bool) or not isinstance(n, int) or not limits.SCANS.contains(n):
            _impossible(path, f"{where}.n_scans", n, f"a scan count is an integer in {limits.SCANS.interval()}")
    if "content" in entry:
        problem = fingerprint_problem(entry["content"])
        if problem is not None:
            field, value, why = problem
            _impossible(path, f"{where}.content{'.' if field else ''}{field}", value, why)


def _impossible(path: Path, field: str, value: Any, why: str) -> None:
    text = json.dumps(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else repr(value)
    if len(text) > 80:
        text = text[:77] + "..."
    raise RecipeError(f"{path}: {field} is {text}: {why}")


def _is_version(value: Any) -> bool:
    return isinstance(value, str) and re.fullmatch(r"\d+\.\d+", value) is not None


def _non_finite_field(tree: Any) -> tuple[str, str] | None:
    """The first NaN or infinite number in a JSON tree: (its field, NaN/Infinity/-Infinity), or None
    (walked without recursion: json.loads accepts trees nested deeper than a recursive walk could go)."""
    todo: list[tuple[str, Any]] = [("", tree)]
    while todo:
        where, node = todo.pop()
        if isinstance(node, float) and not math.isfinite(node):
            return where, json.dumps(node)
        items = list(node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ())
        for key, value in reversed(items):
            todo.append((f"{where}[{key}]" if isinstance(key, int) else f"{where}.{key}" if where else str(key), value))
    return None


def check_against_checksums(manifest: ManifestJson, recorded: ChecksumsJson) -> list[str]:
    """Compare a dataset's manifest with a recipe's recorded checksums; returns one-line problems."""
    problems: list[str] = []
    if manifest.get("config_sha256") != recorded.get("config_sha256"):
        problems.append("the dataset was built with other settings than the recipe's published build")
    # Checksums published before shard schema 1.1 do not record it: they are of 1.0 shards.
    published = str(recorded.get("shard_schema_version", "1.0"))
    built = {str(s.get("schema_version", "")) for s in manifest.get("shards", [])}
    if built and built != {published}:
        problems.append(
            f"the recipe's checksums were published for scan shards of schema version {published}, this dataset's "
            f"shards are version {', '.join(sorted(built))}: the same settings give other bytes; the recipe's "
            "checksums must be published again with this hd (`hd card`)"
        )
        return problems
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


def check_against_recipe(manifest: ManifestJson, recipe_dir: str | os.PathLike) -> list[str]:
    """Compare a dataset's manifest with the checksums published with a recipe (``hd verify --recipe``).

    Raises:
        RecipeError: the recipe cannot be read or has no published ``checksums.json``.
    """
    recipe = load_recipe(recipe_dir)
    recorded = recipe.checksums()
    if recorded is None:
        raise RecipeError(f"{recipe.path.parent}: the recipe has no published {CHECKSUMS_FILE}")
    return check_against_checksums(manifest, recorded)
