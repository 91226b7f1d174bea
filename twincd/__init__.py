"""twincd: robot-arm collision detection in recorded ROS 2 logs with a digital twin."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("twincd")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
