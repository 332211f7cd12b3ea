"""A study with known trials, written through the real SQL store, for the dashboard's browser
tests, its screenshots and its render benchmark.

The trials are synthetic: parameters drawn per generation from a distribution that narrows
towards a hidden parameter set, N_t and T from a smooth made-up response (more friction and less
restitution keep more items; a stiffer contact takes a smaller time step, so a longer run).
Nothing here pretends to be physics; it only gives the pages data with the shape of a real
study. As a feeder run does, a seeded run does less work once items have left, and stops when the
tray empties: its own T and cost are the made-up protocol's over the real ``full_load_factor``
(``dem/scenarios/feeder.py``), and f2 is the whole protocol's (``optimizer/objectives.py``). The
Pareto front is computed here by plain non-dominated filtering, so a test knows how many points
the page must highlight without trusting the code under test.

``snapshot_run`` writes a replayable snapshot directory with the feeder's own ``SnapshotWriter``
(the format the replay endpoint reads): items sliding along the real parametric tray, the
retained ones stopping before the outlet.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from api.auth import create_key
from api.db import create_db_engine, upgrade_database
from api.store import SqlStore
from dem.result import SimulationResult, SimulationStatus
from dem.scenarios.feeder import full_load_factor
from optimizer.driver import Driver, recommend
from optimizer.objectives import evaluate, protocol_wall_time
from optimizer.protocols import StudyStatus, TrialOutcome, TrialSpec, trial_id
from optimizer.space import ParameterSpace
from optimizer.study import VALIDATION_REPLICATE_BASE, StudyDefinition, parse_study

MEASURED = [0, 2, 3, 3, 4, 4, 5, 8, 12, 16]
N_ITEMS = 30
INSERTED, PROTOCOL_END = 1.0, 65.0  # the feeder's insertion and protocol end (s)
TRUTH = {"logE": 6.3, "nu": 0.3, "e": 0.45, "mu": 0.42}


@dataclass
class SeededStudy:
    """What was written, so tests can compare the page with it."""

    study_id: str
    api_key: str
    trial_ids: list[str]
    pareto_ids: list[str]
    replay_trial_id: str | None = None
    target: float = 4.0
    f1: dict[str, float] = field(default_factory=dict)
    n_remaining: dict[str, int] = field(default_factory=dict)
    failed: dict[str, str] = field(default_factory=dict)


def migrated_store(database_url: str) -> SqlStore:
    upgrade_database(database_url)
    return SqlStore(create_db_engine(database_url))


def non_dominated(points: dict[str, tuple[float, float]]) -> list[str]:
    """Ids whose (f1, f2) no other point beats in both (ties in both count as non-dominated)."""
    front = []
    for key, (a1, a2) in points.items():
        dominated = any(
            b1 <= a1 and b2 <= a2 and (b1 < a1 or b2 < a2)
            for other, (b1, b2) in points.items()
            if other != key
        )
        if not dominated:
            front.append(key)
    return front


def _response(params: dict[str, float], rng: np.random.Generator) -> tuple[int, float, float]:
    """Made-up (N_t, T, cost) with noise: N_t is about 4 of 30 at the hidden set and grows with
    friction, falls with restitution; T grows with the square root of E (the time step)."""
    logit = (
        math.log(4 / 26) + 7.0 * (params["mu"] - TRUTH["mu"]) - 3.0 * (params["e"] - TRUTH["e"])
        + rng.normal(0, 0.35)
    )
    n_remaining = int(rng.binomial(N_ITEMS, 1.0 / (1.0 + math.exp(-logit))))
    steps = 6.0e4 * math.sqrt(params["E"] / 1.0e6)
    cost = steps * (350 + 20 * n_remaining)
    wall = cost / 4.0e6 * rng.uniform(0.9, 1.1)
    return n_remaining, wall, cost


def seed_study(
    store: SqlStore,
    *,
    population: int = 20,
    offspring: int = 8,
    generations: int = 4,
    seed: int = 7,
    owner: str = "alice",
    name: str = "feeder-calibration",
    real_results: dict[int, SimulationResult] | None = None,
    failing: bool = False,
) -> SeededStudy:
    """A finished study with every trial done, objectives and the final Pareto flags stored.

    ``real_results`` replaces the made-up result of these individuals (e.g. with a real feeder
    run whose snapshots the replay shows); their parameters become the run's. With ``failing``,
    soft sets (E below 10^5.4 Pa) blow up and every eleventh individual times out, each with the
    count where it stopped, which the pages must not show as N_t; ``failed`` maps their trial ids
    to the status.
    """
    real_results = real_results or {}
    rng = np.random.default_rng(seed)
    study_definition = parse_study(
        {
            "name": name,
            "description": "synthetic trials for the dashboard",
            "scenario": {},
            "experiment": {"measured": MEASURED},
            "ga": {"population": population, "offspring": offspring, "generations": generations},
            "validation": {"seeds": 0},  # the seeded trials are the search's only
            "objective_time": "wall",
        }
    )
    definition = study_definition.model_dump(mode="json")
    target = float(np.median(MEASURED))
    target = math.floor(target + 0.5)
    with store.session() as session:
        _, token = create_key(session, owner)
    study_id = store.create_study(definition, owner=owner)
    store.set_status(study_id, StudyStatus.RUNNING)
    objectives: dict[str, tuple[float, float]] = {}
    params_of: dict[str, dict[str, float]] = {}
    seeded = SeededStudy(study_id=study_id, api_key=token, trial_ids=[], pareto_ids=[], target=target)
    individual = 0
    for generation in range(generations + 1):
        size = population if generation == 0 else offspring
        width = 1.0 / (1.0 + generation)  # the search narrows around the truth
        specs = []
        for _ in range(size):
            params = {
                "E": float(10 ** np.clip(TRUTH["logE"] + rng.normal(0, 1.5 * width), 5, 9)),
                "nu": float(np.clip(TRUTH["nu"] + rng.normal(0, 0.2 * width), 0.0, 0.49)),
                "e": float(np.clip(TRUTH["e"] + rng.normal(0, 0.4 * width), 0.05, 0.95)),
                "mu": float(np.clip(TRUTH["mu"] + rng.normal(0, 0.4 * width), 0.05, 1.0)),
            }
            if individual in real_results:
                params = {name: float(real_results[individual].params[name]) for name in params}
            params_of[trial_id(study_id, individual, 0)] = params
            specs.append(
                TrialSpec(
                    trial_id=trial_id(study_id, individual, 0), study_id=study_id, individual=individual,
                    generation=generation, replicate=0, seed=1000 + individual, params=params,
                    scenario=definition["scenario"],
                )
            )
            individual += 1
        store.add_trials(specs)
        for spec in specs:
            n_remaining, wall, cost = _response(spec.params, rng)
            times = [float(t) for t in np.sort(rng.uniform(5.5, 60.0, N_ITEMS - n_remaining))]
            discharges = times + [None] * n_remaining
            stopped = times[-1] if n_remaining == 0 else PROTOCOL_END  # an empty tray stops the run
            factor = full_load_factor([INSERTED] * N_ITEMS, discharges, stopped, PROTOCOL_END)
            result = SimulationResult(
                status=SimulationStatus.OK, n_items=N_ITEMS, n_remaining=n_remaining,
                discharge_times=discharges, sim_time=stopped, wall_time_s=wall / factor,
                steps=int(cost / 400), dt=65.0 / max(1, int(cost / 400)), cost=cost / factor,
                full_load_factor=factor, params=spec.params, seed=spec.seed,
            )
            if spec.individual in real_results:
                result = real_results[spec.individual]
                n_remaining = result.n_remaining
            failure = _failure(spec) if failing else None
            if failure is not None:
                # A failed run is never scaled (the feeder's full_load_factor is 1 then).
                result = result.model_copy(update=failure | {"full_load_factor": 1.0})
                seeded.failed[spec.trial_id] = failure["status"].value
            store.record_result(TrialOutcome(spec.trial_id, result, worker="seed"))
            seeded.trial_ids.append(spec.trial_id)
            if failure is not None:
                objectives[spec.trial_id] = (None, None)  # not a measurement: views show none
                continue
            f1 = abs(n_remaining - target)
            objectives[spec.trial_id] = (f1, protocol_wall_time(result))  # objective_time "wall"
            seeded.f1[spec.trial_id] = f1
            seeded.n_remaining[spec.trial_id] = n_remaining
        measured = {tid: values for tid, values in objectives.items() if values[0] is not None}
        front = non_dominated(measured)
        store.save_generation(
            study_id, generation + 1, b"synthetic", front,
            driver_recommendation(store, study_id, study_definition),
            objectives={tid: objectives[tid] for tid in (s.trial_id for s in specs)},
        )
        seeded.pareto_ids = front
    store.set_status(study_id, StudyStatus.DONE)
    return seeded


def _validated_definition(match_estimate: str = "own") -> StudyDefinition:
    return parse_study({
        "name": "validated-study", "scenario": {},
        "experiment": {"measured": VALIDATED_MEASURED, "tolerance": 2},
        "ga": {"population": 16, "offspring": 8, "generations": 4, "match_estimate": match_estimate},
        "validation": {"seeds": 6, "candidates": 3}, "objective_time": "wall",
    })  # fmt: skip


def seed_validated_study(store: SqlStore, owner: str = "alice", match_estimate: str = "own") -> str:
    """A feeder study run to its end by the real driver on synthetic results
    (``optimizer.memory.synthetic_result``), validation included: on the fresh seeds, the second
    candidate fails its first run (unstable), so the table has a set that failed to reproduce
    beside sets that validate. ``match_estimate = "neighbours"``: its GA ranks pooled neighbours,
    which choose the candidates. Returns the study id."""
    from optimizer.memory import SyntheticExecutor, synthetic_result

    definition = _validated_definition(match_estimate)
    candidates: list[int] = []

    def respond(spec: TrialSpec) -> SimulationResult:
        result = synthetic_result(spec)
        fresh = spec.generation == definition.validation_batch()
        if fresh and spec.replicate == VALIDATION_REPLICATE_BASE:
            candidates.append(spec.individual)
            if len(candidates) == 2:
                return result.model_copy(update={"status": SimulationStatus.UNSTABLE, "message": "overlap"})
        return result

    study_id = store.create_study(definition.model_dump(mode="json"), owner=owner)
    Driver(store, SyntheticExecutor(respond)).run_to_completion(study_id, poll_timeout=0)
    return study_id


def seed_study_awaiting_validation(store: SqlStore, owner: str = "alice") -> str:
    """The study of ``seed_validated_study`` driven through its search and left running before
    its validation: a recommendation the fresh seeds have not checked yet."""
    from optimizer.memory import SyntheticExecutor

    definition = _validated_definition()
    study_id = store.create_study(definition.model_dump(mode="json"), owner=owner)
    driver = Driver(store, SyntheticExecutor(), reconcile_every_s=0)
    while driver.step(study_id, timeout=0).batch < definition.validation_batch():
        pass
    return study_id


def driver_recommendation(store: SqlStore, study_id: str, definition: StudyDefinition) -> dict | None:
    """The recommendation a study's driver stores after a search batch, from the stored trials
    (``optimizer.driver.recommend``): a seeded study shows what a real one would."""
    records = store.trials(study_id)
    evaluations = evaluate(records, definition, definition.n_items())
    space = ParameterSpace(definition.parameters)
    return recommend(evaluations, records, definition, space, final=False)[1]


def _failure(spec: TrialSpec) -> dict | None:
    """How a seeded run fails, if it does: the result fields to replace."""
    if spec.params["E"] < 10**5.4:
        return {"status": SimulationStatus.UNSTABLE, "n_remaining": N_ITEMS,
                "message": "unstable at t=0.21 s: body 3 overlaps beyond overlap_limit of a sphere radius"}
    if spec.individual % 11 == 5:
        return {"status": SimulationStatus.TIMEOUT, "n_remaining": N_ITEMS // 2,
                "message": "timeout after 600 s of wall time"}
    return None


VALIDATED_MEASURED = [12, 13, 14, 15, 15, 16, 18]
REPLAY_TILT_DEG = 3.0
REPLAY_VIBRATION = (np.cos(np.radians(25)), 0.0, np.sin(np.radians(25)), 1.5e-3, 60.0, 5.0)


def snapshot_run(directory: Path, n_items: int, retained: list[bool], frames: int = 60) -> None:
    """A replayable snapshot directory: boxes moving along a tilted tray that vibrates from 5 s,
    retained ones stopping."""
    from dem.scenarios.render import SnapshotWriter
    from dem.scenarios.tray import TrayConfig, build_tray

    tray = TrayConfig(tilt_deg=REPLAY_TILT_DEG)
    geometry = build_tray(tray)
    vertices, faces = geometry.vertices, geometry.faces
    *direction, amplitude, frequency, start_time = REPLAY_VIBRATION
    rng = np.random.default_rng(3)
    half = np.array([0.073, 0.035, 0.005])
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    hulls = [corners * half * rng.uniform(0.8, 1.1) for _ in range(n_items)]
    writer = SnapshotWriter(
        directory, vertices, faces, [f"item{i}" for i in range(n_items)], ["smartphone"] * n_items, hulls,
        tilt_deg=REPLAY_TILT_DEG, vibration=REPLAY_VIBRATION,
    )
    start = np.column_stack(
        [
            rng.uniform(0.08, 0.22, n_items),
            rng.uniform(-0.09, 0.09, n_items),
            rng.uniform(0.01, 0.05, n_items),
        ]
    )
    stop_x = rng.uniform(0.35, 0.48, n_items)
    yaw = rng.uniform(0, np.pi, n_items)
    for k in range(frames):
        t = 65.0 * k / (frames - 1)
        travel = (tray.length + 0.1 - start[:, 0]) * (k / (frames - 1))
        x = start[:, 0] + travel * rng.uniform(0.9, 1.3, n_items)
        x = np.where(retained, np.minimum(x, stop_x), x)
        y = start[:, 1] * np.clip(1 - 0.8 * (x - 0.25) / 0.25, 0.2, 1.0)
        pos = np.column_stack([x, y, start[:, 2]])
        quat = np.column_stack([np.cos(yaw / 2), np.zeros(n_items), np.zeros(n_items), np.sin(yaw / 2)])
        state = np.where(x > tray.length + 0.05, 2, 1)
        phase = 2 * np.pi * frequency * max(t - start_time, 0.0)
        writer.frame(t, pos, quat, state, amplitude * np.sin(phase) * np.array(direction))
    times = [None if keep else 30.0 for keep in retained]
    writer.summary({"discharge_times": times})


def add_finished_trials(
    store: SqlStore, study_id: str, generation: int, first_individual: int, count: int, seed: int = 11
) -> list[str]:
    """``count`` more done trials in ``generation`` of a study, as a running study gets them."""
    rng = np.random.default_rng(seed)
    specs = [
        TrialSpec(
            trial_id=trial_id(study_id, individual, 0), study_id=study_id, individual=individual,
            generation=generation, replicate=0, seed=individual,
            params={"E": float(10 ** rng.uniform(5, 9)), "nu": float(rng.uniform(0, 0.49)),
                    "e": float(rng.uniform(0.05, 0.95)), "mu": float(rng.uniform(0.05, 1.0))},
            scenario={},
        )
        for individual in range(first_individual, first_individual + count)
    ]
    store.add_trials(specs)
    objectives = {}
    for spec in specs:
        n_remaining, wall, cost = _response(spec.params, rng)
        result = SimulationResult(
            status=SimulationStatus.OK, n_items=N_ITEMS, n_remaining=n_remaining, sim_time=65.0,
            wall_time_s=wall, cost=cost, params=spec.params, seed=spec.seed,
            discharge_times=[30.0] * (N_ITEMS - n_remaining) + [None] * n_remaining,
        )
        store.record_result(TrialOutcome(spec.trial_id, result))
        objectives[spec.trial_id] = (abs(n_remaining - 4.0), wall)
    store.save_generation(study_id, generation, b"synthetic", [], None, objectives=objectives)
    return [spec.trial_id for spec in specs]


HEAP_MEASURED = [29.5, 31.0, 32.5]  # deg
HEAP_TOLERANCE = 1.5
REPOSE_FEEDER = Path(__file__).resolve().parents[2] / "examples" / "study-repose-feeder.toml"


def _angle(params: dict[str, float], target: float, rng: np.random.Generator) -> float:
    """A made-up angle of repose: steeper with friction, about the target at the hidden set."""
    return float(target + 30.0 * (params["mu"] - TRUTH["mu"]) + rng.normal(0, 0.8))


def seed_heap_study(
    store: SqlStore, *, with_feeder: bool = False, owner: str = "alice", seed: int = 9
) -> SeededStudy:
    """A finished angle-of-repose study (or, ``with_feeder``, the heap and feeder study of
    ``examples/study-repose-feeder.toml``) with made-up responses; every seventh run ends
    unstable. ``target`` is the angle's; f1 is the study's own rule (optimizer/objectives.py)."""
    import tomllib

    if with_feeder:
        data = tomllib.loads(REPOSE_FEEDER.read_text())
        data["validation"] = {"seeds": 0}
    else:
        data = {
            "name": "heap-calibration",
            "scenario": {"kind": "angle_of_repose"},
            "experiment": {"response": "angle_deg", "measured": HEAP_MEASURED, "tolerance": HEAP_TOLERANCE},
            "ga": {"population": 8, "offspring": 4, "generations": 3},
            "validation": {"seeds": 0},
        }
    data["objective_time"] = "wall"
    definition = parse_study(data)
    experiments = definition.experiments
    stored = definition.model_dump(mode="json")
    rng = np.random.default_rng(seed)
    study_id = store.create_study(stored, owner=owner)
    store.set_status(study_id, StudyStatus.RUNNING)
    target = experiments[0].target()
    seeded = SeededStudy(study_id=study_id, api_key="", trial_ids=[], pareto_ids=[], target=target)
    objectives: dict[str, tuple[float | None, float | None]] = {}
    individual = 0
    for generation in range(definition.ga.generations + 1):
        size = definition.ga.population if generation == 0 else definition.ga.offspring
        specs = []
        for _ in range(size):
            params = {"E": float(10 ** rng.uniform(5, 7)), "nu": 0.3, "e": float(rng.uniform(0.1, 0.9)),
                      "mu": float(np.clip(TRUTH["mu"] + rng.normal(0, 0.3 / (1 + generation)), 0.1, 1.0))}
            specs.append(TrialSpec(
                trial_id=trial_id(study_id, individual, 0), study_id=study_id, individual=individual,
                generation=generation, replicate=0, seed=2000 + individual, params=params,
                scenario=stored["scenario"],
            ))
            individual += 1
        store.add_trials(specs)
        for spec in specs:
            angle = _angle(spec.params, target, rng)
            n_remaining, wall, cost = _response(spec.params, rng)
            if with_feeder:
                responses = {"heap.angle_deg": angle, "heap.height": 0.04, "feeder.n_remaining": n_remaining}
            else:
                responses = {"angle_deg": angle, "height": 0.04}
            failed = spec.individual % 7 == 3
            result = SimulationResult(
                status=SimulationStatus.UNSTABLE if failed else SimulationStatus.OK,
                message="unstable at t=0.1 s" if failed else "", responses=responses, sim_time=1.0,
                wall_time_s=wall, cost=cost, params=spec.params, seed=spec.seed,
            )
            store.record_result(TrialOutcome(spec.trial_id, result, worker="seed"))
            seeded.trial_ids.append(spec.trial_id)
            if failed:
                seeded.failed[spec.trial_id] = SimulationStatus.UNSTABLE.value
                objectives[spec.trial_id] = (None, None)
                continue
            scale = (lambda x: 1.0) if len(experiments) == 1 else (lambda x: x.tolerance)
            distances = [abs(responses[x.response] - x.target()) / scale(x) for x in experiments]
            objectives[spec.trial_id] = (max(distances), wall)
            seeded.f1[spec.trial_id] = max(distances)
        measured = {tid: values for tid, values in objectives.items() if values[0] is not None}
        seeded.pareto_ids = non_dominated(measured)
        store.save_generation(
            study_id, generation + 1, b"synthetic", seeded.pareto_ids,
            driver_recommendation(store, study_id, definition),
            objectives={s.trial_id: objectives[s.trial_id] for s in specs},
        )
    store.set_status(study_id, StudyStatus.DONE)
    return seeded
