"""The reads every dashboard polls, made cheap: the study list's times and recommendation (in one
page query, no per-study round trips), the cached Pareto front that still follows every
generation, trial pages built from plain rows with the same schema, and the short-lived cache
of verified API keys that still lets a revocation through within its TTL."""

from __future__ import annotations

import time

import pytest
from fastapi.testclient import TestClient

from api.app import create_app
from api.auth import revoke_key
from api.schemas import ParetoFront, TrialPage
from optimizer.driver import Driver
from optimizer.memory import SyntheticExecutor, synthetic_result
from optimizer.protocols import StudyStatus
from optimizer.study import StudyDefinition
from tests.api.conftest import study_definition


def _run(store, owner: str = "alice", executor=None, **ga) -> str:
    definition = StudyDefinition.model_validate(
        study_definition(ga=ga or {"population": 6, "offspring": 3, "generations": 2}, seed=5)
    )
    study_id = store.create_study(definition.model_dump(mode="json"), owner=owner)
    Driver(store, executor or SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0)
    return study_id


def _half_matching(spec):
    """The synthetic feeder, but N_t is exactly the target (4) where mu > 0.5 and far off elsewhere:
    the fastest trial overall need not match, so the recommendation must be the fastest match."""
    result = synthetic_result(spec)
    n_remaining = 4 if spec.params["mu"] > 0.5 else 12
    return result.model_copy(update={"n_remaining": n_remaining, "responses": {"n_remaining": n_remaining}})


def test_study_list_items_carry_times_and_the_recommendation_so_far(client, keys, store):
    finished = _run(store, executor=SyntheticExecutor(_half_matching))
    created = client.post("/api/v1/studies", json=study_definition(), headers=keys.auth()).json()["id"]

    items = {item["id"]: item for item in client.get("/api/v1/studies", headers=keys.auth()).json()["items"]}
    detail = client.get(f"/api/v1/studies/{finished}", headers=keys.auth()).json()
    trials = client.get(f"/api/v1/studies/{finished}/trials", headers=keys.auth()).json()["items"]

    done, fresh = items[finished], items[created]
    matching = [trial for trial in trials if trial["f1"] <= 0.5]
    fastest_match = min(matching, key=lambda trial: trial["cost"])
    assert 0 < len(matching) < len(trials)
    assert min(trials, key=lambda trial: trial["cost"])["id"] != fastest_match["id"]
    assert done["status"] == "done"
    assert done["started_at"] is not None and done["finished_at"] is not None
    assert done["started_at"] <= done["finished_at"]
    assert done["best_f1"] == pytest.approx(detail["best"]["f1"]) == 0
    assert done["recommendation"]["trial_ids"] == [fastest_match["id"]]
    assert done["recommendation"]["params"] == pytest.approx(fastest_match["params"])
    assert "equivalent" not in done["recommendation"]
    assert detail["started_at"] == done["started_at"] and detail["finished_at"] == done["finished_at"]
    assert fresh["started_at"] is None and fresh["finished_at"] is None and fresh["best_f1"] is None
    assert fresh["recommendation"] is None


def test_study_times_follow_the_status_transitions(store):
    study_id = store.create_study(study_definition(), owner="alice")

    store.set_status(study_id, StudyStatus.RUNNING)
    started = store.get_study(study_id).started_at
    store.transition(study_id, [StudyStatus.RUNNING], StudyStatus.PAUSED)
    store.transition(study_id, [StudyStatus.PAUSED], StudyStatus.RUNNING)
    resumed = store.get_study(study_id)
    store.transition(study_id, [StudyStatus.RUNNING], StudyStatus.CANCELLED)
    cancelled = store.get_study(study_id)

    assert started is not None
    assert resumed.started_at == started and resumed.finished_at is None
    assert cancelled.started_at == started
    assert cancelled.finished_at is not None and cancelled.finished_at >= started


def test_study_list_costs_the_same_number_of_queries_for_one_study_or_many(settings, keys, store, engine):
    import sqlalchemy as sa

    # The key cache is held for the whole test (an hour's TTL), so both counts are taken with a
    # cached key however long running the studies takes: no race with its expiry.
    held = settings.model_copy(update={"api_key_cache_s": 3600.0})
    statements: list[str] = []

    def count(*args):
        statements.append(args[2])

    with TestClient(create_app(held, engine=engine)) as client:
        _run(store)
        client.get("/api/v1/studies", headers=keys.auth())  # the key is verified once, then cached
        sa.event.listen(engine, "before_cursor_execute", count)
        try:
            client.get("/api/v1/studies", headers=keys.auth())
            one = len(statements)
            for _ in range(3):
                _run(store)
            statements.clear()
            page = client.get("/api/v1/studies", headers=keys.auth()).json()
            many = len(statements)
        finally:
            sa.event.remove(engine, "before_cursor_execute", count)

    assert page["total"] == 4
    assert many == one


def test_cached_pareto_front_follows_each_new_generation(client, keys, store):
    definition = StudyDefinition.model_validate(
        study_definition(ga={"population": 6, "offspring": 3, "generations": 3}, seed=5)
    )
    study_id = store.create_study(definition.model_dump(mode="json"), owner="alice")
    driver = Driver(store, SyntheticExecutor())
    url = f"/api/v1/studies/{study_id}/pareto"
    fronts = []

    while driver.step(study_id, timeout=0).active:
        fronts.append(client.get(url, headers=keys.auth()).json())
    fronts.append(client.get(url, headers=keys.auth()).json())

    flagged = {row.id for row in store.pareto_rows(study_id)}
    assert {point["id"] for point in fronts[-1]["points"]} == flagged
    # The latest generation's index; the batches after it (replicates, validation) are not ones.
    assert fronts[-1]["generation"] == min(store.get_study(study_id).generation - 1, 3)
    assert len({front["generation"] for front in fronts}) > 1
    ParetoFront.model_validate(fronts[-1])


def test_trial_page_from_plain_rows_keeps_the_schema(client, keys, store):
    study_id = _run(store)

    response = client.get(f"/api/v1/studies/{study_id}/trials", params={"limit": 3}, headers=keys.auth())

    assert response.headers["content-type"] == "application/json"
    page = TrialPage.model_validate(response.json())
    assert page.total == 12 and len(page.items) == 3
    assert all(item.f1 is not None for item in page.items)


def test_revoked_key_stops_working_within_the_cache_ttl(settings, engine, keys, store):
    short_ttl = settings.model_copy(update={"api_key_cache_s": 0.3})
    with TestClient(create_app(short_ttl, engine=engine)) as client:
        assert client.get("/api/v1/studies", headers=keys.auth()).status_code == 200
        with store.session() as session:
            revoke_key(session, keys.alice_id)

        time.sleep(0.4)
        response = client.get("/api/v1/studies", headers=keys.auth())

    assert response.status_code == 401
    assert "revoked" in response.json()["detail"]


def test_cached_trial_total_follows_new_trials(client, keys, store):
    from dataclasses import replace

    from optimizer.protocols import trial_id

    study_id = _run(store)
    url = f"/api/v1/studies/{study_id}/trials"
    before = client.get(url, headers=keys.auth()).json()["total"]
    template = store.trials(study_id)[0].spec

    store.add_trials([replace(template, trial_id=trial_id(study_id, 99, 0), individual=99, generation=3)])
    after = client.get(url, headers=keys.auth()).json()["total"]

    assert after == before + 1


def test_polling_a_study_ranks_its_best_trial_once_per_version(client, keys, store, monkeypatch):
    from api.store import SqlStore

    study_id = _run(store)
    ranked = []
    best_trial = SqlStore.best_trial
    monkeypatch.setattr(SqlStore, "best_trial", lambda self, sid: ranked.append(sid) or best_trial(self, sid))

    polls = [client.get(f"/api/v1/studies/{study_id}", headers=keys.auth()).json()["best"] for _ in range(5)]
    record = store.load_study(study_id)
    pareto = [trial.spec.trial_id for trial in store.trials(study_id)][:1]
    store.save_generation(study_id, record.generation, b"state", pareto, record.recommendation, objectives={})
    after = client.get(f"/api/v1/studies/{study_id}", headers=keys.auth()).json()["best"]

    assert polls[0]["id"] == best_trial(store, study_id).id
    assert all(poll == polls[0] for poll in polls)
    assert after["id"] == polls[0]["id"]
    assert ranked == [study_id, study_id]  # once for the five polls, once after the new generation


def test_polling_the_recommendation_builds_it_once_per_version(client, keys, store, monkeypatch):
    from api.store import SqlStore

    study_id = _run(store, executor=SyntheticExecutor(_half_matching))
    built = []
    columns = SqlStore.trial_columns
    monkeypatch.setattr(SqlStore, "trial_columns",
                        lambda self, sid, **filters: built.append(sid) or columns(self, sid, **filters))
    url = f"/api/v1/studies/{study_id}/recommendation"

    polls = [client.get(url, headers=keys.auth()).json() for _ in range(5)]
    store.transition(study_id, [StudyStatus.DONE], StudyStatus.DONE)  # any change to the study row
    after = client.get(url, headers=keys.auth()).json()

    assert all(poll == polls[0] for poll in polls) and polls[0]["equivalent"]
    assert after == polls[0]
    assert built == [study_id, study_id]  # once for the five polls, once after the row changed


def test_each_dashboard_poll_costs_one_query_and_the_study_read_follows_every_trial_write(
    settings, keys, store, engine
):
    from dataclasses import replace

    import sqlalchemy as sa

    from optimizer.protocols import TrialOutcome, trial_id

    held = settings.model_copy(update={"api_key_cache_s": 3600.0})  # the key is checked once, then cached
    statements: list[str] = []

    def count(*args):
        statements.append(args[2])
    study_id = _run(store)
    base = f"/api/v1/studies/{study_id}"
    polled = ["", "/recommendation", "/progress", "/identifiability", "/pareto"]
    with TestClient(create_app(held, engine=engine)) as client:
        for path in polled:  # the pages' first load builds every view
            client.get(base + path, headers=keys.auth()).raise_for_status()
        cursor = client.get(f"{base}/trials", params={"limit": 1}, headers=keys.auth()).json()["changes"]
        sa.event.listen(engine, "before_cursor_execute", count)
        try:
            cost = {}
            for path in polled:
                statements.clear()
                client.get(base + path, headers=keys.auth()).raise_for_status()
                cost[path] = len(statements)
            statements.clear()
            since = {"changed_since": cursor}
            unchanged = client.get(f"{base}/trials", params=since, headers=keys.auth()).json()
            cost["/trials?changed_since"] = len(statements)
        finally:
            sa.event.remove(engine, "before_cursor_execute", count)
        template = store.trials(study_id)[0].spec
        new = replace(template, trial_id=trial_id(study_id, 99, 0), individual=99, generation=3)
        store.add_trials([new])
        seen = [client.get(base, headers=keys.auth()).json()["progress"]]
        store.mark_running(new.trial_id, worker="w1")  # a write to the trial alone, not to the study row
        seen.append(client.get(base, headers=keys.auth()).json()["progress"])
        store.record_result(TrialOutcome(new.trial_id, synthetic_result(new)))
        seen.append(client.get(base, headers=keys.auth()).json()["progress"])
        changed = client.get(f"{base}/trials", params={"changed_since": cursor}, headers=keys.auth()).json()

    assert cost == dict.fromkeys(cost, 1), cost
    assert unchanged["items"] == [] and unchanged["total"] == 0
    assert [p["trials_by_state"].get("pending", 0) for p in seen] == [1, 0, 0]
    assert [p["trials_by_state"].get("running", 0) for p in seen] == [0, 1, 0]
    assert seen[2]["trials_done"] == seen[0]["trials_done"] + 1
    assert seen[2]["failures"] == seen[0]["failures"]
    assert [item["id"] for item in changed["items"]] == [new.trial_id] and changed["total"] == 1



def test_the_polled_study_read_counts_trials_as_a_fresh_count_does_after_each_kind_of_write(
    client, keys, store
):
    # The polled read keeps its counts between builds and reads only the trials written since
    # (a grouped count of a long study's trials was most of each rebuild): added, queued, running,
    # done, failed and cancelled trials must all move them as a count from scratch would.
    from dataclasses import replace

    from api.auth import Principal
    from api.services.studies import get_study
    from dem.result import SimulationStatus
    from optimizer.protocols import TrialOutcome, trial_id

    study_id = _run(store)
    url = f"/api/v1/studies/{study_id}"
    template = store.trials(study_id)[0].spec
    new = [replace(template, trial_id=trial_id(study_id, 90 + k, 0), individual=90 + k, generation=3)
           for k in range(4)]
    failed = synthetic_result(new[2]).model_copy(update={"status": SimulationStatus.UNSTABLE})
    writes = [
        lambda: store.add_trials(new),
        lambda: store.mark_queued([spec.trial_id for spec in new]),
        lambda: store.mark_running(new[0].trial_id, worker="w1"),
        lambda: store.record_result(TrialOutcome(new[0].trial_id, synthetic_result(new[0]))),
        lambda: store.record_result(TrialOutcome(new[2].trial_id, failed)),
        lambda: store.transition(study_id, [StudyStatus.DONE], StudyStatus.RUNNING),
        lambda: store.transition(study_id, [StudyStatus.RUNNING], StudyStatus.CANCELLED),
    ]

    polled, fresh = [client.get(url, headers=keys.auth()).json()["progress"]], []
    for write in writes:
        write()
        polled.append(client.get(url, headers=keys.auth()).json()["progress"])
        fresh.append(get_study(store, study_id, Principal(0, "alice", True)).progress.model_dump(mode="json"))

    assert polled[1:] == fresh
    assert [p["trials_by_state"].get("cancelled", 0) for p in polled][-2:] == [0, 2]
    assert polled[-1]["trials_done"] == polled[0]["trials_done"] + 2
    assert polled[-1]["failures"] != polled[0]["failures"]


def test_an_unchanged_polled_view_answers_304_to_the_etag_it_sent(client, keys, store):
    study_id = _run(store)
    url = f"/api/v1/studies/{study_id}"

    first = client.get(url, headers=keys.auth())
    again = client.get(url, headers={**keys.auth(), "If-None-Match": first.headers["etag"]})
    store.transition(study_id, [StudyStatus.DONE], StudyStatus.DONE)  # any change to the study row
    changed = client.get(url, headers={**keys.auth(), "If-None-Match": first.headers["etag"]})

    assert first.status_code == 200 and first.headers["cache-control"] == "no-cache"
    assert again.status_code == 304 and again.content == b""
    assert changed.status_code == 200 and changed.json()["updated_at"] != first.json()["updated_at"]


def test_a_view_whose_version_moved_but_not_its_bytes_answers_304_with_its_new_etag(client, keys, store):
    # The recommendation (~100 kB for a long study) and the Pareto front do not change when the
    # study row does for another reason (a batch queued, a status written again): a version ETag
    # alone sent them again in full after each (benchmarks/README.md, session 7).
    study_id = _run(store)
    urls = [f"/api/v1/studies/{study_id}{view}" for view in ("/pareto", "/recommendation")]
    first = {url: client.get(url, headers=keys.auth()) for url in urls}
    store.transition(study_id, [StudyStatus.DONE], StudyStatus.DONE)  # a change of the row alone

    moved = {url: client.get(url, headers={**keys.auth(), "If-None-Match": first[url].headers["ETag"]})
             for url in urls}
    again = {url: client.get(url, headers={**keys.auth(), "If-None-Match": moved[url].headers["ETag"]})
             for url in urls}
    full = {url: client.get(url, headers=keys.auth()) for url in urls}

    assert [moved[url].status_code for url in urls] == [304, 304]
    assert all(moved[url].content == b"" for url in urls)
    assert all(moved[url].headers["ETag"] != first[url].headers["ETag"] for url in urls)
    assert [again[url].status_code for url in urls] == [304, 304]
    assert all(full[url].content == first[url].content for url in urls)
    assert all(full[url].headers["ETag"] == moved[url].headers["ETag"] for url in urls)


POLLED_VIEWS = ("", "/pareto", "/recommendation", "/progress", "/identifiability")


def test_a_client_holding_the_current_version_gets_a_304_from_any_server_without_the_view(
    client, settings, keys, store, engine
):
    # A view's ETag was a hash of its bytes: a conditional GET found (or, in another process or
    # after a change elsewhere, built) the view to compare. Its ETag is now the study's change
    # number, so a server whose cache is empty answers from the one version lookup.
    import sqlalchemy as sa

    study_id = _run(store)
    urls = [f"/api/v1/studies/{study_id}{view}" for view in POLLED_VIEWS]
    tags = {url: client.get(url, headers=keys.auth()).headers["ETag"] for url in urls}
    statements: list[str] = []
    held = settings.model_copy(update={"api_key_cache_s": 3600.0})

    with TestClient(create_app(held, engine=engine)) as replica:  # another process: its cache is empty
        replica.get("/api/v1/studies", headers=keys.auth())  # the key is verified once, then cached
        def count(*args):
            statements.append(args[2])

        sa.event.listen(engine, "before_cursor_execute", count)
        try:
            answers = {url: replica.get(url, headers={**keys.auth(), "If-None-Match": tags[url]})
                       for url in urls}
        finally:
            sa.event.remove(engine, "before_cursor_execute", count)
        store.set_status(study_id, StudyStatus.DONE, "a change of the study")
        after = {url: replica.get(url, headers={**keys.auth(), "If-None-Match": tags[url]}) for url in urls}

    assert {url: answer.status_code for url, answer in answers.items()} == {url: 304 for url in urls}
    assert all(answers[url].headers["ETag"] == tags[url] for url in urls)
    assert all(answer.headers["X-Demcal-View"] == "current" for answer in answers.values())
    assert len(statements) == len(urls)  # the version lookup, and nothing else
    assert after[urls[0]].status_code == 200 and after[urls[0]].json()["status"] == "done"
    assert after[urls[0]].headers["ETag"] != tags[urls[0]]


class _Refused:
    """A pydantic validator that fails: what it replaces must not be called."""

    def validate_python(self, *args, **kwargs):
        raise AssertionError("validated again")


def test_the_recommendation_is_serialised_from_its_column_rows_without_validating_each_point(
    client, keys, store, monkeypatch
):
    # Validating each matching point again was a recommendation build's cost (benchmarks/README.md,
    # API session 8, part 2): its JSON is still what RecommendationRead reads.
    from api.schemas import ParetoPoint, RecommendationRead

    study_id = _run(store, executor=SyntheticExecutor(_half_matching))
    tolerance = StudyDefinition.model_validate(store.load_study(study_id).definition).match_tolerance()
    trials = f"/api/v1/studies/{study_id}/trials"
    items = client.get(trials, params={"limit": 500}, headers=keys.auth()).json()
    first_of_each: dict[int, dict] = {}
    for item in items["items"]:  # ordered by generation, individual, replicate
        if item["status"] == "ok" and item["f1"] is not None and item["f1"] <= tolerance:
            first_of_each.setdefault(item["individual"], {key: item[key] for key in ParetoPoint.model_fields})
    expected = sorted(first_of_each.values(), key=lambda point: (point["f2"], point["f1"]))
    for model in (ParetoPoint, RecommendationRead):
        monkeypatch.setattr(model, "__pydantic_validator__", _Refused())

    body = client.get(f"/api/v1/studies/{study_id}/recommendation", headers=keys.auth()).content
    monkeypatch.undo()

    read = RecommendationRead.model_validate_json(body)
    assert read.model_dump(mode="json")["equivalent"] == expected and expected
    assert read.recommendation == store.load_study(study_id).recommendation
    assert read.status == StudyStatus.DONE


def test_the_recommendations_matching_trials_are_read_off_the_f1_index(tmp_path):
    # Without it each build scanned all the study's trials: 3.0 of its 10 ms of CPU on the
    # benchmark's study (benchmarks/README.md, API session 8, part 2). SQLite's plan: PostgreSQL
    # plans by the table's statistics.
    import sqlalchemy as sa

    from api.db import create_db_engine, upgrade_database
    from api.store import SqlStore

    url = f"sqlite:///{tmp_path}/plan.db"
    upgrade_database(url)
    engine = create_db_engine(url)
    statements = []
    sa.event.listen(engine, "before_cursor_execute", lambda *args: statements.append(args[2:4]))

    SqlStore(engine).trial_columns("st-any", f1_at_most=0.5)

    statement, parameters = statements[-1]
    with engine.connect() as connection:
        rows = connection.exec_driver_sql(f"EXPLAIN QUERY PLAN {statement}", parameters)
        plan = " ".join(str(row[-1]) for row in rows)
    assert "ix_trials_study_f1" in plan, plan
