"""gazehdr, a gaze-adaptive HDR display. `__version__` is the installed distribution's version
(`gazehdr --version` prints it); imports nothing of gazehdr, so `import gazehdr.drivers` stays
light on a tracker machine."""

from importlib.metadata import PackageNotFoundError, version

#: What `__version__` says when the code runs from a source tree that was never installed.
NOT_INSTALLED = "unknown (the gazehdr distribution is not installed: pip install -e .)"

try:
    __version__ = version("gazehdr")
except PackageNotFoundError:
    __version__ = NOT_INSTALLED
