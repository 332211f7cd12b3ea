r"""The linear contact model's range of validity, before a run: how deep an impact goes.

The linear spring-dashpot law (``dem/contact.py``) stands for a contact whose overlap is small
against the spheres that touch; the engine ends a run ``invalid`` once an overlap passes
``OVERLAP_LIMIT`` of a sphere radius while the step resolves the contact (``dem/simulation.py``).
Whether that happens is decided by the hardest impact: a body of mass m hitting a wall at speed
v with the pair's stiffness K and damping ratio zeta (from e) compresses to

    delta_max = (v / omega_0) g(zeta),   omega_0 = sqrt(K / m),

where g is the peak of x'' + 2 zeta x' + x = 0, x(0) = 0, x'(0) = 1: ``exp(-zeta t*)`` with
``t* = atan2(sqrt(1 - zeta^2), zeta) / sqrt(1 - zeta^2)`` below critical damping (g = 1 without
damping), and the two-exponential peak above it. The clamp against attraction does not matter
here: the force is compressive all the way to the peak. Inverting for ``delta_max = limit r``
gives the softest E for which that impact stays valid; ``K = E D / 2`` against a wall of the same
material.

The length the limit is a fraction of (``overlap_scale``) is a clump's smallest sphere radius and a
rounded polyhedron's rounding r: its cores are r_a + r_b apart at contact, and the closest
features that give the normal are those of the cores, so the overlap must stay a fraction of r
(the kernels compare with the ``rounding`` column, which is a clump sphere's radius).

The mass m behind the hardest impact (``impact_mass``) is where the two representations differ.
A clump's faces are rows of bumps: whatever its orientation, it first lands on one sphere off
the line through its centre of mass, and turns as that contact pushes, so the impact is carried
by its smallest effective mass (``dem.timestep.effective_mass``, a corner's). A rounded
polyhedron's face is flat and is one contact (``dem/rounded_contact.py``) whose crowned point
lies under the centre of mass when the face lands level: nothing turns, the whole mass
compresses the one spring K, and its overlap may reach only ``OVERLAP_LIMIT`` of r, which is a
quarter of the item's thinnest dimension (2 mm on a phone, against the 3.65 mm of the clump's
smallest sphere). The feeder's insertion places items edge-down into the gaps between the items
already in (a narrow footprint fits lowest), and such a landing is what ended runs ``invalid``:
a phone of the full feeder (seed 3, E = 1e7 Pa, e 0.5) standing on its 8 mm side face, tilted
0.4 deg from level, hit the floor at 2.0 m/s and slowed from 1.99 to 0.68 m/s turning at only 7
rad/s when its overlap passed 0.5 r; m v^2 / (K (0.5 r)^2) g^2 with its mass gives 1.3e7 Pa for
that impact, what the run's message asked for, where its effective mass (0.028 of 0.172 kg)
gives 2.2e6 Pa. The energy bound says the same: the spring can take at most the body's whole
kinetic energy, 1/2 K delta^2 <= 1/2 m v^2, so m is the safe choice, and the flat face reaches it.
"""

from __future__ import annotations

import math

from dem.clump import Clump
from dem.contact import damping_ratio, wall_stiffness
from dem.polyhedra import Polyhedron
from dem.result import OVERLAP_LIMIT
from dem.timestep import effective_mass


def impact_mass(shape: Clump | Polyhedron) -> float:
    """The mass (kg) behind this body's hardest impact on a wall: its whole mass for a rounded
    polyhedron (a face landing level), its smallest effective mass for a clump (a corner)."""
    if isinstance(shape, Polyhedron):
        return float(shape.mass)
    return effective_mass(shape)


def overlap_scale(shape: Clump | Polyhedron) -> float:
    """The length (m) that ``OVERLAP_LIMIT`` is a fraction of for this body's contacts."""
    if isinstance(shape, Polyhedron):
        return float(shape.rounding)
    return float(min(shape.radius))


def peak_factor(zeta: float) -> float:
    """g(zeta): the peak overlap of a damped linear impact in units of v / omega_0."""
    if zeta <= 0.0:
        return 1.0
    if abs(zeta - 1.0) < 1e-9:
        return math.exp(-1.0)
    if zeta < 1.0:
        wd = math.sqrt(1.0 - zeta * zeta)
        return math.exp(-zeta * math.atan2(wd, zeta) / wd)
    root = math.sqrt(zeta * zeta - 1.0)
    r1, r2 = -zeta + root, -zeta - root
    t = math.log(r2 / r1) / (r1 - r2)
    return (math.exp(r1 * t) - math.exp(r2 * t)) / (r1 - r2)


def peak_overlap(speed: float, mass: float, stiffness: float, e: float) -> float:
    """Deepest overlap (m) of an impact at ``speed`` of ``mass`` on a spring of ``stiffness``."""
    return speed * math.sqrt(mass / stiffness) * peak_factor(damping_ratio(e))


def softest_valid_E(
    speed: float, mass: float, diameter: float, radius: float, e: float, limit: float = OVERLAP_LIMIT
) -> float:
    """The E below which a body (mass, contact diameter D, ``overlap_scale`` r) hitting a wall of
    its own material at ``speed`` overlaps more than ``limit`` r."""
    # delta_max scales as 1 / sqrt(K) and K = E D / 2 is linear in E.
    reference = 1.0
    depth = peak_overlap(speed, mass, wall_stiffness(reference, diameter, reference), e)
    return reference * (depth / (limit * radius)) ** 2
