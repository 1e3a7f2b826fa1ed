"""hdnet — Bayesian SegNet training, MC-dropout inference and evaluation for hazard detection.

Its public names are in docs/api.md. Three of them are functions named like their modules:
``hdnet.fit``, ``hdnet.evaluate`` and ``hdnet.detect`` are the functions, whatever was imported
first, so ``import hdnet.evaluate as m`` and ``from hdnet import evaluate`` give the function too.
Reach such a module (to read or monkeypatch its names) with
``importlib.import_module("hdnet.evaluate")``; ``from hdnet.evaluate import EvalConfig`` works as ever.
"""

from hdcore.exports import lazy_exports

# The public names are listed once, in __init__.pyi (docs/api.md), and imported on first use.
__all__, __getattr__, __dir__ = lazy_exports(__name__, __file__)
