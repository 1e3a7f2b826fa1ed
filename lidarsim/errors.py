"""lidarsim's errors, under hd's root error :class:`hdcore.errors.HdError` (the whole hierarchy is
documented there)::

    LidarsimError              every error lidarsim raises for bad input or bad files
    ├── TerrainError           a DTM file or terrain request that cannot be used
    └── RecipeError            a dataset recipe that cannot be read or holds invalid settings
"""

from __future__ import annotations

from hdcore.errors import HdError


class LidarsimError(HdError):
    """Base class of every error lidarsim raises for bad input or bad files."""


class TerrainError(LidarsimError):
    """A DTM file or terrain request that cannot be used (message names the file and the problem)."""


class RecipeError(LidarsimError):
    """A recipe that cannot be read or holds unknown or invalid settings."""
