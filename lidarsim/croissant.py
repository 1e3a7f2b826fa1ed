"""``croissant.json``: a dataset described in MLCommons Croissant 1.0 (JSON-LD), written by ``hd card``.

What a catalogue reads without hd: the dataset's name, description, version, licence and citation;
the responsible-AI fields that apply (``rai:dataCollection``: how the data was made,
``rai:dataLimitations``, ``rai:dataBiases``, ``rai:personalSensitiveInformation``,
``rai:dataUseCases``); every file (``distribution``: the manifest and each shard as a
``cr:FileObject`` with its sha256 and size, relative to the dataset's root); and the shards' arrays
as record sets (``scans`` from the scan shards, one per labelling from its label shards), each
field named after its HDF5 dataset (``extract.column``), with its type and its shape per scan in
the description. The fields are read from the first shard of each kind, so they are the arrays
the files hold. Validated with the ``mlcroissant`` library in the tests.

The document is written as JSON-LD nodes, each a :data:`JsonLdNode` (a ``dict``: JSON-LD is the
file format, its keys are Croissant's and schema.org's terms, ``@type``, ``@id`` and the like); the
manifest's records read here (the build settings, published checksums) are not nodes.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from hdcore.storage import sha256_file
from lidarsim.manifest_json import BuildConfigJson
from lidarsim.shards import MANIFEST_NAME, read_manifest

# One JSON-LD node of the document being written (the file format itself, see the module docstring).
JsonLdNode = dict[str, Any]

CROISSANT_FILE = "croissant.json"
CONFORMS_TO = "http://mlcommons.org/croissant/1.0"
HDF5_FORMAT = "application/x-hdf5"
# The JSON-LD context of Croissant 1.0 (the specification's, section "Dataset-level information").
CONTEXT: JsonLdNode = {
    "@language": "en",
    "@vocab": "https://schema.org/",
    "citeAs": "cr:citeAs",
    "column": "cr:column",
    "conformsTo": "dct:conformsTo",
    "cr": "http://mlcommons.org/croissant/",
    "rai": "http://mlcommons.org/croissant/RAI/",
    "data": {"@id": "cr:data", "@type": "@json"},
    "dataType": {"@id": "cr:dataType", "@type": "@vocab"},
    "dct": "http://purl.org/dc/terms/",
    "examples": {"@id": "cr:examples", "@type": "@json"},
    "extract": "cr:extract",
    "field": "cr:field",
    "fileProperty": "cr:fileProperty",
    "fileObject": "cr:fileObject",
    "fileSet": "cr:fileSet",
    "format": "cr:format",
    "includes": "cr:includes",
    "isLiveDataset": "cr:isLiveDataset",
    "jsonPath": "cr:jsonPath",
    "key": "cr:key",
    "md5": "cr:md5",
    "parentField": "cr:parentField",
    "path": "cr:path",
    "recordSet": "cr:recordSet",
    "references": "cr:references",
    "regex": "cr:regex",
    "repeated": "cr:repeated",
    "replace": "cr:replace",
    "sc": "https://schema.org/",
    "separator": "cr:separator",
    "source": "cr:source",
    "subField": "cr:subField",
    "transform": "cr:transform",
}
HD_URL = "https://github.com/hd-lidar/hd"  # hd's home, named as the dataset's creator tool
DATA_COLLECTION = (
    "Simulated, not measured: hd (lidarsim) casts the rays of a flash LiDAR ({rows} x {cols} detector, "
    "{fov} deg field of view) at {terrain} along a seeded trajectory and adds Gaussian range noise at "
    "sigma {sigmas} m; labels are the ALHAT slope and roughness rule applied to gridded DEMs (hdlabels). "
    "Every setting is in manifest.json; the recipe and hd version rebuild the same bytes."
)
DATA_LIMITATIONS = (
    "A simulation: one range-noise model (Gaussian, per ray), no motion blur, no atmosphere, no "
    "multi-return; terrain detail is limited by the DTM's resolution; labels are a geometric rule, not "
    "observed landing outcomes. Held-out splits may share terrain with training scans (hd inspect says "
    "how much)."
)
DATA_BIASES = (
    "Scans cover only the terrain and trajectory of the recipe; the safe/unsafe balance follows that "
    "terrain (the class counts are in manifest.json)."
)
USE_CASES = (
    "Training and evaluating hazard-detection networks for planetary landing (Bayesian SegNet, "
    "uncertainty-aware maps); studying robustness to range noise. Not validated for flight use."
)


def _data_type(dtype: np.dtype) -> str:
    if dtype.kind == "b":
        return "sc:Boolean"
    if dtype.kind in "iu":
        return "sc:Integer"
    if dtype.kind == "f":
        return "sc:Float"
    return "sc:Text"


Arrays = dict[str, tuple[str, tuple[int, ...]]]  # HDF5 dataset name -> (numpy dtype name, shape)


def _arrays(path: Path) -> Arrays:
    """The arrays (non-scalar datasets) of the HDF5 file at ``path``."""
    with h5py.File(path, "r") as f:
        return {n: (str(f[n].dtype), tuple(f[n].shape)) for n in f if isinstance(f[n], h5py.Dataset) and f[n].shape}


def _fields(arrays: Arrays, set_id: str, file_set: str) -> list[JsonLdNode]:
    """One field per array of a shard (its rows are the scans)."""
    fields = []
    for name in sorted(arrays):
        dtype, full = arrays[name]
        shape = " x ".join(str(n) for n in full[1:]) or "a scalar"
        fields.append(
            {
                "@type": "cr:Field",
                "@id": f"{set_id}/{name}",
                "name": name,
                "description": f"HDF5 dataset {name!r}, {dtype} per scan: {shape} (docs/shard-format.md)",
                "dataType": _data_type(np.dtype(dtype)),
                "source": {"fileSet": {"@id": file_set}, "extract": {"column": name}},
            }
        )
    return fields


def _file_entry(rel: str, sha256: str, size: int | None) -> JsonLdNode:
    entry: JsonLdNode = {"@type": "cr:FileObject", "@id": rel, "name": rel, "contentUrl": rel}
    if size is not None:
        entry["contentSize"] = f"{size} B"
    entry["encodingFormat"] = "application/json" if rel.endswith(".json") else HDF5_FORMAT
    entry["sha256"] = sha256
    return entry


def _file_object(directory: Path, rel: str, sha256: str | None = None) -> JsonLdNode:
    path = directory / rel
    return _file_entry(rel, sha256 if sha256 is not None else sha256_file(path), path.stat().st_size)


@dataclass(frozen=True)
class Described:
    """What a croissant.json says of a dataset's files and build.

    Attributes:
        manifest: the manifest's file object (None: not listed).
        shards: the scan shards' file objects; ``shard_arrays`` the arrays of the first one.
        labelings: per labelling, (name, label schema, file objects, arrays of the first shard).
        config: the build settings (``BuildConfig.to_dict``); ``sigmas_m`` the noise levels, metres;
        dtm_name: the DTM's file name.
    """

    manifest: JsonLdNode | None
    shards: list[JsonLdNode]
    shard_arrays: Arrays | None
    labelings: list[tuple[str, str | None, list[JsonLdNode], Arrays | None]]
    config: BuildConfigJson | None  # None: a manifest that records none
    sigmas_m: list[float]
    dtm_name: str


def croissant_metadata(
    directory: str | os.PathLike, name: str, description: str, version: int, licence: str, citation: str
) -> JsonLdNode:
    """The Croissant 1.0 record of the dataset at ``directory`` (see the module docstring).

    Args:
        name, description, version: the recipe's ``[dataset]``.
        licence: the data's licence, as the card states it.
        citation: how to cite the work the dataset reproduces.
    """
    root = Path(directory)
    m = read_manifest(root)
    described = Described(
        manifest=_file_object(root, MANIFEST_NAME),
        shards=[_file_object(root, e["path"], e["sha256"]) for e in m["shards"]],
        shard_arrays=_arrays(root / m["shards"][0]["path"]) if m["shards"] else None,
        labelings=[
            (
                lab["name"],
                lab.get("schema"),
                [_file_object(root, e["path"], e["sha256"]) for e in lab["shards"]],
                _arrays(root / lab["shards"][0]["path"]) if lab["shards"] else None,
            )
            for lab in m.get("labelings", [])
        ],
        config=m.get("config"),
        sigmas_m=list(m["sigmas_m"]),
        dtm_name=str(m.get("dtm", {}).get("name", "?")),
    )
    return _metadata(described, name, description, version, licence, citation)


def recipe_croissant(recipe_dir: str | os.PathLike, licence: str, citation: str) -> JsonLdNode:
    """The Croissant 1.0 record of a published recipe's dataset, from its ``recipe.toml`` and
    ``checksums.json`` alone (no build): every shard with its sha256, the arrays as the content
    fingerprints record them (name, dtype, shape). The checksums hold no file sizes and no manifest
    (which is written anew by each build), so the files have no ``contentSize`` and ``manifest.json``
    is not listed; :func:`croissant_metadata` of the built dataset has both.

    Raises:
        RecipeError: no recipe or no checksums.json there, or checksums.json unreadable.
    """
    import json

    from lidarsim.errors import RecipeError
    from lidarsim.recipe import CHECKSUMS_FILE, load_recipe

    recipe = load_recipe(recipe_dir)
    path = recipe.path.parent / CHECKSUMS_FILE
    try:
        sums = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise RecipeError(f"{path}: cannot read the published checksums ({exc})") from exc

    def arrays(entries: list[dict[str, Any]]) -> Arrays | None:
        if not entries:
            return None
        found = entries[0].get("content", {}).get("arrays", {})
        return {n: (str(a["dtype"]), tuple(int(k) for k in a["shape"])) for n, a in found.items() if a["shape"]}

    labelings = []
    for lab in sums.get("labelings", []):
        attrs = lab["shards"][0].get("content", {}).get("attrs", {}) if lab["shards"] else {}
        files = [_file_entry(e["path"], e["sha256"], None) for e in lab["shards"]]
        labelings.append((str(lab["name"]), attrs.get("schema"), files, arrays(lab["shards"])))
    config = recipe.build.to_dict()
    described = Described(
        manifest=None,
        shards=[_file_entry(e["path"], e["sha256"], None) for e in sums["shards"]],
        shard_arrays=arrays(sums["shards"]),
        labelings=labelings,
        config=config,
        sigmas_m=[float(v) for v in config["sigmas_m"]],
        dtm_name=Path(str(config.get("dtm_path") or sums.get("dtm", {}).get("path", "?"))).name,
    )
    return _metadata(described, recipe.name, recipe.description, recipe.version, licence, citation)


def _metadata(d: Described, name: str, description: str, version: int, licence: str, citation: str) -> JsonLdNode:
    """The Croissant record of what ``d`` describes."""
    cfg = d.config
    sensor: Mapping[str, object] = cfg["sensor"] if cfg is not None else {}
    terrain = "hd's procedural Mars terrain" if cfg is None or not cfg["dtm_path"] else f"the DTM {d.dtm_name}"
    distribution: list[JsonLdNode] = [d.manifest] if d.manifest is not None else []
    distribution += d.shards
    distribution.append(
        {
            "@type": "cr:FileSet",
            "@id": "scan-shards",
            "name": "scan-shards",
            "description": "The scan shards (HDF5, schema hd.scan-shard): points, poses, validity per scan.",
            "encodingFormat": HDF5_FORMAT,
            "includes": "shards/*.h5",
        }
    )
    record_sets: list[JsonLdNode] = []
    if d.shard_arrays is not None:
        record_sets.append(
            {
                "@type": "cr:RecordSet",
                "@id": "scans",
                "name": "scans",
                "description": "One record per scan: the rows of the scan shards' arrays.",
                "field": _fields(d.shard_arrays, "scans", "scan-shards"),
            }
        )
    for k, (lab_name, schema, files, lab_arrays) in enumerate(d.labelings):
        set_id = f"labels-{k}"
        distribution += files
        distribution.append(
            {
                "@type": "cr:FileSet",
                "@id": f"{set_id}-shards",
                "name": f"{set_id}-shards",
                "description": f"The label shards of the labelling {lab_name} (HDF5, schema {schema}).",
                "encodingFormat": HDF5_FORMAT,
                "includes": f"labels/{lab_name}/*.h5",
            }
        )
        if lab_arrays is not None:
            record_sets.append(
                {
                    "@type": "cr:RecordSet",
                    "@id": set_id,
                    "name": set_id,
                    "description": f"One record per scan: DEMs and labels of the labelling {lab_name}.",
                    "field": _fields(lab_arrays, set_id, f"{set_id}-shards"),
                }
            )
    sigmas = ", ".join(f"{s:g}" for s in d.sigmas_m)
    return {
        "@context": CONTEXT,
        "@type": "sc:Dataset",
        "conformsTo": CONFORMS_TO,
        "name": name,
        "description": description or f"hd dataset {name}: simulated flash-LiDAR scans of Mars terrain.",
        "version": f"{version}.0.0",
        "license": licence,
        "url": HD_URL,
        "citeAs": citation,
        "creator": {"@type": "sc:Organization", "name": "hd", "url": HD_URL},
        "keywords": ["planetary landing", "hazard detection", "lidar", "digital elevation model", "simulation"],
        "rai:dataCollection": DATA_COLLECTION.format(
            rows=sensor.get("rows", "?"),
            cols=sensor.get("cols", "?"),
            fov=sensor.get("fov_x_deg", sensor.get("fov_deg", "?")),
            terrain=terrain,
            sigmas=sigmas,
        ),
        "rai:dataCollectionType": "Simulation",
        "rai:dataLimitations": DATA_LIMITATIONS,
        "rai:dataBiases": DATA_BIASES,
        "rai:dataUseCases": USE_CASES,
        "rai:personalSensitiveInformation": "None: simulated scans of planetary terrain.",
        "distribution": distribution,
        "recordSet": record_sets,
    }
