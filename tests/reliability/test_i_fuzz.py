"""Class I: property-based fuzzing of every file hd reads, fed to the commands that read it.

Mutations (drawn by hypothesis, deterministic): manifests (keys removed, types changed, numbers
huge, negative or NaN, odd strings, raw bytes), scan and label shards (attributes, dataset shapes
and dtypes, values, stored chunk bytes, raw bytes; with the manifest's checksums updated or not),
checkpoints (state_dict keys, shapes and dtypes, config and other values, raw bytes; with the
content checksum updated or not), recipes and their published checksums, GeoTIFFs (sizes, dtypes,
nodata, cell sizes, rotations, bands, raw header bytes). The commands: ``hd verify``,
``hd inspect``, ``hd label``, ``hd train``, ``hd eval``, ``hd detect`` (and ``hd build-dataset``
on GeoTIFFs). The invariant and the runner are in ``fuzz_kit.py``: exit 0 with a correct result,
or one ``Error:`` line and a non-zero exit; never a traceback, a signal, a hang past the bound or
a damaged input accepted. The normal run draws a few examples per target (about 40 s in all on
two cores); ``HD_FUZZ_CAMPAIGN=long`` runs the long campaign (docs/reliability.md).
"""

from __future__ import annotations

import copy
import json
import math
import os
import shutil
import tempfile
import tomllib
from collections.abc import Iterator
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
    Outcome,
    TreeEdit,
    apply_bytes,
    apply_h5,
    byte_edits,
    check,
    draw_h5_edit,
    draw_tree_edits,
    fuzz_settings,
    json_values,
    reseal,
    scalars,
)
from hypothesis import given
from hypothesis import strategies as st
from rasterio.transform import Affine
from reliability_kit import REPO, assert_one_line_error, hills, invoke

from hdnet.train import checkpoint_digest
from lidarsim.shards import read_manifest

# Examples per target (family/command) in the normal run; the long campaign (HD_FUZZ_CAMPAIGN=long)
# draws about 11 600 in all, sized for about 70 minutes on one core. HD_FUZZ_SCALE multiplies either.
SHORT = {"verify": 6, "inspect": 3, "label": 3, "train": 2, "eval": 2, "detect": 2, "resume": 2, "build": 2}
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
}


# HD_FUZZ_EXAMPLES="shard/verify=1000,geotiff/build=600" sets targets' numbers (e.g. to finish a campaign).
OVERRIDES = {
    k: int(v) for k, _, v in (item.partition("=") for item in os.environ.get("HD_FUZZ_EXAMPLES", "").split(",") if item)
}


def examples(target: str) -> int:
    """The number of examples of ``target`` ("family/command") in this run, before HD_FUZZ_SCALE."""
    if target in OVERRIDES:
        return OVERRIDES[target]
    return LONG[target] if LONG_CAMPAIGN else SHORT[target.split("/")[1]]


TIMEOUT_S = {"verify": 60, "inspect": 60, "label": 120, "train": 180, "eval": 180, "detect": 120, "resume": 180}
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


@pytest.mark.parametrize("name", ["label", "verify"])
def test_mutated_recipes(name, labelled, scratch):
    manifest = read_manifest(labelled)
    published = {
        "config_sha256": manifest["config_sha256"],
        "schema": manifest["schema"],
        "schema_version": manifest["schema_version"],
        "shard_schema_version": manifest["shards"][0]["schema_version"],
        "shards": [{k: e[k] for k in LABEL_FIELDS} for e in manifest["shards"]],
    }

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
