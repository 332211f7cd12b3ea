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

from dem.parameters import ALL_PARAMETER_NAMES, PARAMETER_NAMES, WALL_PARAMETER_NAMES
from dem.scenarios.registry import ScenarioConfig
from optimizer.protocols import StudyStatus, TrialState


class _Wire(BaseModel):
    model_config = ConfigDict(from_attributes=True)


def finite_or_none(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


class Failures(_Wire):
    """Finished runs that measured nothing, by status (invalid, unstable, timeout, error, cancelled)."""

    total: int
    by_status: dict[str, int]
    text: str = Field(description="The sentence every view prints: 'failed: 3 (unstable 2, timeout 1)'.")


class Progress(_Wire):
    trials_total: int = Field(description="Simulations the study's budget allows (upper bound).")
    trials_done: int
    trials_by_state: dict[str, int]
    failures: Failures = Field(description="Finished trials whose simulation measured no N_t.")
    generation: int
    generations_total: int
    validation_batch: int | None = Field(
        None, description="The batch (a trial's 'generation') of the fresh-seed validation runs, which "
        "the search's ranking leaves out (null when the definition cannot be read)."
    )


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
    n_remaining: int | None = Field(
        None, description="N_t: items left in the tray; null unless the run ended ok (the full "
        "result keeps the count where a failed run stopped)."
    )
    responses: dict[str, float | None] | None = Field(
        None, description="The scenario's named responses (units in the study's 'responses')."
    )
    engine: str = Field("numba", description="The engine that runs it.")
    wall_time_s: float | None = Field(None, description="T: wall-clock seconds of the simulation.")
    cost: float | None = Field(None, description="Machine-independent cost of the simulation.")
    protocol_wall_time_s: float | None = Field(
        None, description="T of the whole protocol: wall_time_s scaled to the full protocol for a run "
        "that stopped early (the tray emptied), as f2 prices it (optimizer/objectives.py); "
        "null before the result."
    )
    protocol_cost: float | None = Field(
        None, description="Cost of the whole protocol, as protocol_wall_time_s; with one replicate, the "
        "f2 of a study that ranks on cost."
    )
    f1: float | None = Field(None, description="Objective 1, |N_t - target| (null: not ranked or failed).")
    f2: float | None = Field(
        None, description="Objective 2: the cost or T of the whole protocol (the study's objective_time), "
        "mean over the set's replicates (null: not ranked or failed)."
    )
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
    changes: int = Field(
        description="The study's change number when this page was read: pass it back as "
        "?changed_since= to receive only the trials changed since."
    )


F1_UNIT = ("f1's unit: the response's for one experiment, '1' for several (each distance is divided "
           "by its tolerance).")


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
    version: int = Field(
        0, description="The change number of the study's last change of status, generation, ranking or "
        "trials added: the version of its recommendation, progress, identifiability and Pareto front."
    )
    started_at: datetime | None = Field(None, description="When the study first started running.")
    finished_at: datetime | None = Field(None, description="When it became done, cancelled or failed.")
    recommendation: dict[str, Any] | None = Field(
        None, description="The optimiser's choice so far (params, f1, f2, ...), without its "
        "equivalent sets (GET /api/v1/studies/{id}/recommendation has them)."
    )
    best_f1: float | None = Field(None, description="The lowest f1 of an ok trial so far.")
    f1_unit: str = Field("1", description=F1_UNIT)
    failures: Failures | None = Field(None, description="Finished trials that measured no N_t, by status.")


class StudyPage(_Wire):
    items: list[StudyListItem]
    total: int
    limit: int
    offset: int


class ResponseRead(_Wire):
    """One response a scenario declares (``dem.scenarios.base.Response``)."""

    name: str
    unit: str = Field(description="'1' for pure numbers; a count names what it counts ('items').")
    type: Literal["integer", "real"]
    failed_value: float = Field(description="What a failed simulation counts as in the objectives.")
    description: str = ""
    label: str = Field("", description="A short name for plot axes and tables ('N_t', 'angle of repose').")


class StudyRead(_Wire):
    id: str
    name: str
    owner: str | None
    status: StudyStatus
    message: str
    definition: dict[str, Any]
    progress: Progress
    best: TrialRead | None = Field(None, description="Lowest f1 so far, fastest among equals.")
    recommendation: dict[str, Any] | None = Field(
        None,
        description="The fastest validated set, its 'validation_status' (pending while the search "
        "runs, then validated or not reproduced; not validated without validation seeds) and, after "
        "the validation, the 'validation' table and 'chosen_by' (how it was chosen).",
    )
    warnings: list[str] = Field(
        default_factory=list, description="What to know before trusting the study (bounds in the "
        "contact model's invalid region).",
    )
    created_at: datetime
    updated_at: datetime
    version: int = Field(
        0, description="The change number of the study's last change of status, generation, ranking or "
        "trials added: the version of its recommendation, progress, identifiability and Pareto front."
    )
    started_at: datetime | None = Field(None, description="When the study first started running.")
    finished_at: datetime | None = Field(None, description="When it became done, cancelled or failed.")
    responses: list[ResponseRead] = Field(
        default_factory=list, description="What the study's scenario measures, with units."
    )
    f1_unit: str = Field("1", description=F1_UNIT)
    f1_rule: str = Field(
        "", description="f1 in words, as the search computes it (W1 of the replicates to the measured "
        "values, or the distance of their aggregate to the target); '' if the definition no longer validates."
    )


class Spread(_Wire):
    """Median and spread of one quantity over the ok trials of a generation (the paper's Fig. 5)."""

    median: float
    q1: float
    q3: float
    min: float
    max: float


class ExperimentBand(_Wire):
    median_5: float = Field(description="5 % point of the median of such a generation.")
    median_95: float = Field(description="95 % point of the median of such a generation.")
    w1_95: float = Field(description="95th percentile of its Wasserstein-1 distance to the experiment.")
    alike: bool = Field(description="The generation's W1 is at or below w1_95: it behaves as the experiment.")


class GenerationSummary(_Wire):
    generation: int
    trials: int
    done: int
    ok: int
    failed: int = Field(description="Finished trials that measured nothing; by status in failed_by_status.")
    failed_by_status: dict[str, int]
    n_remaining: Spread | None
    responses: dict[str, Spread] = Field(default_factory=dict, description="Each response's spread.")
    wall_time_s: Spread | None
    cost: Spread | None
    protocol_wall_time_s: Spread | None = Field(
        None, description="The spread of the trials' protocol_wall_time_s (TrialRead): what f2 ranks."
    )
    protocol_cost: Spread | None = Field(
        None, description="The spread of the trials' protocol_cost (TrialRead): what f2 ranks."
    )
    best_f1: float | None
    w1_to_experiment: dict[str, float | None] = Field(
        default_factory=dict,
        description="Per response, the Wasserstein-1 distance from the generation's measured runs "
        "to the experiment's values (None before any run measured).",
    )
    as_experiment: dict[str, ExperimentBand | None] = Field(
        default_factory=dict,
        description="Per response, where a generation of as many runs drawn from the experiment "
        "itself would land (a bootstrap of the measured values), and whether the generation is "
        "alike: behaves as the experiment does, as far as its runs can tell.",
    )


class ParetoPoint(_Wire):
    """A Pareto member in compact form."""

    id: str
    generation: int
    individual: int
    replicate: int
    params: dict[str, float]
    n_remaining: int | None
    responses: dict[str, float | None] | None = None
    wall_time_s: float | None
    cost: float | None
    f1: float | None
    f2: float | None


class ParetoFront(_Wire):
    study_id: str
    generation: int
    points: list[ParetoPoint]


class ProgressPoint(_Wire):
    """Where the study stood when one batch was complete."""

    batch: int
    simulations: int = Field(description="Finished simulations of this batch and the earlier ones.")
    failed: int = Field(description="Of them, runs that measured nothing.")
    hypervolume: float | None = Field(
        None, description="Fraction of the reference box the measured (f1, f2) dominate (pymoo HV)."
    )
    best_f1: float | None
    best_validated_f1: float | None = Field(
        None, description="Lowest f1 among sets a validation on fresh seeds confirmed (null: none yet)."
    )


class ObjectiveReference(_Wire):
    f1: float = Field(description="The number of items: f1 never exceeds it.")
    f2: float = Field(description="1.1 x the largest f2 measured in the initial population.")


class StudyProgressRead(_Wire):
    """Hypervolume and best f1 against simulations, one point per completed batch."""

    study_id: str
    reference: ObjectiveReference | None = Field(
        None, description="The hypervolume's reference point, fixed once the initial population is "
        "complete, so values of one study compare across batches (null before that)."
    )
    points: list[ProgressPoint]


class ParameterIdentifiability(_Wire):
    name: str
    first_order: float = Field(description="Sobol first-order index of the response model's mean.")
    total: float = Field(
        description="Sobol total index: how much the response depends on it, interactions included."
    )
    length_scale: float = Field(description="The Gaussian process's ARD length scale (long = flat).")
    matching_sets: int
    matching_range: list[float] | None = Field(None, description="[low, high] over the matching sets.")
    matching_spread: float | None = Field(
        None, description="The matching sets' range as a share of the searched range (log for E)."
    )
    verdict: Literal["pinned", "weak", "not identifiable"]


class ParameterIdentifiabilityTogether(ParameterIdentifiability):
    """One parameter as all the study's experiments see it together."""

    response: str = Field(description="The experiment's response most sensitive to it (its indices).")
    pinned_by: list[str] = Field(description="The experiments' responses that pin it alone.")
    pinned_together: bool = Field(
        description="Pinned by the experiments together though by none alone (their ridges cross)."
    )


class ExperimentIdentifiability(_Wire):
    """What one experiment alone says (its response's model, its own matching sets)."""

    response: str
    method: str
    simulations: int
    parameters: list[ParameterIdentifiability]
    reason: str = ""


class IdentifiabilityRead(_Wire):
    """Which searched parameters the experiments pin down, each alone and together
    (``optimizer/identifiability.py``)."""

    study_id: str
    method: str
    simulations: int = Field(description="Successful simulations the indices come from.")
    parameters: list[ParameterIdentifiabilityTogether] = Field(
        description="Every experiment together: the sets matching them all (one experiment: its own)."
    )
    experiments: list[ExperimentIdentifiability] = Field(description="Each experiment alone, in order.")
    reason: str = Field("", description="Why there are no indices yet, if there are none.")


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

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    scenario: ScenarioConfig = Field(
        description="A scenario configuration; its kind (default feeder) picks it from the registry.",
    )
    params: dict[str, float] = Field(
        description=f"{', '.join(PARAMETER_NAMES)}; optionally {', '.join(WALL_PARAMETER_NAMES)} "
        "(the walls' material and the item-wall pair). Moduli in Pa.",
        json_schema_extra={
            "properties": {name: {"type": "number"} for name in ALL_PARAMETER_NAMES},
            "required": list(PARAMETER_NAMES),
            "additionalProperties": False,
        },
    )
    seed: int = Field(0, ge=0, le=2**31 - 1)
    timeout_s: float | None = Field(None, gt=0, le=7 * 24 * 3600)
    engine: str = Field("numba", max_length=32, description="numba (built in) or liggghts.")

    @field_validator("params")
    @classmethod
    def _four_parameters(cls, params: dict[str, float]) -> dict[str, float]:
        from dem.parameters import range_problem, unknown_names_problem

        problem = unknown_names_problem(list(params))
        if problem:
            raise ValueError(problem)
        missing = [name for name in PARAMETER_NAMES if name not in params]
        if missing:
            raise ValueError(f"give E, nu, e and mu (missing: {', '.join(missing)})")
        for name, value in params.items():
            problem = range_problem(name, value)
            if problem is not None:
                raise ValueError(problem)
        return params


class SimulationRead(_Wire):
    id: str
    state: TrialState
    status: str | None
    scenario: dict[str, Any]
    params: dict[str, float]
    seed: int
    engine: str = "numba"
    n_remaining: int | None
    responses: dict[str, float | None] | None = None
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


def page_of(page_type: type[_Wire], read_type: type[_Wire], page, limit: int, offset: int):
    """A wire page (``ShapePage``, ``SimulationPage``) of a store page of rows, each read as
    ``read_type``."""
    items = [read_type.model_validate(row) for row in page.items]
    return page_type(items=items, total=page.total, limit=limit, offset=offset)


class ErrorDetail(BaseModel):
    """Every error: a 4xx status and one message that says what to fix."""

    detail: str


class Health(BaseModel):
    status: Literal["ok", "degraded"]
    database: str
    redis: str
    workers: int | None = Field(None, description="RQ workers registered on the queue (null without Redis).")
    queued: int | None = Field(None, description="Jobs waiting on the queue (null without Redis).")
    problem: str | None = Field(None, description="Why the status is degraded, when it is.")
    version: str
