"""Class I: property-based fuzzing of every file hd reads, and of the options it parses, fed to the commands.

Mutations (drawn by hypothesis, deterministic): manifests (keys removed, types changed, numbers
huge, negative or NaN, odd strings, raw bytes), scan and label shards (attributes, dataset shapes
and dtypes, values, stored chunk bytes, raw bytes; with the manifest's checksums updated or not),
checkpoints (state_dict keys, shapes and dtypes, config and other values, raw bytes; with the
content checksum updated or not), recipes and their published checksums, GeoTIFFs (sizes, dtypes,
nodata, cell sizes, rotations, bands, raw header bytes). The commands: ``hd verify``,
``hd inspect``, ``hd label``, ``hd train``, ``hd eval``, ``hd detect`` (and ``hd build-dataset``
on GeoTIFFs). Option and side-file surfaces: a run's threshold cache (``hd detect``, and
``CachedThreshold.get`` in process), ``hd export --scans``, ``hd eval --sigma-sweep`` (with
``--threshold``, ``--nav-sigma``, ``--drop-pixels``), recipes by name (``hd verify --recipe``) and
training mixes (``hd train --also``). The invariant and the runner are in ``fuzz_kit.py``: exit 0 with a correct result,
or one ``Error:`` line and a non-zero exit; never a traceback, a signal, a hang past the bound or
a damaged input accepted (nor a correct input refused, where a target knows it is correct). The
normal run draws a few examples per target (about 70 s in all on two cores);
``HD_FUZZ_CAMPAIGN=long`` runs the long campaign (docs/reliability.md).
"""

from __future__ import annotations

import contextlib
import copy
import json
import math
import os
import shutil
import tempfile
import time
import tomllib
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rasterio
import torch
from fuzz_kit import (
    LONG_CAMPAIGN,
    ByteEdit,
    H5Edit,
    Hang,
    Outcome,
    TreeEdit,
    apply_bytes,
    apply_h5,
    bounded,
    byte_edits,
    check,
    draw_h5_edit,
    draw_tree_edits,
    fuzz_settings,
    json_values,
    report,
    reseal,
    same,
    scalars,
)
from hypothesis import given
from hypothesis import strategies as st
from rasterio.transform import Affine
from reliability_kit import BUILD_ARGS, REPO, assert_one_line_error, hills, invoke

from hdnet.threshold_cache import CACHE_FILE, CachedThreshold, ThresholdKey, entry_digest
from hdnet.train import checkpoint_digest
from lidarsim.shards import read_manifest

# Examples per target (family/command) in the normal run; the long campaign (HD_FUZZ_CAMPAIGN=long)
# draws about 11 600 of the file families, sized for about 70 minutes on one core, and 10 750 of the
# option and side-file targets, about 40 minutes. HD_FUZZ_SCALE multiplies either.
SHORT = {"verify": 6, "inspect": 3, "label": 3, "train": 2, "eval": 2, "detect": 2, "resume": 2, "build": 2}
# Targets whose normal number differs from their command's (cheap ones draw more).
SHORT_TARGETS = {"thresholds/get": 60, "export-spec/export": 6, "recipe-name/verify": 12, "sweep/eval": 3}
LONG = {
    "manifest/verify": 2000,
    "manifest/inspect": 800,
    "manifest/label": 600,
    "manifest/train": 300,
    "manifest/eval": 200,
    "shard/verify": 2000,
    "shard/inspect": 800,
    "shard/label": 600,
    "shard/train": 300,
    "shard/eval": 200,
    "checkpoint/eval": 300,
    "checkpoint/detect": 400,
    "checkpoint/resume": 300,
    "recipe/label": 600,
    "recipe/verify": 1000,
    "geotiff/detect": 400,
    "geotiff/build": 400,
    # The option and side-file surfaces (their own long campaign, about 10 000 examples; docs/reliability.md).
    "thresholds/detect": 300,
    "thresholds/get": 5000,
    "export-spec/export": 2500,
    "sweep/eval": 150,
    "recipe-name/verify": 2500,
    "also/train": 300,
}


# HD_FUZZ_EXAMPLES="shard/verify=1000,geotiff/build=600" sets targets' numbers (e.g. to finish a campaign).
OVERRIDES = {
    k: int(v) for k, _, v in (item.partition("=") for item in os.environ.get("HD_FUZZ_EXAMPLES", "").split(",") if item)
}


def examples(target: str) -> int:
    """The number of examples of ``target`` ("family/command") in this run, before HD_FUZZ_SCALE."""
    if target in OVERRIDES:
        return OVERRIDES[target]
    if LONG_CAMPAIGN:
        return LONG[target]
    return SHORT_TARGETS[target] if target in SHORT_TARGETS else SHORT[target.split("/")[1]]


TIMEOUT_S = {
    "verify": 60,
    "inspect": 60,
    "label": 120,
    "train": 180,
    "eval": 180,
    "detect": 120,
    "resume": 180,
    "export": 60,
}
LABEL_FIELDS = ("sha256", "path", "n_scans")
LABEL_SHARD = "labels/*/labels-00002.h5"


@pytest.fixture(scope="module")
def scratch() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="hd-fuzz-") as d:
        yield Path(d)


def fresh(scratch: Path) -> Path:
    """An empty private directory for one example."""
    return Path(tempfile.mkdtemp(dir=scratch))


def command(name: str, data: Path, work: Path, run: Path | None = None) -> list[Any]:
    """The arguments of ``hd NAME`` on ``data`` (a dataset) with outputs under ``work``."""
    commands: dict[str, list[Any]] = {
        "verify": ["verify", data],
        "inspect": ["inspect", data],
        "label": ["label", data, "--workers", "1", "--max-slope-deg", "8"],  # a new labelling: every scan is read
        "train": ["train", data, "--out", work / "run", "--profile", "tiny", "--epochs", "1"],
        "eval": ["eval", run, "--data", data, "--out", work / "report", "--mc-samples", "2"],
    }
    return commands[name]


def accept_for(name: str, work: Path, data: Path) -> Any:
    """A command's own check of an exit 0: the output it promised is there."""

    def accept(outcome: Outcome) -> str | None:
        if name == "verify" and ": OK," not in outcome.output:
            return "exit 0 without the OK line"
        if name == "inspect" and "status    intact" not in outcome.output:
            return "exit 0 without status intact"
        if name == "train" and not (work / "run" / "last.pt").is_file():
            return "exit 0 without last.pt"
        if name == "eval" and not (work / "report" / "report.json").is_file():
            return "exit 0 without report.json"
        if name == "label" and not any("slope8deg" in lab["name"] for lab in read_manifest(data)["labelings"]):
            return "exit 0 without the new labelling in the manifest"
        return None

    return accept


# ------------------------------------------------------------------------------------- manifests
def _manifest_must_fail(edits: list[TreeEdit], name: str) -> bool:
    """A single edit that every reader of the edited entry must refuse: a listed file's checksum, path
    or scan count, the dataset's scan count or schema."""
    if len(edits) != 1 or not edits[0].changed:
        return False
    path = edits[0].path
    if path in (("n_scans",), ("schema",)) or (path[:1] == ("shards",) and len(path) == 2):
        return True
    scan_entry = len(path) == 3 and path[0] == "shards" and path[2] in LABEL_FIELDS
    label_entry = len(path) == 5 and path[0] == "labelings" and path[2] == "shards" and path[4] in LABEL_FIELDS
    if name in ("verify", "inspect"):
        return scan_entry or label_entry
    if name == "label":
        return scan_entry
    return label_entry  # train and eval read the label shards


@pytest.mark.parametrize("name", ["verify", "inspect", "label", "train", "eval"])
def test_mutated_manifests(name, labelled, trained, scratch):
    @fuzz_settings(examples(f"manifest/{name}"))
    @given(st.data())
    def example(data):
        work = fresh(scratch)
        ds = work / "data"
        shutil.copytree(labelled, ds)
        path = ds / "manifest.json"
        if data.draw(st.integers(0, 4), label="raw bytes?") == 0:
            edit: Any = data.draw(byte_edits(), label="byte edit")
            apply_bytes(path, edit)
            try:
                json.loads(path.read_bytes())
                must_fail = False
            except ValueError:
                must_fail = True
        else:
            tree = json.loads(path.read_text())
            edit = draw_tree_edits(data, tree, json_values())
            path.write_text(json.dumps(tree, indent=1))
            must_fail = _manifest_must_fail(edit, name)
        check(
            f"manifest/{name}",
            command(name, ds, work, trained),
            edit,
            must_fail=must_fail,
            timeout_s=TIMEOUT_S[name],
            roots=(work,),
            accept=accept_for(name, work, ds),
        )
        shutil.rmtree(work, ignore_errors=True)

    example()


# ------------------------------------------------------------------------------------- shards
@pytest.mark.parametrize("name", ["verify", "inspect", "label", "train", "eval"])
def test_mutated_shards(name, labelled, trained, scratch):
    files = sorted(str(p.relative_to(labelled)) for p in labelled.rglob("*.h5"))

    @fuzz_settings(examples(f"shard/{name}"))
    @given(st.data())
    def example(data):
        work = fresh(scratch)
        ds = work / "data"
        shutil.copytree(labelled, ds)
        rel = data.draw(st.sampled_from(files), label="file")
        path = ds / rel
        before = path.read_bytes()
        edit: Any
        if data.draw(st.integers(0, 3), label="raw bytes?") == 0:
            edit = data.draw(byte_edits(), label="byte edit")
            apply_bytes(path, edit)
        else:
            edit = draw_h5_edit(data, path)
            apply_h5(path, edit)
        changed = path.read_bytes() != before
        sealed = data.draw(st.booleans(), label="reseal")
        if sealed:
            reseal(ds)
        # An unsealed change must be refused by every command that reads the file; a sealed one by
        # verify when it removes or changes what verify checks (the schema and the scan count).
        reads = {"verify": True, "inspect": True, "label": rel.startswith("shards/")}.get(
            name, rel.startswith("labels/")
        )
        must_fail = reads and changed and not sealed
        if sealed and name in ("verify", "inspect") and getattr(edit, "kind", "").startswith("attr"):
            must_fail = edit.target in ("schema", "n_scans") and (
                edit.kind == "attr-delete"
                or not isinstance(edit.value, (str, int, float))
                or str(edit.value)
                != str({"schema": "hd.labels" if rel.startswith("labels/") else "hd.lidar-scans"}.get(edit.target, "2"))
            )
        check(
            f"shard/{name}",
            command(name, ds, work, trained),
            (rel, edit, "sealed" if sealed else "unsealed"),
            must_fail=must_fail,
            timeout_s=TIMEOUT_S[name],
            roots=(work,),
            accept=accept_for(name, work, ds),
        )
        shutil.rmtree(work, ignore_errors=True)

    example()


# ------------------------------------------------------------------------------------- checkpoints
def _tensor_values() -> st.SearchStrategy[Any]:
    return st.one_of(
        scalars(big_ints=False),
        st.sampled_from(["shape+1", "shape-axis", "empty", "float64", "float16", "int64", "bool", "nan", "inf"]),
    )


def _tensor_like(old: Any, how: Any) -> Any:
    """A replacement for the tensor ``old``: another shape, dtype or values, or ``how`` itself (not a tensor)."""
    if not isinstance(old, torch.Tensor) or not isinstance(how, str) or not how.isascii() or how.isdigit():
        return how
    if how == "shape+1":
        return torch.zeros(*old.shape[:-1], old.shape[-1] + 1) if old.dim() else torch.zeros(2)
    if how == "shape-axis":
        return old.reshape(-1)
    if how == "empty":
        return torch.zeros(0)
    if how in ("float64", "float16", "int64", "bool"):
        return old.to(getattr(torch, how))
    if how in ("nan", "inf"):
        return torch.full_like(old, math.nan if how == "nan" else math.inf) if old.is_floating_point() else old
    return how


def _draw_checkpoint_edits(data: st.DataObject, ckpt: dict[str, Any]) -> list[Any]:
    """Edits of a loaded checkpoint: its weights (keys, shapes, dtypes, values) or any other value."""
    edits: list[Any] = []
    for _ in range(data.draw(st.integers(1, 2), label="edits")):
        where = data.draw(st.sampled_from(["weights", "weights", "tree"]), label="where")
        model = ckpt.get("model")
        if where == "weights" and isinstance(model, dict) and model:
            key = data.draw(st.sampled_from(sorted(model)), label="tensor")
            how = data.draw(st.one_of(st.sampled_from(["delete", "rename"]), _tensor_values()), label="how")
            if how == "delete":
                del model[key]
            elif how == "rename":
                model[key + ".x"] = model.pop(key)
            else:
                model[key] = _tensor_like(model[key], how)
            edits.append(("model", key, how))
        else:
            rest = {k: v for k, v in ckpt.items() if k not in ("model", "content_sha256")}
            tree_edits = draw_tree_edits(data, rest, json_values(), max_edits=1)
            for k in list(ckpt):
                if k not in rest and k not in ("model", "content_sha256"):
                    del ckpt[k]
            ckpt.update(rest)
            edits += tree_edits
    return edits


@pytest.mark.parametrize("name", ["eval", "detect", "resume"])
def test_mutated_checkpoints(name, labelled, trained, scratch):
    original = torch.load(trained / "last.pt", weights_only=True)
    digest = original["content_sha256"]
    dtm = hills(scratch / f"detect-{name}.tif", n=120)

    @fuzz_settings(examples(f"checkpoint/{name}"))
    @given(st.data())
    def example(data):
        work = fresh(scratch)
        run = work / "run"
        shutil.copytree(trained, run)
        last = run / "last.pt"
        edit: Any
        if data.draw(st.integers(0, 3), label="raw bytes?") == 0:
            edit = data.draw(byte_edits(), label="byte edit")
            apply_bytes(last, edit)
            try:  # a change the loader cannot see (zip padding) leaves a correct checkpoint
                loaded = torch.load(last, weights_only=True)
                must_fail = checkpoint_digest(loaded) != digest or loaded.get("content_sha256") != digest
            except Exception:  # noqa: BLE001 - any failure to load is damage the commands must refuse
                must_fail = True
        else:
            ckpt = copy.deepcopy(original)
            edit = _draw_checkpoint_edits(data, ckpt)
            sealed = data.draw(st.booleans(), label="reseal")
            if sealed:
                ckpt["content_sha256"] = checkpoint_digest({k: v for k, v in ckpt.items() if k != "content_sha256"})
            torch.save(ckpt, last)
            must_fail = not sealed and checkpoint_digest(ckpt) != digest
            edit = (edit, "sealed" if sealed else "unsealed")
        args: list[Any] = {
            "eval": ["eval", run, "--data", labelled, "--out", work / "report", "--mc-samples", "2"],
            "detect": [
                "detect",
                last,
                "--dtm",
                dtm,
                "--out",
                work / "d",
                "--threshold",
                "nats:0.3",
                "--mc-samples",
                "2",
            ],
            "resume": ["train", labelled, "--out", run, "--profile", "tiny", "--epochs", "2", "--resume"],
        }[name]
        check(f"checkpoint/{name}", args, edit, must_fail=must_fail, timeout_s=TIMEOUT_S[name], roots=(work, labelled))
        shutil.rmtree(work, ignore_errors=True)

    example()


# ------------------------------------------------------------------------------------- recipes
def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value if v is not None) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_toml_value(v)}" for k, v in value.items() if v is not None) + "}"
    return '""'  # None: TOML has no null


def to_toml(data: dict[str, Any]) -> str:
    """A TOML document of ``data`` (tables of values; a top-level value that is not a table is written as such)."""
    lines = [f"{json.dumps(k)} = {_toml_value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for name, table in data.items():
        if isinstance(table, dict):
            lines.append(f"[{json.dumps(name)}]")
            lines += [f"{json.dumps(k)} = {_toml_value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


RECIPE = {
    "dataset": {"name": "fuzz", "version": 1, "description": "a recipe of the fuzzing campaign"},
    "build": {"scans": 8, "sigmas_m": [0.0167], "seed": 3, "shard_size": 2, "resolution": 32},
    "label": {
        "lander": "square",
        "lander_diameter_m": 10.0,
        "pad_diameter_m": 1.0,
        "max_slope_deg": 8.0,
        "max_roughness_m": 0.2,
        "convention": "paper",
        "dem_size": 64,
    },
}


def _recipe_values() -> st.SearchStrategy[Any]:
    """Values for recipe keys: small valid ones (so that a run stays short) and invalid ones of every type."""
    return st.one_of(
        scalars(big_ints=False),
        st.sampled_from([2, 8, 16, 3.0, 0.5, 12.0, "hd", "paper", "triangle", "min", "linear", "gzip", "../x.tif"]),
        st.lists(st.sampled_from([0.0167, 0.03, -1.0, math.nan, "x"]), max_size=3),
        st.dictionaries(st.sampled_from(["a", "scans"]), st.integers(0, 3), max_size=2),
    )


def published_checksums(dataset: Path) -> dict[str, Any]:
    """The ``checksums.json`` a recipe would publish for ``dataset`` (its settings hash, schemas and shards)."""
    manifest = read_manifest(dataset)
    return {
        "config_sha256": manifest["config_sha256"],
        "schema": manifest["schema"],
        "schema_version": manifest["schema_version"],
        "shard_schema_version": manifest["shards"][0]["schema_version"],
        "shards": [{"sha256": e["sha256"], "path": e["path"], "n_scans": e["n_scans"]} for e in manifest["shards"]],
    }


@pytest.mark.parametrize("name", ["label", "verify"])
def test_mutated_recipes(name, labelled, scratch):
    published = published_checksums(labelled)

    @fuzz_settings(examples(f"recipe/{name}"))
    @given(st.data())
    def example(data):
        work = fresh(scratch)
        ds = labelled if name == "verify" else work / "data"
        if name == "label":
            shutil.copytree(labelled, ds)
        recipe = work / "recipe"
        recipe.mkdir()
        tree = copy.deepcopy(RECIPE)
        checksums = copy.deepcopy(published)
        what = data.draw(st.sampled_from(["recipe", "recipe", "recipe-bytes", "checksums", "checksums-bytes"]))
        must_fail = False
        if what == "recipe":
            edit: Any = draw_tree_edits(data, tree, _recipe_values())
        elif what == "checksums":
            edit = draw_tree_edits(data, checksums, json_values())
            changed = [e for e in edit if e.changed]
            must_fail = name == "verify" and len(edit) == 1 and bool(changed)
            path = edit[0].path  # a shard entry's n_scans is informative: its path and sha256 are compared
            must_fail = must_fail and path[0] in ("config_sha256", "shards", "shard_schema_version")
            must_fail = must_fail and (len(path) < 3 or path[2] in ("path", "sha256"))
        (recipe / "recipe.toml").write_text(to_toml(tree))
        (recipe / "checksums.json").write_text(json.dumps(checksums, indent=1))
        if what.endswith("bytes"):
            edit = data.draw(byte_edits(), label="byte edit")
            target = recipe / ("recipe.toml" if what.startswith("recipe") else "checksums.json")
            apply_bytes(target, edit)
            if name == "verify" and target.name == "checksums.json":
                try:
                    must_fail = json.loads(target.read_bytes()) != published
                except ValueError:
                    must_fail = True
        try:
            tomllib.loads((recipe / "recipe.toml").read_text(errors="replace"))
        except tomllib.TOMLDecodeError:
            must_fail = True
        args: list[Any] = (
            ["label", ds, "--workers", "1", "--recipe", recipe]
            if name == "label"
            else ["verify", ds, "--recipe", recipe]
        )
        check(f"recipe/{name}", args, (what, edit), must_fail=must_fail, timeout_s=TIMEOUT_S[name], roots=(work,))
        shutil.rmtree(work, ignore_errors=True)

    example()


# ------------------------------------------------------------------------------------- GeoTIFFs
DTYPES = ["float32", "float64", "int16", "uint16", "int32", "uint8", "complex64"]
PATTERNS = ["hills", "nan-sprinkle", "all-nan", "all-nodata", "constant", "huge", "inf-sprinkle", "half-nodata"]


def write_geotiff(path: Path, spec: dict[str, Any]) -> bool:
    """Write the GeoTIFF ``spec`` describes; returns whether it holds no valid height at all."""
    rows, cols = spec["rows"], spec["cols"]
    base = np.asarray(rasterio.open(hills(path.with_suffix(".base.tif"), n=max(rows, cols, 8))).read(1))[:rows, :cols]
    z = base.astype(np.float64) * spec["z_scale"]
    nodata = spec["nodata"]
    pattern = spec["pattern"]
    fill = nodata if nodata is not None else math.nan
    if pattern == "nan-sprinkle":
        z[::3, ::2] = math.nan
    elif pattern == "all-nan":
        z[:] = math.nan
    elif pattern == "all-nodata":
        z[:] = fill
    elif pattern == "constant":
        z[:] = 5.0
    elif pattern == "huge":
        z[::2] = 1e30
    elif pattern == "inf-sprinkle":
        z[1::4, ::3] = math.inf
    elif pattern == "half-nodata":
        z[: rows // 2] = fill
    dtype = np.dtype(spec["dtype"])
    if dtype.kind in "iu":
        info = np.iinfo(dtype)
        z = np.clip(np.nan_to_num(z, nan=info.min, posinf=info.max, neginf=info.min), info.min, info.max)
        if nodata is not None and not (math.isfinite(nodata) and info.min <= nodata <= info.max):
            nodata = None
    if dtype.kind == "c" and nodata is not None and not math.isfinite(nodata):
        nodata = None  # GDAL takes no infinite nodata for complex rasters
    with np.errstate(invalid="ignore", over="ignore"):
        arr = z.astype(dtype)
    res, sign, rot = spec["res_m"], spec["y_sign"], spec["rotation"]
    transform = Affine(res, rot * res, 1000.0, rot * res, sign * res, 2000.0)
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=cols,
        height=rows,
        count=spec["bands"],
        dtype=spec["dtype"],
        nodata=nodata,
        transform=transform,
        crs=spec["crs"],
    ) as dst:
        for band in range(1, spec["bands"] + 1):
            dst.write(arr, band)
    path.with_suffix(".base.tif").unlink()
    zf = z.astype(np.float64)
    invalid = ~np.isfinite(zf) | (np.abs(zf) > 1e5)
    if nodata is not None:
        invalid |= zf == nodata
    return bool(invalid.all()) or pattern in ("all-nan", "all-nodata")


GEOTIFFS = st.fixed_dictionaries(
    {  # repeated entries weigh the draws towards DTMs that hd can use, so that the commands get past the checks
        "rows": st.sampled_from([1, 2, 3, 17, 64, 150, 150, 150, 300]),
        "cols": st.sampled_from([1, 2, 3, 17, 64, 150, 150, 150, 300]),
        "dtype": st.sampled_from([*DTYPES, "float32", "float32", "float32"]),
        "pattern": st.sampled_from([*PATTERNS, "hills", "hills", "hills", "hills"]),
        "nodata": st.sampled_from([None, None, None, math.nan, -9999.0, 0.0, 5.0, 1e30, -math.inf]),
        "z_scale": st.sampled_from([1.0, 1.0, 1.0, 1000.0, 1e-6, -1.0]),
        "res_m": st.sampled_from([1.0, 1.0, 1.0, 0.5, 0.25, 2.0, 1e-3, 1e6]),
        "y_sign": st.sampled_from([-1.0, -1.0, -1.0, 1.0]),
        "rotation": st.sampled_from([0.0, 0.0, 0.0, 0.0, 0.5, 1e-9]),
        "bands": st.sampled_from([1, 1, 1, 2]),
        "crs": st.sampled_from([None, None, None, None, "EPSG:32633", "EPSG:4326", "EPSG:2236"]),
    }
)


TINY_BUILD = ["--scans", "2", "--shard-size", "2", "--resolution", "8", "--seed", "1"]


@pytest.mark.parametrize("name", ["detect", "build"])
def test_mutated_geotiffs(name, trained, scratch):
    @fuzz_settings(examples(f"geotiff/{name}"))
    @given(GEOTIFFS, st.one_of(st.none(), st.none(), byte_edits()))
    def example(spec, raw: ByteEdit | None):
        work = fresh(scratch)
        tif = work / "dtm.tif"
        empty = write_geotiff(tif, spec)
        if raw is not None:
            apply_bytes(tif, raw)
        args: list[Any] = (
            ["detect", trained, "--dtm", tif, "--out", work / "d", "--threshold", "nats:0.3", "--mc-samples", "2"]
            if name == "detect"
            else ["build-dataset", "--out", work / "b", "--dtm", tif, "--workers", "1", *TINY_BUILD]
        )
        check(
            f"geotiff/{name}",
            args,
            (spec, raw),
            must_fail=empty and raw is None,
            timeout_s=TIMEOUT_S["detect"],
            roots=(work,),
        )
        shutil.rmtree(work, ignore_errors=True)

    example()


# ------------------------------------------------------------------------------------- the threshold cache
LN2 = math.log(2.0)
# Values a forged entry may hold: in and just outside the score's range [0, ln 2] nats, and of other types.
THRESHOLD_VALUES = [0.0, -0.0, 0, 0.3, LN2, LN2 + 5e-7, LN2 + 2e-6, 1.0, -1e-12, math.nan, math.inf, None, True, "0.3"]
# An integer literal longer than Python's limit for converting digits to an int (4300): json.loads raises
# a plain ValueError, not a JSONDecodeError.
HUGE_LITERAL = "7" * 5000
CACHE_SPECIALS = [
    "absent",
    "empty",
    "fifo",
    "directory",
    "padded-past-4MiB",
    "sparse-5MiB",
    "link-to-dev-zero",
    "dangling-link",
    "link-loop",
    "link-to-a-copy",
    "nested-100000",
    "huge-integer-literal",
    "schema-version-1",
    "300-copies",
]


@dataclass(frozen=True)
class Calibrated:
    """A private copy of the trained run whose cache holds the calibrated default threshold of ``dtm``."""

    run: Path
    dtm: Path
    value_nats: float
    safety: np.ndarray  # safety.tif of the calibrated detect


def _safety(out: Path) -> np.ndarray:
    with rasterio.open(out / "safety.tif") as src:
        return np.asarray(src.read(1))


@pytest.fixture(scope="module")
def calibrated(trained, scratch) -> Calibrated:
    """``hd detect`` once with the default (calibrated) threshold: the value and maps every example must give."""
    run = scratch / "calibrated-run"
    shutil.copytree(trained, run, ignore=shutil.ignore_patterns(CACHE_FILE))
    dtm = hills(scratch / "calibrated.tif", n=120)
    result = invoke("detect", run, "--dtm", dtm, "--out", scratch / "calibrated-detect", "--mc-samples", "2")
    assert result.exit_code == 0, result.output
    value = json.loads((scratch / "calibrated-detect" / "detect.json").read_text())["threshold"]["value_nats"]
    entries = json.loads((run / CACHE_FILE).read_text())["entries"]
    assert [e["value_nats"] for e in entries] == [value]
    return Calibrated(run, dtm, value, _safety(scratch / "calibrated-detect"))


def _reseal(tree: Any) -> None:
    """Give every entry of a cache tree the digest of its (edited) key, value and record, where it has them."""
    for entry in tree.get("entries", []) if isinstance(tree, dict) and isinstance(tree.get("entries"), list) else []:
        if isinstance(entry, dict) and isinstance(entry.get("key"), dict):
            with contextlib.suppress(KeyError, TypeError, ValueError, RecursionError):
                entry["sha256"] = entry_digest(entry["key"], entry["value_nats"], entry["info"])


def _in_range(value: Any) -> bool:
    """A threshold the cache may hold: None (unbounded) or a number of nats in [0, ln 2] (+ the cache's
    float slack of 1e-6)."""
    if value is None:
        return True
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    return math.isfinite(value) and 0.0 <= value <= LN2 + 1e-6


def _sealed_forgeries(tree: Any) -> list[Any]:
    """The values of a resealed tree's entries that the cache may trust (a consistent forgery: docs, Not covered)."""
    entries = tree.get("entries") if isinstance(tree, dict) else None
    return [
        entry["value_nats"]
        for entry in (entries if isinstance(entries, list) else [])
        if isinstance(entry, dict)
        and "value_nats" in entry
        and _in_range(entry["value_nats"])
        and isinstance(entry.get("info"), dict)
    ]


def _special_cache(path: Path, kind: str, valid: bytes) -> None:
    """Put something that is not a plain threshold cache at ``path`` (a cache's bytes are ``valid``)."""
    path.unlink(missing_ok=True)
    if kind == "empty":
        path.write_bytes(b"")
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "directory":
        path.mkdir()
    elif kind == "padded-past-4MiB":  # a valid cache, too long to be read
        path.write_bytes(valid + b" " * (4 << 20))
    elif kind == "sparse-5MiB":
        with open(path, "wb") as fh:
            fh.truncate(5 << 20)
    elif kind == "link-to-dev-zero":
        path.symlink_to("/dev/zero")
    elif kind == "dangling-link":
        path.symlink_to(path.parent / "nowhere.json")
    elif kind == "link-loop":
        path.symlink_to(path)
    elif kind == "link-to-a-copy":
        (path.parent / "copy.json").write_bytes(valid)
        path.symlink_to(path.parent / "copy.json")
    elif kind == "nested-100000":
        path.write_text("[" * 100_000 + "]" * 100_000)
    elif kind == "huge-integer-literal":
        tree = json.loads(valid)
        tree["entries"][0]["info"]["calibration_images"] = 0  # replaced by the literal below
        path.write_text(json.dumps(tree).replace('"calibration_images": 0', f'"calibration_images": {HUGE_LITERAL}'))
    elif kind == "schema-version-1":
        tree = json.loads(valid)
        tree["schema_version"] = 1
        path.write_text(json.dumps(tree))
    elif kind == "300-copies":
        tree = json.loads(valid)
        tree["entries"] = tree["entries"] * 300
        path.write_text(json.dumps(tree))


def _mutate_cache(data: st.DataObject, path: Path, valid: bytes, values: st.SearchStrategy[Any]) -> tuple[Any, Any]:
    """Damage the cache file at ``path`` (holding ``valid``): a tree edit (resealed or not), raw bytes or a
    special file. Returns the edit and the tree written when it was resealed (else None)."""
    how = data.draw(st.sampled_from(["tree", "tree", "tree", "sealed", "bytes", "bytes", "special"]), label="how")
    if how in ("tree", "sealed"):
        tree = json.loads(valid)
        edit: Any = draw_tree_edits(data, tree, values)
        if how == "sealed":
            _reseal(tree)
        path.write_text(json.dumps(tree, indent=1))
        return (how, edit), tree if how == "sealed" else None
    if how == "bytes":
        edit = data.draw(byte_edits(), label="byte edit")
        apply_bytes(path, edit)
        return (how, edit), None
    kind = data.draw(st.sampled_from(CACHE_SPECIALS), label="special")
    _special_cache(path, kind, valid)
    return (how, kind), None


def _cache_values() -> st.SearchStrategy[Any]:
    return st.one_of(json_values(), st.sampled_from(THRESHOLD_VALUES), st.floats(0.0, 1.0))


def test_mutated_threshold_caches(calibrated, scratch):
    """hd detect with a damaged or forged RUN/thresholds.json: the calibrated value, or a one-line error."""
    valid = (calibrated.run / CACHE_FILE).read_bytes()

    @fuzz_settings(examples("thresholds/detect"))
    @given(st.data())
    def example(data):
        work = fresh(scratch)
        run = work / "run"
        shutil.copytree(calibrated.run, run, ignore=shutil.ignore_patterns(CACHE_FILE))
        (run / CACHE_FILE).write_bytes(valid)
        edit, sealed = _mutate_cache(data, run / CACHE_FILE, valid, _cache_values())
        allowed = [calibrated.value_nats, *(_sealed_forgeries(sealed) if sealed is not None else [])]

        def accept(outcome: Outcome) -> str | None:
            try:
                value = json.loads((work / "d" / "detect.json").read_text())["threshold"]["value_nats"]
            except (OSError, ValueError, KeyError, TypeError) as exc:
                return f"exit 0 without a readable detect.json threshold ({exc})"
            if not any(value == a if a is not None and value is not None else value is a for a in allowed):
                return f"the maps used {value!r} nats; calibrated {calibrated.value_nats!r}"
            if value == calibrated.value_nats and not np.array_equal(_safety(work / "d"), calibrated.safety):
                return "safety.tif differs from the calibrated run's"
            return None

        args = ["detect", run, "--dtm", calibrated.dtm, "--out", work / "d", "--mc-samples", "2"]
        check("thresholds/detect", args, edit, timeout_s=TIMEOUT_S["detect"], roots=(work,), accept=accept)
        shutil.rmtree(work, ignore_errors=True)

    example()


def _cache_keys() -> list[ThresholdKey]:
    """Keys of four calibrations of one run that differ in spec, score or noise level."""
    common: dict[str, Any] = {
        "checkpoint_sha256": "c" * 64,
        "manifest_sha256": "d" * 64,
        "labels": "paper-square",
        "calibrate": "reference",
        "mc_samples": 2,
        "batch_size": 8,
        "seed": 0,
    }
    return [
        ThresholdKey(sigma_m=0.0167, spec="mean", **common),
        ThresholdKey(sigma_m=0.0167, spec="quantile:0.9", **common),
        ThresholdKey(sigma_m=0.05, spec="risk:0.05", **common),
        ThresholdKey(sigma_m=0.0167, spec="mean", uncertainty="mutual-information", **common),
    ]


def test_mutated_threshold_cache_entries(scratch):
    """CachedThreshold.get on a damaged or forged file (in process, no command): None or exactly what was
    stored under the key, never an exception; an entry whose neighbour alone was damaged is still found."""
    keys = _cache_keys()
    values: list[float] = [0.4321, math.inf, 0.0, LN2]
    base = scratch / "cache-entries"
    base.mkdir()
    cache = CachedThreshold(base)
    for key, value in zip(keys, values, strict=True):
        assert cache.put(key, value, {"spec": key.spec, "kind": key.spec.split(":")[0], "calibration_images": 3})
    valid = (base / CACHE_FILE).read_bytes()
    stored = {key: cache.get(key) for key in keys}
    assert all(stored.values())

    @fuzz_settings(examples("thresholds/get"))
    @given(st.data())
    def example(data):
        d = Path(tempfile.mkdtemp(dir=scratch))
        (d / CACHE_FILE).write_bytes(valid)
        edit, sealed = _mutate_cache(data, d / CACHE_FILE, valid, _cache_values())
        start = time.monotonic()
        problem = None
        got: dict[ThresholdKey, Any] = {}
        try:
            with warnings.catch_warnings(), bounded(30.0):
                warnings.simplefilter("ignore")
                got = {key: CachedThreshold(d).get(key) for key in keys}
        except Hang as exc:
            problem = f"hang: {exc}"
        except Exception as exc:  # noqa: BLE001 - any exception is the violation this target looks for
            problem = f"get raised {type(exc).__name__}: {str(exc)[:200]}"
        forged = [None if v is None else float(v) for v in _sealed_forgeries(sealed)] if sealed is not None else []
        for i, (key, hit) in enumerate(got.items()):
            if hit is not None and not (isinstance(hit, tuple) and len(hit) == 2):
                problem = problem or f"get({key.spec}) returned {hit!r}, not (value, record)"
                continue
            if hit is None or same(list(hit), list(stored[key] or ())):
                untouched = _only_touches_another_entry(edit, i)
                if hit is None and untouched:
                    problem = problem or f"the untouched entry {key.spec} (sigma {key.sigma_m}) was not found"
                continue
            value = None if hit[0] == math.inf else hit[0]
            if not any(value == v if v is not None and value is not None else value is v for v in forged):
                problem = problem or f"get({key.spec}) returned {hit!r}, stored {stored[key]!r}"
        shutil.rmtree(d, ignore_errors=True)
        report("thresholds/get", edit, problem, Outcome(0, seconds=time.monotonic() - start))

    example()


def _only_touches_another_entry(edit: Any, index: int) -> bool:
    """True for one tree edit (resealed or not) inside an entry other than the ``index``-th, not its key
    (so the ``index``-th entry and its position are untouched)."""
    how, edits = edit
    if how not in ("tree", "sealed") or len(edits) != 1:
        return False
    path = edits[0].path
    return (
        len(path) >= 3 and path[0] == "entries" and isinstance(path[1], int) and path[1] != index and path[2] != "key"
    )


# ------------------------------------------------------------------------------------- hd export --scans
INDEX_TEXTS = ["0", "1", "3", "5", "7", "00", "007"]
BEYOND_TEXTS = ["8", "10", "999999", "1000000", "4294967296", "99999999999999999999", "1" + "0" * 30]
# Decimal digits of other scripts (Arabic-Indic three and zero, fullwidth one, mathematical double-struck zero,
# N'Ko seven), and characters that str.isdigit or str.isnumeric call digits but that are no decimal digits
# (superscript two and three, one half, Roman numeral eight).
UNICODE_TEXTS = [
    "\u0663",
    "\uff11",
    "\u0660",
    "\U0001d7d8",
    "\u07c7",
    "\u0663\u0663",
    "\u00b2",
    "\u00b3",
    "\u00bd",
    "\u2167",
]
ODD_TEXTS = ["1_0", "+1", "-0", "1e3", "0x1", "1.0", "", " ", "-", "-5", "5-", "1-2-3", ":", "0:3", "_", "0--1"]


def _scan_numbers() -> st.SearchStrategy[str]:
    return st.one_of(
        st.sampled_from(INDEX_TEXTS),
        st.sampled_from(INDEX_TEXTS),
        st.sampled_from(BEYOND_TEXTS),
        st.sampled_from(UNICODE_TEXTS),
    )


def _scan_specs() -> st.SearchStrategy[str]:
    """Texts for ``hd export --scans``: lists of indices and ranges, with odd digits, separators and spaces."""
    pad = st.sampled_from(["", "", "", " ", "  ", "\t"])
    item = st.one_of(
        st.builds(lambda a, n, b: a + n + b, pad, _scan_numbers(), pad),
        st.builds(
            lambda a, lo, dash, hi, b: a + lo + dash + hi + b,
            pad,
            _scan_numbers(),
            st.sampled_from(["-", "-", "-", " - ", "--", ":", "\u2013"]),
            _scan_numbers(),
            pad,
        ),
        st.sampled_from(ODD_TEXTS),
    )
    return st.one_of(
        st.builds(
            lambda items, sep: sep.join(items),
            st.lists(item, min_size=1, max_size=5),
            st.sampled_from([",", ",", ", ", ";", " "]),
        ),
        st.text(alphabet="0123456789-,: _\u00b2\u0663\uff11\t", max_size=12),
    )


def scans_named(spec: str, n_scans: int) -> tuple[set[int] | None, bool]:
    """The scans ``--scans SPEC`` names in a dataset of ``n_scans`` (None: SPEC is no list of valid indices
    and ranges ``A`` and ``A-B``, A <= B < n_scans, between commas, spaces around them), and whether SPEC
    uses decimal digits other than ASCII ones (which hd may accept, read as int() does, or refuse)."""
    out: set[int] = set()
    other_digits = False
    for part in spec.split(","):
        item = part.strip(" \t")
        lo, dash, hi = item.partition("-")
        ends = [lo, hi] if dash else [lo]
        if not all(e and all(c.isdecimal() for c in e) for e in ends):
            return None, False
        other_digits |= not item.isascii()
        first, last = int(ends[0]), int(ends[-1])
        if last < first or last >= n_scans:
            return None, False
        out |= set(range(first, last + 1))
    return out, other_digits


def test_fuzzed_export_scan_specs(labelled, scratch):
    """hd export --scans SPEC: exactly the files SPEC names, or a one-line error."""
    n_scans = int(read_manifest(labelled)["n_scans"])

    @fuzz_settings(examples("export-spec/export"))
    @given(_scan_specs())
    def example(spec):
        work = fresh(scratch)
        named, other_digits = scans_named(spec, n_scans)

        def accept(outcome: Outcome) -> str | None:
            files = {p.name for p in (work / "x").iterdir()}
            want = {f"scan-{k:06d}.laz" for k in named or ()} | {"export.json"}
            return None if files == want else f"exported {sorted(files)[:5]}, the spec names {sorted(want)[:5]}"

        check(
            "export-spec/export",
            ["export", labelled, "--scans", spec, "--out", work / "x"],
            spec,
            must_fail=named is None,
            must_pass=named is not None and not other_digits,
            timeout_s=TIMEOUT_S["export"],
            roots=(work,),
            accept=accept,
        )
        shutil.rmtree(work, ignore_errors=True)

    example()


# ------------------------------------------------------------------------------------- hd eval's lists and ranges
SWEEP_NUMBERS = [
    *["0", "0.0", "0.01", "0.02", "0.0167", "0.05", "0.1", "0.7", "-0", "+0.01", " 0.01 "],
    *["0.7000001", "0.75", "1", "-0.01", "1e-9", "5e-32", "5e-324", "1e-320", "1e308", "1e309"],
    *[
        "nan",
        "NaN",
        "inf",
        "-inf",
        "",
        " ",
        "0x1",
        "1e",
        ".",
        "1_0",
        "\u0660",
        "\u0660.\u0660\u0665",
        "\uff11",
        "0.0\uff15",
        "\u00b2",
    ],
]
# (text, whether hd eval must take it: True, False, or None where either is right)
THRESHOLD_TEXTS = [
    ("mean", True),
    ("MEAN", None),
    (" mean ", None),
    ("quantile:0.9", True),
    ("quantile:0", True),
    ("quantile:1", True),
    ("quantile:1.0000001", False),
    ("quantile:nan", False),
    ("quantile:-0.1", False),
    ("risk:0.05", True),
    ("risk:0", False),
    ("risk:1", False),
    ("risk:1e-300", True),
    ("nats:0.3", True),
    ("nats:0", True),
    ("nats:inf", None),
    ("nats:1e309", None),
    ("nats:-0.0", None),
    ("nats:\u0660.\u0663", None),
    ("nats:-inf", False),
    ("nats:-1", False),
    ("nats:nan", False),
    ("nats:", False),
    ("nats", False),
    ("mean:0.1", False),
    ("nats:0.3:0.4", False),
    ("", False),
    (":", False),
    ("bogus", False),
]
NAV_SIGMA_TEXTS = [
    ("0", True),
    ("1", True),
    ("3", True),
    ("100", True),
    ("-0", None),
    ("1e-320", True),
    ("100.0001", False),
    ("-1", False),
    ("nan", False),
    ("inf", False),
    ("", False),
]
DROP_PIXEL_TEXTS = [
    ("0", True),
    ("1", True),
    ("10", True),
    ("100", True),
    ("9999", None),  # every pixel of a 100 x 100 DEM but one
    ("10000", False),
    ("4194303", False),
    ("4194304", False),
    ("-1", False),
    ("1e3", False),
    ("\u0661\u0660", None),
]


def _sweeps() -> st.SearchStrategy[str]:
    """Texts for ``--sigma-sweep START:STOP:STEP``: odd numbers, a part too many or too few, steps from
    5e-324 to 1e308, sweeps of about 200 levels (each level is an inference: a third of the steps are small)."""
    level = st.floats(0.0, 0.7).map(lambda v: f"{v:.4g}")
    large = st.sampled_from(["0.05", "0.1", "0.2", "0.7", "1", "1e308"])
    small = st.sampled_from(["0.01", "0.0035", "0.00351", "0.001", "1e-12", "1e-13", "5e-324"])
    step = st.one_of(large, large, small)
    return st.one_of(
        st.builds(lambda a, b, c: f"{a}:{b}:{c}", level, level, step),
        st.builds(":".join, st.lists(st.sampled_from(SWEEP_NUMBERS), min_size=3, max_size=3)),
        st.builds(":".join, st.lists(st.sampled_from(SWEEP_NUMBERS), min_size=0, max_size=5)),
        st.text(alphabet="0123456789.:-e naif", max_size=14),
    )


def sweep_levels(spec: str) -> tuple[int, int, bool] | None:
    """The number of levels ``--sigma-sweep SPEC`` asks for, as (fewest, most) where STOP's inclusion is a
    matter of rounding (levels START + k STEP <= STOP, within 1e-9 m), and whether SPEC writes numbers
    other than plainly (other digits, underscores: hd may accept them, read as float() does, or refuse);
    None: no sweep (not three numbers, START or STOP outside [0, 0.7] m, STEP not positive and finite,
    STOP below START, more than 200 levels)."""
    parts = spec.split(":")
    if len(parts) != 3:
        return None
    try:
        start, stop, step = (float(p) for p in parts)
    except ValueError:
        return None
    if not all(math.isfinite(v) for v in (start, stop, step)) or step <= 0:
        return None
    if not (0.0 <= start <= 0.7 and 0.0 <= stop <= 0.7 and start <= stop):
        return None
    fewest = math.floor((stop - start - 1e-9) / step) + 1 if stop - start > 1e-9 else 1
    most = math.floor((stop - start + 1e-9) / step) + 1
    if fewest > 200:
        return None
    plain = spec.isascii() and "_" not in spec
    return fewest, most, not plain


def test_fuzzed_eval_sweeps(labelled, trained, scratch):
    """hd eval --sigma-sweep SPEC (with odd --threshold, --nav-sigma and --drop-pixels values): report.json
    with the levels SPEC names, or a one-line error."""

    @fuzz_settings(examples("sweep/eval"))
    @given(
        _sweeps(),
        st.one_of(st.none(), st.none(), st.sampled_from(THRESHOLD_TEXTS)),
        st.one_of(st.none(), st.none(), st.lists(st.sampled_from(NAV_SIGMA_TEXTS), min_size=1, max_size=3)),
        st.one_of(st.none(), st.none(), st.none(), st.sampled_from(DROP_PIXEL_TEXTS)),
    )
    def example(spec, threshold, nav_sigmas, drop_pixels):
        work = fresh(scratch)
        args: list[Any] = ["eval", trained, "--data", labelled, "--out", work / "report", "--mc-samples", "2"]
        args += ["--sigma-sweep", spec]
        verdicts: list[bool | None] = []
        if threshold is not None:
            args += ["--threshold", threshold[0]]
            verdicts.append(threshold[1])
        for text, verdict in nav_sigmas or ():
            args += ["--nav-sigma", text]
            verdicts.append(verdict)
        if drop_pixels is not None:
            args += ["--drop-pixels", drop_pixels[0]]
            verdicts.append(drop_pixels[1])
        levels = sweep_levels(spec)
        verdicts.append(False if levels is None else None if levels[2] or levels[1] > 200 else True)

        def accept(outcome: Outcome) -> str | None:
            path = work / "report" / "report.json"
            if not path.is_file():
                return "exit 0 without report.json"
            got = json.loads(path.read_text())["run"]["sigma_sweep_m"]
            if levels is None or not levels[0] <= len(got) <= levels[1]:
                return f"{len(got)} sweep levels, the spec names {levels}"
            if len(set(got)) != len(got):
                return f"the sweep's levels repeat: {got[:4]}..."
            return None

        check(
            "sweep/eval",
            args,
            (spec, threshold, nav_sigmas, drop_pixels),
            must_fail=False in verdicts,
            must_pass=all(v is True for v in verdicts),
            timeout_s=TIMEOUT_S["eval"],
            roots=(work,),
            accept=accept,
        )
        shutil.rmtree(work, ignore_errors=True)

    example()


# ------------------------------------------------------------------------------------- recipes by name
PUBLISHED = sorted(p.parent.name for p in (REPO / "datasets").glob("*/recipe.toml"))
# Entries of the directory the commands run in: the dataset's own recipe (a directory, copies, links, one
# that shadows a published name), and things that are not recipes.
OWN_RECIPES = ["fuzz-own", "own-link", "\u00fcn\u00efc\u00f8d\u00e9-own", "mars-landing"]
NOT_RECIPES = ["notes.txt", "data.json", "binary.bin", "empty-dir", "not-a-recipe", "fifo-recipe", "loop", "dangling"]
NAME_SHAPES = [
    "as is",
    "as is",
    "as is",
    "upper",
    "trailing slash",
    "recipe.toml",
    "dot slash",
    "dot dot",
    "through dot dot",
    "absolute",
    "double slash",
    "trailing dot",
    "one more",
    "one less",
    "space",
    "long",
]


@pytest.fixture(scope="module")
def recipe_place(labelled, scratch) -> Path:
    """A directory to run in, holding the recipe of ``labelled`` (under several names) and files that are not
    recipes."""
    place = scratch / "recipe-place"
    own = place / "fuzz-own"
    own.mkdir(parents=True)
    (own / "recipe.toml").write_text(to_toml(RECIPE))
    published = published_checksums(labelled)
    (own / "checksums.json").write_text(json.dumps(published, indent=1))
    (place / "own-link").symlink_to(own)
    shutil.copytree(own, place / OWN_RECIPES[2])
    shutil.copytree(own, place / "mars-landing")  # the current directory comes before the published recipes
    for name in ("recipe.toml", "checksums.json"):  # "." names the current directory's recipe
        shutil.copy(own / name, place / name)
    (place / "notes.txt").write_text("not a recipe\n")
    (place / "data.json").write_text('{"build": {}}')
    (place / "binary.bin").write_bytes(bytes(range(256)))
    (place / "empty-dir").mkdir()
    (place / "not-a-recipe").mkdir()
    (place / "not-a-recipe" / "recipe.toml").write_text("[build\nscans = ")
    (place / "fifo-recipe").mkdir()
    os.mkfifo(place / "fifo-recipe" / "recipe.toml")
    (place / "loop").symlink_to(place / "loop")
    (place / "dangling").symlink_to(place / "nowhere")
    result = invoke("verify", labelled, "--recipe", own)
    assert result.exit_code == 0, result.output
    return place


def _shaped(name: str, shape: str, place: Path) -> str:
    """``name`` written another way."""
    return {
        "as is": name,
        "upper": name.upper(),
        "trailing slash": name + "/",
        "recipe.toml": name + "/recipe.toml",
        "dot slash": "./" + name,
        "dot dot": "../" + name,
        "through dot dot": f"empty-dir/../{name}",
        "absolute": str(place / name),
        "double slash": name.replace("-", "-/") if "-" in name else "/" + name,
        "trailing dot": name + ".",
        "one more": name + "x",
        "one less": name[:-1],
        "space": " " + name,
        "long": (name + "/") * 60 if len(name) < 5 else name * 60,
    }[shape]


LONG_AND_ODD_NAMES = ["", "x" * 300, "\u00e9" * 200, "a/" * 200, "/etc/passwd", "/dev/null", "/proc/self/status"]


def _recipe_names() -> st.SearchStrategy[tuple[str, str]]:
    base = st.sampled_from([*PUBLISHED, *PUBLISHED, *OWN_RECIPES, *NOT_RECIPES, ".", "..", "/", "~", "-", "recipe"])
    texts = st.text(st.characters(exclude_characters="\x00", exclude_categories=["Cs"]), max_size=20)
    return st.one_of(
        st.tuples(base, st.sampled_from(NAME_SHAPES)),
        st.tuples(st.one_of(texts, st.sampled_from(LONG_AND_ODD_NAMES)), st.just("as is")),
    )


def recipe_file(name: str, place: Path) -> Path | None:
    """The recipe file a name leads to, run in ``place``: a ``recipe.toml`` or its directory (relative to
    ``place`` or absolute), else a bare name's directory under the published ``datasets/`` (None: none; an
    empty name names nothing, though pathlib reads it as ".")."""
    if not name:
        return None
    given = Path(name)
    candidates = [place / given]
    if len(given.parts) == 1 and given.name not in (".", ".."):
        candidates.append(REPO / "datasets" / given)
    for candidate in candidates:
        try:
            file = candidate / "recipe.toml" if os.path.isdir(candidate) else candidate
            if os.path.isfile(file):
                return Path(os.path.realpath(file))
        except (OSError, ValueError):
            continue
    return None


def test_fuzzed_recipe_names(labelled, recipe_place, scratch, monkeypatch):
    """hd verify DATA --recipe NAME: NAME that leads to the dataset's own recipe is accepted; any other
    (a published recipe, a file that is no recipe, no file at all) is refused in one line."""
    monkeypatch.chdir(recipe_place)
    monkeypatch.delenv("HD_RECIPE_PATH", raising=False)
    own = {Path(os.path.realpath(recipe_place / n / "recipe.toml")) for n in OWN_RECIPES}
    own.add(Path(os.path.realpath(recipe_place / "recipe.toml")))

    @fuzz_settings(examples("recipe-name/verify"))
    @given(_recipe_names())
    def example(drawn):
        name = _shaped(drawn[0], drawn[1], recipe_place)
        file = recipe_file(name, recipe_place)
        check(
            "recipe-name/verify",
            ["verify", labelled, "--recipe", name],
            (drawn, name),
            must_fail=file not in own,
            must_pass=file in own,
            timeout_s=TIMEOUT_S["verify"],
            roots=(recipe_place,),
        )

    example()


# ------------------------------------------------------------------------------------- hd train --also
ALSO_NAMES = [
    "self",
    "link-self",
    "copy-self",
    "other",
    "link-other",
    "ünïcødé-other",
    "missing",
    "file",
    "fifo",
    "empty-dir",
]
# The dataset each name is (equal names: the same data); None: no dataset.
ALSO_IDENTITY = {
    "self": "self",
    "link-self": "self",
    "copy-self": "self",
    "other": "other",
    "link-other": "other",
    ALSO_NAMES[5]: "other",
}


@pytest.fixture(scope="module")
def mix_place(labelled, scratch) -> Path:
    """Names for ``--also``: the training data itself, a link to it and a copy of it, another dataset (a
    smaller build of another seed, labelled the same way) under three names, and things that are no dataset."""
    place = scratch / "mix-place"
    place.mkdir()
    other = place / "other"
    args = [*BUILD_ARGS]
    args[args.index("--scans") + 1] = "4"
    args[args.index("--seed") + 1] = "4"
    built = invoke("build-dataset", "--out", other, "--dtm", hills(scratch / "other.tif"), "--workers", "1", *args)
    assert built.exit_code == 0, built.output
    assert invoke("label", other, "--workers", "1").exit_code == 0
    (place / "link-self").symlink_to(labelled)
    shutil.copytree(labelled, place / "copy-self")
    (place / "link-other").symlink_to(other)
    shutil.copytree(other, place / ALSO_NAMES[5])
    (place / "file").write_text("not a dataset\n")
    os.mkfifo(place / "fifo")
    (place / "empty-dir").mkdir()
    return place


def test_fuzzed_training_mixes(labelled, mix_place, scratch):
    """hd train DATA --also X [--also Y]: a mix of distinct datasets trains; a mix that names the same data
    twice (the data itself, a link or a byte-identical copy of it, one dataset twice) or no dataset is refused."""
    data = labelled  # "self" names this very path

    @fuzz_settings(examples("also/train"))
    @given(st.lists(st.sampled_from(ALSO_NAMES), min_size=1, max_size=2))
    def example(names):
        work = fresh(scratch)
        args: list[Any] = ["train", data, "--out", work / "run", "--profile", "tiny", "--epochs", "1"]
        for name in names:
            args += ["--also", data if name == "self" else mix_place / name]
        identities = ["self", *(ALSO_IDENTITY.get(n) for n in names)]
        refused = None in identities or len(set(identities)) < len(identities)

        def accept(outcome: Outcome) -> str | None:
            if not (work / "run" / "last.pt").is_file():
                return "exit 0 without last.pt"
            also = json.loads((work / "run" / "config.json").read_text())["extra_config"].get("also", [])
            return None if len(also) == len(names) else f"config.json records {len(also)} --also datasets"

        check(
            "also/train",
            args,
            names,
            must_fail=refused,
            must_pass=not refused,
            timeout_s=TIMEOUT_S["train"],
            roots=(work,),
            accept=accept,
        )
        shutil.rmtree(work, ignore_errors=True)

    example()


def test_the_campaign_sizes_are_documented():
    """docs/reliability.md states the long campaign's command; the module's targets stay in step with it."""
    text = (REPO / "docs" / "reliability.md").read_text()
    assert "HD_FUZZ_CAMPAIGN=long" in text and "test_i_fuzz.py" in text


# ------------------------------------------------------------------------------------- regressions
# Each violation the campaign found, as a plain case: the mutation that broke the invariant, fixed at its root.
def _edit_manifest(data: Path, path: tuple[Any, ...], value: Any) -> None:
    """Set the manifest's value at ``path`` (delete it when ``value`` is ``...``)."""
    m = json.loads((data / "manifest.json").read_text())
    parent = m
    for key in path[:-1]:
        parent = parent[key]
    if value is ...:
        del parent[path[-1]]
    else:
        parent[path[-1]] = value
    (data / "manifest.json").write_text(json.dumps(m))


@pytest.mark.parametrize(
    ("path", "value"),
    [
        (("dtm",), []),
        (("splits",), ...),
        (("seed",), ...),
        (("dtm", "spacing_m"), ["1", None]),
        (("dtm", "crs_wkt"), 5),
    ],
)
def test_inspect_summarises_a_manifest_whose_informative_entries_are_odd(data_copy, path, value):
    """dtm = [] gave AttributeError: 'list' object has no attribute 'get' (a traceback)."""
    _edit_manifest(data_copy, path, value)
    result = invoke("inspect", data_copy)
    assert result.exit_code == 0 and "status    intact" in result.output, result.output


def test_a_labelling_entry_claiming_a_schema_that_is_not_a_string_is_a_problem(data_copy):
    """{"schema": {}} in a label shard entry gave TypeError: unhashable type: 'dict' in verify and inspect."""
    _edit_manifest(data_copy, ("labelings", 0, "shards", 2, "schema"), {})
    verify = invoke("verify", data_copy)
    assert verify.exit_code == 1 and "unknown schema {}" in verify.output and "Traceback" not in verify.output
    assert_one_line_error(invoke("inspect", data_copy), "damaged")


@pytest.mark.parametrize(
    ("where", "needle"),
    [
        ("weight-not-a-tensor", "not a dictionary of tensors"),
        ("optimizer-state-not-a-tensor", "optimizer or RNG state cannot be restored"),
        ("optimizer-state-shape", "optimizer or RNG state cannot be restored"),
        ("optimizer-state-missing", "optimizer or RNG state cannot be restored"),
        ("history-not-rows", "its history"),
        ("epoch-negative", "epoch -1"),
        ("profile-not-a-dict", "another model or profile"),
        ("rng-empty", "RNG states"),
    ],
)
def test_resuming_a_resealed_checkpoint_of_odd_values_is_one_line(trained, labelled, tmp_path, where, needle):
    """train --resume loaded weights, optimizer state and history without checking them (tracebacks from
    load_state_dict and from inside Adam's step), where eval and detect refused the same checkpoint."""
    run = tmp_path / "run"
    shutil.copytree(trained, run)
    ckpt = torch.load(run / "last.pt", weights_only=True)
    state = ckpt["optimizer"]["state"]
    if where == "weight-not-a-tensor":
        ckpt["model"][next(iter(ckpt["model"]))] = 138
    elif where == "optimizer-state-not-a-tensor":
        state[next(iter(state))]["exp_avg_sq"] = []
    elif where == "optimizer-state-shape":
        state[next(iter(state))]["exp_avg"] = torch.zeros(3)
    elif where == "optimizer-state-missing":
        del state[list(state)[-1]]["exp_avg"]
    elif where == "history-not-rows":
        ckpt["history"] = [{"epoch": 1, "val_loss": "low"}]
    elif where == "epoch-negative":
        ckpt["epoch"] = -1
    elif where == "profile-not-a-dict":
        ckpt["profile"] = "tiny"
    else:
        ckpt["rng"] = []
    ckpt["content_sha256"] = checkpoint_digest({k: v for k, v in ckpt.items() if k != "content_sha256"})
    torch.save(ckpt, run / "last.pt")
    result = invoke("train", labelled, "--out", run, "--profile", "tiny", "--epochs", "2", "--resume")
    assert_one_line_error(result, "last.pt", needle)


@pytest.mark.parametrize(
    ("damage", "needle"),
    [
        ("section-not-a-table", "[build] must be a table"),
        ("not-utf8", "not a valid TOML recipe"),
        ("checksums-entry-without-sha256", "shards[0] must give"),
        ("checksums-an-array", "not a JSON object"),
        ("checksums-not-utf8", "unreadable checksums"),
    ],
)
def test_recipes_and_their_checksums_of_odd_layout_are_one_line(labelled, tmp_path, damage, needle):
    """build = "" gave AttributeError: 'str' object has no attribute 'items'; bytes that are not UTF-8 a
    UnicodeDecodeError; a checksums.json entry without its sha256 a KeyError (all tracebacks)."""
    recipe = tmp_path / "recipe"
    recipe.mkdir()
    tree = copy.deepcopy(RECIPE)
    checksums: Any = {"config_sha256": "0" * 64, "shards": [{"path": "shards/scans-00000.h5", "sha256": "0" * 64}]}
    if damage == "section-not-a-table":
        tree["build"] = ""  # type: ignore[assignment]  # the damage: a string where a table belongs
    elif damage == "checksums-entry-without-sha256":
        del checksums["shards"][0]["sha256"]
    elif damage == "checksums-an-array":
        checksums = [checksums]
    (recipe / "recipe.toml").write_text(to_toml(tree))
    (recipe / "checksums.json").write_text(json.dumps(checksums))
    if damage == "not-utf8":
        (recipe / "recipe.toml").write_bytes(b"\xa4" + (recipe / "recipe.toml").read_bytes())
    if damage == "checksums-not-utf8":
        (recipe / "checksums.json").write_bytes(b"\xff\xfe{}")
    assert_one_line_error(invoke("verify", labelled, "--recipe", recipe), needle)
    if damage in ("section-not-a-table", "not-utf8"):
        assert_one_line_error(invoke("label", labelled, "--workers", "1", "--recipe", recipe), needle)


@pytest.mark.parametrize(
    ("path", "value"),
    [(("dem", "rows"), [-math.inf]), (("dem", "spacing_m"), {}), (("dem",), "64x64"), (("lander", "diameter_m"), [])],
)
@pytest.mark.parametrize("name", ["train", "eval"])
def test_a_labelling_entry_whose_grid_or_lander_is_odd_is_one_line(data_copy, trained, tmp_path, path, value, name):
    """labelings[0].dem.rows = [-inf] gave TypeError: int() argument must be ... not 'list' deep inside hd train."""
    _edit_manifest(data_copy, ("labelings", 0, *path), value)
    result = invoke(*command(name, data_copy, tmp_path, trained))
    assert_one_line_error(result, "labelling", "dem|lander")


def test_points_a_huge_distance_away_are_labelled_within_the_bound(data_copy):
    """points_clean with every other value 1e30 (sealed): hd label looped for ever - int(floor(1e30)) in the
    compiled triangle filler overflowed int64, undefined behaviour that became an endless loop."""
    apply_h5(data_copy / "shards" / "scans-00000.h5", H5Edit("ds-values", "points_clean", 1e30))
    reseal(data_copy)
    outcome = check("regression/label", command("label", data_copy, data_copy), "1e30 points", timeout_s=60)
    assert outcome.exit_code is not None and not outcome.timed_out


@pytest.mark.parametrize(
    ("rel", "edit", "name"),
    [
        ("shards/scans-00001.h5", H5Edit("ds-shape", "split", "empty"), "label"),
        ("shards/scans-00001.h5", H5Edit("ds-shape", "points_noisy", "drop-axis"), "label"),
        ("shards/scans-00001.h5", H5Edit("ds-dtype", "points_clean", "complex64"), "label"),
        (LABEL_SHARD, H5Edit("ds-shape", "scan_index", "drop-row"), "train"),
        (LABEL_SHARD, H5Edit("ds-shape", "dem_noisy", "grow-last"), "train"),
        (LABEL_SHARD, H5Edit("ds-delete", "p_safe"), "eval"),
        (LABEL_SHARD, H5Edit("ds-shape", "scan_index", "scalar"), "eval"),
    ],
)
def test_a_sealed_shard_whose_arrays_do_not_fit_together_is_refused_when_opened(
    data_copy, trained, tmp_path, rel, edit, name
):
    """An emptied split array gave IndexError in hd label, a scan_index one row short IndexError in hd train
    (tracebacks): the readers now check every array's rank and sizes against the others when they open a file."""
    path = next(data_copy.glob(rel))
    apply_h5(path, edit)
    reseal(data_copy)
    line = assert_one_line_error(invoke(*command(name, data_copy, tmp_path, trained)), path.name)
    assert edit.target in line or "shape" in line, line
