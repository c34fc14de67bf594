"""The installed distribution's version (``0.0.0+checkout`` in a source checkout)."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("hallray")
except PackageNotFoundError:  # running from a source checkout
    __version__ = "0.0.0+checkout"
