"""lidarsim — Blender-free flash-LiDAR simulation over planetary terrain.

DTM in (GeoTIFF, HiRISE PDS3, or the procedural Mars terrain), clean and noisy point
clouds out, streamed into the documented, versioned HDF5 shard format.
"""

from lidarsim._version import __version__

__all__ = ["__version__"]
