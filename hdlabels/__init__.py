"""hdlabels — point clouds to DEMs, ALHAT deterministic labels and the probabilistic baseline."""

from hdcore.exports import lazy_exports

# The public names are listed once, in __init__.pyi (docs/api.md), and imported on first use.
__all__, __getattr__, __dir__ = lazy_exports(__name__, __file__)
