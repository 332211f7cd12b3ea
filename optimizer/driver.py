"""The driver: advances a study through an Executor (runs trials) and a Store (keeps the truth).

One study is a sequence of *batches*: batch 0 is the initial population, batch k (1..G) the
offspring of generation k, and, when ``elite_reevaluation > 0``, batch G + 1 re-simulates every
matching parameter set with fresh seeds. ``StudyRecord.generation`` counts completed batches.

    load study -> (paused/cancelled: withdraw its work; done: nothing)
    current batch: GA state from the store (or a new search) -> ask -> store trials as pending
    submit pending trials (and, on start and every ``reconcile_every_s``, re-submit queued or
    running trials the executor no longer knows: lost with a restarted process or a flushed queue)
    poll the executor -> record each outcome once (the store ignores duplicates)
    batch complete -> objectives -> tell -> Pareto + recommendation -> save_generation (atomic)
    last batch saved -> status done

Two ways to use it:

- ``Driver.run_to_completion(study_id)``: the embedded ``demcal calibrate`` loop.
- ``Driver.step(study_id, timeout)``: bounded work (at most one poll of ``timeout`` seconds and
  one batch completion) that returns a :class:`Progress`; the service's background loop calls it
  round-robin over its running studies with one shared executor. Outcomes of any study polled in
  one step are recorded, so sharing the executor loses nothing.

Resuming needs nothing but the store: a new driver on the same store re-asks the GA from the
state saved after the last completed batch (the search is deterministic, so it proposes the same
individuals; the stored trials' parameters win if they differ), keeps every recorded result and
re-submits only what has none. The study's status is re-read at every step, so pause and cancel
take effect within one poll.

The driver never imports RQ, Redis, SQLAlchemy or FastAPI; it only knows the protocols.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pydantic import ValidationError

from optimizer.ga import Search, create_search, from_bytes, to_bytes
from optimizer.objectives import Evaluation, evaluate
from optimizer.pareto import Ranking, rank, recommendation_json
from optimizer.protocols import (
    Executor,
    Store,
    StudyRecord,
    StudyStatus,
    TrialRecord,
    TrialSpec,
    TrialState,
    trial_id,
)
from optimizer.space import ParameterSpace
from optimizer.study import StudyDefinition, describe_validation_error

logger = logging.getLogger(__name__)

ACTIVE = (StudyStatus.CREATED, StudyStatus.RUNNING)
IN_FLIGHT = (TrialState.QUEUED, TrialState.RUNNING)


def trial_seed(study_seed: int, individual: int, replicate: int) -> int:
    """A simulation's seed: distinct per individual and replicate, reproducible from the study seed."""
    state = np.random.SeedSequence([study_seed, individual, replicate]).generate_state(1)[0]
    return int(state) & 0x7FFFFFFF


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
        return self.status in ACTIVE


@dataclass
class _Batch:
    index: int
    specs: list[TrialSpec]
    individuals: list[int]
    genes: np.ndarray | None  # the GA's genes in ``individuals`` order; None for re-evaluation
    search: Search | None


@dataclass(frozen=True)
class _Study:
    definition: StudyDefinition
    space: ParameterSpace
    n_items: int

    @property
    def last_batch(self) -> int:
        return self.definition.ga.generations + (1 if self.definition.elite_reevaluation else 0)


class Driver:
    def __init__(self, store: Store, executor: Executor, *, reconcile_every_s: float = 30.0):
        self.store = store
        self.executor = executor
        self.reconcile_every_s = reconcile_every_s
        self._studies: dict[str, _Study] = {}
        self._batches: dict[str, _Batch] = {}
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
            return self._progress(self.store.load_study(study_id), None, [], 0)
        if study.status in (StudyStatus.PAUSED, StudyStatus.CANCELLED):
            self._withdraw(study_id)
        if study.status not in ACTIVE:
            return self._progress(study, context, self.store.trials(study_id), 0)
        if study.status is StudyStatus.CREATED:
            self.store.set_status(study_id, StudyStatus.RUNNING)
            study.status = StudyStatus.RUNNING

        records = self.store.trials(study_id)
        if study.generation > context.last_batch:
            # The last batch was saved but the process stopped before marking the study done.
            self.store.set_status(study_id, StudyStatus.DONE, study.message)
            return self._progress(self.store.load_study(study_id), context, records, 0)
        batch = self._current_batch(study, context, records)
        self._submit(study_id, batch, records)
        recorded = sum(self.store.record_result(outcome) for outcome in self.executor.poll(timeout))
        if recorded:
            records = self.store.trials(study_id)
        done = {record.spec.trial_id for record in records if record.result is not None}
        if all(spec.trial_id in done for spec in batch.specs):
            self._complete(study, context, batch, records)
            study = self.store.load_study(study_id)
        return self._progress(study, context, records, recorded)

    # -- batches --------------------------------------------------------------------------------

    def _context(self, study: StudyRecord) -> _Study:
        if study.study_id not in self._studies:
            definition = StudyDefinition.model_validate(study.definition)
            self._studies[study.study_id] = _Study(
                definition, ParameterSpace(definition.parameters), definition.n_items()
            )
        return self._studies[study.study_id]

    def _current_batch(self, study: StudyRecord, context: _Study, records: list[TrialRecord]) -> _Batch:
        cached = self._batches.get(study.study_id)
        if cached is not None and cached.index == study.generation:
            return cached
        if study.generation <= context.definition.ga.generations:
            batch = self._ga_batch(study, context, records)
        else:
            batch = self._reevaluation_batch(study, context, records)
        self.store.add_trials(batch.specs)
        self._batches[study.study_id] = batch
        return batch

    def _spec(self, study_id: str, context: _Study, individual: int, batch: int, replicate: int, params):
        definition = context.definition
        return TrialSpec(
            trial_id=trial_id(study_id, individual, replicate),
            study_id=study_id,
            individual=individual,
            generation=batch,
            replicate=replicate,
            seed=trial_seed(definition.seed, individual, replicate),
            params=dict(params),
            scenario=definition.scenario,
            timeout_s=definition.trial_timeout_s,
            keep_snapshots=definition.keep_snapshots,
        )

    def _ga_batch(self, study: StudyRecord, context: _Study, records: list[TrialRecord]) -> _Batch:
        definition, index = context.definition, study.generation
        if study.ga_state is None:
            search = create_search(definition.ga, context.space.n_genes, definition.seed)
        else:
            search = from_bytes(study.ga_state)
        genes = search.ask()
        stored: dict[int, dict[str, float]] = {}
        for record in records:
            if record.spec.generation == index:
                stored.setdefault(record.spec.individual, record.spec.params)
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
        else:
            first = 1 + max((record.spec.individual for record in records), default=-1)
            individuals = list(range(first, first + len(genes)))
        specs = [
            self._spec(study.study_id, context, individual, index, replicate, context.space.params(gene))
            for individual, gene in zip(individuals, genes, strict=True)
            for replicate in range(definition.replicates)
        ]
        logger.info("study %s: batch %d with %d individuals", study.study_id, index, len(individuals))
        return _Batch(index, specs, individuals, genes, search)

    def _reevaluation_batch(self, study: StudyRecord, context: _Study, records: list[TrialRecord]) -> _Batch:
        definition, index = context.definition, study.generation
        stored = [record.spec for record in records if record.spec.generation == index]
        if stored:
            return _Batch(index, stored, sorted({spec.individual for spec in stored}), None, None)
        ga_records = [record for record in records if record.spec.generation < index]
        matching = [
            evaluation
            for evaluation in evaluate(ga_records, definition, context.n_items)
            if evaluation.matches(definition.experiment.tolerance)
        ]
        first = definition.replicates
        specs = [
            self._spec(study.study_id, context, evaluation.individual, index, replicate, evaluation.params)
            for evaluation in matching
            for replicate in range(first, first + definition.elite_reevaluation)
        ]
        logger.info("study %s: re-evaluating %d matching sets", study.study_id, len(matching))
        return _Batch(index, specs, [evaluation.individual for evaluation in matching], None, None)

    def _complete(
        self, study: StudyRecord, context: _Study, batch: _Batch, records: list[TrialRecord]
    ) -> None:
        definition = context.definition
        evaluations = evaluate(records, definition, context.n_items)
        ga_state = study.ga_state
        if batch.search is not None:
            by_individual = {evaluation.individual: evaluation for evaluation in evaluations}
            objectives = np.array(
                [[by_individual[i].f1, by_individual[i].f2] for i in batch.individuals], dtype=float
            )
            batch.search.tell(batch.genes, objectives)
            ga_state = to_bytes(batch.search)
        ranking = rank(evaluations, definition.experiment.tolerance, context.space)
        recommendation = recommendation_json(
            ranking,
            definition.experiment.target(),
            definition.experiment.tolerance,
            definition.objective_time,
        )
        pareto_ids = [tid for evaluation in ranking.pareto for tid in evaluation.trial_ids]
        self.store.save_generation(
            study.study_id, batch.index + 1, ga_state or b"", pareto_ids, recommendation
        )
        self._batches.pop(study.study_id, None)
        logger.info(
            "study %s: batch %d complete, best f1 %s, %s",
            study.study_id,
            batch.index,
            ranking.best_f1,
            _verdict(ranking),
        )
        if batch.index >= context.last_batch:
            self.store.set_status(study.study_id, StudyStatus.DONE, _verdict(ranking))

    # -- execution ------------------------------------------------------------------------------

    def _submit(self, study_id: str, batch: _Batch, records: list[TrialRecord]) -> None:
        states = {record.spec.trial_id: record.state for record in records}
        to_send = [
            spec
            for spec in batch.specs
            if states.get(spec.trial_id, TrialState.PENDING) is TrialState.PENDING
        ]
        now = time.monotonic()
        if now - self._last_reconcile.get(study_id, -np.inf) >= self.reconcile_every_s:
            self._last_reconcile[study_id] = now
            known = self.executor.in_flight()
            lost = [
                spec
                for spec in batch.specs
                if states.get(spec.trial_id) in IN_FLIGHT and spec.trial_id not in known
            ]
            if lost:
                logger.info(
                    "study %s: re-submitting %d trials the executor does not know", study_id, len(lost)
                )
            to_send += lost
        if to_send:
            self.executor.submit(to_send)
            self.store.mark_queued([spec.trial_id for spec in to_send])

    def _withdraw(self, study_id: str) -> None:
        """Stop a paused or cancelled study's work; on resume, reconciliation re-sends it."""
        if study_id in self._last_reconcile or study_id in self._batches:
            in_flight = [record.spec.trial_id for record in self.store.trials(study_id, IN_FLIGHT)]
            if in_flight:
                self.executor.cancel(in_flight)
            self._last_reconcile.pop(study_id, None)
            self._batches.pop(study_id, None)

    # -- reporting ------------------------------------------------------------------------------

    def _progress(
        self, study: StudyRecord, context: _Study | None, records: list[TrialRecord], recorded: int
    ) -> Progress:
        evaluations: list[Evaluation] = []
        batches = planned = 0
        if context is not None:
            definition = context.definition
            evaluations = evaluate(records, definition, context.n_items)
            batches = context.last_batch + 1
            reevaluation = sum(record.spec.generation > definition.ga.generations for record in records)
            planned = definition.ga.individuals() * definition.replicates + reevaluation
        return Progress(
            study_id=study.study_id,
            status=study.status,
            batch=study.generation,
            batches=batches,
            trials_done=sum(record.result is not None for record in records),
            trials_planned=planned,
            trials_in_flight=sum(record.state in IN_FLIGHT for record in records),
            best_f1=min((evaluation.f1 for evaluation in evaluations if evaluation.ok), default=None),
            recommendation=study.recommendation,
            recorded=recorded,
            message=study.message,
        )


def _verdict(ranking: Ranking) -> str:
    if ranking.recommendation is None:
        return "no parameter set within tolerance" + (
            f" (best f1 {ranking.best_f1:g})" if ranking.best_f1 is not None else ""
        )
    return (
        f"recommended individual {ranking.recommendation.individual} "
        f"({len(ranking.equivalent)} equivalent sets)"
    )
