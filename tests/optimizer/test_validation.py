"""The validation verdict (``optimizer/validation.py``): fresh runs that are clearly off the
experiment are never ``validated``; runs drawn like the experiment are, nearly always."""

from __future__ import annotations

import numpy as np
import pytest

from dem.result import SimulationResult, SimulationStatus
from optimizer.objectives import Evaluation
from optimizer.protocols import TrialRecord, TrialSpec, TrialState
from optimizer.validation import NOT_REPRODUCED, VALIDATED, check
from tests.optimizer.conftest import make_definition

# A fixed experiment the cases below were built around (median 5), not a copy of the example.
QUICK_MEASURED = [8, 5, 2, 6, 3, 4, 10, 5]


def candidate() -> Evaluation:
    return Evaluation(0, 0, {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.5}, 0.0, 1.0, [5, 5, 5], 1.0, 1.0)


def fresh_runs(values) -> list[TrialRecord]:
    records = []
    for replicate, n in enumerate(values):
        spec = TrialSpec(f"s-v-{replicate}", "s", 0, 9, replicate, 9000 + replicate, {}, {})
        result = SimulationResult(status=SimulationStatus.OK, n_items=10, n_remaining=int(n), cost=1.0)
        records.append(TrialRecord(spec, TrialState.DONE, result))
    return records


@pytest.mark.parametrize(
    "fresh",
    [
        [2, 3, 3, 3, 4, 2, 3, 3],  # median 3 against 5, never above 4 where the experiment reaches 10
        [0, 0, 0, 0, 0, 5, 5, 5],  # five of eight emptied the tray; the experiment never did
        [2, 2, 2, 3, 3, 3, 2, 3],
    ],
)
def test_fresh_runs_clearly_off_the_experiment_are_not_reproduced(fresh):
    """The former rule (the fresh f1 interval's lower end within the search tolerance, 2.38 for
    3 replicates) said ``validated`` for the first two."""
    definition = make_definition(replicates=3, experiment={"measured": QUICK_MEASURED})

    row = check(candidate(), fresh_runs(fresh), definition)

    assert row["verdict"] == NOT_REPRODUCED
    [test] = row["reproduction"]
    assert test["distance"] > test["limit"]


def test_the_truth_itself_is_validated_at_least_nine_times_in_ten():
    """Experiment and fresh runs drawn from one distribution (Poisson, mean 5): the permutation
    bound rejects at most a tenth of them, up to sampling error (200 draws: sd 0.02)."""
    rng = np.random.default_rng(3)
    verdicts = []
    for _ in range(200):
        definition = make_definition(replicates=3, experiment={"measured": rng.poisson(5, 8).tolist()})
        verdicts.append(check(candidate(), fresh_runs(rng.poisson(5, 8)), definition)["verdict"])

    assert verdicts.count(VALIDATED) / len(verdicts) >= 0.85


def test_an_aggregate_study_validates_by_its_median():
    """With distance = 'aggregate' the test statistic is |median - target|: the same spread
    shifted by four items is not reproduced, the experiment's own values are."""
    definition = make_definition(replicates=1, experiment={"measured": QUICK_MEASURED})

    shifted = check(candidate(), fresh_runs([v + 4 for v in QUICK_MEASURED]), definition)
    same = check(candidate(), fresh_runs(QUICK_MEASURED), definition)

    assert (shifted["verdict"], same["verdict"]) == (NOT_REPRODUCED, VALIDATED)
