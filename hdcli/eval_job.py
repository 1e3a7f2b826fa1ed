"""``hd eval``: a trained run scored on a labelled dataset's test split (or ``--split``'s), its report written
(or found current); the terminal's summary: the tables' rows, the threshold and P(safe landing) with
its intervals and scene counts.

The settings are :class:`hdnet.eval_settings.EvalConfig`'s fields and :class:`SweepOption`'s (each
described once, as field metadata); :func:`eval_job` makes the configuration, checks the run and the
datasets (``hdnet.preflight``) and only then imports the evaluation and evaluates.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hdcore.outcome import Done
from hdcore.setting import check, setting, settings_from_options
from hdnet.errors import HdNetError


@dataclass(frozen=True)
class SweepOption:
    """``hd eval --sigma-sweep`` as typed: ``START:STOP:STEP`` in metres."""

    sigma_sweep: str | None = setting(
        None,
        "Also score the test split at these noise levels, {unit} (e.g. 0:0.12:0.01); levels the dataset does "
        "not store are made from its clean points. Adds a table and noise_sweep.png.",
        unit="metres",
        kind=str,
        metavar="START:STOP:STEP",
    )

    def __post_init__(self) -> None:
        check(self, HdNetError)

    def levels(self) -> tuple[float, ...]:
        """The noise levels of the sweep, metres (none without one)."""
        from hdnet.noise_levels import parse_sigma_sweep

        return parse_sigma_sweep(self.sigma_sweep) if self.sigma_sweep is not None else ()


def eval_job(
    run_dir: Path,
    dataset: Path | str,
    out_dir: Path,
    options: dict[str, Any],
    overwrite: bool,
    progress: Callable[[int, int], None] | None = None,
) -> Done:
    """Evaluate ``run_dir`` on ``dataset`` into the report ``out_dir`` with the command line's
    ``options`` (EvalConfig's fields and SweepOption's), unless that report is current already.

    Raises:
        HdNetError / StorageError: bad values, an output that is an input, a missing or misshapen run or
            dataset, an unknown labelling (all before anything is loaded), and whatever ``evaluate`` refuses.
    """
    from hdcore.storage import check_not_input
    from hdnet.eval_settings import EvalConfig
    from hdnet.preflight import check_inputs

    calibrate_on = tuple(options.get("calibrate_on", ()))
    check_not_input(out_dir, {f"the calibration dataset {d}": d for d in calibrate_on})
    sweep = settings_from_options(SweepOption, options).levels()
    options["calibrate_on"] = tuple(str(d) for d in calibrate_on)
    config = settings_from_options(EvalConfig, options, sigma_sweep=sweep)
    # Every option is checked now; the inputs next, before PyTorch is imported and the run loaded.
    check_inputs(run_dir, dataset, config.labels, calibration=config.calibrate_on)

    from hdcli.pipeline import report_written_message
    from hdnet.evaluate import evaluate_to_report, report_is_current

    if not overwrite and report_is_current(out_dir, run_dir, dataset, config):
        said = (
            f"{out_dir} already holds this evaluation's report (same checkpoint, dataset and settings): nothing to do"
        )
        return Done([said], {"command": "eval", "already_done": True, "report": str(out_dir)})
    result = evaluate_to_report(run_dir, dataset, out_dir, config, overwrite=overwrite, progress=progress)
    record = {
        "command": "eval",
        "already_done": False,
        "report": str(out_dir),
        "threshold": result.threshold,
        "rows": [dataclasses.asdict(r) for r in result.rows],
        "landing": [dataclasses.asdict(r) for r in result.landing],
    }
    from hdnet.chance import threshold_warning

    chance = threshold_warning(result.threshold.get("value_nats"))
    landing = result.landing_summary()
    from hdnet.run_files import checkpoint_words

    lines = [
        result.summary(),
        checkpoint_words(str(result.run.get("checkpoint", ""))),
        *([chance] if chance else []),
        *([landing] if landing else []),
    ]
    return Done([*lines, report_written_message(out_dir)], record)
