"""One storage layer for every file hd writes or reads (shards, manifests, checkpoints, reports).

Writing:

* every file is built under a hidden temporary name beside its final name
  (``.NAME.partial-PID``), flushed to disk (``fsync``), renamed into place and the directory
  flushed; on any error (a full disk included) or interruption the temporary file is removed and
  the error is one :class:`StorageError` line naming the path (``write_bytes_atomic``,
  ``write_json_atomic``, ``atomic_path``);
* HDF5 files are built in memory (h5py's ``core`` driver without backing store, :class:`H5Image`)
  and written to disk with plain file I/O. The HDF5 library therefore never sees a failed write:
  after one (``ENOSPC``) HDF5 2.0 crashes the process (segmentation fault) when the file is closed
  or when the interpreter exits, whatever the caller does;
* GeoTIFFs too large to build in memory (``hd detect``'s maps) are written window by window by
  GDAL through :class:`GeoTiffWriter`: GDAL's and libtiff's messages are captured, never printed,
  and a failed write or flush (a full disk) is one :class:`StorageError` line naming the file;
* :func:`check_output_dir` / :func:`check_output_file` check an output path before any work starts
  (not under a regular file, not empty, a writable file system: ``/proc`` and read-only mounts are
  refused) without creating it.

Reading:

* :func:`confine` keeps every path read from a manifest inside its dataset (no absolute paths, no
  ``..``, no symbolic link leading out);
* :func:`verify_sha256` compares a file with the checksum its manifest records before it is
  opened; :func:`open_h5` opens HDF5 files whose every later read error (a damaged chunk, whose
  fletcher32 checksum fails) becomes one :class:`DamagedFileError` line naming the file, the
  dataset and the scan;
* :func:`check_schema` refuses another schema or an unknown major version;
* :func:`read_regular_bytes` (and :func:`read_json`, :func:`read_regular_text`) read side files
  only when they are regular files (a FIFO, socket, device or directory is refused at once, never
  waited on) and of a bounded size; :func:`check_regular_file` is the same check for files opened
  by a library (HDF5, GeoTIFF).

One writer per directory: :class:`WriterLock` holds an exclusive ``flock`` on ``DIR/.hd-lock``
(the holder's PID written in it) for as long as a command writes there; the kernel releases it
when the holder dies, even by SIGKILL. A second writer fails at once with the holder's PID;
readers never take the lock (:func:`lock_holder` probes it with a shared lock released at once).

One output transaction: every command writes its output directory inside an
:class:`OutputTransaction` (create, lock, check, stage, commit or roll back); :class:`OutputDir`
adds the rules of a command whose whole output is replaced at once (``hd eval``'s report,
``hd detect``).

The modules, one a section: :mod:`hdcore.storage.oserrors`,
:mod:`hdcore.storage.hashes`,
:mod:`hdcore.storage.atomic`,
:mod:`hdcore.storage.h5image`,
:mod:`hdcore.storage.h5read`,
:mod:`hdcore.storage.sidefiles`,
:mod:`hdcore.storage.paths`,
:mod:`hdcore.storage.gdal`,
:mod:`hdcore.storage.lock`;
this package re-exports their public names.
"""

from __future__ import annotations

from hdcore.errors import DamagedFileError, FormatError, LockedError, OutputExistsError, StorageError
from hdcore.storage.atomic import (
    PARTIAL_MARK,
    atomic_path,
    commit_file,
    fsync_dir,
    glob_escape,
    partial_path,
    remove_partials,
    remove_stale_partials,
    write_bytes_atomic,
    write_json_atomic,
    write_text_atomic,
)
from hdcore.storage.gdal import (
    GeoTiffWriter,
    captured_gdal_errors,
    gdal_write_error,
)
from hdcore.storage.h5image import (
    ROW_BLOCK_BYTES,
    H5Image,
    RowBlocks,
    h5_chunk_kwargs,
)
from hdcore.storage.h5read import (
    CheckedDataset,
    CheckedH5File,
    attr_float,
    attr_int,
    check_h5_data,
    open_h5,
)
from hdcore.storage.hashes import (
    is_sha256,
    sha256_bytes,
    sha256_file,
    verify_sha256,
)
from hdcore.storage.lock import (
    LOCK_NAME,
    WriterLock,
    lock_holder,
)
from hdcore.storage.oserrors import (
    describe_os_error,
)
from hdcore.storage.paths import (
    NAME_MAX_BYTES,
    OutputDir,
    OutputTransaction,
    check_not_input,
    check_output_dir,
    check_output_file,
    check_relative,
    confine,
    first_missing,
    make_dirs,
    make_subdir,
    remove_empty_dirs,
)
from hdcore.storage.sidefiles import (
    MAX_SIDE_FILE_BYTES,
    check_regular_file,
    check_schema,
    read_json,
    read_regular_bytes,
    read_regular_text,
    require,
)

__all__ = [
    "LOCK_NAME",
    "MAX_SIDE_FILE_BYTES",
    "NAME_MAX_BYTES",
    "PARTIAL_MARK",
    "ROW_BLOCK_BYTES",
    "CheckedDataset",
    "CheckedH5File",
    "DamagedFileError",
    "FormatError",
    "GeoTiffWriter",
    "H5Image",
    "LockedError",
    "OutputDir",
    "OutputExistsError",
    "OutputTransaction",
    "RowBlocks",
    "StorageError",
    "WriterLock",
    "atomic_path",
    "attr_float",
    "attr_int",
    "captured_gdal_errors",
    "check_h5_data",
    "check_not_input",
    "check_output_dir",
    "check_output_file",
    "check_regular_file",
    "check_relative",
    "check_schema",
    "commit_file",
    "confine",
    "describe_os_error",
    "first_missing",
    "fsync_dir",
    "gdal_write_error",
    "glob_escape",
    "h5_chunk_kwargs",
    "is_sha256",
    "lock_holder",
    "make_dirs",
    "make_subdir",
    "open_h5",
    "partial_path",
    "read_json",
    "read_regular_bytes",
    "read_regular_text",
    "remove_empty_dirs",
    "remove_partials",
    "remove_stale_partials",
    "require",
    "sha256_bytes",
    "sha256_file",
    "verify_sha256",
    "write_bytes_atomic",
    "write_json_atomic",
    "write_text_atomic",
]
