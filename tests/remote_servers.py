"""Real servers for the tests of datasets at URLs: an S3 API (moto's server mode) and an HTTP server
that honours Range requests, each on a free port of 127.0.0.1, started and stopped by the test.

Nothing of hd is replaced: hd talks to them through fsspec (s3fs, aiohttp) as it talks to real ones.
"""

from __future__ import annotations

import contextlib
import os
import threading
import urllib.request
from collections.abc import Iterator
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from lidarsim.location import forget_remotes

# Credentials of the S3 server: moto accepts any; they are what a user would export.
S3_ENV = {
    "AWS_ACCESS_KEY_ID": "hd-test-key",
    "AWS_SECRET_ACCESS_KEY": "hd-test-secret",
    "AWS_DEFAULT_REGION": "us-east-1",
}
# Variables that would point botocore at other credentials than the test's (cleared while a server runs).
AWS_OTHER = ("AWS_PROFILE", "AWS_SESSION_TOKEN", "AWS_SHARED_CREDENTIALS_FILE", "AWS_CONFIG_FILE")


@contextlib.contextmanager
def s3_server() -> Iterator[str]:
    """An S3 API server (moto) on a free port; yields its endpoint URL. While it runs, the process
    environment holds the test credentials and ``AWS_ENDPOINT_URL_S3`` (the standard variable that
    points every AWS client at another endpoint), as a user's shell would."""
    import logging

    from moto.server import ThreadedMotoServer

    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # one line per request otherwise
    forget_remotes()  # file systems opened for an earlier server point at its port
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    endpoint = f"http://{host}:{port}"
    # moto keeps its buckets in the process, not in the server: an earlier server's buckets would still
    # be there (a test that deletes a file from its copy would find the earlier module's file).
    urllib.request.urlopen(urllib.request.Request(f"{endpoint}/moto-api/reset", method="POST")).close()
    saved = {k: os.environ.get(k) for k in (*S3_ENV, *AWS_OTHER, "AWS_ENDPOINT_URL_S3", "AWS_EC2_METADATA_DISABLED")}
    os.environ.update(S3_ENV, AWS_ENDPOINT_URL_S3=endpoint, AWS_EC2_METADATA_DISABLED="true")
    os.environ["AWS_SHARED_CREDENTIALS_FILE"] = os.environ["AWS_CONFIG_FILE"] = os.devnull
    os.environ.pop("AWS_PROFILE", None)
    os.environ.pop("AWS_SESSION_TOKEN", None)
    try:
        yield endpoint
    finally:
        server.stop()
        forget_remotes()
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def make_bucket(name: str) -> None:
    """Create a bucket on the running S3 server (as ``aws s3 mb`` would)."""
    import boto3

    boto3.client("s3", endpoint_url=os.environ["AWS_ENDPOINT_URL_S3"]).create_bucket(Bucket=name)


def upload_tree(local: Path, bucket: str, prefix: str) -> None:
    """Copy every file under ``local`` to ``s3://bucket/prefix/`` (as ``aws s3 sync`` would)."""
    import boto3

    client = boto3.client("s3", endpoint_url=os.environ["AWS_ENDPOINT_URL_S3"])
    for path in sorted(local.rglob("*")):
        if path.is_file():
            client.upload_file(str(path), bucket, f"{prefix}/{path.relative_to(local).as_posix()}")


class RangeHandler(SimpleHTTPRequestHandler):
    """A static file server that honours ``Range: bytes=a-b`` (206 Partial Content) and counts the
    bytes of file contents it sends (``server.bytes_sent``)."""

    def log_message(self, format: str, *args: Any) -> None:  # quiet
        pass

    def send_head(self) -> Any:
        path = Path(self.translate_path(self.path))
        if not path.is_file():
            return super().send_head()
        size = path.stat().st_size
        header = self.headers.get("Range")
        start, end = 0, size - 1
        if header and header.startswith("bytes="):
            first, _, last = header[len("bytes=") :].split(",")[0].partition("-")
            if first:
                start = int(first)
                end = min(int(last), size - 1) if last else size - 1
            else:
                start = max(0, size - int(last))
            if start >= size:
                self.send_response(416)
                self.send_header("Content-Range", f"bytes */{size}")
                self.end_headers()
                return None
            self.send_response(206)
            self.send_header("Content-Range", f"bytes {start}-{end}/{size}")
        else:
            self.send_response(200)
        self.send_header("Content-Type", "application/octet-stream")
        self.send_header("Accept-Ranges", "bytes")
        self.send_header("Content-Length", str(end - start + 1))
        self.end_headers()
        fh = open(path, "rb")  # noqa: SIM115 - closed by copyfile's caller (send_head's protocol)
        fh.seek(start)
        self._remaining = end - start + 1
        return fh

    def copyfile(self, source: Any, outputfile: Any) -> None:
        remaining = getattr(self, "_remaining", None)
        while remaining is None or remaining > 0:
            block = source.read(1 << 16 if remaining is None else min(1 << 16, remaining))
            if not block:
                break
            outputfile.write(block)
            self.server.bytes_sent += len(block)  # type: ignore[attr-defined]  # set by http_server below
            if remaining is not None:
                remaining -= len(block)


@contextlib.contextmanager
def http_server(root: Path) -> Iterator[tuple[str, ThreadingHTTPServer]]:
    """An HTTP server of the files under ``root`` (Range requests honoured) on a free port; yields
    its base URL and the server (``bytes_sent``: file bytes sent so far)."""
    server = ThreadingHTTPServer(("127.0.0.1", 0), partial(RangeHandler, directory=str(root)))
    server.bytes_sent = 0  # type: ignore[attr-defined]  # the count RangeHandler keeps
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}", server
    finally:
        server.shutdown()
        server.server_close()
        thread.join()
