"""Energy of elastic, frictionless collisions of rounded boxes in random orientations (issue 12):
the check that ``benchmarks/shape_fidelity.py`` makes for a few set angles, over many.

    NUMBA_NUM_THREADS=1 python -m benchmarks.polyhedra_energy [--cases 12] [--seed 1] [--dt-fraction 0.05]

Two 40 x 30 x 10 mm boxes with edges rounded by 2 mm (``Polyhedron.box``), E = 1e7 Pa, e = 1,
mu = 0, meet along x at 0.5 m/s each; the second is turned by 0, 1, 5 or 45 deg (in turn) about a
random axis and shifted sideways at random (numpy default_rng(seed)). Prints each collision's
kinetic energy change and the largest; the requirement is 0.5 %.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from dem.contact import ContactParams
from dem.polyhedra import Polyhedron
from dem.quaternion import from_axis_angle
from dem.simulation import Simulation
from dem.timestep import DEFAULT_FRACTION

BOX = Polyhedron.box((0.04, 0.03, 0.01), 0.002, 1000.0)
ANGLES_DEG = (0.0, 1.0, 5.0, 45.0)


def collision(axis, angle_deg: float, shift, dt_fraction: float) -> float:
    """Relative change of kinetic energy over one collision."""
    sim = Simulation(
        ContactParams(E=1e7, nu=0.3, e=1.0, mu=0.0),
        gravity=(0, 0, 0),
        domain_min=(-1, -1, -1),
        domain_max=(1, 1, 1),
        dt_fraction=dt_fraction,
    )
    sim.add_body(BOX, (-0.025, 0, 0), velocity=(0.5, 0, 0))
    turn = from_axis_angle(axis, math.radians(angle_deg))
    sim.add_body(BOX, (0.03, shift[0], shift[1]), quaternion=turn, velocity=(-0.5, 0, 0))
    before = sim.kinetic_energy()
    sim.run(0.1)
    if sim.n_contacts:
        raise RuntimeError("the boxes are still in contact; run longer")
    return sim.kinetic_energy() / before - 1.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--cases", type=int, default=12)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--dt-fraction", type=float, default=DEFAULT_FRACTION)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    worst = 0.0
    for k in range(args.cases):
        angle = ANGLES_DEG[k % len(ANGLES_DEG)]
        axis = rng.normal(size=3)
        shift = (rng.uniform(-0.008, 0.008), rng.uniform(-0.004, 0.004))
        change = collision(axis, angle, shift, args.dt_fraction)
        worst = max(worst, abs(change))
        direction = np.round(axis / np.linalg.norm(axis), 2)
        print(f"{angle:4.0f} deg about {direction}: {100 * change:+.2f} %", flush=True)
    print(f"largest |change| {100 * worst:.2f} % (requirement 0.5 %)")


if __name__ == "__main__":
    main()
