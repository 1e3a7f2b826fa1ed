"""The ``hd`` command: wires lidarsim, hdlabels and hdnet together; holds no logic of its own.

Every command turns bad input into a one-line error and a non-zero exit status. Ctrl-C, SIGTERM
and SIGHUP stop a command cleanly (partial files removed, resumable; a second signal does not
interrupt the clean-up) with exit status 128 + the signal number: 130, 143, 129
(docs/reliability.md).
"""

from __future__ import annotations

import math
import signal
import sys
from collections.abc import Callable
from functools import wraps
from pathlib import Path
from typing import Any

import click

from lidarsim import defaults as lidar_defaults
from lidarsim._version import __version__
from lidarsim.errors import LidarsimError


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised in the main thread so that it unwinds like Ctrl-C."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def _ignore(signum: int, frame: Any) -> None:
    """A signal after the first: the clean-up goes on. (A Python no-op, not SIG_IGN: signals already
    pending when the handler changes to SIG_IGN make CPython raise "ignored due to race condition".)"""


def _raise_terminated(signum: int, frame: Any) -> None:
    for sig in _STOP_SIGNALS:  # a second signal (Ctrl-C pressed twice) must not interrupt the clean-up
        signal.signal(sig, _ignore)
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated(signum)


def _install_signal_handlers(ctx: click.Context) -> None:
    """Ctrl-C, SIGTERM and SIGHUP unwind as KeyboardInterrupt, once (restored when the command ends)."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        return
    previous = {sig: signal.signal(sig, _raise_terminated) for sig in _STOP_SIGNALS}
    ctx.call_on_close(lambda: [signal.signal(sig, handler) for sig, handler in previous.items()])


def _one_line(exc: BaseException) -> str:
    """The message of an error as one line (a DataLoader worker's error carries its traceback)."""
    text = str(exc).strip()
    if "Original Traceback" in text:
        text = text.splitlines()[-1].split(": ", 1)[-1]
    return " ".join(text.split()) if "\n" in text else text


def _known_errors() -> tuple[type[BaseException], ...]:
    errors: list[type[BaseException]] = [LidarsimError]
    for module, name in (("hdlabels.errors", "HdLabelsError"), ("hdnet.errors", "HdNetError")):
        try:
            mod = __import__(module, fromlist=[name])
            errors.append(getattr(mod, name))
        except (ImportError, AttributeError):
            pass
    return tuple(errors)


def _close_progress_bars() -> None:
    """End every open tqdm bar (with its newline), so that an error starts on its own line."""
    try:
        from tqdm import tqdm
    except ImportError:
        return
    for bar in list(getattr(tqdm, "_instances", [])):
        try:
            bar.close()
        except Exception:  # noqa: BLE001 - a bar that cannot close must not hide the error
            pass


def friendly_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    """Turn the packages' input errors into click errors: one line, exit status 1, no traceback."""

    @wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except BaseException:
            _close_progress_bars()
            raise

    return _one_line_errors(wrapper)


def _one_line_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    @wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except _known_errors() as exc:
            raise click.ClickException(_one_line(exc)) from None
        except OSError as exc:
            from lidarsim.storage import describe_os_error

            raise click.ClickException(describe_os_error(exc)) from None
        except MemoryError:
            raise click.ClickException("out of memory; use smaller settings (fewer scans per shard, "
                                       "a smaller batch or resolution)") from None
        except KeyboardInterrupt as exc:
            signum = getattr(exc, "signum", signal.SIGINT)
            what = "interrupted" if signum == signal.SIGINT else f"stopped by {signal.Signals(signum).name}"
            click.echo(f"\n{what}; re-run the same command to resume", err=True)
            sys.exit(128 + int(signum))

    return wrapper


def _check_finite(**values: float | None) -> None:
    """Refuse NaN and infinite option values (``--altitude inf``) with the option's name."""
    for name, value in values.items():
        if value is not None and not math.isfinite(value):
            raise LidarsimError(f"--{name.replace('_', '-')} must be a finite number, got {value}")


def _check_range(name: str, value: int | None, low: int, high: int | None = None) -> None:
    """Refuse an integer option outside [low, high]."""
    if value is None:
        return
    if value < low or (high is not None and value > high):
        span = f">= {low}" if high is None else f"in {low}..{high}"
        raise LidarsimError(f"--{name} must be {span}, got {value}")


class _Path(click.Path):
    """click.Path that refuses an empty string (which click would turn into the current directory)."""

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, str) and not value.strip():
            self.fail("must not be empty", param, ctx)
        return super().convert(value, param, ctx)


class _ScanProgress:
    """tqdm progress bar fed with (done, total) counts of scans (or of another ``unit``)."""

    def __init__(self, desc: str, unit: str = "scan") -> None:
        self.desc = desc
        self.unit = unit
        self.bar: Any = None

    def __call__(self, done: int, total: int) -> None:
        from tqdm import tqdm

        if self.bar is None:
            self.bar = tqdm(total=total, initial=done, desc=self.desc, unit=self.unit, dynamic_ncols=True)
        else:
            self.bar.update(done - self.bar.n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="hd")
@click.pass_context
def main(ctx: click.Context) -> None:
    """hd — hazard-detection datasets, ALHAT labels and uncertainty-aware networks for planetary landing."""
    from lidarsim.parallel import forked_children_die_with_parent

    _install_signal_handlers(ctx)
    forked_children_die_with_parent()


@main.command("build-dataset")
@click.option("--out", "out_dir", required=True, type=_Path(file_okay=False, path_type=Path), help="Dataset directory to create.")
@click.option("--dtm", "dtm_path", type=_Path(path_type=Path), default=None, help="DTM (GeoTIFF, HiRISE PDS3 .IMG, any GDAL raster in metres). Default: the procedural Mars terrain.")
@click.option("--sigma", "sigmas", type=float, multiple=True, help=f"Range noise 1-sigma in metres; repeat for several levels (default {lidar_defaults.DEFAULT_SIGMA_M}).")
@click.option("--scans", type=int, default=lidar_defaults.N_SCANS, show_default=True, help="Number of scans.")
@click.option("--seed", type=int, default=0, show_default=True, help="Master seed of every random stream.")
@click.option("--workers", type=int, default=None, help="Local worker processes (default: all cores).")
@click.option("--altitude", type=float, default=lidar_defaults.ALTITUDE_M, show_default=True, help="Sensor altitude above the terrain, metres.")
@click.option("--dtm-scale", type=float, default=1.0, show_default=True, help="Resample the DTM by this factor (the paper used 0.25).")
@click.option("--scheduler", default=None, help="Dask scheduler address (tcp://host:8786) to run shard tasks on a cluster.")
@click.option("--overwrite", is_flag=True, help="Replace an existing dataset in --out.")
@click.option("--shard-size", type=int, default=50, show_default=True, help="Scans per shard file.")
@click.option("--tilt", type=float, default=0.0, show_default=True, help="Off-nadir tilt of the boresight, degrees.")
@click.option("--jitter", type=float, default=0.0, show_default=True, help="1-sigma attitude jitter per axis, degrees.")
@click.option("--resolution", type=int, default=lidar_defaults.DETECTOR_ROWS, show_default=True, help="Detector pixels per side.")
@click.option("--fov", type=float, default=lidar_defaults.FOV_DEG, show_default=True, help="Field of view per side, degrees.")
@click.option("--dead-elements", type=int, default=0, show_default=True, help="Dead detector elements (no return).")
@click.option("--damaged-elements", type=int, default=0, show_default=True, help="Damaged detector elements (large range error).")
@click.option("--compression", type=click.Choice(["gzip", "lzf", "none"]), default="gzip", show_default=True, help="HDF5 compression of the point arrays.")
@click.option("--recipe", type=_Path(path_type=Path), default=None, help="Build exactly the dataset of a recipe (datasets/<name>); the recipe fixes every content setting.")
@friendly_errors
def build_dataset_cmd(out_dir: Path, dtm_path: Path | None, sigmas: tuple[float, ...], scans: int, seed: int,
                      workers: int | None, altitude: float, dtm_scale: float, scheduler: str | None, overwrite: bool,
                      shard_size: int, tilt: float, jitter: float, resolution: int, fov: float, dead_elements: int,
                      damaged_elements: int, compression: str, recipe: Path | None = None) -> None:
    """Simulate flash-LiDAR scans over a terrain and write clean and noisy point clouds as HDF5 shards."""
    from lidarsim.build import BuildConfig, build_dataset
    from lidarsim.sensor import SensorConfig
    from lidarsim.trajectory import TrajectoryConfig

    from lidarsim import limits
    from lidarsim.storage import check_output_dir

    _check_range("workers", workers, 1, limits.MAX_WORKERS)
    _check_range("seed", seed, 0)
    _check_range("scans", scans, 1, limits.MAX_SCANS)
    _check_range("resolution", resolution, 2, limits.MAX_DETECTOR_PX)
    _check_range("shard-size", shard_size, 1)
    _check_finite(altitude=altitude, dtm_scale=dtm_scale, tilt=tilt, jitter=jitter, fov=fov)
    for sigma in sigmas:
        _check_finite(sigma=sigma)
    check_output_dir(out_dir, "--out")
    if scheduler is not None:
        from lidarsim.parallel import check_scheduler_address

        check_scheduler_address(scheduler)
    if recipe is not None:
        from lidarsim.recipe import load_recipe

        ctx = click.get_current_context()
        content = ("dtm_path", "sigmas", "scans", "seed", "altitude", "dtm_scale", "shard_size", "tilt", "jitter",
                   "resolution", "fov", "dead_elements", "damaged_elements", "compression")
        given = [n for n in content if ctx.get_parameter_source(n) == click.core.ParameterSource.COMMANDLINE]
        if given:
            flags = ", ".join("--" + n.replace("_path", "").replace("_", "-") for n in given)
            raise LidarsimError(f"--recipe fixes every content setting; edit the recipe instead of passing {flags}")
        config = load_recipe(recipe).build
    else:
        config = BuildConfig(
            sigmas_m=tuple(sigmas) if sigmas else (lidar_defaults.DEFAULT_SIGMA_M,),
            seed=seed,
            sensor=SensorConfig(rows=resolution, cols=resolution, fov_x_deg=fov, fov_y_deg=fov,
                                dead_elements=dead_elements, damaged_elements=damaged_elements),
            trajectory=TrajectoryConfig(n_scans=scans, altitude_m=altitude, tilt_deg=tilt, jitter_deg=jitter),
            dtm_path=str(dtm_path) if dtm_path is not None else None,
            dtm_scale=dtm_scale,
            shard_size=shard_size,
            compression=compression,
        )
    progress = _ScanProgress("scans")
    try:
        summary = build_dataset(out_dir, config, workers=workers, scheduler=scheduler, overwrite=overwrite, progress=progress)
    finally:
        progress.close()
    click.echo(summary.paragraph())


@main.command("make-dtm")
@click.argument("out_path", type=_Path(dir_okay=False, path_type=Path))
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the procedural terrain.")
@click.option("--size", "size_m", type=float, default=None, help="Side of the square terrain, metres (default: the built-in size).")
@click.option("--spacing", "spacing_m", type=float, default=None, help="Grid spacing, metres/pixel (<= 0.5).")
@click.option("--rock-k", type=float, default=None, help="Golombek-Rapp rock abundance k (0.05 .. 0.4).")
@click.option("--overwrite", is_flag=True, help="Replace an existing file.")
@friendly_errors
def make_dtm_cmd(out_path: Path, seed: int, size_m: float | None, spacing_m: float | None, rock_k: float | None, overwrite: bool) -> None:
    """Write the procedural Mars terrain as a GeoTIFF (the default terrain of build-dataset)."""
    import dataclasses
    import json

    from lidarsim.procedural import MarsTerrainParams, generate_mars_terrain, write_geotiff
    from lidarsim.storage import check_output_file

    _check_range("seed", seed, 0)
    _check_finite(size=size_m, spacing=spacing_m, rock_k=rock_k)
    check_output_file(out_path, "OUT_PATH")
    if out_path.exists() and not overwrite:
        raise LidarsimError(f"{out_path} exists; pass --overwrite to replace it")
    changes = {k: v for k, v in (("size_m", size_m), ("spacing_m", spacing_m), ("rock_k", rock_k)) if v is not None}
    params = dataclasses.replace(MarsTerrainParams(), **changes)
    heights = generate_mars_terrain(params, seed=seed)
    tags = {"generator": "lidarsim.procedural", "seed": str(seed), "params": json.dumps(dataclasses.asdict(params))}
    write_geotiff(out_path, heights, params.spacing_m, origin_xy=(0.0, 0.0), crs_wkt="", tags=tags)
    click.echo(f"wrote {out_path}: {heights.shape[0]} x {heights.shape[1]} cells at {params.spacing_m:g} m/px, "
               f"heights {float(heights.min()):.1f} .. {float(heights.max()):.1f} m")


@main.command("inspect")
@click.argument("directory", type=_Path(file_okay=False, path_type=Path))
@friendly_errors
def inspect_cmd(directory: Path) -> None:
    """Summarise a dataset: scans, splits, noise levels, sensor, terrain, labels; and check every file."""
    from lidarsim.inspect import describe_dataset
    from lidarsim.shards import verify_dataset

    summary = describe_dataset(directory)
    problems = verify_dataset(directory, known_schemas=_known_schemas())
    click.echo(summary)
    if problems:
        click.echo(f"status    DAMAGED: {len(problems)} problem(s)", err=True)
        for p in problems:
            click.echo(f"          {p}", err=True)
        raise click.ClickException(f"{directory} is damaged ({len(problems)} problem(s)); `hd verify {directory}` "
                                   "lists them; rebuild or restore the damaged files")
    click.echo("status    intact: every file matches the manifest's sha256 and schema")


def _known_schemas() -> dict[str, str]:
    schemas: dict[str, str] = {}
    try:
        from hdlabels.store import LABEL_SCHEMA, LABEL_SCHEMA_VERSION

        schemas[LABEL_SCHEMA] = LABEL_SCHEMA_VERSION
    except ImportError:
        pass
    return schemas


@main.command("verify")
@click.argument("directory", type=_Path(file_okay=False, path_type=Path))
@click.option("--recipe", type=_Path(path_type=Path), default=None, help="Also check the dataset against the checksums published with a recipe.")
@friendly_errors
def verify_cmd(directory: Path, recipe: Path | None) -> None:
    """Check every file of a dataset against the manifest's checksums and the schema versions."""
    from lidarsim.shards import read_manifest, verify_dataset

    problems = verify_dataset(directory, known_schemas=_known_schemas())
    if recipe is not None:
        from lidarsim.recipe import RecipeError, check_against_checksums, load_recipe

        loaded = load_recipe(recipe)
        recorded = loaded.checksums()
        if recorded is None:
            raise RecipeError(f"{loaded.path.parent}: the recipe has no published checksums.json")
        problems += check_against_checksums(read_manifest(directory), recorded)
    if problems:
        for p in problems:
            click.echo(p, err=True)
        raise click.ClickException(f"{directory}: {len(problems)} problem(s) found")
    manifest = read_manifest(directory)
    n_files = len(manifest["shards"]) + sum(len(lab.get("shards", [])) for lab in manifest.get("labelings", []))
    click.echo(f"{directory}: OK, {n_files} files match the manifest's checksums and schema versions")


@main.command("label")
@click.argument("directory", type=_Path(file_okay=False, path_type=Path))
@click.option("--lander-diameter", type=float, default=10.0, show_default=True, help="Lander diameter, metres.")
@click.option("--pad-diameter", type=float, default=1.0, show_default=True, help="Footpad diameter, metres.")
@click.option("--max-slope-deg", type=float, default=10.0, show_default=True, help="Critical slope, degrees.")
@click.option("--max-roughness", type=float, default=0.20, show_default=True, help="Critical roughness, metres.")
@click.option("--lander", "layout", type=click.Choice(["square", "triangle"]), default="square", show_default=True, help="Pad layout: 4 pads in a square or 3 in a triangle.")
@click.option("--convention", type=click.Choice(["paper", "hd"]), default="paper", show_default=True, help="Label rules: paper (the ALHAT replica the paper used) or hd (sub-pixel geometric convention).")
@click.option("--baseline-combine", type=click.Choice(["product", "min"]), default=None, help="How the P(safe) baseline combines the nodes under the lander (default: paper product, hd min).")
@click.option("--gridding", type=click.Choice(["linear", "mean", "max", "nearest"]), default=None, help="Points to DEM: linear interpolation, or the mean, max or most central of each cell's returns (default: the convention's).")
@click.option("--yaws", type=int, default=None, help="hd convention: yaws per symmetry period of the pad layout (default 8).")
@click.option("--count-holes", is_flag=True, help="Count terrain below the lander plane as roughness too.")
@click.option("--dem-size", type=int, default=100, show_default=True, help="DEM side, pixels.")
@click.option("--dem-spacing", type=float, default=1.0, show_default=True, help="DEM spacing, metres/pixel.")
@click.option("--workers", type=int, default=None, help="Local worker processes (default: all cores).")
@click.option("--scheduler", default=None, help="Dask scheduler address to run the label tasks on a cluster.")
@click.option("--recipe", type=_Path(path_type=Path), default=None, help="Take the lander and DEM settings from a recipe's [label] section.")
@friendly_errors
def label_cmd(directory: Path, lander_diameter: float, pad_diameter: float, max_slope_deg: float, max_roughness: float,
              layout: str, yaws: int | None, count_holes: bool, dem_size: int, dem_spacing: float, workers: int | None,
              scheduler: str | None, recipe: Path | None = None, convention: str = "paper",
              baseline_combine: str | None = None, gridding: str | None = None) -> None:
    """Grid every scan into DEMs and add ALHAT labels and the baseline P(safe) to the dataset."""
    from hdlabels import defaults as label_defaults
    from hdlabels.errors import HdLabelsError
    from hdlabels.labeling import label_dataset
    from hdlabels.lander import Lander
    from hdlabels.store import DemSpec

    if recipe is not None:
        from lidarsim.recipe import load_recipe

        ctx = click.get_current_context()
        content = ("lander_diameter", "pad_diameter", "max_slope_deg", "max_roughness", "layout", "yaws",
                   "count_holes", "dem_size", "dem_spacing", "convention", "baseline_combine", "gridding")
        given = [n for n in content if ctx.get_parameter_source(n) == click.core.ParameterSource.COMMANDLINE]
        if given:
            flags = ", ".join("--" + ("lander" if n == "layout" else n.replace("_", "-")) for n in given)
            raise HdLabelsError(f"--recipe fixes the lander and DEM settings; edit the recipe instead of passing {flags}")
        settings = load_recipe(recipe).label
        layout = str(settings.get("lander", layout))
        lander_diameter = float(settings.get("lander_diameter_m", lander_diameter))
        pad_diameter = float(settings.get("pad_diameter_m", pad_diameter))
        max_slope_deg = float(settings.get("max_slope_deg", max_slope_deg))
        max_roughness = float(settings.get("max_roughness_m", max_roughness))
        yaws = int(settings["yaws"]) if "yaws" in settings else yaws
        count_holes = bool(settings.get("count_holes", count_holes))
        dem_size = int(settings.get("dem_size", dem_size))
        dem_spacing = float(settings.get("dem_spacing_m", dem_spacing))
        convention = str(settings.get("convention", "hd"))  # recipes from before conventions: hd
        baseline_combine = settings.get("baseline_combine", baseline_combine)
        gridding = settings.get("gridding", gridding)
    if yaws is not None and convention != "hd":
        raise HdLabelsError("--yaws applies to --convention hd only (the paper convention turns the lander in 10-degree steps)")
    from lidarsim import limits

    _check_range("workers", workers, 1, limits.MAX_WORKERS)
    _check_finite(lander_diameter=lander_diameter, pad_diameter=pad_diameter, max_slope_deg=max_slope_deg,
                  max_roughness=max_roughness, dem_spacing=dem_spacing)
    if scheduler is not None:
        from lidarsim.parallel import probe_scheduler

        probe_scheduler(scheduler)  # a malformed or unreachable address, before anything is written
    if dem_size < 2 or not (dem_spacing > 0):
        raise HdLabelsError(f"the DEM must be at least 2 pixels of positive spacing, got {dem_size} x {dem_spacing}")
    lander = Lander(diameter_m=lander_diameter, pad_diameter_m=pad_diameter, max_slope_deg=max_slope_deg,
                    max_roughness_m=max_roughness, layout=layout,  # type: ignore[arg-type]
                    n_yaws=yaws if yaws is not None else label_defaults.N_YAWS, count_holes=count_holes,
                    convention=convention, baseline_combine=baseline_combine)  # type: ignore[arg-type]
    grid = DemSpec.for_convention(convention, dem_size, dem_size, dem_spacing, gridding)
    progress = _ScanProgress("labels")
    try:
        summary = label_dataset(directory, lander, grid, workers=workers, scheduler=scheduler, progress=progress)
    finally:
        progress.close()
    click.echo(summary.paragraph())


@main.command("train")
@click.argument("dataset", type=_Path(file_okay=False, path_type=Path))
@click.option("--out", "run_dir", required=True, type=_Path(file_okay=False, path_type=Path), help="Run directory (checkpoints, metrics.csv, config.json).")
@click.option("--profile", type=click.Choice(["paper", "cpu", "tiny"]), default="cpu", show_default=True, help="Training profile: paper (GPU, 512x512, full width), cpu (2-core machine), tiny (tests, demos); docs/hdnet.md lists their settings.")
@click.option("--epochs", type=int, default=None, help="Epochs (default: the profile's).")
@click.option("--train-sigma", type=float, default=lidar_defaults.DEFAULT_SIGMA_M, show_default=True, help="Noise level of the training inputs, metres.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of initialisation and shuffling.")
@click.option("--resume", is_flag=True, help="Continue an interrupted run from its last checkpoint.")
@click.option("--labels", "labeling", default=None, help="Labelling to train on (when the dataset has several).")
@click.option("--num-workers", type=int, default=0, show_default=True, help="DataLoader worker processes.")
@click.option("--overwrite", is_flag=True, help="Start an existing run again, or write into a non-empty directory that is not a run.")
@friendly_errors
def train_cmd(dataset: Path, run_dir: Path, profile: str, epochs: int | None, train_sigma: float, seed: int,
              resume: bool, labeling: str | None, num_workers: int = 0, overwrite: bool = False) -> None:
    """Train the Bayesian SegNet on the noisy DEMs of a labelled dataset."""
    from hdnet.errors import HdNetError
    from hdnet.fit import fit
    from hdnet.train import load_checkpoint, median_images_per_s

    if epochs is not None and epochs <= 0:
        raise HdNetError(f"--epochs must be > 0, got {epochs}")
    if resume and overwrite:
        raise HdNetError("--resume and --overwrite exclude each other")
    _check_range("seed", seed, 0)
    _check_range("num-workers", num_workers, 0, 256)
    _check_finite(train_sigma=train_sigma)
    checkpoint = fit(dataset, run_dir, profile_name=profile, epochs=epochs, train_sigma_m=train_sigma, seed=seed,
                     resume=resume, labels=labeling, progress=True, num_workers=num_workers, overwrite=overwrite)
    timing = load_checkpoint(checkpoint).get("timing", [])
    rate = median_images_per_s(timing)
    seconds = sum(float(t["train_seconds"]) for t in timing)
    speed = "" if rate is None else f"; {rate:.1f} images/s (median over {len(timing)} epochs, {seconds / 60:.1f} min of training steps)"
    click.echo(f"training done: {checkpoint} (metrics in {run_dir / 'metrics.csv'}){speed}")


@main.command("eval")
@click.argument("run_dir", type=_Path(file_okay=False, path_type=Path))
@click.option("--data", "dataset", required=True, type=_Path(file_okay=False, path_type=Path), help="Labelled dataset to evaluate on (its test split).")
@click.option("--out", "out_dir", required=True, type=_Path(file_okay=False, path_type=Path), help="Report directory (report.md, report.json, figures).")
@click.option("--mc-samples", type=int, default=8, show_default=True, help="MC-dropout samples M.")
@click.option("--drop-pixels", type=int, default=0, show_default=True, help="Dead-pixel test: pixels dropped from each DEM and refilled (paper: 10).")
@click.option("--threshold", default="mean", show_default=True, help="Uncertainty threshold: mean, quantile:Q or risk:ALPHA.")
@click.option("--labels", "labeling", default=None, help="Labelling to evaluate against (when the dataset has several).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of MC dropout and dropped pixels.")
@click.option("--batch-size", type=int, default=8, show_default=True, help="DEMs per inference batch.")
@click.option("--overwrite", is_flag=True, help="Replace an existing report, or write into a non-empty directory that is not a report.")
@friendly_errors
def eval_cmd(run_dir: Path, dataset: Path, out_dir: Path, mc_samples: int, drop_pixels: int, threshold: str,
             labeling: str | None, seed: int, batch_size: int = 8, overwrite: bool = False) -> None:
    """Evaluate a trained run: the paper's tables, threshold sweep, calibration and figures."""
    from hdnet.evaluate import evaluate

    _check_range("seed", seed, 0)
    result = evaluate(run_dir, dataset, out_dir, mc_samples=mc_samples, drop_pixels=drop_pixels,
                      threshold=threshold, labels=labeling, seed=seed, batch_size=batch_size, overwrite=overwrite)
    click.echo(result.summary())
    click.echo(f"report: {out_dir / 'report.md'} (and report.json, figures)")


@main.command("detect")
@click.argument("run_dir", type=_Path(path_type=Path))
@click.option("--dtm", "dtm_path", type=_Path(path_type=Path), default=None, help="Terrain to map: any GDAL raster in metres (GeoTIFF, HiRISE PDS3 .IMG), any size.")
@click.option("--data", "dataset", type=_Path(file_okay=False, path_type=Path), default=None, help="Instead of --dtm: a labelled dataset, with --scan.")
@click.option("--scan", type=int, default=None, help="With --data: the scan whose noisy DEM to map (scan frame).")
@click.option("--out", "out_dir", required=True, type=_Path(path_type=Path), help="Output directory (maps, sites, overview, detect.json).")
@click.option("--mc-samples", type=int, default=8, show_default=True, help="MC-dropout samples M.")
@click.option("--threshold", default="mean", show_default=True, help="Uncertainty threshold: mean, quantile:Q, risk:ALPHA (calibrated as hd eval does) or nats:H (fixed).")
@click.option("--sigma", "sigma_m", type=float, default=None, help="DEM noise of the ALHAT baseline, metres (default: the run's training sigma); with --data also the noise level of the scan's DEM.")
@click.option("--sites", "n_sites", type=int, default=10, show_default=True, help="Most landing sites to propose.")
@click.option("--overwrite", is_flag=True, help="Replace a non-empty --out.")
@click.option("--labels", "labeling", default=None, help="With --data: the labelling (when the dataset has several).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of MC dropout.")
@click.option("--batch-size", type=int, default=8, show_default=True, help="Tiles per inference batch.")
@friendly_errors
def detect_cmd(run_dir: Path, dtm_path: Path | None, dataset: Path | None, scan: int | None, out_dir: Path,
               mc_samples: int, threshold: str, sigma_m: float | None, n_sites: int, overwrite: bool,
               labeling: str | None, seed: int, batch_size: int) -> None:
    """Hazard maps and ranked landing sites of a DTM (or of one scan) from a trained run."""
    from hdnet.detect import detect

    progress = _ScanProgress("tiles", unit="tile")
    try:
        result = detect(run_dir, out_dir, dtm=dtm_path, dataset=dataset, scan=scan, mc_samples=mc_samples,
                        threshold=threshold, sigma_m=sigma_m, n_sites=n_sites, overwrite=overwrite, seed=seed,
                        batch_size=batch_size, labels=labeling, progress=progress)
    finally:
        progress.close()
    click.echo(result.summary())
    click.echo(f"maps, sites.csv, sites.geojson, overview.png and detect.json in {out_dir}")


@main.command("demo")
@click.option("--out", "out_dir", type=_Path(file_okay=False, path_type=Path), default=Path("demo-out"), show_default=True, help="Directory of the demo run.")
@click.option("--scans", type=int, default=200, show_default=True, help="Scans in the demo dataset.")
@click.option("--epochs", type=int, default=10, show_default=True, help="Training epochs (cpu profile).")
@click.option("--workers", type=int, default=None, help="Local worker processes (default: all cores).")
@click.pass_context
@friendly_errors
def demo_cmd(ctx: click.Context, out_dir: Path, scans: int, epochs: int, workers: int | None) -> None:
    """The whole chain at demo scale on the built-in procedural Mars terrain (re-running resumes)."""
    _check_chain(out_dir, scans, epochs, workers)
    stages = _Stages(out_dir)
    data, run, report = out_dir / "dataset", out_dir / "run", out_dir / "report"
    with stages("build", f"{scans} scans x {len(lidar_defaults.PAPER_SIGMAS_M)} noise levels on the procedural Mars terrain"):
        _build_unless_done(ctx, data, scans, None, workers)
    with stages("label", "DEMs, ALHAT labels and the baseline"):
        _label(ctx, data, workers)
    ctx.invoke(inspect_cmd, directory=data)
    with stages("train", f"Bayesian SegNet, cpu profile, {epochs} epochs at sigma = {lidar_defaults.DEFAULT_SIGMA_M} m"):
        ctx.invoke(train_cmd, dataset=data, run_dir=run, profile="cpu", epochs=epochs,
                   train_sigma=lidar_defaults.DEFAULT_SIGMA_M, seed=0, resume=True, labeling=None)
    with stages("eval", "MC dropout (M=8), paper metrics, 10 dropped pixels"):
        _eval_unless_done(ctx, run, data, report, "mean", 10)
    stages.finish()


@main.command("reproduce")
@click.option("--profile", type=click.Choice(["cpu", "paper"]), default="cpu", show_default=True, help="Training profile: cpu (this machine, <= 1 h) or paper (GPU).")
@click.option("--dtm", "dtm_path", type=_Path(path_type=Path), default=None, help="Use this DTM instead of the procedural Mars terrain.")
@click.option("--out", "out_dir", type=_Path(file_okay=False, path_type=Path), default=Path("reproduction"), show_default=True, help="Directory of the reproduction.")
@click.option("--epochs", type=int, default=None, help="Training epochs (default: the profile's).")
@click.option("--workers", type=int, default=None, help="Local worker processes (default: all cores).")
@click.pass_context
@friendly_errors
def reproduce_cmd(ctx: click.Context, profile: str, dtm_path: Path | None, out_dir: Path, epochs: int | None,
                  workers: int | None) -> None:
    """The paper end to end: S-167/S-300/S-700 on one terrain and trajectory (1000 scans, 800/100/100),
    labels, training at 1.67 cm, Table 1, Table 2 (10 dropped pixels), threshold sweep and panels,
    plus the risk-controlled threshold (alpha = 0.05). Each stage is resumable; finished stages are skipped."""
    _check_chain(out_dir, lidar_defaults.N_SCANS, epochs, workers)
    if dtm_path is not None:
        from lidarsim.terrain import DTM

        with DTM.open(dtm_path):
            pass
    stages = _Stages(out_dir)
    data, run = out_dir / "dataset", out_dir / "run"
    with stages("build", "1000 scans x (1.67, 3, 7) cm on one terrain and trajectory"):
        _build_unless_done(ctx, data, lidar_defaults.N_SCANS, dtm_path, workers)
    with stages("label", "DEMs, ALHAT labels and the baseline"):
        _label(ctx, data, workers)
    with stages("train", f"Bayesian SegNet, {profile} profile, trained at sigma = {lidar_defaults.DEFAULT_SIGMA_M} m"):
        ctx.invoke(train_cmd, dataset=data, run_dir=run, profile=profile, epochs=epochs,
                   train_sigma=lidar_defaults.DEFAULT_SIGMA_M, seed=0, resume=True, labeling=None)
    with stages("eval", "Table 1, Table 2 (10 dropped pixels), sweep, calibration, panels (mean-entropy threshold)"):
        _eval_unless_done(ctx, run, data, out_dir / "report", "mean", 10)
    with stages("eval-risk", "risk-controlled threshold, alpha = 0.05"):
        _eval_unless_done(ctx, run, data, out_dir / "report-risk", "risk:0.05", 0)
    stages.finish()


@main.command("card")
@click.argument("dataset", type=_Path(file_okay=False, path_type=Path))
@click.option("--recipe", required=True, type=_Path(path_type=Path), help="Recipe directory the dataset was built from; card.md and checksums.json are written there.")
@click.option("--machine", default="", help="Where the published build was made (recorded in the card).")
@friendly_errors
def card_cmd(dataset: Path, recipe: Path, machine: str) -> None:
    """Write the dataset card (card.md) and the published checksums (checksums.json) of a recipe."""
    from hdlabels.card import checksums_of, render_card
    from lidarsim.recipe import CHECKSUMS_FILE, load_recipe
    from lidarsim.shards import read_manifest, write_json_atomic
    from lidarsim.storage import write_text_atomic

    loaded = load_recipe(recipe)
    manifest = read_manifest(dataset)
    if manifest["config_sha256"] != loaded.build.fingerprint():
        raise LidarsimError(f"{dataset} was not built from {loaded.path} (settings differ); build it with --recipe")
    directory = loaded.path.parent
    sums = checksums_of(dataset)
    write_json_atomic(directory / CHECKSUMS_FILE, sums)
    write_text_atomic(directory / "card.md", render_card(dataset, loaded, machine))
    click.echo(f"wrote {directory / 'card.md'} and {directory / CHECKSUMS_FILE} ({len(sums['shards'])} shards)")


def _check_chain(out_dir: Path, scans: int, epochs: int | None, workers: int | None) -> None:
    """Every option of a multi-stage command, checked before its first stage runs."""
    from lidarsim import limits
    from lidarsim.build import assign_splits
    from lidarsim.storage import check_output_dir

    _check_range("scans", scans, 3, limits.MAX_SCANS)
    _check_range("epochs", epochs, 1)
    _check_range("workers", workers, 1, limits.MAX_WORKERS)
    if min(int((assign_splits(scans, seed=0) == code).sum()) for code in (0, 1, 2)) == 0:
        raise LidarsimError(f"--scans {scans} leaves a split empty; use more scans")
    check_output_dir(out_dir, "--out")


class _Stages:
    """Prints, times and records (OUT/stages.json) the stages of a multi-stage command."""

    def __init__(self, out_dir: Path) -> None:
        self.out_dir = out_dir
        self.times: dict[str, float] = {}

    def __call__(self, name: str, what: str) -> Any:
        import contextlib
        import time

        @contextlib.contextmanager
        def stage() -> Any:
            click.echo(f"== {name}: {what}")
            t0 = time.perf_counter()
            yield
            self.times[name] = round(time.perf_counter() - t0, 1)
            click.echo(f"== {name}: done in {self.times[name]:.1f} s")

        return stage()

    def finish(self) -> None:
        import json

        from lidarsim.storage import make_dirs, write_json_atomic

        make_dirs(self.out_dir)
        path = self.out_dir / "stages.json"
        try:
            previous = json.loads(path.read_text()) if path.exists() else {}
        except (OSError, ValueError):
            previous = {}
        if not isinstance(previous, dict) or not isinstance(previous.get("runs", []), list):
            previous = {}
        previous.setdefault("runs", []).append(self.times)
        write_json_atomic(path, previous)
        click.echo("stage times (s): " + ", ".join(f"{k} {v:.1f}" for k, v in self.times.items()))


def _build_unless_done(ctx: click.Context, data: Path, scans: int, dtm_path: Path | None, workers: int | None) -> None:
    from lidarsim.shards import MANIFEST_NAME

    if (data / MANIFEST_NAME).exists():
        click.echo(f"dataset {data} already built")
        return
    ctx.invoke(build_dataset_cmd, out_dir=data, dtm_path=dtm_path, sigmas=lidar_defaults.PAPER_SIGMAS_M, scans=scans,
               seed=0, workers=workers, altitude=lidar_defaults.ALTITUDE_M, dtm_scale=1.0, scheduler=None,
               overwrite=False, shard_size=50, tilt=0.0, jitter=0.0, resolution=lidar_defaults.DETECTOR_ROWS,
               fov=lidar_defaults.FOV_DEG, dead_elements=0, damaged_elements=0, compression="gzip")


def _label(ctx: click.Context, data: Path, workers: int | None) -> None:
    ctx.invoke(label_cmd, directory=data, lander_diameter=10.0, pad_diameter=1.0, max_slope_deg=10.0,
               max_roughness=0.20, layout="square", yaws=None, count_holes=False, dem_size=100, dem_spacing=1.0,
               workers=workers, scheduler=None)


def _eval_unless_done(ctx: click.Context, run: Path, data: Path, report: Path, threshold: str, drop: int) -> None:
    if (report / "report.json").exists():
        click.echo(f"report {report} already written")
        return
    ctx.invoke(eval_cmd, run_dir=run, dataset=data, out_dir=report, mc_samples=8, drop_pixels=drop,
               threshold=threshold, labeling=None, seed=0)


if __name__ == "__main__":
    main()
