"""Errors raised by hdlabels for bad input: one-line messages that name the problem.

hdlabels' hierarchy sits under hd's root error, ``hdcore.errors.HdError`` (documented there).
"""

from __future__ import annotations

from hdcore.errors import HdError


class HdLabelsError(HdError):
    """Base class of every error hdlabels raises for bad input (a lander, a DEM, a point cloud)."""


class LabelStoreError(HdLabelsError):
    """A dataset without the requested labels, or a label shard of an unknown format."""
