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
import functools
import json
import math
import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_serializer,
    model_validator,
)

from dem.parameters import (
    ALL_PARAMETER_NAMES,
    WALL_PARAMETER_NAMES,
    in_physical_range,
    item_parameter,
    physical_range_text,
    unknown_names_problem,
)
from dem.scenarios import registry
from optimizer.seeds import CommonSeeds


class StudyDefinitionError(ValueError):
    """A study file or definition cannot be used; the message says what to fix."""


class StudyLimitError(StudyDefinitionError):
    """A valid study asks for more than this service allows (population, simulations)."""


# Replicate numbers below this are the search's; validation runs are numbered from it, so their
# trial ids never collide with a search replicate.
MAX_REPLICATES = 99
VALIDATION_REPLICATE_BASE = 100
NOISE_FLOOR_QUANTILE = 0.9

DEFAULT_BOUNDS: dict[str, tuple[float, float]] = {
    "E": (1e5, 1e9),
    "nu": (0.0, 0.49),
    "e": (0.05, 0.95),
    "mu": (0.05, 1.0),
}
DEFAULT_BOUNDS.update({name: DEFAULT_BOUNDS[item_parameter(name)] for name in WALL_PARAMETER_NAMES})


# Larger measurements are no physical count or angle; they only overflow the target's arithmetic.
MAX_MEASURED = 1e9


class _Strict(BaseModel):
    # No Infinity or NaN anywhere: a study is computed with and stored as JSON (PostgreSQL refuses
    # them), so they are refused at creation with the field's name.
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class ParameterRange(_Strict):
    """One contact parameter: searched between ``low`` and ``high``, or ``fixed``."""

    low: float | None = None
    high: float | None = None
    fixed: float | None = None
    log: bool | None = Field(None, description="Search on a log10 scale; default true for E only.")


class Parameters(_Strict):
    """The four contact parameters of the paper's eq. 1-2, the items' material (an omitted one
    gets the default bounds), and the optional item-wall ones (``dem/parameters.py``): an omitted
    one is not a parameter of the study at all, and the walls keep the items' value."""

    E: ParameterRange = Field(default_factory=ParameterRange, description="Young's modulus, Pa.")
    nu: ParameterRange = Field(default_factory=ParameterRange, description="Poisson's ratio.")
    e: ParameterRange = Field(default_factory=ParameterRange, description="Restitution coefficient.")
    mu: ParameterRange = Field(default_factory=ParameterRange, description="Friction coefficient.")
    E_wall: ParameterRange | None = Field(
        None, description="The walls' Young's modulus, Pa (the feeder's tray, the heap's plate and "
        "cylinder); omitted: the items' E.",
    )
    nu_wall: ParameterRange | None = Field(
        None, description="The walls' Poisson's ratio (the item-wall pair's tangential stiffness); "
        "omitted: the items' nu.",
    )
    e_wall: ParameterRange | None = Field(
        None, description="Restitution of an item against the walls; omitted: the items' e."
    )
    mu_wall: ParameterRange | None = Field(
        None, description="Friction of an item against the walls; omitted: the items' mu."
    )

    @model_validator(mode="before")
    @classmethod
    def _known_names(cls, data: Any) -> Any:
        """An unknown name is refused with the names that fit (not only the nearest one)."""
        if isinstance(data, dict):
            problem = unknown_names_problem(list(data))
            if problem:
                raise ValueError(problem)
        return data

    @model_serializer(mode="wrap")
    def _without_omitted_wall(self, handler):
        """An omitted item-wall parameter is not stored: a study written before they existed
        stores and reads as it did."""
        data = handler(self)
        return {name: spec for name, spec in data.items() if spec is not None}

    def names(self) -> list[str]:
        """Every parameter the study's trials carry (searched or fixed), in the canonical order."""
        return [name for name in ALL_PARAMETER_NAMES if getattr(self, name) is not None]

    @model_validator(mode="after")
    def _complete_and_physical(self) -> Parameters:
        for name in self.names():
            spec: ParameterRange = getattr(self, name)
            if spec.fixed is not None:
                if spec.low is not None or spec.high is not None:
                    raise ValueError(f"parameters.{name}: give either 'fixed' or 'low'/'high', not both")
                if not in_physical_range(name, spec.fixed):
                    raise ValueError(
                        f"parameters.{name}.fixed = {spec.fixed:g} is outside the physical range "
                        f"{physical_range_text(name)}"
                    )
                continue
            default_low, default_high = DEFAULT_BOUNDS[name]
            spec.low = default_low if spec.low is None else spec.low
            spec.high = default_high if spec.high is None else spec.high
            spec.log = (item_parameter(name) == "E") if spec.log is None else spec.log
            for end in ("low", "high"):
                value = getattr(spec, end)
                if not in_physical_range(name, value):
                    raise ValueError(
                        f"parameters.{name}.{end} = {value:g} is outside the physical range "
                        f"{physical_range_text(name)}"
                    )
            if not spec.low < spec.high:
                raise ValueError(
                    f"parameters.{name}: low ({spec.low:g}) must be smaller than high ({spec.high:g}); "
                    "to hold it constant use 'fixed'"
                )
            if spec.log and spec.low <= 0:
                raise ValueError(f"parameters.{name}: a log-scale range needs low > 0")
        if all(getattr(self, name).fixed is not None for name in self.names()):
            raise ValueError("parameters: every parameter is fixed; leave at least one free to calibrate")
        return self

    def free(self) -> list[str]:
        """Names of the searched parameters, in the canonical order (the GA's gene order)."""
        return [name for name in self.names() if getattr(self, name).fixed is None]

    def fixed_values(self) -> dict[str, float]:
        values = {name: getattr(self, name).fixed for name in self.names()}
        return {name: value for name, value in values.items() if value is not None}


class Experiment(_Strict):
    """The measured values of one named response of the study's scenario and how the calibration
    target is formed from them."""

    response: str | None = Field(
        None,
        description="Which response of the scenario was measured (the feeder's 'n_remaining', a "
        "heap's 'angle_deg', a combined scenario's 'heap.angle_deg'); default: the scenario's first.",
    )
    measured: list[float] = Field(
        ..., min_length=1, description="Measured values, one per repetition of the experiment."
    )
    aggregate: Literal["median", "mean"] = Field(
        "median", description="How replicates (simulated) and experiments (measured) are summarised."
    )
    round: Literal["none", "half_up", "half_even"] | None = Field(
        None,
        description="Rounding of the aggregated measurement to a count: the paper used its median "
        "3.5 as 4, which is 'half_up'; 'half_even' would give 4 too but 2.5 -> 2. Default: "
        "'half_up' for an integer response, 'none' for a real one.",
    )
    tolerance: float | None = Field(
        None,
        ge=0,
        description="f1 at or below which a parameter set matches. Default: 0.5 items for "
        "'aggregate'; for 'wasserstein', the experiment's own noise floor (see noise_floor).",
    )
    distance: Literal["auto", "aggregate", "wasserstein"] = Field(
        "auto",
        description="f1: 'aggregate' = |aggregate(simulated) - target|; 'wasserstein' = the "
        "Wasserstein-1 distance between the simulated replicates and all measured values; 'auto' = "
        "wasserstein with 3 or more replicates (f1 of a distribution, not of one lucky run), else "
        "aggregate.",
    )

    @field_validator("measured")
    @classmethod
    def _finite(cls, values: list[float]) -> list[float]:
        for index, value in enumerate(values):
            if not math.isfinite(value):
                raise ValueError(f"measured[{index}] = {value} must be a finite number")
        return values

    def target(self) -> float:
        """The value simulations must reproduce, with the rounding rule applied."""
        return round_count(aggregate(self.measured, self.aggregate), self.round or "half_up")

    def noise_floor(self, replicates: int, quantile: float = NOISE_FLOOR_QUANTILE) -> float:
        """The W1 a perfect model would show: the ``quantile`` of the Wasserstein-1 distance
        between ``replicates`` values drawn from the measured ones and the measured ones (a
        deterministic bootstrap). A tolerance below it would reject the experiment itself."""
        from optimizer.noise import wasserstein_floor

        return round(wasserstein_floor(self.measured, replicates, quantile), 2)


class Validation(_Strict):
    """The end of every study: the recommendation and the next candidates re-simulated on fresh
    seeds never used in the search (``optimizer/validation.py``)."""

    seeds: int = Field(
        10, ge=0, le=200, description="Fresh seeds per candidate; 0 skips the validation."
    )
    candidates: int = Field(
        3, ge=1, le=20, description="The search's best candidates validated (optimizer/validation.py)."
    )

    def simulations(self) -> int:
        return self.seeds * self.candidates


class GASettings(_Strict):
    """The genetic algorithm: pymoo's NSGA-II with the paper's operators by default."""

    algorithm: Literal["nsga2", "spea2", "random", "surrogate"] = Field(
        "nsga2",
        description="'nsga2' (the paper's elitist MOGA), 'spea2' (strength Pareto archive), "
        "'random' (uniform random search with the same budget: the honest baseline), or "
        "'surrogate' (Gaussian-process models choose each batch; fewest simulations).",
    )
    population: int = Field(50, ge=2, description="Initial population (simulated in generation 0).")
    offspring: int = Field(15, ge=1, description="New individuals per generation.")
    generations: int = Field(9, ge=0, description="Generations after the initial population.")
    survivors: int | None = Field(
        None,
        ge=2,
        description="Individuals the elitist selection carries over to each next generation, the "
        "parents of its offspring (the paper: 50 initial, 15 carried over). Default: the whole "
        "population, so that a generation only drops its worst ga.offspring sets.",
    )
    crossover_prob: float = Field(0.98, ge=0, le=1, description="One-point crossover probability.")
    mutation_prob: float = Field(0.02, ge=0, le=1, description="Polynomial mutation probability per gene.")
    match_estimate: Literal["own", "neighbours"] = Field(
        "own",
        description="What nsga2 and spea2 rank a set's match on: 'own' (f1 of its own runs) or "
        "'neighbours' (its runs pooled with those of nearby sets, weighted by distance in genes: "
        "a noise-aware estimate at no extra simulation, optimizer/neighbours.py).",
    )

    @model_validator(mode="after")
    def _estimate_for_a_ga(self) -> GASettings:
        if self.match_estimate == "neighbours" and self.algorithm not in ("nsga2", "spea2"):
            raise ValueError(
                f"ga.match_estimate = 'neighbours' applies to 'nsga2' and 'spea2', not to "
                f"'{self.algorithm}' (the surrogate models the response itself; random search ranks "
                "nothing): remove it or choose a GA"
            )
        return self

    @model_validator(mode="after")
    def _survivors_of_a_ga(self) -> GASettings:
        if self.survivors is None:
            return self
        if self.algorithm not in ("nsga2", "spea2"):
            raise ValueError(
                f"ga.survivors applies to 'nsga2' and 'spea2', not to '{self.algorithm}' (it keeps no "
                "population): remove it or choose a GA"
            )
        if self.survivors > self.population:
            raise ValueError(
                f"ga.survivors = {self.survivors} exceeds ga.population = {self.population}: the first "
                "selection chooses the survivors from the initial population; use at most "
                f"{self.population}"
            )
        return self

    def survivors_kept(self) -> int:
        """How many sets each survival keeps (the GA's population after generation 0)."""
        return self.population if self.survivors is None else self.survivors

    def individuals(self) -> int:
        return self.population + self.offspring * self.generations


class StudyDefinition(_Strict):
    """Everything a study needs; stored as JSON, so the scenario is always inline."""

    name: str = Field("study", min_length=1, max_length=120, pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
    description: str = ""
    scenario: registry.ScenarioConfig = Field(
        ...,
        description="The scenario's configuration as a table; its 'kind' (default 'feeder') picks the "
        "scenario from dem.scenarios.registry, whose config model validates the rest.",
    )
    engine: str = Field(
        "numba",
        description="The engine that runs the simulations: 'numba' (built in), 'liggghts', or "
        "'command' with engine_options (dem/engines).",
    )
    engine_options: dict[str, Any] = Field(
        default_factory=dict,
        description="The engine's options: the command engine's template, command and patterns; "
        "LIGGGHTS' binary.",
    )
    parameters: Parameters = Field(default_factory=Parameters)
    experiments: list[Experiment] = Field(
        ...,
        min_length=1,
        description="One or more experiments, each the measured values of one response. Several "
        "are combined into one match objective f1 = max over experiments of |simulated - target| / "
        "tolerance, so f1 <= 1 means every experiment matches (see optimizer/objectives.py). "
        "'experiment = {...}' is accepted for one.",
    )
    ga: GASettings = Field(default_factory=GASettings)
    replicates: int = Field(
        1,
        ge=1,
        le=MAX_REPLICATES,
        description="Simulations per individual, on the seeds common_seeds says.",
    )
    common_seeds: CommonSeeds = Field(
        "generation",
        description="Which simulations share a seed: 'generation' (replicate r of every set of a "
        "generation; new seeds each generation), 'study' (replicate r, for the whole study) or "
        "'trial' (none: every simulation its own seed). Why each: optimizer/seeds.py.",
    )
    max_replicates: int | None = Field(
        None,
        ge=1,
        le=MAX_REPLICATES,
        description="Adaptive replicates: sets on or near the front (matching, or whose f1 interval "
        "reaches the tolerance) earn replicates up to this many, inside the budget, and only a "
        "set with this many can be recommended. Default: replicates (no extra replicates).",
    )
    budget: int | None = Field(
        None,
        ge=1,
        description="Simulations the study may run in all: the search (individuals x replicates), "
        "the extra replicates, and the validation. What is left after the search and the "
        "validation is the pool of extra replicates. Default: the search, plus (max_replicates - "
        "replicates) x ga.offspring extra replicates, plus the validation.",
    )
    validation: Validation = Field(default_factory=Validation)
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

    @model_validator(mode="before")
    @classmethod
    def _one_experiment(cls, data: Any) -> Any:
        """``experiment = {...}`` (one experiment, and every study stored before several existed)."""
        if isinstance(data, dict) and "experiment" in data:
            if "experiments" in data:
                raise ValueError("give either 'experiment' (one) or 'experiments' (a list), not both")
            from dem.scenarios.base import error_line

            try:  # errors name the key the user wrote: experiment.measured, not experiments.0.measured
                Experiment.model_validate(data["experiment"])
            except ValidationError as exc:
                raise ValueError(
                    "; ".join(error_line(err, Experiment, "experiment") for err in exc.errors())
                ) from None
            data = {**data, "experiments": [data["experiment"]]}
            del data["experiment"]
        return data

    @model_validator(mode="after")
    def _responses_and_engine(self) -> StudyDefinition:
        """Every experiment names a response the scenario measures; the engine can run it."""
        from dem.engines.base import UnknownEngineError, parameters_refusal, refusal

        scenario = registry.get(self.scenario.kind)
        declared = {r.name: r for r in scenario.declared(self.scenario)}
        for index, experiment in enumerate(self.experiments):
            name = experiment.response or next(iter(declared))
            if name not in declared:
                raise ValueError(
                    f"experiments[{index}].response: scenario {scenario.kind!r} has no response "
                    f"{name!r}; it measures {', '.join(declared)}"
                )
            experiment.response = name
            if experiment.round is None:
                experiment.round = "half_up" if declared[name].integer else "none"
        try:
            problem = refusal(self.engine, scenario, self.scenario, self.engine_options)
            problem = problem or parameters_refusal(self.engine, self.parameters.names())
        except UnknownEngineError as exc:
            raise ValueError(f"engine: {exc}") from None
        if problem:
            raise ValueError(f"engine: {problem}")
        return self

    @property
    def experiment(self) -> Experiment:
        """The first experiment (the only one in most studies)."""
        return self.experiments[0]

    def measured_by_response(self) -> dict[str, list[float]]:
        """Each experiment's measured values, by the response it measures."""
        return {experiment.response: list(experiment.measured) for experiment in self.experiments}

    def match_tolerance(self) -> float:
        """f1 at or below which a parameter set matches: the experiment's tolerance, or 1 when
        several experiments are combined (each distance is divided by its own tolerance)."""
        return self.experiments[0].tolerance if len(self.experiments) == 1 else 1.0

    @model_validator(mode="before")
    @classmethod
    def _former_elite_reevaluation(cls, data: Any) -> Any:
        """Definitions stored before adaptive replicates: elite_reevaluation = k meant k more
        seeds for every matching set; it becomes max_replicates = replicates + k."""
        if isinstance(data, dict) and "elite_reevaluation" in data:
            data = dict(data)
            extra = data.pop("elite_reevaluation") or 0
            if extra and data.get("max_replicates") is None:
                data["max_replicates"] = int(data.get("replicates", 1)) + int(extra)
        return data

    @model_validator(mode="after")
    def _resolve_and_fit_the_budget(self) -> StudyDefinition:
        """Resolve the defaults that depend on replicates; refuse a budget that cannot hold the
        search and the validation, saying what fits."""
        for experiment in self.experiments:
            if experiment.distance == "auto":
                experiment.distance = "wasserstein" if self.replicates >= 3 else "aggregate"
            if experiment.tolerance is None:
                wasserstein = experiment.distance == "wasserstein"
                experiment.tolerance = experiment.noise_floor(self.replicates) if wasserstein else 0.5
        if self.max_replicates is None:
            self.max_replicates = self.replicates
        if self.max_replicates < self.replicates:
            raise ValueError(
                f"max_replicates ({self.max_replicates}) must be at least replicates ({self.replicates})"
            )
        if self.budget is None:
            self.budget = self.search_simulations() + self._default_pool() + self.validation.simulations()
        needed = self.search_simulations() + self.validation.simulations()
        if self.budget < needed:
            raise ValueError(self._what_fits(needed))
        return self

    def _default_pool(self) -> int:
        return (self.max_replicates - self.replicates) * self.ga.offspring

    def fits_within(self, budget: int) -> list[str]:
        """The changes, one field each, that would make the search and the validation fit."""
        ga, checks, search = self.ga, self.validation.simulations(), self.search_simulations()
        fits = []
        if budget - checks >= ga.individuals():
            fits.append(f"replicates <= {(budget - checks) // ga.individuals()}")
        room = (budget - checks) // self.replicates - ga.offspring * ga.generations
        if room >= 2:
            fits.append(f"ga.population <= {room}")
        if budget - search >= 0:
            fits.append(f"validation.seeds <= {(budget - search) // self.validation.candidates}")
        return fits

    def _what_fits(self, needed: int) -> str:
        ga, budget = self.ga, self.budget
        fits = self.fits_within(budget)
        hint = ("; within it: " + ", or ".join(fits)) if fits else ""
        return (
            f"budget = {budget} simulations cannot hold the search ((ga.population {ga.population} + "
            f"ga.offspring {ga.offspring} x ga.generations {ga.generations}) x replicates "
            f"{self.replicates} = {self.search_simulations()}) and the validation (validation.seeds "
            f"{self.validation.seeds} x validation.candidates {self.validation.candidates} = "
            f"{self.validation.simulations()}): {needed} are needed{hint}, or raise budget to {needed}"
        )

    def validity_warning(self) -> str | None:
        """A warning when the E bounds reach below the E at which the contact model's overlap
        limit is likely exceeded at insertion (``dem.scenarios.feeder.softest_valid_E``)."""
        return _validity_warning(self.scenario.model_dump_json(), self.parameters.model_dump_json())

    @model_validator(mode="after")
    def _target_computable(self) -> StudyDefinition:
        """The driver computes with the target at every batch: a measurement it cannot aggregate
        and round (1e308 overflows the rounding) is refused here, not found out mid-study."""
        measured = self.experiment.measured
        if any(abs(value) > MAX_MEASURED for value in measured):
            raise ValueError(
                f"experiment.measured: {measured} holds a value above {MAX_MEASURED:g}; measured "
                "values are counts or angles"
            )
        try:
            self.experiment.target()
        except (ArithmeticError, ValueError) as exc:
            message = f"experiment.measured: no target can be computed from {measured} ({exc})"
            raise ValueError(message) from None
        return self

    def total_simulations(self) -> int:
        """The budget: the most simulations the study runs (search, extra replicates, validation)."""
        return int(self.budget)

    def search_simulations(self) -> int:
        """Every individual of the GA with its replicates."""
        return self.ga.individuals() * self.replicates

    def replicate_pool(self) -> int:
        """Simulations left for extra replicates of promising sets."""
        return self.total_simulations() - self.search_simulations() - self.validation.simulations()

    # The phases of a study, as batch indices: 0 .. G the GA's generations (each may carry extra
    # replicates of earlier sets), G + 1 the last extra replicates, G + 2 the validation.
    def replicate_batch(self) -> int:
        return self.ga.generations + 1

    def validation_batch(self) -> int:
        return self.ga.generations + 2

    def phase(self, batch: int) -> str:
        """'search', 'replicates' or 'validation': what a batch (a trial's generation) is."""
        if batch <= self.ga.generations:
            return "search"
        return "replicates" if batch == self.replicate_batch() else "validation"

    def n_items(self) -> int:
        """What the first experiment's response counts as for a failed simulation (the feeder:
        every item retained); f1 of a failed individual with one experiment."""
        failed = registry.get(self.scenario.kind).failed_responses(self.scenario)
        return failed[self.experiments[0].response]

    def declared_responses(self) -> dict:
        """The scenario's responses by name (``dem.scenarios.base.Response``: unit, integer, label)."""
        return {r.name: r for r in registry.get(self.scenario.kind).declared(self.scenario)}

    def failed_responses(self) -> dict[str, float]:
        """Every response's value for a failed simulation."""
        return registry.get(self.scenario.kind).failed_responses(self.scenario)


@functools.lru_cache(maxsize=64)
def _validity_warning(scenario_json: str, parameters_json: str) -> str | None:
    from dem.scenarios.feeder import softest_valid_E
    from dem.scenarios.feeder_config import FeederConfig

    parameters = Parameters.model_validate_json(parameters_json)
    try:
        config = FeederConfig.model_validate_json(scenario_json)
    except ValueError:
        return None  # not the feeder: its insertion drop is what the estimate knows
    if parameters.E is None or parameters.e is None:
        return None
    E, e = parameters.E, parameters.e
    e_low, e_high = (e.fixed, e.fixed) if e.fixed is not None else (e.low, e.high)
    E_low, E_high = (E.fixed, E.fixed) if E.fixed is not None else (E.low, E.high)
    elastic = softest_valid_E(config, e_high)  # the least damped impact goes deepest
    damped = softest_valid_E(config, e_low)
    if E_low >= elastic:
        return None
    basis = (
        "estimated from the insertion drop of the heaviest item against the overlap limit of the "
        "linear contact model; such runs end 'invalid' and count as constraint violations"
    )
    if E_high < damped:
        return (
            f"parameters.E lies entirely below about {damped:.2g} Pa, where runs are expected to be "
            f"invalid even at e = {e_low:g} ({basis}); raise parameters.E above {elastic:.2g} Pa"
        )
    if E.fixed is not None:
        share = "the fixed E"
    else:
        span = math.log10(E_high / E_low)
        below = (math.log10(min(elastic, E_high) / E_low) / span) if span > 0 else 1.0
        share = f"{below:.0%} of the E range (log scale)"
    return (
        f"parameters.E reaches down to {E_low:.3g} Pa: below about {elastic:.2g} Pa (e = {e_high:g}; "
        f"{damped:.2g} Pa at e = {e_low:g}) runs are likely to be invalid, {share} ({basis})"
    )


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
        from dem.scenarios.registry import load_config_file

        data["scenario"] = load_config_file(path).model_dump(mode="json")
    options = data.get("engine_options")
    if isinstance(options, dict) and isinstance(options.get("template"), str):
        template = Path(options["template"])
        if not template.is_absolute():
            data["engine_options"] = {**options, "template": str((base_dir or Path.cwd()) / template)}
    from dem.scenarios.paths import READ_FILES

    return StudyDefinition.model_validate(data, context=READ_FILES)  # the user's own files


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
    """pydantic's errors as one line per field, in the study file's own key names; an unknown key
    names the nearest valid one."""
    from dem.scenarios.base import error_line

    return "; ".join(error_line(err, StudyDefinition) for err in exc.errors())


def check_limits(definition: StudyDefinition, *, max_population: int, max_simulations: int) -> None:
    """Refuse a study bigger than the service allows; the message names the field and the limit."""
    if definition.ga.population > max_population:
        raise StudyLimitError(
            f"ga.population = {definition.ga.population} exceeds this service's limit of "
            f"{max_population} (DEMCAL_MAX_POPULATION)"
        )
    total = definition.total_simulations()
    if total > max_simulations:
        needed = definition.search_simulations() + definition.validation.simulations()
        if needed <= max_simulations:
            advice = f"set budget <= {max_simulations}"
        else:
            advice = ", or ".join(definition.fits_within(max_simulations)) or "make the study smaller"
        raise StudyLimitError(
            f"the study needs up to {total} simulations (search {definition.search_simulations()}, "
            f"extra replicates {definition.replicate_pool()}, validation "
            f"{definition.validation.simulations()}); this service allows {max_simulations} "
            f"(DEMCAL_MAX_SIMULATIONS): {advice}"
        )
