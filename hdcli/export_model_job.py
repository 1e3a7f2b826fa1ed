"""``hd export-model``: a trained run's network as an ONNX graph and its side file, for flight software.

:func:`export_model_job` checks the settings (:class:`~hdnet.export_model_settings.ExportModelSettings`,
described once there) and the run before PyTorch is imported, then runs
``hdnet.onnx_export.export_onnx`` and says what it wrote.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hdcore.outcome import Done
from hdcore.setting import settings_from_options
from hdnet.export_model_settings import ExportModelSettings


def export_model_job(run_dir: Path, out: Path, options: dict[str, Any], overwrite: bool) -> Done:
    """Export the network of ``run_dir`` to ``out`` (and ``model.json`` beside it) with the command
    line's ``options`` (:class:`ExportModelSettings`' fields).

    Raises:
        HdNetError / StorageError: a bad setting, no run at ``run_dir``, an unfinished run, ``out``
            existing without ``overwrite``, onnx missing, a failed export; nothing is written then.
    """
    from hdnet.preflight import check_run

    settings = settings_from_options(ExportModelSettings, options)
    check_run(run_dir)  # the run and the outputs before PyTorch is imported
    settings.check_outputs(out, overwrite)

    from hdnet.onnx_export import export_onnx

    exported = export_onnx(run_dir, out, settings, overwrite=overwrite)
    m = exported.model
    record: dict[str, object] = {
        "command": "export-model",
        "out": str(exported.out),
        "sidecar": str(exported.sidecar),
        "format": m["format"],
        "opset": m["opset"],
        "grid": m["input"]["grid"],
        "masks": [mask["name"] for mask in m["masks"]],
        "threshold_nats": m["threshold"].get("value_nats"),
        "checkpoint_sha256": m["run"]["checkpoint_sha256"],
    }
    return Done([exported.summary()], record)
