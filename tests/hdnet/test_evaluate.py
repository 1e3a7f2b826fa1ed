"""hdnet.evaluate end to end on a tiny run: report files, hand-checked baseline, dead pixels, risk, errors."""

from __future__ import annotations

import importlib
import json
import math
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any, cast

import h5py
import numpy as np
import pytest
import torch
from hdnet_datasets import SIGMAS_M, build_labelled

from hdcore.errors import HdWarning, OutputExistsError
from hdlabels.errors import LabelStoreError
from hdlabels.store import find_labeling
from hdnet.checkpoint_json import CheckpointJson, EpochRow
from hdnet.data import HazardDataset
from hdnet.errors import HdNetError
from hdnet.evaluate import METHODS, EvalConfig, evaluate, evaluate_to_report, reliability
from hdnet.fit import FitConfig, fit
from hdnet.report import ROW_KEYS, report_dict
from hdnet.run_record import checkpoint_data
from hdnet.scored_split import ScoredSplit
from lidarsim.shards import iter_scans


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    root = tmp_path_factory.mktemp("hdnet-eval")
    dataset = build_labelled(root / "data")
    run = root / "run"
    fit(dataset, run, FitConfig(profile="tiny", epochs=1, progress=False))
    out = root / "report"
    result = evaluate_to_report(run, dataset, out, EvalConfig(mc_samples=4, drop_pixels=10, seed=0))
    return dataset, run, out, result


def hand_metrics(truth: np.ndarray, safe_pred: np.ndarray, valid: np.ndarray) -> tuple[float, float, float, float]:
    """PA, mIoU, precision and sensitivity of "safe", counted by hand over valid pixels."""
    t, p = truth[valid] == 1, safe_pred[valid]
    ts, fs, fu, tu = (t & p).sum(), (~t & p).sum(), (t & ~p).sum(), (~t & ~p).sum()
    iou_safe, iou_unsafe = ts / (ts + fs + fu), tu / (tu + fu + fs)
    return (ts + tu) / t.size, (iou_safe + iou_unsafe) / 2, ts / (ts + fs), ts / (ts + fu)


def test_report_files_have_every_row_and_exact_keys(setup):
    _, _, out, _ = setup
    report = json.loads((out / "report.json").read_text())
    assert {"rows", "threshold", "sweep", "calibration"} <= set(report)
    rows = report["rows"]
    assert all(list(r) == list(ROW_KEYS) for r in rows)
    keys = {(r["table"], r["method"], r["test_sigma_m"]) for r in rows}
    assert keys == {(t, m, s) for t in ("noise", "dead_pixels") for m in METHODS for s in SIGMAS_M}
    assert len(rows) == 2 * 3 * len(SIGMAS_M)
    for r in rows:
        assert (r["vc_fraction"] is None) == (r["method"] != "uncertainty_aware")
        assert r["train_sigma_m"] == (None if r["method"] == "alhat_baseline" else 0.0167)
    th = report["threshold"]
    assert th["spec"] == "mean" and th["calibration_split"] == "val" and th["calibration_sigma_m"] == 0.0167
    assert 0 < th["value_nats"] <= math.log(2) and th["value_nats"] == th["mean_nats"]
    assert len(report["sweep"]) == 9 * len(SIGMAS_M)
    assert [c["test_sigma_m"] for c in report["calibration"]["per_sigma"]] == list(SIGMAS_M)
    md = (out / "report.md").read_text()
    assert "## Table 1: noise levels" in md and "## Table 2: dead pixels" in md
    assert "0.9345" not in md and report["run"]["paper_dataset"] is False  # the paper's values: its dataset only
    for name in ("reliability.png", "threshold_sweep.png", "qualitative_1.67cm.png", "qualitative_7.00cm.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG", name


def test_baseline_rows_equal_a_hand_count_from_the_label_shards(setup):
    dataset, _, _, result = setup
    for s, sigma in enumerate(SIGMAS_M):
        truth, pred = [], []
        for path in find_labeling(dataset).shard_paths(dataset):
            with h5py.File(path) as f:
                rows = f["split"][:] == 2
                truth.append(f["label"][:][rows])
                pred.append(np.nan_to_num(f["p_safe"][:, s][rows]) >= 0.5)
        t, p = np.concatenate(truth), np.concatenate(pred)
        expected = hand_metrics(t, p, t != 255)
        row = next(
            r for r in result.rows if r.table == "noise" and r.method == "alhat_baseline" and r.test_sigma_m == sigma
        )
        np.testing.assert_allclose((row.pixel_accuracy, row.miou, row.precision, row.sensitivity), expected, rtol=1e-12)


def test_network_rows_follow_from_the_stored_inference(setup):
    _, _, _, result = setup
    h_t = result.threshold["value_nats"]
    for sigma, inf in result.test.items():
        valid = inf.label != 255
        base = next(r for r in result.rows if r.table == "noise" and r.method == "base_net" and r.test_sigma_m == sigma)
        np.testing.assert_allclose(
            (base.pixel_accuracy, base.miou, base.precision, base.sensitivity),
            hand_metrics(inf.label, inf.prediction == 1, valid),
            rtol=1e-12,
        )
        ua = next(
            r for r in result.rows if r.table == "noise" and r.method == "uncertainty_aware" and r.test_sigma_m == sigma
        )
        certain = inf.entropy_nats < h_t
        assert ua.vc_fraction == pytest.approx((valid & certain).sum() / valid.sum())
        # sensitivity: uncertain truly safe pixels count as false unsafe
        t = inf.label == 1
        ts = (valid & certain & t & (inf.prediction == 1)).sum()
        assert ua.sensitivity == pytest.approx(ts / (valid & t).sum())
        # the sweep keeps more pixels at higher quantiles
        vc = [p["vc_fraction"] for p in result.sweep if p["test_sigma_m"] == sigma]
        assert vc == sorted(vc) and len(vc) == 9


def test_dead_pixel_rows_ignore_the_lander_neighbourhoods(setup):
    dataset, _, _, result = setup
    ds = HazardDataset(dataset, "test", 0.0167, dead_pixels=10, seed=0)
    inf = result.test[0.0167]
    ignore = np.stack([ds.dem_sample(i).ignore for i in range(len(ds))])
    valid = inf.label != 255
    assert (valid & ~ignore).sum() < valid.sum()
    # Outside the ignored neighbourhoods the repaired DEM gives the same baseline as the shard's.
    expected = hand_metrics(inf.label, inf.baseline_safe, valid & ~ignore)
    row = next(
        r for r in result.rows if r.table == "dead_pixels" and r.method == "alhat_baseline" and r.test_sigma_m == 0.0167
    )
    np.testing.assert_allclose((row.pixel_accuracy, row.miou, row.precision, row.sensitivity), expected, rtol=1e-12)


def test_reliability_of_a_hand_case():
    p = np.array([0.05, 0.05, 0.95, 0.95, 1.0])
    y = np.array([False, True, True, True, True])
    bins = reliability(p, y, n_bins=10)
    assert bins.count.tolist() == [2, 0, 0, 0, 0, 0, 0, 0, 0, 3]
    # bin 0: |0.5 - 0.05| * 2/5; bin 9: |1 - 0.9667| * 3/5
    assert bins.ece == pytest.approx((0.45 * 2 + (1 - (0.95 + 0.95 + 1.0) / 3) * 3) / 5)


def test_risk_threshold_reports_the_achieved_false_safe_rate(setup, tmp_path):
    dataset, run, _, _ = setup
    result = evaluate_to_report(run, dataset, tmp_path, EvalConfig(mc_samples=2, threshold="risk:0.3"), figures=False)
    th = json.loads((tmp_path / "report.json").read_text())["threshold"]
    assert th["kind"] == "risk" and th["alpha"] == 0.3
    assert [a["test_sigma_m"] for a in th["achieved_risk"]] == list(SIGMAS_M)
    for a in th["achieved_risk"]:
        inf = result.test[a["test_sigma_m"]]
        t = math.inf if th["value_nats"] is None else th["value_nats"]
        valid = inf.label != 255
        per_image = (valid & (inf.label == 0) & (inf.prediction == 1) & (inf.entropy_nats < t)).sum((1, 2)) / valid.sum(
            (1, 2)
        )
        assert a["false_safe_rate"] == pytest.approx(per_image.mean())
    assert not list(tmp_path.glob("*.png"))


def test_bad_input_fails_with_one_clear_sentence(setup, tmp_path):
    dataset, run, _, _ = setup
    cases: list[tuple[dict[str, Any], str]] = [
        ({"mc_samples": 0}, "mc-samples"),
        ({"drop_pixels": -1}, "drop-pixels"),
        ({"drop_pixels": 10_000}, "drop-pixels"),
        ({"threshold": "risk:1.5"}, "alpha must be in"),
        ({"threshold": "median"}, "threshold spec"),
    ]
    for kwargs, message in cases:
        with pytest.raises(HdNetError, match=message):
            evaluate_to_report(run, dataset, tmp_path / "x", EvalConfig(**kwargs))
    torch.save({"schema": "someone.else", "weights": torch.zeros(1)}, tmp_path / "other.pt")
    with pytest.raises(HdNetError, match="not an hdnet checkpoint"):
        evaluate(tmp_path / "other.pt", dataset)
    unlabelled = build_labelled(tmp_path / "u", n_scans=4, label=False)
    with pytest.raises(LabelStoreError, match="no labels"):
        evaluate(run, unlabelled)
    assert not (tmp_path / "x").exists()


def test_a_dataset_without_the_training_sigma_is_calibrated_on_dems_made_at_it(setup, tmp_path):
    """A run trained at 1.67 cm on a user's dataset of 3 and 7 cm: H_t from validation DEMs made at 1.67 cm."""
    _, run, _, _ = setup
    other_sigmas = build_labelled(tmp_path / "s", sigmas_m=(0.03, 0.07))
    result = evaluate(run, other_sigmas, EvalConfig(mc_samples=1))
    assert result.threshold["calibration_sigma_m"] == 0.0167 and result.threshold["value_nats"] is not None
    assert sorted({r.test_sigma_m for r in result.rows}) == [0.03, 0.07]


def test_evaluate_returns_the_result_and_the_caller_writes_the_report(setup, tmp_path, monkeypatch):
    dataset, run, out, first = setup
    config = EvalConfig(mc_samples=4, drop_pixels=10, seed=0)
    monkeypatch.chdir(tmp_path)
    result = evaluate(run, dataset, config)
    assert list(tmp_path.iterdir()) == []  # evaluate wrote nothing
    assert json.dumps(report_dict(result)) == json.dumps(report_dict(first))
    evaluate_to_report(run, dataset, tmp_path / "again", config, figures=False)
    assert (tmp_path / "again" / "report.json").read_text() == (out / "report.json").read_text()


def test_a_bad_report_directory_fails_before_the_evaluation(setup, tmp_path, monkeypatch):
    trained_run_module = importlib.import_module("hdnet.trained_run")  # where hd eval loads a checkpoint

    def no_work(*args: object, **kwargs: object) -> None:
        raise AssertionError("the evaluation ran")

    dataset, run, _, _ = setup
    monkeypatch.setattr(trained_run_module, "load_trained_model", no_work)
    occupied = tmp_path / "occupied"
    occupied.mkdir()
    (occupied / "notes.txt").write_text("mine")
    with pytest.raises(OutputExistsError, match="not empty and holds no hd report output"):
        evaluate_to_report(run, dataset, occupied, EvalConfig(mc_samples=2))
    assert [p.name for p in occupied.iterdir()] == ["notes.txt"]


def test_report_and_figures_do_not_import_the_evaluation() -> None:
    code = "import sys, hdnet.report, hdnet.figures; print('hdnet.evaluate' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_a_run_saved_before_input_specs_evaluates_like_before(setup, tmp_path):
    """An hd 0.1.0 checkpoint: no ``input`` spec in extra_config, no ``depth`` in the model config."""
    from hdnet.train import load_checkpoint, save_checkpoint

    dataset, run, _, _ = setup
    ckpt = load_checkpoint(run / "last.pt")
    spec = checkpoint_data(ckpt, run / "last.pt").input
    assert spec.normalisation is not None  # hd 0.1.0 knew min-max heights only, recorded beside the input
    old_extra = {k: v for k, v in ckpt["extra_config"].items() if k != "input"}
    old_extra.update(normalisation=spec.normalisation.to_dict(), input_size=spec.input_size)
    old_model = {k: v for k, v in ckpt["model_config"].items() if k != "depth"}
    old = cast(CheckpointJson, {**ckpt, "extra_config": old_extra, "model_config": old_model})
    old.pop("timing")
    old["history"] = [  # hd 0.1.0's rows: no mIoU, no learning rate
        cast(EpochRow, {k: h[k] for k in ("epoch", "train_loss", "val_loss", "val_pixel_accuracy")})
        for h in ckpt["history"]
    ]
    save_checkpoint(tmp_path / "old.pt", old)
    before = evaluate(run, dataset, EvalConfig(mc_samples=2))
    after = evaluate(tmp_path / "old.pt", dataset, EvalConfig(mc_samples=2))
    assert after.rows == before.rows
    assert after.run["input"] == before.run["input"] and after.run["input"]["heights"] == "minmax"


def test_validation_summary_matches_the_validation_inference(setup):
    from hdnet.evaluate import infer_split, score, validation_summary
    from hdnet.inputs import InputSpec
    from hdnet.train import load_trained_model

    dataset, run, _, _ = setup
    summary = validation_summary(run, dataset, mc_samples=3, seed=1, other_sigmas_m=(0.07,), risk_alpha=0.3)
    model, ckpt = load_trained_model(run / "last.pt")
    spec = InputSpec.from_run_config(ckpt["extra_config"], ckpt["model_config"])
    inf = infer_split(model, HazardDataset(dataset, "val", 0.0167, input_spec=spec), 3, 8, 1, torch.device("cpu"))
    valid = inf.label != 255
    base = hand_metrics(inf.label, inf.prediction == 1, valid)
    np.testing.assert_allclose(
        [summary[k] for k in ("base_pa", "base_miou", "base_precision", "base_sensitivity")], base, rtol=1e-12
    )
    h = float(inf.entropy_nats[valid].astype(np.float64).mean())
    assert summary["threshold_nats"] == pytest.approx(h)
    ua = score(inf.label, inf.prediction, inf.ignore, inf.entropy_nats >= h)
    assert summary["ua_vc"] == pytest.approx(ua.vc_fraction) and summary["ua_precision"] == pytest.approx(
        ua.precision_safe, nan_ok=True
    )
    assert summary["q_vc"] == pytest.approx(0.5, abs=0.02)
    assert summary["risk_false_safe"] <= 0.3  # conformal risk control on the same images: in-sample bound
    other = infer_split(model, HazardDataset(dataset, "val", 0.07, input_spec=spec), 3, 8, 1, torch.device("cpu"))
    b7 = hand_metrics(other.label, other.prediction == 1, other.label != 255)
    assert summary["base_pa@7cm"] == pytest.approx(b7[0])
    certain = (other.label != 255) & (other.entropy_nats < h)
    assert summary["ua_vc@7cm"] == pytest.approx(certain.sum() / (other.label != 255).sum())


def test_the_paper_values_sit_beside_the_paper_dataset_only(setup):
    import dataclasses

    from hdnet.report import report_markdown

    *_, result = setup
    paper = dataclasses.replace(result, run={**result.run, "paper_dataset": True})
    assert "0.9345" in report_markdown(paper) and "0.9345" not in report_markdown(result)


def test_the_report_says_which_truth_the_run_was_scored_against(setup):
    import dataclasses

    from hdnet.report import report_markdown

    _, _, out, result = setup
    assert result.run["truth"] == "clean-scan"
    assert "scored against the clean-scan truth" in (out / "report.md").read_text()
    terrain = dataclasses.replace(result, run={**result.run, "truth": "terrain"})
    assert "scored against the terrain truth" in report_markdown(terrain)


def test_table_1_gives_the_training_noise_the_run_was_trained_on(setup):
    import dataclasses

    from hdnet.report import report_markdown

    *_, result = setup

    def train_cells(run: dict) -> set[str]:
        md = report_markdown(dataclasses.replace(result, run=run))
        table = md.split("## Table 1: noise levels")[1].split("\n\n")[1]
        return {line.split(" | ")[1] for line in table.splitlines()[2:]}

    assert train_cells(result.run) == {"--", "1.67 cm"}  # the baseline is not trained
    ranged = {**result.run, "train_noise": {"kind": "range", "levels_m": [], "range_m": [0.0, 0.1]}}
    assert train_cells(ranged) == {"--", "0 to 10 cm"}  # not the reference level of the range
    levels = {**result.run, "train_noise": {"kind": "levels", "levels_m": [0.0167, 0.03, 0.07], "range_m": None}}
    assert train_cells(levels) == {"--", "1.67, 3, 7 cm"}


# --- the uncertainty score: predictive entropy (the default) or mutual information ---------------------
# The threshold record of a default report: exactly the keys reports had before the score was a choice.
DEFAULT_THRESHOLD_KEYS = {
    "spec",
    "kind",
    "parameter",
    "value_nats",
    "mean_nats",
    "mean_quantile",
    "calibration_split",
    "calibration_sigma_m",
    "calibration_images",
    "calibration_pixels",
    "calibrate",
    "calibration_datasets",
    "calibration_source",
}
MI = {"uncertainty": "mutual-information"}
CPU = torch.device("cpu")


@pytest.fixture(scope="module")
def mi_report(setup, tmp_path_factory):
    """The tiny run evaluated with the mutual information as its uncertainty score, report written."""
    dataset, run, _, _ = setup
    out = tmp_path_factory.mktemp("mi") / "report"
    config = EvalConfig(uncertainty="mutual-information", mc_samples=4)
    return out, config, evaluate_to_report(run, dataset, out, config)


def validation_inference(dataset, run, mc_samples: int, seed: int = 0):
    """MC dropout over the validation split at the run's 1.67 cm, as evaluate's calibration makes it."""
    from hdnet.evaluate import infer_split
    from hdnet.inputs import InputSpec
    from hdnet.train import load_trained_model

    model, ckpt = load_trained_model(run / "last.pt")
    spec = InputSpec.from_run_config(ckpt["extra_config"], ckpt["model_config"])
    return infer_split(model, HazardDataset(dataset, "val", 0.0167, input_spec=spec), mc_samples, 8, seed, CPU)


def test_mutual_information_is_calibrated_on_the_validation_mutual_information(setup, mi_report):
    dataset, run, _, default = setup
    _, _, result = mi_report
    val = validation_inference(dataset, run, 4)
    assert val.mutual_information_nats is not None
    mi = val.mutual_information_nats[val.valid].astype(np.float64)
    th = result.threshold
    assert th["uncertainty"] == "mutual-information" and th["spec"] == "mean"
    assert th["value_nats"] == pytest.approx(mi.mean(), rel=1e-9) and th["value_nats"] == th["mean_nats"]
    assert th["calibration_pixels"] == mi.size and th["mean_quantile"] == pytest.approx(np.mean(mi < mi.mean()))
    assert th["value_nats"] < default.threshold["value_nats"]  # MI <= H pixel by pixel
    for q, t in [(s["quantile"], s["threshold_nats"]) for s in result.sweep if s["test_sigma_m"] == 0.07]:
        assert t == pytest.approx(np.quantile(val.mutual_information_nats[val.valid], q), rel=1e-6)


def test_mutual_information_rows_equal_a_hand_count(mi_report):
    _, _, result = mi_report
    h_t = result.threshold["value_nats"]
    for sigma, inf in result.test.items():
        assert inf.mutual_information_nats is not None
        mi = inf.mutual_information_nats
        assert ((mi >= 0) & (mi <= inf.entropy_nats)).all()
        valid = inf.label != 255
        certain = valid & (mi < h_t)
        ua = next(
            r for r in result.rows if r.table == "noise" and r.method == "uncertainty_aware" and r.test_sigma_m == sigma
        )
        t, p = inf.label == 1, inf.prediction == 1
        ts, fs = (certain & t & p).sum(), (certain & ~t & p).sum()
        assert ua.vc_fraction == pytest.approx(certain.sum() / valid.sum())
        assert ua.precision == pytest.approx(ts / (ts + fs)) and ua.sensitivity == pytest.approx(ts / (valid & t).sum())
        base = next(r for r in result.rows if r.table == "noise" and r.method == "base_net" and r.test_sigma_m == sigma)
        assert base.pixel_accuracy == pytest.approx(((t == p) & valid).sum() / valid.sum())  # the score leaves it be


def test_the_report_names_the_mutual_information_and_the_default_report_is_unchanged(setup, mi_report):
    dataset, run, default_out, default = setup
    out, config, result = mi_report
    md = (out / "report.md").read_text()
    assert "- uncertainty score `mutual-information`: the mutual information H[mean p] - mean H[p]" in md
    assert "(mean mutual information " in md and "on the mutual information" in result.summary()
    assert json.loads((out / "report.json").read_text())["threshold"]["uncertainty"] == "mutual-information"
    assert (out / "qualitative_7.00cm.png").read_bytes()[:4] == b"\x89PNG"
    # The default: the score unnamed, the report's threshold record and wording as before the choice.
    th = json.loads((default_out / "report.json").read_text())["threshold"]
    assert set(th) == DEFAULT_THRESHOLD_KEYS
    md = (default_out / "report.md").read_text()
    assert "uncertainty score" not in md and "(mean entropy " in md and " on the " not in default.summary()
    # Each report is current for its own score only.
    from hdnet.evaluate import report_is_current

    entropy_config = EvalConfig(mc_samples=4, drop_pixels=10, seed=0)
    assert report_is_current(default_out, run, dataset, entropy_config)
    assert not report_is_current(default_out, run, dataset, EvalConfig(**{**vars(entropy_config), **MI}))
    assert report_is_current(out, run, dataset, config)
    assert not report_is_current(out, run, dataset, EvalConfig(mc_samples=4))


def test_an_unknown_uncertainty_score_is_refused():
    with pytest.raises(HdNetError, match="uncertainty"):
        EvalConfig(uncertainty="bald")


def unfinished_copy(run: Path, dest: Path, planned: int) -> Path:
    """A copy of a finished run whose config.json plans ``planned`` epochs: what an interrupted
    training leaves (its checkpoint saved after fewer epochs than planned)."""
    shutil.copytree(run, dest)
    config = json.loads((dest / "config.json").read_text())
    config["epochs"] = planned
    (dest / "config.json").write_text(json.dumps(config))
    return dest


def test_an_unreachable_risk_level_and_an_unfinished_run_are_said(setup, tmp_path):
    """risk:0.05 on 2 validation images (alpha < 1/(n+1) = 1/3) keeps every pixel uncertain whatever
    the network: a warning, a line in report.md beside the threshold and report.json's threshold say
    so with the 19 images it needs; a run stopped at epoch 1 of 10 is evaluated with a warning."""
    dataset, run, _, _ = setup
    partial = unfinished_copy(run, tmp_path / "run", planned=10)
    out = tmp_path / "report"
    with pytest.warns(HdWarning) as caught:
        result = evaluate_to_report(
            partial, dataset, out, EvalConfig(mc_samples=2, threshold="risk:0.05"), figures=False
        )
    said = [str(w.message) for w in caught if issubclass(w.category, HdWarning)]
    assert any("1 of its 10 epochs trained" in m and "unfinished" in m for m in said), said
    assert any("risk:0.05 cannot be certified with 2 validation image(s)" in m and "at least 19" in m for m in said)
    th = json.loads((out / "report.json").read_text())["threshold"]
    assert th["unreachable"] is True and th["needs_images"] == 19 and th["calibration_images"] == 2
    assert th["value_nats"] == 0.0
    md = (out / "report.md").read_text().splitlines()
    at = next(i for i, line in enumerate(md) if line.startswith("- threshold `risk:0.05`"))
    assert md[at + 1].startswith("- **unreachable risk level**: risk:0.05 cannot be certified") and "19" in md[at + 1]
    assert "unreachable with 2 validation images: it needs 19" in result.summary()
    reachable = EvalConfig(mc_samples=2, threshold="risk:0.5")
    assert evaluate_to_report(run, dataset, tmp_path / "r2", reachable, figures=False).threshold["unreachable"] is False


def test_hd_compare_shows_two_real_reports_numbers_and_their_differing_settings(setup, mi_report):
    """hd compare on two reports of the tiny run (entropy with 10 dead pixels; mutual information):
    Table 1's numbers and H_t are the reports', and the settings that differ are named."""
    from click.testing import CliRunner

    from hdcli.cli import main
    from hdnet.report import METHOD_WORDS

    entropy_dir, mi_dir = setup[2], mi_report[0]
    result = CliRunner().invoke(main, ["--json", "compare", str(entropy_dir), str(mi_dir)])
    assert result.exit_code == 0, result.output
    record = json.loads(result.output)
    names = [r["name"] for r in record["reports"]]
    assert len(set(names)) == 2 and all(n.endswith("/report") for n in names)  # both are called report
    shown = {r["row"]: r["values"] for r in record["rows"]}
    for name, directory in zip(names, (entropy_dir, mi_dir), strict=True):
        report = json.loads((directory / "report.json").read_text())
        for r in (r for r in report["rows"] if r["table"] == "noise"):
            prefix = f"{METHOD_WORDS[r['method']]} {r['test_sigma_m'] * 100:.3g} cm"
            assert shown[f"{prefix} PA"][name] == r["pixel_accuracy"]
            assert shown[f"{prefix} sensitivity"][name] == r["sensitivity"]
        assert shown["H_t (nats)"][name] == report["threshold"]["value_nats"]
    differ = record["settings_differ"]
    assert differ["threshold.uncertainty"] == dict(zip(names, ("entropy", "mutual-information"), strict=True))
    assert differ["run.drop_pixels"] == dict(zip(names, (10, 0), strict=True))
    assert "run.checkpoint_sha256" not in differ and "run.checkpoint_sha256" in record["settings_equal"]


def test_overwriting_a_report_removes_a_landing_figure_the_new_report_does_not_have(setup, tmp_path):
    import dataclasses

    from hdnet.report import write_report

    _, _, _, result = setup
    assert result.landing  # the evaluation scores landings (against the clean scan): a landing figure
    out = tmp_path / "report"
    write_report(result, out)
    assert (out / "landing.png").read_bytes()[:4] == b"\x89PNG"
    write_report(dataclasses.replace(result, landing=[]), out, overwrite=True)  # a report without landings
    assert not (out / "landing.png").exists()
    assert "landing.png" not in (out / "report.md").read_text()


# --- which split is scored (--split) ---------------------------------------------------------------
# The run's record keys of a default report, as before --split existed (its bytes must not move).
DEFAULT_SCAN_KEYS = ("test_scans", "val_scans", "paper_dataset")


def test_the_default_split_is_the_test_split_and_its_report_is_unchanged(setup):
    dataset, run, out, _ = setup
    recorded = json.loads((out / "report.json").read_text())["run"]
    assert list(recorded)[-3:] == list(DEFAULT_SCAN_KEYS)  # no split, no scored_scans
    assert recorded["test_scans"] == len(list(iter_scans(dataset, "test")))
    md = (out / "report.md").read_text()
    assert " test / " in md and "## Landing outcome (test split)" in md and "scored scans" not in md
    # --split test said explicitly is the default: the same report, current for either.
    from hdnet.evaluate import report_is_current

    explicit = EvalConfig(mc_samples=4, drop_pixels=10, seed=0, split="test")
    assert explicit == EvalConfig(mc_samples=4, drop_pixels=10, seed=0)
    assert report_is_current(out, run, dataset, explicit)
    assert not report_is_current(out, run, dataset, EvalConfig(mc_samples=4, drop_pixels=10, seed=0, split="all"))


@pytest.mark.parametrize(("split", "calibrated", "trained"), [("val", 2, 0), ("train", 0, 16)])
def test_split_val_and_train_score_those_scans_and_say_what_overlaps(setup, split, calibrated, trained):
    """The run was trained (and H_t is calibrated) on this very dataset: val scans calibrated H_t,
    train scans trained the run; each overlap is warned about and counted."""
    dataset, run, _, _ = setup
    expected = sorted(s.scan_index for s in iter_scans(dataset, split))
    assert len(expected) == {"val": 2, "train": 16}[split]
    with pytest.warns(HdWarning, match=f"--split {split} scores") as caught:
        result = evaluate(run, dataset, EvalConfig(mc_samples=1, nav_sigma_m=(0.0,), split=split))
    assert len([w for w in caught if "--split" in str(w.message)]) == 1
    for inf in result.test.values():
        assert sorted(inf.scan_index.tolist()) == expected
    assert result.run["split"] == split and result.run["scored_scans"] == len(expected)
    assert result.run.get("calibration_scans_scored", 0) == calibrated
    assert result.run.get("training_scans_scored", 0) == trained
    assert "test_scans" not in result.run
    assert {r.scenes for r in result.landing} == {len(expected)}


def test_split_all_scores_every_scan_once_and_the_summary_gives_p_safe_landing(setup, tmp_path, monkeypatch):
    from click.testing import CliRunner

    from hdcli.cli import main
    from lidarsim.shards import read_manifest

    dataset, run, _, _ = setup
    module = importlib.import_module("hdnet.evaluate")
    inferred: list[tuple[str, list[int]]] = []  # (split, scan indices) of every inference hd eval makes
    infer = module.infer_split

    def spy(model: Any, ds: HazardDataset, *args: Any, **kwargs: Any) -> Any:
        inf = infer(model, ds, *args, **kwargs)
        inferred.append((ds.split, inf.scan_index.tolist()))
        return inf

    monkeypatch.setattr(module, "infer_split", spy)
    out = tmp_path / "all"
    args = ["eval", str(run), "--data", str(dataset), "--out", str(out), "--mc-samples", "2", "--split", "all"]
    cli = CliRunner().invoke(main, [*args, "--nav-sigma", "0", "--nav-sigma", "2"])
    assert cli.exit_code == 0, cli.output
    manifest = read_manifest(dataset)
    n = manifest["n_scans"]
    assert n == sum(manifest["splits"].values()) == 20
    report = json.loads((out / "report.json").read_text())
    recorded = report["run"]
    assert (recorded["split"], recorded["scored_scans"]) == ("all", n) and "test_scans" not in recorded
    assert (recorded["calibration_scans_scored"], recorded["training_scans_scored"]) == (2, 16)
    assert {r["scenes"] for r in report["landing"]} == {n}
    # Every scene exactly once at each noise level; H_t from the validation split alone.
    assert [split for split, _ in inferred] == ["val", *["all"] * len(SIGMAS_M)]
    assert all(sorted(scans) == list(range(n)) for split, scans in inferred if split == "all")
    md = (out / "report.md").read_text()
    assert f"{n} scans of all splits scored / 2 validation scans" in md
    assert "- **scored scans calibrated H_t**: 2 of the 20 scored scans" in md
    assert "- **scored scans trained the run**: 16 of the 20 scored scans" in md
    assert "## Landing outcome (all splits)" in md and "in every scored scene" in md
    # The terminal: the overlaps warned, then P(safe landing) per method and noise level, n and interval.
    assert "validation scans H_t was calibrated on" in cli.output
    lines = cli.output.splitlines()
    head = lines.index("P(safe landing) against the clean-scan truth [95 % CI] n=landed/scenes, navigation 1σ 0 | 2 m:")
    body = lines[head + 1 : head + 1 + len(METHODS) * len(SIGMAS_M)]
    assert [line.split()[0] for line in body] == [m for _ in SIGMAS_M for m in METHODS]
    landing = {(r["method"], r["test_sigma_m"], r["nav_sigma_m"]): r for r in report["landing"]}
    for line in body:
        method, sigma = line.split()[0], float(line.split()[1].removesuffix("cm")) / 100
        cells = line.split("  ")[-1].split(" | ")
        assert len(cells) == 2
        for nav, cell in zip((0.0, 2.0), cells, strict=True):
            row = next(r for (m, s, v), r in landing.items() if m == method and abs(s - sigma) < 1e-6 and v == nav)
            assert cell.endswith(f"n={row['landed']}/{n}")
            if row["landed"]:
                assert cell.startswith(f"{row['p_safe']:.3f} [{row['p_safe_low']:.3f}, {row['p_safe_high']:.3f}]")


def test_an_empty_or_unknown_split_is_one_clear_sentence(setup, tmp_path):
    from hdnet.scored_split import scored_split
    from hdnet.trained_run import recorded_training_data

    dataset, run, _, _ = setup
    data = recorded_training_data(run / "last.pt")
    with pytest.raises(HdNetError, match="split must be one of"):
        EvalConfig(split="everything")
    with pytest.raises(HdNetError, match=r"--split must be one of train, val, test or all, got 'x'"):
        scored_split("x", dataset, [], data)
    # A copy of the dataset is the same dataset (its manifest); another dataset's scans overlap nothing.
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    assert scored_split("all", dataset, [str(copy)], data) == ScoredSplit("all", 20, 2, 16)
    other = tmp_path / "other"  # a manifest of 3 validation scans, no other split
    other.mkdir()
    manifest = json.loads((dataset / "manifest.json").read_text())
    counts = {"train": 0, "val": 3, "test": 0}
    shard = {**manifest["shards"][0], "n_scans": 3, "split_counts": counts}
    manifest |= {"splits": counts, "n_scans": 3, "shards": [shard], "labelings": []}
    (other / "manifest.json").write_text(json.dumps(manifest))
    assert scored_split("all", other, [str(dataset)], data) == ScoredSplit("all", 3)
    with pytest.raises(HdNetError, match=r"the test split is empty \(the dataset holds 0 train, 3 val, 0 test scans\)"):
        scored_split("test", other, [str(dataset)], data)
