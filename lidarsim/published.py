"""A dataset against its recipe's published build: ``hd verify DIR --recipe datasets/<name>``.

A recipe's ``checksums.json`` (written by ``hd card``, :func:`lidarsim.card.checksums_of`) records,
for every file of the published build (scan shards, label shards, the procedural terrain), its
sha256 and its content fingerprint (:mod:`lidarsim.fingerprint`). A dataset's file is then, at one
of two levels:

* **identical (sha256)**: byte for byte the published file;
* **rebuilt: equal to the published build within tolerance**: other bytes (another machine's zlib,
  another CPU's rounding in the label kernels), same content: every attribute, integer statistic
  and label count equal, every floating sum and extreme within the fingerprint tolerances.

Anything else is a problem naming the file, the array or attribute and the difference. A damaged
file fails either way: its chunks are read (fletcher32) to compute its fingerprint.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hdcore.storage import DamagedFileError, FormatError, StorageError, confine
from lidarsim.build import BuildConfig, setting_changes
from lidarsim.checksums_json import ChecksumsJson, FingerprintJson, PublishedFileJson, PublishedLabelingJson
from lidarsim.errors import RecipeError
from lidarsim.fingerprint import (
    FLOAT32_EXTREME_RTOL,
    FLOAT32_RTOL,
    FLOAT64_RTOL,
    array_fingerprint,
    attr_record,
    check_fingerprint_schema,
    compare_fingerprints,
    h5_fingerprint,
)
from lidarsim.manifest_json import FileEntryJson, ManifestJson, ShardRefJson
from lidarsim.recipe import CHECKSUMS_FILE, load_recipe
from lidarsim.recipe_deviation import recorded_deviation
from lidarsim.shards import TRUTH_DTM_SHA256_ATTR, read_manifest

__all__ = [
    "IDENTICAL",
    "PublishedComparison",
    "compare_with_published",
    "compare_with_recipe",
    "content_fingerprints",
    "terrain_fingerprint",
]

IDENTICAL = "identical (sha256)"
_TOLERANCES = (
    f"float32 sums {FLOAT32_RTOL:g}, extremes {FLOAT32_EXTREME_RTOL:g}, float64 {FLOAT64_RTOL:g} of the array's "
    "scale; integers, label counts and attributes exact"
)


@dataclass
class PublishedComparison:
    """The comparison of a dataset with a recipe's published build.

    Attributes:
        verdicts: one line per compared file: ``PATH: identical (sha256)`` or
            ``PATH: rebuilt: equal to the published build within tolerance (...)``, and notes on
            what could not be compared (a labelling not made yet).
        problems: one line per difference beyond tolerance (empty: the dataset is the published one).
        identical: files identical to the published ones.
        rebuilt: files equal to the published ones within tolerance.
    """

    verdicts: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    identical: int = 0
    rebuilt: int = 0

    def summary(self) -> str:
        """One line: how many files are identical and how many rebuilt within tolerance."""
        same = f"{self.identical} file{'' if self.identical == 1 else 's'} identical to the recipe's published build"
        if not self.rebuilt:
            return f"{same} (sha256)"
        return (
            f"{same} (sha256), {self.rebuilt} rebuilt: equal to it within tolerance (content fingerprints, "
            "docs/shard-format.md)"
        )


def terrain_fingerprint(path: str | os.PathLike, what: str | None = None) -> FingerprintJson:
    """Content fingerprint of a GeoTIFF terrain: its heights (array ``heights``) and, as attributes,
    its size, transform, CRS, nodata value and tags (``hd.content-fingerprint`` 1.0).

    Raises:
        DamagedFileError: the file cannot be read as a raster.
    """
    import rasterio
    from rasterio.errors import RasterioIOError

    name = what or str(path)
    try:
        with rasterio.open(path) as src:
            heights = src.read(1)
            attrs: dict[str, object] = {
                "width": int(src.width),
                "height": int(src.height),
                "transform": [float(v) for v in tuple(src.transform)[:6]],
                "crs": src.crs.to_wkt() if src.crs else "",
                "nodata": None if src.nodata is None else str(float(src.nodata)),
                **{f"tag_{k}": str(v) for k, v in sorted(src.tags().items())},
            }
    except (RasterioIOError, OSError) as exc:
        raise DamagedFileError(f"{name}: cannot read the terrain ({exc}); the file is damaged") from exc
    return {
        "attrs": {k: attr_record(v) for k, v in sorted(attrs.items())},
        "arrays": {"heights": array_fingerprint([heights], heights.dtype, heights.shape)},
    }


def content_fingerprints(directory: str | os.PathLike, manifest: ManifestJson) -> dict[str, FingerprintJson]:
    """Fingerprints of every file a manifest lists (scan shards, label shards, a terrain kept inside
    the dataset), keyed by path relative to the dataset.

    Raises:
        DamagedFileError, StorageError: a file cannot be read.
    """
    directory = Path(directory)
    out: dict[str, FingerprintJson] = {}
    entries: list[FileEntryJson] = list(manifest.get("shards", []))
    for labelling in manifest.get("labelings", []):
        entries.extend(labelling.get("shards", []))
    for entry in entries:
        out[entry["path"]] = h5_fingerprint(confine(directory, entry["path"]), entry["path"])
    terrain = _terrain_entry(manifest)
    if terrain is not None:
        out[terrain["path"]] = terrain_fingerprint(confine(directory, terrain["path"]), terrain["path"])
    return out


def _terrain_entry(manifest: ManifestJson) -> ShardRefJson | None:
    """The manifest's terrain when the dataset keeps it (a relative path: the procedural terrain)."""
    dtm = manifest.get("dtm")
    if not isinstance(dtm, dict) or not isinstance(dtm.get("path"), str) or os.path.isabs(dtm["path"]):
        return None
    return {"path": dtm["path"], "sha256": dtm["sha256"]} if isinstance(dtm.get("sha256"), str) else None


def _entries(recorded: Any, where: str) -> list[PublishedFileJson]:
    if not isinstance(recorded, list) or not all(isinstance(e, dict) for e in recorded):
        raise RecipeError(f"{where} must be a list of entries")
    for i, entry in enumerate(recorded):
        if not isinstance(entry.get("path"), str) or not isinstance(entry.get("sha256"), str):
            raise RecipeError(f"{where}[{i}] must give a 'path' and a 'sha256' as strings")
        if "content" in entry and not isinstance(entry["content"], dict):
            raise RecipeError(f"{where}[{i}]: 'content' must be a JSON object (a content fingerprint)")
    return recorded


class _Comparer:
    """Compares the files of one dataset with the published entries, file by file."""

    def __init__(
        self,
        directory: Path | None,
        manifest: ManifestJson,
        out: PublishedComparison,
        published_sha: dict[str, str],
        published_dtm: str | None,
    ) -> None:
        self.directory = directory
        self.manifest = manifest
        self.out = out
        self.local_sha = {e["path"]: e["sha256"] for e in manifest.get("shards", [])}
        self.published_sha = published_sha
        self.published_dtm = published_dtm

    def files(self, published: list[PublishedFileJson], have: Sequence[ShardRefJson], what: str) -> None:
        want = {e["path"]: e for e in published}
        got = {e["path"]: e for e in have if isinstance(e, dict) and isinstance(e.get("path"), str)}
        for path in sorted(set(want) | set(got)):
            if path not in got:
                self.out.problems.append(f"{path}: listed by the recipe's checksums, missing from the dataset")
            elif path not in want:
                self.out.problems.append(f"{path}: not part of the recipe's published build ({what})")
            else:
                self.one(path, want[path], got[path]["sha256"])

    def one(self, path: str, published: PublishedFileJson, sha256: str) -> None:
        if sha256 == published["sha256"]:
            self.out.identical += 1
            self.out.verdicts.append(f"{path}: {IDENTICAL}")
            return
        content = published.get("content")
        if content is None:
            self.out.problems.append(
                f"{path}: sha256 differs from the recipe's published build (the recipe publishes no content "
                "fingerprint to compare the content with; publish its checksums again with `hd card`)"
            )
            return
        if self.directory is None:
            self.out.problems.append(
                f"{path}: sha256 differs from the recipe's published build (content not compared: the dataset "
                "has other problems)"
            )
            return
        try:
            file = confine(self.directory, path)
            rebuilt = terrain_fingerprint(file, path) if path.endswith(".tif") else h5_fingerprint(file, path)
        except (DamagedFileError, FormatError, StorageError) as exc:
            self.out.problems.append(str(exc))
            return
        result = compare_fingerprints(content, rebuilt, path)
        problems = result.problems + self._digest_problems(path, rebuilt.get("attrs", {}))
        if problems:
            self.out.problems += problems
            return
        self.out.rebuilt += 1
        newer = f"; {result.newer}" if result.newer else ""
        self.out.verdicts.append(
            f"{path}: rebuilt: equal to the published build within tolerance ({result.n_arrays} arrays, "
            f"{result.n_attrs} attributes; largest difference {result.worst:.2g} of its tolerance; "
            f"tolerances: {_TOLERANCES}{newer})"
        )

    def _digest_problems(self, path: str, attrs: dict[str, object]) -> list[str]:
        """Attributes naming another file's sha256 must name the dataset's own file (or the published one)."""
        problems = []
        source, digest = attrs.get("source_shard"), attrs.get("source_sha256")
        if isinstance(source, str) and digest not in (None, self.local_sha.get(source), self.published_sha.get(source)):
            problems.append(
                f"{path}: source_sha256 names neither this dataset's {source} nor the published one: "
                "the labels were made from another scan shard"
            )
        terrain = _terrain_entry(self.manifest)
        dtm_digest = attrs.get("dtm_sha256")
        if terrain is not None and dtm_digest not in (None, terrain["sha256"], self.published_dtm):
            problems.append(
                f"{path}: dtm_sha256 names neither this dataset's terrain nor the published one: "
                "the scans were made on another terrain"
            )
        dtm = self.manifest.get("dtm")
        truth_digest = attrs.get(TRUTH_DTM_SHA256_ATTR)
        own = dtm.get("sha256") if isinstance(dtm, dict) else None
        if truth_digest not in (None, own, self.published_dtm):
            problems.append(
                f"{path}: {TRUTH_DTM_SHA256_ATTR} names neither this dataset's terrain nor the published one: "
                "the labels were made from another terrain"
            )
        return problems


def _not_comparable(manifest: ManifestJson, recorded: ChecksumsJson, recipe_config: BuildConfig | None) -> str | None:
    """Step 1 of :func:`compare_with_published`: why the dataset's files cannot be the published build's
    (a deviation from its recipe, other settings, another shard schema version), or None."""
    try:
        deviation = recorded_deviation(manifest)
    except FormatError as exc:
        return str(exc)
    if deviation is not None:
        return (
            f"the dataset deviates from its recipe {deviation.recipe} ({deviation.words()}): its files are not the "
            "published build's, their checksums are not compared"
        )
    if manifest.get("config_sha256") != recorded.get("config_sha256"):
        return _other_settings(manifest, recorded, recipe_config)
    # Checksums published before shard schema 1.1 do not record it: they are of 1.0 shards.
    shard_schema = str(recorded.get("shard_schema_version", "1.0"))
    built = {str(s.get("schema_version", "")) for s in manifest.get("shards", [])}
    if built and built != {shard_schema}:
        return (
            f"the recipe's checksums were published for scan shards of schema version {shard_schema}, this "
            f"dataset's shards are version {', '.join(sorted(built))}: the same settings give other bytes; the "
            "recipe's checksums must be published again with this hd (`hd card`)"
        )
    return None


def _compare_labelings(
    comparer: _Comparer, labelings: list[PublishedLabelingJson], manifest: ManifestJson, out: PublishedComparison
) -> None:
    """Step 2 of :func:`compare_with_published`: each published labelling's files against the dataset's
    labelling of the same name; one missing on either side is a verdict, not a problem."""
    have = {lab.get("name"): lab for lab in manifest.get("labelings", []) if isinstance(lab, dict)}
    for lab in labelings:
        mine = have.get(lab["name"])
        if mine is None:
            out.verdicts.append(
                f"labelling {lab['name']}: not in this dataset, not compared (label it with the recipe: "
                "`hd label DIR --recipe RECIPE`)"
            )
            continue
        comparer.files(_entries(lab.get("shards", []), f"labelings[{lab['name']}].shards"), mine["shards"], "label")
    published_names = {lab["name"] for lab in labelings}
    for name in sorted(n for n in have if isinstance(n, str) and n not in published_names):
        out.verdicts.append(f"labelling {name}: not part of the recipe's published build, not compared")


def compare_with_published(
    manifest: ManifestJson,
    recorded: ChecksumsJson,
    directory: str | os.PathLike | None = None,
    recipe_config: BuildConfig | None = None,
) -> PublishedComparison:
    """Compare a dataset (its manifest, and its files under ``directory``) with a recipe's published
    build (the parsed ``checksums.json``).

    Without ``directory`` only the sha256 are compared. Published labellings are compared with the
    dataset's labelling of the same name; one the dataset lacks is noted, not a problem (label the
    dataset with the recipe to compare it). A dataset built at another size than its recipe's
    (``lidarsim.recipe_deviation``) is named as such and not compared; one built with other
    settings has them named against ``recipe_config`` (the recipe's own), when given.

    Raises:
        RecipeError: malformed published checksums.
        FormatError: malformed published fingerprints, or fingerprints of an unknown major schema
            version (``lidarsim.fingerprint``'s own error, passed on).
    """
    out = PublishedComparison()
    reason = _not_comparable(manifest, recorded, recipe_config)
    if reason is not None:
        out.problems.append(reason)
        return out
    try:
        check_fingerprint_schema(recorded, CHECKSUMS_FILE)
    except FormatError as exc:
        raise type(exc)(f"{exc}; this hd cannot compare the content of a rebuild with them") from exc
    shards = _entries(recorded.get("shards", []), "shards")
    labelings = recorded.get("labelings", [])
    if not isinstance(labelings, list) or not all(
        isinstance(lab, dict) and isinstance(lab.get("name"), str) for lab in labelings
    ):
        raise RecipeError(f"{CHECKSUMS_FILE}: 'labelings' must be a list of entries with a 'name'")
    dtm = recorded.get("dtm")
    comparer = _Comparer(
        Path(directory) if directory is not None else None,
        manifest,
        out,
        published_sha={e["path"]: e["sha256"] for e in shards},
        published_dtm=dtm.get("sha256") if isinstance(dtm, dict) else None,
    )
    comparer.files(shards, manifest.get("shards", []), "scan shard")
    _compare_labelings(comparer, labelings, manifest, out)
    terrain = _terrain_entry(manifest)
    if isinstance(dtm, dict) and terrain is not None:
        (entry,) = _entries([dtm], "dtm")
        if entry["path"] != terrain["path"]:
            out.problems.append(f"{terrain['path']}: the published build's terrain is {entry['path']}")
        else:
            comparer.one(terrain["path"], entry, terrain["sha256"])
    return out


# hd choice: the differing settings a message names, the others counted.
SHOWN_SETTINGS = 6


def _other_settings(manifest: ManifestJson, recorded: ChecksumsJson, recipe_config: BuildConfig | None) -> str:
    """Why a dataset's settings hash is not the published build's, naming the settings that differ
    (the dataset's value, then the recipe's) when the recipe's own configuration is known."""
    vague = "the dataset was built with other settings than the recipe's published build"
    if recipe_config is None:
        return vague
    if manifest.get("config_sha256") == recipe_config.fingerprint():
        return (
            "the recipe's settings are not those of its published build (its checksums were published for "
            "other settings): publish them again with `hd card`"
        )
    changes = setting_changes(manifest.get("config"), recipe_config)
    if not changes:
        why = "not recorded" if not isinstance(manifest.get("config"), dict) else "the same, another settings hash"
        return f"{vague} (the dataset's settings: {why})"
    shown = ", ".join(
        f"{key} {json.dumps(mine)} (recipe: {json.dumps(theirs)})" for key, mine, theirs in changes[:SHOWN_SETTINGS]
    )
    more = f" and {len(changes) - SHOWN_SETTINGS} more" if len(changes) > SHOWN_SETTINGS else ""
    return f"the dataset was built with other settings than the recipe's: {shown}{more}"


def compare_with_recipe(
    directory: str | os.PathLike, recipe_dir: str | os.PathLike, content: bool = True
) -> PublishedComparison:
    """Compare the dataset at ``directory`` with the build published with a recipe (``hd verify --recipe``).

    ``content=False`` compares the sha256 only (for a dataset whose own checks failed: its files are
    not read).

    Raises:
        RecipeError: the recipe cannot be read, has no published ``checksums.json``, or its
            checksums are malformed (``FormatError``: its fingerprints, see :func:`compare_with_published`).
    """
    recipe = load_recipe(recipe_dir)
    recorded = recipe.checksums()
    if recorded is None:
        raise RecipeError(f"{recipe.path.parent}: the recipe has no published {CHECKSUMS_FILE}")
    return compare_with_published(read_manifest(directory), recorded, directory if content else None, recipe.build)
