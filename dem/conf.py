"""Numba compilation flags for every kernel of the engine, kept in one place (as PySDM does).

``cache=True`` writes compiled kernels next to the sources so that a worker process pays the JIT
compile once per installation, not once per simulation. ``fastmath`` stays off: reassociation
would make results depend on the compiler's choices and break determinism across runs.
Numba's cache checks only the source file of the cached function, not the modules it calls (the
run loop in ``dem/loop.py`` calls kernels of ``dem/integrate.py``, ``dem/neighbours.py``,
``dem/forces.py``, ``dem/facets.py``, ``dem/contact.py``, ``dem/rounded_contact.py``,
``dem/crown.py``, ``dem/convex.py``, ``dem/motion.py``, ``dem/quaternion.py``):
after editing one of those in a working copy, delete ``dem/__pycache__/*.nb[ic]`` (installed
releases change every file at once, so they are safe).
This module must not import anything heavier than the standard library.
"""

from __future__ import annotations

JIT_FLAGS = dict(cache=True, fastmath=False, error_model="numpy", boundscheck=False)
