"""Content fingerprints of shards: what a rebuild on another machine must reproduce, within tolerances.

A shard's sha256 proves that a received copy is the published file, byte for byte. It cannot say
whether a rebuild elsewhere is the same *dataset*: the bytes of a shard also depend on the zlib the
operating system provides (HDF5 in the h5py wheel compresses with the system's ``libz.so.1``), and
the label kernels round differently with another BLAS kernel family or another compiler target
(``docs/reliability.md``, class J, has the measurements). A content fingerprint records, per file,
what the arrays *hold*, so that such a rebuild can be compared with the published build, and a
damaged or altered copy still fails.

Format (schema ``hd.content-fingerprint``, version 1.0; one JSON object per file, published in a
recipe's ``checksums.json`` beside the file's sha256; ``docs/shard-format.md``)::

    {"attrs":  {NAME: VALUE, ...},            # the file's attributes
     "arrays": {NAME: {"dtype": "float32", "shape": [50, 128, 128, 3],
                       "nan": 0, "inf": 0,    # floating arrays: NaN and +-inf elements
                       "sum": 1.2e6,          # float64 sum of the finite elements
                       "sum_abs": 3.4e6,      # float64 sum of their absolute values
                       "wsum": 5.6e5,         # float64 sum of w_i x_i, w_i = ((i mod 65521) + 1) / 65522
                       "min": -52.1, "max": 51.9,   # of the finite elements (null: none)
                       "attrs": {...}},       # the array's attributes
                NAME: {"dtype": "uint8", "shape": [...], "sum": 7, "min": 0, "max": 255,
                       "wsum": 912,           # sum of ((i mod 65521) + 1) x_i, exact
                       "counts": {"0": 123, "1": 456, "255": 789}}}}   # one-byte arrays

``i`` is an element's flat index in C order: the weighted sums change when elements move (two
scans swapped, an image flipped), which sums, extremes and counts do not see.

An attribute value is kept as JSON when its canonical JSON text is at most
:data:`MAX_INLINE_ATTR_CHARS` characters long, else as ``"sha256:"`` and the first 16 hex digits of
the SHA-256 of that text. Attributes that record the sha256 of another file of the dataset
(:data:`FILE_DIGEST_ATTRS`) differ wherever that file's bytes differ; their values are kept but
compared with the dataset's own files (``lidarsim.published``), not with the published values.

Tolerances (:func:`compare_fingerprints`), per array: dtype, shape, NaN and inf counts, every
statistic of an integer array (sums, extremes, counts per value: label codes, status codes, splits)
and every attribute must be equal. The sum, weighted sum and sum of absolute values of a floating
array may differ by ``rtol * sum_abs`` and its extremes by ``rtol_extreme * max(|min|, |max|)``:
float32 arrays :data:`FLOAT32_RTOL` (1e-6) and :data:`FLOAT32_EXTREME_RTOL` (1e-5), float64 arrays
:data:`FLOAT64_RTOL` (1e-9) for both.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import h5py
import numpy as np

from hdcore.bounds import Bound
from hdcore.storage import CheckedDataset, FormatError, check_schema, open_h5
from lidarsim.checksums_json import ArrayFingerprintJson, FingerprintJson
from lidarsim.shards import TRUTH_DTM_SHA256_ATTR

__all__ = [
    "FILE_DIGEST_ATTRS",
    "FINGERPRINT_SCHEMA",
    "FINGERPRINT_SCHEMA_VERSION",
    "FLOAT32_EXTREME_RTOL",
    "FLOAT32_RTOL",
    "FLOAT64_RTOL",
    "MAX_INLINE_ATTR_CHARS",
    "MINOR_VERSION_ATTRS",
    "Comparison",
    "array_fingerprint",
    "attr_record",
    "check_fingerprint_schema",
    "compare_fingerprints",
    "fingerprint_problem",
    "h5_fingerprint",
]

FINGERPRINT_SCHEMA = "hd.content-fingerprint"
FINGERPRINT_SCHEMA_VERSION = "1.0"

# Relative tolerance of the sums of float32 arrays, as a fraction of the sum of absolute values.
# One rounding moves a float32 value by at most 2**-24 of its magnitude (6.0e-8). Across x86-64
# machines the label arrays (slope, roughness, P(safe)) differ by up to 7 float32 steps per element
# (OpenBLAS's SkylakeX kernels against the Haswell kernels of the published build's machine,
# docs/reliability.md), which moved their sums by at most 1.6e-11 of the sum of absolute values:
# differences of random sign average out. 1e-6 bounds even 8 steps of every element in the same
# direction (at most 8 * 2**-23 = 9.5e-7), and still catches one element changed by a millionth of
# the array's total magnitude.
FLOAT32_RTOL = 1e-6
# Relative tolerance of the extremes of float32 arrays, as a fraction of the array's largest
# magnitude: an extreme is one element, and one element moved by up to 4.2e-7 of the array's largest
# magnitude across machines (P(safe), whose scale is 1); 1e-5 is 84 float32 steps at the top of
# the range (0.5 mm on points 53 m from the scan origin).
FLOAT32_EXTREME_RTOL = 1e-5
# float64 arrays (scan origins, sensor positions and attitudes) are computed in float64 from float32
# terrain heights and settings: an ulp-level change of a height moves them by far less than 1e-9.
FLOAT64_RTOL = 1e-9
# Position weights of the weighted sums: (flat index mod 65521) + 1, 65521 being prime so that rows of
# any width get other weights; float weighted sums are divided by 65522 (weights in (0, 1)).
_WEIGHT_PRIME = 65521
# Attribute values longer than this as canonical JSON are kept as a SHA-256 prefix.
MAX_INLINE_ATTR_CHARS = 80
# Attributes that hold the sha256 of another file of the dataset (scan shards: the terrain; label
# shards: their scan shard and, for the terrain truth, the terrain): they change with those files'
# bytes, so a rebuild elsewhere has its own.
FILE_DIGEST_ATTRS = frozenset({"dtm_sha256", "source_sha256", TRUTH_DTM_SHA256_ATTR})
# Attributes that a minor version of a schema added, by (schema, version): a file written at that
# version, compared with one published at an earlier minor version of the same schema (the same
# content otherwise), holds them where the published one has none; they and the schema version
# are not differences. hd.labels 1.2: a terrain-truth label shard's terrain (hdlabels.store).
MINOR_VERSION_ATTRS: dict[tuple[str, str], frozenset[str]] = {
    ("hd.labels", "1.2"): frozenset({TRUTH_DTM_SHA256_ATTR}),
}


def _plain(value: Any) -> Any:
    """An HDF5 attribute value as plain JSON-able Python (bytes decoded, numpy made Python)."""
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if isinstance(value, np.generic):
        return _plain(value.item())
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)  # "nan", "inf", "-inf": JSON has no such numbers
    return value


def attr_record(value: Any) -> Any:
    """What a fingerprint keeps of an attribute: the value, or ``sha256:`` + 16 hex digits of its JSON."""
    plain = _plain(value)
    text = json.dumps(plain, sort_keys=True)
    if len(text) <= MAX_INLINE_ATTR_CHARS:
        return json.loads(text)
    return "sha256:" + hashlib.sha256(text.encode()).hexdigest()[:16]


def _attrs(obj: h5py.HLObject) -> dict[str, object]:
    return {str(k): attr_record(obj.attrs[k]) for k in sorted(obj.attrs.keys())}


def array_fingerprint(blocks: Any, dtype: np.dtype, shape: tuple[int, ...]) -> ArrayFingerprintJson:
    """Statistics of an array given as an iterable of blocks (numpy arrays of ``dtype``).

    Floating arrays: NaN and inf counts, float64 sum, sum of absolute values and position-weighted
    sum of the finite elements (the blocks' pairwise sums added with ``math.fsum``), finite
    extremes. Integer and boolean arrays: exact sum, weighted sum and extremes, and for one-byte
    arrays the count of every value.
    """
    kind = np.dtype(dtype).kind
    record: ArrayFingerprintJson = {"dtype": str(np.dtype(dtype)), "shape": [int(n) for n in shape]}
    if kind == "f":
        nan = inf = 0
        sums: list[float] = []
        sums_abs: list[float] = []
        wsums: list[float] = []
        lo: float | None = None
        hi: float | None = None
        offset = 0
        for block in blocks:
            b64 = np.asarray(block).astype(np.float64, copy=False).ravel()
            weights = _weights(offset, b64.size)
            offset += b64.size
            nan += int(np.isnan(b64).sum())
            inf += int(np.isinf(b64).sum())
            keep = np.isfinite(b64)
            finite = b64[keep]
            if finite.size:
                sums.append(float(finite.sum()))
                sums_abs.append(float(np.abs(finite).sum()))
                wsums.append(float((finite * weights[keep]).sum()) / (_WEIGHT_PRIME + 1))
                lo = float(finite.min()) if lo is None else min(lo, float(finite.min()))
                hi = float(finite.max()) if hi is None else max(hi, float(finite.max()))
        record["nan"], record["inf"] = nan, inf
        record["sum"], record["sum_abs"], record["wsum"] = math.fsum(sums), math.fsum(sums_abs), math.fsum(wsums)
        record["min"], record["max"] = lo, hi
    elif kind in "iub":
        total = 0
        ilo: int | None = None
        ihi: int | None = None
        wtotal = 0
        counts: dict[int, int] = {}
        one_byte = np.dtype(dtype).itemsize == 1
        offset = 0
        for block in blocks:
            b = np.asarray(block).ravel()
            weights = _weights(offset, b.size)
            offset += b.size
            if not b.size:
                continue
            total += int(b.sum(dtype=np.uint64 if kind == "u" else np.int64))
            wtotal += sum(int(v) * int(c) for v, c in _weighted_int_sums(b, weights))
            ilo = int(b.min()) if ilo is None else min(ilo, int(b.min()))
            ihi = int(b.max()) if ihi is None else max(ihi, int(b.max()))
            if one_byte:
                values, n = np.unique(b, return_counts=True)
                for v, c in zip(values.tolist(), n.tolist(), strict=True):
                    counts[int(v)] = counts.get(int(v), 0) + int(c)
        record["sum"], record["wsum"], record["min"], record["max"] = total, wtotal, ilo, ihi
        if one_byte:
            record["counts"] = {str(k): counts[k] for k in sorted(counts)}
    else:  # strings and other types: their bytes
        digest = hashlib.sha256()
        for block in blocks:
            digest.update(repr(_plain(np.asarray(block))).encode())
        record["sha256"] = digest.hexdigest()[:16]
    return record


def _weights(offset: int, n: int) -> np.ndarray:
    """Position weights ``(i mod 65521) + 1`` of the flat (C order) element indices offset .. offset + n - 1."""
    return (np.arange(offset, offset + n, dtype=np.int64) % _WEIGHT_PRIME) + 1


def _weighted_int_sums(values: np.ndarray, weights: np.ndarray) -> list[tuple[int, int]]:
    """(value, sum of its elements' weights) for every distinct value of an integer array, so that
    ``sum(weight * value)`` is exact in Python integers (the weight sums stay far below 2**53)."""
    uniq, inverse = np.unique(values, return_inverse=True)
    totals = np.bincount(inverse.ravel(), weights=weights.astype(np.float64), minlength=uniq.size)
    return [(int(v), round(float(t))) for v, t in zip(uniq.tolist(), totals.tolist(), strict=True)]


def _blocks(ds: CheckedDataset) -> Any:
    """The rows of a dataset, one chunk of rows at a time (checked reads)."""
    if not ds.shape:
        yield np.asarray(ds[()])
        return
    step = ds.chunks[0] if ds.chunks else max(1, ds.shape[0])
    for k in range(0, ds.shape[0], step):
        yield ds[k : k + step]


def h5_fingerprint(path: str | os.PathLike, what: str | None = None) -> FingerprintJson:
    """Content fingerprint of an HDF5 file (schema ``hd.content-fingerprint`` 1.0, module docstring).

    Every chunk is read (fletcher32 and decompression checked), one chunk of rows at a time.

    Raises:
        DamagedFileError: an unreadable file or chunk, named with the dataset and the scan.
        StorageError: a missing file.
    """
    with open_h5(path, what) as f:
        names: list[str] = []
        f._f.visit(lambda n: names.append(n) if isinstance(f._f[n], h5py.Dataset) else None)
        arrays: dict[str, ArrayFingerprintJson] = {}
        for name in sorted(names):
            ds = f[name]
            record = array_fingerprint(_blocks(ds), ds.dtype, tuple(ds.shape))
            attrs = _attrs(ds)
            if attrs:
                record["attrs"] = attrs
            arrays[name] = record
        return {"attrs": _attrs(f._f), "arrays": arrays}


# A count of elements (NaN, inf, elements of one value) or an axis length: an integer >= 0.
COUNT = Bound(0, integer=True)
# Slack of the consistency bounds between a floating array's statistics (sums of absolute values
# against the extremes and the element count): far above float64 rounding (1e-16 per addition),
# far below any change a rebuild's tolerance would let through (1e-6).
_CONSISTENCY_SLACK = 1e-9
_HEX16 = re.compile(r"^[0-9a-f]{16}$")

# One impossible value of a published fingerprint: (its field, relative to the record; the value; why).
Problem = tuple[str, Any, str]


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def fingerprint_problem(record: Any) -> Problem | None:
    """The first value of a published content fingerprint that no file can have, or None.

    Checked against the format of the module docstring: every array's dtype (one numpy knows) and
    shape (lengths >= 0); element counts (NaN, inf, per value) integers >= 0 that add up to at most
    (per value: exactly) the array's size; sums and extremes finite numbers, the minimum at most the
    maximum, both null exactly when no element is finite; and the statistics of a floating array
    consistent with each other (``max(|min|, |max|) <= sum_abs <= n_finite * max(|min|, |max|)``,
    ``|sum|`` and ``|wsum|`` at most ``sum_abs``): a published scale that is infinite, NaN or larger
    than its elements allow would widen every tolerance until any rebuild passes.
    An integer array's extremes lie in its dtype's range and its counts' values too.

    Returns:
        ``(field, value, why)``, ``field`` relative to the record (``arrays.label.counts.7``).
    """
    if not isinstance(record, dict):
        return "", record, "a content fingerprint is a JSON object"
    for key in ("attrs", "arrays"):
        if not isinstance(record.get(key, {}), dict):
            return key, record[key], "must be a JSON object"
    for name, array in record.get("arrays", {}).items():
        problem = _array_problem(array)
        if problem is not None:
            field, value, why = problem
            return f"arrays.{name}{'.' if field else ''}{field}", value, why
    return None


def _array_problem(array: Any) -> Problem | None:
    """:func:`fingerprint_problem` of one array's record."""
    if not isinstance(array, dict):
        return "", array, "an array's fingerprint is a JSON object"
    try:
        dtype = np.dtype(array["dtype"]) if isinstance(array.get("dtype"), str) else None
    except TypeError:
        dtype = None
    if dtype is None:
        return "dtype", array.get("dtype"), "not a numpy dtype"
    shape = array.get("shape")
    if not isinstance(shape, list) or not all(_is_int(n) and COUNT.contains(n) for n in shape):
        return "shape", shape, "an array's shape is a list of lengths >= 0"
    if not isinstance(array.get("attrs", {}), dict):
        return "attrs", array["attrs"], "must be a JSON object"
    size = math.prod(shape)
    if dtype.kind == "f":
        return _float_problem(array, size)
    if dtype.kind in "iub":
        return _int_problem(array, dtype, size)
    digest = array.get("sha256")
    return None if isinstance(digest, str) and _HEX16.match(digest) else ("sha256", digest, "16 hex digits")


def _count_problem(value: Any, key: str, size: int) -> Problem | None:
    if not _is_int(value) or not COUNT.contains(value) or value > size:
        return key, value, f"a count of elements must be an integer in [0, {size}] (the array's size)"
    return None


def _float_problem(array: dict[str, Any], size: int) -> Problem | None:
    """The statistics of a floating array (module docstring): counts, finite sums and extremes, consistent."""
    values: dict[str, Any] = {k: array.get(k) for k in ("nan", "inf", "sum", "sum_abs", "wsum", "min", "max")}
    for key in ("nan", "inf"):
        if (problem := _count_problem(values[key], key, size)) is not None:
            return problem
    n_finite = size - int(values["nan"]) - int(values["inf"])
    if n_finite < 0:
        return "inf", values["inf"], f"NaN and infinite elements together exceed the array's size {size}"
    for key in ("sum", "sum_abs", "wsum"):
        if not _is_number(values[key]):
            return key, values[key], "a sum must be a finite number"
    total, total_abs, wsum = float(values["sum"]), float(values["sum_abs"]), float(values["wsum"])
    if n_finite == 0:
        for key in ("min", "max"):
            if values[key] is not None:
                return key, values[key], "must be null: the array has no finite element"
        for key in ("sum", "sum_abs", "wsum"):
            if values[key] != 0:
                return key, values[key], "must be 0: the array has no finite element"
        return None
    for key in ("min", "max"):
        if not _is_number(values[key]):
            return key, values[key], "an extreme of finite elements must be a finite number"
    lo, hi = float(values["min"]), float(values["max"])
    if lo > hi:
        return "min", values["min"], f"greater than the maximum {values['max']}"
    largest = max(abs(lo), abs(hi))
    low, high = largest * (1.0 - _CONSISTENCY_SLACK), n_finite * largest * (1.0 + _CONSISTENCY_SLACK)
    if not low <= total_abs <= high:
        why = f"the sum of {n_finite} absolute values of at most {largest:g} must lie in [{low:g}, {high:g}]"
        return "sum_abs", values["sum_abs"], why
    for key, value in (("sum", total), ("wsum", wsum)):
        if abs(value) > total_abs * (1.0 + _CONSISTENCY_SLACK):
            return key, values[key], f"larger in magnitude than the sum of absolute values {total_abs:g}"
    return None


def _int_problem(array: dict[str, Any], dtype: np.dtype, size: int) -> Problem | None:
    """The statistics of an integer or boolean array: exact, within the dtype's range, counts adding up."""
    first, last = (0, 1) if dtype.kind == "b" else (int(np.iinfo(dtype).min), int(np.iinfo(dtype).max))
    values: dict[str, Any] = {k: array.get(k) for k in ("sum", "wsum", "min", "max")}
    for key in ("sum", "wsum"):
        if not _is_int(values[key]):
            return key, values[key], "a sum of integers must be an integer"
    lo: int | None = None
    hi: int | None = None
    if size == 0:
        for key in ("min", "max"):
            if values[key] is not None:
                return key, values[key], "must be null: the array is empty"
    else:
        for key in ("min", "max"):
            if not _is_int(values[key]) or not first <= values[key] <= last:
                return key, values[key], f"an extreme of {dtype} elements must be an integer in [{first}, {last}]"
        lo, hi = int(values["min"]), int(values["max"])
        if lo > hi:
            return "min", lo, f"greater than the maximum {hi}"
        if not size * lo <= int(values["sum"]) <= size * hi:
            return "sum", values["sum"], f"{size} elements in [{lo}, {hi}] cannot add up to it"
    counts = array.get("counts")
    if counts is None:
        return None
    if not isinstance(counts, dict):
        return "counts", counts, "must be a JSON object of value: count"
    for value, n in counts.items():
        try:
            number = int(value)
        except ValueError:
            return f"counts.{value}", n, "a value of the array must be an integer"
        if lo is not None and hi is not None and not lo <= number <= hi:
            return f"counts.{value}", n, f"the value {value} lies outside the array's extremes [{lo}, {hi}]"
        if not _is_int(n) or not COUNT.contains(n):
            return f"counts.{value}", n, "a count of elements must be an integer >= 0"
    if sum(counts.values()) != size:
        return "counts", counts, f"the counts add up to {sum(counts.values())}, not the array's size {size}"
    return None


def check_fingerprint_schema(recorded: Mapping[str, object], where: str) -> None:
    """Refuse published fingerprints of another schema or an unknown major version.

    Raises:
        FormatError: naming ``where``.
    """
    check_schema(
        str(recorded.get("fingerprint_schema", FINGERPRINT_SCHEMA)),
        str(recorded.get("fingerprint_schema_version", FINGERPRINT_SCHEMA_VERSION)),
        FINGERPRINT_SCHEMA,
        FINGERPRINT_SCHEMA_VERSION,
        where,
    )


@dataclass
class Comparison:
    """The comparison of a file's fingerprint with the published one.

    Attributes:
        problems: one-line differences beyond tolerance (empty: equal within tolerance).
        worst: the largest difference of a floating statistic as a fraction of its tolerance (1 is at
            the tolerance): ``|difference| / scale / tolerance``, the scale being the sum of
            ``|x|`` for sums and ``max(|min|, |max|)`` for extremes.
        n_arrays: arrays compared.
        n_attrs: attributes compared (file and arrays).
        newer: when the file is of a newer minor schema version than the published one, what that
            version adds and was therefore not compared (``MINOR_VERSION_ATTRS``); else "".
    """

    problems: list[str] = field(default_factory=list)
    worst: float = 0.0
    n_arrays: int = 0
    n_attrs: int = 0
    newer: str = ""


def _fmt(value: Any) -> str:
    return json.dumps(value)


def _minor_version_additions(published: dict[str, object], rebuilt: dict[str, object]) -> frozenset[str]:
    """The file attributes of ``rebuilt`` that its newer minor schema version added and ``published``
    (an earlier minor version of the same schema) lacks, with ``schema_version``; empty otherwise."""
    schema, old, new = rebuilt.get("schema"), published.get("schema_version"), rebuilt.get("schema_version")
    if schema != published.get("schema") or not isinstance(old, str) or not isinstance(new, str):
        return frozenset()
    try:
        (old_major, old_minor), (new_major, new_minor) = (tuple(int(p) for p in v.split(".")) for v in (old, new))
    except ValueError:
        return frozenset()
    if old_major != new_major or old_minor >= new_minor:
        return frozenset()
    added: set[str] = set()
    for minor in range(old_minor + 1, new_minor + 1):
        added |= MINOR_VERSION_ATTRS.get((str(schema), f"{new_major}.{minor}"), frozenset())
    added = {name for name in added if name in rebuilt and name not in published}
    return frozenset(added | {"schema_version"}) if added else frozenset()


def _compare_attrs(
    published: dict[str, object],
    rebuilt: dict[str, object],
    where: str,
    out: Comparison,
    skip: frozenset[str] = frozenset(),
) -> None:
    for name in sorted(set(published) | set(rebuilt)):
        if name in skip:
            continue
        if name not in rebuilt:
            out.problems.append(f"{where}: attribute {name} of the published build is missing")
        elif name not in published:
            out.problems.append(f"{where}: attribute {name} is not in the published build")
        elif name not in FILE_DIGEST_ATTRS and published[name] != rebuilt[name]:
            out.problems.append(
                f"{where}: attribute {name} is {_fmt(rebuilt[name])}, the published build's is {_fmt(published[name])}"
            )
        out.n_attrs += 1


def _compare_array(pub: ArrayFingerprintJson, new: ArrayFingerprintJson, where: str, out: Comparison) -> None:
    for key in ("dtype", "shape"):
        if pub.get(key) != new.get(key):
            out.problems.append(f"{where}: {key} {_fmt(new.get(key))}, the published build's is {_fmt(pub.get(key))}")
            return
    _compare_attrs(pub.get("attrs", {}), new.get("attrs", {}), where, out)
    kind = np.dtype(str(pub["dtype"])).kind
    if kind != "f":  # integers, booleans, strings: exact
        for key in ("counts", "sum", "wsum", "min", "max", "sha256"):
            if pub.get(key) != new.get(key):
                what = {"counts": "counts per value", "wsum": "position-weighted sum"}.get(key, key)
                got, want = _fmt(new.get(key)), _fmt(pub.get(key))
                out.problems.append(f"{where}: {what} {got}, the published build's is {want} (must be equal)")
                return  # one line per array: other counts imply other sums
        return
    for key in ("nan", "inf"):
        if pub.get(key) != new.get(key):
            out.problems.append(
                f"{where}: {new.get(key)} {key.upper() if key == 'nan' else 'infinite'} elements, "
                f"the published build has {pub.get(key)} (must be equal)"
            )
    single = np.dtype(str(pub["dtype"])).itemsize <= 4
    rtol = FLOAT32_RTOL if single else FLOAT64_RTOL
    rtol_extreme = FLOAT32_EXTREME_RTOL if single else FLOAT64_RTOL
    if (pub.get("min") is None) != (new.get("min") is None):
        out.problems.append(f"{where}: finite elements differ from the published build's (none in one of them)")
        return
    if pub.get("min") is None:
        return
    old, now = _float_stats(pub), _float_stats(new)
    sum_scale = max(abs(old["sum_abs"]), abs(now["sum_abs"]))
    ext_scale = max(abs(v) for v in (old["min"], old["max"], now["min"], now["max"]))
    for key, scale, tol, name in (
        ("sum", sum_scale, rtol, "sum"),
        ("wsum", sum_scale, rtol, "position-weighted sum"),
        ("sum_abs", sum_scale, rtol, "sum of absolute values"),
        ("min", ext_scale, rtol_extreme, "minimum"),
        ("max", ext_scale, rtol_extreme, "maximum"),
    ):
        a, b = old[key], now[key]
        diff = abs(a - b)
        rel = diff / scale if scale > 0 else (0.0 if diff == 0 else math.inf)
        out.worst = max(out.worst, rel / tol)
        if rel > tol:
            out.problems.append(
                f"{where}: {name} {b:.10g}, the published build's is {a:.10g}: a difference of {rel:.2g} of the "
                f"array's scale (tolerance {tol:g})"
            )


def _float_stats(record: ArrayFingerprintJson) -> dict[str, float]:
    """The sums and extremes of a floating array that has finite elements (a fingerprint checked by
    :func:`fingerprint_problem`), by key."""
    return {
        "sum": float(record.get("sum", 0.0)),
        "wsum": float(record.get("wsum", 0.0)),
        "sum_abs": float(record.get("sum_abs", 0.0)),
        "min": float(record.get("min") or 0.0),
        "max": float(record.get("max") or 0.0),
    }


def compare_fingerprints(published: FingerprintJson, rebuilt: FingerprintJson, where: str) -> Comparison:
    """Compare a file's fingerprint with the published one within the module's tolerances.

    ``where`` names the file in the problems (``shards/scans-00003.h5``); each problem names the
    array or attribute, the rebuilt and the published value.
    """
    out = Comparison()
    try:
        pub_attrs, new_attrs = published.get("attrs", {}), rebuilt.get("attrs", {})
        added = _minor_version_additions(pub_attrs, new_attrs)
        if added:
            names = ", ".join(sorted(added - {"schema_version"}))
            out.newer = (
                f"schema {new_attrs['schema_version']} of a file published as {pub_attrs['schema_version']}: "
                f"{names}, added since, not compared"
            )
        _compare_attrs(pub_attrs, new_attrs, where, out, added)
        pub_arrays, new_arrays = published.get("arrays", {}), rebuilt.get("arrays", {})
        for name in sorted(set(pub_arrays) | set(new_arrays)):
            if name not in new_arrays:
                out.problems.append(f"{where}: array {name} of the published build is missing")
            elif name not in pub_arrays:
                out.problems.append(f"{where}: array {name} is not in the published build")
            else:
                out.n_arrays += 1
                _compare_array(pub_arrays[name], new_arrays[name], f"{where}: {name}", out)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise FormatError(f"{where}: malformed published content fingerprint ({type(exc).__name__}: {exc})") from exc
    return out
