"""The committed golden dataset (``tests/data/golden/``, written by ``make_golden.py``) pins the
public formats: plain h5py and json read it as the format documents show, hd's readers read it, and
today's writers produce the same layout (every dataset, dtype, shape, chunking, filter, attribute
and manifest key). A change of any of these fails here until the schema version, the documents and
the golden files change together."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
from make_golden import GOLDEN, SCAN_SHARD, TERRAIN, make_golden


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def manifest() -> dict[str, Any]:
    return json.loads((GOLDEN / "manifest.json").read_text())


@pytest.fixture(scope="module")
def fresh(tmp_path_factory) -> Path:
    """The golden dataset as today's writers make it (built once for the layout and the values)."""
    return make_golden(tmp_path_factory.mktemp("fresh") / "golden")


def test_the_scan_shard_reads_with_plain_h5py_as_the_format_document_shows(manifest):
    # docs/shard-format.md, "Reading a shard without hd"
    assert manifest["shards"][0]["path"] == SCAN_SHARD
    with h5py.File(GOLDEN / manifest["shards"][0]["path"], "r") as f:
        assert f.attrs["schema"] == "hd.lidar-scans" and f.attrs["schema_version"].split(".")[0] == "1"
        sigmas = f.attrs["sigmas_m"]
        assert sigmas.tolist() == manifest["sigmas_m"] == [0.0167, 0.07]
        clean = f["points_clean"][0]
        assert clean.shape == (24, 24, 3) and clean.dtype == np.float32
        noisy = f["points_noisy"][0, 1]  # scan 0 at sigma = 0.07 m
        xyz_map = clean.astype(np.float64) + f["origin_map"][0]
        status, valid = f["status"][:], f["valid"][:]
        assert set(np.unique(status)) <= {0, 1, 2, 3}
        assert np.array_equal(valid, np.isin(status, (0, 3)).astype(np.uint8))
        returns = valid[0] == 1
        assert returns.any() and np.isfinite(clean[returns]).all() and np.isnan(clean[~returns]).all()
        # the noisy points lie on the same rays as the clean ones, a few sigma away (scan frame)
        origin = f["sensor_position"][0]
        shift = np.linalg.norm(noisy[returns] - origin, axis=-1) - np.linalg.norm(clean[returns] - origin, axis=-1)
        assert 0.02 < float(np.std(shift)) < 0.2
        assert np.allclose(xyz_map[..., :2][returns], f["origin_map"][0][:2] + clean[returns][:, :2], atol=1e-6)
        # the sensor looks down from the scan's altitude; the attitude is a rotation
        assert np.allclose(origin, [0.0, 0.0, f.attrs["trajectory_altitude_m"]])
        rot = f["sensor_attitude"][0]
        assert np.allclose(rot @ rot.T, np.eye(3), atol=1e-12)
        assert [x.decode() if isinstance(x, bytes) else x for x in f["split"].attrs["names"]] == [
            "train",
            "val",
            "test",
        ]
        assert sorted(f["split"][:].tolist()) == [0, 1, 2]  # one scan per split
        assert f["points_clean"].fletcher32 and f["points_clean"].chunks == (1, 24, 24, 3)


def test_the_label_shard_reads_with_plain_h5py_as_the_format_document_shows(manifest):
    # docs/labels-format.md
    (labeling,) = manifest["labelings"]
    assert labeling["schema"] == "hd.labels" and labeling["convention"] == "paper"
    assert labeling["label_codes"] == {"unsafe": 0, "safe": 1, "invalid": 255}
    with h5py.File(GOLDEN / labeling["shards"][0]["path"], "r") as f:
        label = f["label"][0]
        assert label.shape == (12, 12) and label.dtype == np.uint8
        noisy = f["dem_noisy"][0, 0]
        p = f["p_safe"][0, 0]
        assert noisy.shape == p.shape == (12, 12)
        labels = f["label"][:]
        assert set(np.unique(labels)) <= {0, 1, 255}
        counts = {name: int((labels == code).sum()) for name, code in labeling["label_codes"].items()}
        assert counts == labeling["label_counts"]
        band = 2  # the paper convention's lander radius in whole pixels, int(2.5 m / 1 m): invalid border band
        for edge in (labels[:, :band], labels[:, -band:], labels[:, :, :band], labels[:, :, -band:]):
            assert (edge == 255).all()
        assert (labels[:, band:-band, band:-band] != 255).any()
        finite = np.isfinite(f["p_safe"][:])
        assert finite.any() and ((f["p_safe"][:][finite] >= 0) & (f["p_safe"][:][finite] <= 1)).all()
        assert f.attrs["source_shard"] == SCAN_SHARD
        assert f.attrs["source_sha256"] == manifest["shards"][0]["sha256"]


def test_every_listed_file_matches_the_manifest_and_hd_reads_it(manifest, tmp_path):
    from hdlabels.store import LABEL_SCHEMA, LABEL_SCHEMA_VERSION, LabelShardReader
    from lidarsim.shards import open_scan_shard, verify_dataset

    entries = manifest["shards"] + manifest["labelings"][0]["shards"]
    for entry in entries:
        assert _sha256(GOLDEN / entry["path"]) == entry["sha256"], entry["path"]
    assert manifest["dtm"]["path"] == TERRAIN and _sha256(GOLDEN / TERRAIN) == manifest["dtm"]["sha256"]
    copy = tmp_path / "golden"
    shutil.copytree(GOLDEN, copy)
    assert verify_dataset(copy, known_schemas={LABEL_SCHEMA: LABEL_SCHEMA_VERSION}) == []
    with open_scan_shard(copy, manifest["shards"][0]) as reader:
        assert len(reader) == 3 and reader.sigmas_m == (0.0167, 0.07)
        assert [reader[k].split for k in range(3)] == [
            ["train", "val", "test"][int(c)] for c in h5py.File(GOLDEN / SCAN_SHARD, "r")["split"][:]
        ]
    with LabelShardReader(copy / manifest["labelings"][0]["shards"][0]["path"]) as reader:
        assert len(reader) == 3


def _layout(path: Path) -> dict[str, Any]:
    """Everything of an HDF5 file's layout, none of its values: attributes (name, kind, shape),
    datasets (dtype, shape, chunks, filters, their attributes)."""

    def attrs(obj: Any) -> dict[str, tuple[str, tuple[int, ...]]]:
        return {k: (np.asarray(v).dtype.kind, np.asarray(v).shape) for k, v in obj.attrs.items()}

    out: dict[str, Any] = {"/": attrs(h5py.File(path, "r"))}
    with h5py.File(path, "r") as f:
        out["/"] = attrs(f)
        for name, d in f.items():
            out[name] = {
                "dtype": str(d.dtype),
                "shape": d.shape,
                "chunks": d.chunks,
                "compression": d.compression,
                "compression_opts": d.compression_opts,
                "shuffle": d.shuffle,
                "fletcher32": d.fletcher32,
                "attrs": attrs(d),
            }
    return out


def _keys(value: Any) -> Any:
    """The key structure of a JSON document (lists by their first element)."""
    if isinstance(value, dict):
        return {k: _keys(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_keys(value[0])] if value and isinstance(value[0], (dict, list)) else "list"
    return type(value).__name__


def test_todays_writers_produce_the_golden_layout(manifest, fresh):
    now = json.loads((fresh / "manifest.json").read_text())
    assert _keys(now) == _keys(manifest)
    for key in ("schema", "schema_version", "kind", "n_scans", "sigmas_m", "seed", "config_sha256", "splits"):
        assert now[key] == manifest[key], key
    assert [s["path"] for s in now["shards"]] == [s["path"] for s in manifest["shards"]]
    assert now["labelings"][0]["name"] == manifest["labelings"][0]["name"]
    paths = [SCAN_SHARD, manifest["labelings"][0]["shards"][0]["path"]]
    for rel in paths:
        assert _layout(fresh / rel) == _layout(GOLDEN / rel), rel
        with h5py.File(fresh / rel, "r") as new, h5py.File(GOLDEN / rel, "r") as old:
            for name in ("scan_index", "split"):
                assert np.array_equal(new[name][:], old[name][:]), (rel, name)
            for name in ("schema", "schema_version"):
                assert new.attrs[name] == old.attrs[name]
    with h5py.File(fresh / SCAN_SHARD, "r") as new, h5py.File(GOLDEN / SCAN_SHARD, "r") as old:
        assert new.attrs["config_json"] == old.attrs["config_json"]


# The tolerances of the values (make_golden.py, "Values"): a change of the sensor, the noise model,
# the gridding or the label rule moves values by far more; float rounding of another CPU or library
# build moves them by far less.
POINTS_ATOL_M = 1e-4  # points and DEM heights: 0.1 mm, against a smallest noise level of 16.7 mm
POSE_ATOL = 1e-9  # sensor positions (metres), attitudes and frame origins: computed in float64
SLOPE_ATOL_RAD = 1e-4  # the labels' slope map: 0.006 degrees, against a 10-degree threshold
P_SAFE_ATOL = 1e-4  # the baseline's P(safe), a probability


def _same(new: np.ndarray, old: np.ndarray, atol: float) -> bool:
    """Equal shapes, NaN in the same places, finite values within ``atol``."""
    return new.shape == old.shape and bool(np.allclose(new, old, rtol=0.0, atol=atol, equal_nan=True))


def test_todays_writers_produce_the_golden_values(manifest, fresh):
    with h5py.File(fresh / SCAN_SHARD, "r") as new, h5py.File(GOLDEN / SCAN_SHARD, "r") as old:
        for name in ("status", "valid", "split", "scan_index"):
            assert np.array_equal(new[name][:], old[name][:]), name
        for name in ("sensor_position", "sensor_attitude", "origin_map"):
            assert _same(new[name][:], old[name][:], POSE_ATOL), name
        for name in ("points_clean", "points_noisy"):
            assert _same(new[name][:], old[name][:], POINTS_ATOL_M), name
    rel = manifest["labelings"][0]["shards"][0]["path"]
    with h5py.File(fresh / rel, "r") as new, h5py.File(GOLDEN / rel, "r") as old:
        assert np.array_equal(new["label"][:], old["label"][:])
        for name in ("dem_clean", "dem_noisy", "roughness_m"):
            assert _same(new[name][:], old[name][:], POINTS_ATOL_M), name
        assert _same(new["slope_rad"][:], old["slope_rad"][:], SLOPE_ATOL_RAD)
        assert _same(new["p_safe"][:], old["p_safe"][:], P_SAFE_ATOL)
    now = json.loads((fresh / "manifest.json").read_text())
    assert now["labelings"][0]["label_counts"] == manifest["labelings"][0]["label_counts"]


def test_the_tolerances_lie_far_below_what_a_model_change_moves(manifest):
    # a noise draw at the smallest level moves a point by ~100 point tolerances; a noise level moves
    # P(safe) by ~100 P(safe) tolerances: a changed noise model or baseline cannot hide in them
    with h5py.File(GOLDEN / SCAN_SHARD, "r") as f:
        returns = f["valid"][:] == 1
        shift = np.linalg.norm(f["points_noisy"][:, 0] - f["points_clean"][:], axis=-1)[returns]
    assert float(np.median(shift)) > 50 * POINTS_ATOL_M
    with h5py.File(GOLDEN / manifest["labelings"][0]["shards"][0]["path"], "r") as f:
        p = f["p_safe"][:]
    assert float(np.nanmax(np.abs(p[:, 1] - p[:, 0]))) > 50 * P_SAFE_ATOL
