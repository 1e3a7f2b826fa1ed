"""Content fingerprints (lidarsim.fingerprint): the statistics of every array and attribute, and the
tolerances within which a rebuild on another machine equals the published build."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from hdcore.storage import FormatError
from lidarsim.fingerprint import (
    MAX_INLINE_ATTR_CHARS,
    array_fingerprint,
    check_fingerprint_schema,
    compare_fingerprints,
    h5_fingerprint,
)
from lidarsim.published import terrain_fingerprint


def _shard(path: Path, points: np.ndarray, label: np.ndarray, **attrs: object) -> Path:
    """A small HDF5 file laid out like hd's shards: float32 points, uint8 labels, int64 indices."""
    with h5py.File(path, "w") as f:
        f.attrs.update({"seed": 3, "sigmas_m": np.array([0.0167, 0.07]), "nodata": np.nan, "text": "x" * 200})
        f.attrs.update(attrs)
        kw = {"compression": "gzip", "compression_opts": 1, "shuffle": True, "fletcher32": True}
        f.create_dataset("points", data=points, chunks=(1, *points.shape[1:]), **kw)
        f.create_dataset("label", data=label, chunks=(1, *label.shape[1:]), **kw)
        f["label"].attrs["codes"] = "0 unsafe, 1 safe, 255 invalid"
        f.create_dataset("scan_index", data=np.arange(points.shape[0], dtype=np.int64) + 10)
    return path


@pytest.fixture
def arrays() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    points = rng.normal(0.0, 20.0, (4, 16, 16, 3)).astype(np.float32)
    points[0, 0, 0] = np.nan
    points[1, 2, 3, 1] = np.inf
    label = rng.choice(np.array([0, 1, 255], dtype=np.uint8), size=(4, 12, 12))
    return points, label


def test_statistics_of_every_array_and_attribute(tmp_path, arrays):
    points, label = arrays
    fp = h5_fingerprint(_shard(tmp_path / "a.h5", points, label))
    assert json.loads(json.dumps(fp, allow_nan=False)) == fp  # plain JSON, no NaN literals
    p = fp["arrays"]["points"]
    finite = points[np.isfinite(points)].astype(np.float64)
    assert p["dtype"] == "float32" and p["shape"] == [4, 16, 16, 3]
    assert p["nan"] == 3 and p["inf"] == 1
    assert p["sum"] == pytest.approx(finite.sum(), rel=1e-12) and p["sum_abs"] == pytest.approx(np.abs(finite).sum())
    assert p["min"] == float(finite.min()) and p["max"] == float(finite.max())
    lab = fp["arrays"]["label"]
    assert lab["counts"] == {str(v): int((label == v).sum()) for v in (0, 1, 255)}
    assert lab["sum"] == int(label.astype(np.int64).sum()) and lab["attrs"] == {
        "codes": "0 unsafe, 1 safe, 255 invalid"
    }
    weights = np.arange(label.size) % 65521 + 1
    assert lab["wsum"] == int((label.ravel().astype(np.int64) * weights).sum())
    assert fp["arrays"]["scan_index"] == {
        "dtype": "int64",
        "shape": [4],
        "sum": 46,
        "wsum": 10 + 22 + 36 + 52,
        "min": 10,
        "max": 13,
    }
    attrs = fp["attrs"]
    assert attrs["seed"] == 3 and attrs["sigmas_m"] == [0.0167, 0.07] and attrs["nodata"] == "nan"
    text = attrs["text"]
    assert isinstance(text, str) and text.startswith("sha256:") and len(text) == len("sha256:") + 16
    assert len(json.dumps("x" * 200)) > MAX_INLINE_ATTR_CHARS


def test_blocks_give_the_statistics_of_the_whole_array(arrays):
    points, _ = arrays
    whole = array_fingerprint([points], points.dtype, points.shape)
    rows = array_fingerprint(list(points), points.dtype, points.shape)
    assert rows["nan"] == whole["nan"] and rows["min"] == whole["min"] and rows["max"] == whole["max"]
    for key in ("sum", "sum_abs", "wsum"):
        assert rows[key] == pytest.approx(whole[key], rel=1e-12)


def test_a_rebuild_that_differs_by_rounding_is_within_tolerance(tmp_path, arrays):
    points, label = arrays
    published = h5_fingerprint(_shard(tmp_path / "a.h5", points, label))
    # every finite element moved by up to 4 float32 steps (another CPU's rounding), other gzip bytes
    rng = np.random.default_rng(1)
    moved = points.copy()
    for _ in range(4):
        toward = np.where(rng.random(points.shape) < 0.5, -np.inf, np.inf).astype(np.float32)
        moved = np.where(np.isfinite(moved), np.nextafter(moved, toward), moved)
    rebuilt = h5_fingerprint(_shard(tmp_path / "b.h5", moved, label))
    result = compare_fingerprints(published, rebuilt, "b.h5")
    assert result.problems == []
    assert 0.0 < result.worst < 1.0 and result.n_arrays == 3


@pytest.mark.parametrize(
    ("change", "needles"),
    [
        ("one-point", ["points: sum", "tolerance 1e-06"]),
        ("one-label", ["label: counts per value", '{"0":', "must be equal"]),
        ("flipped-image", ["label: position-weighted sum"]),
        ("swapped-scans", ["points: position-weighted sum"]),
        ("a-nan-more", ["points: 4 NAN elements, the published build has 3"]),
        ("attribute", ["attribute seed is 4, the published build's is 3"]),
        ("long-attribute", ["attribute text is"]),
        ("dtype", ["label: dtype"]),
    ],
)
def test_an_altered_copy_is_beyond_tolerance(tmp_path, arrays, change, needles):
    points, label = arrays
    published = h5_fingerprint(_shard(tmp_path / "a.h5", points, label))
    points, label = points.copy(), label.copy()
    attrs: dict[str, object] = {}
    if change == "one-point":
        points[2, 5, 5, 2] += 1.0  # one metre on one point
    elif change == "one-label":
        label[1, 6, 6] = 0 if label[1, 6, 6] else 1
    elif change == "flipped-image":
        label = label[:, ::-1, :].copy()
    elif change == "swapped-scans":
        points = points[[0, 1, 3, 2]].copy()
    elif change == "a-nan-more":
        points[3, 3, 3, 0] = np.nan
    elif change == "attribute":
        attrs["seed"] = 4
    elif change == "long-attribute":
        attrs["text"] = "y" * 200
    else:
        label = label.astype(np.uint16)
    rebuilt = h5_fingerprint(_shard(tmp_path / "b.h5", points, label, **attrs))
    problems = compare_fingerprints(published, rebuilt, "b.h5").problems
    assert problems, change
    text = "\n".join(problems)
    for needle in needles:
        assert needle in text, text
    assert all(p.startswith("b.h5: ") and "\n" not in p for p in problems)


def test_malformed_or_newer_published_fingerprints_are_one_line(tmp_path, arrays):
    fp = h5_fingerprint(_shard(tmp_path / "a.h5", *arrays))
    broken = json.loads(json.dumps(fp))
    broken["arrays"]["points"]["sum"] = "many"
    with pytest.raises(FormatError, match=r"b\.h5: malformed published content fingerprint"):
        compare_fingerprints(broken, fp, "b.h5")
    check_fingerprint_schema({"fingerprint_schema": "hd.content-fingerprint", "fingerprint_schema_version": "1.3"}, "x")
    with pytest.raises(FormatError, match=r"version 2\.0 is not supported"):
        check_fingerprint_schema({"fingerprint_schema_version": "2.0"}, "checksums.json")


def test_a_damaged_chunk_is_named_not_fingerprinted(tmp_path, arrays):
    path = _shard(tmp_path / "a.h5", *arrays)
    with h5py.File(path, "r") as f:
        info = f["points"].id.get_chunk_info(2)
    with open(path, "r+b") as fh:
        fh.seek(info.byte_offset + info.size // 2)
        byte = fh.read(1)
        fh.seek(info.byte_offset + info.size // 2)
        fh.write(bytes([byte[0] ^ 0xFF]))
    with pytest.raises(FormatError, match=r"a\.h5: cannot read points of scan 12 \(row 2\)"):
        h5_fingerprint(path, "a.h5")


def test_terrain_fingerprint_of_a_geotiff(tmp_path):
    from lidarsim.procedural import write_geotiff

    heights = np.arange(12.0, dtype=np.float32).reshape(3, 4)
    heights[1, 1] = np.nan
    write_geotiff(tmp_path / "t.tif", heights, 0.5, tags={"seed": "3"})
    fp = terrain_fingerprint(tmp_path / "t.tif")
    h = fp["arrays"]["heights"]
    assert h["shape"] == [3, 4] and h["nan"] == 1 and h["sum"] == 66.0 - 5.0 and h["max"] == 11.0
    assert fp["attrs"]["tag_seed"] == "3" and fp["attrs"]["transform"] == [0.5, 0.0, 0.0, 0.0, -0.5, 0.0]
