"""Class C: a full disk gives one line naming the file, leaves no partial file, and the same command
resumes to the uninterrupted result once space is freed.

Two ways: a real small tmpfs (skipped with the reason where it cannot be mounted), with worker
processes; and ENOSPC injected at the storage layer's write for every kind of file hd writes, so
the path is covered everywhere.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
from pathlib import Path

import pytest
from reliability_kit import (
    BUILD_ARGS,
    assert_one_line_error,
    hd_process,
    hills,
    inject_enospc,
    invoke,
    partials,
    remount,
    shard_sums,
    tmpfs,
)


def _build(out, dtm, workers=1):
    return ["build-dataset", "--out", out, "--dtm", dtm, "--workers", str(workers), *BUILD_ARGS]


def _error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert lines and lines[-1].startswith("Error: "), err
    return lines[-1]


# ------------------------------------------------------------------------------------- a real full disk
def test_build_and_label_on_a_full_tmpfs_then_resume(tmp_path, dtm, reference, labelled):
    with tmpfs(tmp_path / "disk", "200k") as disk:
        out = disk / "data"
        proc = hd_process(_build(out, dtm, 2))
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 1, err  # not 139: no segmentation fault
        assert "Traceback" not in err and "no space left on device" in _error_line(err)
        assert str(out) in _error_line(err)
        assert partials(out) == []
        remount(disk, "4m")
        result = invoke(*_build(out, dtm))
        assert result.exit_code == 0, result.output
        assert shard_sums(out) == shard_sums(reference)
        # labelling: room for about two of the four label shards
        used = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
        remount(disk, f"{(used + 700_000) // 1024}k")
        proc = hd_process(["label", out, "--workers", "2"])
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 1, err
        assert "Traceback" not in err and "no space left on device" in _error_line(err)
        assert partials(out) == [] and json.loads((out / "manifest.json").read_text())["labelings"] == []
        remount(disk, "8m")
        result = invoke("label", out, "--workers", "1")
        assert result.exit_code == 0, result.output
        assert shard_sums(out) == shard_sums(labelled)


def test_train_and_eval_on_a_full_tmpfs(tmp_path, labelled, trained):
    with tmpfs(tmp_path / "disk", "2m") as disk:
        run = disk / "run"
        result = invoke("train", labelled, "--out", run, "--profile", "tiny", "--epochs", "1")
        line = assert_one_line_error(result, "no space left on device")
        assert "best.pt" in line  # config.json and last.pt fit, best.pt does not
        assert partials(disk) == []
        remount(disk, "8m")
        result = invoke("train", labelled, "--out", run, "--profile", "tiny", "--epochs", "1", "--resume")
        assert result.exit_code == 0, result.output
        assert sorted(p.name for p in run.iterdir()) == ["best.pt", "config.json", "last.pt", "metrics.csv"]
        assert len((run / "metrics.csv").read_text().splitlines()) == 2
        shutil.rmtree(run)
        used = sum(p.stat().st_size for p in disk.rglob("*") if p.is_file())
        remount(disk, f"{used // 1024 + 60}k")
        report = disk / "report"
        result = invoke("eval", trained, "--data", labelled, "--out", report, "--mc-samples", "2")
        assert_one_line_error(result, "no space left on device")
        assert not report.exists()  # created by the failed evaluation, removed with its staging area
        remount(disk, "16m")
        result = invoke("eval", trained, "--data", labelled, "--out", report, "--mc-samples", "2")
        assert result.exit_code == 0, result.output
        assert (report / "report.json").is_file() and partials(disk) == []


# ------------------------------------------------------------------------------------- injected ENOSPC
@pytest.mark.parametrize("name", ["scans-00002.h5", "manifest.json", ".hd-build.json"])
def test_build_disk_full_at_each_file(tmp_path, dtm, reference, monkeypatch, name):
    out = tmp_path / "data"
    failed = inject_enospc(monkeypatch, name)
    result = invoke(*_build(out, dtm))
    assert_one_line_error(result, name, "no space left on device")
    assert failed == [name] and partials(tmp_path) == []
    if name == ".hd-build.json":
        assert not out.exists()  # a fresh build that completed nothing leaves nothing
    monkeypatch.undo()
    result = invoke(*_build(out, dtm))
    assert result.exit_code == 0, result.output
    assert shard_sums(out) == shard_sums(reference)


def test_procedural_terrain_disk_full(tmp_path, monkeypatch):
    out = tmp_path / "data"
    inject_enospc(monkeypatch, "mars-procedural-seed3.tif")
    result = invoke("build-dataset", "--out", out, "--workers", "1", *BUILD_ARGS)
    assert_one_line_error(result, "mars-procedural-seed3.tif", "no space left on device")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["labels-00001.h5", "manifest.json"])
def test_label_disk_full_at_each_file(tmp_path, reference, labelled, monkeypatch, name):
    data = tmp_path / "data"
    shutil.copytree(reference, data)
    inject_enospc(monkeypatch, name)
    result = invoke("label", data, "--workers", "1")
    assert_one_line_error(result, name, "no space left on device")
    assert partials(data) == [] and json.loads((data / "manifest.json").read_text())["labelings"] == []
    monkeypatch.undo()
    result = invoke("label", data, "--workers", "1")
    assert result.exit_code == 0, result.output
    assert shard_sums(data) == shard_sums(labelled)


@pytest.mark.parametrize("name", ["config.json", "last.pt", "best.pt", "metrics.csv"])
def test_train_disk_full_at_each_file(tmp_path, labelled, monkeypatch, name):
    run = tmp_path / "run"
    inject_enospc(monkeypatch, name)
    result = invoke("train", labelled, "--out", run, "--profile", "tiny", "--epochs", "1")
    assert_one_line_error(result, name, "no space left on device")
    assert partials(tmp_path) == []
    if name in ("config.json", "last.pt"):  # no epoch committed: no run directory holding only config.json
        assert not run.exists()
    monkeypatch.undo()
    result = invoke("train", labelled, "--out", run, "--profile", "tiny", "--epochs", "1", "--resume")
    assert result.exit_code == 0, result.output
    assert len((run / "metrics.csv").read_text().splitlines()) == 2 and (run / "best.pt").is_file()


@pytest.mark.parametrize("name", ["report.json", "report.md"])
def test_eval_disk_full_leaves_no_half_report(tmp_path, labelled, trained, monkeypatch, name):
    report = tmp_path / "report"
    inject_enospc(monkeypatch, name)
    result = invoke("eval", trained, "--data", labelled, "--out", report, "--mc-samples", "2")
    assert_one_line_error(result, name, "no space left on device")
    assert not report.exists()


def test_make_dtm_disk_full(tmp_path, monkeypatch):
    inject_enospc(monkeypatch, "mars.tif")
    result = invoke("make-dtm", tmp_path / "mars.tif", "--size", "64")
    assert_one_line_error(result, "mars.tif", "no space left on device")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------- hd detect
def _detect(trained, dtm_path, out):
    return ["detect", trained, "--dtm", dtm_path, "--out", out, "--threshold", "nats:0.3", "--mc-samples", "2"]


def test_detect_on_a_full_tmpfs_names_the_map(tmp_path, trained):
    """GDAL writes the maps itself: its messages are captured, the error names the map."""
    site = hills(tmp_path / "site.tif", n=120)
    with tmpfs(tmp_path / "disk", "60k") as disk:
        out = disk / "d"
        proc = hd_process(_detect(trained, site, out))
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 1, err
        lines = [line for line in err.replace("\r", "\n").splitlines() if line.strip()]
        raw = [line for line in lines if not line.startswith(("tiles:", "Error: "))]
        assert raw == [], err  # no "ERROR 1: TIFFAppendToStrip", no "_tiffWriteProc: ..."
        line = _error_line(err)
        assert line.startswith(f"Error: {out}/") and ".tif: no space left on device" in line, line
        assert not out.exists() and partials(disk) == []
        remount(disk, "4m")
        result = invoke(*_detect(trained, site, out))
        assert result.exit_code == 0, result.output


@pytest.mark.parametrize("name", ["entropy.tif", "sites.csv", "overview.png", "detect.json"])
def test_detect_disk_full_at_each_file(tmp_path, trained, monkeypatch, capfd, name):
    """ENOSPC while each file is written (for the GDAL-written maps: written to /dev/full)."""
    import rasterio

    site = hills(tmp_path / "site.tif", n=120)
    out = tmp_path / "d"
    if name.endswith(".tif"):
        real_open = rasterio.open

        def open_full(fp, mode="r", *args, **kwargs):
            if mode == "w" and Path(fp).name == name:
                fp = "/dev/full"
            return real_open(fp, mode, *args, **kwargs)

        monkeypatch.setattr(rasterio, "open", open_full)
    elif name == "overview.png":
        import matplotlib.figure

        def savefig_full(self, fname, *args, **kwargs):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        monkeypatch.setattr(matplotlib.figure.Figure, "savefig", savefig_full)
    else:
        inject_enospc(monkeypatch, name)
    result = invoke(*_detect(trained, site, out))
    line = assert_one_line_error(result, f"{out / name}: no space left on device")
    assert ".partial" not in line
    raw = capfd.readouterr().err
    assert "ERROR" not in raw and "_tiff" not in raw, raw
    assert not out.exists() and partials(tmp_path) == []
