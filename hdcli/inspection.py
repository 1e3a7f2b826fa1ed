"""``hd inspect`` and ``hd verify``: what they print about a dataset or a run, and whether it passes.

Each returns a :class:`Verdict`: the lines for standard output, then those for standard error, and
the one-line failure (None when the directory passes), which the command turns into its error.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from hdnet.errors import HdNetError


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


def inspect_directory(
    directory: Path | str, as_json: bool, plot: Path | None = None, labels: str | None = None, overwrite: bool = False
) -> Verdict:
    """A dataset's summary (scans, splits, noise levels, sensor, terrain, labels; every file checked)
    or a run's (profile, training data and noise, epochs, metrics); as one JSON object with ``as_json``.

    ``plot``: also draw the dataset at a glance into that file (``hdnet.dataset_figure``), with the
    labelling ``labels`` names (default: the dataset's only one), replacing an existing file only
    with ``overwrite``; written only when every file of the dataset is intact. The figure's path,
    its labelling and the dataset are checked before anything is read.

    Raises:
        HdNetError / StorageError / LabelStoreError / OutputExistsError: ``labels`` or ``overwrite``
            without ``plot``, ``plot`` for a run, a figure path that cannot be used (another
            suffix, inside the dataset, an existing file), an unknown labelling; as the summaries
            for a directory that is neither a dataset nor a run.
    """
    from hdnet.run_summary import describe_run, is_run_dir, run_record
    from lidarsim.inspect import INTACT_STATUS, damaged_message, damaged_status, dataset_record, describe_dataset
    from lidarsim.location import dataset_label, is_url
    from lidarsim.shards import MANIFEST_NAME, verify_dataset

    if plot is None and (labels is not None or overwrite):
        raise HdNetError("--labels and --overwrite go with --plot FILE (the figure's labelling, and replacing it)")
    if is_url(directory) and plot is not None:
        raise HdNetError(
            f"{dataset_label(directory)} is a URL: --plot draws a local dataset; `hd pull` copies it here first"
        )
    local = None if is_url(directory) else Path(directory)
    if local is not None and is_run_dir(local) and not (local / MANIFEST_NAME).exists():
        if plot is not None:
            raise HdNetError(f"{directory} is a run: --plot draws a dataset at a glance; give a dataset directory")
        return Verdict([json.dumps(run_record(local)) if as_json else describe_run(local)])
    labeling = None
    if plot is not None:
        from hdnet.dataset_figure import check_figure_path, chosen_labeling

        labeling = chosen_labeling(directory, labels)  # a bad directory or labelling, refused first
        check_figure_path(directory, plot, overwrite)
    summary = describe_dataset(directory)
    problems = verify_dataset(directory, known_schemas=known_schemas())
    failure = damaged_message(directory, problems) if problems else None
    figure: dict[str, object] | None = None
    lines = [summary]
    if plot is not None and not problems:
        from hdnet.dataset_figure import dataset_overview, write_dataset_figure

        overview = dataset_overview(directory, labeling)
        write_dataset_figure(overview, plot)
        figure = overview.record(plot)
        lines.append(overview.summary(plot))
    if as_json:
        record = {**dataset_record(directory), "intact": not problems, "problems": problems}
        if plot is not None:
            record["figure"] = figure
        return Verdict([json.dumps(record)], [], failure)
    if problems:
        unwritten = [f"figure    not written ({plot}): the dataset is damaged"] if plot is not None else []
        return Verdict([summary], damaged_status(problems) + unwritten, failure)
    return Verdict([*lines, INTACT_STATUS])


def verify_directory(directory: Path | str, recipe: Path | None) -> Verdict:
    """Every file of a dataset against the manifest's checksums and the schema versions; with
    ``recipe``, also against the recipe's published build (identical, or equal within the
    tolerances of its content fingerprints)."""
    from lidarsim.location import dataset_label, is_url
    from lidarsim.published import compare_with_recipe
    from lidarsim.shards import read_manifest, verify_dataset

    problems = verify_dataset(directory, known_schemas=known_schemas())
    out: list[str] = []
    published = None
    if recipe is not None:
        # At a URL only the sha256 are compared (rebuilt files' fingerprints are read from a local copy).
        published = compare_with_recipe(directory, recipe, content=not problems and not is_url(directory))
        out += published.verdicts
        problems += published.problems
    if problems:
        return Verdict(out, list(problems), f"{dataset_label(directory)}: {len(problems)} problem(s) found")
    manifest = read_manifest(directory)
    n_files = len(manifest["shards"]) + sum(len(lab.get("shards", [])) for lab in manifest.get("labelings", []))
    against = f"; {published.summary()}" if published is not None else ""
    out.append(
        f"{dataset_label(directory)}: OK, {n_files} files match the manifest's checksums and schema versions{against}"
    )
    return Verdict(out)
