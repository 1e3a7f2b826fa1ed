"""Secrets in dataset URLs never leave memory (docs/reliability.md, "Secrets in URLs").

A unique marker is planted as the password of a dataset URL and as the value of its query tokens
(``?token=``, ``?X-Amz-Signature=``), and given to every command that takes a URL (inspect, verify,
label, train, eval --data, detect --data, pull, publish) and, refused, to those that take a local
path only (view, compare, mosaic, export, card, eval's run, --out). Every byte printed (stdout and
stderr, with and without ``hd --json``) and every file written (the run and its checkpoints, the
report, detect's output, the view pages, the pulled dataset and the mark of an interrupted pull) is
searched for the marker; so are the error lines of a URL whose host cannot be reached, that holds
nothing, or that the protocol refuses. The URLs are served by the suite's real HTTP server (which
ignores credentials and query strings, as a public server would) and S3 API server.
"""

from __future__ import annotations

import json
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest
from click.testing import CliRunner

from hdcli.cli import main
from hdcore.redact import is_redacted, printable_location, redact_text, redact_urls
from lidarsim.shards import read_manifest
from tests.hdnet.hdnet_datasets import build_labelled
from tests.remote_servers import (
    MisbehavingHandler,
    RecordingHandler,
    RedirectHandler,
    http_server,
    make_bucket,
    s3_server,
)

MARK = "Zq7SeCrEt"  # the secret: a password and every query value
DETECT_ARGS = ("--scan", "17", "--sigma", "0.0167", "--mc-samples", "2")


def secret_url(base: str, path: str) -> str:
    """``base`` (``http://host:port``) with the marker as password and as two query tokens."""
    scheme, rest = base.split("://", 1)
    return f"{scheme}://hduser:{MARK}@{rest}/{path}?token={MARK}&X-Amz-Signature={MARK}"


def hd(*args: object) -> tuple[int, str]:
    """``hd ARGS`` in this process: the exit status and every byte printed (stdout and stderr)."""
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert "Traceback" not in result.output, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    at = result.output.find(MARK)
    assert at == -1, (args[:2], result.output[max(0, at - 300) : at + 50])
    return result.exit_code, result.output


def both(*args: object) -> list[tuple[int, str]]:
    """``hd ARGS`` and ``hd --json ARGS``."""
    return [hd(*args), hd("--json", *args)]


def assert_no_secret_in_files(*roots: Path) -> int:
    """No file under ``roots`` holds the marker (bytes: JSON, Markdown, HTML, HDF5, pickles); returns
    the number of files searched."""
    files = [p for root in roots for p in sorted(root.rglob("*")) if p.is_file()]
    for path in files:
        assert MARK.encode() not in path.read_bytes(), path
    return len(files)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """A tiny labelled dataset: 20 scans of 48 x 48 px in 2 shards, two noise levels."""
    return build_labelled(tmp_path_factory.mktemp("secrets") / "b")


@pytest.fixture(scope="module")
def url(dataset) -> Iterator[str]:
    """The dataset at an HTTP URL that carries the marker."""
    with http_server(dataset.parent) as (base, _):
        yield secret_url(base, dataset.name)


@pytest.fixture(scope="module")
def run(url, tmp_path_factory) -> Path:
    """A tiny run trained on the secret URL."""
    out = tmp_path_factory.mktemp("secret-run") / "run"
    code, text = hd("train", url, "--out", out, "--profile", "tiny", "--epochs", "1")
    assert code == 0, text
    return out


# ------------------------------------------------------------------------------------ the one function
def test_printable_location_takes_out_user_information_query_values_and_fragment():
    assert printable_location("https://user:pw@host:8080/d") == "https://***@host:8080/d"
    assert printable_location("https://TOKEN@host/d") == "https://***@host/d"  # a token as the user name
    assert printable_location("https://host/d?X-Amz-Signature=abc&X-Amz-Expires=60") == (
        "https://host/d?X-Amz-Signature=***&X-Amz-Expires=***"
    )
    assert printable_location("https://host/d?abc") == "https://host/d?***"  # no key: a value
    assert printable_location("https://host/d#access_token=x") == "https://host/d#***"
    assert printable_location("https://host/d?") == "https://host/d?"
    assert printable_location("s3://bucket/prefix") == "s3://bucket/prefix"
    assert printable_location(Path("/data/a@b?c=d")) == "/data/a@b?c=d"  # a local path is unchanged
    assert printable_location("relative/x?y=z") == "relative/x?y=z"


def test_redacted_urls_are_known_as_such_and_secrets_are_taken_out_of_any_text():
    assert is_redacted("https://***@host/d") and is_redacted("https://host/d?sig=***")
    assert not is_redacted("https://host/d") and not is_redacted("/data/***")
    text = "404, url='http://u:pw0123@h/d/manifest.json?t=tok0123'; http:/u:pw0123@h/d is gone."
    assert redact_urls(text) == "404, url='http://***@h/d/manifest.json?t=***'; http:/***@h/d is gone."
    said = 'Invalid bucket name "key:pw0123@bucket"'  # a URL's secret quoted outside a URL
    assert redact_text(said, "s3://key:pw0123@bucket/d") == 'Invalid bucket name "***@bucket"'


# ------------------------------------------------------------------------------------ every command
def test_inspect_verify_and_label_of_a_secret_url_print_no_secret(url):
    for code, text in both("inspect", url):
        assert code == 0 and "hduser" not in text and "token=***" in text, text
    code, text = hd("inspect", "--json", url)
    assert code == 0 and json.loads(text)["dataset"].endswith("/dataset?token=***&X-Amz-Signature=***"), text
    code, text = hd("verify", url)
    assert code == 0 and "OK" in text, text
    code, text = hd("label", url)  # refused: it names the commands, with the URL's printable form
    assert code == 1 and "hd pull http://***@127.0.0.1" in text, text


def test_a_run_trained_on_a_secret_url_records_and_prints_no_secret(url, run, dataset, tmp_path):
    config = json.loads((run / "config.json").read_text())
    assert config["extra_config"]["dataset"] == printable_location(url)
    code, text = hd("train", url, "--out", run, "--profile", "tiny", "--epochs", "1")
    assert code == 0 and "already holds this training" in text, text  # same data: the redacted forms agree
    code, text = hd("--json", "train", url, "--out", run, "--profile", "tiny", "--epochs", "1")
    assert code == 0 and json.loads(text)["already_done"] is True, text
    code, text = hd("train", url, "--out", run, "--profile", "tiny", "--epochs", "2", "--resume")
    assert code == 0, text  # resumed on the same data (checked on the record's redacted form and manifest)
    for code, text in both("inspect", run):
        assert code == 0 and "***" in text, text
    code, text = hd("train", dataset, "--also", url, "--out", tmp_path / "mix", "--profile", "tiny")
    assert code == 2 and "is a URL" in text, text  # --also takes local datasets: refused, named without secret
    assert assert_no_secret_in_files(run) >= 4  # config.json, last.pt, best.pt, metrics.csv


def test_eval_detect_view_and_compare_of_a_secret_url_write_and_print_no_secret(url, run, tmp_path):
    report, maps = tmp_path / "report", tmp_path / "maps"
    code, text = hd("--json", "eval", run, "--data", url, "--out", report, "--mc-samples", "2", "--drop-pixels", "3")
    assert code == 0, text
    recorded = json.loads((report / "report.json").read_text())
    assert recorded["run"]["dataset"] == printable_location(url) and recorded["run"]["same_dataset_as_training"]
    code, text = hd("eval", run, "--data", url, "--out", report, "--mc-samples", "2", "--drop-pixels", "3")
    assert code == 0 and "already holds this evaluation's report" in text, text  # compared on the redacted form
    assert recorded["threshold"]["calibration_datasets"] == [printable_location(url)]
    for code, text in both("detect", run, "--data", url, "--out", maps, *DETECT_ARGS, "--overwrite"):
        assert code == 0, text
    assert json.loads((maps / "detect.json").read_text())["input"]["dataset"] == printable_location(url)
    for directory in (report, maps):
        for code, text in both("view", directory):
            assert code == 0, text
    for code, text in both("compare", report, report):
        assert code in (0, 1) and "Zq7" not in text, text
    assert (tmp_path / "report-view.html").is_file() and (tmp_path / "maps-view.html").is_file()  # beside them
    assert assert_no_secret_in_files(tmp_path) >= 6  # report.json, report.md, detect.json, the pages, ...


def test_pull_of_a_secret_url_and_its_interrupted_mark_hold_no_secret(url, tmp_path, monkeypatch):
    import lidarsim.transfer as transfer

    dest = tmp_path / "copy"
    real, calls = transfer._download, []

    def interrupted(*args, **kwargs):
        calls.append(args[1])
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(transfer, "_download", interrupted)
    code, text = hd("pull", url, dest)
    assert code == 130, text
    mark = json.loads((dest / transfer.PULL_MARK).read_text())
    assert mark["url"] == printable_location(url)
    assert_no_secret_in_files(dest)
    monkeypatch.undo()
    code, text = hd("--json", "pull", url, dest)  # the same pull resumes
    assert code == 0 and json.loads(text)["url"] == printable_location(url) and json.loads(text)["files_kept"] == 1
    code, text = hd("pull", url, tmp_path / "again")
    assert code == 0 and "pulled http://***@127.0.0.1" in text, text
    assert assert_no_secret_in_files(dest, tmp_path / "again") >= 10


def test_publish_to_a_secret_url_prints_no_secret(dataset, tmp_path):
    with s3_server():
        make_bucket("hd-data")
        for target in (f"s3://key:{MARK}@hd-data/x?sig={MARK}", secret_url("http://127.0.0.1:9", "x")):
            code, text = hd("publish", dataset, target)
            assert code == 1 and text.strip().splitlines()[-1].startswith("Error: "), text


# ------------------------------------------------------------------------------------ failures
def test_error_lines_of_secret_urls_hold_no_secret(url, run, dataset, tmp_path):
    unreachable = secret_url(f"http://127.0.0.1:{free_port()}", "b")
    nothing = url.replace("/dataset?", "/nothing?")
    assert nothing != url
    for bad, needle in ((unreachable, "cannot reach the host"), (nothing, "no dataset there")):
        for argv in (
            ["inspect", bad],
            ["verify", bad],
            ["label", bad],
            ["train", bad, "--out", tmp_path / "r", "--profile", "tiny"],
            ["eval", run, "--data", bad, "--out", tmp_path / "e", "--mc-samples", "2"],
            ["detect", run, "--data", bad, "--out", tmp_path / "d", *DETECT_ARGS],
            ["pull", bad, tmp_path / "p"],
        ):
            for code, text in both(*argv) if argv[0] != "verify" else [hd(*argv)]:
                assert code == 1 and needle in text.strip().splitlines()[-1], (argv, text)
    for argv in (  # a URL where a local path is needed: refused, named without its secrets
        ["view", url],
        ["compare", url],
        ["mosaic", url, "--out", tmp_path / "m"],
        ["export", url, "--out", tmp_path / "x"],
        ["card", url, "--recipe", tmp_path],
        ["eval", url, "--data", dataset, "--out", tmp_path / "e"],
        ["detect", run, "--data", dataset, "--out", url, *DETECT_ARGS],
        ["publish", url, "s3://hd-data/x"],
        ["pull", url, url],
    ):
        code, text = hd(*argv)
        assert code in (1, 2) and "Error: " in text, (argv, text)


def test_a_redirect_to_another_host_receives_neither_the_password_nor_the_query_token(dataset, tmp_path):
    """A server answering every request with 302 to another origin (another port): hd follows it (aiohttp),
    sends the user information as Basic auth to the first server only and the query token only where the
    redirect's Location puts it (here: nowhere); the verify and the pull work from the second server."""
    with (
        http_server(dataset.parent, RecordingHandler) as (target, second),
        http_server(dataset.parent, RedirectHandler, redirect_to=target) as (base, first),
    ):
        url = secret_url(base, dataset.name)
        for argv in (["verify", url], ["pull", url, tmp_path / "copy"]):
            code, text = hd(*argv)
            assert code == 0, text
    assert first.seen and all(auth and auth.startswith("Basic ") for _, auth in first.seen)  # the test can fail
    assert all(MARK in path for path, _ in first.seen)
    assert len(second.seen) >= len(first.seen) - 1
    assert all(auth is None and MARK not in path for path, auth in second.seen), second.seen[:3]
    assert_no_secret_in_files(tmp_path / "copy")


def test_timeout_and_size_refusals_of_a_secret_url_hold_no_secret(dataset, tmp_path, monkeypatch):
    """The error lines of hd's idle-read timeout and of a server that sends more than the manifest records,
    for a URL with a password and query tokens: the printable URL, no secret."""
    import lidarsim.location as location

    shard = read_manifest(dataset)["shards"][0]["path"]
    monkeypatch.setenv(location.READ_TIMEOUT_ENV, "1")
    for fault, needle in (("silent", "the server sent nothing for 1 s"), ("more", "the server sent more than")):
        location.forget_remotes()
        name = shard.rsplit("/", 1)[-1] + f"?token={MARK}&X-Amz-Signature={MARK}"  # the handler's key: the query too
        with http_server(dataset.parent, MisbehavingHandler, faults={name: fault}) as (base, _):
            code, text = hd("pull", secret_url(base, dataset.name), tmp_path / fault)
        last = text.strip().splitlines()[-1]
        assert code == 1 and needle in last and "http://***@127.0.0.1" in last and "token=***" in last, text
    location.forget_remotes()
