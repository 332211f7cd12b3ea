"""Single simulations asked for through the API: validated and stored as ``pending``.

The service's background loop (``demcal serve``) enqueues pending simulations and records their
results through the store (see ``api/store/``); this module only accepts and reads them.
"""

from __future__ import annotations

from pathlib import Path

from api.auth import Principal
from api.errors import InvalidInputError
from api.schemas import SimulationCreate, SimulationPage, SimulationRead, page_of
from api.services.scenario_paths import confine_paths
from api.services.shapes import attach_uploaded_shapes
from api.store import SqlStore


def create_simulation(
    store: SqlStore, request: SimulationCreate, principal: Principal, *, data_dir: Path
) -> SimulationRead:
    from dem.engines.base import UnknownEngineError, refusal
    from dem.scenarios.registry import for_config

    scenario = request.scenario.model_dump(mode="json")
    try:
        problem = refusal(request.engine, for_config(request.scenario), request.scenario)
    except UnknownEngineError as exc:
        raise InvalidInputError(f"engine: {exc}") from None
    if problem:
        raise InvalidInputError(f"engine: {problem}")
    scenario = attach_uploaded_shapes(store, principal, confine_paths(scenario, data_dir), data_dir)
    sim_id = store.create_simulation(
        scenario, dict(request.params), request.seed, principal.owner, timeout_s=request.timeout_s,
        engine=request.engine,
    )
    return SimulationRead.model_validate(store.get_simulation(sim_id))


def get_simulation(store: SqlStore, sim_id: str, principal: Principal) -> SimulationRead:
    return SimulationRead.model_validate(store.get_simulation(sim_id, principal.visible_to))


def list_simulations(store: SqlStore, principal: Principal, limit: int, offset: int) -> SimulationPage:
    page = store.list_simulations(principal.visible_to, limit, offset)
    return page_of(SimulationPage, SimulationRead, page, limit, offset)
