"""lead_s2r: sim-to-real multi-dataset training for end-to-end driving."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("lead-s2r")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0"
