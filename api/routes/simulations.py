"""Single simulations: queue one parameter set on a scenario, read its state and result."""

from __future__ import annotations

from fastapi import APIRouter, status

from api.deps import ApiKeyDep, Limit, Offset, SettingsDep, StoreDep
from api.schemas import SimulationCreate, SimulationPage, SimulationRead
from api.services import simulations

router = APIRouter(prefix="/api/v1/simulations", tags=["simulations"])


@router.post("", status_code=status.HTTP_202_ACCEPTED, response_model=SimulationRead)
def create_simulation(
    request: SimulationCreate, principal: ApiKeyDep, store: StoreDep, settings: SettingsDep
):
    """Queue one simulation; poll GET /api/v1/simulations/{id} until its state is done."""
    return simulations.create_simulation(store, request, principal, data_dir=settings.data_dir)


@router.get("", response_model=SimulationPage)
def list_simulations(
    principal: ApiKeyDep, store: StoreDep,
    limit: Limit = 50, offset: Offset = 0,
):
    return simulations.list_simulations(store, principal, limit, offset)


@router.get("/{simulation_id}", response_model=SimulationRead)
def get_simulation(simulation_id: str, principal: ApiKeyDep, store: StoreDep):
    return simulations.get_simulation(store, simulation_id, principal)
