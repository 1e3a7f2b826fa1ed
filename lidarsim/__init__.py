"""lidarsim — Blender-free flash-LiDAR simulation over planetary terrain.

DTM in (GeoTIFF, HiRISE PDS3, or the procedural Mars terrain), clean and noisy point
clouds out, streamed into the documented, versioned HDF5 shard format.
"""

from hdcore.exports import lazy_exports

# The public names are listed once, in __init__.pyi (docs/api.md), and imported on first use.
__all__, __getattr__, __dir__ = lazy_exports(__name__, __file__)
