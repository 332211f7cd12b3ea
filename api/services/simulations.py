"""Single simulations asked for through the API: validated and stored as ``pending``.

The service's background loop (``demcal serve``) enqueues pending simulations and records their
results through the store (see ``api/store.py``); this module only accepts and reads them.
"""

from __future__ import annotations

from pydantic import ValidationError

from api.auth import Principal
from api.errors import InvalidInputError
from api.schemas import SimulationCreate, SimulationPage, SimulationRead
from api.store import SqlStore


def create_simulation(store: SqlStore, request: SimulationCreate, principal: Principal) -> SimulationRead:
    from dem.scenarios.feeder import FeederConfig

    try:
        scenario = FeederConfig.model_validate(request.scenario).model_dump(mode="json")
    except ValidationError as exc:
        problems = "; ".join(
            f"scenario.{'.'.join(str(p) for p in err['loc'])}: {err['msg'].removeprefix('Value error, ')}"
            for err in exc.errors()
        )
        raise InvalidInputError(problems) from None
    sim_id = store.create_simulation(
        scenario, dict(request.params), request.seed, principal.owner, timeout_s=request.timeout_s
    )
    return SimulationRead.model_validate(store.get_simulation(sim_id))


def get_simulation(store: SqlStore, sim_id: str, principal: Principal) -> SimulationRead:
    return SimulationRead.model_validate(store.get_simulation(sim_id, principal.visible_to))


def list_simulations(store: SqlStore, principal: Principal, limit: int, offset: int) -> SimulationPage:
    page = store.list_simulations(principal.visible_to, limit, offset)
    return SimulationPage(
        items=[SimulationRead.model_validate(row) for row in page.items], total=page.total, limit=limit,
        offset=offset,
    )
