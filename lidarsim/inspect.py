"""Human summaries of a dataset directory (``hd inspect``)."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from hdcore.outcome import counted
from hdcore.storage import FormatError, StorageError, confine, lock_holder
from lidarsim.location import dataset_key, dataset_label, is_url, remote_dataset
from lidarsim.manifest_json import ManifestJson, ShardRefJson
from lidarsim.noise import stored_kind
from lidarsim.shards import SPLIT_NAMES, open_scan_shard, read_manifest


def _size(directory: Path | str, entries: Sequence[ShardRefJson]) -> int:
    total = 0
    if isinstance(directory, str):  # a URL: the sizes its listing gives
        remote = remote_dataset(directory)
        for entry in entries:
            with contextlib.suppress(FormatError):
                total += remote.size(entry["path"]) or 0
        return total
    for entry in entries:
        try:
            path = confine(directory, entry["path"])
            total += path.stat().st_size if path.is_file() else 0
        except (FormatError, OSError):
            pass
    return total


def _first_scan_lines(directory: Path | str, manifest: ManifestJson) -> list[str]:
    """Step 1 of :func:`describe_dataset`: the lines read from the first shard (mosaic, sensor, descents,
    realism, the first scan's returns and height range in m), or one line saying why it cannot be read."""
    shards = manifest["shards"]
    lines: list[str] = []
    if not shards:
        return lines
    try:
        with open_scan_shard(directory, shards[0]) as reader:
            a = reader.attrs
            if reader.is_mosaic:
                lines.append(_mosaic_line(a, _mapping(manifest.get("mosaic"))))
            pose = (
                "altitude and tilt: the descents' (below)"
                if "descent_frames" in a
                else f"altitude {_span(a, 'trajectory_altitude')}, tilt {_span(a, 'trajectory_tilt')}"
            )
            if not reader.is_mosaic:
                lines.append(
                    f"sensor    {a.get('sensor_rows')} x {a.get('sensor_cols')} px, "
                    f"FOV {a.get('sensor_fov_x_deg')} x {a.get('sensor_fov_y_deg')} deg, {pose}, "
                    f"jitter {_span(a, 'trajectory_jitter')}"
                )
            lines += _descent_lines(a, manifest.get("n_descents"))
            realism = _realism(a)
            if realism:
                lines.append(f"realism   {realism}")
            if len(reader):
                scan = reader[0]
                valid = float(np.mean(scan.valid))
                z = scan.points_clean[..., 2]
                lines.append(
                    f"scan 0    {valid * 100:.1f}% returns, "
                    f"height range {np.nanmin(z):.2f} .. {np.nanmax(z):.2f} m "
                    f"(scan frame), origin E {scan.origin_map[0]:.1f} N {scan.origin_map[1]:.1f} m"
                )
    except (FormatError, StorageError) as exc:
        lines.append(f"sensor    unknown: the first shard cannot be read ({exc})")
    except (IndexError, ValueError, TypeError) as exc:  # arrays of other shapes or types than hd writes
        lines.append(f"sensor    unknown: the first scan of {shards[0]['path']} is not as hd writes it ({exc})")
    return lines


def _labeling_lines(directory: Path | str, manifest: ManifestJson) -> list[str]:
    """Step 2 of :func:`describe_dataset`: one line per labelling (finished, then unfinished ones found
    on disk) and one for a process writing the dataset now (neither looked for at a URL)."""
    labelings = manifest.get("labelings", [])
    lines: list[str] = []
    for lab in labelings:
        frac = lab.get("safe_fraction")
        frac_txt = f", {frac * 100:.1f}% of labelled pixels safe" if isinstance(frac, float) else ""
        truth = "terrain (the DTM on each scan's DEM grid)" if lab.get("truth") == "terrain" else "clean scan"
        lines.append(
            f"labels    {lab.get('name')}: {len(lab.get('shards', []))} label shards{frac_txt}; truth: {truth}"
        )
    if not labelings:
        lines.append("labels    none (run `hd label`)")
    listed = {lab.get("name") for lab in labelings}
    if isinstance(directory, str):  # a URL: no unfinished labelling or writer is looked for there
        return lines
    labels_dir = directory / "labels"
    if labels_dir.is_dir():
        for d in sorted(labels_dir.iterdir()):
            if d.is_dir() and d.name not in listed:
                n = len(list(d.glob("labels-*.h5")))
                lines.append(
                    f"labels    {d.name}: unfinished ({n} label shards written); re-run the same `hd label` "
                    "command to finish it"
                )
    holder = lock_holder(directory)
    if holder is not None:
        lines.append(f"writing   another hd process (PID {holder}) is writing this dataset now")
    return lines


def describe_dataset(directory: str | os.PathLike) -> str:
    """A multi-line summary of a dataset: size, splits, noise levels, sensor, DTM, labelings.

    Reads the manifest and the first scan of the first shard (checked against its sha256) only;
    ``hd inspect`` adds the checks of every file (``verify_dataset``).

    Raises:
        ShardFormatError: not an hd dataset (an unfinished build is named as such), a malformed
            manifest, or a schema version this hd does not read.
    """
    directory = str(directory).rstrip("/") if is_url(directory) else Path(directory)
    manifest = read_manifest(directory)
    shards = manifest["shards"]
    size = _size(directory, shards)
    lines = [
        f"dataset   {dataset_label(directory)}",
        (
            f"schema    {manifest['schema']} {manifest['schema_version']} "
            f"(software {manifest.get('software_version', '?')})"
        ),
        f"scans     {manifest['n_scans']}{_descents(manifest)} in {counted(len(shards), 'shard')}, {size / 1e6:.1f} MB",
        "splits    " + ", ".join(f"{_mapping(manifest.get('splits')).get(k, '?')} {k}" for k in SPLIT_NAMES),
        "sigma     " + ", ".join(f"{s:g} m" for s in manifest["sigmas_m"]),
        f"seed      {manifest.get('seed', '?')}",
    ]
    dtm = _mapping(manifest.get("dtm"))
    lines.append(
        f"terrain   {dtm.get('name', '?')} ({dtm.get('rows', '?')} x {dtm.get('cols', '?')} cells, "
        f"{_fmt_spacing(dtm.get('spacing_m'))} m/px, scale {dtm.get('scale', '?')}, "
        f"CRS {'none (local metres)' if not dtm.get('crs_wkt') else _short_crs(str(dtm['crs_wkt']))}, "
        f"sha256 {str(dtm.get('sha256', ''))[:12]}...)"
    )
    lines += _first_scan_lines(directory, manifest)
    lines += _labeling_lines(directory, manifest)
    return "\n".join(lines)


def dataset_record(directory: str | os.PathLike) -> dict[str, object]:
    """A JSON-ready summary of a dataset (``hd inspect --json``): what :func:`describe_dataset` prints,
    from the manifest alone.

    Raises:
        ShardFormatError: as :func:`describe_dataset`.
    """
    directory = str(directory).rstrip("/") if is_url(directory) else Path(directory)
    manifest = read_manifest(directory)
    shards = manifest["shards"]
    dtm = _mapping(manifest.get("dtm"))
    record: dict[str, object] = {
        "dataset": dataset_key(directory),
        "kind": "hd.dataset",
        "schema": manifest.get("schema"),
        "schema_version": manifest.get("schema_version"),
        "software_version": manifest.get("software_version"),
        "n_scans": manifest.get("n_scans"),
        "n_shards": len(shards),
        "size_bytes": _size(directory, shards),
        "splits": _mapping(manifest.get("splits")),
        "sigmas_m": manifest.get("sigmas_m"),
        "seed": manifest.get("seed"),
        "terrain": {k: dtm.get(k) for k in ("name", "rows", "cols", "spacing_m", "scale", "sha256", "path")},
        "labelings": [
            {
                "name": lab.get("name"),
                "convention": lab.get("convention"),
                "truth": lab.get("truth", "clean-scan"),
                "n_shards": len(lab.get("shards", [])),
                "safe_fraction": lab.get("safe_fraction"),
                "label_counts": lab.get("label_counts"),
                "baseline_safe_fraction": lab.get("baseline_safe_fraction"),
            }
            for lab in manifest.get("labelings", [])
            if isinstance(lab, dict)
        ],
        "writer_pid": None if isinstance(directory, str) else lock_holder(directory),
    }
    if isinstance(manifest.get("mosaic"), dict):  # a mosaic dataset: how its mosaics were made
        record["mosaic"] = manifest["mosaic"]
    if "descent_frames" in manifest:  # a descent build: its descents and their settings, navigation error included
        record["n_descents"] = manifest.get("n_descents")
        record["descent_frames"] = manifest.get("descent_frames")
        record["descent"] = _mapping(_mapping(_mapping(manifest.get("config")).get("trajectory")).get("descent"))
    return record


def _mapping(value: object) -> dict:
    """An informative manifest entry (``splits``, ``dtm``) as a dict; one of another type shows as unknown."""
    return value if isinstance(value, dict) else {}


def _span(attrs: dict[str, object], key: str) -> str:
    """A trajectory setting of a shard's attributes (``trajectory_altitude``) with its unit: ``500.0 m``
    or, drawn per scan from a range, ``250.0 to 1000.0 m per scan``."""
    unit = "m" if key.endswith("altitude") else "deg"
    low, high = attrs.get(f"{key}_{unit}"), attrs.get(f"{key}_max_{unit}")
    return f"{low} {unit}" if high is None else f"{low} to {high} {unit} per scan"


def _mosaic_line(attrs: dict[str, object], mosaic: dict[str, object]) -> str:
    """The line of a mosaic dataset's shard (1.4): what each scan is and where it came from."""
    source = _mapping(mosaic.get("source"))
    return (
        f"mosaics   one per descent of {attrs.get('mosaic_frames')} frames ({attrs.get('mosaic_poses')} poses), "
        f"{attrs.get('mosaic_dem_rows')} x {attrs.get('mosaic_dem_cols')} cells of "
        f"{attrs.get('mosaic_dem_spacing_m')} m "
        f"({attrs.get('mosaic_dem_gridding')} gridding per frame), from {source.get('path', '?')}"
    )


def _descents(manifest: ManifestJson) -> str:
    """`` (40 descents of 9 frames)`` of a descent build's manifest, else ``""``."""
    if "descent_frames" not in manifest:
        return ""
    return f" ({manifest.get('n_descents')} descents of {manifest.get('descent_frames')} frames)"


def _descent_lines(attrs: dict[str, object], n_descents: object) -> list[str]:
    """The descent and navigation error lines of a descent's shard (1.3; none for single scans)."""
    if "descent_frames" not in attrs:
        return []
    approach = attrs.get("descent_approach_deg")
    path = (
        "vertical"
        if approach == 0
        else f"approach {approach} deg from the vertical, from a direction drawn per descent"
    )
    return [
        (
            f"descents  {n_descents if isinstance(n_descents, int) else '?'} of {attrs.get('descent_frames')} "
            f"frames, {attrs.get('descent_altitude_start_m')} m down to {attrs.get('descent_altitude_end_m')} m "
            f"above the target, {path}"
        ),
        (
            f"nav error position {attrs.get('nav_position_sigma_m')} m bias + {attrs.get('nav_position_walk_m')} m "
            f"walk per frame, attitude {attrs.get('nav_attitude_sigma_deg')} deg bias + "
            f"{attrs.get('nav_attitude_walk_deg')} deg walk per frame (1-sigma per map axis)"
        ),
    ]


def _realism(attrs: dict[str, object]) -> str:
    """The pixel footprint and noise model of a 1.2 shard, in words ("" for the paper's sensor)."""
    parts = []
    if "footprint_samples" in attrs:
        k = attrs["footprint_samples"]
        parts.append(
            f"footprint {k} x {k} sub-rays, {attrs.get('footprint_spot_profile')} spot, "
            f"{attrs.get('footprint_range_estimator')} range (pulse {attrs.get('footprint_pulse_width_m')} m)"
        )
    noise_line = stored_kind(attrs).inspect_line(attrs)
    if noise_line:
        parts.append(noise_line)
    return "; ".join(parts)


def _fmt_spacing(spacing: object) -> str:
    """``sx x sy`` of a spacing in metres; anything else as written."""
    if (
        isinstance(spacing, (list, tuple))
        and len(spacing) == 2
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in spacing)
    ):
        return f"{spacing[0]:g} x {spacing[1]:g}"
    return str(spacing)


def _short_crs(wkt: str) -> str:
    start = wkt.find('"')
    end = wkt.find('"', start + 1)
    return wkt[start + 1 : end] if start >= 0 and end > start else wkt[:40]


# The status lines `hd inspect` prints after the summary.
INTACT_STATUS = "status    intact: every file matches the manifest's sha256 and schema"


def damaged_status(problems: list[str]) -> list[str]:
    """The status lines of a damaged dataset: a count, then one indented line per problem."""
    return [f"status    DAMAGED: {len(problems)} problem(s)", *(f"          {p}" for p in problems)]


def damaged_message(directory: str | os.PathLike, problems: list[str]) -> str:
    """The one-line error of a damaged dataset (a URL named without its secrets)."""
    name = dataset_label(directory)
    return (
        f"{name} is damaged ({len(problems)} problem(s)); `hd verify {name}` lists them; rebuild or "
        "restore the damaged files"
    )
