"""What one simulation returns: the response (N_t, discharge times), what it cost, and how it
ended. This is the only dem type the optimiser and the workers exchange, so it is plain data
that round-trips through JSON (``model_dump(mode="json")`` / ``model_validate``).
"""

from __future__ import annotations

from enum import StrEnum

from pydantic import BaseModel, Field


class SimulationStatus(StrEnum):
    """How a run ended. Only ``ok`` carries a response the optimiser can trust."""

    OK = "ok"
    UNSTABLE = "unstable"  # blow-up detected (NaN, absurd velocity or overlap); physics, not retried
    TIMEOUT = "timeout"  # the deadline passed between two chunks
    CANCELLED = "cancelled"  # asked to stop between two chunks
    ERROR = "error"  # an exception; ``message`` says which


class SimulationResult(BaseModel):
    """One simulation's outcome. Times are simulated seconds unless the name says wall."""

    status: SimulationStatus
    message: str = ""
    n_items: int = Field(0, ge=0, description="Bodies created.")
    n_remaining: int | None = Field(None, ge=0, description="N_t: items still in the tray at the end.")
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
    params: dict[str, float] = Field(default_factory=dict)
    seed: int = 0
    version: str = ""

    @property
    def ok(self) -> bool:
        return self.status is SimulationStatus.OK
