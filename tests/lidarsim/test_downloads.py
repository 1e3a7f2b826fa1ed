"""Bounded downloads: the manifest records every file's size (1.4) and hd verify checks it; pull and
remote reads refuse a server that sends more and stop at the recorded size; every manifest path is
checked before a byte is fetched; hd's own connect and idle-read timeouts; static servers without
range requests; hd card without a recipe; a bucket whose name contains "bucket". Against real servers
(tests/remote_servers.py).
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from hdcli.cli import main
from lidarsim import location, transfer
from lidarsim.shards import read_manifest
from tests.hdnet.hdnet_datasets import build_labelled
from tests.remote_servers import MisbehavingHandler, PlainHandler, http_server, make_bucket, s3_server


def invoke(*args: object) -> tuple[int, str]:
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert "Traceback" not in result.output, result.output
    return result.exit_code, result.output


def last_line(output: str) -> str:
    return output.strip().splitlines()[-1]


def entries(manifest: Any) -> list[Any]:
    return manifest["shards"] + [e for lab in manifest["labelings"] for e in lab["shards"]]


def files_of(dataset: Path) -> dict[str, bytes]:
    return {e["path"]: (dataset / e["path"]).read_bytes() for e in entries(read_manifest(dataset))}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """A tiny labelled dataset (2 scan shards, 2 label shards) beside its terrain, hills.tif."""
    return build_labelled(tmp_path_factory.mktemp("downloads") / "b")


@pytest.fixture(autouse=True)
def fresh_remotes(monkeypatch):
    for name in (location.CONNECT_TIMEOUT_ENV, location.READ_TIMEOUT_ENV):
        monkeypatch.delenv(name, raising=False)
    location.forget_remotes()
    yield
    location.forget_remotes()


def test_the_manifest_records_every_files_size(dataset):
    m = read_manifest(dataset)
    assert m["schema_version"] == "1.4"
    assert len(entries(m)) == 4
    for e in entries(m):
        assert e["size_bytes"] == (dataset / e["path"]).stat().st_size > 0


def test_verify_names_a_size_mismatch_and_reads_manifests_without_sizes(dataset, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    m = json.loads((copy / "manifest.json").read_text())
    size = m["shards"][1]["size_bytes"]
    with open(copy / "shards" / "scans-00001.h5", "ab") as fh:
        fh.write(b"\0" * 10)
    code, out = invoke("verify", copy)
    assert code == 1 and f"shards/scans-00001.h5: {size + 10} bytes, the manifest records {size}" in out, out
    (copy / "shards" / "scans-00001.h5").write_bytes((dataset / "shards" / "scans-00001.h5").read_bytes())
    for e in entries(m):  # a manifest written before 1.4
        del e["size_bytes"]
    m["schema_version"] = "1.0"
    (copy / "manifest.json").write_text(json.dumps(m))
    code, out = invoke("verify", copy)
    assert code == 0 and "OK, 4 files match" in out, out


def test_pull_stops_at_the_recorded_size_of_a_server_that_sends_more(dataset, tmp_path, monkeypatch):
    written: list[int] = []
    write_all = transfer.atomic._write_all

    def counting(fd: int, block: bytes) -> None:
        written.append(len(block))
        write_all(fd, block)

    monkeypatch.setattr(transfer.atomic, "_write_all", counting)
    sizes = {e["path"]: e["size_bytes"] for e in entries(read_manifest(dataset))}
    faults = {"scans-00001.h5": "more"}  # the file, then up to 64 MiB of zeros
    with http_server(dataset.parent, MisbehavingHandler, faults=faults) as (base, server):
        code, out = invoke("pull", f"{base}/dataset", tmp_path / "copy")
        sent = server.bytes_sent
    line = last_line(out)
    recorded = sizes["shards/scans-00001.h5"]
    assert code == 1 and "shards/scans-00001.h5" in line, out
    assert f"the server sent more than the {recorded} bytes the manifest records" in line, out
    assert sum(written) <= sizes["shards/scans-00000.h5"] + recorded  # the first shard, then at most the recorded size
    assert sent < 32 << 20, sent  # hd stopped reading: the server could not send its 64 MiB
    assert not (tmp_path / "copy" / "shards" / "scans-00001.h5").exists()
    assert not list((tmp_path / "copy" / "shards").glob(".scans-00001.h5.partial-*"))


def test_a_server_silent_mid_body_ends_in_the_idle_read_timeout(dataset, tmp_path, monkeypatch):
    monkeypatch.setenv(location.READ_TIMEOUT_ENV, "1")
    with http_server(dataset.parent, MisbehavingHandler, faults={"scans-00000.h5": "silent"}) as (base, _):
        t0 = time.monotonic()
        code, out = invoke("pull", f"{base}/dataset", tmp_path / "copy")
        elapsed = time.monotonic() - t0
    line = last_line(out)
    assert code == 1 and "scans-00000.h5" in line, out
    assert "the server sent nothing for 1 s (hd's idle-read timeout, HD_READ_TIMEOUT_S" in line, out
    assert elapsed < 15, elapsed


def test_a_slow_server_that_keeps_sending_is_not_cut(dataset, tmp_path, monkeypatch):
    monkeypatch.setenv(location.READ_TIMEOUT_ENV, "1")
    faults = {"scans-00000.h5": "slow"}
    with http_server(dataset.parent, MisbehavingHandler, faults=faults, slow_blocks=5, slow_pause_s=0.4) as (base, _):
        t0 = time.monotonic()
        code, out = invoke("pull", f"{base}/dataset", tmp_path / "copy")
        elapsed = time.monotonic() - t0
    assert code == 0 and "all checked" in out, out
    assert elapsed > 1.5  # the shard took longer than the idle-read timeout, in parts each within it
    assert files_of(tmp_path / "copy") == files_of(dataset)


def test_a_traversing_dtm_path_is_refused_before_any_file_is_fetched(dataset, tmp_path):
    served = tmp_path / "served"
    shutil.copytree(dataset.parent, served)
    m = json.loads((served / "dataset" / "manifest.json").read_text())
    m["dtm"]["path"] = "../hills.tif"
    (served / "dataset" / "manifest.json").write_text(json.dumps(m))
    with http_server(served, PlainHandler) as (base, server):
        for args in (("pull", f"{base}/dataset", tmp_path / "copy"), ("verify", f"{base}/dataset")):
            code, out = invoke(*args)
            assert code == 1 and "dtm.path" in last_line(out) and "leaves the dataset" in last_line(out), out
        asked = list(server.requests)
    assert asked and all(path.endswith("/manifest.json") for path in asked), asked
    assert not (tmp_path / "copy").exists()


def test_a_static_server_without_ranges_serves_pull_verify_and_inspect(dataset, tmp_path, monkeypatch):
    """``python -m http.server``'s handler answers every GET with the whole file; with blocks of 64 kB
    every shard is larger than the blocks hd would ask for as ranges."""
    monkeypatch.setattr(location, "STREAM_BYTES", 1 << 16)
    monkeypatch.setattr(location, "BLOCK_BYTES", 1 << 16)
    monkeypatch.setattr(location, "WHOLE_FILE_BLOCKS", 1)
    code, local = invoke("inspect", dataset)
    assert code == 0, local
    with http_server(dataset.parent, PlainHandler) as (base, _):
        url = f"{base}/dataset"
        code, out = invoke("verify", url)
        assert code == 0 and f"{url}: OK, 4 files match" in out, out
        code, remote = invoke("inspect", url)
        assert code == 0 and "unknown" not in remote and "range requests" not in remote, remote
        same = [line for line in remote.splitlines() if not line.startswith("dataset ")]
        assert same == [line for line in local.splitlines() if not line.startswith("dataset ")]
        code, out = invoke("pull", url, tmp_path / "copy")
        assert code == 0 and "all checked" in out, out
    assert files_of(tmp_path / "copy") == files_of(dataset)


def test_card_of_a_dataset_without_its_recipe_is_one_line(dataset, tmp_path):
    code, out = invoke("card", dataset)
    assert code == 2 and last_line(out).startswith("Error: Missing option '--recipe'"), out
    copy = tmp_path / "damaged"
    shutil.copytree(dataset, copy)
    shard = copy / "shards" / "scans-00000.h5"
    shard.write_bytes(shard.read_bytes()[:-10])
    code, out = invoke("card", copy)
    assert code == 2 and last_line(out).startswith("Error: Missing option '--recipe'"), out
    code, out = invoke("card", copy, "--recipe", "mars-paper")
    assert code == 1 and "was not built from" in last_line(out) and len(out.strip().splitlines()) == 1, out


def test_publish_and_pull_with_a_bucket_named_bucket(dataset, tmp_path):
    with s3_server():
        make_bucket("team-bucket")
        code, out = invoke("publish", dataset, "s3://team-bucket/hd/data")  # the README's own example
        assert code == 0 and "published" in out, out
        code, out = invoke("pull", "s3://team-bucket/hd/data", tmp_path / "copy")
        assert code == 0 and "all checked" in out, out
        code, out = invoke("verify", "s3://team-bucket/hd/nothing")
        assert code == 1 and "no dataset there (nothing at that URL)" in last_line(out), out
        code, out = invoke("verify", "s3://no-such-bucket/hd/data")
        assert code == 1 and "no such bucket 'no-such-bucket'" in last_line(out), out
    assert files_of(tmp_path / "copy") == files_of(dataset)


def test_timeouts_are_named_and_a_bad_setting_is_one_line(monkeypatch):
    import aiohttp

    url = "https://host/data"
    exc = aiohttp.ConnectionTimeoutError("Connection timeout to host https://host/data")
    assert str(location.remote_error(url, exc)) == (
        f"{url}: no connection within 30 s (hd's connect timeout, HD_CONNECT_TIMEOUT_S)"
    )
    monkeypatch.setenv(location.READ_TIMEOUT_ENV, "2.5")
    wrapped = RuntimeError("FSTimeoutError")
    wrapped.__cause__ = aiohttp.SocketTimeoutError("Timeout on reading data from socket")
    assert "the server sent nothing for 2.5 s (hd's idle-read timeout" in str(location.remote_error(url, wrapped))
    assert location.storage_options("s3://b/x", location.timeouts()) == {
        "config_kwargs": {"connect_timeout": 30.0, "read_timeout": 2.5}
    }
    monkeypatch.setenv(location.CONNECT_TIMEOUT_ENV, "abc")
    code, out = invoke("verify", "http://127.0.0.1:9/data")
    assert code == 1 and last_line(out) == "Error: HD_CONNECT_TIMEOUT_S='abc': not a number of seconds > 0", out
