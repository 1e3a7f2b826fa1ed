"""Class H: ``hd inspect`` tells an intact dataset from a damaged, unfinished or busy one."""

from __future__ import annotations

import json
import os
import shutil

import pytest
from reliability_kit import BUILD_ARGS, assert_one_line_error, invoke

from lidarsim.storage import WriterLock


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
