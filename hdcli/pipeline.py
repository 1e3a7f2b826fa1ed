"""Multi-stage commands: build, label, (inspect), train and evaluate in one output directory.

``hd demo`` and ``hd reproduce`` are :class:`Pipeline` s, made by :func:`demo_pipeline` and
:func:`reproduce_pipeline` (the paper's dataset recipe, ``datasets/mars-paper``) and run by
:func:`run_pipeline`; the command line only passes options and prints. Layout of ``OUT``::

    OUT/dataset/       the dataset (hd build-dataset, then hd label)
    OUT/run/           the training run (hd train)
    OUT/report*/       one report per evaluation (hd eval)
    OUT/stages.json    the stage times of every run of the command

Every option is checked before the first stage runs (:meth:`Pipeline.check`). Each stage is
resumable and a finished one is skipped: the dataset by its manifest, the labelling by its entry in
the manifest, the training by its checkpoint (it resumes), a report by its ``report.json``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from hdcore.errors import HdError
from hdcore.storage import read_regular_text
from hdlabels import defaults as label_defaults
from hdlabels.settings import LabelSettings
from hdnet import defaults as net_defaults
from hdnet.checkpoint_json import EpochProgress
from hdnet.noise_levels import parse_sigma_sweep
from hdnet.profiles import ROBUST_THRESHOLD_SPEC, get_profile
from lidarsim import defaults as lidar_defaults
from lidarsim.build import BuildConfig
from lidarsim.errors import LidarsimError

if TYPE_CHECKING:
    pass

# hd choice: the risk level of the risk-controlled threshold `hd reproduce` adds to the paper's
# mean-entropy threshold (docs/evaluation.md, "risk:ALPHA").
REPRODUCE_RISK_ALPHA = 0.05
# hd choice: the noise sweep of a robust reproduction steps by 1 cm.
ROBUST_SWEEP_STEP_M = 0.01
# The fewest scans a pipeline accepts: one per split.
MIN_SCANS = 3
STAGES_FILE = "stages.json"


class ProgressBar(Protocol):
    """A progress display fed with (done, total) counts; closed when its stage ends."""

    def __call__(self, done: int, total: int) -> None: ...

    def close(self) -> None: ...


Echo = Callable[[str], None]
ProgressFactory = Callable[[str, str], ProgressBar]  # (description, unit) -> bar


@dataclass(frozen=True)
class Evaluation:
    """One evaluation stage: ``hd eval`` with ``threshold``, ``drop_pixels``, ``calibrate`` and
    ``sigma_sweep`` (metres) into ``OUT/<directory>``."""

    stage: str
    directory: str
    threshold: str
    drop_pixels: int
    what: str
    calibrate: str = "reference"
    sigma_sweep: tuple[float, ...] = ()


@dataclass(frozen=True)
class Pipeline:
    """The settings of every stage of a multi-stage command.

    Attributes:
        out_dir: the output directory (layout in the module docstring).
        build: the dataset to build.
        label: the labelling to make.
        profile: training profile name (``hdnet.profiles``).
        epochs: training epochs; None takes the profile's.
        evaluations: the evaluation stages, in order.
        inspect: print the dataset's summary and check every file after labelling.
        train_sigma_m: noise level of the training inputs, metres; None: the profile's training noise
            range (``TrainingProfile.train_sigma_range_m``).
        seed: seed of the training and of the evaluations.
        mc_samples: MC-dropout samples of the evaluations.
        train_what: the training stage's one-line description.
    """

    out_dir: Path
    build: BuildConfig
    label: LabelSettings
    profile: str
    epochs: int | None
    evaluations: tuple[Evaluation, ...]
    inspect: bool = False
    train_sigma_m: float | None = lidar_defaults.DEFAULT_SIGMA_M
    seed: int = 0
    mc_samples: int = net_defaults.MC_SAMPLES
    train_what: str = ""

    @property
    def dataset_dir(self) -> Path:
        return self.out_dir / "dataset"

    @property
    def run_dir(self) -> Path:
        return self.out_dir / "run"

    def build_what(self) -> str:
        """The build stage's one-line description."""
        terrain = "the procedural Mars terrain" if self.build.dtm_path is None else Path(self.build.dtm_path).name
        sigmas = ", ".join(f"{s * 100:g}" for s in self.build.sigmas_m)
        return f"{self.build.trajectory.n_scans} scans x ({sigmas}) cm on {terrain}, one trajectory"

    def check(self) -> None:
        """Check every stage's settings and the output directory before anything runs or is written.

        Raises:
            HdError: naming the option (a split left empty, a DTM that cannot be read, a lander that
                does not fit the DEM, an output path that cannot be written).
        """
        from hdcore.storage import check_not_input, check_output_dir
        from lidarsim.build import assign_splits
        from lidarsim.terrain import DTM

        n_scans = self.build.trajectory.n_scans
        splits = assign_splits(n_scans, seed=self.build.seed)
        if n_scans < MIN_SCANS or min(int((splits == code).sum()) for code in (0, 1, 2)) == 0:
            raise LidarsimError(f"--scans {n_scans} leaves a split empty; use more scans")
        from hdlabels.labeling import check_lander_fits

        check_lander_fits(self.label.to_lander(), self.label.to_dem_spec())
        check_output_dir(self.out_dir, "--out")
        check_not_input(self.out_dir, {"the DTM": self.build.dtm_path})
        if self.build.dtm_path is not None:
            with DTM.open(self.build.dtm_path, scale=self.build.dtm_scale):
                pass


def demo_pipeline(out_dir: Path, scans: int, epochs: int) -> Pipeline:
    """``hd demo``: the paper's three noise levels on the procedural Mars terrain at demo scale, the
    default labels, the cpu profile, one evaluation with the dead-pixel test."""
    build = dataclasses.replace(
        _paper_build(), trajectory=dataclasses.replace(_paper_build().trajectory, n_scans=scans)
    )
    sigma = lidar_defaults.DEFAULT_SIGMA_M
    n_dead = label_defaults.N_DEAD_PIXELS
    return Pipeline(
        out_dir=out_dir,
        build=build,
        label=LabelSettings(),
        profile="cpu",
        epochs=epochs,
        inspect=True,
        evaluations=(
            Evaluation(
                "eval",
                "report",
                net_defaults.THRESHOLD_SPEC,
                n_dead,
                f"MC dropout (M={net_defaults.MC_SAMPLES}), paper metrics, {n_dead} dropped pixels",
            ),
        ),
        train_what=f"Bayesian SegNet, cpu profile, {epochs} epochs at sigma = {sigma} m",
    )


def reproduce_pipeline(
    out_dir: Path, recipe_dir: Path, profile: str, epochs: int | None, dtm_path: Path | None = None
) -> Pipeline:
    """``hd reproduce``: the dataset and labels of the recipe at ``recipe_dir`` (the paper's,
    ``datasets/mars-paper``), optionally on another DTM, then Table 1, Table 2 and the risk-controlled
    threshold.

    Raises:
        RecipeError: the recipe cannot be read; HdLabelsError: its [label] section is invalid.
    """
    from lidarsim.recipe import load_recipe

    recipe = load_recipe(recipe_dir)
    build = recipe.build
    if dtm_path is not None:
        build = dataclasses.replace(build, dtm_path=str(Path(dtm_path).resolve()))
    n_dead = label_defaults.N_DEAD_PIXELS
    sigma = lidar_defaults.DEFAULT_SIGMA_M
    label = LabelSettings.from_recipe(recipe.label, str(recipe.path))
    noise_range = get_profile(profile).train_sigma_range_m
    if noise_range is not None:
        return _robust_pipeline(out_dir, build, label, profile, epochs, noise_range)
    return Pipeline(
        out_dir=out_dir,
        build=build,
        label=label,
        profile=profile,
        epochs=epochs,
        evaluations=(
            Evaluation(
                "eval",
                "report",
                net_defaults.THRESHOLD_SPEC,
                n_dead,
                f"Table 1, Table 2 ({n_dead} dropped pixels), sweep, calibration, panels (mean-entropy threshold)",
            ),
            Evaluation(
                "eval-risk",
                "report-risk",
                f"risk:{REPRODUCE_RISK_ALPHA:g}",
                0,
                f"risk-controlled threshold, alpha = {REPRODUCE_RISK_ALPHA:g}",
            ),
        ),
        train_what=f"Bayesian SegNet, {profile} profile, trained at sigma = {sigma} m",
    )


def _robust_pipeline(
    out_dir: Path,
    build: BuildConfig,
    label: LabelSettings,
    profile: str,
    epochs: int | None,
    noise_range: tuple[float, float],
) -> Pipeline:
    """``hd reproduce`` with a profile trained across noise levels: the robust rule (``quantile:Q``
    calibrated at each test level, guarded above the range) and ``risk:ALPHA`` likewise, both with
    the noise sweep up to 1.5 times the range's top (``ROBUST_SWEEP_STEP_M`` steps)."""
    lo, hi = noise_range
    sweep = parse_sigma_sweep(f"0:{1.5 * hi:.6g}:{ROBUST_SWEEP_STEP_M:g}")
    n_dead = label_defaults.N_DEAD_PIXELS
    rule = ROBUST_THRESHOLD_SPEC
    return Pipeline(
        out_dir=out_dir,
        build=build,
        label=label,
        profile=profile,
        epochs=epochs,
        train_sigma_m=None,
        evaluations=(
            Evaluation(
                "eval",
                "report",
                rule,
                n_dead,
                f"Table 1, Table 2, noise sweep to {1.5 * hi * 100:g} cm ({rule}, calibrated at each noise level)",
                calibrate="each",
                sigma_sweep=sweep,
            ),
            Evaluation(
                "eval-risk",
                "report-risk",
                f"risk:{REPRODUCE_RISK_ALPHA:g}",
                0,
                f"risk-controlled threshold, alpha = {REPRODUCE_RISK_ALPHA:g}, calibrated at each noise level",
                calibrate="each",
                sigma_sweep=sweep,
            ),
        ),
        train_what=(
            f"Bayesian SegNet, {profile} profile, trained across {lo * 100:g} to {hi * 100:g} cm "
            "(noisy DEMs made on the fly)"
        ),
    )


def _paper_build() -> BuildConfig:
    """The paper's dataset settings on the procedural terrain (defaults, the three noise levels)."""
    from lidarsim.recipe import BuildSettings

    return BuildSettings(sigmas_m=lidar_defaults.PAPER_SIGMAS_M).to_config()


def run_pipeline(
    pipeline: Pipeline,
    workers: int | None,
    echo: Echo,
    progress: ProgressFactory,
    train_progress: EpochProgress = True,
) -> dict[str, float]:
    """Check, then run every stage of ``pipeline`` (finished ones are skipped); returns the stage times, seconds.

    ``echo`` prints one message (stage headers, summaries); ``progress`` makes a progress bar;
    ``train_progress`` shows the training's epochs as ``hd train`` does (``hdnet.train.train``'s
    ``progress``: a bar, nothing, or a function given each epoch's metrics row, e.g. one log line).
    """
    pipeline.check()
    log = StageLog(pipeline.out_dir, echo)
    with log.stage("build", pipeline.build_what()):
        _build_unless_done(pipeline, workers, echo, progress)
    with log.stage("label", "DEMs, ALHAT labels and the baseline"):
        _label(pipeline, workers, echo, progress)
    if pipeline.inspect:
        _inspect(pipeline.dataset_dir, echo)
    with log.stage("train", pipeline.train_what):
        _train(pipeline, echo, train_progress)
    for evaluation in pipeline.evaluations:
        with log.stage(evaluation.stage, evaluation.what):
            _evaluate_unless_done(pipeline, evaluation, echo, progress)
    return log.finish()


def training_done_message(checkpoint: Path, run_dir: Path) -> str:
    """What ``hd train`` (and a pipeline's training stage) prints at the end: where, and how fast.

    The speed is the median training throughput over the run's epochs (images/s over the training
    steps, data loading included, validation excluded) and the minutes spent in training steps.
    """
    from hdnet.train import load_checkpoint, median_images_per_s

    timing = load_checkpoint(checkpoint).get("timing", [])
    rate = median_images_per_s(timing)
    seconds = sum(float(t["train_seconds"]) for t in timing)
    speed = (
        ""
        if rate is None
        else (f"; {rate:.1f} images/s (median over {len(timing)} epochs, {seconds / 60:.1f} min of training steps)")
    )
    return f"training done: {checkpoint} (metrics in {Path(run_dir) / 'metrics.csv'}){speed}"


def report_written_message(report_dir: Path) -> str:
    """What ``hd eval`` (and a pipeline's evaluation stage) prints at the end."""
    return f"report: {Path(report_dir) / 'report.md'} (and report.json, figures)"


# ------------------------------------------------------------------------------------------- stages
def _build_unless_done(pipeline: Pipeline, workers: int | None, echo: Echo, progress: ProgressFactory) -> None:
    from lidarsim.build import build_dataset
    from lidarsim.shards import MANIFEST_NAME

    data = pipeline.dataset_dir
    if (data / MANIFEST_NAME).exists():
        echo(f"dataset {data} already built")
        return
    with _closing(progress("scans", "scan")) as bar:
        summary = build_dataset(data, pipeline.build, workers=workers, progress=bar)
    echo(summary.paragraph())


def _label(pipeline: Pipeline, workers: int | None, echo: Echo, progress: ProgressFactory) -> None:
    from hdlabels.labeling import label_dataset

    with _closing(progress("labels", "scan")) as bar:
        summary = label_dataset(pipeline.dataset_dir, pipeline.label, workers=workers, progress=bar)
    echo(summary.paragraph())


def _inspect(directory: Path, echo: Echo) -> None:
    from hdcore.errors import DamagedFileError
    from hdlabels.store import LABEL_SCHEMA, LABEL_SCHEMA_VERSION
    from lidarsim.inspect import INTACT_STATUS, damaged_message, damaged_status, describe_dataset
    from lidarsim.shards import verify_dataset

    echo(describe_dataset(directory))
    problems = verify_dataset(directory, known_schemas={LABEL_SCHEMA: LABEL_SCHEMA_VERSION})
    if problems:
        for line in damaged_status(problems):
            echo(line)
        raise DamagedFileError(damaged_message(directory, problems))
    echo(INTACT_STATUS)


def _train(pipeline: Pipeline, echo: Echo, progress: EpochProgress) -> None:
    from hdnet.fit import FitConfig, fit

    config = FitConfig(
        profile=pipeline.profile,
        epochs=pipeline.epochs,
        train_sigma_m=pipeline.train_sigma_m,
        seed=pipeline.seed,
        resume=True,
        progress=progress,
    )
    checkpoint = fit(pipeline.dataset_dir, pipeline.run_dir, config)
    echo(training_done_message(checkpoint, pipeline.run_dir))


def _evaluate_unless_done(
    pipeline: Pipeline, evaluation: Evaluation, echo: Echo, progress: ProgressFactory | None = None
) -> None:
    from hdnet.evaluate import EvalConfig, evaluate_to_report

    report = pipeline.out_dir / evaluation.directory
    if (report / "report.json").exists():
        echo(f"report {report} already written")
        return
    config = EvalConfig(
        mc_samples=pipeline.mc_samples,
        drop_pixels=evaluation.drop_pixels,
        threshold=evaluation.threshold,
        seed=pipeline.seed,
        calibrate=evaluation.calibrate,
        sigma_sweep=evaluation.sigma_sweep,
    )
    if progress is None:
        result = evaluate_to_report(pipeline.run_dir, pipeline.dataset_dir, report, config)
    else:
        with _closing(progress("eval", "image")) as bar:
            result = evaluate_to_report(pipeline.run_dir, pipeline.dataset_dir, report, config, progress=bar)
    echo(result.summary())
    echo(report_written_message(report))


@contextlib.contextmanager
def _closing(bar: ProgressBar) -> Iterator[ProgressBar]:
    try:
        yield bar
    finally:
        bar.close()


class StageLog:
    """Prints, times and records (``OUT/stages.json``) the stages of a multi-stage command."""

    def __init__(self, out_dir: Path, echo: Echo) -> None:
        self.out_dir = out_dir
        self.echo = echo
        self.times: dict[str, float] = {}

    @contextlib.contextmanager
    def stage(self, name: str, what: str) -> Iterator[None]:
        """``== NAME: WHAT`` before the stage, ``== NAME: done in S s`` after it."""
        self.echo(f"== {name}: {what}")
        t0 = time.perf_counter()
        yield
        self.times[name] = round(time.perf_counter() - t0, 1)
        self.echo(f"== {name}: done in {self.times[name]:.1f} s")

    def finish(self) -> dict[str, float]:
        """Append this run's stage times to ``stages.json`` (a damaged file is started again)."""
        from hdcore.storage import OutputTransaction, write_json_atomic

        path = self.out_dir / STAGES_FILE
        previous: Any
        with OutputTransaction(self.out_dir, "pipeline"):
            try:
                previous = json.loads(read_regular_text(path)) if os.path.lexists(path) else {}
            except (OSError, ValueError):
                previous = {}
            if not isinstance(previous, dict) or not isinstance(previous.get("runs", []), list):
                previous = {}
            previous.setdefault("runs", []).append(self.times)
            write_json_atomic(path, previous)
        self.echo("stage times (s): " + ", ".join(f"{k} {v:.1f}" for k, v in self.times.items()))
        return self.times


def first_test_scan(dataset_dir: Path) -> int | None:
    """The index of the dataset's first test-split scan (one the network never trained on), or None:
    no test scan, or a dataset that cannot be read (only the ``split`` and ``scan_index`` arrays are)."""
    from hdcore.storage import confine, open_h5
    from lidarsim.shards import SPLIT_NAMES, read_manifest

    test = SPLIT_NAMES.index("test")
    try:
        for entry in read_manifest(dataset_dir)["shards"]:
            with open_h5(confine(dataset_dir, entry["path"])) as f:
                split = np.asarray(f["split"][:])
                if (split == test).any():
                    return int(np.asarray(f["scan_index"][:])[np.argmax(split == test)])
    except (HdError, OSError, KeyError, TypeError):
        return None
    return None


def demo_next_steps(out_dir: Path) -> str:
    """What to try after ``hd demo``: the hazard map of one test scan (the first of the test split:
    a scan of the training split would map ground the network has seen) and of a whole DTM."""
    import shutil
    import sys

    hd = "hd" if shutil.which("hd") else f"{Path(sys.executable).parent / 'hd'}"
    scan = first_test_scan(out_dir / "dataset")
    scan = 0 if scan is None else scan
    return (
        "Next: map the hazards of a test scan at 7 cm, or of a whole terrain:\n"
        f"  {hd} detect {out_dir}/run --data {out_dir}/dataset --scan {scan} --sigma 0.07 "
        f"--out {out_dir}/detect-scan{scan}\n"
        f"  {hd} make-dtm {out_dir}/mars.tif && {hd} detect {out_dir}/run --dtm {out_dir}/mars.tif "
        f"--out {out_dir}/detect-mars"
    )
