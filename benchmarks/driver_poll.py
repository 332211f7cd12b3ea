"""Cost of one driver poll on a study of many trials (SQLite, synthetic results): the time of an
idle poll and the trial rows it reads. Before issue 16's incremental reads a poll read every
trial of the study (and re-evaluated it); now it reads the trials written since the last poll.

    python -m benchmarks.driver_poll [--batches 30] [--polls 20]
"""

from __future__ import annotations

import argparse
import tempfile
import time

import sqlalchemy as sa

from api.db import create_db_engine, upgrade_database
from api.models import TrialRow
from api.store import SqlStore
from optimizer.driver import Driver
from optimizer.memory import SyntheticExecutor
from optimizer.study import StudyDefinition


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, default=30, help="completed batches before timing")
    parser.add_argument("--polls", type=int, default=20)
    args = parser.parse_args()

    url = f"sqlite:///{tempfile.mkdtemp()}/poll.db"
    upgrade_database(url)
    store = SqlStore(create_db_engine(url))
    definition = StudyDefinition.model_validate({
        "scenario": {}, "experiment": {"measured": [3, 4, 4, 2, 5]}, "seed": 3, "validation": {"seeds": 0},
        "ga": {"population": 100, "offspring": 50, "generations": max(args.batches + 1, 2)},
    })
    study_id = store.create_study(definition.model_dump(mode="json"), None)
    filler = Driver(store, SyntheticExecutor(per_poll=20))
    while store.load_study(study_id).generation < args.batches:
        filler.step(study_id, timeout=0)

    # Nothing finishes during the timed polls: each is the steady cost of watching the study.
    idle = Driver(store, SyntheticExecutor(per_poll=0), reconcile_every_s=3600)
    idle.step(study_id, timeout=0)  # the first poll reads the study whole
    loaded: list[int] = []
    sa.event.listen(TrialRow, "load", lambda *_: loaded.append(1))
    start = time.perf_counter()
    for _ in range(args.polls):
        idle.step(study_id, timeout=0)
    seconds = (time.perf_counter() - start) / args.polls
    print(
        f"{len(store.trials(study_id))} trials: idle poll {seconds * 1e3:.1f} ms, "
        f"{len(loaded) / args.polls:.0f} trial rows read per poll"
    )


if __name__ == "__main__":
    main()
