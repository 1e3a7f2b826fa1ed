"""Datasets read where they lie: hd inspect and hd verify of a URL, against a real S3 API server
(moto) and a real HTTP server with Range requests, give what they give for the local copy; the
training read loop (``hdnet.data.HazardDataset``) reads the same arrays, bit for bit; bad URLs get
one line.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import socket
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from hdcli.cli import main
from lidarsim.shards import read_manifest
from tests.hdnet.hdnet_datasets import build_labelled
from tests.remote_servers import http_server, make_bucket, s3_server, upload_tree


def invoke(*args: object) -> tuple[int, str]:
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert "Traceback" not in result.output, result.output
    return result.exit_code, result.output


def one_line_error(output: str) -> str:
    last = output.strip().splitlines()[-1]
    assert last.startswith("Error: "), output
    return last


def dataset_files(dataset: Path) -> list[str]:
    m = read_manifest(dataset)
    return [e["path"] for e in m["shards"]] + [e["path"] for lab in m["labelings"] for e in lab["shards"]]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """A tiny labelled dataset: 20 scans of 48 x 48 px in 2 shards, two noise levels."""
    return build_labelled(tmp_path_factory.mktemp("remote") / "b")


@pytest.fixture(scope="module")
def s3(dataset):
    """The S3 server, holding the dataset at s3://hd-data/team/tiny (uploaded as `aws s3 sync` would)."""
    with s3_server() as endpoint:
        make_bucket("hd-data")
        upload_tree(dataset, "hd-data", "team/tiny")
        yield endpoint


@pytest.fixture(scope="module")
def http(dataset, tmp_path_factory):
    """An HTTP server of the dataset's parent directory: the dataset at BASE/dataset."""
    with http_server(dataset.parent) as (base, server):
        yield f"{base}/dataset", server


def without_dataset_line(text: str) -> list[str]:
    return [line for line in text.splitlines() if not line.startswith("dataset ")]


@pytest.mark.parametrize("where", ["s3", "http"])
def test_inspect_and_verify_of_a_url_say_what_they_say_of_the_local_copy(dataset, s3, http, where):
    url = "s3://hd-data/team/tiny" if where == "s3" else http[0]
    code, local = invoke("inspect", dataset)
    assert code == 0, local
    code, remote = invoke("inspect", url)
    assert code == 0, remote
    assert f"dataset   {url}" in remote
    assert without_dataset_line(remote) == without_dataset_line(local)
    code, local_json = invoke("inspect", "--json", dataset)
    code, remote_json = invoke("inspect", "--json", url + "/")  # a trailing slash is the same URL
    assert code == 0, remote_json
    a, b = json.loads(local_json), json.loads(remote_json)
    assert b.pop("dataset") == url and a.pop("dataset") == str(dataset.resolve())
    assert a == b
    code, out = invoke("verify", url)
    assert code == 0 and f"{url}: OK, 4 files match" in out, out


def test_verify_of_a_url_reads_each_byte_once(dataset, http):
    url, server = http
    sizes = sum((dataset / rel).stat().st_size for rel in dataset_files(dataset))
    manifest = (dataset / "manifest.json").stat().st_size
    before = server.bytes_sent
    code, out = invoke("verify", url)
    assert code == 0, out
    sent = server.bytes_sent - before
    assert sizes <= sent <= sizes + 3 * manifest, (sent, sizes, manifest)  # the manifest is small and read twice


def test_one_scan_of_a_url_is_read_without_the_whole_shard(dataset, http, monkeypatch):
    from lidarsim import location
    from lidarsim.shards import open_scan_shard

    monkeypatch.setattr(location, "BLOCK_BYTES", 1 << 16)  # blocks of 64 kB: this shard is ~0.7 MB
    url, server = http
    entry = read_manifest(dataset)["shards"][0]
    size = (dataset / entry["path"]).stat().st_size
    before = server.bytes_sent
    with open_scan_shard(url, entry) as remote, open_scan_shard(dataset, entry) as local:
        scan = remote[3]
        want = local[3]
    assert np.array_equal(scan.points_noisy, want.points_noisy, equal_nan=True)
    assert scan.scan_index == want.scan_index
    read = server.bytes_sent - before
    assert read < size / 2, (read, size)  # the block cache fetched the metadata and scan 3's chunks


def test_the_training_read_loop_reads_a_url_bit_for_bit(dataset, s3):
    from hdnet.data import HazardDataset

    url = "s3://hd-data/team/tiny"
    local = HazardDataset(dataset, "train", 0.0167, input_size=64)
    remote = HazardDataset(url, "train", 0.0167, input_size=64)
    assert remote.normalisation == local.normalisation and len(remote) == len(local) == 16
    for i in range(len(local)):
        a, b = local[i], remote[i]
        assert a.keys() == b.keys()
        for key in a:
            assert np.array_equal(np.asarray(a[key]), np.asarray(b[key]), equal_nan=True), key
    remote.close()
    local.close()


def test_a_damaged_shard_at_a_url_is_named_by_verify(dataset, s3, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    shard = copy / read_manifest(copy)["shards"][1]["path"]
    data = bytearray(shard.read_bytes())
    data[len(data) // 2] ^= 0xFF
    shard.write_bytes(bytes(data))
    upload_tree(copy, "hd-data", "team/damaged")
    code, out = invoke("verify", "s3://hd-data/team/damaged")
    assert code == 1 and "scans-00001.h5: checksum mismatch" in out, out
    assert one_line_error(out) == "Error: s3://hd-data/team/damaged: 1 problem(s) found"


def test_a_manifest_naming_a_missing_shard_is_one_line(dataset, s3, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    (copy / read_manifest(copy)["shards"][0]["path"]).unlink()
    upload_tree(copy, "hd-data", "team/holes")
    code, out = invoke("verify", "s3://hd-data/team/holes")
    assert code == 1 and "shards/scans-00000.h5: missing" in out, out
    code, out = invoke("inspect", "s3://hd-data/team/holes")
    assert code == 1 and "shards/scans-00000.h5: missing" in out, out


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_bad_urls_get_one_line(s3, tmp_path, monkeypatch):
    cases = {
        "s3://no-such-bucket/x": "no such bucket 'no-such-bucket'",
        "s3://hd-data/nothing/here": "no dataset there (nothing at that URL)",
        f"http://127.0.0.1:{free_port()}/data": "cannot reach the host",
    }
    (tmp_path / "notes.txt").write_text("not a dataset")
    with http_server(tmp_path) as (base, _):
        cases[f"{base}/notes.txt"] = "no dataset there"  # a file, not a folder of one
        upload_tree(tmp_path, "hd-data", "team/notes")
        cases["s3://hd-data/team/notes"] = "not an hd dataset (no manifest.json; it holds 1 other file)"
        for url, needle in cases.items():
            code, out = invoke("verify", url)
            last = one_line_error(out)
            assert code == 1 and url in last and any(n in last for n in needle.split("|")), (url, out)


def test_no_credentials_is_one_line(s3, monkeypatch):
    monkeypatch.delenv("AWS_ACCESS_KEY_ID")
    monkeypatch.delenv("AWS_SECRET_ACCESS_KEY")
    from lidarsim import location

    location._remote.cache_clear()  # a new process would make its file system anew
    import fsspec

    fsspec.filesystem("s3").clear_instance_cache()
    code, out = invoke("inspect", "s3://hd-data/team/tiny")
    last = one_line_error(out)
    assert code == 1 and "no credentials for s3://" in last and "AWS_ACCESS_KEY_ID" in last, out
    location._remote.cache_clear()
    fsspec.filesystem("s3").clear_instance_cache()


def test_an_unreachable_s3_endpoint_is_one_line(s3, monkeypatch):
    monkeypatch.setenv("AWS_ENDPOINT_URL_S3", f"http://127.0.0.1:{free_port()}")
    monkeypatch.setenv("AWS_MAX_ATTEMPTS", "1")
    from lidarsim import location

    location._remote.cache_clear()
    import fsspec

    fsspec.filesystem("s3").clear_instance_cache()
    code, out = invoke("verify", "s3://hd-data/team/tiny")
    last = one_line_error(out)
    assert code == 1 and "cannot reach the host" in last, out
    location._remote.cache_clear()
    fsspec.filesystem("s3").clear_instance_cache()


def test_a_url_where_a_local_path_is_needed_names_the_commands_that_read_urls(tmp_path):
    code, out = invoke("build-dataset", "--out", "s3://bucket/new")
    assert code == 2 and "s3://bucket/new is a URL" in out and "hd pull URL DIR" in out, out
    assert not os.path.exists("s3:")


def test_the_user_guides_reader_without_hd_runs_against_s3(dataset, s3, capsys):
    """The snippet of docs/user-guide.md ("Sharing a dataset"), as printed, with the test's URL."""
    import re

    guide = (Path(__file__).resolve().parents[2] / "docs" / "user-guide.md").read_text()
    section = guide[guide.index("## Sharing a dataset") :]
    code = re.findall(r"```python\n(.*?)```", section, re.S)[0]
    assert 'url = "s3://team-bucket/hd/data"' in code
    exec(code.replace("s3://team-bucket/hd/data", "s3://hd-data/team/tiny"), {})
    printed = capsys.readouterr().out
    assert printed.strip() == "hd.lidar-scans (10, 2, 48, 48, 3)", printed


def test_a_small_shard_at_a_url_is_fetched_once_and_checked_against_the_manifest(dataset, http):
    """A file of at most WHOLE_FILE_BLOCKS blocks is fetched whole, once per process however often it
    is opened, and its sha256 checked in memory: altered bytes are named, never read."""
    from hdcore.errors import DamagedFileError
    from hdlabels.store import LabelShardEntry, open_label_shard
    from lidarsim import location

    url, server = http
    location.forget_remotes()
    entry = LabelShardEntry.from_json(read_manifest(dataset)["labelings"][0]["shards"][0], "shard", "1.1")
    size = (dataset / entry.path).stat().st_size
    assert size <= location.WHOLE_FILE_BLOCKS * location.BLOCK_BYTES
    before = server.bytes_sent
    for _ in range(3):
        with open_label_shard(url, entry) as remote, open_label_shard(dataset, entry) as local:
            assert np.array_equal(remote.h5["label"][2], local.h5["label"][2])
    assert server.bytes_sent - before == size  # one request for the whole file; the re-opens cost none
    location.forget_remotes()
    wrong = dataclasses.replace(entry, sha256="0" * 64)
    with pytest.raises(DamagedFileError, match=r"checksum mismatch .* the manifest says 000000000000"):
        open_label_shard(url, wrong)


@pytest.fixture
def s3_requests(s3, monkeypatch):
    """The requests the S3 server answers from now on: (method, object name, ranged) of each."""
    from moto.moto_server.werkzeug_app import DomainDispatcherApplication

    seen: list[tuple[str, str, bool]] = []
    answer = DomainDispatcherApplication.__call__

    def counting(self, environ, start_response):
        seen.append((environ["REQUEST_METHOD"], environ["PATH_INFO"].rsplit("/", 1)[-1], "HTTP_RANGE" in environ))
        return answer(self, environ, start_response)

    monkeypatch.setattr(DomainDispatcherApplication, "__call__", counting)
    return seen


def put_manifest(prefix: str, data: bytes) -> None:
    """Replace the manifest at s3://hd-data/PREFIX as another writer would (not through hd's file system)."""
    import boto3

    boto3.client("s3", endpoint_url=os.environ["AWS_ENDPOINT_URL_S3"]).put_object(
        Bucket="hd-data", Key=f"{prefix}/manifest.json", Body=data
    )


def test_a_dataset_set_up_again_asks_only_whether_its_manifest_changed(dataset, s3, s3_requests):
    """The manifest and the label shards are fetched by the first set-up; a second set-up in the same
    process sends one HEAD per manifest read and nothing else."""
    from hdnet.data import HazardDataset
    from lidarsim import location

    upload_tree(dataset, "hd-data", "team/again")
    url = "s3://hd-data/team/again"
    location.forget_remotes()
    first = HazardDataset(url, "train", 0.0167, input_size=64)
    a = first[0]
    first.close()
    fetched = [r for r in s3_requests if r[0] == "GET"]
    assert sorted(name for _, name, _ in fetched) == ["labels-00000.h5", "labels-00001.h5", "manifest.json"]
    del s3_requests[:]
    again = HazardDataset(url, "train", 0.0167, input_size=64)  # finds the labelling, normalises, reads
    b = again[0]
    again.close()
    assert s3_requests and set(s3_requests) == {("HEAD", "manifest.json", False)}, s3_requests
    assert len(s3_requests) == 1  # the labelling's entry, read once, also gives the normalisation
    assert all(np.array_equal(np.asarray(a[k]), np.asarray(b[k]), equal_nan=True) for k in a)


def test_a_manifest_replaced_at_the_url_is_read_by_the_next_set_up(dataset, s3, s3_requests):
    """Kept manifest bytes are given again only while the server reports the same size and ETag: a
    manifest replaced by another writer, also by one of the same size, is read anew."""
    from hdcore.storage import sha256_bytes
    from hdlabels.store import LabelStoreError
    from hdnet.data import HazardDataset
    from lidarsim.location import manifest_sha256

    upload_tree(dataset, "hd-data", "team/replaced")
    url = "s3://hd-data/team/replaced"
    original = (dataset / "manifest.json").read_bytes()
    assert manifest_sha256(url) == sha256_bytes(original)
    HazardDataset(url, "train", 0.0167, input_size=64).close()
    same_size = original[:-1] + (b" " if original[-1:] != b" " else b"\n")  # one byte other, as long
    assert len(same_size) == len(original) and same_size != original
    put_manifest("team/replaced", same_size)
    assert manifest_sha256(url) == sha256_bytes(same_size)
    unlabelled = json.loads(original)
    unlabelled["labelings"] = []
    put_manifest("team/replaced", json.dumps(unlabelled).encode())
    del s3_requests[:]
    with pytest.raises(LabelStoreError, match="the dataset has no labels"):
        HazardDataset(url, "train", 0.0167, input_size=64)
    assert ("GET", "manifest.json", True) in s3_requests
    put_manifest("team/replaced", original)
    HazardDataset(url, "train", 0.0167, input_size=64).close()  # labelled again


def test_the_version_of_a_file_is_its_strong_etag_or_content_hash():
    from lidarsim.location import content_version

    assert content_version({"size": 3, "ETag": '"9a0364b9e99bb480dd25e1f0284c8555"'}) is not None
    s3 = {"size": 3, "ETag": '"a"', "LastModified": "2026-01-01"}
    assert content_version(s3) != content_version(dict(s3, ETag='"b"'))
    assert content_version({"size": 3, "md5Hash": "x", "generation": 7}) == "md5Hash=x generation=7"
    assert content_version({"size": 3, "ETag": 'W/"a"'}) is None  # weak: may stay as the bytes change
    assert content_version({"size": 3, "Last-Modified": "Thu, 03 Dec 2026 08:00:00 GMT"}) is None
    assert content_version({"size": 3, "mtime": 1.5, "type": "file"}) is None  # a local file: read each time
