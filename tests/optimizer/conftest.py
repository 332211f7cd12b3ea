"""Study definitions for the optimiser's unit tests: the paper's protocol on the default feeder
(30 items), whose simulations the synthetic executor of ``optimizer/memory.py`` stands in for."""

from __future__ import annotations

import pytest

from optimizer.study import StudyDefinition

# The ten experiments' N_t are not published individually; these match the published median 3.5,
# mean 5.7 and standard deviation 6.2, with two experiments that emptied the tray.
PAPER_MEASURED = [0, 0, 1, 2, 3, 4, 4, 12, 15, 16]


def make_definition(**overrides) -> StudyDefinition:
    data = {"scenario": {}, "experiment": {"measured": PAPER_MEASURED}, "seed": 7}
    data.update(overrides)
    return StudyDefinition.model_validate(data)


@pytest.fixture
def paper_definition() -> StudyDefinition:
    return make_definition()


@pytest.fixture
def small_definition() -> StudyDefinition:
    """20 simulations, no validation (tests of the validation ask for it)."""
    return make_definition(ga={"population": 8, "offspring": 4, "generations": 3}, validation={"seeds": 0})
