"""``hd detect``: hazard maps and ranked landing sites of a DTM (or of one scan) from a trained run.

:func:`detect_job` runs ``hdnet.detect.detect`` with the command's settings
(:class:`~hdnet.detect_settings.DetectSettings`, described once there) and says what it wrote.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from hdcore.outcome import Done
from hdnet.detect_settings import DetectSettings


def detect_job(
    run_dir: Path,
    out_dir: Path,
    dtm: Path | None,
    dataset: Path | str | None,
    settings: DetectSettings,
    progress: Callable[[int, int], None] | None = None,
) -> Done:
    """Map ``dtm`` (or the scan ``settings.scan`` of ``dataset``) with the run ``run_dir`` into ``out_dir``.

    Raises:
        HdNetError / TerrainError / StorageError: as ``hdnet.detect.detect``, before anything is written;
            a missing or misshapen run, dataset or DTM, an unknown labelling and a window outside the
            DTM before anything is loaded.
    """
    from hdnet.preflight import check_inputs

    # The settings were checked as they were made; the inputs now, before PyTorch is imported.
    settings.check_inputs(dtm, dataset)
    check_inputs(run_dir, dataset, settings.labels, dtm=dtm, window=settings.window)

    from hdnet.detect import detect

    result = detect(run_dir, out_dir, settings, dtm=dtm, dataset=dataset, progress=progress)
    from hdnet.chance import threshold_warning

    chance = threshold_warning(result.threshold_nats, len(result.sites))
    from hdnet.run_files import checkpoint_words

    lines = [result.summary(), checkpoint_words(str(result.info["run"]["checkpoint"])), *([chance] if chance else [])]
    lines.append(f"maps, sites.csv, sites.geojson, overview.png and detect.json in {out_dir}")
    return Done(lines, {"command": "detect", "out": str(out_dir), **result.info})
