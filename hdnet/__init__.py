"""hdnet — Bayesian SegNet training, MC-dropout inference and evaluation for hazard detection."""

from hdnet._version import __version__

__all__ = ["__version__"]
