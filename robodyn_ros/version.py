"""The package version, read from the installed distribution (setup.py takes it from package.xml)."""
from importlib.metadata import PackageNotFoundError, version as _version

try:
    __version__ = _version('robodyn_ros')
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = '0+unknown'
