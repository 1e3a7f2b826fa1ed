"""Training on a mix of terrains (``hd train --also``) and calibrating on another dataset (``--calibrate-on``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from hdnet_datasets import build_labelled

from hdcli.cli import main
from hdlabels.errors import LabelStoreError
from hdnet.data import HazardDataset, MixedDataset
from hdnet.evaluate import EvalConfig, evaluate
from hdnet.fit import MIX_SEED_STRIDE, FitConfig, fit
from hdnet.inputs import InputSpec
from hdnet.noise_levels import TrainingNoise
from hdnet.profiles import TINY


@pytest.fixture(scope="module")
def two(tmp_path_factory) -> tuple[Path, Path]:
    """Two tiny labelled datasets of different scan counts (20 and 30 scans), same labelling."""
    return build_labelled(tmp_path_factory.mktemp("terrain-a")), build_labelled(
        tmp_path_factory.mktemp("terrain-b"), n_scans=30
    )


@pytest.fixture(scope="module")
def mixed_run(two, tmp_path_factory) -> Path:
    a, b = two
    run = tmp_path_factory.mktemp("mix") / "run"
    fit(a, run, FitConfig(profile=TINY, epochs=1, progress=False, also=(str(b),)))
    return run


def test_the_mix_holds_every_dataset_and_its_run_names_them(two, mixed_run):
    a, b = two
    spec = InputSpec(heights="median")
    one = [HazardDataset(d, "train", 0.0167, input_spec=spec) for d in (a, b)]
    mix = MixedDataset(one)
    assert len(mix) == len(one[0]) + len(one[1])
    # Sample k of the second part is sample k - len(first) of the mix, bit for bit.
    k = len(one[0])
    assert torch.equal(mix[k]["image"], one[1][0]["image"])
    extra = json.loads((mixed_run / "config.json").read_text())["extra_config"]
    assert extra["dataset"] == str(a.resolve())
    assert [e["dataset"] for e in extra["also"]] == [str(b.resolve())]
    assert len(extra["also"][0]["manifest_sha256"]) == 64


def test_drawn_noise_differs_between_the_parts_of_a_mix(two):
    a, _ = two
    spec = InputSpec(heights="median", extra_channels=("sigma",))
    noise = TrainingNoise(range_m=(0.0, 0.1))
    first = HazardDataset(a, "train", None, input_spec=spec, noise=noise, seed=0)
    second = HazardDataset(a, "train", None, input_spec=spec, noise=noise, seed=MIX_SEED_STRIDE)
    mix = MixedDataset([first, second])
    mix.set_epoch(3)
    assert first.epoch == 3 and second.epoch == 3
    # The same scans, keyed on another seed: other noise levels.
    sig = [float(first[i]["sigma_m"]) for i in range(4)], [float(second[i]["sigma_m"]) for i in range(4)]
    assert sig[0] != sig[1]


def test_a_dataset_without_the_labelling_is_refused_before_training(two, tmp_path):
    a, _ = two
    unlabelled = build_labelled(tmp_path / "bare", n_scans=20, label=False)
    with pytest.raises(LabelStoreError, match="has no labels"):  # the label store's own error, kept
        fit(a, tmp_path / "run", FitConfig(profile=TINY, epochs=1, progress=False, also=(str(unlabelled),)))
    assert not (tmp_path / "run").exists()


def test_calibrating_on_other_datasets_uses_their_validation_splits(two, mixed_run):
    a, b = two
    own = evaluate(mixed_run, b, EvalConfig(mc_samples=2, threshold="quantile:0.5", calibrate_on=(str(b),)))
    other = evaluate(mixed_run, b, EvalConfig(mc_samples=2, threshold="quantile:0.5", calibrate_on=(str(a),)))
    assert own.threshold["calibration_datasets"] == [str(b.resolve())]
    assert other.threshold["calibration_datasets"] == [str(a.resolve())]
    assert own.threshold["calibration_source"] == other.threshold["calibration_source"] == "calibrate-on"
    # b has 30 scans, a 20: validation splits of 3 and 2 images (block splits 80/10/10).
    assert own.threshold["calibration_images"] > other.threshold["calibration_images"] > 0
    # The test split scored is b's in all three: the baseline rows do not depend on the threshold.
    for r1, r2 in zip(own.rows, other.rows, strict=True):
        if r1.method == "alhat_baseline":
            assert np.array_equal((r1.pixel_accuracy, r1.precision), (r2.pixel_accuracy, r2.precision), equal_nan=True)
    assert own.threshold["value_nats"] != other.threshold["value_nats"]


def test_cli_train_also_and_eval_calibrate_on(two, mixed_run, tmp_path):
    a, b = two
    runner = CliRunner()
    args = ["train", str(a), "--out", str(tmp_path / "run"), "--profile", "tiny", "--epochs", "1", "--also", str(b)]
    result = runner.invoke(main, args)
    assert result.exit_code == 0, result.output
    assert json.loads((tmp_path / "run" / "config.json").read_text())["extra_config"]["also"]
    report = tmp_path / "r"
    result = runner.invoke(
        main,
        ["eval", str(mixed_run), "--data", str(b), "--out", str(report), "--mc-samples", "2", "--calibrate-on", str(a)],
    )
    assert result.exit_code == 0, result.output
    threshold = json.loads((report / "report.json").read_text())["threshold"]
    assert threshold["calibration_datasets"] == [str(a.resolve())]
    # A report never goes into a calibration dataset.
    bad = runner.invoke(
        main, ["eval", str(mixed_run), "--data", str(b), "--out", str(a / "r"), "--calibrate-on", str(a)]
    )
    assert bad.exit_code != 0 and "calibration dataset" in bad.output and not (a / "r").exists()


def test_eval_takes_a_fixed_threshold_in_nats(two, mixed_run):
    a, _ = two
    fixed = evaluate(mixed_run, a, EvalConfig(mc_samples=2, threshold="nats:0.3", calibrate="each"))
    assert fixed.threshold["value_nats"] == 0.3 and fixed.threshold["kind"] == "nats"
    assert all(p["value_nats"] == 0.3 for p in fixed.threshold["per_sigma"])  # never moved by a guard


def test_eval_reports_its_progress_in_images_against_an_exact_plan(two, mixed_run):
    a, _ = two
    calls: list[tuple[int, int]] = []
    cfg = EvalConfig(mc_samples=1, drop_pixels=2, sigma_sweep=(0.05,), calibrate="each", threshold="quantile:0.5")
    evaluate(mixed_run, a, cfg, progress=lambda done, total: calls.append((done, total)))
    totals = {t for _, t in calls}
    assert len(totals) == 1, "the plan was exact: the total never moved"
    done = [d for d, _ in calls]
    assert done[0] == 0 and done == sorted(done) and done[-1] == calls[-1][1]
    # The run's own validation splits (a: 2 images, b: 3) at each of 3 calibration levels (1.67, 7,
    # 5 cm), 2 test images in 2 + 2 + 1 passes.
    assert calls[-1][1] == (2 + 3) * 3 + 2 * 5


def test_eval_calibrates_on_the_runs_own_training_data_by_default(two, mixed_run, tmp_path):
    from hdnet.report import write_report

    a, b = two
    default = evaluate(mixed_run, b, EvalConfig(mc_samples=2, threshold="quantile:0.5"))
    named = evaluate(mixed_run, b, EvalConfig(mc_samples=2, threshold="quantile:0.5", calibrate_on=(str(a), str(b))))
    assert default.threshold["calibration_source"] == "run"
    assert default.threshold["calibration_datasets"] == [str(a.resolve()), str(b.resolve())]
    assert default.threshold["calibration_images"] == 2 + 3
    assert default.threshold["value_nats"] == named.threshold["value_nats"]
    write_report(default, tmp_path / "r", figures=False)
    assert "of the run's training data" in (tmp_path / "r" / "report.md").read_text()


def test_eval_falls_back_to_the_evaluated_dataset_when_the_runs_data_is_gone(two, tmp_path):
    import shutil

    from hdnet.report import write_report

    a, b = two
    moved = tmp_path / "train-copy"
    shutil.copytree(a, moved)
    run = tmp_path / "run"
    fit(moved, run, FitConfig(profile=TINY, epochs=1, progress=False))
    shutil.rmtree(moved)
    result = evaluate(run, b, EvalConfig(mc_samples=1, threshold="quantile:0.5"))
    assert result.threshold["calibration_source"] == "evaluated"
    assert result.threshold["calibration_datasets"] == [str(b.resolve())]
    assert "is not present" in result.threshold["calibration_note"]
    write_report(result, tmp_path / "r", figures=False)
    assert "of the evaluated dataset (the run's training data" in (tmp_path / "r" / "report.md").read_text()


def test_a_report_on_another_dataset_sets_no_paper_numbers_beside_it(two, mixed_run, tmp_path):
    from hdnet.report import write_report

    a, b = two
    result = evaluate(mixed_run, b, EvalConfig(mc_samples=1, calibrate_on=(str(a),)))
    assert result.run["paper_dataset"] is False
    write_report(result, tmp_path / "r", figures=False)
    md = (tmp_path / "r" / "report.md").read_text()
    assert "The paper's values" not in md and "few test scans" in md and f"`{a.resolve()}`" in md


def test_detect_calibrates_on_the_runs_own_training_data_as_eval_does(two, mixed_run, tmp_path):
    from hdnet.detect import detect
    from hdnet.detect_settings import DetectSettings
    from tests.geotiff import write_geotiff

    a, b = two
    cfg = EvalConfig(mc_samples=2, threshold="quantile:0.5", batch_size=4)
    reference = evaluate(mixed_run, b, cfg).threshold
    x = np.arange(60, dtype=np.float32)
    dtm = write_geotiff(tmp_path / "plane.tif", np.tile(x * 0.05, (60, 1)), 1.0)
    own = [str(a.resolve()), str(b.resolve())]
    for out, where, scan in (("dtm", {"dtm": dtm}, None), ("scan", {"dataset": b}, 0)):
        settings = DetectSettings(scan=scan, mc_samples=2, threshold="quantile:0.5", batch_size=4)
        detect(mixed_run, tmp_path / out, settings, **where)
        info = json.loads((tmp_path / out / "detect.json").read_text())["threshold"]
        assert info["calibration_datasets"] == own, out
        assert info["value_nats"] == reference["value_nats"], out
