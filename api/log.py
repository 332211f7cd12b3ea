"""Logging as a service operator expects it: one line per event on stderr, level from settings.

Library code only calls ``logging.getLogger(__name__)``; this is the one place that configures it.
"""

from __future__ import annotations

import logging
import sys

FORMAT = "%(asctime)s %(levelname)-7s %(name)s: %(message)s"


def configure_logging(level: str = "INFO") -> None:
    """Send every logger's records to stderr as single lines; quiet chatty libraries."""
    root = logging.getLogger()
    root.handlers.clear()
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(FORMAT, datefmt="%Y-%m-%dT%H:%M:%S"))
    root.addHandler(handler)
    root.setLevel(level)
    for noisy in ("numba", "matplotlib", "PIL", "trimesh", "urllib3"):
        logging.getLogger(noisy).setLevel(max(logging.WARNING, root.level))
