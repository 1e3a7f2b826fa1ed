"""Training across noise levels and the noise sweep: noisy DEMs made on the fly, drawn per sample, scored per level."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from hdnet_datasets import SIGMAS_M, build_labelled
from torch.utils.data import DataLoader

from hdcli.cli import main
from hdnet.data import HazardDataset
from hdnet.errors import HdNetError
from hdnet.evaluate import EvalConfig, evaluate
from hdnet.fit import FitConfig, fit
from hdnet.inputs import InputSpec, network_input
from hdnet.noise_levels import TrainingNoise, parse_sigma_range, parse_sigma_sweep
from hdnet.profiles import TINY


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return build_labelled(tmp_path_factory.mktemp("noise-training"))


SPEC = InputSpec(heights="median", extra_channels=("slope", "sigma"))


# --- parsing -------------------------------------------------------------------------------------
def test_levels_ranges_and_sweeps_parse_and_refuse_nonsense():
    assert parse_sigma_range("0:0.10") == (0.0, 0.1)
    assert parse_sigma_sweep("0:0.12:0.01") == tuple(round(0.01 * k, 12) for k in range(13))
    assert parse_sigma_sweep("0.0167:0.0167:0.01") == (0.0167,)
    for bad, needle in [
        ("0.1:0", "LOW < HIGH"),
        ("0:", "LOW:HIGH"),
        ("-1:0.1", r"in \[0, 0\.7\]"),
        ("0:nan", "finite"),
    ]:
        with pytest.raises(HdNetError, match=needle):
            parse_sigma_range(bad)
    for bad, needle in [
        ("0:0.1", "START:STOP:STEP"),
        ("0:0.1:0", "STEP"),
        ("0.1:0:0.01", "below"),
        ("0:0.5:1e-4", "at most"),
        ("0:1e-12:1e-13", "finer than noise levels"),
    ]:
        with pytest.raises(HdNetError, match=needle):
            parse_sigma_sweep(bad)
    noise = TrainingNoise(range_m=(0.0, 0.1))
    assert noise.validation_levels() == (0.0, 0.05, 0.1) and noise.contains(0.07) and not noise.contains(0.11)
    assert TrainingNoise.from_dict(noise.to_dict()) == noise
    levels = TrainingNoise(levels_m=(0.0167, 0.07))
    rng = np.random.default_rng(0)
    assert {levels.draw(rng) for _ in range(50)} == {0.0167, 0.07}
    assert all(0.0 <= noise.draw(rng) <= 0.1 for _ in range(50))
    with pytest.raises(HdNetError, match="distinct"):
        TrainingNoise(levels_m=(0.01, 0.01))


# --- datasets ------------------------------------------------------------------------------------
def test_a_stored_level_made_on_the_fly_equals_the_stored_dem_bit_for_bit(dataset):
    for sigma in SIGMAS_M:
        ds = HazardDataset(dataset, "train", sigma, input_spec=SPEC)
        assert not ds.made_on_the_fly
        for i in range(len(ds)):
            stored, made = ds.dem_sample(i), ds.dem_sample(i, sigma)
            assert np.array_equal(stored.dem_noisy_m, made.dem_noisy_m, equal_nan=True)
            assert np.array_equal(stored.label, made.label) and made.p_safe is None
            assert stored.p_safe is not None  # stored at a stored level; the same rule on the same DEM:
            assert np.array_equal(ds.baseline_p_safe(made), stored.p_safe, equal_nan=True)


def test_a_level_the_dataset_does_not_store_is_made_from_the_clean_points(dataset):
    ds = HazardDataset(dataset, "val", 0.04, input_spec=SPEC)
    assert ds.made_on_the_fly and ds.sigma_m == 0.04
    s = ds.dem_sample(0)
    clean = s.dem_clean_m
    assert s.sigma_m == 0.04 and s.p_safe is None
    noise = (s.dem_noisy_m - clean)[np.isfinite(s.dem_noisy_m - clean)]
    assert 0.015 < noise.std() < 0.06
    x = ds[0]
    assert x["sigma_m"] == 0.04 and np.allclose(x["image"][2].numpy(), 0.04 / 0.05)  # the sigma channel
    with pytest.raises(HdNetError, match=r"in \[0, 0\.7\]"):
        HazardDataset(dataset, "val", 0.9, input_spec=SPEC)


def _batches(ds: HazardDataset, workers: int, epoch: int) -> list[dict]:
    ds.set_epoch(epoch)
    loader = DataLoader(ds, batch_size=4, num_workers=workers, shuffle=False)
    return list(loader)


def test_drawn_samples_are_the_same_with_0_and_2_workers_and_change_with_the_epoch(dataset):
    ds = HazardDataset(dataset, "train", None, input_spec=SPEC, augment="d4", noise=TrainingNoise(range_m=(0.0, 0.1)))
    a, b = _batches(ds, 0, epoch=3), _batches(ds, 2, epoch=3)
    assert len(a) == len(b) == 4
    for x, y in zip(a, b, strict=True):
        assert torch.equal(x["image"], y["image"]) and torch.equal(x["mask"], y["mask"])
        assert torch.equal(x["sigma_m"], y["sigma_m"])
    sigmas = torch.cat([x["sigma_m"] for x in a])
    assert len(set(sigmas.tolist())) == len(sigmas) and ((sigmas >= 0) & (sigmas <= 0.1)).all()
    c = _batches(ds, 0, epoch=4)
    assert not torch.equal(a[0]["image"], c[0]["image"])
    # The noise of a drawn sample is a fresh realisation, not the stored draw at that level.
    levels = HazardDataset(dataset, "train", None, input_spec=SPEC, noise=TrainingNoise(levels_m=SIGMAS_M), seed=0)
    levels.set_epoch(0)
    sample = levels[0]
    k = SIGMAS_M.index(sample["sigma_m"])
    stored = HazardDataset(dataset, "train", SIGMAS_M[k], input_spec=SPEC)[0]
    assert not torch.equal(sample["image"][0], stored["image"][0])


def test_the_sigma_channel_needs_the_dem_noise_level():
    with pytest.raises(HdNetError, match="noise level as an input"):
        network_input(np.zeros((8, 8)), SPEC)
    x = network_input(np.zeros((8, 8)), SPEC, 0.07)
    assert x.shape[0] == 3 and torch.allclose(x[2], torch.full_like(x[2], 1.4))


# --- training and the sweep ----------------------------------------------------------------------
@pytest.fixture(scope="module")
def range_run(dataset, tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("range-run") / "run"
    profile = replace(TINY, heights="median", extra_channels=("sigma",))
    fit(
        dataset,
        run,
        FitConfig(profile=profile, epochs=1, train_noise=TrainingNoise(range_m=(0.0, 0.08)), progress=False),
    )
    return run


def test_a_range_run_records_its_training_noise(range_run):
    extra = json.loads((range_run / "config.json").read_text())["extra_config"]
    assert extra["train_noise"] == {"kind": "range", "levels_m": [], "range_m": [0.0, 0.08]}
    assert extra["train_sigma_m"] == 0.0167  # the reference level: the paper's, inside the range
    assert extra["input"]["extra_channels"] == ["sigma"]


def test_the_sweep_scores_every_level_and_the_report_shows_it(dataset, range_run, tmp_path):
    from hdnet.report import write_report

    cfg = EvalConfig(mc_samples=2, sigma_sweep=(0.0, 0.04, 0.07, 0.12), threshold="mean")
    result = evaluate(range_run, dataset, cfg)
    sweep = [r for r in result.rows if r.table == "sigma_sweep"]
    assert sorted({r.test_sigma_m for r in sweep}) == [0.0, 0.04, 0.07, 0.12]
    assert {r.method for r in sweep} == {"alhat_baseline", "base_net", "uncertainty_aware"}
    # At a stored level the sweep's rows are Table 1's rows.
    table = {(r.method, r.test_sigma_m): r for r in result.rows if r.table == "noise"}
    for r in sweep:
        if r.test_sigma_m == 0.07:
            t = table[(r.method, 0.07)]
            got, want = (r.pixel_accuracy, r.precision, r.sensitivity), (t.pixel_accuracy, t.precision, t.sensitivity)
            assert np.array_equal(got, want, equal_nan=True)
    # The baseline at sigma 0 on the clean points: the clean DEM's labels up to the product rule's margin.
    base0 = next(r for r in sweep if r.method == "alhat_baseline" and r.test_sigma_m == 0.0)
    assert base0.precision > 0.9
    assert result.run["train_noise"]["range_m"] == [0.0, 0.08] and result.run["sigma_sweep_m"] == [
        0.0,
        0.04,
        0.07,
        0.12,
    ]
    paths = write_report(result, tmp_path / "report")
    md = (tmp_path / "report" / "report.md").read_text()
    assert "## Noise sweep" in md and "| 12.00 cm | above |" in md and "| 4.00 cm | in range |" in md
    assert tmp_path / "report" / "noise_sweep.png" in paths
    each = evaluate(range_run, dataset, replace(cfg, calibrate="each", sigma_sweep=(0.04, 0.12)))
    per = {round(p["calibration_sigma_m"], 6): p for p in each.threshold["per_sigma"]}
    assert set(per) == {0.0167, 0.07, 0.04, 0.12}
    assert [s for s, p in per.items() if p["guarded"]] == [0.12]  # above the 0-8 cm training range only
    assert each.threshold["calibrate"] == "each"


def test_detect_gives_the_sensor_sigma_to_the_network_and_calibrates_there(dataset, range_run, tmp_path):
    from hdnet.detect import detect
    from hdnet.detect_settings import DetectSettings

    info = {}
    for sigma in SIGMAS_M:
        out = tmp_path / f"d{sigma}"
        detect(range_run, out, DetectSettings(scan=0, sigma_m=sigma, mc_samples=2, calibrate="each"), dataset=dataset)
        info[sigma] = json.loads((out / "detect.json").read_text())
    for sigma in SIGMAS_M:
        assert info[sigma]["sensor_sigma_m"] == sigma and info[sigma]["threshold"]["calibration_sigma_m"] == sigma
        assert info[sigma]["run"]["train_noise"]["range_m"] == [0.0, 0.08]
    assert info[SIGMAS_M[0]]["threshold"]["value_nats"] != info[SIGMAS_M[1]]["threshold"]["value_nats"]


def test_cli_train_and_eval_take_the_noise_options(dataset, tmp_path):
    runner = CliRunner()
    out = tmp_path / "run"
    result = runner.invoke(
        main, ["train", str(dataset), "--out", str(out), "--profile", "tiny", "--epochs", "1",
               "--train-sigma", "0.0167", "--train-sigma", "0.05"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    extra = json.loads((out / "config.json").read_text())["extra_config"]
    assert extra["train_noise"]["levels_m"] == [0.0167, 0.05]
    bad = runner.invoke(main, ["train", str(dataset), "--out", str(tmp_path / "x"), "--train-sigma-range", "0.2:0.1"])
    assert bad.exit_code == 1 and "LOW < HIGH" in bad.output
    both = runner.invoke(
        main,
        ["train", str(dataset), "--out", str(tmp_path / "y"), "--train-sigma", "0.01", "--train-sigma-range", "0:1"],
    )
    assert both.exit_code == 1 and "exclude each other" in both.output
    rep = tmp_path / "rep"
    result = runner.invoke(
        main, ["eval", str(out), "--data", str(dataset), "--out", str(rep), "--mc-samples", "1",
               "--sigma-sweep", "0.02:0.04:0.02", "--calibrate", "each"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    report = json.loads((rep / "report.json").read_text())
    assert sorted({r["test_sigma_m"] for r in report["rows"] if r["table"] == "sigma_sweep"}) == [0.02, 0.04]
    bad = runner.invoke(main, ["eval", str(out), "--data", str(dataset), "--out", str(rep), "--sigma-sweep", "0:1"])
    assert bad.exit_code == 1 and "START:STOP:STEP" in bad.output
