"""monoavatar: animatable, textured 3D avatars and 3D motion from monocular video."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("monoavatar")
except PackageNotFoundError:  # pragma: no cover - source tree without install
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
