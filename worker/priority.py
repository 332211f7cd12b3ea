"""Workers run DEM at a lower CPU priority than the API: a trial is batch work that may take
seconds longer, while a dashboard poll waits for a core in front of a person.

Two busy workers on a 2-core laptop otherwise take the cores from ``demcal serve``'s API at equal
priority, and every poll of an open dashboard queues behind them (``benchmarks/README.md``, API
session 6). ``DEMCAL_WORKER_NICE`` (default ``DEFAULT_NICE``; 0 keeps the priority of whoever
started the worker) is added to the process's nice value at start, before the kernels' warm-up.

Linux schedules each session (a terminal, a service) as one group when ``autogroup`` is on (the
default on desktops): nice then orders the processes of one session only. The local pool's
workers are ``serve``'s own children, in its session, so they yield to its API; a ``demcal
worker`` started from another terminal competes with ``serve`` as a group, whatever its nice
value (``renice`` of the group, ``/proc/<pid>/autogroup``, or a service manager's CPU weight
orders groups).

Must not: raise priority (a process may only lower its own without privileges).
"""

from __future__ import annotations

import logging
import os

logger = logging.getLogger(__name__)

DEFAULT_NICE = 10


def lower_priority(increment: int) -> None:
    """Add ``increment`` (0-19) to this process's nice value; 0 leaves it as it is."""
    if increment <= 0:
        return
    now = os.nice(increment)
    logger.debug("worker %d: nice %d", os.getpid(), now)
