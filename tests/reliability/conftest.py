"""Shared fixtures of the fault catalogue: a tiny terrain, reference datasets and runs.

Reference results are made once per test session, uninterrupted and in this process; every fault
test compares what a resumed or repaired command leaves with them, byte for byte (sha256).
"""

from __future__ import annotations

import shutil
import signal
from pathlib import Path

import pytest
from reliability_kit import BUILD_ARGS, LABEL_ARGS, hills, invoke


# ---------------------------------------------------------------------------------------- references
@pytest.fixture(scope="session", autouse=True)
def one_torch_thread():
    """Tiny trainings run faster on one thread than on two competing with other processes."""
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


@pytest.fixture(scope="session")
def dtm(tmp_path_factory) -> Path:
    return hills(tmp_path_factory.mktemp("terrain") / "hills.tif")


@pytest.fixture(scope="session")
def reference(tmp_path_factory, dtm) -> Path:
    """The uninterrupted build (unlabelled)."""
    out = tmp_path_factory.mktemp("ref") / "data"
    result = invoke("build-dataset", "--out", out, "--dtm", dtm, "--workers", "1", *BUILD_ARGS)
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="session")
def labelled(tmp_path_factory, reference) -> Path:
    """The reference build, labelled uninterrupted (a copy of ``reference``)."""
    out = tmp_path_factory.mktemp("lab") / "data"
    shutil.copytree(reference, out)
    result = invoke("label", out, "--workers", "1", *LABEL_ARGS)
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="session")
def trained(tmp_path_factory, labelled) -> Path:
    """A one-epoch tiny run on the labelled reference."""
    run = tmp_path_factory.mktemp("run") / "run"
    result = invoke("train", labelled, "--out", run, "--profile", "tiny", "--epochs", "1")
    assert result.exit_code == 0, result.output
    return run


@pytest.fixture
def data_copy(tmp_path, labelled) -> Path:
    """A private copy of the labelled reference, free to damage."""
    out = tmp_path / "copy"
    shutil.copytree(labelled, out)
    return out


@pytest.fixture
def no_hang():
    """A read that blocks (a FIFO opened for reading waits for a writer) fails the test after 20 s."""

    def _timeout(signum, frame):
        raise TimeoutError("the read blocked")

    previous = signal.signal(signal.SIGALRM, _timeout)
    signal.alarm(20)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, previous)
