"""``hd publish DIR URL`` and ``hd pull URL DIR``: a dataset copied to and from a URL, never half visible.

Publish (local directory to URL):

1. the local dataset is checked as ``hd verify`` checks it (a damaged dataset is never published);
2. what is at the URL decides: nothing, or an interrupted publication of the same dataset (its
   mark, :data:`~lidarsim.location.PUBLISH_MARK`, names the same manifest sha256): go on, files
   already there with their size are kept (resume); the same dataset complete: nothing to do;
   anything else (another dataset, another publication, files that are no dataset) is refused
   unless ``overwrite``, which first removes the old manifest (from then on the URL holds no dataset);
3. the mark, then every file the manifest lists (scan shards, label shards, the dataset's terrain),
   each written whole (an S3 object appears only once its upload completes; on a local file system
   a temporary name is renamed), then ``manifest.json`` last, then the mark is removed.

A reader therefore sees, at any moment and whatever kills the publisher: no dataset, the old one
intact, or the new one complete; a manifest never names a missing or partial file.

Pull (URL to local directory): the manifest is read first; each file is streamed into a temporary
name beside its final one while its sha256 is computed, refused when it differs from the manifest's,
and renamed into place; files already there with the right sha256 are kept (resume after an
interruption); the manifest is written last (the same bytes as at the URL) and the copy ends with
``hd verify``'s checks. The directory is locked while it is written (``WriterLock``).
"""

from __future__ import annotations

import datetime
import hashlib
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hdcore.errors import DamagedFileError, FormatError, OutputExistsError, StorageError
from hdcore.outcome import Done, counted
from hdcore.redact import printable_location
from hdcore.storage import (
    WriterLock,
    atomic,
    atomic_path,
    check_not_input,
    confine,
    make_dirs,
    read_regular_bytes,
    sha256_bytes,
    sha256_file,
    write_bytes_atomic,
    write_json_atomic,
)
from lidarsim.location import PUBLISH_MARK, RemoteDataset, is_url, remote_dataset, remote_errors
from lidarsim.manifest_json import ManifestJson
from lidarsim.shards import (
    MANIFEST_NAME,
    entry_size,
    manifest_text,
    read_manifest,
    validate_manifest,
    verify_dataset,
)

# The mark ``hd pull`` keeps in a directory it is filling (the manifest sha256 it copies), removed
# once the manifest is written: a re-run resumes, another dataset into the same directory is refused.
# It names the URL in its printable form only (no password, no query value): the manifest's sha256,
# not the URL, decides whether a re-run resumes.
PULL_MARK = ".hd-pull.json"
# hd choice: bytes handed to the protocol per write while uploading one file.
UPLOAD_BLOCK_BYTES = 8 << 20

Progress = Callable[[str, int], None]


def dataset_files(manifest: ManifestJson) -> list[str]:
    """The relative paths of every file a manifest names: scan shards, label shards and the terrain
    kept inside the dataset (``dtm.path`` when relative), in that order."""
    files = [e["path"] for e in manifest["shards"]]
    for labelling in manifest.get("labelings", []):
        files += [e["path"] for e in labelling.get("shards", [])]
    dtm = manifest.get("dtm")
    if isinstance(dtm, dict) and isinstance(dtm.get("path"), str) and not os.path.isabs(dtm["path"]):
        files.append(dtm["path"])
    return files


def _expected_sizes(manifest: ManifestJson) -> dict[str, int | None]:
    """Relative path -> the size in bytes the manifest records for it (None: a manifest before 1.4)."""
    sizes = {e["path"]: entry_size(e) for e in manifest["shards"]}
    for labelling in manifest.get("labelings", []):
        sizes.update({e["path"]: entry_size(e) for e in labelling.get("shards", [])})
    dtm = manifest.get("dtm")
    if isinstance(dtm, dict) and isinstance(dtm.get("path"), str):
        sizes[dtm["path"]] = entry_size(dtm)
    return sizes


def _expected_sha256(manifest: ManifestJson) -> dict[str, str]:
    """Relative path -> the sha256 the manifest records for it."""
    sums = {e["path"]: e["sha256"] for e in manifest["shards"]}
    for labelling in manifest.get("labelings", []):
        sums.update({e["path"]: e["sha256"] for e in labelling.get("shards", [])})
    dtm = manifest.get("dtm")
    if isinstance(dtm, dict) and isinstance(dtm.get("path"), str) and isinstance(dtm.get("sha256"), str):
        sums[dtm["path"]] = dtm["sha256"]
    return sums


def _check_url(url: str) -> str:
    if not is_url(url):
        raise StorageError(f"{printable_location(url)} is not a URL (s3://bucket/prefix, file:///path, ...)")
    return url.rstrip("/")


def _publish_url(url: str) -> str:
    """Where ``hd publish`` writes: a URL as it is, a local folder path (``/mnt/share/mars``,
    ``../published``) as its ``file://`` URL: a local folder is a file system like any other."""
    if is_url(url):
        return url.rstrip("/")
    if not url.strip():
        raise StorageError("the URL is empty: give s3://bucket/prefix, file:///path or a local folder")
    return Path(url).absolute().as_uri()


def _publish_target(url: str, root: Path) -> RemoteDataset:
    """The place at ``url`` to publish the dataset ``root`` to; a local one that is, holds or lies
    inside the dataset is refused.

    Raises:
        StorageError: one line naming both.
    """
    remote = remote_dataset(url)
    if remote.is_local:
        check_not_input(remote.root, {"the dataset": root}, "URL")
    return remote


# ------------------------------------------------------------------------------------------ publish
def _send_block(fh: Any, block: bytes) -> None:
    """Hand one block of a file to the protocol (the one place publish writes bytes)."""
    fh.write(block)


def _upload(remote: RemoteDataset, source: Path, relative: str) -> None:
    """Write ``source`` at ``relative`` whole: visible at its name only once complete."""
    dest = remote.path_of(relative)
    local = remote.is_local
    target = f"{dest}.partial-{os.getpid()}" if local else dest
    with remote_errors(remote.url_of(relative)):
        if local:
            remote.fs.makedirs(dest.rsplit("/", 1)[0], exist_ok=True)
        with open(source, "rb") as src, remote.fs.open(target, "wb") as fh:
            while block := src.read(UPLOAD_BLOCK_BYTES):
                _send_block(fh, block)
        if local:
            remote.fs.mv(target, dest)


def _upload_manifest(remote: RemoteDataset, source: Path) -> None:
    """The last step of a publication: the manifest, once every file it names is there."""
    _upload(remote, source, MANIFEST_NAME)


def _remote_manifest(remote: RemoteDataset) -> bytes | None:
    return remote.read_if_there(MANIFEST_NAME)


def _publication_state(remote: RemoteDataset, manifest_bytes: bytes, overwrite: bool) -> tuple[str, list[str]]:
    """What is at the URL: ``same`` (this dataset, complete), ``resume`` (its interrupted publication)
    or ``new``; and the files the old dataset named (removed once the new one is complete).

    Raises:
        OutputExistsError: something else is there and ``overwrite`` is not given.
    """
    there = _remote_manifest(remote)
    digest = sha256_bytes(manifest_bytes)
    if there is not None:
        if there == manifest_bytes:
            return "same", []
        if not overwrite:
            raise OutputExistsError(
                f"{remote.label} holds another dataset (its {MANIFEST_NAME} differs from this one's); give "
                "--overwrite to replace it, or publish to another URL"
            )
        try:
            old = dataset_files(validate_manifest(manifest_text(there, remote.label), remote.label))
        except FormatError:
            old = []
        with remote_errors(remote.url_of(MANIFEST_NAME)):
            remote.fs.rm_file(remote.path_of(MANIFEST_NAME))  # from here the URL holds no dataset
        return "new", old
    if remote.size(PUBLISH_MARK) is not None:
        mark = manifest_text(remote.read_bytes(PUBLISH_MARK), remote.label_of(PUBLISH_MARK))
        if isinstance(mark, dict) and mark.get("manifest_sha256") == digest:
            return "resume", []
        if not overwrite:
            raise OutputExistsError(
                f"{remote.label}: an interrupted publication of another dataset is there; give --overwrite to "
                "replace it, or publish to another URL"
            )
        return "new", []
    held = [p for p in remote.listing() if p != PUBLISH_MARK]
    if held and not overwrite:
        raise OutputExistsError(
            f"{remote.label} holds {counted(len(held), 'file')} and no hd dataset; give --overwrite to publish "
            "there anyway (they are left in place, the dataset's own files replaced), or publish to another URL"
        )
    return "new", []


def publish_dataset(
    directory: str | os.PathLike,
    url: str,
    overwrite: bool = False,
    known_schemas: dict[str, str] | None = None,
    progress: Progress | None = None,
) -> Done:
    """Publish the dataset at ``directory`` to ``url`` (module docstring: order, resume, refusals).

    Args:
        directory: the local dataset.
        url: where to publish it (``s3://bucket/prefix``, ``file:///path``...; HTTPS is read-only), or
            a local folder's path (published as its ``file://`` URL).
        overwrite: replace another dataset (or files) at ``url``.
        known_schemas: the schemas of its label shards (``hdcli.inspection.known_schemas``).
        progress: called with each file's relative path and size in bytes once it is there.

    Raises:
        DamagedFileError: the local dataset fails ``hd verify``'s checks.
        OutputExistsError: something else at ``url`` without ``overwrite``.
        StorageError: ``url`` cannot be reached or written, or is, holds or lies in the dataset (one line).
    """
    root = Path(directory)
    url = _publish_url(url)
    read_manifest(root)
    manifest_bytes = read_regular_bytes(root / MANIFEST_NAME)
    manifest = validate_manifest(manifest_text(manifest_bytes, str(root / MANIFEST_NAME)), str(root))
    problems = verify_dataset(root, known_schemas)
    if problems:
        raise DamagedFileError(
            f"{root} is damaged ({len(problems)} problem(s): {problems[0]}); `hd verify {root}` lists them; "
            "it is not published"
        )
    remote = _publish_target(url, root)
    files = dataset_files(manifest)
    sizes = {rel: confine(root, rel).stat().st_size for rel in files}
    state, old_files = _publication_state(remote, manifest_bytes, overwrite)
    sent = kept = 0
    if state != "same":
        mark = {"manifest_sha256": sha256_bytes(manifest_bytes), "started": _now()}
        with remote_errors(remote.url_of(PUBLISH_MARK)):
            if remote.is_local:
                remote.fs.makedirs(remote.root, exist_ok=True)
            remote.fs.pipe_file(remote.path_of(PUBLISH_MARK), json.dumps(mark).encode())
    for rel in files:
        if state in ("same", "resume") and remote.size(rel) == sizes[rel]:
            kept += 1
            continue
        _upload(remote, confine(root, rel), rel)
        sent += sizes[rel]
        if progress is not None:
            progress(rel, sizes[rel])
    if state != "same":
        _upload_manifest(remote, root / MANIFEST_NAME)
    if remote.size(PUBLISH_MARK) is not None:
        with remote_errors(remote.url_of(PUBLISH_MARK)):
            remote.fs.rm_file(remote.path_of(PUBLISH_MARK))
    stale = [rel for rel in old_files if rel not in sizes and remote.size(rel) is not None]
    for rel in stale:
        with remote_errors(remote.url_of(rel)):
            remote.fs.rm_file(remote.path_of(rel))
    total = sum(sizes.values())
    url = remote.label  # from here on the URL is named, never its secrets
    if state == "same" and not sent:
        line = f"{url}: already holds this dataset ({counted(len(files), 'file')}, {total / 1e6:.1f} MB); nothing sent"
    else:
        line = f"published {root} to {url}: {counted(len(files), 'file')} and {MANIFEST_NAME}, {total / 1e6:.1f} MB" + (
            f" ({sent / 1e6:.1f} MB sent, {counted(kept, 'file')} already there)" if kept else ""
        )
    record = {
        "command": "publish",
        "dataset": str(root),
        "url": url,
        "n_files": len(files),
        "bytes": total,
        "bytes_sent": sent,
        "files_kept": kept,
        "replaced": bool(old_files),
    }
    return Done([line], record)


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


# ------------------------------------------------------------------------------------------ pull
def _download(remote: RemoteDataset, relative: str, final: Path, expected: str, limit: int | None) -> int:
    """Stream ``relative`` into ``final`` (temporary name, renamed once its sha256 matches); returns its size.
    With ``limit`` (the manifest's size in bytes), a server that sends more is refused at that size: no
    byte past it is written or held.

    Raises:
        DamagedFileError: the bytes at the URL are not those the manifest records, or more of them.
    """
    make_dirs(final.parent)
    h = hashlib.sha256()
    size = 0
    with atomic_path(final) as tmp:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
        try:
            for block in remote.stream(relative, limit):
                h.update(block)
                atomic._write_all(fd, block)  # the one writer of file contents (hdcore.storage.atomic)
                size += len(block)
            os.fsync(fd)
        finally:
            os.close(fd)
        digest = h.hexdigest()
        if digest != expected:
            raise DamagedFileError(
                f"{remote.label_of(relative)}: checksum mismatch (sha256 {digest[:12]}..., the manifest says "
                f"{expected[:12]}...): the copy at the URL is damaged; nothing of it is kept"
            )
    return size


def _check_pull_target(root: Path, manifest_bytes: bytes) -> str:
    """``same`` (this dataset is there), ``resume`` (its interrupted pull) or ``new``.

    Raises:
        OutputExistsError: the directory holds another dataset or other files.
    """
    if not root.exists():
        return "new"
    if not root.is_dir():
        raise StorageError(f"{root} exists and is not a directory")
    if (root / MANIFEST_NAME).exists():
        if read_regular_bytes(root / MANIFEST_NAME) == manifest_bytes:
            return "same"
        raise OutputExistsError(
            f"{root} holds another dataset (its {MANIFEST_NAME} differs); pull into another directory"
        )
    mark = root / PULL_MARK
    if mark.is_file():
        try:
            recorded = json.loads(read_regular_bytes(mark)).get("manifest_sha256")
        except (ValueError, AttributeError):
            recorded = None
        if recorded == sha256_bytes(manifest_bytes):
            return "resume"
        raise OutputExistsError(f"{root} holds an interrupted pull of another dataset; pull into another directory")
    if any(p.name != ".hd-lock" for p in root.iterdir()):
        raise OutputExistsError(f"{root} is not empty; pull into a new or empty directory")
    return "new"


def pull_dataset(
    url: str,
    directory: str | os.PathLike,
    known_schemas: dict[str, str] | None = None,
    progress: Progress | None = None,
) -> Done:
    """Copy the dataset at ``url`` into ``directory`` (module docstring: checks, resume, order).

    Raises:
        FormatError: no hd dataset at ``url``. DamagedFileError: a file whose bytes differ from the
        manifest's sha256, or a copy that fails ``hd verify``'s checks. OutputExistsError: another
        dataset or other files in ``directory``. StorageError: ``url`` unreachable, no credentials.
    """
    url = _check_url(url)
    root = Path(directory)
    manifest = read_manifest(url)
    remote = remote_dataset(url)
    label = remote.label  # how the URL is named: never its secrets
    manifest_bytes = remote.read_bytes(MANIFEST_NAME)
    if manifest_text(manifest_bytes, label) != manifest:  # replaced between the two reads
        raise StorageError(f"{label}: its manifest changed while it was read; re-run")
    files = dataset_files(manifest)  # every path checked by read_manifest (no ``..``, dtm.path too)
    state = _check_pull_target(root, manifest_bytes)
    make_dirs(root)
    targets = {rel: confine(root, rel) for rel in files}  # inside the directory, links resolved: before any fetch
    sums = _expected_sha256(manifest)
    sizes = _expected_sizes(manifest)
    fetched = kept = 0
    with WriterLock(root, "dataset"):
        if state == "new":
            write_json_atomic(root / PULL_MARK, {"manifest_sha256": sha256_bytes(manifest_bytes), "url": label})
        for rel in files:
            final = targets[rel]
            if final.is_file() and sha256_file(final) == sums[rel]:
                kept += 1
                continue
            size = _download(remote, rel, final, sums[rel], sizes[rel])
            fetched += size
            if progress is not None:
                progress(rel, size)
        if state != "same":
            write_bytes_atomic(root / MANIFEST_NAME, manifest_bytes)
        (root / PULL_MARK).unlink(missing_ok=True)
    problems = verify_dataset(root, known_schemas)
    if problems:
        raise DamagedFileError(f"{root}: the copy fails its checks ({len(problems)} problem(s): {problems[0]})")
    line = f"pulled {label} into {root}: {counted(len(files), 'file')} and {MANIFEST_NAME}, all checked"
    if kept:
        line += f" ({fetched / 1e6:.1f} MB fetched, {counted(kept, 'file')} already there)"
    record = {
        "command": "pull",
        "url": label,
        "dataset": str(root),
        "n_files": len(files),
        "bytes_fetched": fetched,
        "files_kept": kept,
    }
    return Done([line], record)
