"""Class E: damaged and hostile files are caught by every reader, not only by ``hd verify``.

Scan and label shards are checked against the manifest's sha256 before they are read, and every
chunk carries a fletcher32 checksum checked at read time (errors name the file and the scan);
manifests are validated (keys, types, paths confined to the dataset); checkpoints carry a content
sha256 checked on load.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch
from reliability_kit import assert_one_line_error, hills, invoke

from hdcore.storage import DamagedFileError
from lidarsim.shards import ScanShardReader, read_manifest, sha256_file

LABEL_GLOB = "labels/*/labels-00000.h5"


def flip_chunk_byte(path: Path, dataset: str, chunk: int = 0) -> None:
    """Flip one byte in the middle of a stored (compressed) chunk of ``dataset``."""
    with h5py.File(path, "r") as f:
        info = f[dataset].id.get_chunk_info(chunk)
    with open(path, "r+b") as fh:
        fh.seek(info.byte_offset + info.size // 2)
        b = fh.read(1)
        fh.seek(info.byte_offset + info.size // 2)
        fh.write(bytes([b[0] ^ 0xFF]))


def reseal(dataset: Path) -> None:
    """Record the damaged files' sha256 in the manifest, so that only read-time checks remain."""
    m = json.loads((dataset / "manifest.json").read_text())
    for e in m["shards"] + [e for lab in m["labelings"] for e in lab["shards"]]:
        e["sha256"] = sha256_file(dataset / e["path"])
        e["size_bytes"] = (dataset / e["path"]).stat().st_size
    (dataset / "manifest.json").write_text(json.dumps(m))


def label_shard(data: Path) -> Path:
    return next(data.glob(LABEL_GLOB))


def train(data: Path, run: Path, *more: str):
    return invoke("train", data, "--out", run, "--profile", "tiny", "--epochs", "1", *more)


def evaluate(run: Path, data: Path, out: Path):
    return invoke("eval", run, "--data", data, "--out", out, "--mc-samples", "2")


# ------------------------------------------------------------------------------------- shards
def test_a_flipped_byte_in_a_scan_shard_is_caught_by_label_and_verify(data_copy, tmp_path):
    shard = data_copy / "shards" / "scans-00001.h5"
    flip_chunk_byte(shard, "points_noisy", 1)
    line = assert_one_line_error(
        invoke("label", data_copy, "--max-slope-deg", "8", "--workers", "1"), "scans-00001.h5", "checksum mismatch"
    )
    assert "hd verify" in line
    verify = invoke("verify", data_copy)
    assert verify.exit_code == 1 and "shards/scans-00001.h5: checksum mismatch" in verify.output
    assert not list(data_copy.rglob("*.partial-*")) and len(read_manifest(data_copy)["labelings"]) == 1


def test_a_flipped_byte_is_caught_at_read_time_naming_file_and_scan(data_copy):
    shard = data_copy / "shards" / "scans-00001.h5"
    flip_chunk_byte(shard, "points_noisy", 1)
    with ScanShardReader(shard) as reader:  # no manifest checksum: the chunk's fletcher32 catches it
        reader[0]
        with pytest.raises(DamagedFileError, match=r"scans-00001\.h5: cannot read points_noisy of scan 3 \(row 1\)"):
            reader[1]
    reseal(data_copy)
    line = assert_one_line_error(
        invoke("label", data_copy, "--max-slope-deg", "8", "--workers", "1"), "scans-00001.h5", "scan 3"
    )
    assert "damaged" in line


def _row_of_split(data: Path, code: int, nth: int = 0) -> tuple[Path, int, int]:
    """(label shard, row, scan index) of the ``nth`` scan of a split (0 train, 2 test)."""
    found = []
    for path in sorted(data.glob("labels/*/labels-*.h5")):
        with h5py.File(path, "r") as f:
            found += [(path, int(r), int(f["scan_index"][r])) for r in np.flatnonzero(f["split"][:] == code)]
    return found[nth]


@pytest.mark.parametrize("command", ["train", "train-with-dataloader-workers", "eval"])
def test_a_flipped_byte_in_a_label_shard_is_caught_by_train_and_eval(data_copy, trained, tmp_path, command):
    workers = command == "train-with-dataloader-workers"
    # a scan the command reads; with workers the second training scan, which only a worker reads
    path, row, scan = _row_of_split(data_copy, 2 if command == "eval" else 0, nth=1 if workers else 0)
    dataset = "label" if workers else "dem_noisy"
    flip_chunk_byte(path, dataset, row)
    more = ["--num-workers", "2"] if workers else []
    result = (
        train(data_copy, tmp_path / "run", *more) if command != "eval" else evaluate(trained, data_copy, tmp_path / "r")
    )
    assert_one_line_error(result, path.name, "checksum mismatch")
    reseal(data_copy)
    result = (
        train(data_copy, tmp_path / "run2", *more)
        if command != "eval"
        else evaluate(trained, data_copy, tmp_path / "r2")
    )
    assert_one_line_error(result, path.name, f"scan {scan} (row {row})", "damaged")
    assert not (tmp_path / "r").exists() and not (tmp_path / "r2").exists()


@pytest.mark.parametrize("where", ["file-attribute", "manifest-entry"])
@pytest.mark.parametrize("command", ["train", "eval"])
def test_an_unknown_label_schema_major_version_is_refused(data_copy, trained, tmp_path, where, command):
    if where == "file-attribute":
        with h5py.File(label_shard(data_copy), "r+") as f:
            f.attrs["schema_version"] = "2.0"
        reseal(data_copy)
    else:
        m = json.loads((data_copy / "manifest.json").read_text())
        m["labelings"][0]["shards"][0]["schema_version"] = "2.0"
        (data_copy / "manifest.json").write_text(json.dumps(m))
    result = train(data_copy, tmp_path / "run") if command == "train" else evaluate(trained, data_copy, tmp_path / "r")
    assert_one_line_error(result, "labels-00000.h5", "version 2.0", "upgrade hd")
    verify = invoke("verify", data_copy)  # said OK for the manifest entry that train and eval refuse
    assert verify.exit_code == 1 and "version 2.0" in verify.output, verify.output


@pytest.mark.parametrize("damage", ["truncated", "zeroed", "garbage", "deleted", "directory", "empty"])
def test_damaged_scan_shard_files(data_copy, damage):
    shard = data_copy / "shards" / "scans-00002.h5"
    data = shard.read_bytes()
    if damage == "truncated":
        shard.write_bytes(data[: len(data) // 2])
    elif damage == "zeroed":
        shard.write_bytes(bytes(len(data)))
    elif damage == "garbage":
        shard.write_bytes(np.random.default_rng(0).bytes(len(data)))
    elif damage == "deleted":
        shard.unlink()
    elif damage == "directory":
        shard.unlink()
        shard.mkdir()
    else:
        shard.write_bytes(b"")
    assert_one_line_error(invoke("label", data_copy, "--max-slope-deg", "8", "--workers", "1"), "scans-00002.h5")
    verify = invoke("verify", data_copy)
    assert verify.exit_code == 1 and "scans-00002.h5" in verify.output and "Traceback" not in verify.output
    assert_one_line_error(invoke("inspect", data_copy), "damaged", "hd verify")


def test_a_deleted_label_shard_is_named(data_copy, trained, tmp_path):
    label_shard(data_copy).unlink()
    assert_one_line_error(train(data_copy, tmp_path / "run"), "labels-00000.h5", "missing")
    assert_one_line_error(evaluate(trained, data_copy, tmp_path / "r"), "labels-00000.h5", "missing")


# ------------------------------------------------------------------------------------- manifests
def _edit(m: dict, damage: str) -> object:
    if damage == "no-shards-key":
        del m["shards"]
    elif damage == "shards-not-a-list":
        m["shards"] = "scans-00000.h5"
    elif damage == "entry-without-sha256":
        del m["shards"][0]["sha256"]
    elif damage == "sha256-not-hex":
        m["shards"][0]["sha256"] = "not-a-checksum"
    elif damage == "scan-count-mismatch":
        m["n_scans"] = 9
    elif damage == "path-escapes":
        m["shards"][0]["path"] = "../../../../etc/passwd"
    elif damage == "absolute-path":
        m["shards"][0]["path"] = "/etc/passwd"
    elif damage == "label-path-escapes":
        m["labelings"][0]["shards"][0]["path"] = "labels/../../../etc/passwd"
    elif damage == "labelling-name-escapes":
        m["labelings"][0]["name"] = "../x"
    elif damage == "major-version":
        m["schema_version"] = "2.0"
    elif damage == "n-scans-not-int":
        m["n_scans"] = "eight"
    elif damage == "split-counts-do-not-add-up":
        m["shards"][0]["split_counts"]["train"] += 1
    elif damage == "splits-differ-from-shards":
        m["shards"][0]["split_counts"]["train"] -= 1
        m["shards"][0]["split_counts"]["test"] += 1
    elif damage == "shard-scan-count-wrong":
        m["shards"][0]["n_scans"] += 1
        m["shards"][0]["split_counts"]["train"] += 1
        m["shards"][1]["n_scans"] -= 1
        m["shards"][1]["split_counts"]["train"] -= 1
    elif damage == "absurd-scan-count":
        m["shards"][0]["n_scans"] = 10**12 - sum(e["n_scans"] for e in m["shards"][1:])
        m["n_scans"] = 10**12
    elif damage == "not-an-object":
        return [m]
    return m


MANIFEST_DAMAGE = [
    "no-shards-key",
    "shards-not-a-list",
    "entry-without-sha256",
    "sha256-not-hex",
    "scan-count-mismatch",
    "path-escapes",
    "absolute-path",
    "label-path-escapes",
    "labelling-name-escapes",
    "major-version",
    "n-scans-not-int",
    "split-counts-do-not-add-up",
    "splits-differ-from-shards",
    "absurd-scan-count",
    "not-an-object",
    "truncated-json",
    "binary",
    "empty",
    "is-a-directory",
]
NEEDLE = {
    "no-shards-key": "'shards'",
    "shards-not-a-list": "shards",
    "entry-without-sha256": "'sha256'",
    "sha256-not-hex": "sha256",
    "scan-count-mismatch": "9 scans",
    "path-escapes": "leaves the dataset",
    "absolute-path": "leaves the dataset",
    "label-path-escapes": "leaves the dataset",
    "labelling-name-escapes": "labelling name",
    "major-version": "version 2.0",
    "n-scans-not-int": "n_scans",
    "split-counts-do-not-add-up": "do not add up",
    "splits-differ-from-shards": "differ from its shards' split counts",
    "absurd-scan-count": "'n_scans' must be in 0..1000000",
    "not-an-object": "not a JSON object",
    "truncated-json": "unreadable manifest",
    "binary": "unreadable manifest",
    "empty": "unreadable manifest",
    "is-a-directory": "manifest.json",
}


@pytest.mark.parametrize("command", ["verify", "inspect", "label", "train", "eval"])
@pytest.mark.parametrize("damage", MANIFEST_DAMAGE)
def test_damaged_or_hostile_manifests(data_copy, trained, tmp_path, damage, command):
    path = data_copy / "manifest.json"
    text = path.read_text()
    if damage == "truncated-json":
        path.write_text(text[: len(text) // 2])
    elif damage == "binary":
        path.write_bytes(b"\x89HDF\r\n\x1a\n\x00\xff" * 10)
    elif damage == "empty":
        path.write_text("")
    elif damage == "is-a-directory":
        path.unlink()
        path.mkdir()
    else:
        path.write_text(json.dumps(_edit(json.loads(text), damage)))
    args = {
        "verify": ["verify", data_copy],
        "inspect": ["inspect", data_copy],
        "label": ["label", data_copy, "--workers", "1"],
        "train": ["train", data_copy, "--out", tmp_path / "run", "--profile", "tiny", "--epochs", "1"],
        "eval": ["eval", trained, "--data", data_copy, "--out", tmp_path / "r"],
    }[command]
    assert_one_line_error(invoke(*args), NEEDLE[damage])
    assert not (tmp_path / "run").exists() and not (tmp_path / "r").exists()


def test_a_shard_holding_other_than_its_entry_claims_is_damaged(data_copy):
    """Two entries' scan counts moved by one: totals still add up, the shards do not match."""
    from lidarsim.shards import open_scan_shard

    path = data_copy / "manifest.json"
    m = _edit(json.loads(path.read_text()), "shard-scan-count-wrong")
    path.write_text(json.dumps(m))
    assert isinstance(m, dict)
    shards = m["shards"]
    assert isinstance(shards, list)
    with pytest.raises(DamagedFileError, match="claims 3"):
        open_scan_shard(data_copy, shards[0])
    result = invoke("verify", data_copy)
    assert result.exit_code == 1 and "holds 2 scans, manifest says 3" in result.output


def test_verify_never_follows_a_link_out_of_the_dataset(data_copy, tmp_path):
    shard = data_copy / "shards" / "scans-00000.h5"
    outside = tmp_path / "outside.h5"
    shutil.copy(shard, outside)  # same bytes: only the path check can refuse it
    shard.unlink()
    shard.symlink_to(outside)
    verify = invoke("verify", data_copy)
    assert verify.exit_code == 1 and "leads outside the dataset" in verify.output
    assert_one_line_error(invoke("label", data_copy, "--max-slope-deg", "8", "--workers", "1"), "outside the dataset")


# ------------------------------------------------------------------------------------- checkpoints
def _flip_tensor_bytes(ckpt_path: Path, n: int = 16) -> None:
    """Flip ``n`` bytes inside the largest weight tensor's data in the checkpoint file."""
    ckpt = torch.load(ckpt_path, weights_only=True)
    name, tensor = max(ckpt["model"].items(), key=lambda kv: kv[1].numel())
    raw = tensor.numpy().tobytes()
    data = bytearray(ckpt_path.read_bytes())
    at = data.find(raw)
    assert at > 0, name
    for k in range(n):
        data[at + len(raw) // 2 + k] ^= 0x5A
    ckpt_path.write_bytes(bytes(data))


@pytest.mark.parametrize("damage", ["flipped-weights", "truncated", "garbage", "digest-removed"])
def test_damaged_checkpoints_are_refused(trained, labelled, tmp_path, damage):
    run = tmp_path / "run"
    shutil.copytree(trained, run)
    last = run / "last.pt"
    if damage == "flipped-weights":
        _flip_tensor_bytes(last)
        assert torch.load(last, weights_only=True)["schema"] == "hdnet.checkpoint"  # still loads as a zip
    elif damage == "truncated":
        last.write_bytes(last.read_bytes()[:5000])
    elif damage == "garbage":
        last.write_bytes(os.urandom(4096))
    else:
        ckpt = torch.load(last, weights_only=True)
        del ckpt["content_sha256"]
        torch.save(ckpt, last)
    needle = {
        "flipped-weights": "checksum mismatch",
        "truncated": "not a readable",
        "garbage": "not a readable",
        "digest-removed": "lacks",
    }[damage]
    assert_one_line_error(evaluate(run, labelled, tmp_path / "r"), "last.pt", needle)
    assert_one_line_error(train(labelled, run, "--resume"), "last.pt", needle)
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("change", ["key-missing", "key-extra", "shape", "absurd-width", "config-unknown-field"])
def test_checkpoints_from_elsewhere_are_checked_against_their_tensors_first(trained, tmp_path, change):
    """A state_dict lacking a key gave a traceback; an absurd width built a 4.8 GB model before any check."""
    from hdnet.train import checkpoint_digest

    ckpt = torch.load(trained / "last.pt", weights_only=True)
    model = ckpt["model"]
    if change == "key-missing":
        del model[next(iter(model))]
    elif change == "key-extra":
        model["decoder.extra.weight"] = torch.zeros(3)
    elif change == "shape":
        name = next(k for k, v in model.items() if v.dim() == 4)
        model[name] = torch.zeros(*model[name].shape[:-1], model[name].shape[-1] + 1)
    elif change == "absurd-width":
        ckpt["model_config"]["width"] = 10_000.0
    else:
        ckpt["model_config"]["heads"] = 3
    ckpt["content_sha256"] = checkpoint_digest({k: v for k, v in ckpt.items() if k != "content_sha256"})
    path = tmp_path / "other.pt"
    torch.save(ckpt, path)
    needle = {
        "key-missing": "lack",
        "key-extra": "does not have",
        "shape": "has shape",
        "absurd-width": "has shape",
        "config-unknown-field": "does not describe a SegNet",
    }[change]
    assert_one_line_error(
        invoke("detect", path, "--dtm", hills(tmp_path / "t.tif", n=120), "--out", tmp_path / "d"), needle
    )
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("damage", ["label-chunk", "label-bytes", "scan-origin"])
def test_detect_on_a_scan_reads_through_the_storage_layer(trained, data_copy, tmp_path, damage):
    """detect --data printed raw HDF5 messages, and read the scan origin with raw h5py (exit 0, origin null)."""
    label = next(data_copy.glob(LABEL_GLOB))
    with h5py.File(label, "r") as f:
        scan = int(f["scan_index"][0])
        source = data_copy / str(f.attrs["source_shard"])
    if damage == "label-chunk":
        flip_chunk_byte(label, "dem_noisy")
        reseal(data_copy)  # only the read-time check is left
        needle = "cannot read dem_noisy"
    elif damage == "label-bytes":
        flip_chunk_byte(label, "dem_noisy")  # the manifest's sha256 no longer matches
        needle = "checksum"
    else:
        with h5py.File(source, "r+") as f:
            f["origin_map"][0] = [1.0, 2.0, 3.0]
        needle = "checksum"
    out = tmp_path / "d"
    result = invoke(
        "detect", trained, "--data", data_copy, "--scan", str(scan), "--out", out, "--threshold", "nats:0.3"
    )
    last = assert_one_line_error(result, needle)
    assert ("labels-00000.h5" in last) != (damage == "scan-origin") and not out.exists()


def test_a_schema_1_checkpoint_loads_with_a_warning(trained, tmp_path):
    """docs/reliability.md: version 1 checkpoints (no content_sha256) still load; now never silently."""
    ckpt = torch.load(trained / "last.pt", weights_only=True)
    del ckpt["content_sha256"]
    ckpt["schema_version"] = 1
    path = tmp_path / "old.pt"
    torch.save(ckpt, path)
    out = tmp_path / "d"
    result = invoke("detect", path, "--dtm", hills(tmp_path / "t.tif", n=120), "--out", out, "--threshold", "nats:0.3")
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.output.splitlines() if line.startswith("Warning: ")]
    assert len(warnings) == 1 and "schema-1 checkpoint" in warnings[0] and "cannot be detected" in warnings[0]


# ------------------------------------------------------------------------------------- old shards
def _rewrite_old_way(path: Path) -> None:
    """Rewrite a 1.1 shard as hd wrote 1.0 shards: no fletcher32, small arrays contiguous."""
    tmp = path.with_suffix(".old")
    with h5py.File(path, "r") as src, h5py.File(tmp, "w") as dst:
        for k, v in src.attrs.items():
            dst.attrs[k] = v
        dst.attrs["schema_version"] = "1.0"
        for name, ds in src.items():
            kw = (
                {
                    "chunks": ds.chunks,
                    "compression": ds.compression,
                    "compression_opts": ds.compression_opts,
                    "shuffle": ds.shuffle,
                }
                if ds.compression
                else {}
            )
            if ds.compression is None and ds.ndim < 3:
                kw = {}
            out = dst.create_dataset(name, data=ds[()], track_times=False, **kw)
            for k, v in ds.attrs.items():
                out.attrs[k] = v
            assert not out.fletcher32
    os.replace(tmp, path)


def test_shards_written_the_old_way_stay_readable(data_copy, tmp_path):
    m = json.loads((data_copy / "manifest.json").read_text())
    for entry in m["shards"] + m["labelings"][0]["shards"]:
        _rewrite_old_way(data_copy / entry["path"])
        entry["sha256"] = sha256_file(data_copy / entry["path"])
        entry["size_bytes"] = (data_copy / entry["path"]).stat().st_size
        entry["schema_version"] = "1.0"
    m["labelings"][0]["schema_version"] = "1.0"
    (data_copy / "manifest.json").write_text(json.dumps(m))
    assert invoke("verify", data_copy).exit_code == 0
    assert invoke("inspect", data_copy).exit_code == 0
    result = invoke("label", data_copy, "--max-slope-deg", "8", "--workers", "1")
    assert result.exit_code == 0, result.output
    result = train(data_copy, tmp_path / "run", "--labels", read_manifest(data_copy)["labelings"][0]["name"])
    assert result.exit_code == 0, result.output


# ------------------------------------------------------------------------------------- hostile file types
@pytest.mark.parametrize("what", ["scan-shard", "label-shard", "manifest", "dtm"])
def test_a_pipe_in_place_of_a_file_never_hangs(data_copy, tmp_path, what):
    path = {
        "scan-shard": data_copy / "shards" / "scans-00001.h5",
        "label-shard": label_shard(data_copy),
        "manifest": data_copy / "manifest.json",
        "dtm": tmp_path / "pipe.tif",
    }[what]
    path.unlink(missing_ok=True)
    os.mkfifo(path)
    if what == "dtm":
        result = invoke("build-dataset", "--out", tmp_path / "new", "--dtm", path)
        assert_one_line_error(result, "not a regular file")
        return
    result = invoke("verify", data_copy)
    assert result.exit_code == 1 and "not a regular file" in result.output
    if what == "scan-shard":
        assert_one_line_error(
            invoke("label", data_copy, "--max-slope-deg", "8", "--workers", "1"), "not a regular file"
        )
    if what == "label-shard":
        assert_one_line_error(train(data_copy, tmp_path / "run"), "not a regular file")


def test_a_lock_file_linked_to_another_file_is_never_written_through(data_copy, tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (data_copy / ".hd-lock").symlink_to(victim)
    assert_one_line_error(invoke("label", data_copy, "--max-slope-deg", "8", "--workers", "1"), "cannot lock")
    (data_copy / ".hd-lock").unlink()
    os.link(victim, data_copy / ".hd-lock")
    assert_one_line_error(invoke("label", data_copy, "--max-slope-deg", "8", "--workers", "1"), "not a plain file")
    assert victim.read_text() == "precious"


def test_a_labels_directory_linked_outside_is_refused(data_copy, tmp_path):
    outside = tmp_path / "elsewhere"
    before = sorted(p.name for p in (data_copy / "labels").iterdir())
    shutil.move(data_copy / "labels", outside)
    (data_copy / "labels").symlink_to(outside)
    assert_one_line_error(invoke("label", data_copy, "--max-slope-deg", "8", "--workers", "1"), "symbolic link")
    assert sorted(p.name for p in outside.iterdir()) == before  # no new labelling written through the link


def test_a_dtm_changed_during_an_interrupted_build_is_not_mixed_in(tmp_path, monkeypatch):
    from reliability_kit import BUILD_ARGS, hills

    import lidarsim.build as build

    dtm = hills(tmp_path / "dtm.tif")
    out = tmp_path / "data"
    real = build.run_shard
    calls: list[object] = []

    def stop_after_two(task):
        if len(calls) == 2:
            raise KeyboardInterrupt
        calls.append(task)
        return real(task)

    monkeypatch.setattr(build, "run_shard", stop_after_two)
    assert invoke("build-dataset", "--out", out, "--dtm", dtm, "--workers", "1", *BUILD_ARGS).exit_code == 130
    monkeypatch.undo()
    hills(dtm, seed=11)  # the user replaces the terrain file before resuming
    result = invoke("build-dataset", "--out", out, "--dtm", dtm, "--workers", "1", *BUILD_ARGS)
    assert result.exit_code == 0 and "already complete" not in result.output, result.output
    fresh = tmp_path / "fresh"
    assert invoke("build-dataset", "--out", fresh, "--dtm", dtm, "--workers", "1", *BUILD_ARGS).exit_code == 0
    from reliability_kit import shard_sums

    assert shard_sums(out) == shard_sums(fresh)


@pytest.mark.parametrize("lie", ["longer", "shorter"])
def test_a_server_that_lies_about_content_length_is_one_line_and_leaves_no_file(labelled, tmp_path, lie):
    """A server whose Content-Length of a shard is a block longer than what it sends before it closes, or
    half of what it sends: hd pull and hd verify of the URL end in one line naming the shard; the pull keeps
    no byte of it (no shard, no partial file)."""
    from lidarsim.location import forget_remotes
    from tests.remote_servers import LyingLengthHandler, http_server

    shard = read_manifest(labelled)["shards"][1]["path"]
    forget_remotes()
    with http_server(labelled.parent, LyingLengthHandler, faults={shard.rsplit("/", 1)[-1]: lie}) as (base, server):
        url = f"{base}/{labelled.name}"
        pulled = invoke("pull", url, tmp_path / "copy")
        checked = invoke("verify", url)
    forget_remotes()
    assert any(shard in path for path in server.requests)  # the lie was told
    assert_one_line_error(pulled, Path(shard).name)
    assert_one_line_error(checked, "problem") and Path(shard).name in checked.output
    assert not (tmp_path / "copy" / shard).exists() and not (tmp_path / "copy" / "manifest.json").exists()
    assert [p for p in (tmp_path / "copy").rglob("*") if ".partial" in p.name] == []
