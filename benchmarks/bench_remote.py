"""Datasets at URLs: one epoch of the cpu profile's read loop from a local S3 server against local disk,
and the bytes ``hd verify`` reads of a remote dataset against its size.

Measured side by side in one run, interleaved round by round: one epoch of the training split of
``hdnet.data.HazardDataset`` with the cpu profile's inputs (every sample read, its input channels
made, D4 off), from the dataset's directory and from ``s3://`` on a moto S3 server on this machine
(the dataset published there with ``hd publish``'s code). Prints the seconds per epoch, the ratio
(target: at most 1.5), and, through an HTTP server that counts the bytes it sends, the bytes
``verify_dataset`` of the URL read over the dataset's size (target: 1, each byte once).

Usage::

    python benchmarks/bench_remote.py [DATASET] [--rounds 3]

Without DATASET a 60-scan dataset of the procedural terrain (128 x 128 detector, two noise levels)
is built and labelled in a temporary directory first. Needs the ``test`` extra (moto).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from machine import cpu_model

from hdcli.inspection import known_schemas
from hdnet.data import HazardDataset
from hdnet.fit import input_spec_for
from hdnet.profiles import CPU
from lidarsim import location
from lidarsim.shards import read_manifest, verify_dataset
from lidarsim.transfer import dataset_files, publish_dataset
from tests.remote_servers import http_server, make_bucket, s3_server


def _small_dataset(root: Path) -> Path:
    from hdlabels.labeling import label_dataset
    from lidarsim.build import BuildConfig, build_dataset
    from lidarsim.trajectory import TrajectoryConfig

    out = root / "data"
    build_dataset(out, BuildConfig(sigmas_m=(0.0167, 0.07), trajectory=TrajectoryConfig(n_scans=60)), workers=1)
    label_dataset(out, workers=1)
    return out


def _epoch_s(location: str | Path, sigma_m: float) -> float:
    """Seconds of one epoch of the training split read as the cpu profile reads it (a fresh dataset:
    the manifest, the normalisation pass and every sample)."""
    start = time.perf_counter()
    probe = HazardDataset(location, "train", sigma_m)
    spec = input_spec_for(CPU, probe.spacing_m, probe.normalisation)
    probe.close()
    ds = HazardDataset(location, "train", sigma_m, input_spec=spec)
    for i in range(len(ds)):
        ds[i]
    ds.close()
    return time.perf_counter() - start


def _remote_epoch_s(url: str, sigma_m: float, whole_file_blocks: int, kept: bool = False) -> float:
    """:func:`_epoch_s` of a URL, files of at most ``whole_file_blocks`` blocks fetched whole (0: none):
    a first epoch (no file and no manifest kept from an earlier one; the S3 session is kept, as in a
    training run), or with ``kept`` a later epoch of the same process (the whole files and the manifest
    kept in memory)."""
    saved = location.WHOLE_FILE_BLOCKS
    if not kept:
        location._WHOLE.clear()
        location._SIDE.clear()
    location.WHOLE_FILE_BLOCKS = whole_file_blocks
    try:
        return _epoch_s(url, sigma_m)
    finally:
        location.WHOLE_FILE_BLOCKS = saved


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", nargs="?", type=Path)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        dataset = args.dataset or _small_dataset(Path(tmp))
        sigma = float(read_manifest(dataset)["sigmas_m"][0])
        size = sum((dataset / rel).stat().st_size for rel in dataset_files(read_manifest(dataset)))
        size += (dataset / "manifest.json").stat().st_size
        print(f"CPU: {cpu_model()}")
        print(f"dataset: {dataset} ({size / 1e6:.1f} MB)")
        with s3_server():
            make_bucket("bench")
            url = "s3://bench/data"
            publish_dataset(dataset, url, known_schemas=known_schemas())
            local_s: list[float] = []
            blocks = location.WHOLE_FILE_BLOCKS
            variants = {
                "block cache only (2 MiB blocks)": (0, False),
                f"files <= {blocks} blocks fetched whole, first epoch": (blocks, False),
                f"files <= {blocks} blocks fetched whole, later epoch": (blocks, True),
            }
            remote_s: dict[str, list[float]] = {name: [] for name in variants}
            _epoch_s(dataset, sigma)  # warm-up: imports, page cache, the S3 session
            _remote_epoch_s(url, sigma, blocks)
            for _ in range(args.rounds):
                local_s.append(_epoch_s(dataset, sigma))
                for name, (n, kept) in variants.items():
                    remote_s[name].append(_remote_epoch_s(url, sigma, n, kept))
        local = statistics.median(local_s)
        print(f"epoch of the cpu profile's reads, local disk: {local:.3f} s (median of {args.rounds})")
        for name, times in remote_s.items():
            remote = statistics.median(times)
            print(f"  local S3 (moto), {name}: {remote:.3f} s, ratio S3 / disk {remote / local:.2f} (target <= 1.5)")
        with http_server(dataset.parent) as (base, server):
            problems = verify_dataset(f"{base}/{dataset.name}", known_schemas())
            sent = server.bytes_sent  # counted by tests.remote_servers
        assert not problems, problems
        print(f"hd verify of the URL read {sent / 1e6:.2f} MB of {size / 1e6:.2f} MB: {sent / size:.3f} x its size")


if __name__ == "__main__":
    main()
