"""The driver: advances a study through an Executor (runs trials) and a Store (keeps the truth).

One study is a sequence of *batches*: batch 0 is the initial population, batch k (1..G) the
offspring of generation k together with the extra replicates earlier sets earned
(``optimizer/replicates.py``), batch G + 1 the last extra replicates, batch G + 2 the validation
of the best candidates on fresh seeds (``optimizer/validation.py``); an empty batch
completes at once. ``StudyRecord.generation`` counts completed batches. The search gets
objectives and constraints (``optimizer/ga.py``): the match first, invalid runs as violations.

    load study -> (paused/cancelled: withdraw its work; done: nothing)
    current batch: GA state from the store (or a new search) -> ask -> store trials as pending
    submit pending trials (and, on start and every ``reconcile_every_s``, re-submit queued or
    running trials the executor no longer knows: lost with a restarted process or a flushed queue)
    poll the executor -> record each outcome once (the store ignores duplicates)
    batch complete -> objectives -> tell -> Pareto + recommendation -> save_generation (atomic,
    with the objectives of the batch's individuals: the store computes nothing)
    last batch saved -> status done

No round trips on the data path: the driver keeps a copy of each study's trials, read whole on
start and at each reconciliation and otherwise only what changed since the last poll
(``Store.changed_trials``); its own writes (queued, results) go into the copy as it makes them,
and only an individual that gained a result is evaluated again, so a poll costs the same on a
study of ten trials or ten thousand.

Two ways to use it:

- ``Driver.run_to_completion(study_id)``: the embedded ``demcal calibrate`` loop.
- ``Driver.step(study_id, timeout)``: bounded work (at most one poll of ``timeout`` seconds and
  one batch completion) that returns a :class:`Progress`; the service's background loop calls it
  round-robin over its running studies with one shared executor. Outcomes of any study polled in
  one step are recorded, so sharing the executor loses nothing.

Resuming needs nothing but the store: a new driver on the same store re-asks the GA from the
state saved after the last completed batch (the search is deterministic, so it proposes the same
individuals; the stored trials win if they differ: parameters and seeds), keeps every recorded result and
re-submits only what has none. The study's status is re-read at every step, so pause and cancel
take effect within one poll.

The driver never imports RQ, Redis, SQLAlchemy or FastAPI; it only knows the protocols.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from pydantic import ValidationError

from dem.result import SimulationStatus
from optimizer import validation
from optimizer.ga import Search, create_search, from_bytes, to_bytes
from optimizer.neighbours import PooledMatch, pooled_evidence
from optimizer.objectives import Evaluation, evaluate, match_rule, observation
from optimizer.outcomes import shown_objectives
from optimizer.pareto import Ranking, rank, recommendation_json, summary
from optimizer.protocols import (
    ACTIVE_STUDIES,
    IN_FLIGHT,
    STOPPING_STUDIES,
    Executor,
    Store,
    StudyRecord,
    StudyStatus,
    TrialOutcome,
    TrialRecord,
    TrialSpec,
    TrialState,
    is_trial_of,
    study_of,
    trial_id,
)
from optimizer.replicates import allocate
from optimizer.seeds import search_seed, validation_seeds
from optimizer.space import ParameterSpace
from optimizer.study import VALIDATION_REPLICATE_BASE, StudyDefinition, describe_validation_error
from optimizer.validation import NOT_VALIDATED, PENDING

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Progress:
    """Where a study stands after a step; what progress displays and the service report."""

    study_id: str
    status: StudyStatus
    batch: int  # index of the batch being run (== batches when done)
    batches: int  # 1 + generations (+ 1 with elite re-evaluation)
    trials_done: int
    trials_planned: int
    trials_in_flight: int
    best_f1: float | None
    recommendation: dict | None
    recorded: int  # results recorded during this step (any study sharing the executor)
    message: str = ""

    @property
    def active(self) -> bool:
        return self.status in ACTIVE_STUDIES


@dataclass
class _Batch:
    index: int
    specs: list[TrialSpec]
    individuals: list[int]
    genes: np.ndarray | None  # the GA's genes in ``individuals`` order; None for re-evaluation
    search: Search | None
    # The validation batch's ``pooled_evidence``, which chose its candidates, kept for its rows:
    # the search's runs do not change while the batch runs. None when not computed (a batch read
    # back from the store) or when the search ranks on own runs.
    pooled: dict[int, PooledMatch] | None = None


@dataclass(frozen=True)
class _Study:
    definition: StudyDefinition
    space: ParameterSpace
    n_items: int

    @property
    def last_batch(self) -> int:
        return self.definition.validation_batch()


@dataclass
class _Known:
    """The driver's copy of one study's trials, and the f1 of each individual that measured
    (what ``Progress.best_f1`` needs) kept up to date one individual at a time."""

    context: _Study
    records: dict[str, TrialRecord] = field(default_factory=dict)
    members: dict[int, list[str]] = field(default_factory=dict)  # individual -> its trial ids
    f1: dict[int, float] = field(default_factory=dict)
    cursor: Any = None

    def merge(self, changed: Iterable[TrialRecord]) -> None:
        gained = set()
        for record in changed:
            tid, before = record.spec.trial_id, self.records.get(record.spec.trial_id)
            if before is None:
                self.members.setdefault(record.spec.individual, []).append(tid)
            if record.result is not None and (before is None or before.result is None):
                gained.add(record.spec.individual)
            self.records[tid] = record
        for individual in gained:
            group = [self.records[tid] for tid in self.members[individual]]
            definition, n_items = self.context.definition, self.context.n_items
            measured = [ev for ev in evaluate(group, definition, n_items) if ev.ok]
            if measured:
                self.f1[individual] = measured[0].f1
            else:
                self.f1.pop(individual, None)

    def queued(self, specs: Iterable[TrialSpec]) -> None:
        """The driver's own ``mark_queued``, as the store applies it."""
        for spec in specs:
            record = self.records.get(spec.trial_id)
            if record is None:
                self.merge([TrialRecord(spec, TrialState.QUEUED, attempts=1)])
            elif record.state in (TrialState.PENDING, *IN_FLIGHT):  # a lost running one is queued again
                record.state = TrialState.QUEUED

    def recorded(self, outcome: TrialOutcome) -> None:
        """The driver's own ``record_result`` that the store accepted."""
        record = self.records.get(outcome.trial_id)
        if record is not None:
            self.merge([replace(record, state=TrialState.DONE, result=outcome.result, worker=outcome.worker)])

    def ordered(self) -> list[TrialRecord]:
        """The records in the store's order (individual, replicate)."""
        return sorted(self.records.values(), key=lambda rec: (rec.spec.individual, rec.spec.replicate))

    def finished(self, specs: Iterable[TrialSpec]) -> bool:
        return all(
            (record := self.records.get(spec.trial_id)) is not None and record.result is not None
            for spec in specs
        )


class Driver:
    def __init__(self, store: Store, executor: Executor, *, reconcile_every_s: float = 30.0):
        self.store = store
        self.executor = executor
        self.reconcile_every_s = reconcile_every_s
        self._studies: dict[str, _Study] = {}
        self._batches: dict[str, _Batch] = {}
        self._known: dict[str, _Known] = {}
        self._last_reconcile: dict[str, float] = {}

    # -- the two entry points -------------------------------------------------------------------

    def run_to_completion(
        self,
        study_id: str,
        *,
        poll_timeout: float = 0.5,
        on_progress: Callable[[Progress], None] | None = None,
    ) -> Progress:
        """Step until the study is done, failed, paused or cancelled."""
        while True:
            progress = self.step(study_id, timeout=poll_timeout)
            if on_progress is not None:
                on_progress(progress)
            if not progress.active:
                return progress

    def step(self, study_id: str, timeout: float = 1.0) -> Progress:
        study = self.store.load_study(study_id)
        try:
            context = self._context(study)
        except ValidationError as exc:
            message = f"the stored definition is invalid: {describe_validation_error(exc)}"
            self.store.set_status(study_id, StudyStatus.FAILED, message)
            return self._progress(self.store.load_study(study_id), None, 0)
        sent = study_id in self._last_reconcile or study_id in self._batches
        if study.status in STOPPING_STUDIES and sent:
            self.withdraw(study_id)  # once, when this driver had sent its work
        if study.status not in ACTIVE_STUDIES:
            self._known.pop(study_id, None)
            return self._progress(study, self._read(study_id, context), 0)
        if study.status is StudyStatus.CREATED:
            self.store.set_status(study_id, StudyStatus.RUNNING)
            study.status = StudyStatus.RUNNING

        reconcile = self._reconcile_due(study_id)
        known = self._read(study_id, context, incremental=not reconcile)
        if study.generation > context.last_batch:
            # The last batch was saved but the process stopped before marking the study done.
            self.store.set_status(study_id, StudyStatus.DONE, study.message)
            return self._progress(self.store.load_study(study_id), known, 0)
        batch = self._current_batch(study, context, known)
        self._submit(study_id, batch, known, reconcile)
        recorded = self._record(self.executor.poll(timeout))
        if known.finished(batch.specs):
            self._complete(study, context, batch, known.ordered())
            study = self.store.load_study(study_id)
        return self._progress(study, known, recorded)

    def _read(self, study_id: str, context: _Study, incremental: bool = False) -> _Known:
        """The study's trials: what changed since the last read, or all of them (a new copy)."""
        known = self._known.get(study_id) if incremental else None
        if known is None:
            known = self._known[study_id] = _Known(context)
        changed, known.cursor = self.store.changed_trials(study_id, known.cursor)
        known.merge(changed)
        return known

    def _record(self, outcomes: list[TrialOutcome]) -> int:
        """Record outcomes of any study sharing the executor; each study's copy learns its own."""
        recorded = 0
        for outcome in outcomes:
            if self.store.record_result(outcome):
                recorded += 1
                known = self._known.get(study_of(outcome.trial_id))
                if known is not None:
                    known.recorded(outcome)
        return recorded

    def _reconcile_due(self, study_id: str) -> bool:
        now = time.monotonic()
        if now - self._last_reconcile.get(study_id, -np.inf) < self.reconcile_every_s:
            return False
        self._last_reconcile[study_id] = now
        return True

    # -- batches --------------------------------------------------------------------------------

    def _context(self, study: StudyRecord) -> _Study:
        if study.study_id not in self._studies:
            definition = StudyDefinition.model_validate(study.definition)
            self._studies[study.study_id] = _Study(
                definition, ParameterSpace(definition.parameters), definition.n_items()
            )
        return self._studies[study.study_id]

    def _current_batch(self, study: StudyRecord, context: _Study, known: _Known) -> _Batch:
        cached = self._batches.get(study.study_id)
        if cached is not None and cached.index == study.generation:
            return cached
        definition, records = context.definition, known.ordered()
        if study.generation <= definition.ga.generations:
            batch = self._ga_batch(study, context, records)
        elif study.generation == definition.replicate_batch():
            batch = _Batch(study.generation, self._extra_replicates(study, context, records), [], None, None)
        else:
            batch = self._validation_batch(study, context, records)
        self.store.add_trials(batch.specs)
        self._batches[study.study_id] = batch
        return batch

    def _spec(
        self, study_id: str, context: _Study, individual: int, batch: int, replicate: int, params, seed=None
    ):
        definition = context.definition
        return TrialSpec(
            trial_id=trial_id(study_id, individual, replicate),
            study_id=study_id,
            individual=individual,
            generation=batch,
            replicate=replicate,
            seed=search_seed(definition.seed, replicate, batch, individual, definition.common_seeds)
            if seed is None
            else seed,
            params=dict(params),
            scenario=definition.scenario.model_dump(mode="json"),
            timeout_s=definition.trial_timeout_s,
            keep_snapshots=definition.keep_snapshots,
            engine=definition.engine,
            engine_options=dict(definition.engine_options) or None,
        )

    def _ga_batch(self, study: StudyRecord, context: _Study, records: list[TrialRecord]) -> _Batch:
        """The GA's next individuals, plus the extra replicates earned by earlier sets."""
        definition, index = context.definition, study.generation
        if study.ga_state is None:
            search = create_search(
                definition.ga,
                context.space.n_genes,
                definition.seed,
                match_rule(definition, context.n_items),
            )
        else:
            search = from_bytes(study.ga_state)
        genes = search.ask()
        born = _first_batches(records)
        stored_specs = {
            (record.spec.individual, record.spec.replicate): record.spec
            for record in records
            if record.spec.generation == index and born[record.spec.individual] == index
        }
        stored = {individual: spec.params for (individual, _), spec in stored_specs.items()}
        if stored:
            # What was simulated is the truth; the re-ask only restores the search's internal state.
            individuals = sorted(stored)
            if len(individuals) != len(genes):
                logger.warning(
                    "study %s batch %d: %d stored individuals, the GA re-proposed %d; using the stored",
                    study.study_id,
                    index,
                    len(individuals),
                    len(genes),
                )
            genes = np.array([context.space.genes(stored[individual]) for individual in individuals])
            extra = [
                record.spec
                for record in records
                if record.spec.generation == index and born[record.spec.individual] < index
            ]
        else:
            first = 1 + max((record.spec.individual for record in records), default=-1)
            individuals = list(range(first, first + len(genes)))
            extra = self._extra_replicates(study, context, records)
        specs = [
            stored_specs.get((individual, replicate))
            or self._spec(study.study_id, context, individual, index, replicate, context.space.params(gene))
            for individual, gene in zip(individuals, genes, strict=True)
            for replicate in range(definition.replicates)
        ]
        logger.info(
            "study %s: batch %d with %d individuals and %d extra replicates",
            study.study_id,
            index,
            len(individuals),
            len(extra),
        )
        return _Batch(index, specs + extra, individuals, genes, search)

    def _extra_replicates(
        self, study: StudyRecord, context: _Study, records: list[TrialRecord]
    ) -> list[TrialSpec]:
        """Trials of the replicates earned by promising sets (``optimizer/replicates.py``)."""
        definition, index = context.definition, study.generation
        stored = [record.spec for record in records if record.spec.generation == index]
        born = _first_batches(records)
        if stored and index == definition.replicate_batch():
            return stored
        spent = sum(
            record.spec.replicate >= definition.replicates
            and record.spec.generation < definition.validation_batch()
            for record in records
        )
        evaluations = {ev.individual: ev for ev in evaluate(records, definition, context.n_items)}
        earned = allocate(list(evaluations.values()), definition, spent, index)
        return [
            self._spec(study.study_id, context, individual, index, replicate, evaluations[individual].params)
            for individual, replicates in earned.items()
            if born.get(individual, index) < index
            for replicate in replicates
        ]

    def _validation_batch(self, study: StudyRecord, context: _Study, records: list[TrialRecord]) -> _Batch:
        """The candidates re-simulated on fresh seeds (``optimizer/validation.py``)."""
        definition, index = context.definition, study.generation
        stored = [record.spec for record in records if record.spec.generation == index]
        if stored:
            return _Batch(index, stored, sorted({spec.individual for spec in stored}), None, None)
        evaluations = evaluate(records, definition, context.n_items)
        pooled = pooled_evidence(evaluations, definition, context.space)
        checked = validation.candidates(
            _ranking(evaluations, definition, context.space), evaluations, context.space, definition, pooled
        )
        used = {record.spec.seed for record in records}
        seeds = validation_seeds(definition.seed, definition.validation.seeds, used)
        specs = [
            self._spec(
                study.study_id,
                context,
                evaluation.individual,
                index,
                VALIDATION_REPLICATE_BASE + k,
                evaluation.params,
                seed=seed,
            )  # fmt: skip
            for evaluation in checked
            for k, seed in enumerate(seeds)
        ]
        logger.info(
            "study %s: validating %d sets on %d fresh seeds", study.study_id, len(checked), len(seeds)
        )
        return _Batch(index, specs, [evaluation.individual for evaluation in checked], None, None, pooled)

    def _complete(
        self, study: StudyRecord, context: _Study, batch: _Batch, records: list[TrialRecord]
    ) -> None:
        definition = context.definition
        evaluations = evaluate(records, definition, context.n_items)
        by_individual = {evaluation.individual: evaluation for evaluation in evaluations}
        ga_state = study.ga_state
        if batch.search is not None:
            told = [by_individual[i] for i in batch.individuals]
            batch.search.tell(
                batch.genes, *_objectives_and_constraints(told), observations=[observation(ev) for ev in told]
            )
            revised = sorted(
                {spec.individual for spec in batch.specs} - set(batch.individuals) & set(by_individual)
            )
            if revised:
                again = [by_individual[i] for i in revised]
                genes = np.array([context.space.genes(ev.params) for ev in again])
                batch.search.revise(
                    genes, *_objectives_and_constraints(again), observations=[observation(ev) for ev in again]
                )
            ga_state = to_bytes(batch.search)
        final = batch.index == definition.validation_batch()
        ranking, recommendation, verdict = recommend(
            evaluations, records, definition, context.space, final, batch.pooled
        )
        pareto_ids = [tid for evaluation in ranking.pareto for tid in evaluation.trial_ids]
        # Shown objectives depend on an individual's own results only: those of this batch's.
        touched = {spec.individual for spec in batch.specs}
        objectives = shown_objectives([ev for ev in evaluations if ev.individual in touched])
        self.store.save_generation(
            study.study_id, batch.index + 1, ga_state or b"", pareto_ids, recommendation, objectives
        )
        self._batches.pop(study.study_id, None)
        logger.info(
            "study %s: batch %d complete, best f1 %s, %s",
            study.study_id,
            batch.index,
            ranking.best_f1,
            verdict,
        )
        hopeless = _all_invalid(evaluations, batch) if batch.index == 0 else ""
        if hopeless:
            self.store.set_status(study.study_id, StudyStatus.FAILED, hopeless)
        elif batch.index >= context.last_batch:
            self.store.set_status(study.study_id, StudyStatus.DONE, verdict)

    # -- execution ------------------------------------------------------------------------------

    def _submit(self, study_id: str, batch: _Batch, known: _Known, reconcile: bool) -> None:
        """Send the batch's pending trials; on reconciliation also those in flight that the
        executor no longer knows (lost with a restarted process or a flushed queue)."""
        states = {tid: record.state for tid, record in known.records.items()}
        to_send = [
            spec
            for spec in batch.specs
            if states.get(spec.trial_id, TrialState.PENDING) is TrialState.PENDING
        ]
        if reconcile:
            expected = {spec.trial_id for spec in batch.specs if states.get(spec.trial_id) in IN_FLIGHT}
            missing = expected - self.executor.in_flight(expected)
            lost = [spec for spec in batch.specs if spec.trial_id in missing]
            if lost:
                logger.info(
                    "study %s: re-submitting %d trials the executor does not know", study_id, len(lost)
                )
            to_send += lost
        if to_send:
            self.executor.submit(to_send)
            waiting = getattr(self.executor, "waiting", dict)()  # engine -> why its trials wait
            for message in {"", *waiting.values()}:
                ids = [spec.trial_id for spec in to_send if waiting.get(spec.engine, "") == message]
                if ids and message:
                    self.store.mark_queued(ids, message)
                elif ids:
                    self.store.mark_queued(ids)
            known.queued(to_send)

    def withdraw(self, study_id: str) -> None:
        """Stop a study's queued and running trials as the executor holds them (the store may
        have marked them cancelled, or deleted the study) and forget what this driver knew of it;
        on resume, reconciliation sends its unfinished trials again."""
        records = self._known[study_id].records if study_id in self._known else {}
        expected = [tid for tid, record in records.items() if record.state in IN_FLIGHT]
        doomed = sorted(trial for trial in self.executor.in_flight(expected) if is_trial_of(trial, study_id))
        if doomed:
            logger.info("study %s: withdrawing %d queued or running trials", study_id, len(doomed))
            self.executor.cancel(doomed)
        self._last_reconcile.pop(study_id, None)
        self._batches.pop(study_id, None)
        self._known.pop(study_id, None)

    # -- reporting ------------------------------------------------------------------------------

    def _progress(self, study: StudyRecord, known: _Known | None, recorded: int) -> Progress:
        records = [] if known is None else known.records.values()
        batches = planned = 0
        if known is not None:
            definition = known.context.definition
            batches = known.context.last_batch + 1
            extra = sum(record.spec.replicate >= definition.replicates for record in records)
            if study.generation < definition.validation_batch():
                extra += definition.validation.simulations()  # an upper bound until it starts
            planned = definition.search_simulations() + extra
        return Progress(
            study_id=study.study_id,
            status=study.status,
            batch=study.generation,
            batches=batches,
            trials_done=sum(record.result is not None for record in records),
            trials_planned=planned,
            trials_in_flight=sum(record.state in IN_FLIGHT for record in records),
            best_f1=min(known.f1.values(), default=None) if known is not None else None,
            recommendation=study.recommendation,
            recorded=recorded,
            message=study.message,
        )


def _first_batches(records: list[TrialRecord]) -> dict[int, int]:
    """Individual -> the batch it was created in (its extra replicates come in later batches)."""
    born: dict[int, int] = {}
    for record in records:
        individual = record.spec.individual
        born[individual] = min(born.get(individual, record.spec.generation), record.spec.generation)
    return born


def _objectives_and_constraints(evaluations: list[Evaluation]) -> tuple[np.ndarray, np.ndarray]:
    """F and G of the search interface (``optimizer/ga.py``), rows in the given order."""
    objectives = np.array([[ev.f1, ev.f2] for ev in evaluations], dtype=float)
    constraints = np.array([[ev.g_match, ev.g_validity] for ev in evaluations], dtype=float)
    return objectives, constraints


def _all_invalid(evaluations: list[Evaluation], batch: _Batch) -> str:
    """The message ending a study whose whole initial population left the contact model."""
    initial = [ev for ev in evaluations if ev.individual in set(batch.individuals)]
    if not initial or any(ev.status != SimulationStatus.INVALID.value for ev in initial):
        return ""
    softest = max(ev.params["E"] for ev in initial)
    return (
        f"all {len(initial)} sets of the initial population were invalid (the linear contact "
        f"model's overlap limit was exceeded up to E = {softest:.3g} Pa): the parameter bounds lie "
        "where the model is invalid, so nothing can be calibrated; raise parameters.E (its low bound "
        f"above {softest:.3g} Pa). First: {initial[-1].failure}"
    )


def recommend(
    evaluations: list[Evaluation],
    records: list[TrialRecord],
    definition: StudyDefinition,
    space: ParameterSpace,
    final: bool,
    pooled: dict[int, PooledMatch] | None = None,
) -> tuple[Ranking, dict | None, str]:
    """What a study stores after a batch: the ranking, the recommendation (JSON, None when no set
    matches) and a one-line verdict for the log. ``final`` is the validation batch's: the
    recommendation then carries the validation table (``optimizer/validation.py``), with
    ``pooled``, ``pooled_evidence`` of ``evaluations`` when the caller has it (computed here
    otherwise)."""
    ranking = _ranking(evaluations, definition, space)
    if final:
        return ranking, *_validated(ranking, evaluations, records, definition, space, pooled)
    recommendation = recommendation_json(
        ranking, definition.experiment.target(), definition.match_tolerance(), definition.objective_time
    )
    if recommendation is not None:
        recommendation["validation_status"] = PENDING if definition.validation.seeds else NOT_VALIDATED
    return ranking, recommendation, _verdict(ranking)


def _ranking(evaluations: list[Evaluation], definition: StudyDefinition, space: ParameterSpace) -> Ranking:
    """The study's fronts and own-run matches; a set needs its full replicates to be recommended."""
    return rank(evaluations, definition.match_tolerance(), space, min_replicates=definition.max_replicates)


def _validated(
    ranking: Ranking,
    evaluations: list[Evaluation],
    records: list[TrialRecord],
    definition: StudyDefinition,
    space: ParameterSpace,
    pooled: dict[int, PooledMatch] | None,
) -> tuple[dict | None, str]:
    """The recommendation after the validation, with the table: the fastest validated set whose
    fresh runs lie as close to every experiment as a repeat of it would (fresh W1 within the
    experiment's own noise floor), else the fastest validated set. Why the first tier: ten
    measured values make the validation's test weak (its limit is 4-5 items on the paper's
    experiment), and among the sets that pass, the fastest is mostly the softest, whose fresh runs
    empty the tray or jam more than the experiment's: the paper's study recommended fresh medians
    0 and 8 (W1 3.70, 3.40) where it had validated sets with medians 4.5 and 3.5 (W1 1.50, 1.70;
    calibration 19). Preferring the sets the pooled estimate calls feasible was tried first: its
    floor then tightened as runs pooled (since mended in ``optimizer/neighbours.py``), and it
    chose a 3.3x slower set with a worse fresh W1."""
    if pooled is None:
        pooled = pooled_evidence(evaluations, definition, space)
    checked = _checked(ranking, evaluations, records, definition, space, pooled)
    if not checked:
        return None, _verdict(ranking)
    rows = validation.table(checked, records, definition, pooled) if definition.validation.seeds else []
    validated = [i for i, row in enumerate(rows) if row["verdict"] == validation.VALIDATED]
    floors = {x.response: x.noise_floor(len(x.measured)) for x in definition.experiments} if rows else {}
    close = [_as_close_as_a_repeat(row, floors) for row in rows]
    chosen = min(validated, key=lambda i: (not close[i], checked[i].f2, i)) if validated else None
    status = (
        validation.VALIDATED
        if chosen is not None
        else (validation.NOT_REPRODUCED if definition.validation.seeds else NOT_VALIDATED)
    )
    # Nothing validated: the search's fastest match stays, as in a study without pooled candidates.
    pick = checked[chosen] if chosen is not None else (ranking.recommendation or checked[0])
    own = [] if ranking.recommendation is None else [ranking.recommendation, *ranking.equivalent]
    alike = [*own, *(checked[i] for i in validated)]  # sets that matched in the search or on fresh seeds
    others = {ev.individual: ev for ev in alike if ev.individual != pick.individual}
    recommendation = {
        **summary(pick),
        "target": definition.experiment.target(),
        "tolerance": definition.match_tolerance(),
        "objective_time": definition.objective_time,
        "equivalent": [summary(ev) for ev in others.values()],
        "validation_status": status,
        "validation": rows,
        "chosen_by": _chosen_by(status, pick is ranking.recommendation, chosen is not None and close[chosen]),
    }
    if status == validation.VALIDATED:
        row = rows[chosen]
        verdict = (
            f"recommended individual {pick.individual}, validated on {len(row['n_remaining'])} fresh "
            f"seeds (median N_t {row['median']:g}, W1 {row['w1']:.2f})"
        )
    elif status == NOT_VALIDATED:
        verdict = f"recommended individual {pick.individual}, not validated (validation.seeds = 0)"
    else:
        verdict = f"{recommendation['chosen_by']} ({len(rows)} tried): individual {pick.individual}"
    return recommendation, verdict


def _checked(
    ranking: Ranking,
    evaluations: list[Evaluation],
    records: list[TrialRecord],
    definition: StudyDefinition,
    space: ParameterSpace,
    pooled: dict | None,
) -> list[Evaluation]:
    """The validated sets, in the candidates' order: the candidates as ``_validation_batch`` chose
    them, but once a validation batch is stored, exactly its sets (a batch stored by an earlier
    rule, then resumed, keeps the sets it ran)."""
    checked = validation.candidates(ranking, evaluations, space, definition, pooled)
    batch = definition.validation_batch()
    stored = {record.spec.individual for record in records if record.spec.generation == batch}
    if not stored:
        return checked
    by_individual = {evaluation.individual: evaluation for evaluation in evaluations}
    kept = [evaluation for evaluation in checked if evaluation.individual in stored]
    missed = sorted(stored - {evaluation.individual for evaluation in kept})
    return kept + [by_individual[i] for i in missed if i in by_individual]


def _as_close_as_a_repeat(row: dict, floors: dict[str, float]) -> bool:
    """Whether a validation row's fresh W1 to every experiment is within that experiment's own
    noise floor: ``floors``, by response, ``Experiment.noise_floor`` for its own number of values
    (the caller computes them once for all rows)."""
    tests = row["reproduction"]
    return bool(tests) and all(test["value"] <= floors[test["response"]] + 1e-9 for test in tests)


def _chosen_by(status: str, fastest_match: bool, close: bool = False) -> str:
    """How the recommendation after the validation was chosen, as the CLI and the dashboard say it."""
    if status == validation.VALIDATED:
        return "the fastest validated parameter set" + (
            " whose fresh runs lie within the experiment's own noise" if close else ""
        )
    which = (
        "the fastest match of the search"
        if fastest_match
        else "the set the search's pooled estimate ranks first (its own runs not within tolerance)"
    )
    if status == validation.NOT_REPRODUCED:
        return f"no candidate reproduced the experiment on fresh seeds; {which}"
    return f"{which}, not validated"


def _verdict(ranking: Ranking) -> str:
    if ranking.recommendation is None:
        return "no parameter set within tolerance" + (
            f" (best f1 {ranking.best_f1:g})" if ranking.best_f1 is not None else ""
        )
    return (
        f"recommended individual {ranking.recommendation.individual} "
        f"({len(ranking.equivalent)} equivalent sets)"
    )
