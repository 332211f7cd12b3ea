"""Numba compilation flags for every kernel of the engine, kept in one place (as PySDM does).

``cache=True`` writes compiled kernels next to the sources so that a worker process pays the JIT
compile once per installation, not once per simulation. ``fastmath`` stays off: reassociation
would make results depend on the compiler's choices and break determinism across runs.
Numba's cache checks only the source file of the cached function, not the modules it calls (the
run loop in ``dem/loop.py`` calls kernels of ``dem/integrate.py``, ``dem/neighbours.py``,
``dem/forces.py``, ``dem/facets.py``, ``dem/contact.py``, ``dem/rounded_contact.py``,
``dem/kept_contact.py``, ``dem/crown.py``, ``dem/convex.py``, ``dem/motion.py``,
``dem/quaternion.py``):
after editing one of those in a working copy, delete ``dem/__pycache__/*.nb[ic]`` (installed
releases change every file at once, so they are safe).
This module imports nothing of the engine (every kernel module imports it), and of numba only
what says which options this release takes.
"""

from __future__ import annotations


def _numba_takes_nrt() -> bool:
    """Whether this numba takes the private ``_nrt`` option (0.59-0.68 do; tested on 0.68.1). A
    release without it compiles every kernel with its runtime: the same results, a slower step,
    and ``tests/dem/test_reference_counts.py`` fails to say so."""
    from numba.core.cpu import CPUTargetOptions
    from numba.core.options import TargetOptions

    return isinstance(getattr(CPUTargetOptions, "_nrt", None), TargetOptions.Mapping)


_RUNTIME_OPTION = _numba_takes_nrt()

JIT_FLAGS = dict(cache=True, fastmath=False, error_model="numpy", boundscheck=False)
if _RUNTIME_OPTION:
    JIT_FLAGS["_nrt"] = True

# The step loop (``dem.loop._steps``), ``compute_forces``, ``evaluate_into`` and the contact
# geometry kernels that allocate nothing (``dem/convex.py``, ``dem/crown.py``,
# ``dem/rounded_contact.py``, GJK in the caller's scratch ``gjk_query``; not ``gjk_distance`` nor
# the facet's triangles one by one, ``_facet_triangles``, which allocate) are compiled
# without numba's runtime (``_nrt=False``): no atomic reference count up and down for each array
# they bind (their container arguments, every ``bodies.pos`` read, every view), which numba's
# pruning left at about 150 pairs a step, 97 % of a one-sphere step (``benchmarks/README.md``,
# engine speed session 9), and about 40 a touching piece pair (polyhedra session 12). Safe
# because they only borrow: they allocate nothing (numba refuses to compile an allocation without
# the runtime) and return no array, and each compiled function they call balances its own counts
# (which is why ``JIT_FLAGS`` sets ``_nrt=True`` explicitly: a callee compiled for a caller
# inherits the caller's setting unless it sets its own). The results are the same to the bit.
STEP_FLAGS = dict(JIT_FLAGS, _nrt=False) if _RUNTIME_OPTION else dict(JIT_FLAGS)
