"""What every elastic, frictionless collision test checks (issue 12): kinetic energy within 0.5 %,
linear and angular momentum to 1e-10 relative, once the bodies have met and parted."""

from __future__ import annotations

import numpy as np
import pytest

from dem.simulation import Simulation


def momenta(sim: Simulation) -> tuple[np.ndarray, np.ndarray]:
    """Total linear momentum and angular momentum about the origin."""
    b = sim.bodies
    linear = (b.mass[:, None] * b.vel).sum(axis=0)
    angular = (np.cross(b.pos, b.mass[:, None] * b.vel) + b.angmom).sum(axis=0)
    return linear, angular


def assert_collision_conserves_energy_and_momenta(sim: Simulation, duration: float = 0.15) -> None:
    """Runs sim for ``duration`` simulated s, long enough for its bodies to meet and part."""
    e0 = sim.kinetic_energy()
    p0, l0 = momenta(sim)

    report = sim.run(duration)

    assert report.ok, report.message
    assert sim.n_contacts == 0, "the bodies must have separated"
    assert sim.kinetic_energy() == pytest.approx(e0, rel=0.005)
    p1, l1 = momenta(sim)
    assert np.abs(p1 - p0).max() <= 1e-10 * np.abs(sim.bodies.mass[:, None] * sim.bodies.vel).sum()
    assert np.abs(l1 - l0).max() <= 1e-10 * max(np.linalg.norm(l0), 1e-12)
