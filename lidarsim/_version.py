"""The installed hd distribution's version string (shared by the three packages)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("hd")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.1.0"
