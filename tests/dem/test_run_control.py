"""Run control (issue 3, test 10 and the driver's contract): determinism, blow-ups end as
``unstable``, deadline, cancellation, bodies leaving the domain, walls grouped into facets."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from dem.clump import Clump
from dem.contact import ContactParams
from dem.simulation import Simulation, SimulationError
from dem.walls import WallMesh

PARAMS = ContactParams(E=1e6, nu=0.3, e=0.5, mu=0.5)


def ball(radius=0.005, density=2500.0) -> Clump:
    return Clump.solid_sphere(radius, density)


def dimer(radius=0.004) -> Clump:
    offset = np.array([[-0.004, 0, 0], [0.004, 0, 0]])
    mass = 1000 * 2 * 4 / 3 * math.pi * radius**3
    return Clump(
        radius=np.full(2, radius),
        offset=offset,
        mass=mass,
        inertia=np.array([0.4, 1.2, 1.2]) * mass * radius**2,
        volume=mass / 1000,
    )


def poured_box(seed: int, **kwargs) -> Simulation:
    sim = Simulation(PARAMS, domain_min=(-0.1, -0.1, -0.1), domain_max=(0.1, 0.1, 0.3), seed=seed, **kwargs)
    sim.add_wall(WallMesh.box((-0.04, -0.04, 0), (0.04, 0.04, 0.2)))
    jitter = sim.rng.uniform(-1e-3, 1e-3, size=(40, 3))
    for k in range(40):
        x, y, z = (k % 4) * 0.018 - 0.027, (k // 4 % 4) * 0.018 - 0.027, 0.01 + (k // 16) * 0.014
        sim.add_body(dimer() if k % 2 else ball(), np.array([x, y, z]) + jitter[k])
    return sim


def test_same_inputs_and_seed_give_identical_results():
    first, second = poured_box(seed=3), poured_box(seed=3)

    report = first.run(0.1)
    second.run(0.1)

    assert report.ok, report.message
    assert np.array_equal(first.bodies.pos, second.bodies.pos)
    assert np.array_equal(first.bodies.quat, second.bodies.quat)
    assert first.cost == second.cost and first.steps == second.steps


def test_absurd_forced_step_ends_unstable_without_exception():
    sim = poured_box(seed=1, dt=1e-2)

    report = sim.run(0.5)

    assert report.status == "unstable"
    assert report.t < 0.5
    assert "unstable at t=" in report.message


def test_deadline_in_the_past_times_out_and_cancel_cancels():
    sim = poured_box(seed=1)

    timed_out = sim.run(0.05, deadline=time.monotonic() - 1)
    cancelled = sim.run(0.05, chunk_time=0.005, should_stop=lambda: sim.t > 0.01)

    assert timed_out.status == "timeout" and timed_out.steps == 0
    assert cancelled.status == "cancelled"
    assert 0.01 < cancelled.t < 0.05


def test_body_leaving_the_domain_is_removed_and_reported():
    sim = Simulation(PARAMS, domain_min=(-0.1, -0.1, -0.1), domain_max=(0.1, 0.1, 0.1))
    sim.add_body(ball(), (0, 0, 0.0))
    sim.add_body(ball(), (0.05, 0, 0.0), velocity=(0, 0, 0))

    report = sim.run(0.2, chunk_time=0.01)

    # Free fall from z = 0 reaches z = -0.1 at t = sqrt(2 * 0.1 / g).
    assert report.ok
    assert [b for b, _ in sim.removed_out_of_domain] == [0, 1]
    assert sim.removed_out_of_domain[0][1] == pytest.approx(math.sqrt(0.2 / 9.81), abs=2 * sim.dt)
    assert not sim.bodies.active.any()


def test_removed_body_no_longer_interacts():
    sim = Simulation(PARAMS, gravity=(0, 0, 0), domain_min=(-1, -1, -1), domain_max=(1, 1, 1))
    a = sim.add_body(ball(), (0, 0, 0), velocity=(0.5, 0, 0))
    b = sim.add_body(ball(), (0.02, 0, 0))
    sim.remove_body(b)

    sim.run(0.1)

    assert sim.bodies.vel[a, 0] == pytest.approx(0.5, rel=1e-12)


def test_body_outside_domain_is_refused():
    sim = Simulation(PARAMS, domain_min=(0, 0, 0), domain_max=(1, 1, 1))

    with pytest.raises(SimulationError, match="outside the domain"):
        sim.add_body(ball(), (2, 0, 0))


def test_coplanar_triangles_form_one_facet_and_a_cube_six():
    square = WallMesh.plane((0, 0, 0), (0, 0, 1), 1.0)
    cube = WallMesh.box((0, 0, 0), (1, 1, 1), open_top=False)

    assert square.n_facets == 1
    assert cube.n_facets == 6


def test_sphere_rolling_over_the_shared_edge_of_coplanar_triangles_feels_one_force():
    # The square's diagonal is a shared edge: a sphere resting on it must have the same overlap
    # as anywhere else (a double force would halve it).
    sim = Simulation(PARAMS, domain_min=(-1, -1, -1), domain_max=(1, 1, 1))
    sim.add_wall(WallMesh.plane((0, 0, 0), (0, 0, 1), 0.2))
    body = ball()
    sim.add_body(body, (0.0, 0.0, 0.005))  # on the diagonal
    sim.add_body(body, (0.05, -0.03, 0.005))  # inside one triangle

    sim.run(0.3)

    static = body.mass * 9.81 / (PARAMS.E * 0.005)
    overlaps = 0.005 - sim.bodies.pos[:, 2]
    assert overlaps == pytest.approx([static, static], rel=1e-3)


def test_sphere_on_a_convex_edge_of_two_facets_feels_one_force():
    # A roof ridge along x: two facets meeting at z = 0 with slopes of +-45 degrees. A sphere
    # balanced on the ridge touches only the edge, which both facets share.
    vertices = np.array(
        [
            [-0.1, -0.1, -0.1],
            [0.1, -0.1, -0.1],
            [0.1, 0, 0],
            [-0.1, 0, 0],
            [0.1, 0.1, -0.1],
            [-0.1, 0.1, -0.1],
        ]
    )
    faces = np.array([[0, 1, 2], [0, 2, 3], [3, 2, 4], [3, 4, 5]])
    sim = Simulation(PARAMS, domain_min=(-1, -1, -1), domain_max=(1, 1, 1))
    sim.add_wall(WallMesh(vertices, faces))
    body = ball()
    sim.add_body(body, (0, 0, 0.005))

    sim.run(0.3)

    assert sim.walls[0].n_facets == 2
    assert 0.005 - sim.bodies.pos[0, 2] == pytest.approx(body.mass * 9.81 / (PARAMS.E * 0.005), rel=1e-3)


def test_stop_less_than_half_a_step_ahead_is_still_reached():
    sim = Simulation(PARAMS, dt=1e-4, domain_min=(-1, -1, -1), domain_max=(1, 1, 1))
    sim.add_body(ball(), (0.0, 0.0, 0.5))
    sim.run(until=0.01)
    stop = sim.t + 0.3 * sim.dt

    report = sim.run(until=stop)

    assert report.steps == 1
    assert sim.t >= stop


def _impact(E, e, speed, dt=None, chunk=None):
    """A sphere thrown at a floor without gravity; returns (simulation, report, deepest overlap)."""
    from dem.contact import ContactParams

    params = ContactParams(E=E, nu=0.3, e=e, mu=0.0)
    sim = Simulation(params, gravity=(0, 0, 0), domain_min=(-1, -1, -1), domain_max=(1, 1, 1), dt=dt)
    sim.add_wall(WallMesh.plane((0, 0, 0), (0, 0, 1), 0.4))
    body = Clump.solid_sphere(0.01, 2500.0)
    sim.add_body(body, (0, 0, 0.0100001), velocity=(0, 0, -speed))
    deepest = 0.0

    def watch(s):
        nonlocal deepest
        deepest = max(deepest, s.current_overlap())

    report = sim.run(0.006, chunk_time=chunk or sim.dt, on_chunk=watch)
    return sim, body, report, deepest


@pytest.mark.parametrize("e", [1.0, 0.5, 0.1])
def test_peak_overlap_of_an_impact_matches_the_damped_oscillator(e):
    from dem.validity import peak_overlap

    # A step well below the automatic one, so the discrete damping is within 0.1 % of the ODE's.
    sim, body, report, deepest = _impact(E=1e6, e=e, speed=0.5, dt=2.5e-6)

    expected = peak_overlap(0.5, body.mass, 0.01 * 1e6, e)  # K = E D / 2 = E r
    assert report.ok, report.message
    assert deepest * 0.01 == pytest.approx(expected, rel=2e-3)
    assert sim.max_overlap == pytest.approx(deepest)  # what a run reports: the deepest seen


def test_softest_valid_E_separates_valid_and_invalid_impacts():
    from dem.validity import softest_valid_E

    body = Clump.solid_sphere(0.01, 2500.0)
    threshold = softest_valid_E(2.0, body.mass, 0.02, 0.01, e=0.5)

    _, _, above, _ = _impact(E=1.3 * threshold, e=0.5, speed=2.0)
    sim, _, below, _ = _impact(E=0.7 * threshold, e=0.5, speed=2.0)

    assert above.ok, above.message
    assert below.status == "invalid"
    assert "too soft for this impact" in below.message and "outside the linear contact model" in below.message
    # The measured figure: where the impact was heading, beyond the limit; about (1/0.7)^0.5 x it.
    assert sim.max_overlap == pytest.approx(0.5 / math.sqrt(0.7), rel=0.1)


def test_overlap_past_the_limit_with_a_step_too_long_is_unstable_with_step_advice():
    from dem.validity import softest_valid_E

    body = Clump.solid_sphere(0.01, 2500.0)
    E = 3 * softest_valid_E(2.0, body.mass, 0.02, 0.01, e=0.5)

    _, _, report, _ = _impact(E=E, e=0.5, speed=2.0, dt=4e-3, chunk=4e-3)

    assert report.status == "unstable"
    assert "forced dt exceeds the automatic step" in report.message


def _box_impact(E, e, speed):
    """A rounded box (20 mm thick, r = 4 mm) thrown flat at a floor without gravity."""
    from dem.contact import ContactParams
    from dem.polyhedra import Polyhedron

    params = ContactParams(E=E, nu=0.3, e=e, mu=0.0)
    sim = Simulation(params, gravity=(0, 0, 0), domain_min=(-1, -1, -1), domain_max=(1, 1, 1))
    sim.add_wall(WallMesh.plane((0, 0, 0), (0, 0, 1), 0.4))
    box = Polyhedron.box((0.06, 0.04, 0.02), rounding=0.004, density=1000.0)
    sim.add_body(box, (0, 0, 0.0100001), velocity=(0, 0, -speed))
    deepest = 0.0

    def watch(s):
        nonlocal deepest
        deepest = max(deepest, s.current_overlap())

    report = sim.run(0.02, chunk_time=sim.dt, on_chunk=watch)
    return sim, box, report, deepest


def test_a_rounded_polyhedron_overlap_is_measured_against_its_rounding_and_limited_there():
    """The limit's length for a rounded polyhedron is its rounding r (``overlap_scale``): the
    estimate with r separates valid and invalid flat landings, and the figures are fractions of r."""
    from dem.polyhedra import Polyhedron
    from dem.validity import overlap_scale, peak_overlap, softest_valid_E

    box = Polyhedron.box((0.06, 0.04, 0.02), rounding=0.004, density=1000.0)
    assert overlap_scale(box) == 0.004
    threshold = softest_valid_E(2.0, box.mass, box.equivalent_diameter, overlap_scale(box), e=0.5)

    sim, _, above, deepest = _box_impact(E=1.3 * threshold, e=0.5, speed=2.0)
    stiffness = 1.3 * threshold * box.equivalent_diameter / 2  # against a wall of the same material
    assert above.ok, above.message
    assert deepest * 0.004 == pytest.approx(peak_overlap(2.0, box.mass, stiffness, 0.5), rel=0.02)
    assert sim.max_overlap == pytest.approx(deepest)

    sim, _, below, _ = _box_impact(E=0.7 * threshold, e=0.5, speed=2.0)
    assert below.status == "invalid"
    assert "of its rounding" in below.message and "too soft for this impact" in below.message
    assert sim.max_overlap == pytest.approx(0.5 / math.sqrt(0.7), rel=0.1)


def test_the_feeder_estimates_the_softest_valid_E_of_its_rounded_polyhedra_from_their_rounding():
    from dem.scenarios.feeder import make_items, softest_valid_E
    from dem.scenarios.feeder_config import load_feeder_config

    clumps = load_feeder_config("examples/feeder.toml")
    items = clumps.items.model_copy(update={"representation": "polyhedron"})
    polyhedra = clumps.model_copy(update={"items": items})
    nominal = polyhedra.items.model_copy(update={"spread": 0.0})
    roundings = {item.shape.rounding for item in make_items(nominal, np.random.default_rng(0))}

    # Thinner than the clumps' smallest spheres: the same drop must be stiffer to stay valid.
    assert max(roundings) < 0.01
    assert softest_valid_E(polyhedra, 0.5) > 2 * softest_valid_E(clumps, 0.5)


def _phone_landing_flat(E, speed):
    """The feeder's nominal smartphone as a rounded polyhedron, landing on its face level (its
    thinnest principal axis vertical) at ``speed``, without gravity; returns the run's report."""
    from dem.scenarios.feeder import make_items
    from dem.scenarios.feeder_config import load_feeder_config

    config = load_feeder_config("examples/feeder.toml")
    items = config.items.model_copy(
        update={"representation": "polyhedron", "counts": {"smartphone": 1}, "spread": 0.0}
    )
    phone = make_items(items, np.random.default_rng(0))[0].shape
    assert np.argmax(phone.inertia) == 2  # the principal frame's z is the phone's thickness
    params = ContactParams(E=E, nu=0.3, e=0.5, mu=0.5)
    sim = Simulation(params, gravity=(0, 0, 0), domain_min=(-1, -1, -1), domain_max=(1, 1, 1))
    sim.add_wall(WallMesh.plane((0, 0, 0), (0, 0, 1), 0.4))
    bottom = -phone.core[:, 2].min() + phone.rounding
    sim.add_body(phone, (0, 0, bottom + 1e-7), velocity=(0, 0, -speed))
    return sim.run(0.01)


def test_a_rounded_phone_landing_flat_from_the_insertion_drop_is_valid_above_the_feeders_estimate():
    """A level face is one contact under the centre of mass: the phone's whole mass, not its
    corner's effective mass, compresses the spring (``dem.validity.impact_mass``), so the feeder's
    softest valid E for polyhedra must hold for that landing, and not be far above it."""
    from dem.scenarios.feeder import GRAVITY, _FeederRun, softest_valid_E
    from dem.scenarios.feeder_config import load_feeder_config

    config = load_feeder_config("examples/feeder.toml")
    polyhedra = config.model_copy(
        update={"items": config.items.model_copy(update={"representation": "polyhedron"})}
    )
    threshold = softest_valid_E(polyhedra, 0.5)
    speed = math.sqrt(2 * GRAVITY * (config.tray.wall_height + _FeederRun.INSERT_ZONE_HEIGHT))

    above = _phone_landing_flat(1.1 * threshold, speed)
    below = _phone_landing_flat(0.8 * threshold, speed)

    assert above.ok, above.message
    assert below.status == "invalid", below.message
