"""hd demo and hd reproduce as pipelines: what they build, what they check first, and a whole run
at tiny size that a second run skips stage by stage."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hdnet_datasets import hills_dtm

from hdcli.pipeline import Evaluation, Pipeline, demo_pipeline, reproduce_pipeline, run_pipeline
from hdcore.errors import HdError
from hdlabels.settings import LabelSettings
from hdlabels.store import labeling_name
from hdnet.checkpoint_json import EpochRow
from lidarsim import defaults
from lidarsim.build import BuildConfig
from lidarsim.recipe import BuildSettings, load_recipe
from lidarsim.trajectory import TrajectoryConfig

REPO = Path(__file__).resolve().parents[2]
PAPER_RECIPE = REPO / "datasets" / "mars-paper"


class _NoBar:
    def __call__(self, done: int, total: int) -> None:
        assert 0 <= done <= total

    def close(self) -> None:
        pass


def test_reproduce_runs_the_paper_recipe(tmp_path):
    pipe = reproduce_pipeline(tmp_path / "r", PAPER_RECIPE, "cpu", None)
    recipe = load_recipe(PAPER_RECIPE)
    assert pipe.build == recipe.build
    # the paper's dataset: three noise levels, 1000 scans, the defaults otherwise
    paper = BuildConfig(sigmas_m=defaults.PAPER_SIGMAS_M, trajectory=TrajectoryConfig(n_scans=defaults.N_SCANS))
    assert pipe.build.fingerprint() == paper.fingerprint()
    assert pipe.label == LabelSettings.from_recipe(recipe.label)
    # the recipe's labels are hd label's defaults: the paper convention with its gridding
    lander, dem = pipe.label.to_lander(), pipe.label.to_dem_spec()
    assert labeling_name(lander, dem) == labeling_name(LabelSettings().to_lander(), LabelSettings().to_dem_spec())
    assert [(e.directory, e.threshold, e.drop_pixels) for e in pipe.evaluations] == [
        ("report", "mean", 10),
        ("report-risk", "risk:0.05", 0),
    ]
    other = reproduce_pipeline(tmp_path / "r", PAPER_RECIPE, "paper", 5, dtm_path=Path("site.tif"))
    assert other.build.dtm_path == str(Path("site.tif").resolve()) and other.profile == "paper" and other.epochs == 5
    assert other.build.sigmas_m == recipe.build.sigmas_m and other.build.seed == recipe.build.seed


def test_reproduce_with_the_robust_profile_trains_across_noise_and_sweeps(tmp_path):
    from hdnet.profiles import ROBUST, ROBUST_THRESHOLD_SPEC

    pipe = reproduce_pipeline(tmp_path / "r", PAPER_RECIPE, "robust", None)
    assert pipe.profile == "robust" and pipe.train_sigma_m is None  # the profile's range, 0 to 10 cm
    assert ROBUST.train_sigma_range_m == (0.0, 0.10) and "sigma" in ROBUST.extra_channels
    sweep = tuple(round(0.01 * k, 12) for k in range(16))  # 0 to 15 cm: 1.5 times the range's top
    assert [(e.directory, e.threshold, e.calibrate, e.sigma_sweep) for e in pipe.evaluations] == [
        ("report", ROBUST_THRESHOLD_SPEC, "each", sweep),
        ("report-risk", "risk:0.05", "each", sweep),
    ]
    assert "0 to 10 cm" in pipe.train_what


def test_demo_is_the_paper_dataset_at_demo_scale(tmp_path):
    pipe = demo_pipeline(tmp_path / "d", scans=200, epochs=3)
    assert pipe.build.trajectory.n_scans == 200 and pipe.build.sigmas_m == defaults.PAPER_SIGMAS_M
    assert pipe.build.dtm_path is None and pipe.profile == "cpu" and pipe.epochs == 3 and pipe.inspect
    assert [(e.threshold, e.drop_pixels) for e in pipe.evaluations] == [("mean", 10)]


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        ({"scans": 2}, "leaves a split empty"),
        ({"dtm": "missing.tif"}, "missing.tif"),
        ({"lander_diameter_m": 150.0}, "larger than the DEM"),
    ],
)
def test_every_stage_is_checked_before_anything_is_written(tmp_path, change, needle):
    build = BuildSettings(
        scans=change.get("scans", 20),
        resolution=16,
        dtm_path=str(tmp_path / change["dtm"]) if "dtm" in change else None,
    ).to_config()
    label = LabelSettings(lander_diameter_m=change.get("lander_diameter_m", defaults.ALTITUDE_M / 50))
    pipe = Pipeline(tmp_path / "out", build, label, "tiny", 1, ())
    with pytest.raises(HdError, match=needle):
        run_pipeline(pipe, 1, echo=print, progress=lambda desc, unit: _NoBar())
    assert not (tmp_path / "out").exists()


def test_a_tiny_pipeline_runs_every_stage_then_skips_them(tmp_path):
    dtm = hills_dtm(tmp_path / "hills.tif")
    build = BuildSettings(sigmas_m=(0.0167, 0.07), scans=20, resolution=48, shard_size=10, dtm_path=str(dtm))
    pipe = Pipeline(
        out_dir=tmp_path / "out",
        build=build.to_config(),
        label=LabelSettings(),
        profile="tiny",
        epochs=1,
        evaluations=(Evaluation("eval", "report", "mean", 3, "tiny evaluation"),),
        inspect=True,
        mc_samples=2,
        train_what="tiny training",
    )
    lines: list[str] = []
    times = run_pipeline(pipe, 1, echo=lines.append, progress=lambda desc, unit: _NoBar())
    assert list(times) == ["build", "label", "train", "eval"]
    text = "\n".join(lines)
    for line in (
        "== build: 20 scans x (1.67, 7) cm on hills.tif",
        "== label: DEMs",
        "status    intact",
        "== train: tiny training",
        "training done:",
        "images/s (median over 1 epochs",
        "== eval: tiny evaluation",
        "report: ",
    ):
        assert line in text, line
    report = json.loads((tmp_path / "out" / "report" / "report.json").read_text())
    assert {r["table"] for r in report["rows"]} == {"noise", "dead_pixels"}
    again: list[str] = []
    run_pipeline(pipe, 1, echo=again.append, progress=lambda desc, unit: _NoBar())
    text = "\n".join(again)
    assert f"dataset {pipe.dataset_dir} already built" in text and "already labelled" in text
    assert f"report {tmp_path / 'out' / 'report'} already written" in text
    runs = json.loads((tmp_path / "out" / "stages.json").read_text())["runs"]
    assert len(runs) == 2 and set(runs[1]) == {"build", "label", "train", "eval"}


def _tiny_pipeline(tmp_path: Path, epochs: int) -> Pipeline:
    dtm = hills_dtm(tmp_path / "hills.tif")
    build = BuildSettings(sigmas_m=(0.0167,), scans=20, resolution=48, shard_size=10, dtm_path=str(dtm))
    return Pipeline(tmp_path / "out", build.to_config(), LabelSettings(), "tiny", epochs, (), train_what="tiny")


def test_demo_training_prints_hd_trains_epoch_lines_and_says_where_it_resumes(tmp_path, monkeypatch):
    from click.testing import CliRunner

    import hdcli.pipeline
    from hdcli.cli import main

    pipe = _tiny_pipeline(tmp_path, epochs=2)

    def ctrl_c_after_the_first_epoch(row: EpochRow, total: int) -> None:
        raise KeyboardInterrupt  # the checkpoint of epoch 1 is written before the epoch is reported

    with pytest.raises(KeyboardInterrupt):
        run_pipeline(pipe, 1, echo=print, progress=lambda d, u: _NoBar(), train_progress=ctrl_c_after_the_first_epoch)
    assert (pipe.run_dir / "last.pt").is_file()
    monkeypatch.setattr(hdcli.pipeline, "demo_pipeline", lambda out_dir, scans, epochs: pipe)
    result = CliRunner().invoke(main, ["demo", "--out", str(pipe.out_dir), "--workers", "1"])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    resumed = [k for k, line in enumerate(lines) if line.startswith("train: resuming at epoch 2 of 2")]
    epoch = [k for k, line in enumerate(lines) if line.startswith("train: epoch 2/2, train loss ")]
    assert len(resumed) == 1 and len(epoch) == 1 and resumed[0] < epoch[0], result.output
    assert not any(line.startswith("train: epoch 1/2") for line in lines)  # done before the interruption
