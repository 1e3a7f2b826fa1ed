"""Where a dataset lies: a local directory, read by today's code unchanged, or a URL read through fsspec.

The one seam between hd's readers and remote storage. A dataset or run is given either as a
directory (every function here hands it to ``hdcore.storage`` as before: same checks, same bytes)
or as a URL (``s3://bucket/prefix``, ``https://host/path``, ``file:///abs/path``, or anything else
fsspec reads): then

* :func:`join` gives a manifest path's URL (the path checked as :func:`hdcore.storage.confine`
  checks a local one: relative, no ``..``);
* :meth:`RemoteDataset.read_bytes` reads a side file (the manifest) whole, bounded like a local one,
  and keeps it for the process while the server reports the same version of it (its ETag);
* :func:`open_h5_at` opens an HDF5 file lazily: h5py reads through an fsspec file object with a
  block cache (``BLOCK_BYTES`` blocks, at most ``CACHE_BLOCKS`` of them), so one scan costs a few
  range requests, never the whole shard; a file of at most ``WHOLE_FILE_BLOCKS`` blocks is fetched
  whole in one request instead, checked against the manifest's sha256 and kept for the process;
* :func:`remote_errors` turns what the protocol raises (an unreachable host, a missing bucket or
  object, missing credentials, access denied) into one :class:`~hdcore.errors.StorageError` line
  naming the URL.

A URL may carry secrets (``https://user:PASSWORD@host/d``, a query token ``?X-Amz-Signature=...``):
they stay in memory for the reads; every message, record and summary names the URL in
:func:`hdcore.redact.printable_location`'s form (:func:`dataset_label`, :func:`dataset_key`,
:meth:`RemoteDataset.label_of`). A query string is sent with every file's request
(``https://host/d?token=T`` reads ``https://host/d/manifest.json?token=T``).

Credentials come from each protocol's standard places (S3: ``AWS_*`` variables, profiles, the
instance's role; HTTPS: none), never from hd options. fsspec and its protocol packages are the
optional extra ``remote`` (docs/dependencies.md); without them a URL is refused in one line.
"""

from __future__ import annotations

import collections
import contextlib
import functools
import hashlib
import io
import math
import os
import re
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py

from hdcore.errors import DamagedFileError, FormatError, HdError, StorageError
from hdcore.redact import is_redacted, printable_location, redact_text
from hdcore.storage import (
    MAX_SIDE_FILE_BYTES,
    CheckedH5File,
    check_relative,
    confine,
    open_h5,
    read_regular_bytes,
    sha256_bytes,
)
from lidarsim.errors import LidarsimError

URL_PATTERN = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*://")
# hd choice: the block of an HDF5 file fetched per range request, bytes. A scan's chunk of a shard
# (128 x 128 x 3 float32 points per noise level, deflated) is 50-200 kB: 2 MiB holds a few scans of
# one array, and a read of scan k's arrays costs one request per array.
BLOCK_BYTES = 2 << 20
# hd choice: blocks kept per open file (64 MiB): a shard's metadata and the current scans stay cached.
CACHE_BLOCKS = 32
# hd choice: an HDF5 file of at most this many blocks is fetched whole, in one request, and kept in
# memory for the process (a label shard of 50 scans is 2-10 MB, opened several times as a dataset is set
# up and then read entirely by an epoch): per-request and per-open costs, not bytes, dominate remote reads.
WHOLE_FILE_BLOCKS = 8
# hd choice: the whole files kept per process, bytes (least recently opened dropped first).
WHOLE_CACHE_BYTES = 256 << 20
# hd choice: the side files (manifests) kept per process with their version (least recently read dropped first).
SIDE_CACHE_FILES = 32
# hd choice: the block a whole-file stream (hd verify, hd pull) reads per request, bytes.
STREAM_BYTES = 8 << 20
INSTALL_HINT = "pip install 'hd[remote]'"
# hd's own limits on a remote read, seconds: a connection not made within the connect timeout, or a
# server that sends nothing for the idle-read timeout, ends the command in one line naming it. A slow
# download that keeps sending bytes is never cut (no limit on a whole request). Set by these variables.
CONNECT_TIMEOUT_ENV = "HD_CONNECT_TIMEOUT_S"
READ_TIMEOUT_ENV = "HD_READ_TIMEOUT_S"
# hd choice: 30 s to connect (a reachable host answers within a few), 60 s without a byte (a busy
# server's pause is seconds; aiohttp's own 300 s limit on a whole request would cut a large shard).
CONNECT_TIMEOUT_S = 30.0
READ_TIMEOUT_S = 60.0
# The mark ``hd publish`` leaves at a URL while it uploads (removed once the manifest is there): the
# sha256 of the manifest it is publishing, so that a re-run resumes and a reader names the state.
PUBLISH_MARK = ".hd-publish.json"


def is_url(value: object) -> bool:
    """True for a string that names a URL (``scheme://...``), False for a local path."""
    return isinstance(value, str) and bool(URL_PATTERN.match(value))


def split_query(url: str) -> tuple[str, str]:
    """A URL's part before its query string (and fragment), without a trailing ``/``, and that query
    string itself (``?...``; empty when there is none): the files of a dataset at ``BASE?QUERY`` are
    read at ``BASE/FILE?QUERY``. Only HTTP(S) sends a query string; another scheme's URL is kept whole
    (without a trailing ``/``), as its protocol reads it."""
    if not url.lower().startswith(("http://", "https://")):
        return url.rstrip("/"), ""
    cut = min((i for i in (url.find("?"), url.find("#")) if i != -1), default=len(url))
    return url[:cut].rstrip("/"), url[cut:]


def _canonical(url: str) -> str:
    """A dataset's URL as hd keeps it: without a trailing ``/`` before its query string."""
    base, query = split_query(url)
    return base + query


def _fsspec() -> Any:
    try:
        import fsspec
    except ImportError as exc:
        raise StorageError(f"reading a URL needs fsspec, which is not installed: {INSTALL_HINT}") from exc
    return fsspec


@dataclass(frozen=True)
class Timeouts:
    """hd's limits on a remote read, seconds: to make a connection, and without a byte received."""

    connect_s: float = CONNECT_TIMEOUT_S
    read_s: float = READ_TIMEOUT_S


def _seconds(name: str, default: float) -> float:
    text = os.environ.get(name, "").strip()
    if not text:
        return default
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value <= 0:
        raise StorageError(f"{name}={text!r}: not a number of seconds > 0")
    return value


def timeouts() -> Timeouts:
    """The timeouts in effect: ``HD_CONNECT_TIMEOUT_S`` and ``HD_READ_TIMEOUT_S`` (seconds), else 30 and 60.

    Raises:
        StorageError: a variable that is not a number of seconds > 0.
    """
    return Timeouts(_seconds(CONNECT_TIMEOUT_ENV, CONNECT_TIMEOUT_S), _seconds(READ_TIMEOUT_ENV, READ_TIMEOUT_S))


def storage_options(url: str, limits: Timeouts) -> dict[str, Any]:
    """fsspec's options for ``url`` that carry hd's timeouts: aiohttp's socket timeouts over HTTP(S)
    (no limit on a whole request), botocore's connect and read timeouts for S3."""
    scheme = url.split("://", 1)[0].lower()
    if scheme in ("http", "https"):
        import aiohttp

        timeout = aiohttp.ClientTimeout(total=None, sock_connect=limits.connect_s, sock_read=limits.read_s)
        return {"client_kwargs": {"timeout": timeout}}
    if scheme in ("s3", "s3a"):
        return {"config_kwargs": {"connect_timeout": limits.connect_s, "read_timeout": limits.read_s}}
    return {}


# The exception classes of a timeout, by the timeout that fired (aiohttp, botocore).
CONNECT_TIMEOUTS = frozenset({"ConnectionTimeoutError", "ConnectTimeoutError"})
READ_TIMEOUTS = frozenset({"SocketTimeoutError", "ReadTimeoutError", "ReadTimeout"})


def _timeout_error(url: str, exc: BaseException) -> StorageError | None:
    """The one line of a timeout anywhere in ``exc``'s chain (fsspec raises its own FSTimeoutError
    from aiohttp's): which of hd's timeouts fired and after how long; None for any other error."""
    seen: BaseException | None = exc
    for _ in range(8):  # the chain's first links: a protocol wraps its cause once or twice
        if seen is None:
            break
        names = {c.__name__ for c in type(seen).__mro__}
        limits = Timeouts(_seconds(CONNECT_TIMEOUT_ENV, CONNECT_TIMEOUT_S), _seconds(READ_TIMEOUT_ENV, READ_TIMEOUT_S))
        if names & CONNECT_TIMEOUTS or (names & {"ServerTimeoutError"} and "connect" in str(seen).lower()):
            return StorageError(
                f"{url}: no connection within {limits.connect_s:g} s (hd's connect timeout, {CONNECT_TIMEOUT_ENV})"
            )
        if names & READ_TIMEOUTS or names & {"ServerTimeoutError"}:
            return StorageError(
                f"{url}: the server sent nothing for {limits.read_s:g} s (hd's idle-read timeout, "
                f"{READ_TIMEOUT_ENV}; raise it for a slow server)"
            )
        seen = seen.__cause__ or seen.__context__
    return None


def missing_bucket(exc: BaseException) -> bool:
    """True when a protocol's error says the bucket itself does not exist (S3's NoSuchBucket), not
    merely the object (whose key or bucket name may well contain the word "bucket")."""
    text = str(exc)
    return "NoSuchBucket" in text or "bucket does not exist" in text.lower()


def too_long(where: str, recorded: int) -> DamagedFileError:
    """The refusal of a file whose server sends more than the size its manifest records."""
    return DamagedFileError(
        f"{where}: the server sent more than the {recorded} bytes the manifest records for this file; "
        "refused, nothing past that size read (the copy at the URL is damaged or was replaced)"
    )


def remote_error(url: str, exc: BaseException) -> StorageError:
    """One line for what reading or writing ``url`` raised: the host, the bucket, the credentials,
    the object or the access named as the cause. The URL, and any URL the protocol's message quotes,
    is named in its printable form (no password, no query value)."""
    kind = type(exc).__name__
    names = {c.__name__ for c in type(exc).__mro__}
    text = redact_text(str(exc).strip().splitlines()[0], url) if str(exc).strip() else kind
    scheme = url.split("://", 1)[0]
    url = printable_location(url)
    if names & {"NoCredentialsError", "PartialCredentialsError", "NoAuthTokenError"}:
        return StorageError(
            f"{url}: no credentials for {scheme}:// (set AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY, or "
            "AWS_PROFILE naming a profile; for a public bucket, anonymous access is not tried)"
        )
    if (timed_out := _timeout_error(url, exc)) is not None:
        return timed_out
    if missing_bucket(exc):
        bucket = split_query(url)[0].split("://", 1)[1].split("/", 1)[0].rpartition("@")[2]
        return StorageError(f"{url}: no such bucket {bucket!r}")
    if isinstance(exc, FileNotFoundError):
        return StorageError(f"{url}: not found")
    if isinstance(exc, PermissionError) or "AccessDenied" in text or "Forbidden" in text:
        return StorageError(f"{url}: access denied ({text})")
    if names & {
        "EndpointConnectionError",
        "ConnectTimeoutError",
        "ClientConnectorError",
        "ClientConnectorDNSError",
        "ServerDisconnectedError",
        "ConnectionError",
        "TimeoutError",
        "ConnectionRefusedError",
    }:
        return StorageError(f"{url}: cannot reach the host ({text})")
    if isinstance(exc, ValueError) and "protocol" in text.lower():
        return StorageError(f"{url}: unknown URL scheme {scheme!r} ({text}); {INSTALL_HINT} installs s3 and https")
    if isinstance(exc, ImportError):
        return StorageError(f"{url}: {scheme}:// needs a package that is not installed ({text}); {INSTALL_HINT}")
    return StorageError(f"{url}: {text}")


@contextlib.contextmanager
def remote_errors(url: str) -> Iterator[None]:
    """Every exception of the block but hd's own becomes :func:`remote_error`'s one line."""
    try:
        yield
    except HdError:
        raise
    except Exception as exc:  # protocols raise their own classes (botocore, aiohttp): all become one line
        raise remote_error(url, exc) from exc


class RemoteDataset:
    """A dataset (or run) at a URL: its file system and root, opened once per process.

    Args:
        url: ``scheme://...``; a trailing ``/`` is ignored; a query string is sent with every file's
            request (:func:`split_query`).
    """

    def __init__(self, url: str, limits: Timeouts | None = None) -> None:
        self.url = _canonical(url)
        base, self.query = split_query(self.url)
        fsspec = _fsspec()
        with remote_errors(self.url):
            self.fs, self.root = fsspec.core.url_to_fs(base, **storage_options(base, limits or timeouts()))
        self.root = str(self.root).rstrip("/")
        self._ranges: bool | None = None  # whether the server answers range requests (HTTP; asked once)

    def __str__(self) -> str:
        return self.label

    @property
    def label(self) -> str:
        """How messages and records name the URL (:func:`hdcore.redact.printable_location`)."""
        return printable_location(self.url)

    def label_of(self, relative: str) -> str:
        """How messages and records name the URL of a manifest path (no password, no query value)."""
        return printable_location(self.url_of(relative))

    @property
    def is_http(self) -> bool:
        """True for HTTP(S): whole files are read as one plain GET, which any static server answers."""
        protocol = self.fs.protocol
        return bool({"http", "https"} & set((protocol,) if isinstance(protocol, str) else protocol))

    @property
    def is_local(self) -> bool:
        """True for a local file system (``file://``): files are written under a temporary name and renamed."""
        protocol = self.fs.protocol
        return bool({"file", "local"} & set((protocol,) if isinstance(protocol, str) else protocol))

    def path_of(self, relative: str, where: str | None = None) -> str:
        """The file system path of a manifest path (checked: relative, no ``..``)."""
        check_relative(relative, where or printable_location(self._joined(relative)))
        return f"{self.root}/{relative}{self.query}"

    def url_of(self, relative: str) -> str:
        """The URL of a manifest path (checked: relative, no ``..``), its query string included."""
        url = self._joined(relative)
        check_relative(relative, printable_location(url))
        return url

    def _joined(self, relative: str) -> str:
        return f"{split_query(self.url)[0]}/{relative}{self.query}"

    def exists(self, relative: str) -> bool:
        """True when the file ``relative`` is there."""
        with remote_errors(self.url_of(relative)):
            return bool(self.fs.exists(self.path_of(relative)))

    def size(self, relative: str) -> int | None:
        """Size in bytes of the file ``relative`` (None when it is not there)."""
        with remote_errors(self.url_of(relative)):
            try:
                info = self.fs.info(self.path_of(relative))
            except FileNotFoundError as exc:
                if missing_bucket(exc):
                    raise
                return None
        size = info.get("size")
        return int(size) if isinstance(size, int) and info.get("type", "file") == "file" else None

    def probe(self, relative: str) -> bool:
        """Ask for ``relative`` itself (not its listing or its size, which some protocols answer with
        "not found" when the host cannot be reached): False when it is not there.

        Raises:
            StorageError: unreachable, no such bucket, no credentials.
        """
        url = self.url_of(relative)
        with remote_errors(url):
            try:
                if self.is_http:  # a server without ranges would send the whole file for a range of one byte
                    with self._reader(self.path_of(relative), 1) as fh:
                        fh.read(1)
                else:
                    self.fs.cat_file(self.path_of(relative), start=0, end=1)
            except FileNotFoundError as exc:
                if missing_bucket(exc):
                    raise
                return False
        return True

    def read_bytes(self, relative: str, max_bytes: int = MAX_SIDE_FILE_BYTES) -> bytes:
        """The bytes of the side file ``relative`` (at most ``max_bytes``), as :meth:`read_if_there` reads them.

        Raises:
            StorageError: not there, unreachable, no credentials. FormatError: larger than ``max_bytes``.
        """
        data = self.read_if_there(relative, max_bytes)
        if data is None:
            raise StorageError(f"{self.label_of(relative)}: not found")
        return data

    def read_if_there(self, relative: str, max_bytes: int = MAX_SIDE_FILE_BYTES) -> bytes | None:
        """The bytes of the side file ``relative`` (at most ``max_bytes``; None when it is not there).

        One request asks for the file's size and version (its strong ETag, or the protocol's content
        hash or generation); bytes read earlier in the process at the same URL, size and version are
        given again without reading them (a dataset set up once per epoch costs one request per manifest
        read), and a file replaced at the URL is read anew. A file whose protocol names no version is
        read every time.

        Raises:
            StorageError: unreachable, no credentials. FormatError: larger than ``max_bytes``.
        """
        url = self.url_of(relative)
        info = self._fresh_info(relative)
        if info is None:
            return None
        size, version = int(info["size"]), content_version(info)
        if size > max_bytes:
            raise FormatError(f"{self.label_of(relative)}: {size} bytes, more than the {max_bytes} this file can hold")
        kept = _SIDE.get(url)
        if version is not None and kept is not None and kept[:2] == (size, version):
            _SIDE.move_to_end(url)
            return kept[2]
        data = self.fetch(relative, size)
        _SIDE.pop(url, None)
        if len(data) != size:  # replaced while read: read as it is now, and not kept
            with remote_errors(url):
                return bytes(self.fs.cat_file(self.path_of(relative)))
        if version is not None:
            after = self._fresh_info(relative)  # unchanged while read: the bytes are this version's
            if after is not None and (int(after["size"]), content_version(after)) == (size, version):
                _SIDE[url] = (size, version, data)
                while len(_SIDE) > SIDE_CACHE_FILES:
                    _SIDE.popitem(last=False)
        return data

    def fetch(self, relative: str, size: int) -> bytes:
        """The bytes of the file ``relative``, whose size was just reported as ``size`` bytes, in one
        request: asked for as the range of ``size + 1`` bytes from the start (the protocol then does not
        ask for the size once more), so that a file that changed size since gives another length. Over
        HTTP, one plain GET read no further than those bytes (a server without ranges answers it too)."""
        if self.is_http:
            return b"".join(self._blocks(relative, size + 1))
        path = self.path_of(relative)
        with remote_errors(self.url_of(relative)):  # an empty file has no range to ask for
            return bytes(self.fs.cat_file(path, start=0, end=size + 1) if size > 0 else self.fs.cat_file(path))

    def _fresh_info(self, relative: str) -> dict[str, Any] | None:
        """The file system's details of the file ``relative``, asked of the server (not of a listing
        cached earlier); None when it is not there, as :meth:`size` says."""
        path = self.path_of(relative)
        with remote_errors(self.url_of(relative)):
            self.fs.invalidate_cache(path)
            try:
                info = self.fs.info(path)
            except FileNotFoundError as exc:
                if missing_bucket(exc):
                    raise
                return None
        if not isinstance(info.get("size"), int) or info.get("type", "file") != "file":
            return None
        return dict(info)

    def stream(self, relative: str, limit: int | None = None, block_bytes: int = STREAM_BYTES) -> Iterator[bytes]:
        """The bytes of ``relative`` in blocks, read once from start to end (no cache). With ``limit``
        (the size the manifest records), no block past it is given: one byte more ends the read.

        Raises:
            DamagedFileError: the server sends more than ``limit`` bytes. StorageError: unreachable,
                a timeout.
        """
        got = 0
        for block in self._blocks(relative, None if limit is None else limit + 1, block_bytes):
            got += len(block)
            if limit is not None and got > limit:
                raise too_long(printable_location(self.url_of(relative)), limit)
            yield block

    def _blocks(self, relative: str, stop: int | None, block_bytes: int = STREAM_BYTES) -> Iterator[bytes]:
        """The bytes of ``relative`` from its start, in blocks of at most ``block_bytes``, ``stop`` bytes at
        most in all: no more is asked for, or read from the connection. Over HTTP one plain GET (any
        static server answers it, with or without range support); elsewhere the protocol's own reads."""
        path = self.path_of(relative)
        with remote_errors(self.url_of(relative)), self._reader(path, stop) as fh:
            got = 0
            while stop is None or got < stop:
                block = fh.read(block_bytes if stop is None else min(block_bytes, stop - got))
                if not block:
                    return
                got += len(block)
                yield block

    def _reader(self, path: str, stop: int | None) -> Any:
        """A file object that reads ``path`` once from its start (see :meth:`_blocks`)."""
        if self.is_http:  # block_size=0: fsspec's streamed GET; a size given spares the HEAD request
            return self.fs.open(path, "rb", block_size=0, size=stop or None)
        return self.fs.open(path, "rb", cache_type="none")

    def ranges(self, relative: str) -> bool:
        """True when the server answers a range request with that range (asked once, of ``relative``):
        always outside HTTP; a static server without range support (``python -m http.server``) answers
        with the whole file, of which nothing is read."""
        if not self.is_http:
            return True
        if self._ranges is None:
            from fsspec.asyn import sync

            url = self.url_of(relative)
            with remote_errors(url):
                self._ranges = bool(sync(self.fs.loop, _answers_ranges, self.fs, self.path_of(relative)))
        return self._ranges

    def open_file(self, relative: str) -> Any:
        """A read-only file object of ``relative`` with a block cache (``BLOCK_BYTES`` x ``CACHE_BLOCKS``)."""
        with remote_errors(self.url_of(relative)):
            return self.fs.open(
                self.path_of(relative),
                "rb",
                block_size=BLOCK_BYTES,
                cache_type="blockcache",
                cache_options={"maxblocks": CACHE_BLOCKS},
            )

    def listing(self) -> list[str]:
        """Every file under the root, as paths relative to it (empty when there is none)."""
        with remote_errors(self.url):
            try:
                found = self.fs.find(self.root + self.query)
            except FileNotFoundError as exc:
                if missing_bucket(exc):
                    raise
                return []
        prefix = self.root + "/"
        return sorted(str(p)[len(prefix) :] for p in found if str(p).startswith(prefix))


async def _answers_ranges(fs: Any, path: str) -> bool:
    """True when an HTTP server answers ``Range: bytes=0-0`` with 206 (its body, one byte, unread otherwise)."""
    session = await fs.set_session()
    async with session.get(fs.encode_url(path), headers={"Range": "bytes=0-0"}, **fs.kwargs) as response:
        if response.status == 404:
            raise FileNotFoundError(path)
        response.raise_for_status()
        return response.status == 206 or "Content-Range" in response.headers


_WHOLE: collections.OrderedDict[tuple[str, str], bytes] = collections.OrderedDict()
# The side files (manifests) read at URLs: URL -> (size in bytes, version, bytes), see ``read_if_there``.
_SIDE: collections.OrderedDict[str, tuple[int, str, bytes]] = collections.OrderedDict()
# What identifies a file's content in fsspec's ``info()``: S3's ETag (most HTTP servers send one too),
# Azure's etag, GCS's md5Hash and generation, a versioned store's VersionId.
VERSION_FIELDS = ("ETag", "etag", "md5Hash", "generation", "VersionId", "version_id")


def content_version(info: dict[str, Any]) -> str | None:
    """The version of a file's content in fsspec's ``info()`` of it: its version fields joined (a weak
    ``W/`` ETag, which may stay when the bytes change, is none); None when it has none (a local file,
    an HTTP server that sends only Last-Modified, of a second's resolution)."""
    found = []
    for field in VERSION_FIELDS:
        value = info.get(field)
        if value is None or value == "" or (isinstance(value, str) and value.startswith("W/")):
            continue
        found.append(f"{field}={value}")
    return " ".join(found) or None


def _whole_key(url: str, sha256: str | None, size: int | None) -> tuple[str, str]:
    return (url, f"sha256:{sha256}" if sha256 is not None else f"size:{size}")


def _whole_file(
    remote: RemoteDataset, relative: str, size: int, sha256: str | None, name: str, recorded: bool = False
) -> bytes:
    """The bytes of the file ``relative`` (``size`` bytes), fetched in one request the first time and
    kept (at most ``WHOLE_CACHE_BYTES`` in all). With ``sha256`` (the manifest's) the bytes are checked
    against it, in memory, and kept under it; without, under their size. ``recorded``: ``size`` is the
    manifest's, and a longer body is refused as such.

    Raises:
        DamagedFileError: the bytes are not the manifest's. StorageError: unreachable, or a file that
            changed while read.
    """
    url = remote.url_of(relative)
    key = _whole_key(url, sha256, size)
    if key in _WHOLE:
        _WHOLE.move_to_end(key)
        return _WHOLE[key]
    data = remote.fetch(relative, size)
    if recorded and len(data) > size:
        raise too_long(name, size)
    if len(data) != size:
        raise StorageError(
            f"{remote.label_of(relative)}: {len(data)} bytes read, {size} expected (the file changed while read)"
        )
    if sha256 is not None and (digest := sha256_bytes(data)) != sha256:
        raise DamagedFileError(
            f"{name}: checksum mismatch (sha256 {digest[:12]}..., the manifest says {sha256[:12]}...): "
            "the file is damaged or was replaced; run `hd verify`"
        )
    _WHOLE[key] = data
    while sum(len(v) for v in _WHOLE.values()) > WHOLE_CACHE_BYTES and len(_WHOLE) > 1:
        _WHOLE.popitem(last=False)
    return data


@functools.lru_cache(maxsize=16)
def _remote(url: str, pid: int, limits: Timeouts) -> RemoteDataset:
    return RemoteDataset(url, limits)


def forget_remotes() -> None:
    """Drop the file systems made so far (hd's and fsspec's instance caches), so that the next URL is
    opened with the environment as it is now: for a long-lived process whose endpoint or credentials
    change (a test session starting a new server)."""
    _remote.cache_clear()
    _WHOLE.clear()
    _SIDE.clear()
    if "fsspec" in sys.modules:  # nothing was opened through fsspec otherwise
        from fsspec.spec import AbstractFileSystem

        pending: list[Any] = [AbstractFileSystem]
        while pending:  # every file system class keeps its own cache of instances
            cls = pending.pop()
            cls.clear_instance_cache()
            pending.extend(cls.__subclasses__())


def remote_dataset(url: str) -> RemoteDataset:
    """The :class:`RemoteDataset` of ``url``, made once per process (a forked reader makes its own)
    and per setting of :func:`timeouts`."""
    return _remote(_canonical(url), os.getpid(), timeouts())


def dataset_label(location: str | os.PathLike) -> str:
    """How messages name a dataset: its URL in its printable form (no password, no query value), or
    its path."""
    return printable_location(_canonical(str(location))) if is_url(location) else str(Path(location))


def dataset_at(location: str | os.PathLike) -> Path | str:
    """A dataset given as a string or a path, to read: a URL kept as the string, secrets included
    (``Path`` would collapse its ``//``), anything else as a ``Path``."""
    return _canonical(str(location)) if is_url(location) else Path(location)


def dataset_location(location: str | os.PathLike) -> str:
    """A dataset as hd reads it and compares it within a process: its URL as given, secrets included
    (without a trailing ``/``), or its resolved path. Never written: records take :func:`dataset_key`."""
    return _canonical(str(location)) if is_url(location) else str(Path(location).resolve())


def dataset_key(location: str | os.PathLike) -> str:
    """How a run, an eval report or a detect output records the dataset it read: its URL in its
    printable form (:func:`hdcore.redact.printable_location`: no password, no query value; a record
    compares with the printable form of the URL given), or its resolved path."""
    return printable_location(dataset_location(location))


def manifest_sha256(location: str | os.PathLike, name: str = "manifest.json") -> str:
    """The sha256 of a dataset's manifest (a directory's or a URL's): the identity runs record.

    Raises:
        StorageError: no manifest there, unreachable, no credentials.
    """
    if is_url(location):
        return sha256_bytes(remote_dataset(str(location)).read_bytes(name))
    return sha256_bytes(read_regular_bytes(Path(location) / name))


def has_manifest(location: str | os.PathLike, name: str = "manifest.json") -> bool:
    """True when a dataset's manifest is there (a URL is asked; a lost host is False, as a missing file;
    a URL whose secrets a record left out, :func:`hdcore.redact.is_redacted`, is not asked and is False)."""
    if is_redacted(location):
        return False
    if is_url(location):
        try:
            return remote_dataset(str(location)).size(name) is not None
        except (LidarsimError, ValueError):
            return False
    return (Path(location) / name).is_file()


def join(location: str | os.PathLike, relative: Any, where: str | None = None) -> Path | str:
    """The file ``relative`` (a manifest path) of a dataset: a URL under a URL, else
    :func:`hdcore.storage.confine`'s checked path.

    Raises:
        FormatError: an absolute path, ``..``, or a link leading outside the dataset.
    """
    if is_url(location):
        base, query = split_query(str(location))
        check_relative(relative, where or printable_location(f"{base}/{relative}{query}"))
        return f"{base}/{relative}{query}"
    return confine(location, relative, where)


def split_url(url: str) -> tuple[RemoteDataset, str]:
    """The folder and file name of a file URL (the folder's file system, made once per process)."""
    path, query = split_query(url)
    base, _, name = path.rpartition("/")
    return remote_dataset(base + query), name


def _local_copy(remote: RemoteDataset, relative: str, size: int, sha256: str | None, name: str) -> Any:
    """The file ``relative`` (``size`` bytes, the manifest's when known) streamed into an unnamed
    temporary file, for a server without range requests: h5py then reads it as a local file. Checked
    against ``sha256``; removed once closed."""
    fh = tempfile.TemporaryFile()  # noqa: SIM115 - handed to h5py, closed by the caller (or below on error)
    try:
        h = hashlib.sha256()
        for block in remote.stream(relative, size):
            h.update(block)
            fh.write(block)
        if fh.tell() != size:
            raise StorageError(f"{remote.url_of(relative)}: {fh.tell()} bytes read, {size} expected")
        if sha256 is not None and (digest := h.hexdigest()) != sha256:
            raise DamagedFileError(
                f"{name}: checksum mismatch (sha256 {digest[:12]}..., the manifest says {sha256[:12]}...): "
                "the file is damaged or was replaced; run `hd verify`"
            )
    except BaseException:
        fh.close()
        raise
    fh.seek(0)
    return fh


def _remote_h5_file(url: str, name: str, sha256: str | None, size_bytes: int | None) -> Any:
    """The file object h5py reads of the HDF5 file at ``url`` (see :func:`open_h5_at`)."""
    remote, relative = split_url(url)
    size = remote.size(relative)
    if size is None:
        raise DamagedFileError(f"{name}: missing (the manifest lists it); run `hd verify`")
    if size_bytes is not None and size > size_bytes:
        raise too_long(name, size_bytes)
    expected = size if size_bytes is None else size_bytes
    if expected <= WHOLE_FILE_BLOCKS * BLOCK_BYTES:
        return io.BytesIO(_whole_file(remote, relative, expected, sha256, name, recorded=size_bytes is not None))
    if not remote.ranges(relative):
        return _local_copy(remote, relative, expected, sha256, name)
    return remote.open_file(relative)


def open_h5_at(
    path: str | os.PathLike, what: str | None = None, sha256: str | None = None, size_bytes: int | None = None
) -> CheckedH5File:
    """Open an HDF5 file read-only with checked reads: a local path as :func:`hdcore.storage.open_h5`
    opens it, a URL lazily through fsspec (block cache; see the module docstring); a file of at most
    ``WHOLE_FILE_BLOCKS`` blocks is fetched whole once per process and, given the manifest's
    ``sha256``, checked against it (then opened again without a request). A larger file on a server
    without range requests is streamed into a temporary file first. Given the manifest's
    ``size_bytes``, a server that holds or sends more is refused before (or as soon as) it does.

    Raises:
        StorageError: unreachable or missing. DamagedFileError: not HDF5 or damaged metadata, or longer
            than ``size_bytes``.
    """
    if not is_url(path):
        return open_h5(path, what)
    url = str(path)
    name = what or printable_location(url)
    kept = _WHOLE.get(_whole_key(url, sha256, None)) if sha256 is not None else None
    fh: Any = io.BytesIO(kept) if kept is not None else _remote_h5_file(url, name, sha256, size_bytes)
    try:
        f = h5py.File(fh, "r")
    except OSError as exc:
        fh.close()
        raise DamagedFileError(
            f"{name}: cannot open as HDF5 ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__}); "
            "the file is damaged or not an hd file"
        ) from exc
    except Exception as exc:  # a protocol's own error while h5py reads (a lost connection)
        fh.close()
        raise remote_error(url, exc) from exc
    return CheckedH5File(f, name)
