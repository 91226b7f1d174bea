"""The installed twincd's version (what files and logs it writes record), in a module that imports
nothing of twincd, so that every stage can name it without importing the package's root."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("twincd")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"
