"""The settings of ``hd export-model``, described once (help, unit, default, range as field metadata:
the command's options and checks are made from them).

A leaf module without PyTorch: ``hdnet.onnx_export.export_onnx`` takes an
:class:`ExportModelSettings` and ``hdcli.export_model_job`` runs it with the command's, so a bad
value, and an output that exists (:meth:`ExportModelSettings.check_outputs`), are refused before
PyTorch is imported.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from hdcore.errors import StorageError
from hdcore.setting import check, setting
from hdcore.storage import check_output_file
from hdnet import limits
from hdnet.errors import HdNetError

# The model formats hd exports (docs/user-guide.md, "Exporting the network for flight software").
FORMATS = ("onnx",)


@dataclass(frozen=True)
class ExportModelSettings:
    """How ``hd export-model`` writes a run's network: the ``format`` and the DEM size the graph takes
    (``rows`` x ``cols`` cells; None: the run's training DEMs'). The graph's grid is the network's
    (``hdnet.inputs.network_shape``): the DEM padded to a multiple of 2**depth, or the run's
    ``input_size`` squared for a run that resizes its inputs."""

    format: str = setting("onnx", "Model format", choices=FORMATS)
    rows: int | None = setting(
        None, "DEM rows the graph takes, {unit} (default: the training DEMs')", unit="cells", bound=limits.DEM_SIDE
    )
    cols: int | None = setting(
        None, "DEM columns the graph takes, {unit} (default: the training DEMs')", unit="cells", bound=limits.DEM_SIDE
    )

    def __post_init__(self) -> None:
        check(self, HdNetError)

    def check_outputs(self, out: str | os.PathLike, overwrite: bool) -> Path:
        """The side file of the graph ``out`` (:func:`sidecar_path`), once both can be written: ``out``
        names a ``.onnx`` file in a writable directory, and neither exists unless ``overwrite``.

        Raises:
            HdNetError: ``out`` is not a ``.onnx`` name; StorageError: either file exists without
                ``overwrite``, is a directory, or cannot be written.
        """
        path = Path(out)
        if path.suffix.lower() != ".onnx":
            raise HdNetError(f"--out {path} must name a .onnx file (its side file takes the name with .json).")
        check_output_file(path, "--out")
        side = sidecar_path(path)
        for p in (path, side):
            if p.is_dir():
                raise StorageError(f"{p} is a directory.")
            if (p.exists() or p.is_symlink()) and not overwrite:
                raise StorageError(f"{p} exists; give --overwrite to replace it.")
        return side


def sidecar_path(out: str | os.PathLike) -> Path:
    """The side file of the graph ``out``: its name with the suffix ``.json`` (``model.onnx`` -> ``model.json``)."""
    return Path(out).with_suffix(".json")
