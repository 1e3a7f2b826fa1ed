"""The inputs of ``hd eval``, ``hd detect`` and ``hd train`` checked before anything heavy is imported
or loaded.

A leaf module without PyTorch: it reads only small JSON files (a dataset's ``manifest.json``) and
looks at paths, so that a wrong path or labelling is refused in a second, not after the network
library is imported, the run's checkpoint loaded and a split inferred (minutes on a busy machine).
The settings themselves (the threshold's form included) are checked as they are made
(``hdnet.eval_settings``, ``hdnet.detect_settings``), before these checks.

* :func:`check_run`: a checkpoint file, or a run directory that holds ``last.pt`` (a dataset, a run
  without a checkpoint yet and a directory that is no run are each refused with their fix);
* :func:`check_dataset`: a dataset directory with a readable manifest and labels, and the labelling
  ``--labels`` names, when given (a full name or an alias, ``hdlabels.store.find_labeling``);
* :func:`check_dtm`: a DTM file that exists (with ``--window``: a DTM the window overlaps);
* :func:`check_inputs`: all of a command's inputs, in that order.
"""

from __future__ import annotations

import os
from pathlib import Path

from hdlabels.store import find_labeling
from hdnet.errors import HdNetError
from hdnet.run_files import CONFIG, LAST
from lidarsim.errors import TerrainError
from lidarsim.map_window import MapWindow, window_cells
from lidarsim.shards import MANIFEST_NAME, read_manifest


def check_run(run: str | os.PathLike) -> Path:
    """The checkpoint of the run ``run``: ``RUN/last.pt`` for a run directory, else the file itself.

    Raises:
        HdNetError: nothing at ``run``; a directory that is a dataset, a run whose training has not
            saved a checkpoint yet, or no run at all (neither ``config.json`` nor ``last.pt``);
            something that is neither a directory nor a regular file.
    """
    path = Path(run)
    if path.is_dir():
        if (path / LAST).is_file():
            return path / LAST
        if (path / MANIFEST_NAME).is_file():
            raise HdNetError(
                f"{path} is a dataset, not a run: give the run directory `hd train --out` wrote (it holds {LAST})."
            )
        if (path / CONFIG).is_file():
            raise HdNetError(
                f"{path} is a run without a checkpoint yet (no {LAST}): its training has not finished an epoch; "
                "`hd train ... --resume` continues it."
            )
        raise HdNetError(
            f"{path} is not an hd run (no {CONFIG} or {LAST}): give the run directory `hd train --out` wrote, "
            "or a checkpoint file."
        )
    if path.is_file():
        return path
    if path.exists():
        raise HdNetError(f"{path} is neither a run directory nor a checkpoint file.")
    raise HdNetError(f"run {path} does not exist.")


def check_dataset(dataset: str | os.PathLike, labels: str | None = None) -> None:
    """A labelled dataset at ``dataset``, with the labelling ``labels`` when one is named (None: the
    choice waits for the run, whose labelling is the default).

    Raises:
        StorageError: no such directory, no (readable) manifest, an unfinished build.
        LabelStoreError: no labels; an unknown or ambiguous ``labels`` (the names and aliases there are).
    """
    manifest = read_manifest(dataset)
    if labels is not None or not manifest.get("labelings"):
        find_labeling(dataset, labels)  # its errors: "no labels; run hd label", "no labelling named ..."


def check_dtm(dtm: str | os.PathLike, window: MapWindow | None = None) -> None:
    """A DTM file at ``dtm`` (its content is read, and checked, by ``lidarsim.terrain.DTM``); with a
    ``window`` (map metres), a raster that GDAL opens and that the window overlaps (its header
    alone is read: ``lidarsim.map_window.window_cells``).

    Raises:
        TerrainError: nothing there; with a window, a file that is no usable DTM or a window outside
            its bounds (the message names them).
    """
    if not os.path.exists(dtm):
        raise TerrainError(f"{os.path.abspath(os.fspath(dtm))}: no such file")
    if window is not None:
        from lidarsim.terrain import DTM  # rasterio, imported only for a window

        with DTM.open(dtm) as probe:
            i = probe.info
            window_cells(window, i.transform, i.rows, i.cols, i.name)


def check_inputs(
    run: str | os.PathLike,
    dataset: str | os.PathLike | None = None,
    labels: str | None = None,
    *,
    dtm: str | os.PathLike | None = None,
    calibration: tuple[str | os.PathLike, ...] = (),
    window: MapWindow | None = None,
) -> Path:
    """Every input of ``hd eval`` or ``hd detect``, in the order a user reads the command: the run
    (:func:`check_run`), the dataset and its ``labels`` (:func:`check_dataset`), the DTM
    (:func:`check_dtm`, with its ``window``) and each ``calibration`` dataset (``--calibrate-on``);
    returns the checkpoint.

    Raises:
        HdError: as the checks above, for the first input that fails.
    """
    checkpoint = check_run(run)
    if dataset is not None:
        check_dataset(dataset, labels)
    if dtm is not None:
        check_dtm(dtm, window)
    for other in calibration:
        check_dataset(other)
    return checkpoint
