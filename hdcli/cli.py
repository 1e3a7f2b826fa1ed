"""The ``hd`` command: options and calls; lidarsim, hdlabels and hdnet do the work.

Each command's options are generated from the settings it fills (``hdcore.setting.click_options``
over ``lidarsim.recipe.BuildSettings``, ``hdlabels.settings.LabelSettings``, ``hdnet.fit.FitConfig``,
...), shared ones come from ``hdnet.shared_settings``, and the terminal (one-line errors, signals,
summaries, progress) is ``hdcli.terminal`` (docs/reliability.md).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import click
from click.core import ParameterSource

from hdcli import terminal
from hdcli.chains import PAPER_RECIPE, DemoSettings, ReproduceSettings, run_demo, run_reproduce
from hdcli.inspection import Verdict, inspect_directory, known_schemas, verify_directory
from hdcli.options import dtm_option, out_option, overwrite_option, recipe_option, scheduler_option, workers_option
from hdcli.terminal import (
    OUTPUT,
    HdGroup,
    ScanProgress,
    epoch_progress,
    friendly_errors,
    json_output,
    record,
    refuse_with_recipe,
    say,
)
from hdcore.outcome import Done, counted
from hdcore.redact import redact_urls
from hdcore.setting import (
    DATASET_OR_URL,
    DIRECTORY,
    FILE_OR_DIRECTORY,
    NonEmptyPath,
    SettingsCommand,
    bounded,
    click_options,
    settings_from_options,
)
from hdlabels.errors import HdLabelsError
from hdnet.detect_settings import DetectSettings
from hdnet.shared_settings import LABELS_FORMS
from lidarsim import limits
from lidarsim._version import __version__
from lidarsim.errors import LidarsimError
from lidarsim.make_dtm import DtmSettings


# ------------------------------------------------------------------------------------------ commands
@click.group(cls=HdGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="hd")
@click.option("-q", "--quiet", is_flag=True, help="No progress and no summaries: errors and warnings only.")
@click.option("--no-progress", is_flag=True, help="No progress bars (also: TQDM_DISABLE=1).")
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="Each command's summary as one JSON object on stdout (for scripts); a command without one refuses it.",
)
@click.pass_context
def main(ctx: click.Context, quiet: bool = False, no_progress: bool = False, as_json: bool = False) -> None:
    """hd — hazard-detection datasets, ALHAT labels and uncertainty-aware networks for planetary landing."""
    terminal.start(ctx, quiet, no_progress, as_json)


@main.command("build-dataset", cls=SettingsCommand, settings=("lidarsim.recipe:BuildSettings",))
@out_option(
    "out_dir",
    "Dataset directory to create (default: named after the recipe, the DTM file or the procedural terrain, in the "
    "current directory).",
    required=False,
)
@workers_option()
@scheduler_option()
@click.option(
    "--max-shards",
    type=bounded(limits.SHARD_FILES),
    default=limits.MAX_SHARD_FILES,
    show_default=True,
    help="Shard files the build may write (scans / --shard-size, rounded up); a build that needs more is "
    "refused before any work. Not recorded in the dataset.",
)
@overwrite_option("Replace an existing dataset in --out.")
@recipe_option(
    "Build the dataset of a recipe (datasets/<name>): the recipe fixes every content setting but the size; "
    "--scans or --shard-size with it build a deviation from the recipe, recorded in the manifest."
)
@click.pass_context
@json_output
@friendly_errors
def build_dataset_cmd(ctx: click.Context, out_dir: Path | None, recipe: Path | None, **options: Any) -> None:
    """Simulate flash-LiDAR scans over a terrain and write clean and noisy point clouds as HDF5 shards."""
    from hdcli.build_job import build_job
    from lidarsim.recipe_deviation import SIZE_OPTIONS, SIZE_SETTINGS

    workers, scheduler, overwrite = options.pop("workers"), options.pop("scheduler"), options.pop("overwrite")
    max_shards = options.pop("max_shards")
    resized = None
    if recipe is not None:
        sizes = set(SIZE_SETTINGS)
        refuse_with_recipe(
            ctx,
            set(options) - sizes,
            f"every content setting but the size ({', '.join(SIZE_OPTIONS.values())})",
            LidarsimError,
        )
        resized = {k: options[k] for k in sizes if ctx.get_parameter_source(k) is ParameterSource.COMMANDLINE}
    with ScanProgress("scans") as progress:
        _done(build_job(out_dir, options, recipe, workers, scheduler, overwrite, progress, say, max_shards, resized))


@main.command("make-dtm")
@click.argument("out_path", type=NonEmptyPath(dir_okay=False, path_type=Path))
@click_options(DtmSettings)
@overwrite_option("Replace an existing file.")
@friendly_errors
def make_dtm_cmd(out_path: Path, overwrite: bool, **settings: Any) -> None:
    """Write the procedural Mars terrain as a GeoTIFF (the default terrain of build-dataset); with
    --base, a real DTM's relief with the procedural rocks (and small craters) added."""
    from lidarsim.make_dtm import make_dtm

    say(make_dtm(out_path, DtmSettings(**settings), overwrite))


def _show(verdict: Verdict) -> None:
    """Print a check's lines (stdout, then stderr; URLs without their secrets); its failure is the command's error."""
    for line in verdict.out:
        click.echo(redact_urls(line))
    for line in verdict.err:
        click.echo(redact_urls(line), err=True)
    if verdict.failure is not None:
        raise click.ClickException(redact_urls(verdict.failure))


@main.command("inspect")
@click.argument("directory", type=DATASET_OR_URL)
@click.option("--json", "as_json", is_flag=True, help="Print the summary as one JSON object (for scripts).")
@click.option(
    "--plot",
    type=NonEmptyPath(dir_okay=False, path_type=Path),
    default=None,
    metavar="FILE",
    help="Also draw the dataset at a glance into FILE (.png, .pdf or .svg; never inside the dataset): scan "
    "footprints by split on the terrain, safe fraction per sigma and split, heights, altitudes.",
)
@click.option(
    "--labels",
    default=None,
    metavar="NAME",
    help=f"With --plot: the labelling to show (default: the dataset's only one): {LABELS_FORMS}.",
)
@overwrite_option("With --plot: replace an existing FILE.")
@json_output
@friendly_errors
def inspect_cmd(directory: Path | str, as_json: bool, plot: Path | None, labels: str | None, overwrite: bool) -> None:
    """Summarise a dataset (a directory or a URL: s3://bucket/prefix, https://host/path; scans, splits, noise
    levels, sensor, terrain, labels; every file checked) or a
    run (profile, training data and noise, epochs, metrics); --plot draws a dataset at a glance."""
    _show(inspect_directory(directory, as_json or OUTPUT.json, plot, labels, overwrite))


@main.command("compare")
@click.argument("reports", nargs=-1, metavar="REPORT...", type=click.Path(path_type=Path))
@click.option(
    "--format",
    "fmt",
    type=click.Choice(("table", "markdown", "json")),
    default=None,
    help="table (the terminal's, default), markdown, or json (as hd --json compare).",
)
@json_output
@friendly_errors
def compare_cmd(reports: tuple[Path, ...], fmt: str | None) -> None:
    """The key rows of several hd eval reports side by side (Table 1, the threshold, P(safe landing)),
    then the settings that differ. Each REPORT is an hd eval --out directory; nothing is written."""
    from hdnet.compare import compare, render

    if OUTPUT.json and fmt not in (None, "json"):
        raise click.UsageError(f"hd --json prints JSON; drop --format {fmt} or --json")
    click.echo(render(compare(list(reports)), "json" if OUTPUT.json else fmt or "table"))


@main.command("view", cls=SettingsCommand, settings=("hdnet.view:ViewSettings",))
@click.argument("directory", type=FILE_OR_DIRECTORY)
@click.option(
    "--out",
    "out_path",
    type=NonEmptyPath(dir_okay=False, path_type=Path),
    default=None,
    help="The page to write (default: DIRECTORY-view.html beside DIRECTORY, which is left as it is); an existing "
    "file is replaced only when it is an earlier page of hd view.",
)
@dtm_option(
    "With an hd detect output whose DTM has moved: the DTM it read (checked against detect.json's sha256), for the "
    "hillshade."
)
@json_output
@friendly_errors
def view_cmd(directory: Path, out_path: Path | None, dtm_path: Path | None, **settings: Any) -> None:
    """One self-contained HTML page (no network needed) of an hd detect output (hillshade, safety map, P(safe),
    uncertainty and baseline as layers, the landing sites, the settings), of an hd descend output (each
    descent frame by frame: the mosaic, its maps and the site track with its diverts) or of an hd eval report
    (its tables, figures and settings). DIRECTORY is an hd detect, hd descend or hd eval --out directory."""
    from hdnet.view import ViewSettings, view_job

    _done(view_job(directory, out_path, ViewSettings(**settings), dtm_path))


@main.command("verify")
@click.argument("directory", type=DATASET_OR_URL)
@recipe_option("Also check the dataset against the checksums published with a recipe.")
@friendly_errors
def verify_cmd(directory: Path | str, recipe: Path | None) -> None:
    """Check every file of a dataset (a directory or a URL, each byte read once) against the manifest's
    checksums and the schema versions.

    With --recipe, also every file against the recipe's published build: identical (sha256), or
    rebuilt and equal to it within the tolerances of its content fingerprints (docs/shard-format.md).
    """
    _show(verify_directory(directory, recipe))


@main.command("label", cls=SettingsCommand, settings=("hdlabels.settings:LabelSettings",))
@click.argument("directory", type=DATASET_OR_URL)
@workers_option()
@scheduler_option()
@recipe_option("Take the lander and DEM settings from a recipe's [label] section.")
@click.pass_context
@json_output
@friendly_errors
def label_cmd(ctx: click.Context, directory: Path, workers: int | None, recipe: Path | None, **options: Any) -> None:
    """Grid every scan into DEMs and add ALHAT labels and the baseline P(safe) to the dataset."""
    from hdcli.label_job import label_job

    scheduler = options.pop("scheduler")
    truth = None
    if recipe is not None:
        # The truth picks which labelling of the recipe to make; the lander and DEM stay the recipe's.
        refuse_with_recipe(ctx, set(options) - {"truth"}, "the lander and DEM settings", HdLabelsError)
        if ctx.get_parameter_source("truth") is ParameterSource.COMMANDLINE:
            truth = options["truth"]
    with ScanProgress("labels") as progress:
        _done(label_job(directory, options, recipe, workers, scheduler, progress, truth=truth))


@main.command("mosaic", cls=SettingsCommand, settings=("hdlabels.mosaic_dataset:MosaicSettings",))
@click.argument("source", type=DIRECTORY)
@out_option("out_dir", "Mosaic dataset directory to create (one scan per descent).")
@workers_option()
@scheduler_option()
@overwrite_option("Replace an existing mosaic dataset in --out.")
@recipe_option("Take the DEM grid (size, spacing, convention, gridding) from a recipe's [label] section.")
@click.pass_context
@json_output
@friendly_errors
def mosaic_cmd(
    ctx: click.Context, source: Path, out_dir: Path, workers: int | None, recipe: Path | None, **options: Any
) -> None:
    """Mosaic every descent of a descent build into one DEM: a dataset with one scan per descent."""
    from hdcli.mosaic_job import mosaic_job

    scheduler, overwrite = options.pop("scheduler"), options.pop("overwrite")
    if recipe is not None:
        refuse_with_recipe(ctx, set(options) - {"poses", "frames"}, "the DEM grid", HdLabelsError)
    with ScanProgress("descents", unit="descent") as progress:
        _done(mosaic_job(source, out_dir, options, recipe, workers, scheduler, overwrite, progress))


def _done(done: Done) -> None:
    """Print a job's summary (``say``) and its JSON record (``hd --json``)."""
    for line in done.lines:
        say(line)
    record(done.record)


@main.command("train", cls=SettingsCommand, settings=("hdnet.fit:FitConfig", "hdcli.train_job:TrainingNoiseOptions"))
@click.argument("dataset", type=DATASET_OR_URL)
@out_option("run_dir", "Run directory (checkpoints, metrics.csv, config.json).")
@json_output
@friendly_errors
def train_cmd(dataset: Path | str, run_dir: Path, **options: Any) -> None:
    """Train the Bayesian SegNet on the noisy DEMs of a labelled dataset (a directory or a URL:
    s3://bucket/prefix, https://host/path; the run is written locally)."""
    from hdcli.train_job import train_job

    _done(train_job(dataset, run_dir, options, epoch_progress()))


@main.command("eval", cls=SettingsCommand, settings=("hdnet.eval_settings:EvalConfig", "hdcli.eval_job:SweepOption"))
@click.argument("run_dir", type=DIRECTORY)
@click.option(
    "--data",
    "dataset",
    required=True,
    type=DATASET_OR_URL,
    help="Labelled dataset to evaluate on (its test split, or --split's): a directory or a URL.",
)
@out_option("out_dir", "Report directory (report.md, report.json, figures).")
@overwrite_option("Replace an existing report (never other files, never an input).")
@json_output
@friendly_errors
def eval_cmd(run_dir: Path, dataset: Path | str, out_dir: Path, overwrite: bool, **options: Any) -> None:
    """Evaluate a trained run: the paper's tables, threshold sweep, calibration, noise sweep and figures."""
    from hdcli.eval_job import eval_job

    with ScanProgress("eval", unit="image") as progress:
        _done(eval_job(run_dir, dataset, out_dir, options, overwrite, progress))


@main.command("detect")
@click.argument("run_dir", type=FILE_OR_DIRECTORY)
@dtm_option("Terrain to map: any GDAL raster in metres (GeoTIFF, HiRISE PDS3 .IMG), any size.")
@click.option(
    "--data",
    "dataset",
    type=DATASET_OR_URL,
    help="Instead of --dtm: a labelled dataset (a directory or a URL), with --scan.",
)
@out_option("out_dir", "Output directory (maps, sites, overview, detect.json).", directory=False)
@click_options(DetectSettings)
@overwrite_option("Replace an earlier hd detect output in --out (never other files, never an input).")
@json_output
@friendly_errors
def detect_cmd(
    run_dir: Path, out_dir: Path, dataset: Path | str | None, dtm_path: Path | None, overwrite: bool, **settings: Any
) -> None:
    """Hazard maps and ranked landing sites of a DTM (or of one scan) from a trained run."""
    from hdcli.detect_job import detect_job

    with ScanProgress("tiles", unit="tile") as progress:
        _done(
            detect_job(run_dir, out_dir, dtm_path, dataset, DetectSettings(**settings, overwrite=overwrite), progress)
        )


@main.command("descend", cls=SettingsCommand, settings=("hdnet.descend_settings:DescendSettings",))
@click.argument("run_dir", type=FILE_OR_DIRECTORY)
@click.option(
    "--data",
    "dataset",
    required=True,
    type=DIRECTORY,
    help="The descent build whose frames to fly (hd build-dataset --descent-frames K).",
)
@out_option("out_dir", "Output directory (per-frame maps, site tracks, descend.json).", directory=False)
@overwrite_option("Replace an earlier hd descend output in --out (never other files, never an input).")
@json_output
@friendly_errors
def descend_cmd(run_dir: Path, dataset: Path, out_dir: Path, overwrite: bool, **settings: Any) -> None:
    """Fly descents as a lander does: each frame registered to those before, the mosaic mapped after every
    frame, and the aim diverted when its ground turns out unsafe."""
    from hdcli.descend_job import descend_job

    with ScanProgress("frames", unit="frame") as progress:
        _done(descend_job(run_dir, dataset, out_dir, settings, overwrite, progress))


@main.command("export-model", cls=SettingsCommand, settings=("hdnet.export_model_settings:ExportModelSettings",))
@click.argument("run_dir", type=FILE_OR_DIRECTORY)
@out_option(
    "out",
    "The graph to write (a .onnx file); its side file is written beside it (the same name, .json).",
    directory=False,
)
@overwrite_option("Replace an earlier export at --out (the graph and its side file).")
@json_output
@friendly_errors
def export_model_cmd(run_dir: Path, out: Path, overwrite: bool, **options: Any) -> None:
    """The network of a trained run (its last.pt) as one ONNX graph for flight software, its dropout masks as
    inputs (MC dropout outside the graph), with a side file of everything needed to run it: the input
    preparation, the masks' names and shapes, the class order and H_t when calibrated (docs/user-guide.md)."""
    from hdcli.export_model_job import export_model_job

    _done(export_model_job(run_dir, out, options, overwrite))


@main.command("demo")
@out_option("out_dir", "Directory of the demo run.", required=False, default=Path("demo-out"))
@click_options(DemoSettings)
@workers_option()
@friendly_errors
def demo_cmd(out_dir: Path, workers: int | None, **settings: Any) -> None:
    """The whole chain at demo scale on the built-in procedural Mars terrain (re-running resumes)."""
    say(run_demo(out_dir, DemoSettings(**settings), workers, click.echo, ScanProgress, epoch_progress()))


@main.command("reproduce")
@click_options(ReproduceSettings)
@dtm_option("Use this DTM instead of the recipe's terrain.")
@out_option("out_dir", "Directory of the reproduction.", required=False, default=Path("reproduction"))
@workers_option()
@recipe_option(
    f"The dataset recipe to reproduce the paper on (default: {PAPER_RECIPE}, the recipe that comes with hd, "
    "in a source checkout or an installed package)."
)
@friendly_errors
def reproduce_cmd(
    dtm_path: Path | None, out_dir: Path, workers: int | None, recipe: Path | None, **settings: Any
) -> None:
    """The paper end to end: the dataset of datasets/mars-paper (S-167/S-300/S-700 on one terrain and trajectory,
    1000 scans, 800/100/100) and its labels, training at 1.67 cm, Table 1, Table 2 (10 dropped pixels), threshold
    sweep and panels, plus the risk-controlled threshold (alpha = 0.05). Each stage is resumable; finished stages
    are skipped."""
    run_reproduce(
        out_dir, recipe, dtm_path, ReproduceSettings(**settings), workers, click.echo, ScanProgress, epoch_progress()
    )


@main.command("export", cls=SettingsCommand, settings=("lidarsim.export:ExportSettings",))
@click.argument("dataset", type=DIRECTORY)
@out_option("out_dir", "Directory of the LAS/LAZ files (one per scan) and export.json.")
@click.option(
    "--scans",
    "scans_text",
    default=None,
    metavar="LIST",
    help="Scans to export: indices and ranges, e.g. 0,5,10-19 (default: every scan).",
)
@overwrite_option("Replace an earlier export in --out.")
@json_output
@friendly_errors
def export_cmd(dataset: Path, out_dir: Path, scans_text: str | None, overwrite: bool, **options: Any) -> None:
    """Write scans as LAS 1.4 / LAZ point clouds for point-cloud tools (CloudCompare, PDAL), one file per scan,
    in the scan frame or in map coordinates with the DTM's CRS."""
    from lidarsim.export import ExportSettings, export_scans, parse_scans

    scans = parse_scans(scans_text) if scans_text is not None else ()
    settings = settings_from_options(ExportSettings, options, scans=scans)
    with ScanProgress("export") as progress:
        summary = export_scans(dataset, out_dir, settings, overwrite=overwrite, progress=progress)
    say(summary.paragraph())
    record({"command": "export", **dataclasses.asdict(summary)})


@main.command("card")
@click.argument("dataset", type=DIRECTORY, required=False)
@recipe_option(
    "Recipe directory the dataset was built from; card.md and checksums.json are written there.", required=True
)
@click.option("--machine", default="", help="Where the published build was made (recorded in the card).")
@friendly_errors
def card_cmd(dataset: Path | None, recipe: Path, machine: str) -> None:
    """Write the dataset card (card.md), the published checksums (checksums.json) and the Croissant 1.0
    metadata (croissant.json) of a recipe. Without DATASET: croissant.json alone, from the recipe and
    its published checksums (no build; the files are listed without their sizes)."""
    from lidarsim.card import publish_card, publish_recipe_croissant

    if dataset is None:
        say(f"wrote {publish_recipe_croissant(recipe)} (from the recipe's checksums.json, no build)")
        return
    card = publish_card(dataset, recipe, machine)
    say(f"wrote {card.card_path}, {card.checksums_path} and {card.croissant_path} ({counted(card.n_shards, 'shard')})")


@main.command("publish")
@click.argument("directory", type=DIRECTORY)
@click.argument("url")
@overwrite_option("Replace another dataset (or other files) at URL; without it they are kept and publish refuses.")
@json_output
@friendly_errors
def publish_cmd(directory: Path, url: str, overwrite: bool) -> None:
    """Upload a dataset to URL (s3://bucket/prefix, file:///path, or a local folder such as /mnt/share/mars):
    shards first, manifest.json last, so
    a reader never sees a half-published dataset; re-run the same command to resume an interrupted one."""
    from lidarsim.transfer import publish_dataset

    _done(publish_dataset(directory, url, overwrite, known_schemas()))


@main.command("pull")
@click.argument("url")
@click.argument("directory", type=DIRECTORY)
@json_output
@friendly_errors
def pull_cmd(url: str, directory: Path) -> None:
    """Copy the dataset at URL into DIRECTORY (new or empty): each file checked against the manifest's sha256,
    the manifest written last, then every file verified; re-run the same command to resume."""
    from lidarsim.transfer import pull_dataset

    _done(pull_dataset(url, directory, known_schemas()))
