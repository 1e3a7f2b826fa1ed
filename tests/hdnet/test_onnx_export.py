"""hd export-model: the run's network as one ONNX graph with its dropout masks as inputs, and model.json.

The graph is exported once, through the command line (``python -m hdcli export-model``), from a tiny
run trained here on the fake hazard dataset; ONNX Runtime then runs it with masks drawn by hd's own
code, against hd's own forward and hd detect's own MC-dropout pass with the same draws.
"""

from __future__ import annotations

import importlib
import json
import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from hdnet_fakes import FakeHazardDataset

from hdcore.errors import StorageError
from hdcore.storage import sha256_file
from hdnet.dropout_masks import keep_scale
from hdnet.engine import inference_model, predict
from hdnet.errors import HdNetError
from hdnet.export_model_settings import ExportModelSettings
from hdnet.infer import predictive_entropy
from hdnet.inputs import InputSpec, Normalisation, network_inputs
from hdnet.model import MCDropout
from hdnet.noise_levels import TrainingNoise
from hdnet.onnx_export import MaskedSegNet, draw_masks, export_onnx, recorded_threshold
from hdnet.profiles import TINY
from hdnet.run_record import TrainingData
from hdnet.threshold_cache import CachedThreshold, ThresholdKey
from hdnet.train import train
from hdnet.trained_run import TrainedRun

ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")
pytest.importorskip("onnxscript")

ROOT = Path(__file__).resolve().parents[2]
DEM_SHAPE = (40, 40)  # padded to the tiny network's 64 x 64 grid (2**5)
GRID = (64, 64)
SAMPLES, BATCH = 4, 2
onnx_export = importlib.import_module("hdnet.onnx_export")


def make_run(path: Path, epochs: int = 1, stop_after: int | None = None) -> Path:
    """A tiny run of hdnet.train on the fake dataset, recorded as hdnet.fit records its data (min-max heights)."""
    spec = InputSpec(heights="minmax", normalisation=Normalisation(0.0, 1.0))
    data = TrainingData(
        train_sigma_m=0.0167, input=spec, train_noise=TrainingNoise.single(0.0167), dem_shape=DEM_SHAPE, labels="x"
    )
    profile = replace(TINY, dropout_p=0.3)  # 1 / (1 - p) is not a power of two: the scaling is exercised
    train(
        path,
        FakeHazardDataset(4, 32, seed=0),
        FakeHazardDataset(2, 32, seed=1),
        profile,
        epochs=epochs,
        progress=False,
        extra_config=data.to_dict(),
        stop_after=stop_after,
    )
    return path


def hd(*args: str) -> subprocess.CompletedProcess[str]:
    """``python -m hdcli ARGS`` (the worktree's hd: PYTHONPATH is inherited)."""
    return subprocess.run(
        [sys.executable, "-m", "hdcli", *args], cwd=ROOT, capture_output=True, text=True, check=False, timeout=600
    )


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """(run directory, model.onnx, the --json record of hd export-model)."""
    root = tmp_path_factory.mktemp("onnx")
    run = make_run(root / "run")
    out = root / "model.onnx"
    result = hd("--json", "export-model", str(run), "--format", "onnx", "--out", str(out))
    assert result.returncode == 0, result.stderr
    return run, out, json.loads(result.stdout)


def network_input_batch(run: Path, seed: int) -> torch.Tensor:
    """BATCH network inputs of random 40 x 40 DEMs (metres, a hole included), prepared as the run prepares them."""
    rng = np.random.default_rng(seed)
    heights = rng.uniform(0.0, 1.0, (BATCH, *DEM_SHAPE))
    heights[0, 5, 5] = np.nan
    return network_inputs(list(heights), TrainedRun.load(run / "last.pt").data.input)


def run_graph(path: Path, x: torch.Tensor, masks: list[torch.Tensor]) -> list[np.ndarray]:
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    feed = {"dem": x.numpy(), **{f"mask_{k}": m.numpy() for k, m in enumerate(masks)}}
    return session.run(None, feed)


def hooked_forward(run: Path, x: torch.Tensor, masks: list[torch.Tensor]) -> torch.Tensor:
    """hd's own BayesianSegNet.forward, sample by sample, its dropout modules' outputs multiplied by the
    given masks (forward hooks, in call order): (M, N, 2, H, W) logits."""
    model = TrainedRun.load(run / "last.pt").model.eval()
    out = []
    for s in range(masks[0].shape[0]):
        pending = [m[s] for m in masks]

        def masked(_mod: torch.nn.Module, _inp: object, y: torch.Tensor, pending: list = pending) -> torch.Tensor:
            return y * pending.pop(0)

        hooks = [d.register_forward_hook(masked) for d in model.modules() if isinstance(d, MCDropout)]
        with torch.no_grad():
            out.append(model(x))
        for h in hooks:
            h.remove()
        assert not pending
    return torch.stack(out)


def test_the_graph_gives_hds_logits_with_the_same_masks(exported):
    run, out, _ = exported
    x = network_input_batch(run, 1)
    assert tuple(x.shape) == (BATCH, 1, *GRID)
    torch.manual_seed(5)
    masks = draw_masks(MaskedSegNet(TrainedRun.load(run / "last.pt").model), SAMPLES, BATCH, GRID)
    assert sorted({float(v) for m in masks for v in m.unique()}) == [0.0, pytest.approx(keep_scale(0.3))]
    logits, probs = run_graph(out, x, masks)
    want = hooked_forward(run, x, masks)
    assert logits.shape == (SAMPLES, BATCH, 2, *GRID)
    assert np.abs(logits - want.numpy()).max() < 1e-4
    assert np.abs(probs - torch.softmax(want, dim=2).numpy()).max() < 1e-5
    # Other masks give other samples: the masks are inputs, not constants of the graph.
    assert np.abs(run_graph(out, x, [torch.ones_like(m) for m in masks])[0] - logits).max() > 1e-3


def test_m_samples_of_the_graph_are_hd_detects_mc_prediction_for_the_same_seed(exported):
    """The masks draw_masks draws after torch.manual_seed(s) are those of hd detect's MC pass seeded with
    s: P(safe) and the predictive entropy of the M samples agree within 1e-5."""
    run, out, _ = exported
    x = network_input_batch(run, 2)
    model = TrainedRun.load(run / "last.pt").model
    torch.manual_seed(11)
    ref = predict(inference_model(model, "channels-last"), x, SAMPLES, "channels-last-per-tile")
    torch.manual_seed(11)
    _, probs = run_graph(out, x, draw_masks(MaskedSegNet(model), SAMPLES, BATCH, GRID))
    mean = torch.from_numpy(probs).mean(dim=0)
    assert (mean[:, 1] - ref.mean_probs[:, 1]).abs().max() < 1e-5
    assert (predictive_entropy(mean) - ref.entropy_nats).abs().max() < 1e-5
    assert float(ref.entropy_nats.max()) > 1e-3  # the samples differ: the comparison has something to compare


def test_m_and_n_are_free_axes_of_the_graph(exported):
    run, out, _ = exported
    x = network_input_batch(run, 3)[:1]
    masks = draw_masks(MaskedSegNet(TrainedRun.load(run / "last.pt").model), 1, 1, GRID)
    logits, probs = run_graph(out, x, masks)
    assert logits.shape == (1, 1, 2, *GRID)
    assert np.allclose(probs.sum(axis=2), 1.0, atol=1e-6)
    assert np.abs(logits[0] - hooked_forward(run, x, masks)[0].numpy()).max() < 1e-4


def test_the_side_file_describes_the_run_and_the_graph(exported):
    run, out, record = exported
    side = json.loads(out.with_suffix(".json").read_text())
    trained = TrainedRun.load(run / "last.pt")
    assert record["sidecar"] == str(out.with_suffix(".json")) and record["out"] == str(out)
    assert side["schema"] == "hd.onnx-model" and side["schema_version"] == 1 and side["format"] == "onnx"
    assert side["run"]["checkpoint_sha256"] == sha256_file(run / "last.pt") == record["checkpoint_sha256"]
    assert side["onnx_sha256"] == sha256_file(out) and side["onnx_file"] == "model.onnx"
    assert side["input"]["spec"] == trained.data.input.to_dict()
    assert side["input"]["dem_shape"] == list(DEM_SHAPE) and side["input"]["grid"] == list(GRID)
    assert side["input"]["channels"] == ["heights:minmax"] and side["input"]["shape"] == ["batch", 1, *GRID]
    assert side["dropout_p"] == pytest.approx(0.3) and side["mask_values"] == [0.0, pytest.approx(keep_scale(0.3))]
    assert side["classes"] == ["unsafe", "safe"]
    assert side["run"]["train_sigma_m"] == 0.0167 and side["run"]["epoch"] == 1
    # No threshold calibrated for this checkpoint: none is claimed, and the note says how to get one.
    assert side["threshold"]["value_nats"] is None and "hd detect" in side["threshold"]["note"]
    # The masks the side file names are the graph's inputs, with its shapes, in its order.
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    inputs = session.get_inputs()
    assert [i.name for i in inputs] == ["dem"] + [m["name"] for m in side["masks"]]
    for given, described in zip(inputs[1:], side["masks"], strict=True):
        assert given.shape[2:] == described["shape"][2:]
        assert described["shape"][3] * described["grid_divisor"] == GRID[0]
    # Tiny network at depth 5: dropout after pools 3-5 and at the end of decoder units 5, 4, 3.
    layers = ["drop_pool3", "drop_pool4", "drop_pool5", "drop_dec5", "drop_dec4", "drop_dec3"]
    assert [m["layer"] for m in side["masks"]] == layers
    assert [m["grid_divisor"] for m in side["masks"]] == [8, 16, 32, 16, 8, 4]
    assert [o.name for o in session.get_outputs()] == ["logits", "probs"]
    import onnx

    opsets = {o.domain: o.version for o in onnx.load(str(out)).opset_import}
    assert side["opset"] == record["opset"] == opsets.get("", opsets.get("ai.onnx"))


def test_the_threshold_is_taken_from_the_runs_cache_for_this_checkpoint_only(tmp_path, exported):
    run = exported[0]
    sha = sha256_file(run / "last.pt")
    scratch = tmp_path / "run"
    scratch.mkdir()
    (scratch / "config.json").write_text((run / "config.json").read_text())
    cache = CachedThreshold(scratch)

    def key(checkpoint: str, spec: str) -> ThresholdKey:
        return ThresholdKey(checkpoint, "m" * 64, "x", 0.0167, spec, "reference", 8, 4, 0)

    assert cache.put(key("0" * 64, "mean"), 0.1, {"spec": "mean"})  # another checkpoint's
    assert recorded_threshold(scratch, sha)["value_nats"] is None
    assert cache.put(key(sha, "quantile:0.9"), 0.2, {"spec": "quantile:0.9"})
    assert cache.put(key(sha, "mean"), 0.25, {"spec": "mean"})
    assert cache.put(key(sha, "quantile:0.5"), 0.3, {"spec": "quantile:0.5"})
    found = recorded_threshold(scratch, sha)
    assert found["value_nats"] == 0.25 and found["spec"] == "mean"  # the default rule before a newer other one
    assert found["mc_samples"] == 8 and found["calibration_sigma_m"] == 0.0167


def test_bad_runs_and_outputs_are_refused_in_one_line_and_write_nothing(tmp_path, exported):
    run = exported[0]
    (tmp_path / "empty").mkdir()
    unfinished = make_run(tmp_path / "unfinished", epochs=2, stop_after=1)
    taken = tmp_path / "taken.onnx"
    taken.write_bytes(b"keep me")
    cases = [
        ([str(tmp_path / "empty"), "--out", str(tmp_path / "a.onnx")], 1, "is not an hd run"),
        ([str(tmp_path / "nope"), "--out", str(tmp_path / "a.onnx")], 1, "does not exist"),
        ([str(unfinished), "--out", str(tmp_path / "a.onnx")], 1, "is an unfinished run: 1 of its 2 epochs"),
        ([str(run), "--out", str(taken)], 1, "exists; give --overwrite"),
        ([str(run), "--out", str(tmp_path / "a.onnx"), "--format", "tflite"], 2, "'--format': 'tflite' is not 'onnx'"),
        ([str(run), "--out", str(tmp_path / "a.pt")], 1, "must name a .onnx file"),
    ]
    for args, code, needle in cases:
        result = hd("export-model", *args)
        lines = result.stderr.strip().splitlines()
        assert result.returncode == code and "Traceback" not in result.stderr, result.stderr
        assert lines[-1].startswith("Error: ") and needle in lines[-1], result.stderr
        assert not (tmp_path / "a.onnx").exists() and not (tmp_path / "a.json").exists()
    assert taken.read_bytes() == b"keep me" and not (tmp_path / "taken.json").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "taken.onnx", "unfinished"]


def test_a_failed_write_leaves_neither_file(tmp_path, exported, monkeypatch):
    run = exported[0]
    monkeypatch.setattr(onnx_export, "onnx_model_bytes", lambda model, grid: (b"graph", 20))
    done = export_onnx(run, tmp_path / "m.onnx", ExportModelSettings(rows=30, cols=70))
    assert (tmp_path / "m.onnx").read_bytes() == b"graph"
    assert done.model["input"]["grid"] == [32, 96] and done.model["input"]["dem_shape"] == [30, 70]
    assert [m["shape"][3:] for m in done.model["masks"]][:3] == [[4, 12], [2, 6], [1, 3]]

    def broken(self: Path, *args: object, **kwargs: object) -> int:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Path, "write_text", broken)
    with pytest.raises(StorageError, match=r"n\.json: no space left on device"):
        export_onnx(run, tmp_path / "n.onnx")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json", "m.onnx"]


def test_without_onnx_the_export_is_refused_with_the_extra_to_install(tmp_path, exported, monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "onnxscript" else real(name, *a))
    with pytest.raises(HdNetError, match=r"needs onnxscript: pip install 'hd\[onnx\]'"):
        export_onnx(exported[0], tmp_path / "m.onnx")
    assert not list(tmp_path.iterdir())


def test_the_user_guide_example_runs_as_printed(exported, tmp_path, monkeypatch):
    out = exported[1]
    guide = (ROOT / "docs" / "user-guide.md").read_text()
    section = guide[guide.index("## Exporting the network for flight software") :]
    code = section.split("```python\n", 1)[1].split("```", 1)[0]
    monkeypatch.chdir(out.parent)
    rng = np.random.default_rng(0)
    scope: dict[str, object] = {"dem_m": rng.uniform(0.0, 1.0, DEM_SHAPE), "sigma_m": 0.0167}
    exec(compile(code, "user-guide.md snippet", "exec"), scope)
    p_safe, entropy = np.asarray(scope["p_safe"]), np.asarray(scope["entropy"])
    assert p_safe.shape == entropy.shape == DEM_SHAPE
    assert np.all((p_safe >= 0) & (p_safe <= 1)) and np.all((entropy >= 0) & (entropy <= math.log(2) + 1e-6))
