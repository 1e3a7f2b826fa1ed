"""Writes the golden dataset of ``tests/data/golden/``: one tiny dataset in hd's public formats.

    python tests/data/make_golden.py            # rewrite tests/data/golden/ (commit the result)

The dataset pins the public file formats (``docs/shard-format.md``, ``docs/labels-format.md``):
``manifest.json``, one scan shard (schema ``hd.lidar-scans``), one label shard (schema
``hd.labels``) and the procedural terrain they were made on. ``tests/data/test_golden.py`` reads
the committed files with plain h5py and json, and checks that today's writers still produce the
same layout and the same values.

Values: the points (clean and noisy) and the DEM heights agree within 0.1 mm, the slope map within
1e-4 rad, P(safe) within 1e-4, and the labels, returns and splits exactly (the constants at the
end of ``test_golden.py``). A change of the sensor, the noise model, the gridding, the label rule
or the baseline therefore fails there. Rewrite the golden files only for a deliberate change: a
format change together with the schema version and the format documents; a change of values
together with the reason in the commit message (and, where published datasets change, their
recipes' versions and checksums).

Everything is seeded; the sizes are the smallest that exercise every field: 3 scans (one per
split) of a 24 x 24 detector at two noise levels, 80 m above a 48 m procedural terrain, labelled
on 12 x 12 DEMs of 1 m with a 5 m lander in the paper convention.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
GOLDEN = Path(__file__).resolve().parent / "golden"
# The files of the golden dataset, relative to it (the manifest names the same ones).
SCAN_SHARD = "shards/scans-00000.h5"
TERRAIN = "terrain/mars-procedural-seed7.tif"


def build_config():  # -> lidarsim.build.BuildConfig
    """The golden dataset's build settings."""
    from lidarsim.build import BuildConfig
    from lidarsim.procedural import MarsTerrainParams
    from lidarsim.sensor import SensorConfig
    from lidarsim.trajectory import TrajectoryConfig

    return BuildConfig(
        sigmas_m=(0.0167, 0.07),
        seed=7,
        sensor=SensorConfig(rows=24, cols=24),
        trajectory=TrajectoryConfig(n_scans=3, altitude_m=80.0),
        terrain=MarsTerrainParams(size_m=48.0, spacing_m=0.5),
        shard_size=3,
    )


def label_settings():  # -> hdlabels.settings.LabelSettings
    """The golden dataset's labelling."""
    from hdlabels.settings import LabelSettings

    return LabelSettings(lander_diameter_m=5.0, pad_diameter_m=1.0, dem_size=12, dem_spacing_m=1.0)


def make_golden(out_dir: Path) -> Path:
    """Build and label the golden dataset in ``out_dir`` (which must not exist); returns it."""
    from hdlabels.labeling import label_dataset
    from lidarsim.build import build_dataset

    settings = label_settings()
    build_dataset(out_dir, build_config(), workers=1)
    label_dataset(out_dir, settings, workers=1)
    return out_dir


def main() -> None:
    sys.path.insert(0, str(REPO))
    with tempfile.TemporaryDirectory() as tmp:
        built = make_golden(Path(tmp) / "golden")
        shutil.rmtree(GOLDEN, ignore_errors=True)
        shutil.copytree(built, GOLDEN, ignore=shutil.ignore_patterns(".hd-*"))
    for path in sorted(GOLDEN.rglob("*")):
        if path.is_file():
            print(f"{path.relative_to(REPO)}  {path.stat().st_size} bytes")


if __name__ == "__main__":
    main()
