"""hd publish and hd pull against a real S3 API server (moto): the round trip is byte for byte, another
dataset is never replaced without --overwrite, and a publish or a pull killed (SIGKILL) at any
point leaves the URL with no dataset, the old one intact, or the new one complete, and the
directory resumable to the same bytes.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from hdcli.cli import main
from lidarsim.shards import read_manifest
from tests.hdnet.hdnet_datasets import build_labelled
from tests.remote_servers import make_bucket, s3_server

REPO = Path(__file__).resolve().parents[2]
FAULTS = REPO / "tests" / "reliability" / "faultinject"


def invoke(*args: object) -> tuple[int, str]:
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert "Traceback" not in result.output, result.output
    return result.exit_code, result.output


def tree(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` but the lock, by relative path."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def files_of(dataset: Path) -> dict[str, bytes]:
    m = read_manifest(dataset)
    names = [e["path"] for e in m["shards"]] + [e["path"] for lab in m["labelings"] for e in lab["shards"]]
    return {n: (dataset / n).read_bytes() for n in ["manifest.json", *names]}


def s3_keys(prefix: str) -> list[str]:
    import boto3

    client = boto3.client("s3", endpoint_url=os.environ["AWS_ENDPOINT_URL_S3"])
    bucket, _, key = prefix.partition("/")
    pages = client.get_paginator("list_objects_v2").paginate(Bucket=bucket, Prefix=key + "/")
    return sorted(o["Key"][len(key) + 1 :] for page in pages for o in page.get("Contents", []))


@pytest.fixture(scope="module")
def datasets(tmp_path_factory) -> tuple[Path, Path]:
    """Two tiny labelled datasets (20 and 10 scans): the one published, and another one."""
    root = tmp_path_factory.mktemp("transfer")
    return build_labelled(root / "a"), build_labelled(root / "b", n_scans=10)


@pytest.fixture(scope="module")
def s3():
    with s3_server() as endpoint:
        make_bucket("hd-pub")
        yield endpoint


def test_publish_then_pull_is_byte_for_byte(datasets, s3, tmp_path):
    a, _ = datasets
    code, out = invoke("publish", a, "s3://hd-pub/rt")
    assert code == 0 and "published" in out and "4 files and manifest.json" in out, out
    assert ".hd-publish.json" not in s3_keys("hd-pub/rt")
    code, out = invoke("publish", a, "s3://hd-pub/rt")
    assert code == 0 and "already holds this dataset" in out and "nothing sent" in out, out
    code, out = invoke("pull", "s3://hd-pub/rt", tmp_path / "copy")
    assert code == 0 and "all checked" in out, out
    assert files_of(tmp_path / "copy") == files_of(a)
    assert not list((tmp_path / "copy").glob(".hd-*"))
    code, out = invoke("pull", "s3://hd-pub/rt", tmp_path / "copy")  # already there: checked, kept
    assert code == 0 and "4 files already there" in out, out


def test_another_dataset_is_replaced_only_with_overwrite(datasets, s3, tmp_path):
    a, b = datasets
    assert invoke("publish", a, "s3://hd-pub/swap")[0] == 0
    before = s3_keys("hd-pub/swap")
    code, out = invoke("publish", b, "s3://hd-pub/swap")
    assert code == 1 and "holds another dataset" in out and "--overwrite" in out.strip().splitlines()[-1], out
    assert s3_keys("hd-pub/swap") == before
    code, out = invoke("pull", "s3://hd-pub/swap", tmp_path / "old")
    assert code == 0 and files_of(tmp_path / "old") == files_of(a)  # the old one, intact
    code, out = invoke("publish", "--overwrite", b, "s3://hd-pub/swap")
    assert code == 0, out
    assert invoke("pull", "s3://hd-pub/swap", tmp_path / "new")[0] == 0
    assert files_of(tmp_path / "new") == files_of(b)
    names = set(files_of(b))
    assert set(s3_keys("hd-pub/swap")) == names  # the old dataset's other files are gone
    code, out = invoke("pull", "s3://hd-pub/swap", tmp_path / "old")
    assert code == 1 and "holds another dataset" in out, out


def test_a_url_holding_other_files_is_refused(datasets, s3, tmp_path):
    import boto3

    boto3.client("s3", endpoint_url=os.environ["AWS_ENDPOINT_URL_S3"]).put_object(
        Bucket="hd-pub", Key="busy/report.pdf", Body=b"%PDF"
    )
    code, out = invoke("publish", datasets[0], "s3://hd-pub/busy")
    last = out.strip().splitlines()[-1]
    assert code == 1 and "holds 1 file and no hd dataset" in last, out
    assert s3_keys("hd-pub/busy") == ["report.pdf"]
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    assert invoke("publish", datasets[0], "s3://hd-pub/ok")[0] == 0
    code, out = invoke("pull", "s3://hd-pub/ok", tmp_path / "full")
    assert code == 1 and "is not empty" in out, out


def test_a_damaged_dataset_is_not_published(datasets, s3, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(datasets[0], copy)
    shard = copy / "shards" / "scans-00000.h5"
    shard.write_bytes(shard.read_bytes()[:-10])
    code, out = invoke("publish", copy, "s3://hd-pub/damaged")
    assert code == 1 and "is damaged" in out and "not published" in out, out
    assert s3_keys("hd-pub/damaged") == []


def hd(*args: object, env: dict[str, str]) -> subprocess.Popen:
    """``hd ARGS`` in its own process with the fault injector of tests/reliability loaded."""
    full = {**os.environ, "PYTHONPATH": f"{FAULTS}{os.pathsep}{REPO}", "HD_TEST_FAULTS": "1", **env}
    return subprocess.Popen(
        [sys.executable, "-m", "hdcli", *[str(a) for a in args]],
        env=full,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )


def kill_when(proc: subprocess.Popen, marker: Path, timeout_s: float = 60.0) -> None:
    """SIGKILL ``proc`` as soon as ``marker`` exists (the injected pause has begun)."""
    deadline = time.monotonic() + timeout_s
    while not marker.exists():
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
        assert time.monotonic() < deadline, "the pause never began"
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


@pytest.mark.parametrize("moment", ["_send_block", "_upload_manifest"])
def test_a_killed_publish_leaves_no_dataset_and_resumes(datasets, s3, tmp_path, moment):
    """Killed while a shard's bytes are handed over, or after every shard and before the manifest:
    the URL holds no dataset (a reader says a publication is under way), then a re-run completes."""
    a, _ = datasets
    url = f"s3://hd-pub/killed-{moment.strip('_')}"
    marks = tmp_path / "marks"
    marks.mkdir()
    faults = {"HD_TEST_SLEEP": f"lidarsim.transfer.{moment}:60", "HD_TEST_MARK_DIR": str(marks)}
    proc = hd("publish", a, url, env=faults)
    kill_when(proc, marks / moment)
    keys = s3_keys(url[len("s3://") :])
    assert "manifest.json" not in keys and ".hd-publish.json" in keys, keys
    if moment == "_upload_manifest":
        assert len(keys) == 5  # every shard and the mark
    code, out = invoke("inspect", url)
    assert code == 1 and "being published there, or its publication was interrupted" in out, out
    code, out = invoke("publish", a, url)
    assert code == 0, out
    if moment == "_upload_manifest":
        assert "4 files already there" in out, out
    assert invoke("pull", url, tmp_path / "copy")[0] == 0
    assert files_of(tmp_path / "copy") == files_of(a)


def test_a_killed_overwrite_leaves_no_dataset_never_a_mix(datasets, s3, tmp_path):
    a, b = datasets
    url = "s3://hd-pub/killed-overwrite"
    assert invoke("publish", a, url)[0] == 0
    marks = tmp_path / "marks"
    marks.mkdir()
    proc = hd(
        "publish",
        "--overwrite",
        b,
        url,
        env={"HD_TEST_SLEEP": "lidarsim.transfer._send_block:60", "HD_TEST_MARK_DIR": str(marks)},
    )
    kill_when(proc, marks / "_send_block")
    assert "manifest.json" not in s3_keys(url[len("s3://") :])
    code, out = invoke("verify", url)
    assert code == 1 and "being published" in out, out
    assert invoke("publish", "--overwrite", b, url)[0] == 0
    assert invoke("pull", url, tmp_path / "copy")[0] == 0
    assert files_of(tmp_path / "copy") == files_of(b)


def test_a_killed_pull_resumes_to_the_same_bytes(datasets, s3, tmp_path):
    a, _ = datasets
    url = "s3://hd-pub/pull-src"
    assert invoke("publish", a, url)[0] == 0
    out_dir = tmp_path / "copy"
    release = tmp_path / "never"
    proc = hd(
        "pull",
        url,
        out_dir,
        env={"HD_TEST_WRITE_PAUSE": "scans-00001.h5:60", "HD_TEST_RELEASE": str(release)},
    )
    deadline = time.monotonic() + 60
    while not list((out_dir / "shards").glob(".scans-00001.h5.partial-*")) if out_dir.exists() else True:
        assert proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.02)
    time.sleep(0.2)  # half of the shard written, the pause under way
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (out_dir / "manifest.json").exists()
    assert (out_dir / "shards" / "scans-00000.h5").is_file()
    code, out = invoke("inspect", out_dir)
    assert code == 1, out
    code, out = invoke("pull", url, out_dir)
    assert code == 0 and "1 file already there" in out, out
    assert files_of(out_dir) == files_of(a)
    assert set(tree(out_dir)) == set(files_of(a))  # no partial file, no mark, no lock left
    assert json.loads((out_dir / "manifest.json").read_text()) == read_manifest(a)


def test_a_local_folder_is_a_place_to_publish_to_and_pull_from(datasets, tmp_path, monkeypatch):
    source = datasets[0]
    code, text = invoke("publish", source, tmp_path / "shared" / "mars")  # a plain path, not yet there
    assert code == 0 and f"published {source} to file://" in text, text
    assert tree(tmp_path / "shared" / "mars") == files_of(source)  # the dataset's files and nothing else
    monkeypatch.chdir(tmp_path)
    code, text = invoke("publish", source, "shared/mars")  # relative: the same folder, already complete
    assert code == 0 and "already holds this dataset" in text and "nothing sent" in text, text
    code, text = invoke("pull", (tmp_path / "shared" / "mars").as_uri(), tmp_path / "copy")
    assert code == 0, text
    assert files_of(tmp_path / "copy") == files_of(source)


@pytest.mark.parametrize("where", ["{data}", "{data}/published", "{data}/.."])
def test_a_local_folder_that_is_holds_or_lies_in_the_dataset_is_refused(datasets, tmp_path, where):
    data = tmp_path / "data"
    shutil.copytree(datasets[1], data)
    before = tree(tmp_path)
    target = where.format(data=data)
    for url in (target, Path(os.path.abspath(target)).as_uri()):
        code, text = invoke("publish", data, url)
        lines = text.strip().splitlines()
        assert code == 1 and len(lines) == 1 and "the dataset" in lines[0] and "choose another URL" in lines[0], text
    assert tree(tmp_path) == before  # nothing written, nothing removed
