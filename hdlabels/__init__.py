"""hdlabels — point clouds to DEMs, ALHAT deterministic labels and the probabilistic baseline."""

from hdlabels._version import __version__

__all__ = ["__version__"]
