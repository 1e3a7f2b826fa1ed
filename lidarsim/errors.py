"""Errors raised by lidarsim for bad input: one-line messages that name the problem."""

from __future__ import annotations


class LidarsimError(ValueError):
    """Base class of every error lidarsim raises for bad input or bad files."""


class TerrainError(LidarsimError):
    """A DTM file or terrain request that cannot be used (message names the file and the problem)."""
