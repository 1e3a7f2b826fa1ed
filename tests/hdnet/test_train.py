"""Training: files written, exact resume after a kill, refusal of foreign checkpoints, DDP on gloo."""

import csv
import json
import os
import random
import socket
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import cast

import numpy as np
import pytest
import torch
from hdnet_fakes import FakeHazardDataset

from hdnet.checkpoint_json import CheckpointJson
from hdnet.errors import HdNetError
from hdnet.model import BayesianSegNet
from hdnet.profiles import TINY
from hdnet.train import load_checkpoint, load_trained_model, save_checkpoint, train

PROFILE = replace(TINY, batch_size=4)


def _datasets():
    return FakeHazardDataset(n=8, size=32, seed=0), FakeHazardDataset(n=4, size=32, seed=1)


def _weights(path: Path) -> dict[str, torch.Tensor]:
    return load_checkpoint(path)["model"]


def test_train_writes_checkpoint_config_and_metrics(tmp_path: Path) -> None:
    tr, va = _datasets()
    last = train(
        tmp_path / "run",
        tr,
        va,
        PROFILE,
        epochs=2,
        progress=False,
        extra_config={"norm_min_m": -1.5, "norm_max_m": 2.0},
    )
    run = tmp_path / "run"
    assert last == run / "last.pt" and (run / "best.pt").exists()
    config = json.loads((run / "config.json").read_text())
    assert config["extra_config"] == {"norm_min_m": -1.5, "norm_max_m": 2.0} and config["profile"]["name"] == "tiny"
    rows = list(csv.DictReader((run / "metrics.csv").open()))
    assert [int(r["epoch"]) for r in rows] == [1, 2]
    assert list(rows[0]) == [
        "epoch",
        "train_loss",
        "val_loss",
        "val_pixel_accuracy",
        "val_miou",
        "lr",
        "train_images_per_s",
    ]
    assert all(0.0 <= float(r["val_pixel_accuracy"]) <= 1.0 and float(r["train_loss"]) > 0 for r in rows)
    assert all(
        0.0 <= float(r["val_miou"]) <= float(r["val_pixel_accuracy"]) and float(r["train_images_per_s"]) > 0
        for r in rows
    )
    model, ckpt = load_trained_model(last)
    assert isinstance(model, BayesianSegNet) and not model.training and ckpt["epoch"] == 2
    assert ckpt["extra_config"]["norm_max_m"] == 2.0
    assert not list(run.glob("*.partial"))


def test_resume_after_kill_reproduces_uninterrupted_run(tmp_path: Path) -> None:
    tr, va = _datasets()
    straight = train(tmp_path / "a", tr, va, PROFILE, epochs=2, seed=3, progress=False)
    train(tmp_path / "b", tr, va, PROFILE, epochs=1, seed=3, progress=False)
    # A new process would start from other RNG states: scramble them before resuming.
    torch.manual_seed(12345), np.random.seed(12345), random.seed(12345)  # noqa: NPY002 - the global state on purpose
    resumed = train(tmp_path / "b", tr, va, PROFILE, epochs=2, seed=3, resume=True, progress=False)
    a, b = _weights(straight), _weights(resumed)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    assert load_checkpoint(straight)["history"] == load_checkpoint(resumed)["history"]
    # ... and the weights did move during the second epoch.
    one = train(tmp_path / "c", tr, va, PROFILE, epochs=1, seed=3, progress=False)
    assert not all(torch.equal(a[k], _weights(one)[k]) for k in a)


def test_existing_run_without_resume_and_mismatched_profile_are_refused(tmp_path: Path) -> None:
    tr, va = _datasets()
    train(tmp_path / "r", tr, va, PROFILE, epochs=1, progress=False)
    with pytest.raises(HdNetError, match="already holds a checkpoint"):
        train(tmp_path / "r", tr, va, PROFILE, epochs=2, progress=False)
    with pytest.raises(HdNetError, match="another model or profile"):
        train(tmp_path / "r", tr, va, replace(PROFILE, width=1 / 8), epochs=2, resume=True, progress=False)


def test_resume_with_another_extra_config_is_refused_and_the_record_kept(tmp_path: Path) -> None:
    """train(resume=True) rewrote config.json with whatever extra_config it was given (the record of
    what the run was trained on) and continued."""
    tr, va = _datasets()
    run = tmp_path / "r"
    train(run, tr, va, PROFILE, epochs=1, progress=False, extra_config={"data": "a", "n": 1})
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    with pytest.raises(HdNetError, match=r"extra_config's data: recorded \"a\", given \"b\"; .* train a new run"):
        train(run, tr, va, PROFILE, epochs=2, resume=True, progress=False, extra_config={"data": "b", "n": 1})
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before
    train(run, tr, va, PROFILE, epochs=2, resume=True, progress=False, extra_config={"n": 1, "data": "a"})
    assert load_checkpoint(run / "last.pt")["epoch"] == 2


def test_resume_with_another_seed_is_refused_and_the_record_kept(tmp_path: Path) -> None:
    """train(resume=True, seed=other) continued the run from its checkpoint's RNG states and wrote the
    other seed into config.json: a record of a training that never happened."""
    tr, va = _datasets()
    run = tmp_path / "r"
    train(run, tr, va, PROFILE, epochs=1, seed=3, progress=False)
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    with pytest.raises(HdNetError, match=r"cannot be resumed with --seed 4: it was trained with seed 3; .*--seed 3"):
        train(run, tr, va, PROFILE, epochs=2, seed=4, resume=True, progress=False)
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before


def test_a_changed_total_is_refused_where_the_schedule_spans_it(tmp_path: Path) -> None:
    """A cosine schedule's rates depend on the total: 2 epochs of a 2-epoch run are not the first 2
    of a 3-epoch run, so --epochs 3 on it is refused (the record kept) and --epochs 2 finishes it."""
    tr, va = _datasets()
    cosine = replace(PROFILE, lr_schedule="cosine")
    assert cosine.learning_rate(1, 2) != cosine.learning_rate(1, 3) and not cosine.extendable
    run = tmp_path / "r"
    train(run, tr, va, cosine, epochs=2, progress=False, stop_after=1)
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    with pytest.raises(HdNetError, match=r"--epochs 3: its learning-rate schedule spans 2 epochs; finish it with"):
        train(run, tr, va, cosine, epochs=3, resume=True, progress=False)
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before
    train(run, tr, va, cosine, epochs=2, resume=True, progress=False)
    assert load_checkpoint(run / "last.pt")["epoch"] == 2


def test_a_constant_rate_run_may_be_extended_but_not_cut_below_its_epochs(tmp_path: Path) -> None:
    """With a constant rate a run of 1 epoch is the first epoch of a run of 2 (the exact resume
    test above): raising the total is a resume, recorded as the new total; a total below the epochs
    already trained is refused."""
    tr, va = _datasets()
    assert PROFILE.extendable
    run = tmp_path / "r"
    train(run, tr, va, PROFILE, epochs=2, progress=False)
    with pytest.raises(HdNetError, match=r"--epochs 1: it has trained 2 epochs already; train a new run of 1"):
        train(run, tr, va, PROFILE, epochs=1, resume=True, progress=False)
    train(run, tr, va, PROFILE, epochs=3, resume=True, progress=False)
    assert json.loads((run / "config.json").read_text())["epochs"] == 3
    assert load_checkpoint(run / "last.pt")["epoch"] == 3


def test_foreign_checkpoints_are_refused(tmp_path: Path) -> None:
    plain = tmp_path / "plain.pt"
    torch.save(BayesianSegNet(width=1 / 16).state_dict(), plain)
    with pytest.raises(HdNetError, match="not an hdnet checkpoint"):
        load_checkpoint(plain)
    pickled = tmp_path / "pickled.pt"
    torch.save({"schema": "hdnet.checkpoint", "obj": FakeHazardDataset(n=1)}, pickled)
    with pytest.raises(HdNetError, match="not a readable"):
        load_checkpoint(pickled)
    newer = tmp_path / "newer.pt"
    save_checkpoint(
        newer,
        cast(CheckpointJson, {"schema": "hdnet.checkpoint", "schema_version": 99, "model_name": "bayesian_segnet"}),
    )
    with pytest.raises(HdNetError, match="version 99"):
        load_checkpoint(newer)
    other = tmp_path / "other.pt"
    save_checkpoint(
        other, cast(CheckpointJson, {"schema": "hdnet.checkpoint", "schema_version": 1, "model_name": "unet"})
    )
    with pytest.raises(HdNetError, match="unet"):
        load_checkpoint(other)
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a checkpoint")
    with pytest.raises(HdNetError):
        load_checkpoint(garbage)


def test_bad_arguments_raise(tmp_path: Path) -> None:
    tr, va = _datasets()
    with pytest.raises(HdNetError):
        train(tmp_path / "x", tr, va, PROFILE, epochs=0, progress=False)
    with pytest.raises(HdNetError):
        train(tmp_path / "x", tr, va, PROFILE, epochs=1, progress=False, extra_config={"bad": object()})


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_torchrun_two_gloo_processes(tmp_path: Path) -> None:
    script = tmp_path / "ddp_job.py"
    script.write_text(
        "import sys\n"
        f"sys.path[:0] = [{str(Path(__file__).parent)!r}, {os.getcwd()!r}]\n"
        "from dataclasses import replace\n"
        "from hdnet.profiles import TINY\n"
        "from hdnet.train import train\n"
        "from hdnet_fakes import FakeHazardDataset\n"
        f"train({str(tmp_path / 'run')!r}, FakeHazardDataset(8, 32, 0), FakeHazardDataset(4, 32, 1),\n"
        "      replace(TINY, batch_size=4), epochs=2, progress=False)\n"
    )
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--nproc-per-node=2",
        "--master-port",
        str(_free_port()),
        str(script),
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    ckpt = load_checkpoint(tmp_path / "run" / "last.pt")
    assert ckpt["epoch"] == 2 and len(ckpt["history"]) == 2
    assert all(np.isfinite(h["train_loss"]) and np.isfinite(h["val_loss"]) for h in ckpt["history"])
    # Both ranks' RNG states are saved, and they differ (each rank is seeded with seed + rank).
    assert len(ckpt["rng"]) == 2 and not torch.equal(ckpt["rng"][0]["torch"], ckpt["rng"][1]["torch"])
    assert json.loads((tmp_path / "run" / "config.json").read_text())["world_size"] == 2
    # Rank 0 alone wrote: no leftovers, one metrics row per epoch.
    assert not list((tmp_path / "run").glob("*.partial"))
    assert len(list(csv.DictReader((tmp_path / "run" / "metrics.csv").open()))) == 2


def test_validation_counts_and_class_weights_by_hand() -> None:
    from hdnet.train import _accuracy_and_miou, _sum_loss, _val_counts, class_weights_from_counts

    # truth 0,0,1,1,1 and 255; prediction 0,1,1,1,0 (argmax of the logits)
    logits = torch.tensor([[2.0, 0.0], [0.0, 1.0], [0.0, 3.0], [0.0, 1.0], [1.0, 0.0], [0.0, 5.0]]).T.reshape(
        1, 2, 1, 6
    )
    mask = torch.tensor([[[0, 0, 1, 1, 1, 255]]])
    counts = _val_counts(logits, mask)
    assert counts[1] == 5 and counts[2:].tolist() == [1, 1, 1, 2]  # [tu, fs, fu, ts] truth-major
    pa, miou = _accuracy_and_miou(counts[2:])
    assert pa == pytest.approx(3 / 5) and miou == pytest.approx((1 / 3 + 2 / 4) / 2)
    assert class_weights_from_counts([30, 70]) == pytest.approx([100 / 60, 100 / 140])
    assert class_weights_from_counts([0, 10]) == [0.0, 0.5]
    w = torch.tensor([2.0, 0.5])
    loss, norm = _sum_loss(logits, mask, w)
    ce = torch.nn.functional.cross_entropy(logits, mask, ignore_index=255, reduction="none")[0, 0, :5]
    assert norm.item() == pytest.approx(2 * 2.0 + 3 * 0.5)
    assert loss.item() == pytest.approx(float((ce * torch.tensor([2.0, 2.0, 0.5, 0.5, 0.5])).sum()), rel=1e-6)


def test_cpu_levers_train_and_resume_exactly(tmp_path: Path) -> None:
    tr, va = _datasets()
    profile = replace(
        PROFILE, depth=3, channels_last=True, class_weighting="balanced", lr_schedule="onecycle", dropout_p=0.2
    )
    straight = train(tmp_path / "a", tr, va, profile, epochs=2, seed=1, progress=False)
    train(tmp_path / "b", tr, va, profile, epochs=2, seed=1, progress=False, stop_after=1)  # "killed" after epoch 1
    assert load_checkpoint(tmp_path / "b" / "last.pt")["epoch"] == 1
    resumed = train(tmp_path / "b", tr, va, profile, epochs=2, seed=1, resume=True, progress=False)
    a, b = _weights(straight), _weights(resumed)
    assert all(torch.equal(a[k], b[k]) for k in a)  # the one-cycle schedule spans both calls
    config = json.loads((tmp_path / "a" / "config.json").read_text())
    assert config["model_config"]["depth"] == 3 and config["model_config"]["dropout_p"] == 0.2
    masks = torch.stack([tr[i]["mask"] for i in range(len(tr))])
    n0, n1 = int((masks == 0).sum()), int((masks == 1).sum())
    assert config["class_weights"] == pytest.approx([(n0 + n1) / (2 * n0), (n0 + n1) / (2 * n1)])
    model, ckpt = load_trained_model(straight)
    assert (
        model.config.depth == 3
        and len(ckpt["timing"]) == 2
        and ckpt["history"][1]["lr"] == pytest.approx(profile.learning_rate(1, 2))
    )


def test_bfloat16_and_fast_masks_train_resume_exactly_and_differ_from_float32(tmp_path: Path) -> None:
    tr, va = _datasets()
    fast = replace(PROFILE, dropout_p=0.2, precision="bfloat16", fast_dropout=True)
    straight = train(tmp_path / "a", tr, va, fast, epochs=2, seed=5, progress=False)
    train(tmp_path / "b", tr, va, fast, epochs=2, seed=5, progress=False, stop_after=1)
    torch.manual_seed(999)  # a new process: other RNG states before resuming
    resumed = train(tmp_path / "b", tr, va, fast, epochs=2, seed=5, resume=True, progress=False)
    a, b = _weights(straight), _weights(resumed)
    assert all(torch.equal(a[k], b[k]) for k in a)  # the masks' seeds follow PyTorch's checkpointed RNG
    assert all(v.dtype != torch.bfloat16 for v in a.values())  # autocast: the weights stay float32
    slow = _weights(train(tmp_path / "c", tr, va, replace(PROFILE, dropout_p=0.2), epochs=2, seed=5, progress=False))
    assert not all(torch.equal(a[k], slow[k]) for k in a)
    config = json.loads((tmp_path / "a" / "config.json").read_text())
    assert config["profile"]["precision"] == "bfloat16" and config["profile"]["fast_dropout"] is True
    # A loaded model draws nn.Dropout's masks: MC-dropout inference is the same whatever the training.
    model, _ = load_trained_model(straight)
    assert not any(m.fast_masks for m in model.dropout_modules())
