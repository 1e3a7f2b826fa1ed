"""hdnet — Bayesian SegNet training, MC-dropout inference and evaluation for hazard detection."""

from hdcore.exports import lazy_exports

# The public names are listed once, in __init__.pyi (docs/api.md), and imported on first use.
__all__, __getattr__, __dir__ = lazy_exports(__name__, __file__)
