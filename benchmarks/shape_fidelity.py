"""Shape fidelity (issue 12): how far each representation departs from the item meshes, and how
much kinetic energy elastic, frictionless box collisions gain or lose.

    NUMBA_NUM_THREADS=1 python benchmarks/shape_fidelity.py

Gaps: largest and mean distance from the smartphone mesh's surface to the shape's surface
(clumps at 12, 24, 48 spheres; the rounded polyhedron). Collisions: two 40 mm cubes (a clump of
4 x 4 x 4 spheres, or a rounded polyhedron with r = 2 mm), e = 1, mu = 0, 0.5 m/s each, one of
them turned about z by the given angle and shifted sideways by half a sphere spacing.
"""

from __future__ import annotations

import math

import numpy as np

from dem.clump import Clump
from dem.clumping import clump_fit, make_clump
from dem.contact import ContactParams
from dem.polyhedra import Polyhedron, make_polyhedron, surface_gap
from dem.quaternion import from_axis_angle
from dem.scenarios.items import CATALOGUE
from dem.simulation import Simulation

ELASTIC = ContactParams(E=1e7, nu=0.3, e=1.0, mu=0.0)
SIDE = 0.04


def box_clump(side: float, per_side: int, density: float = 1000.0) -> Clump:
    radius = side / (2 * per_side)
    axis = (np.arange(per_side) - (per_side - 1) / 2) * 2 * radius
    offset = np.array(np.meshgrid(axis, axis, axis, indexing="ij")).reshape(3, -1).T
    mass = density * side**3
    return Clump(
        radius=np.full(len(offset), radius),
        offset=offset,
        mass=mass,
        inertia=np.full(3, mass * side**2 / 6),
        volume=side**3,
    )


def energy_change(body, angle_deg: float, shift: float) -> float:
    sim = Simulation(ELASTIC, gravity=(0, 0, 0), domain_min=(-1, -1, -1), domain_max=(1, 1, 1))
    sim.add_body(body, (-0.04, 0, 0), velocity=(0.5, 0, 0))
    sim.add_body(
        body,
        (0.04, shift, 0.5 * shift),
        quaternion=from_axis_angle((0, 0, 1), math.radians(angle_deg)),
        velocity=(-0.5, 0, 0),
    )
    before = sim.kinetic_energy()
    sim.run(0.2)
    return sim.kinetic_energy() / before - 1.0


def main() -> None:
    spec = CATALOGUE["smartphone"]
    mesh = spec.mesh()
    for n in (12, 24, 48):
        clump = make_clump(mesh, mass=spec.mass, n_spheres=n, cache_dir=False)
        fit = clump_fit(mesh, clump.com + clump.offset @ clump.axes.T, clump.radius)
        print(
            f"smartphone clump, {clump.n_spheres} spheres: max gap {fit.max_gap * 1e3:.1f} mm, "
            f"mean gap {fit.mean_gap * 1e3:.2f} mm"
        )
    poly = make_polyhedron(mesh, mass=spec.mass, pieces=spec.pieces())
    largest, mean = surface_gap(poly, mesh)
    print(
        f"smartphone rounded polyhedron, r {poly.rounding * 1e3:.1f} mm, {len(poly.core)} core vertices: "
        f"max gap {largest * 1e3:.2f} mm, mean gap {mean * 1e3:.3f} mm"
    )
    shapes = {
        "clump 4x4x4": box_clump(SIDE, 4),
        "clump 8x8x8": box_clump(SIDE, 8),
        "rounded polyhedron": Polyhedron.box((SIDE, SIDE, SIDE), 0.002, 1000.0),
    }
    print("kinetic energy change of an elastic frictionless collision, %:")
    print("| shape | face-on | face-on, rows staggered | turned 1 deg | turned 5 deg | turned 30 deg |")
    print("|---|---|---|---|---|---|")
    for name, body in shapes.items():
        spacing = SIDE / 4 if name != "clump 8x8x8" else SIDE / 8
        cases = [
            (0.0, 0.0),
            (0.0, 0.5 * spacing),
            (1.0, 0.5 * spacing),
            (5.0, 0.5 * spacing),
            (30.0, 0.5 * spacing),
        ]
        changes = [100 * energy_change(body, angle, shift) for angle, shift in cases]
        print(f"| {name} | " + " | ".join(f"{c:+.2f}" for c in changes) + " |")


if __name__ == "__main__":
    main()
