"""Class H: ``hd inspect`` tells an intact dataset from a damaged, unfinished or busy one."""

from __future__ import annotations

import json
import os
import shutil

import pytest
from reliability_kit import BUILD_ARGS, assert_one_line_error, invoke

from hdcore.storage import WriterLock


def test_an_intact_dataset_is_summarised_as_intact(labelled):
    result = invoke("inspect", labelled)
    assert result.exit_code == 0, result.output
    assert "8 in 4 shards" in result.output and "status    intact" in result.output


@pytest.mark.parametrize(
    "damage", ["scan-shard-deleted", "scan-shard-flipped", "label-shard-deleted", "label-shard-truncated"]
)
def test_a_damaged_dataset_is_not_summarised_as_normal(data_copy, damage):
    kind, _, what = damage.rpartition("-")
    path = next(data_copy.glob("shards/scans-00002.h5" if kind.startswith("scan") else "labels/*/labels-00001.h5"))
    if what == "deleted":
        path.unlink()
    elif what == "flipped":
        data = bytearray(path.read_bytes())
        data[len(data) // 2] ^= 1
        path.write_bytes(bytes(data))
    else:
        path.write_bytes(path.read_bytes()[:1000])
    result = invoke("inspect", data_copy)
    line = assert_one_line_error(result, "damaged", "hd verify")
    assert "1 problem" in line and "DAMAGED" in result.output and path.name in result.output


def test_a_damaged_dataset_gets_no_figure(data_copy, tmp_path):
    """hd inspect --plot draws only an intact dataset: a damaged one is named as such and no figure
    (not even a temporary file) is written."""
    path = data_copy / "shards" / "scans-00001.h5"
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 1
    path.write_bytes(bytes(data))
    figure = tmp_path / "figures" / "glance.png"
    figure.parent.mkdir()
    result = invoke("inspect", data_copy, "--plot", figure)
    assert_one_line_error(result, "damaged", "hd verify")
    assert f"figure    not written ({figure}): the dataset is damaged" in result.output
    assert list(figure.parent.iterdir()) == []


def test_an_unfinished_build_is_named_as_such(tmp_path, dtm, monkeypatch):
    out = tmp_path / "data"
    calls: list[object] = []
    import lidarsim.build as build

    real = build.run_shard

    def stop_after_two(task):
        if len(calls) == 2:
            raise KeyboardInterrupt
        calls.append(task)
        return real(task)

    monkeypatch.setattr(build, "run_shard", stop_after_two)
    result = invoke("build-dataset", "--out", out, "--dtm", dtm, "--workers", "1", *BUILD_ARGS)
    assert result.exit_code == 130
    monkeypatch.undo()
    for command in (["inspect", out], ["verify", out], ["label", out], ["train", out, "--out", tmp_path / "run"]):
        assert_one_line_error(
            invoke(*command), "unfinished build (2 of 4 shards complete)", "re-run the same `hd build-dataset` command"
        )
    with WriterLock(out):  # a build at work in it
        assert_one_line_error(invoke("inspect", out), f"a build is in progress (PID {os.getpid()})")


def test_an_unfinished_labelling_is_named(data_copy):
    lab = next((data_copy / "labels").iterdir())
    shutil.copytree(lab, data_copy / "labels" / "square-d10m-pad1m-slope8deg-other")
    result = invoke("inspect", data_copy)
    assert result.exit_code == 0, result.output
    assert "square-d10m-pad1m-slope8deg-other: unfinished (4 label shards written)" in result.output


def test_inspect_of_a_manifest_listing_fewer_scans_than_its_shards(data_copy):
    m = json.loads((data_copy / "manifest.json").read_text())
    del m["shards"][-1]
    (data_copy / "manifest.json").write_text(json.dumps(m))
    assert_one_line_error(invoke("inspect", data_copy), "lists 8 scans but its shards hold 6")


def test_the_procedural_terrain_inside_a_dataset_is_checked(tmp_path):
    out = tmp_path / "data"
    assert invoke("build-dataset", "--out", out, "--workers", "1", *BUILD_ARGS).exit_code == 0
    tif = next((out / "terrain").glob("*.tif"))
    good = tif.read_bytes()
    for damage in ("deleted", "flipped"):
        if damage == "deleted":
            tif.unlink()
        else:
            data = bytearray(good)
            data[len(data) // 2] ^= 1
            tif.write_bytes(bytes(data))
        verify = invoke("verify", out)
        assert verify.exit_code == 1 and f"terrain/{tif.name}" in verify.output, damage
        assert_one_line_error(invoke("inspect", out), "damaged")


# ------------------------------------------------------------------------------------- runs
def _run_copy(trained, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(trained, run)
    return run


def _reseal(path, change):
    """Rewrite a checkpoint with ``change`` applied and its content digest made to match (a forgery)."""
    import torch

    from hdnet.train import checkpoint_digest

    ckpt = torch.load(path, weights_only=True)
    change(ckpt)
    ckpt["content_sha256"] = checkpoint_digest({k: v for k, v in ckpt.items() if k != "content_sha256"})
    torch.save(ckpt, path)


def _edit_json(path, change):
    record = json.loads(path.read_text())
    change(record)
    path.write_text(json.dumps(record))


def _flip_weights(path):
    import torch

    ckpt = torch.load(path, weights_only=True)
    raw = max(ckpt["model"].values(), key=lambda t: t.numel()).numpy().tobytes()
    data = bytearray(path.read_bytes())
    at = data.find(raw) + len(raw) // 2
    data[at : at + 16] = bytes(b ^ 0x5A for b in data[at : at + 16])
    path.write_bytes(bytes(data))


def test_an_intact_run_is_summarised(trained):
    result = invoke("inspect", trained)
    assert result.exit_code == 0, result.output
    assert "epochs    1 of 1 done" in result.output and "files     last.pt, best.pt" in result.output
    record = json.loads(invoke("inspect", trained, "--json").output)
    assert record["epochs_done"] == 1 and record["checkpoints"] == ["last.pt", "best.pt"]


RUN_DAMAGE = [
    # (file, damage, what the error line says besides the file's name)
    ("last.pt", "truncated", "not a readable hdnet checkpoint"),
    ("last.pt", "garbage", "not a readable hdnet checkpoint"),
    ("last.pt", "flipped-weights", "checksum mismatch"),
    ("last.pt", "digest-removed", "lacks its content_sha256"),
    ("last.pt", "empty", "not a readable hdnet checkpoint"),
    ("last.pt", "deleted", "missing"),
    ("last.pt", "forged-dataset", "dataset"),
    ("last.pt", "forged-model", "model"),
    ("last.pt", "forged-epoch", "epoch"),
    ("best.pt", "truncated", "not a readable hdnet checkpoint"),
    ("best.pt", "garbage", "not a readable hdnet checkpoint"),
    ("best.pt", "forged-dataset", "dataset"),
    ("config.json", "forged-dataset", "dataset"),
    ("config.json", "forged-labels", "labelling"),
    ("config.json", "forged-profile", "profile"),
    ("config.json", "input-garbage", "unreadable"),
    ("config.json", "noise-garbage", "unreadable"),
    ("config.json", "truncated", "unreadable run config"),
    ("metrics.csv", "garbage", "metrics"),
    ("metrics.csv", "text-garbage", "metrics"),
    ("metrics.csv", "header-truncated", "metrics"),
    ("metrics.csv", "row-truncated", "metrics"),
    ("metrics.csv", "not-a-number", "metrics"),
    ("metrics.csv", "forged-value", "val_loss"),
    ("metrics.csv", "forged-extra-epoch", "epoch"),
    ("metrics.csv", "emptied", "metrics"),
]


@pytest.mark.parametrize(("name", "damage", "needle"), RUN_DAMAGE, ids=[f"{f}-{d}" for f, d, _ in RUN_DAMAGE])
def test_a_damaged_or_forged_run_is_never_summarised_as_normal(trained, tmp_path, name, damage, needle):
    """hd inspect RUN read config.json and metrics.csv only: garbage, truncated and forged
    checkpoints, a config.json that names other data than the checkpoints, and metrics.csv files
    that are not the checkpoint's history were summarised with exit status 0."""
    run = _run_copy(trained, tmp_path)
    path = run / name
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])
    elif damage == "garbage":
        path.write_bytes(os.urandom(4096))
    elif damage == "empty":
        path.write_bytes(b"")
    elif damage == "deleted":
        path.unlink()
    elif damage == "flipped-weights":
        _flip_weights(path)
    elif damage == "digest-removed":
        import torch

        ckpt = torch.load(path, weights_only=True)
        del ckpt["content_sha256"]
        torch.save(ckpt, path)
    elif name.endswith(".pt"):
        _reseal(
            path,
            {
                "forged-dataset": lambda c: c["extra_config"].update(dataset="/elsewhere/data"),
                "forged-model": lambda c: c["model_config"].update(dropout_p=0.25),
                "forged-epoch": lambda c: c.update(epoch=7),
            }[damage],
        )
    elif name == "config.json":
        _edit_json(
            path,
            {
                "forged-dataset": lambda r: r["extra_config"].update(dataset="/elsewhere/data"),
                "forged-labels": lambda r: r["extra_config"].update(labels="other-labels"),
                "forged-profile": lambda r: r["profile"].update(name="paper"),
                "input-garbage": lambda r: r["extra_config"].update(input="x"),
                "noise-garbage": lambda r: r["extra_config"].update(train_noise={"levels_m": ["low"]}),
            }[damage],
        )
    else:
        text = path.read_text()
        header, row = text.splitlines()
        path.write_text(
            {
                "text-garbage": "garbage\n",
                "header-truncated": header[:40] + "\n",
                "row-truncated": header + "\n" + row[: len(row) // 2] + "\n",
                "not-a-number": header + "\n" + row.replace(row.split(",")[2], "low", 1) + "\n",
                "forged-value": header + "\n" + row.replace(row.split(",")[2], "0.001", 1) + "\n",
                "forged-extra-epoch": text + row.replace("1,", "2,", 1) + "\n",
                "emptied": "",
            }[damage]
        )
    result = invoke("inspect", run)
    line = assert_one_line_error(result, needle)
    assert name in line, line
    assert "profile   " not in result.output  # nothing of the summary is printed
    assert_one_line_error(invoke("inspect", run, "--json"), needle)


@pytest.mark.parametrize("name", ["config.json", "metrics.csv", "last.pt", "best.pt"])
def test_a_fifo_in_a_run_is_refused_at_once(trained, tmp_path, no_hang, name):
    run = _run_copy(trained, tmp_path)
    (run / name).unlink()
    os.mkfifo(run / name)
    line = assert_one_line_error(invoke("inspect", run), "not a regular file")
    assert name in line, line
