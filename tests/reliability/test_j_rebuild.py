"""J. A recipe rebuilt on another machine: `hd verify --recipe` says identical (sha256), or rebuilt and
equal to the published build within the content fingerprints' tolerances; a damaged or altered
copy fails, naming the file and the array or attribute."""

from __future__ import annotations

import json
import math
import os
import platform
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
from reliability_kit import BUILD_ARGS, LABEL_ARGS, REPO, assert_one_line_error, invoke

from lidarsim.shards import read_manifest, sha256_file

LABEL_GLOB = "labels/*/labels-00001.h5"
Edit = Callable[[str, np.ndarray], np.ndarray]


@pytest.fixture(scope="module")
def recipe(tmp_path_factory, labelled, dtm) -> Path:
    """The recipe of the labelled reference, published from it with `hd card` (checksums and fingerprints)."""
    values = dict(zip(BUILD_ARGS[::2], BUILD_ARGS[1::2], strict=True))
    directory = tmp_path_factory.mktemp("recipe") / "reference"
    directory.mkdir()
    (directory / "recipe.toml").write_text(
        f'[dataset]\nname = "reference"\n[build]\nscans = {values["--scans"]}\nshard_size = {values["--shard-size"]}\n'
        f"resolution = {values['--resolution']}\nsigmas_m = [{values['--sigma']}]\nseed = {values['--seed']}\n"
        f'dtm = "{dtm}"\n'
    )
    result = invoke("card", labelled, "--recipe", directory)
    assert result.exit_code == 0, result.output
    return directory


def rewrite(path: Path, edit: Edit | None = None, attrs: dict[str, Any] | None = None) -> None:
    """Write an HDF5 shard again with deflate level 9 instead of 1: other bytes for the same arrays,
    as another zlib gives (``edit`` changes arrays, ``attrs`` file attributes)."""
    with h5py.File(path, "r") as src:
        file_attrs = {**dict(src.attrs), **(attrs or {})}
        datasets = {
            name: (ds[()], ds.chunks, ds.compression, ds.shuffle, ds.fletcher32, dict(ds.attrs))
            for name, ds in src.items()
        }
    path.unlink()
    with h5py.File(path, "w") as dst:
        dst.attrs.update(file_attrs)
        for name, (data, chunks, compression, shuffle, fletcher32, ds_attrs) in datasets.items():
            level = {"compression": "gzip", "compression_opts": 9} if compression == "gzip" else {}
            new = dst.create_dataset(
                name,
                data=edit(name, data) if edit else data,
                chunks=chunks,
                shuffle=shuffle,
                fletcher32=fletcher32,
                **level,
            )
            new.attrs.update(ds_attrs)


def reseal(dataset: Path) -> None:
    """Record every file's sha256 in the manifest (a copy edited consistently)."""
    m = read_manifest(dataset)
    for e in m["shards"] + [e for lab in m["labelings"] for e in lab["shards"]]:
        e["sha256"] = sha256_file(dataset / e["path"])
        e["size_bytes"] = (dataset / e["path"]).stat().st_size
    (dataset / "manifest.json").write_text(json.dumps(m))


def verify(data: Path, recipe: Path) -> tuple[int, str, str]:
    result = invoke("verify", data, "--recipe", recipe)
    return result.exit_code, result.stdout, result.stderr


def test_the_published_build_itself_is_identical_file_by_file(labelled, recipe):
    code, out, _ = verify(labelled, recipe)
    manifest = read_manifest(labelled)
    paths = [e["path"] for e in manifest["shards"] + manifest["labelings"][0]["shards"]]
    assert code == 0
    for path in paths:
        assert f"{path}: identical (sha256)\n" in out
    assert f"{len(paths)} files identical to the recipe's published build (sha256)" in out
    published = json.loads((recipe / "checksums.json").read_text())
    assert published["fingerprint_schema"] == "hd.content-fingerprint"
    assert published["fingerprint_schema_version"] == "1.0"
    assert all("content" in e for e in published["shards"] + published["labelings"][0]["shards"])


def test_a_rebuild_with_other_bytes_and_rounding_is_equal_within_tolerance(data_copy, recipe):
    """Every shard written with other deflate bytes, the label maps moved by float32 rounding steps."""
    rng = np.random.default_rng(0)

    def rounding(name: str, data: np.ndarray) -> np.ndarray:
        if name not in ("slope_rad", "roughness_m", "p_safe") or data.dtype != np.float32:
            return data
        toward = np.where(rng.random(data.shape) < 0.5, -np.inf, np.inf).astype(np.float32)
        moved = np.nextafter(data, toward)
        return np.where(np.isfinite(data) & (data > 0) & (data < 1), moved, data)

    manifest = read_manifest(data_copy)
    for e in manifest["shards"]:
        rewrite(data_copy / e["path"])
    for label_shard in manifest["labelings"][0]["shards"]:
        rewrite(data_copy / label_shard["path"], rounding)
    reseal(data_copy)
    code, out, err = verify(data_copy, recipe)
    assert code == 0, err
    n = len(manifest["shards"]) + len(manifest["labelings"][0]["shards"])
    assert out.count(": rebuilt: equal to the published build within tolerance (") == n
    assert (
        f"0 files identical to the recipe's published build (sha256), {n} rebuilt: equal to it within tolerance" in out
    )


@pytest.mark.parametrize(
    ("change", "needles"),
    [
        ("changed-label", ["label: counts per value", "must be equal"]),
        ("changed-attribute", ["attribute lander_max_slope_deg is 12.0, the published build's is"]),
        ("moved-points", ["points_clean: sum", "tolerance 1e-06"]),
        ("swapped-scans", ["points_noisy: position-weighted sum"]),
    ],
)
def test_an_altered_copy_fails_naming_file_and_array(data_copy, recipe, change, needles):
    label = next(data_copy.glob(LABEL_GLOB))
    scans = data_copy / "shards" / "scans-00001.h5"
    if change == "changed-label":

        def one_label(name: str, data: np.ndarray) -> np.ndarray:
            if name == "label":
                data[0, 20, 20] = 1 - data[0, 20, 20] if data[0, 20, 20] < 2 else 0
            return data

        rewrite(label, one_label)
        where = label.relative_to(data_copy)
    elif change == "changed-attribute":
        rewrite(label, attrs={"lander_max_slope_deg": 12.0})
        where = label.relative_to(data_copy)
    elif change == "moved-points":
        rewrite(scans, lambda name, data: data + np.float32(0.5) if name == "points_clean" else data)
        where = scans.relative_to(data_copy)
    else:
        rewrite(scans, lambda name, data: data[::-1].copy() if name == "points_noisy" else data)
        where = scans.relative_to(data_copy)
    reseal(data_copy)
    code, _, err = verify(data_copy, recipe)
    assert code != 0
    lines = err.strip().splitlines()
    assert lines[-1].startswith("Error: ") and "problem(s) found" in lines[-1]
    for needle in needles:
        assert any(line.startswith(f"{where}: ") and needle in line for line in lines), err


@pytest.mark.parametrize("resealed", [False, True])
def test_a_flipped_chunk_byte_fails_with_or_without_a_resealed_manifest(data_copy, recipe, resealed):
    path = data_copy / "shards" / "scans-00000.h5"
    with h5py.File(path, "r") as f:
        info = f["points_noisy"].id.get_chunk_info(1)
    with open(path, "r+b") as fh:
        fh.seek(info.byte_offset + info.size // 2)
        byte = fh.read(1)
        fh.seek(info.byte_offset + info.size // 2)
        fh.write(bytes([byte[0] ^ 0xFF]))
    if resealed:
        reseal(data_copy)
    code, _, err = verify(data_copy, recipe)
    assert code != 0
    needle = (
        "shards/scans-00000.h5: cannot read points_noisy" if resealed else "shards/scans-00000.h5: checksum mismatch"
    )
    assert needle in err


def test_checksums_without_fingerprints_name_what_is_missing(data_copy, recipe, tmp_path):
    old = tmp_path / "old"
    shutil.copytree(recipe, old)
    published = json.loads((old / "checksums.json").read_text())
    for e in published["shards"]:
        del e["content"]
    (old / "checksums.json").write_text(json.dumps(published))
    assert verify(data_copy, old)[0] == 0  # the same bytes: identical
    rewrite(data_copy / "shards" / "scans-00000.h5")
    reseal(data_copy)
    code, _, err = verify(data_copy, old)
    assert code != 0 and "shards/scans-00000.h5: sha256 differs from the recipe's published build" in err
    assert "publishes no content fingerprint" in err


def test_a_labelling_the_copy_lacks_is_noted_and_a_newer_fingerprint_schema_refused(data_copy, recipe, tmp_path):
    other = tmp_path / "other"
    shutil.copytree(recipe, other)
    published = json.loads((other / "checksums.json").read_text())
    published["labelings"][0]["name"] = "another-labelling"
    (other / "checksums.json").write_text(json.dumps(published))
    code, out, _ = verify(data_copy, other)
    assert code == 0
    assert "labelling another-labelling: not in this dataset, not compared" in out
    assert "not part of the recipe's published build, not compared" in out
    published["fingerprint_schema_version"] = "2.0"
    (other / "checksums.json").write_text(json.dumps(published))
    result = invoke("verify", data_copy, "--recipe", other)
    assert result.exit_code != 0 and "version 2.0 is not supported" in result.output


# Switches that make this machine compute as another x86-64 CPU would (docs/reliability.md, class J).
OTHER_CPUS = {
    # numpy's loops for CPUs without AVX-512 (float64 power, exp, sin, cos: no SVML)
    "numpy-avx2": {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR"},
    # OpenBLAS's kernels for Intel AVX-512 CPUs (the lander's plane weights in the label kernels)
    "openblas-skylakex": {"OPENBLAS_CORETYPE": "SkylakeX"},
}


def _has_avx512() -> bool:
    try:
        return "avx512f" in Path("/proc/cpuinfo").read_text().split()
    except OSError:
        return False


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="switches of x86-64 code paths")
@pytest.mark.parametrize("cpu", sorted(OTHER_CPUS))
def test_a_rebuild_computed_as_on_another_cpu_passes_with_identical_scans(tmp_path, recipe, cpu):
    if cpu == "openblas-skylakex" and not _has_avx512():
        pytest.skip("OpenBLAS's SkylakeX kernels need AVX-512")
    out = tmp_path / "other-cpu"
    env = {**os.environ, "OMP_NUM_THREADS": "1", **OTHER_CPUS[cpu]}
    for args in (
        ["build-dataset", "--recipe", str(recipe), "--out", str(out), "--workers", "1"],
        ["label", str(out), "--workers", "1", *LABEL_ARGS],
    ):
        done = subprocess.run(
            [sys.executable, "-m", "hdcli", *args], env=env, capture_output=True, text=True, timeout=600
        )
        assert done.returncode == 0, done.stderr
    code, out_text, err = verify(out, recipe)
    assert code == 0, err
    manifest = read_manifest(out)
    for entry in manifest["shards"]:  # ray casting, terrain and noise: the same bits
        assert f"{entry['path']}: identical (sha256)\n" in out_text
    for label_shard in manifest["labelings"][0]["shards"]:  # label maps: the same bits or a few rounding steps
        path = label_shard["path"]
        assert f"{path}: identical (sha256)\n" in out_text or f"{path}: rebuilt: " in out_text


def test_a_build_deviating_from_its_recipe_in_size_is_recorded_and_named_by_verify(recipe, tmp_path):
    out = tmp_path / "small"
    args = ("build-dataset", "--recipe", recipe, "--scans", "4", "--shard-size", "1", "--workers", "1")
    built = invoke(*args, "--out", out)
    assert built.exit_code == 0, built.output
    deviation = "--scans 4 (recipe: 8), --shard-size 1 (recipe: 2)"
    assert f"deviates from the recipe reference: {deviation}" in built.output
    manifest = read_manifest(out)
    assert manifest["schema_version"] == "1.4" and manifest["recipe_deviation"] == {
        "recipe": "reference",
        "recipe_version": 1,
        "settings": [
            {"setting": "scans", "option": "--scans", "recipe": 8, "used": 4},
            {"setting": "shard_size", "option": "--shard-size", "recipe": 2, "used": 1},
        ],
    }
    code, _, err = verify(out, recipe)
    assert code == 1 and err.splitlines()[0] == (
        f"the dataset deviates from its recipe reference ({deviation}): its files are not the published build's, "
        "their checksums are not compared"
    ), err
    assert invoke("verify", out).exit_code == 0  # the dataset itself is intact
    assert_one_line_error(invoke("card", out, "--recipe", recipe), "not built from")
    again = invoke(*args, "--out", out)
    assert again.exit_code == 0 and "already holds this dataset" in again.output
    assert_one_line_error(invoke("build-dataset", "--recipe", recipe, "--sigma", "0.03"), "--sigma", "--recipe")
    same = invoke("build-dataset", "--recipe", recipe, "--scans", "8", "--out", tmp_path / "same", "--workers", "1")
    assert same.exit_code == 0 and "deviates" not in same.output  # the recipe's own value is no deviation
    assert "recipe_deviation" not in read_manifest(tmp_path / "same")
    assert verify(tmp_path / "same", recipe)[0] == 0


def test_verify_names_the_settings_a_dataset_was_built_with_other_than_its_recipes(recipe, dtm, tmp_path):
    values = dict(zip(BUILD_ARGS[::2], BUILD_ARGS[1::2], strict=True)) | {"--scans": "6", "--seed": "4"}
    out = tmp_path / "other"
    args = [a for pair in values.items() for a in pair]
    built = invoke("build-dataset", *args, "--dtm", dtm, "--out", out, "--workers", "1")
    assert built.exit_code == 0, built.output
    code, _, err = verify(out, recipe)
    assert code == 1 and err.splitlines()[0] == (
        "the dataset was built with other settings than the recipe's: seed 4 (recipe: 3), trajectory.n_scans 6 "
        "(recipe: 8)"
    ), err


def _set(tree: Any, path: tuple[Any, ...], value: Any) -> None:
    for key in path[:-1]:
        tree = tree[key]
    tree[path[-1]] = value


POINTS = ("shards", 0, "content", "arrays", "points_clean")
LABELS = ("labelings", 0, "shards", 0, "content", "arrays", "label")


@pytest.mark.parametrize(
    ("field", "value", "needle"),
    [
        (("config_sha256",), "not-a-digest", "config_sha256 is 'not-a-digest'"),
        (("shards", 0, "sha256"), "xyz", "shards[0].sha256 is 'xyz'"),
        (("labelings", 0, "shards", 1, "sha256"), "A" * 64, "labelings[0].shards[1].sha256"),
        (("shards", 1, "n_scans"), -5, "shards[1].n_scans is -5"),
        (("shards", 1, "n_scans"), 2.5, "shards[1].n_scans is 2.5"),
        (("shards", 0, "path"), "../elsewhere.h5", "shards[0].path is '../elsewhere.h5'"),
        (("shard_schema_version",), "one", "shard_schema_version is 'one'"),
        ((*POINTS, "nan"), -1, "points_clean.nan is -1"),
        ((*POINTS, "sum"), math.nan, "points_clean.sum is NaN"),
        ((*POINTS, "sum_abs"), math.inf, "points_clean.sum_abs is Infinity"),
        ((*POINTS, "sum_abs"), 1e300, "points_clean.sum_abs is 1e+300"),
        ((*POINTS, "min"), 1e6, "points_clean.min is 1000000.0"),
        ((*POINTS, "shape"), [-2, 32, 32, 3], "points_clean.shape is [-2, 32, 32, 3]"),
        ((*POINTS, "dtype"), "float99", "points_clean.dtype is 'float99'"),
        ((*LABELS, "counts", "0"), -3, "label.counts.0 is -3"),
        ((*LABELS, "counts", "7"), 1, "label.counts"),
        ((*LABELS, "max"), 300, "label.max is 300"),
    ],
    ids=lambda v: "-".join(map(str, v)) if isinstance(v, tuple) else None,
)
def test_checksums_with_impossible_values_are_refused_naming_the_field(
    data_copy, recipe, tmp_path, field, value, needle
):
    """A published checksums.json whose values no build can have (negative counts, NaN or infinite
    statistics, scales that make every rebuild pass, digests that are not sha256, paths out of the
    dataset) is refused when it is read, with one line naming the field: the untouched copy verified
    OK against it (its bytes are identical, so the content was never looked at)."""
    bad = tmp_path / "bad"
    shutil.copytree(recipe, bad)
    published = json.loads((bad / "checksums.json").read_text())
    _set(published, field, value)
    (bad / "checksums.json").write_text(json.dumps(published))  # NaN and Infinity as Python's json writes them
    last = assert_one_line_error(invoke("verify", data_copy, "--recipe", bad), "checksums.json", needle)
    assert "problem(s) found" not in last


def test_checksums_whose_scales_are_infinite_no_longer_pass_a_changed_rebuild(data_copy, recipe, tmp_path):
    """An infinite published sum of absolute values and minimum made every tolerance infinite: a copy
    whose points moved by half a metre was "rebuilt: equal to the published build within tolerance"."""
    bad = tmp_path / "bad"
    shutil.copytree(recipe, bad)
    published = json.loads((bad / "checksums.json").read_text())
    arrays = published["shards"][1]["content"]["arrays"]["points_clean"]
    arrays["sum_abs"], arrays["min"] = math.inf, -math.inf
    (bad / "checksums.json").write_text(json.dumps(published))
    scans = data_copy / "shards" / "scans-00001.h5"
    rewrite(scans, lambda name, data: data + np.float32(0.5) if name == "points_clean" else data)
    reseal(data_copy)
    assert_one_line_error(
        invoke("verify", data_copy, "--recipe", bad), "shards[1].content.arrays.points_clean.sum_abs is Infinity"
    )


def test_every_published_checksums_file_has_possible_values():
    from lidarsim.recipe import load_recipe

    for published in sorted((REPO / "datasets").glob("*/checksums.json")):
        assert load_recipe(published.parent).checksums() is not None, published


def test_terrain_labels_published_before_they_recorded_their_terrain_are_rebuilt_within_tolerance(
    data_copy, recipe, tmp_path
):
    """Terrain-truth label shards are schema 1.2 since they record their terrain's sha256; a recipe
    published before (1.1 shards without it, mars-landing) still verifies a rebuild: within tolerance,
    saying what was not compared. Any other difference of the attributes is still one."""
    assert invoke("label", data_copy, "--truth", "terrain", "--workers", "1").exit_code == 0
    published_dir = tmp_path / "published"
    published_dir.mkdir()
    shutil.copy(recipe / "recipe.toml", published_dir)
    assert invoke("card", data_copy, "--recipe", published_dir).exit_code == 0
    published = json.loads((published_dir / "checksums.json").read_text())
    (terrain,) = [lab for lab in published["labelings"] if lab["name"].endswith("-truth-terrain")]
    for entry in terrain["shards"]:  # as hd wrote them before: version 1.1, no truth_dtm_sha256, other bytes
        attrs = entry["content"]["attrs"]
        assert attrs.pop("truth_dtm_sha256") == read_manifest(data_copy)["dtm"]["sha256"]
        attrs["schema_version"] = "1.1"
        entry["sha256"] = "0" * 64
    (published_dir / "checksums.json").write_text(json.dumps(published))
    code, out, err = verify(data_copy, published_dir)
    assert code == 0, err
    for entry in terrain["shards"]:
        assert (
            f"{entry['path']}: rebuilt: equal to the published build within tolerance (" in out
            and "schema 1.2 of a file published as 1.1: truth_dtm_sha256, added since, not compared)" in out
        )
    del terrain["shards"][0]["content"]["attrs"]["truth_dtm"]
    (published_dir / "checksums.json").write_text(json.dumps(published))
    code, _, err = verify(data_copy, published_dir)
    assert code == 1 and f"{terrain['shards'][0]['path']}: attribute truth_dtm is not in the published build" in err
