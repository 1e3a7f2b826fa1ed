"""Real servers for the tests of datasets at URLs: an S3 API (moto's server mode) and HTTP servers
(one that honours Range requests, the standard library's plain one without them, and misbehaving
ones: a server that sends more than a file holds, one that goes silent mid-body, one that is slow
but keeps sending), each on a free port of 127.0.0.1, started and stopped by the test.

Nothing of hd is replaced: hd talks to them through fsspec (s3fs, aiohttp) as it talks to real ones.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
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


class PlainHandler(SimpleHTTPRequestHandler):
    """The standard library's static server (``python -m http.server``): no Range support, every GET
    answered 200 with the whole file. Records each request's path (``server.requests``)."""

    def log_message(self, format: str, *args: Any) -> None:  # quiet
        pass

    def send_head(self) -> Any:
        self.server.requests.append(self.path)  # type: ignore[attr-defined]  # set by http_server below
        return super().send_head()


class MisbehavingHandler(PlainHandler):
    """A plain server whose GET of a file named in ``server.faults`` misbehaves (HEAD answers honestly):

    * ``"more"``: the file, then zeros without end (no Content-Length; ``server.bytes_sent`` counts);
    * ``"silent"``: half of the file, then nothing until ``server.release`` is set;
    * ``"slow"``: the file in ``server.slow_blocks`` parts, ``server.slow_pause_s`` apart.
    """

    protocol_version = "HTTP/1.0"  # a body without Content-Length ends when the connection closes

    def do_GET(self) -> None:
        fault = self.server.faults.get(self.path.rsplit("/", 1)[-1])  # type: ignore[attr-defined]  # set by http_server below
        if fault is None:
            super().do_GET()
            return
        self.server.requests.append(self.path)  # type: ignore[attr-defined]  # set by http_server below
        data = Path(self.translate_path(self.path)).read_bytes()
        self.send_response(200)
        self.send_header("Content-Type", "application/octet-stream")
        if fault != "more":
            self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        # the client may stop reading: what a server sees when hd refuses the rest
        with contextlib.suppress(BrokenPipeError, ConnectionResetError):
            getattr(self, f"_send_{fault}")(data)

    def _send_more(self, data: bytes) -> None:
        self._send(data)
        zeros = bytes(1 << 16)
        for _ in range(1024):  # 64 MiB at most
            self._send(zeros)

    def _send_silent(self, data: bytes) -> None:
        self._send(data[: len(data) // 2])
        self.wfile.flush()
        self.server.release.wait(60)  # type: ignore[attr-defined]  # set by http_server below

    def _send_slow(self, data: bytes) -> None:
        n = self.server.slow_blocks  # type: ignore[attr-defined]  # set by http_server below
        step = -(-len(data) // n)
        for k in range(n):
            self._send(data[k * step : (k + 1) * step])
            self.wfile.flush()
            time.sleep(self.server.slow_pause_s)  # type: ignore[attr-defined]  # set by http_server below

    def _send(self, block: bytes) -> None:
        self.wfile.write(block)
        self.server.bytes_sent += len(block)  # type: ignore[attr-defined]  # set by http_server below


class RecordingHandler(RangeHandler):
    """A Range server that records each request's path and ``Authorization`` header (``server.seen``)."""

    def send_head(self) -> Any:
        self.server.seen.append((self.path, self.headers.get("Authorization")))  # type: ignore[attr-defined]  # set by http_server below
        return super().send_head()


class RedirectHandler(RecordingHandler):
    """A server that records each request (``server.seen``) and answers it with ``302 Found`` to the same
    path, without its query string, at ``server.redirect_to`` (another origin: ``http://127.0.0.1:PORT``)."""

    def send_head(self) -> Any:
        self.server.seen.append((self.path, self.headers.get("Authorization")))  # type: ignore[attr-defined]  # set by http_server below
        self.send_response(302)
        self.send_header("Location", self.server.redirect_to + self.path.split("?", 1)[0])  # type: ignore[attr-defined]  # set by http_server below
        self.send_header("Content-Length", "0")
        self.end_headers()
        return None


class LyingLengthHandler(PlainHandler):
    """A plain server whose GET of a file named in ``server.faults`` lies about its length: ``"longer"``
    announces a Content-Length one block longer than the file and closes after the file; ``"shorter"``
    announces half the file's length and sends all of it."""

    def do_GET(self) -> None:
        fault = self.server.faults.get(self.path.split("?", 1)[0].rsplit("/", 1)[-1])  # type: ignore[attr-defined]  # set by http_server below
        if fault is None:
            super().do_GET()
            return
        self.server.requests.append(self.path)  # type: ignore[attr-defined]  # set by http_server below
        data = Path(self.translate_path(self.path.split("?", 1)[0])).read_bytes()
        self.send_response(200)
        self.send_header("Content-Type", "application/octet-stream")
        self.send_header("Content-Length", str(len(data) + (1 << 16) if fault == "longer" else len(data) // 2))
        self.send_header("Connection", "close")
        self.end_headers()
        with contextlib.suppress(BrokenPipeError, ConnectionResetError):
            self.wfile.write(data)
        self.close_connection = True


class QuietServer(ThreadingHTTPServer):
    """A threaded HTTP server that says nothing when a client hangs up mid-body (hd asking whether a
    server has ranges, or refusing the rest of a body): that is no error of the server's."""

    def handle_error(self, request: Any, client_address: Any) -> None:
        if isinstance(sys.exc_info()[1], (BrokenPipeError, ConnectionResetError)):
            return
        super().handle_error(request, client_address)


@contextlib.contextmanager
def http_server(
    root: Path, handler: type[SimpleHTTPRequestHandler] = RangeHandler, **settings: Any
) -> Iterator[tuple[str, Any]]:  # the server with the counts set below
    """An HTTP server of the files under ``root`` on a free port (``handler``: Range requests honoured
    by default; :class:`PlainHandler`, :class:`MisbehavingHandler`); yields its base URL and the server
    (``bytes_sent``: file bytes sent so far; ``requests``: the paths asked for, by the plain handlers;
    ``settings``: the misbehaving handler's ``faults``, ``slow_blocks``, ``slow_pause_s``)."""
    server = QuietServer(("127.0.0.1", 0), partial(handler, directory=str(root)))
    server.bytes_sent = 0  # type: ignore[attr-defined]  # the count RangeHandler keeps
    server.requests = []  # type: ignore[attr-defined]  # the paths PlainHandler records
    server.release = threading.Event()  # type: ignore[attr-defined]  # ends a silent handler's wait
    server.faults = {}  # type: ignore[attr-defined]  # set by http_server below
    server.seen = []  # type: ignore[attr-defined]  # (path, Authorization) of each request, by the recording handlers
    for key, value in settings.items():
        setattr(server, key, value)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}", server
    finally:
        server.release.set()  # type: ignore[attr-defined]  # set by http_server below
        server.shutdown()
        server.server_close()
        thread.join()
