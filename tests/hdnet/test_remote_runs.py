"""hd train, hd eval and hd detect --data of a dataset at a URL, against a real S3 API server (moto)
and a real HTTP server with Range requests: a tiny run and its evaluation give what the local copy
gives, bit for bit (weights, metrics, report numbers); only the recorded dataset location differs.
hd label of a URL is refused in one line that says what to do; bad URLs get one line.
"""

from __future__ import annotations

import json
import shutil
import socket
from pathlib import Path
from typing import Any

import pytest
import torch
from click.testing import CliRunner
from hdnet_datasets import build_labelled

from hdcli.cli import main
from lidarsim.shards import read_manifest
from tests.remote_servers import http_server, make_bucket, s3_server, upload_tree

S3_URL = "s3://hd-data/runs/tiny"


def invoke(*args: object) -> tuple[int, str]:
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert "Traceback" not in result.output, result.output
    return result.exit_code, result.output


def one_line_error(output: str) -> str:
    last = output.strip().splitlines()[-1]
    assert last.startswith("Error: "), output
    return last


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """A tiny labelled dataset: 20 scans of 48 x 48 px in 2 shards, two noise levels."""
    return build_labelled(tmp_path_factory.mktemp("remote-runs") / "b")


@pytest.fixture(scope="module")
def s3(dataset):
    """The S3 server, holding the dataset at S3_URL (uploaded as `aws s3 sync` would)."""
    with s3_server() as endpoint:
        make_bucket("hd-data")
        upload_tree(dataset, "hd-data", "runs/tiny")
        yield endpoint


@pytest.fixture(scope="module")
def http(dataset):
    """An HTTP server of the dataset's parent directory: the dataset at BASE/b."""
    with http_server(dataset.parent) as (base, server):
        yield f"{base}/{dataset.name}", server


@pytest.fixture(scope="module")
def local_run(dataset, tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("local-run") / "run"
    code, out = invoke("train", dataset, "--out", run, "--profile", "tiny", "--epochs", "1")
    assert code == 0, out
    return run


def weights(run: Path) -> dict[str, Any]:
    return torch.load(run / "last.pt", map_location="cpu", weights_only=False)


def metrics(run: Path) -> list[list[str]]:
    """metrics.csv's rows as written, without train_images_per_s (a wall-clock figure)."""
    rows = [line.split(",") for line in (run / "metrics.csv").read_text().splitlines()]
    drop = rows[0].index("train_images_per_s")
    return [row[:drop] + row[drop + 1 :] for row in rows]


def same(a: Any, b: Any, where: str = "") -> None:
    """a and b hold the same values, tensors bit for bit."""
    assert type(a) is type(b), where
    if isinstance(a, torch.Tensor):
        assert a.dtype == b.dtype and torch.equal(a, b), where
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for key in a:
            same(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            same(x, y, f"{where}[{i}]")
    else:
        assert a == b, where


def without_location(value: Any) -> Any:
    """A report or record without the fields that name where the dataset and the run lie."""
    if isinstance(value, dict):
        return {
            k: without_location(v)
            for k, v in value.items()
            if k not in {"dataset", "checkpoint", "calibration_dataset", "calibration_datasets"}
        }
    if isinstance(value, list):
        return [without_location(v) for v in value]
    return value


@pytest.mark.parametrize("where", ["s3", "http"])
def test_a_tiny_run_from_a_url_is_the_local_copys_bit_for_bit(dataset, s3, http, local_run, tmp_path, where):
    url = S3_URL if where == "s3" else http[0]
    run = tmp_path / "run"
    code, out = invoke("train", url, "--out", run, "--profile", "tiny", "--epochs", "1")
    assert code == 0, out
    assert metrics(run) == metrics(local_run)
    a, b = weights(local_run), weights(run)
    assert b["extra_config"].pop("dataset") == url and a["extra_config"].pop("dataset") == str(dataset.resolve())
    for ckpt in (a, b):  # wall-clock figures, and the digest of a content that names the dataset's location
        del ckpt["timing"], ckpt["content_sha256"]
    same(a, b)  # weights, optimizer state, random states, history, the rest of the training record
    config = json.loads((run / "config.json").read_text())
    local_config = json.loads((local_run / "config.json").read_text())
    assert config["extra_config"]["dataset"] == url
    assert config["extra_config"]["manifest_sha256"] == local_config["extra_config"]["manifest_sha256"]
    assert without_location(config) == without_location(local_config)
    code, out = invoke("train", url, "--out", run, "--profile", "tiny", "--epochs", "1")
    assert code == 0 and "already holds this training" in out, out  # the URL's run is recognised as done


@pytest.mark.parametrize("where", ["s3", "http"])
def test_eval_of_a_url_reports_the_local_copys_numbers(dataset, s3, http, local_run, tmp_path, where):
    url = S3_URL if where == "s3" else http[0]
    args = ["--mc-samples", "2", "--drop-pixels", "3"]
    code, out = invoke("eval", local_run, "--data", dataset, "--out", tmp_path / "local", *args)
    assert code == 0, out
    code, out = invoke("eval", local_run, "--data", url, "--out", tmp_path / "remote", *args)
    assert code == 0, out
    local = json.loads((tmp_path / "local" / "report.json").read_text())
    remote = json.loads((tmp_path / "remote" / "report.json").read_text())
    assert remote["run"]["dataset"] == url and local["run"]["dataset"] == str(dataset.resolve())
    assert remote["run"]["manifest_sha256"] == local["run"]["manifest_sha256"]
    assert remote["run"]["same_dataset_as_training"] is True
    assert without_location(remote) == without_location(local)


def test_detect_of_a_scan_at_a_url_writes_the_local_copys_maps(dataset, s3, local_run, tmp_path):
    args = ["--scan", "17", "--sigma", "0.0167", "--mc-samples", "2"]
    code, out = invoke("detect", local_run, "--data", dataset, "--out", tmp_path / "local", *args)
    assert code == 0, out
    code, out = invoke("detect", local_run, "--data", S3_URL, "--out", tmp_path / "remote", *args)
    assert code == 0, out
    local, remote = tmp_path / "local", tmp_path / "remote"
    arrays = sorted(p.name for p in local.iterdir() if p.suffix in {".tif", ".npy", ".npz", ".csv", ".geojson"})
    assert arrays and arrays == sorted(p.name for p in remote.iterdir() if p.name in arrays)
    for name in arrays:
        assert (remote / name).read_bytes() == (local / name).read_bytes(), name
    a = json.loads((local / "detect.json").read_text())
    b = json.loads((remote / "detect.json").read_text())
    assert b["input"]["dataset"] == S3_URL
    assert b["input"]["manifest_sha256"] == a["input"]["manifest_sha256"]


def test_label_of_a_url_is_refused_in_one_line_that_says_what_to_do(s3):
    code, out = invoke("label", S3_URL)
    last = one_line_error(out)
    assert code == 1 and f"hd pull {S3_URL} DIR" in last and "hd label DIR" in last and "hd publish" in last, out
    code, out = invoke("label", "s3://no-such-bucket/x")  # the URL is read first: its own error
    assert code == 1 and "no such bucket 'no-such-bucket'" in one_line_error(out), out


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_bad_urls_get_one_line_from_train_eval_and_detect(dataset, s3, local_run, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    label_shard = read_manifest(copy)["labelings"][0]["shards"][0]["path"]
    (copy / label_shard).unlink()  # the DEMs training reads
    upload_tree(copy, "hd-data", "runs/holes")
    (tmp_path / "notes" / "x").mkdir(parents=True)
    (tmp_path / "notes" / "x" / "notes.txt").write_text("not a dataset")
    upload_tree(tmp_path / "notes", "hd-data", "runs/notes")
    cases = {
        "s3://no-such-bucket/x": "no such bucket 'no-such-bucket'",
        f"http://127.0.0.1:{free_port()}/data": "cannot reach the host",
        "s3://hd-data/runs/notes/x": "not an hd dataset",
        "s3://hd-data/nothing/here": "no dataset there",
    }
    for url, needle in cases.items():
        for argv in (
            ["train", url, "--out", tmp_path / "run", "--profile", "tiny", "--epochs", "1"],
            ["eval", local_run, "--data", url, "--out", tmp_path / "report", "--mc-samples", "2"],
            ["detect", local_run, "--data", url, "--scan", "17", "--out", tmp_path / "maps"],
        ):
            code, out = invoke(*argv)
            last = one_line_error(out)
            assert code == 1 and needle in last, (argv, out)
        assert not (tmp_path / "run").exists() and not (tmp_path / "report").exists()
    code, out = invoke("train", "s3://hd-data/runs/holes", "--out", tmp_path / "run", "--profile", "tiny")
    last = one_line_error(out)
    assert code == 1 and Path(label_shard).name in last and "missing" in last, out
    assert not (tmp_path / "run").exists()


def test_no_credentials_for_train_is_one_line(s3, tmp_path, monkeypatch):
    from lidarsim.location import forget_remotes

    monkeypatch.delenv("AWS_ACCESS_KEY_ID")
    monkeypatch.delenv("AWS_SECRET_ACCESS_KEY")
    forget_remotes()  # a new process would make its file system anew
    try:
        code, out = invoke("train", S3_URL, "--out", tmp_path / "run", "--profile", "tiny", "--epochs", "1")
    finally:
        monkeypatch.undo()
        forget_remotes()
    last = one_line_error(out)
    assert code == 1 and "no credentials for s3://" in last and "AWS_ACCESS_KEY_ID" in last, out
    assert not (tmp_path / "run").exists()
