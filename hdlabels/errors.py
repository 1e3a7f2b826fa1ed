"""Errors raised by hdlabels for bad input: one-line messages that name the problem."""

from __future__ import annotations


class HdLabelsError(ValueError):
    """Base class of every error hdlabels raises for bad input (a lander, a DEM, a point cloud)."""
