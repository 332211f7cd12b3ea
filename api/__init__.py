"""demcal's front doors and persistence: settings, CLI, REST API, store, dashboard.

This is the composition root: it may import every other package; nothing imports it.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("demcal")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"
