"""Every `hd` line of the README's code blocks is a valid command line, as pasted."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import click
import pytest

from hdcli.cli import main

README = Path(__file__).resolve().parents[2] / "README.md"


def readme_commands() -> list[str]:
    """The lines of the README's bash blocks that call hd (comments removed)."""
    blocks = re.findall(r"```bash\n(.*?)```", README.read_text(), re.S)
    lines = [line.split("  #")[0].strip() for block in blocks for line in block.splitlines()]
    return [line for line in lines if line.startswith("hd ")]


def test_the_readme_shows_the_workflow_in_order():
    commands = [c.split()[1] for c in readme_commands()]
    order = [commands.index(c) for c in ("build-dataset", "label", "train", "eval", "detect")]
    assert order == sorted(order)
    assert "source .venv/bin/activate" in README.read_text()


def test_the_readme_says_which_hd_before_its_first_hd_command():
    """Outside the virtual environment ``hd`` is the system's hexdump, which answers ``hd --out`` with
    "hd: unrecognized option '--out'": the README says so before the first ``hd`` line."""
    text = README.read_text()
    first = text.index("\n" + readme_commands()[0])
    warning = text.index("hexdump")
    assert warning < first and ".venv/bin/hd" in text[:first]
    assert "unrecognized option '--out'" in text[warning - 300 : warning + 300]


@pytest.mark.parametrize("line", readme_commands())
def test_each_readme_command_parses(line: str):
    assert "|" not in line, "one command per line: a pipe would run the commands as a shell pipeline"
    for part in line.split(" && "):
        args = shlex.split(part)[1:]
        name = args[0]
        command = main.get_command(click.Context(main), name)
        assert command is not None, f"no command {name!r}"
        # Parsing checks the options and their values without running anything; inputs need not exist.
        with click.Context(main, info_name="hd") as parent:
            try:
                command.make_context(name, args[1:], parent=parent)
            except click.BadParameter as exc:
                if "does not exist" not in str(exc):
                    raise


def test_the_demo_ends_with_commands_that_parse(tmp_path):
    from hdcli.pipeline import demo_next_steps

    text = demo_next_steps(tmp_path / "demo-out")
    lines = [line.strip() for line in text.splitlines()[1:]]
    assert lines and all("detect" in line for line in lines)
    for line in lines:
        test_each_readme_command_parses("hd " + line.split(" ", 1)[1].replace(" && " + line.split()[0], " && hd"))


@pytest.mark.slow
def test_the_quick_start_runs_line_by_line_as_pasted(tmp_path):
    """The README's first bash block, each line run in order by bash in a fresh directory beside the
    project's .venv (about 20 minutes on 2 cores: `make test-all`)."""
    import os
    import subprocess

    block = re.findall(r"```bash\n(.*?)```", README.read_text(), re.S)[1]  # [0] is make demo / make test
    lines = [line for line in block.splitlines() if line.strip()]
    assert lines[0].startswith("source .venv/bin/activate")
    (tmp_path / ".venv").symlink_to(README.parent / ".venv")
    env = {k: v for k, v in os.environ.items() if k != "VIRTUAL_ENV"}
    script = "set -e\n" + "\n".join(lines) + "\n"
    result = subprocess.run(["bash", "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-2000:]
    for out in ("data", "run", "report", "scan850", "mars-detect"):
        assert (tmp_path / out).is_dir(), out
    assert (tmp_path / "report" / "report.json").is_file() and (tmp_path / "mars-detect" / "detect.json").is_file()


def test_the_demo_suggests_mapping_a_test_scan_not_a_training_scan(tmp_path):
    from hdnet_datasets import build_labelled

    from hdcli.pipeline import demo_next_steps, first_test_scan
    from lidarsim.shards import iter_scans

    dataset = build_labelled(tmp_path / "demo-out", label=False)
    splits = {scan.scan_index: scan.split for scan in iter_scans(dataset)}
    first = first_test_scan(dataset)
    assert first is not None and splits[first] == "test"
    assert all(split != "test" for index, split in splits.items() if index < first)
    assert f"--scan {first} " in demo_next_steps(tmp_path / "demo-out")
    assert first_test_scan(tmp_path / "nothing") is None


def test_the_readme_maps_a_test_scan_of_its_own_build():
    from lidarsim import defaults
    from lidarsim.build import assign_splits

    scan = int(re.search(r"--scan (\d+)", README.read_text()).group(1))  # type: ignore[union-attr]  # the README has one
    assert assign_splits(defaults.N_SCANS, defaults.SEED)[scan] == 2  # the quick start builds 1000 scans, seed 0
