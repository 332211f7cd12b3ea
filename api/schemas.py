"""The wire models of the REST API (pydantic): what clients send and receive.

They are distinct from the table rows (``api/models.py``) so that the database can change without
changing the API, and the API never leaks a column by accident. The study definition a client
POSTs is the optimiser's own ``StudyDefinition``: the API and ``demcal calibrate`` accept the same
document.

Non-finite floats have no JSON spelling; objective values that are infinite (a failed simulation's
penalty) are sent as ``null`` and the trial's ``status`` says why.
"""

from __future__ import annotations

import math
from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from optimizer.protocols import PARAMETER_NAMES, StudyStatus, TrialState


class _Wire(BaseModel):
    model_config = ConfigDict(from_attributes=True)


def finite_or_none(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


class Progress(_Wire):
    trials_total: int = Field(description="Simulations the study's budget allows (upper bound).")
    trials_done: int
    trials_by_state: dict[str, int]
    generation: int
    generations_total: int


class TrialRead(_Wire):
    """A trial in compact form: what tables and plots need, without the full result."""

    id: str
    generation: int
    individual: int
    replicate: int
    seed: int
    params: dict[str, float]
    state: TrialState
    status: str | None = Field(None, description="How the simulation ended: ok, unstable, timeout, error.")
    n_remaining: int | None = Field(None, description="N_t: items left in the tray.")
    wall_time_s: float | None = Field(None, description="T: wall-clock seconds of the simulation.")
    cost: float | None = Field(None, description="Machine-independent cost of the simulation.")
    f1: float | None = Field(None, description="Objective 1, |N_t - target| (null: not ranked or failed).")
    f2: float | None = Field(None, description="Objective 2, computation time (null: not ranked or failed).")
    pareto: bool
    worker: str | None = None
    attempts: int
    message: str = ""
    updated_at: datetime


class TrialDetail(TrialRead):
    """One trial with its full simulation result."""

    dt: float | None = None
    timeout_s: float | None = None
    result: dict[str, Any] | None = None
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None


class TrialPage(_Wire):
    items: list[TrialRead]
    total: int
    limit: int
    offset: int
    server_time: datetime = Field(
        description="Pass it back as ?updated_since= to receive only trials changed since this page."
    )


class StudyListItem(_Wire):
    id: str
    name: str
    owner: str | None
    status: StudyStatus
    message: str
    generation: int
    trials_done: int
    trials_total: int
    generations_total: int = Field(0, description="Generations the study's budget allows.")
    created_at: datetime
    updated_at: datetime
    started_at: datetime | None = Field(None, description="When the study first started running.")
    finished_at: datetime | None = Field(None, description="When it became done, cancelled or failed.")
    recommendation: dict[str, Any] | None = Field(
        None, description="The optimiser's choice so far (params, f1, f2, ...), without its "
        "equivalent sets (GET /api/v1/studies/{id}/recommendation has them)."
    )
    best_f1: float | None = Field(None, description="The lowest f1 of an ok trial so far.")


class StudyPage(_Wire):
    items: list[StudyListItem]
    total: int
    limit: int
    offset: int


class StudyRead(_Wire):
    id: str
    name: str
    owner: str | None
    status: StudyStatus
    message: str
    definition: dict[str, Any]
    progress: Progress
    best: TrialRead | None = Field(None, description="Lowest f1 so far, fastest among equals.")
    recommendation: dict[str, Any] | None = None
    created_at: datetime
    updated_at: datetime
    started_at: datetime | None = Field(None, description="When the study first started running.")
    finished_at: datetime | None = Field(None, description="When it became done, cancelled or failed.")


class Spread(_Wire):
    """Median and spread of one quantity over the ok trials of a generation (the paper's Fig. 5)."""

    median: float
    q1: float
    q3: float
    min: float
    max: float


class GenerationSummary(_Wire):
    generation: int
    trials: int
    done: int
    ok: int
    failed: int
    n_remaining: Spread | None
    wall_time_s: Spread | None
    cost: Spread | None
    best_f1: float | None


class ParetoPoint(_Wire):
    """A Pareto member in compact form."""

    id: str
    generation: int
    individual: int
    replicate: int
    params: dict[str, float]
    n_remaining: int | None
    wall_time_s: float | None
    cost: float | None
    f1: float | None
    f2: float | None


class ParetoFront(_Wire):
    study_id: str
    generation: int
    points: list[ParetoPoint]


class RecommendationRead(_Wire):
    study_id: str
    status: StudyStatus
    recommendation: dict[str, Any] | None = Field(
        None, description="The optimiser's choice: the fastest Pareto member within tolerance."
    )
    equivalent: list[ParetoPoint] = Field(
        description="Every evaluated parameter set whose f1 is within the experiment's tolerance, "
        "fastest first (the problem is multimodal: these match the experiment equally well)."
    )


class SimulationCreate(BaseModel):
    """One simulation to run outside any study."""

    model_config = ConfigDict(extra="forbid")

    scenario: dict[str, Any] = Field(description="A feeder configuration (dem.scenarios.feeder).")
    params: dict[str, float] = Field(description="E (Pa), nu, e, mu.")
    seed: int = Field(0, ge=0, le=2**31 - 1)
    timeout_s: float | None = Field(None, gt=0, le=7 * 24 * 3600)

    @field_validator("params")
    @classmethod
    def _four_parameters(cls, params: dict[str, float]) -> dict[str, float]:
        from optimizer.study import PHYSICAL_RANGES

        missing = [name for name in PARAMETER_NAMES if name not in params]
        unknown = [name for name in params if name not in PARAMETER_NAMES]
        if missing or unknown:
            raise ValueError(
                f"give exactly E, nu, e, mu (missing: {missing or 'none'}, unknown: {unknown or 'none'})"
            )
        for name, value in params.items():
            low, high, low_in, high_in = PHYSICAL_RANGES[name]
            above = value >= low if low_in else value > low
            below = value <= high if high_in else value < high
            inside = above and below
            if not (math.isfinite(value) and inside):
                raise ValueError(
                    f"{name} = {value} is outside its physical range "
                    f"{'[' if low_in else '('}{low:g}, {high:g}{']' if high_in else ')'}"
                )
        return params


class SimulationRead(_Wire):
    id: str
    state: TrialState
    status: str | None
    scenario: dict[str, Any]
    params: dict[str, float]
    seed: int
    n_remaining: int | None
    wall_time_s: float | None
    result: dict[str, Any] | None
    worker: str | None
    attempts: int
    created_at: datetime
    updated_at: datetime
    finished_at: datetime | None


class SimulationPage(_Wire):
    items: list[SimulationRead]
    total: int
    limit: int
    offset: int


class ShapeRead(_Wire):
    id: str
    name: str
    file_type: str
    mass: float
    n_bytes: int
    sha256: str
    report: dict[str, Any] = Field(description="The mesh validation report.")
    clump: dict[str, Any] | None = Field(None, description="The sphere clump generated from the mesh.")
    created_at: datetime


class ShapePage(_Wire):
    items: list[ShapeRead]
    total: int
    limit: int
    offset: int


class ErrorDetail(BaseModel):
    """Every error: a 4xx status and one message that says what to fix."""

    detail: str


class Health(BaseModel):
    status: Literal["ok", "degraded"]
    database: str
    redis: str
    workers: int | None = Field(None, description="RQ workers registered on the queue (null without Redis).")
    version: str
