"""``hd inspect`` and ``hd verify``: what they print about a dataset or a run, and whether it passes.

Each returns a :class:`Verdict`: the lines for standard output, then those for standard error, and
the one-line failure (None when the directory passes), which the command turns into its error.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path


@dataclass(frozen=True)
class Verdict:
    """What a check prints (``out`` on stdout, then ``err`` on stderr) and its failure, if any."""

    out: list[str] = field(default_factory=list)
    err: list[str] = field(default_factory=list)
    failure: str | None = None


def known_schemas() -> dict[str, str]:
    """The schemas of the files a dataset may hold beyond scan shards (label shards)."""
    from hdlabels.store import LABEL_SCHEMA, LABEL_SCHEMA_VERSION

    return {LABEL_SCHEMA: LABEL_SCHEMA_VERSION}


def inspect_directory(directory: Path, as_json: bool) -> Verdict:
    """A dataset's summary (scans, splits, noise levels, sensor, terrain, labels; every file checked)
    or a run's (profile, training data and noise, epochs, metrics); as one JSON object with ``as_json``."""
    from hdnet.run_summary import describe_run, is_run_dir, run_record
    from lidarsim.inspect import INTACT_STATUS, damaged_message, damaged_status, dataset_record, describe_dataset
    from lidarsim.shards import MANIFEST_NAME, verify_dataset

    if is_run_dir(directory) and not (directory / MANIFEST_NAME).exists():
        return Verdict([json.dumps(run_record(directory)) if as_json else describe_run(directory)])
    summary = describe_dataset(directory)
    problems = verify_dataset(directory, known_schemas=known_schemas())
    failure = damaged_message(directory, problems) if problems else None
    if as_json:
        return Verdict(
            [json.dumps({**dataset_record(directory), "intact": not problems, "problems": problems})], [], failure
        )
    if problems:
        return Verdict([summary], damaged_status(problems), failure)
    return Verdict([summary, INTACT_STATUS])


def verify_directory(directory: Path, recipe: Path | None) -> Verdict:
    """Every file of a dataset against the manifest's checksums and the schema versions; with
    ``recipe``, also against the recipe's published build (identical, or equal within the
    tolerances of its content fingerprints)."""
    from lidarsim.published import compare_with_recipe
    from lidarsim.shards import read_manifest, verify_dataset

    problems = verify_dataset(directory, known_schemas=known_schemas())
    out: list[str] = []
    published = None
    if recipe is not None:
        published = compare_with_recipe(directory, recipe, content=not problems)
        out += published.verdicts
        problems += published.problems
    if problems:
        return Verdict(out, list(problems), f"{directory}: {len(problems)} problem(s) found")
    manifest = read_manifest(directory)
    n_files = len(manifest["shards"]) + sum(len(lab.get("shards", [])) for lab in manifest.get("labelings", []))
    against = f"; {published.summary()}" if published is not None else ""
    out.append(f"{directory}: OK, {n_files} files match the manifest's checksums and schema versions{against}")
    return Verdict(out)
