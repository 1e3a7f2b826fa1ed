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
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from lidarsim.shards import MANIFEST_NAME, read_manifest
from lidarsim.storage import sha256_file

CROISSANT_FILE = "croissant.json"
CONFORMS_TO = "http://mlcommons.org/croissant/1.0"
HDF5_FORMAT = "application/x-hdf5"
# The JSON-LD context of Croissant 1.0 (the specification's, section "Dataset-level information").
CONTEXT: dict[str, Any] = {
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


def _fields(path: Path, set_id: str, file_set: str) -> list[dict[str, Any]]:
    """One field per array of the HDF5 file at ``path`` (its rows are the scans)."""
    fields = []
    with h5py.File(path, "r") as f:
        for name in sorted(f):
            ds = f[name]
            if not isinstance(ds, h5py.Dataset) or not ds.shape:
                continue
            shape = " x ".join(str(n) for n in ds.shape[1:]) or "a scalar"
            fields.append(
                {
                    "@type": "cr:Field",
                    "@id": f"{set_id}/{name}",
                    "name": name,
                    "description": f"HDF5 dataset {name!r}, {ds.dtype} per scan: {shape} (docs/shard-format.md)",
                    "dataType": _data_type(ds.dtype),
                    "source": {"fileSet": {"@id": file_set}, "extract": {"column": name}},
                }
            )
    return fields


def _file_object(directory: Path, rel: str, sha256: str | None = None) -> dict[str, Any]:
    path = directory / rel
    return {
        "@type": "cr:FileObject",
        "@id": rel,
        "name": rel,
        "contentUrl": rel,
        "contentSize": f"{path.stat().st_size} B",
        "encodingFormat": "application/json" if rel.endswith(".json") else HDF5_FORMAT,
        "sha256": sha256 if sha256 is not None else sha256_file(path),
    }


def croissant_metadata(
    directory: str | os.PathLike, name: str, description: str, version: int, licence: str, citation: str
) -> dict[str, Any]:
    """The Croissant 1.0 record of the dataset at ``directory`` (see the module docstring).

    Args:
        name, description, version: the recipe's ``[dataset]``.
        licence: the data's licence, as the card states it.
        citation: how to cite the work the dataset reproduces.
    """
    root = Path(directory)
    m = read_manifest(root)
    cfg = m.get("config", {})
    sensor = cfg.get("sensor", {}) if isinstance(cfg, dict) else {}
    dtm = m.get("dtm", {})
    terrain = "hd's procedural Mars terrain" if not cfg.get("dtm_path") else f"the DTM {dtm.get('name', '?')}"
    distribution: list[dict[str, Any]] = [_file_object(root, MANIFEST_NAME)]
    distribution += [_file_object(root, e["path"], e["sha256"]) for e in m["shards"]]
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
    record_sets: list[dict[str, Any]] = []
    if m["shards"]:
        record_sets.append(
            {
                "@type": "cr:RecordSet",
                "@id": "scans",
                "name": "scans",
                "description": "One record per scan: the rows of the scan shards' arrays.",
                "field": _fields(root / m["shards"][0]["path"], "scans", "scan-shards"),
            }
        )
    for k, lab in enumerate(m.get("labelings", [])):
        set_id = f"labels-{k}"
        distribution += [_file_object(root, e["path"], e["sha256"]) for e in lab["shards"]]
        distribution.append(
            {
                "@type": "cr:FileSet",
                "@id": f"{set_id}-shards",
                "name": f"{set_id}-shards",
                "description": f"The label shards of the labelling {lab['name']} (HDF5, schema {lab.get('schema')}).",
                "encodingFormat": HDF5_FORMAT,
                "includes": f"labels/{lab['name']}/*.h5",
            }
        )
        if lab["shards"]:
            record_sets.append(
                {
                    "@type": "cr:RecordSet",
                    "@id": set_id,
                    "name": set_id,
                    "description": f"One record per scan: DEMs and labels of the labelling {lab['name']}.",
                    "field": _fields(root / lab["shards"][0]["path"], set_id, f"{set_id}-shards"),
                }
            )
    sigmas = ", ".join(f"{s:g}" for s in m["sigmas_m"])
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
