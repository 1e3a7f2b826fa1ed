"""lidarsim — Blender-free flash-LiDAR simulation over planetary terrain.

DTM in (GeoTIFF, HiRISE PDS3, or the procedural Mars terrain), clean and noisy point
clouds out, streamed into the documented, versioned HDF5 shard format.

Its public names are in docs/api.md. ``lidarsim.make_dtm`` is the function, whatever was imported
first (``import lidarsim.make_dtm as m`` gives it too); the module of that name is
``importlib.import_module("lidarsim.make_dtm")``.
"""

from hdcore.exports import lazy_exports

# The public names are listed once, in __init__.pyi (docs/api.md), and imported on first use.
__all__, __getattr__, __dir__ = lazy_exports(__name__, __file__)
