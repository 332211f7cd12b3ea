"""A calibration study's definition: what to simulate, what to search, what to match, how hard to
try. Read from TOML or JSON, validated by pydantic, stored as JSON (``model_dump(mode="json")``)
so that a worker or a restarted server needs nothing else: a scenario given by path is read and
inlined when the file is loaded.

Defaults are the paper's protocol (Kawaguchi et al., Mater. Trans. 62(4), 2021, ch. 2.3-2.4):
population 50, 15 offspring per generation, 9 generations (50 + 9 x 15 = 185 simulations),
one-point crossover p = 0.98, mutation p = 0.02, one simulation per individual, target N_t = the
median of the ten experiments (3.5) used as 4 (``round = "half_up"``).

This module only describes and checks a study; it must not run anything, touch a database or know
about the GA's internals. Service limits (largest population, largest budget) are checked by
:func:`check_limits`, which the API calls with its settings.
"""

from __future__ import annotations

import decimal
import json
import math
import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from optimizer.protocols import PARAMETER_NAMES


class StudyDefinitionError(ValueError):
    """A study file or definition cannot be used; the message says what to fix."""


class StudyLimitError(StudyDefinitionError):
    """A valid study asks for more than this service allows (population, simulations)."""


# Physical ranges: open bounds are excluded (E > 0, -1 < nu < 0.5, 0 < e <= 1, mu >= 0).
PHYSICAL_RANGES: dict[str, tuple[float, float, bool, bool]] = {
    # name: (low, high, low inclusive, high inclusive)
    "E": (0.0, math.inf, False, False),
    "nu": (-1.0, 0.5, False, False),
    "e": (0.0, 1.0, False, True),
    "mu": (0.0, math.inf, True, False),
}

UNITS = {"E": "Pa", "nu": "-", "e": "-", "mu": "-"}

DEFAULT_BOUNDS: dict[str, tuple[float, float]] = {
    "E": (1e5, 1e9),
    "nu": (0.0, 0.49),
    "e": (0.05, 0.95),
    "mu": (0.05, 1.0),
}


def _physical(name: str, value: float) -> bool:
    low, high, low_in, high_in = PHYSICAL_RANGES[name]
    above = value >= low if low_in else value > low
    below = value <= high if high_in else value < high
    return above and below and math.isfinite(value)


def _range_text(name: str) -> str:
    low, high, low_in, high_in = PHYSICAL_RANGES[name]
    return f"{'[' if low_in else '('}{low:g}, {high:g}{']' if high_in else ')'}"


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ParameterRange(_Strict):
    """One contact parameter: searched between ``low`` and ``high``, or ``fixed``."""

    low: float | None = None
    high: float | None = None
    fixed: float | None = None
    log: bool | None = Field(None, description="Search on a log10 scale; default true for E only.")


class Parameters(_Strict):
    """The four contact parameters of the paper's eq. 1-2; an omitted one gets the default bounds."""

    E: ParameterRange = Field(default_factory=ParameterRange, description="Young's modulus, Pa.")
    nu: ParameterRange = Field(default_factory=ParameterRange, description="Poisson's ratio.")
    e: ParameterRange = Field(default_factory=ParameterRange, description="Restitution coefficient.")
    mu: ParameterRange = Field(default_factory=ParameterRange, description="Friction coefficient.")

    @model_validator(mode="after")
    def _complete_and_physical(self) -> Parameters:
        for name in PARAMETER_NAMES:
            spec: ParameterRange = getattr(self, name)
            if spec.fixed is not None:
                if spec.low is not None or spec.high is not None:
                    raise ValueError(f"parameters.{name}: give either 'fixed' or 'low'/'high', not both")
                if not _physical(name, spec.fixed):
                    raise ValueError(
                        f"parameters.{name}.fixed = {spec.fixed:g} is outside the physical range "
                        f"{_range_text(name)}"
                    )
                continue
            default_low, default_high = DEFAULT_BOUNDS[name]
            spec.low = default_low if spec.low is None else spec.low
            spec.high = default_high if spec.high is None else spec.high
            spec.log = (name == "E") if spec.log is None else spec.log
            for end in ("low", "high"):
                value = getattr(spec, end)
                if not _physical(name, value):
                    raise ValueError(
                        f"parameters.{name}.{end} = {value:g} is outside the physical range "
                        f"{_range_text(name)}"
                    )
            if not spec.low < spec.high:
                raise ValueError(
                    f"parameters.{name}: low ({spec.low:g}) must be smaller than high ({spec.high:g}); "
                    "to hold it constant use 'fixed'"
                )
            if spec.log and spec.low <= 0:
                raise ValueError(f"parameters.{name}: a log-scale range needs low > 0")
        if all(getattr(self, name).fixed is not None for name in PARAMETER_NAMES):
            raise ValueError("parameters: every parameter is fixed; leave at least one free to calibrate")
        return self

    def free(self) -> list[str]:
        """Names of the searched parameters, in the canonical order (the GA's gene order)."""
        return [name for name in PARAMETER_NAMES if getattr(self, name).fixed is None]

    def fixed_values(self) -> dict[str, float]:
        values = {name: getattr(self, name).fixed for name in PARAMETER_NAMES}
        return {name: value for name, value in values.items() if value is not None}


class Experiment(_Strict):
    """The measured response and how the calibration target is formed from it."""

    measured: list[float] = Field(
        ..., min_length=1, description="Measured N_t of each experiment (items left in the tray)."
    )
    aggregate: Literal["median", "mean"] = Field(
        "median", description="How replicates (simulated) and experiments (measured) are summarised."
    )
    round: Literal["none", "half_up", "half_even"] = Field(
        "half_up",
        description="Rounding of the aggregated measurement to an item count: the paper used its "
        "median 3.5 as 4, which is 'half_up'; 'half_even' would give 4 too but 2.5 -> 2.",
    )
    tolerance: float = Field(
        0.5, ge=0, description="|simulated - target| at or below which a parameter set matches."
    )
    distance: Literal["aggregate", "wasserstein"] = Field(
        "aggregate",
        description="f1: 'aggregate' = |aggregate(simulated) - target|; 'wasserstein' = the "
        "Wasserstein-1 distance between the simulated replicates and all measured values.",
    )

    @field_validator("measured")
    @classmethod
    def _counts(cls, values: list[float]) -> list[float]:
        for index, value in enumerate(values):
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"measured[{index}] = {value} must be a finite count >= 0")
        return values

    def target(self) -> float:
        """The value simulations must reproduce, with the rounding rule applied."""
        return round_count(aggregate(self.measured, self.aggregate), self.round)


class GASettings(_Strict):
    """The genetic algorithm: pymoo's NSGA-II with the paper's operators by default."""

    algorithm: Literal["nsga2", "spea2", "random"] = Field(
        "nsga2",
        description="'nsga2' (the paper's elitist MOGA), 'spea2' (strength Pareto archive), or "
        "'random' (uniform random search with the same budget: the honest baseline).",
    )
    population: int = Field(50, ge=2, description="Initial population (simulated in generation 0).")
    offspring: int = Field(15, ge=1, description="New individuals per generation.")
    generations: int = Field(9, ge=0, description="Generations after the initial population.")
    crossover_prob: float = Field(0.98, ge=0, le=1, description="One-point crossover probability.")
    mutation_prob: float = Field(0.02, ge=0, le=1, description="Polynomial mutation probability per gene.")

    def individuals(self) -> int:
        return self.population + self.offspring * self.generations


class StudyDefinition(_Strict):
    """Everything a study needs; stored as JSON, so the scenario is always inline."""

    name: str = Field("study", min_length=1, max_length=120, pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
    description: str = ""
    scenario: dict[str, Any] = Field(
        ..., description="The feeder configuration (dem.scenarios.feeder.FeederConfig) as a table."
    )
    parameters: Parameters = Field(default_factory=Parameters)
    experiment: Experiment
    ga: GASettings = Field(default_factory=GASettings)
    replicates: int = Field(
        1, ge=1, le=100, description="Simulations per individual, each with its own seed."
    )
    elite_reevaluation: int = Field(
        0,
        ge=0,
        le=100,
        description="After the last generation, re-simulate every matching parameter set with this "
        "many fresh seeds and rank on all its simulations (guards against a lucky seed).",
    )
    objective_time: Literal["wall", "cost"] = Field(
        "cost",
        description="f2: 'wall' = wall seconds T (the paper); 'cost' = the machine-independent cost "
        "(sum over steps of spheres + contacts), reproducible and fair across workers.",
    )
    trial_timeout_s: float | None = Field(
        None, gt=0, description="Wall-clock limit of one simulation; a slower one ends as 'timeout'."
    )
    seed: int = Field(0, ge=0, le=2**31 - 1, description="Seeds the GA and every simulation.")
    keep_snapshots: bool = Field(
        False,
        description="Workers keep every trial's snapshots (bodies every scenario run.snapshot_interval) "
        "under <data dir>/snapshots/<trial id>/ so the dashboard can replay the run.",
    )

    @field_validator("scenario")
    @classmethod
    def _feeder_config(cls, scenario: dict[str, Any]) -> dict[str, Any]:
        from dem.scenarios.feeder import FeederConfig

        try:
            return FeederConfig.model_validate(scenario).model_dump(mode="json")
        except ValidationError as exc:
            problems = "; ".join(
                f"scenario.{'.'.join(str(part) for part in err['loc'])}: {err['msg']}" for err in exc.errors()
            )
            raise ValueError(problems) from None

    def total_simulations(self) -> int:
        """The budget: every individual x replicates, plus the final re-evaluation's upper bound."""
        return self.ga.individuals() * self.replicates + self.reevaluation_upper_bound()

    def reevaluation_upper_bound(self) -> int:
        return self.ga.individuals() * self.elite_reevaluation

    def n_items(self) -> int:
        """Items in the scenario: the worst possible N_t, used to penalise failed simulations."""
        from dem.scenarios.feeder import FeederConfig

        return sum(FeederConfig.model_validate(self.scenario).items.counts.values())


def aggregate(values: list[float], how: str) -> float:
    ordered = sorted(values)
    if how == "mean":
        return sum(ordered) / len(ordered)
    middle = len(ordered) // 2
    return ordered[middle] if len(ordered) % 2 else (ordered[middle - 1] + ordered[middle]) / 2


def round_count(value: float, rule: str) -> float:
    """Round with an explicit rule; Python's round() is half-even, which is why this exists."""
    if rule == "none":
        return value
    mode = decimal.ROUND_HALF_UP if rule == "half_up" else decimal.ROUND_HALF_EVEN
    return float(decimal.Decimal(repr(value)).quantize(decimal.Decimal(1), rounding=mode))


def parse_study(data: dict[str, Any], base_dir: Path | None = None) -> StudyDefinition:
    """Validate a study given as a mapping; ``scenario_path`` is read relative to ``base_dir``."""
    data = dict(data)
    scenario_path = data.pop("scenario_path", None)
    if scenario_path is not None:
        if "scenario" in data:
            raise StudyDefinitionError("give either 'scenario' (inline) or 'scenario_path', not both")
        path = Path(scenario_path)
        if not path.is_absolute():
            path = (base_dir or Path.cwd()) / path
        if not path.is_file():
            raise StudyDefinitionError(f"scenario_path: no such file {path}")
        from dem.scenarios.feeder import load_feeder_config

        data["scenario"] = load_feeder_config(path).model_dump(mode="json")
    return StudyDefinition.model_validate(data)


def load_study_file(path: str | Path) -> StudyDefinition:
    """Read a study from a .toml or .json file; errors name the file and the field."""
    path = Path(path)
    if not path.is_file():
        raise StudyDefinitionError(f"no study file at {path}")
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(path.read_text())
        else:
            data = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise StudyDefinitionError(f"{path}: not valid {path.suffix.lstrip('.').upper()}: {exc}") from None
    try:
        return parse_study(data, base_dir=path.parent)
    except ValidationError as exc:
        raise StudyDefinitionError(f"{path}: {describe_validation_error(exc)}") from None


def describe_validation_error(exc: ValidationError) -> str:
    """pydantic's errors as one line per field, in the study file's own key names."""
    problems = []
    for err in exc.errors():
        where = ".".join(str(part) for part in err["loc"])
        message = err["msg"].removeprefix("Value error, ")
        problems.append(message if not where or message.startswith(where) else f"{where}: {message}")
    return "; ".join(problems)


def check_limits(definition: StudyDefinition, *, max_population: int, max_simulations: int) -> None:
    """Refuse a study bigger than the service allows; the message names the field and the limit."""
    if definition.ga.population > max_population:
        raise StudyLimitError(
            f"ga.population = {definition.ga.population} exceeds this service's limit of "
            f"{max_population} (DEMCAL_MAX_POPULATION)"
        )
    total = definition.total_simulations()
    if total > max_simulations:
        raise StudyLimitError(
            f"the study needs up to {total} simulations ((ga.population + ga.offspring x "
            f"ga.generations) x (replicates + elite_reevaluation)); this service allows "
            f"{max_simulations} (DEMCAL_MAX_SIMULATIONS)"
        )
