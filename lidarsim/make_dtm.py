"""``hd make-dtm``: the procedural Mars terrain as a GeoTIFF, or a real DTM's relief with the rocks.

:class:`DtmSettings` describes the command's settings once (options, checks); :func:`make_dtm`
writes the file and returns its one-line summary.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from hdcore.setting import NonEmptyPath, check, setting
from lidarsim import defaults, limits
from lidarsim import terrain_defaults as td
from lidarsim.errors import LidarsimError

if TYPE_CHECKING:
    from lidarsim.procedural import MarsTerrainParams


@dataclass(frozen=True)
class DtmSettings:
    """The settings of ``hd make-dtm`` (None: the procedural terrain's own, ``terrain_defaults``)."""

    seed: int = setting(defaults.SEED, "Seed of the procedural terrain", bound=limits.SEED)
    size_m: float | None = setting(
        None,
        "Side of the square terrain (default: the built-in size)",
        unit="metres",
        bound=limits.TERRAIN_SIZE_M,
        flag="--size",
    )
    spacing_m: float | None = setting(
        None, "Grid spacing", unit="metres/pixel", bound=limits.TERRAIN_SPACING_M, flag="--spacing"
    )
    rock_k: float | None = setting(
        None, f"Golombek-Rapp rock abundance k: 0 (no rocks) or from {td.ROCK_K_MIN:g}", bound=limits.ROCK_K
    )
    base_path: Path | None = setting(
        None,
        "A real DTM (e.g. HiRISE) whose relief replaces the procedural one: resampled to --spacing, with the "
        "procedural rocks added (its CRS and corner are kept)",
        kind=Path,
        flag="--base",
        click_type=NonEmptyPath(exists=True, dir_okay=False, path_type=Path),
    )
    craters_below_m: float | None = setting(
        None,
        "With --base: also add fresh craters of 2 m up to this diameter, below the base's resolution",
        unit="metres",
        bound=limits.CRATER_DIAMETER_M,
        flag="--craters-below",
    )

    def __post_init__(self) -> None:
        check(self, LidarsimError)


def make_dtm(out_path: str | os.PathLike, settings: DtmSettings | None = None, overwrite: bool = False) -> str:
    """Write the terrain of ``settings`` (default: ``DtmSettings()``, the procedural terrain) to
    ``out_path`` (a GeoTIFF, heights in metres); returns what was written, in one line.

    Raises:
        LidarsimError: an unusable ``out_path``, an existing file without ``overwrite``, options
            that exclude each other, before anything is written.
    """
    from hdcore.storage import check_not_input, check_output_file
    from lidarsim.procedural import MarsTerrainParams, write_procedural_dtm

    out_path = Path(out_path)
    settings = settings if settings is not None else DtmSettings()
    base_path, craters_below_m = settings.base_path, settings.craters_below_m
    check_output_file(out_path, "OUT_PATH")
    if base_path is not None:
        check_not_input(out_path, {"the base DTM": base_path}, "OUT_PATH")
    if out_path.exists() and not overwrite:
        raise LidarsimError(f"{out_path} exists; pass --overwrite to replace it")
    changes = {k: getattr(settings, k) for k in ("size_m", "spacing_m", "rock_k") if getattr(settings, k) is not None}
    if base_path is None and craters_below_m is not None:
        raise LidarsimError("--craters-below needs --base (the procedural terrain has its own craters)")
    if base_path is not None:
        if settings.size_m is not None:
            raise LidarsimError("--size and --base exclude each other: the base DTM gives the size")
        if craters_below_m is not None:
            changes["crater_d_max_m"] = craters_below_m
        params = dataclasses.replace(MarsTerrainParams(), **changes)
        return _make_rocky_dtm(out_path, Path(base_path), params, settings.seed, craters_below_m)
    params = dataclasses.replace(MarsTerrainParams(), **changes)
    heights = write_procedural_dtm(out_path, params, settings.seed)
    return (
        f"wrote {out_path}: {heights.shape[0]} x {heights.shape[1]} cells at {params.spacing_m:g} m/px, "
        f"heights {float(heights.min()):.1f} .. {float(heights.max()):.1f} m"
    )


def _make_rocky_dtm(
    out_path: Path, base_path: Path, params: MarsTerrainParams, seed: int, craters_below_m: float | None
) -> str:
    """``hd make-dtm --base``: the base's relief resampled, with rocks (and small craters)."""
    from lidarsim.base_relief import rocks_on_base, write_rocky_dtm

    terrain = rocks_on_base(base_path, params, seed, params.spacing_m, craters=craters_below_m is not None)
    write_rocky_dtm(out_path, terrain)
    rows, cols = terrain.heights.shape
    return (
        f"wrote {out_path}: {base_path.name} at {terrain.spacing_m:g} m/px ({rows} x {cols} cells) with "
        f"{terrain.n_rocks} rocks (k = {params.rock_k:g})"
        + (
            f" and {terrain.n_craters} craters of {params.crater_d_min_m:g}-{params.crater_d_max_m:g} m"
            if craters_below_m
            else ""
        )
    )
