"""The step loop and ``compute_forces`` are compiled without numba's runtime (``dem/conf.py``:
``STEP_FLAGS``): they must leave every array's reference count as they found it. A compiled call
from them that returned an array (a new reference nobody releases) would keep the simulation's
arrays alive for ever: one more reference per call, seen here on the arrays' Python objects."""

from __future__ import annotations

import sys

import numpy as np

from dem.clump import Clump
from dem.contact import ContactParams
from dem.motion import SinusoidalTranslation
from dem.polyhedra import Polyhedron
from dem.simulation import Simulation
from dem.walls import WallMesh

PARAMS = ContactParams(E=1e6, nu=0.3, e=0.5, mu=0.5)


def _arrays(value, out: dict[int, np.ndarray]) -> None:
    if isinstance(value, np.ndarray):
        out[id(value)] = value
    elif isinstance(value, tuple):
        for item in value:
            _arrays(item, out)


def _state_arrays(sim: Simulation) -> dict[int, np.ndarray]:
    out: dict[int, np.ndarray] = {}
    for holder in (sim.bodies, sim.spheres):
        for value in vars(holder).values():
            _arrays(value.base if isinstance(value, np.ndarray) and value.base is not None else value, out)
    for value in (sim._run, sim._settings, sim._walls, sim._lists):
        _arrays(value, out)
    return out


def _tray() -> Simulation:
    """A shaken open tray with spheres, a clump and a rounded box on it and spheres that fall off
    its open end out of the domain: wall pairs, sphere pairs, piece pairs, list rebuilds, bodies
    leaving."""
    sim = Simulation(PARAMS, domain_min=(-0.05, -0.05, -0.03), domain_max=(0.3, 0.15, 0.2), seed=3)
    vertices = np.array(
        [[0, 0, 0], [0.2, 0, 0], [0.2, 0.1, 0], [0, 0.1, 0], [0, 0, 0.05], [0, 0.1, 0.05]], float
    )
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 5], [0, 5, 4]], dtype=np.int64)
    sim.add_wall(WallMesh(vertices, faces, motion=SinusoidalTranslation((0.9, 0.0, 0.42), 1e-3, 40.0)))
    ball = Clump.solid_sphere(0.005, 2500.0)
    for k in range(12):
        sim.add_body(ball, (0.02 + 0.012 * (k % 6), 0.03 + 0.03 * (k // 6), 0.0052), velocity=(0.4, 0, 0))
    for k in range(4):  # past the open end: they fall out of the domain
        sim.add_body(ball, (0.21 + 0.011 * k, 0.05, 0.01))
    sim.add_body(Clump.solid_sphere(0.004, 2500.0), (0.05, 0.07, 0.016))
    sim.add_body(Polyhedron.box((0.02, 0.015, 0.01), 0.002, 1000.0), (0.1, 0.05, 0.0055))
    return sim


def test_step_loop_keeps_reference_counts() -> None:
    sim = _tray()
    for t in (0.002, 0.004, 0.006):  # compiled or loaded, lists sized: Python's own references settled
        assert sim.run(t, chunk_time=0.002).ok
    before = _state_arrays(sim)
    counts = {k: sys.getrefcount(before[k]) for k in before}
    for k in range(1, 16):
        assert sim.run(0.006 + 0.01 * k, chunk_time=0.002).ok
    assert len(sim.removed_out_of_domain) >= 4
    kept = [k for k in before if k in _state_arrays(sim)]  # the arrays still in use
    assert len(kept) > 40
    now = {k: sys.getrefcount(before[k]) for k in kept}  # measured as ``counts`` was
    assert {k: (counts[k], now[k]) for k in kept if now[k] != counts[k]} == {}


def test_the_step_flags_turn_the_runtime_off_where_numba_takes_the_option():
    from dem import conf

    assert conf.STEP_FLAGS["_nrt"] is False and conf.JIT_FLAGS["_nrt"] is True


def test_a_numba_without_the_private_runtime_option_compiles_the_step_with_its_runtime(monkeypatch):
    """``_nrt`` is private: a numba release that drops it must still compile the engine (slower,
    the same results), not fail with numba's "Unrecognized options"."""
    import importlib

    import numba
    from numba.core.cpu import CPUTargetOptions

    from dem import conf

    monkeypatch.setattr(CPUTargetOptions, "_nrt", None, raising=False)  # hides the base's mapping
    try:
        reloaded = importlib.reload(conf)
        assert "_nrt" not in reloaded.STEP_FLAGS and "_nrt" not in reloaded.JIT_FLAGS
        flags = dict(reloaded.STEP_FLAGS, cache=False)
        total = numba.njit(**flags)(lambda values: values.sum())
        assert total(np.arange(4.0)) == 6.0
    finally:
        monkeypatch.undo()
        importlib.reload(conf)
