"""What one simulation returns: the response (N_t, discharge times), what it cost, and how it
ended. This is the only dem type the optimiser and the workers exchange, so it is plain data
that round-trips through JSON (``model_dump(mode="json")`` / ``model_validate``).
"""

from __future__ import annotations

from enum import StrEnum

from pydantic import BaseModel, Field, model_validator

# The range of validity of the linear contact model: an overlap beyond this fraction of a sphere
# radius, reached while the step resolves the contact, makes a run ``invalid``. The engine's
# ``Simulation(overlap_limit=...)`` defaults to it.
OVERLAP_LIMIT = 0.5


class SimulationStatus(StrEnum):
    """How a run ended. Only ``ok`` carries a response the optimiser can trust."""

    OK = "ok"
    # The contact model left its range of validity: an overlap beyond the stated fraction of a
    # sphere radius while the step resolved the contact, so the overlap is physical (too soft a
    # material for the impacts), not numerical. The parameters are outside the model, not the run.
    INVALID = "invalid"
    UNSTABLE = "unstable"  # numerical blow-up (NaN, absurd speed, a step too long for the contact)
    TIMEOUT = "timeout"  # the deadline passed between two chunks
    CANCELLED = "cancelled"  # asked to stop between two chunks
    ERROR = "error"  # an exception; ``message`` says which


class SimulationResult(BaseModel):
    """One simulation's outcome. Times are simulated seconds unless the name says wall."""

    status: SimulationStatus
    message: str = ""
    n_items: int = Field(0, ge=0, description="Bodies created.")
    n_remaining: int | None = Field(None, ge=0, description="N_t: items still in the tray at the end.")
    responses: dict[str, int | float | None] = Field(
        default_factory=dict,
        description="The scenario's named responses (dem.scenarios.base.Response), None if not measured.",
    )
    engine: str = Field("numba", description="The engine that ran it (dem/engines).")
    discharge_times: list[float | None] = Field(
        default_factory=list, description="Per item, the simulated time it left; None if it stayed."
    )
    emptied_at: float | None = Field(None, description="Simulated time the tray emptied, if it did.")
    sim_time: float = Field(0.0, ge=0, description="Simulated seconds reached.")
    wall_time_s: float = Field(0.0, ge=0, description="T: wall-clock seconds of the run.")
    steps: int = Field(0, ge=0)
    dt: float = Field(0.0, ge=0, description="Time step in seconds.")
    cost: float = Field(
        0.0, ge=0, description="Machine-independent cost: sum over steps of (spheres + contacts)."
    )
    full_load_factor: float = Field(
        1.0,
        ge=1.0,
        description="The protocol's body-seconds over this run's: how much more work the whole "
        "protocol would take with every body kept to its end (1 when none left early). A run that "
        "empties the tray stops early and does less work; T x this factor prices the parameters, "
        "not the outcome (optimizer/objectives.py).",
    )
    max_overlap: float | None = Field(
        None,
        ge=0,
        description="Largest overlap seen, as a fraction of the smaller sphere's radius (sampled at "
        "the end of every chunk; for an 'invalid' run, the offending overlap).",
    )
    params: dict[str, float] = Field(default_factory=dict)
    seed: int = 0
    version: str = ""

    @model_validator(mode="before")
    @classmethod
    def _responses_of_older_results(cls, data):
        """Results stored before responses had names carry N_t only: it is the feeder's response."""
        if isinstance(data, dict) and not data.get("responses") and data.get("n_remaining") is not None:
            data = {**data, "responses": {"n_remaining": data["n_remaining"]}}
        return data

    @property
    def ok(self) -> bool:
        return self.status is SimulationStatus.OK
