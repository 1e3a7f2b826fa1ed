"""The keys of a recipe's ``checksums.json`` and of content fingerprints as typed records.

``checksums.json`` is the record of a recipe's published build (``lidarsim.card.checksums_of``):
its settings hash and, per file, the sha256 and the content fingerprint (``hd.content-fingerprint``,
``lidarsim.fingerprint`` and ``docs/shard-format.md``) that ``hd verify --recipe`` compares a rebuild
with. Both are JSON, so they are ``TypedDict``: the file's own dictionaries at run time, their keys
and types checked by mypy. ``lidarsim.fingerprint.fingerprint_problem`` and
``lidarsim.published`` check a published file against them before a comparison reads it.
"""

from __future__ import annotations

from typing import NotRequired, TypedDict

__all__ = [
    "ArrayFingerprintJson",
    "ChecksumsJson",
    "FingerprintJson",
    "PublishedFileJson",
    "PublishedLabelingJson",
]


class ArrayFingerprintJson(TypedDict):
    """The statistics of one array (``lidarsim.fingerprint.array_fingerprint``): floating arrays give
    ``nan``, ``inf``, ``sum``, ``sum_abs``, ``wsum``, ``min`` and ``max`` (of the finite elements);
    integer and boolean arrays ``sum``, ``wsum``, ``min``, ``max`` and, one byte wide, ``counts``;
    other arrays a ``sha256`` prefix of their values."""

    dtype: str
    shape: list[int]
    nan: NotRequired[int]
    inf: NotRequired[int]
    sum: NotRequired[float]
    sum_abs: NotRequired[float]
    wsum: NotRequired[float]
    min: NotRequired[float | None]
    max: NotRequired[float | None]
    counts: NotRequired[dict[str, int]]
    sha256: NotRequired[str]
    attrs: NotRequired[dict[str, object]]


class FingerprintJson(TypedDict):
    """A file's content fingerprint: its attributes (values, or a sha256 prefix of long ones) and arrays."""

    attrs: dict[str, object]
    arrays: dict[str, ArrayFingerprintJson]


class PublishedFileJson(TypedDict):
    """One published file: its path in the dataset, sha256 and (since fingerprints) its content."""

    path: str
    sha256: str
    n_scans: NotRequired[int]  # scan shards
    content: NotRequired[FingerprintJson]


class PublishedLabelingJson(TypedDict):
    """One published labelling: its name and its label shards."""

    name: str
    shards: list[PublishedFileJson]


class ChecksumsJson(TypedDict):
    """A recipe's ``checksums.json``."""

    software_version: NotRequired[str]
    config_sha256: NotRequired[str | None]
    schema: NotRequired[str]
    schema_version: NotRequired[str]
    shard_schema_version: NotRequired[str | None]  # absent before scan shard schema 1.1: 1.0
    fingerprint_schema: NotRequired[str]
    fingerprint_schema_version: NotRequired[str]
    shards: NotRequired[list[PublishedFileJson]]
    labelings: NotRequired[list[PublishedLabelingJson]]
    dtm: NotRequired[PublishedFileJson]  # the procedural terrain kept in the dataset
